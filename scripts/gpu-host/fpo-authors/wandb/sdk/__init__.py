"""Stand-in package: `wandb.sdk.wandb_run.Run`, which the authors' rollouts module imports for a type."""
