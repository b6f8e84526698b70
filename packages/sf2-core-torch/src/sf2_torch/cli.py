"""`sf2-torch`: train, evaluate and plot TD3/SAC agents, vanilla, with SF² or a baseline, on MuJoCo
Playground, with PyTorch. The same commands, flags, run folders and exit statuses as `sf2-jax` (both are
`sf2_common.cli`): switch framework by changing that one word. Torch-only flags: `--device`, `--compile`,
`--cudagraphs`. JAX still runs the Playground envs, so `--compile-cache` (JAX's persistent compilation
cache) applies here too.

    sf2-torch train --task CartpoleBalance --algo td3 --repr sf2 --config quick --seeds 0-3 --out runs/cp
    sf2-torch train --task CartpoleBalance --algo td3 --repr sf2,none --config quick --seeds 0-1 \
        --out runs/cmp
    sf2-torch eval runs/cp [--epoch N] [--episodes 20] [--stochastic]
    sf2-torch plot runs/cmp/td3-sf2 runs/cmp/td3-none --out curves.png
    sf2-torch tasks

`--repr` takes none, sf2 and, with sf2-baselines installed (`pip install packages/sf2-baselines`), sim,
simlap, simlap_authors, spr. Heavy imports (torch, torchrl, jax, playground) happen after the arguments
are parsed.
"""

from __future__ import annotations

import sys

from sf2_common import cli as _cli

from sf2_torch.agents import configs

__all__ = ["main", "build_parser", "FRAMEWORK"]


# The torch agents' functions the commands call, imported on first use (`sf2-torch tasks` imports no
# torch beyond the config class).
def _registry():
    from sf2_torch.agents import representations

    return representations.REGISTRY


def _train(*args, **kwargs):
    from sf2_torch.agents.trainer import train

    return train(*args, **kwargs)


def _evaluate_checkpoint(*args, **kwargs):
    from sf2_torch.agents.trainer import evaluate_checkpoint

    return evaluate_checkpoint(*args, **kwargs)


def _evaluate_checkpoint_noises(*args, **kwargs):
    from sf2_torch.agents.trainer import evaluate_checkpoint_noises

    return evaluate_checkpoint_noises(*args, **kwargs)


FRAMEWORK = _cli.Framework(
    prog="sf2-torch", package="sf2_torch", doc=__doc__,
    seeds_help="the seeds' envs step in one batch, their SGD steps one after the other",
    cache_env="SF2_TORCH_COMPILE_CACHE", config_class=configs.TrainConfig, registry=_registry,
    validate=configs.validate, train=_train, evaluate_checkpoint=_evaluate_checkpoint,
    evaluate_checkpoint_noises=_evaluate_checkpoint_noises,
    env_defaults=(("XLA_PYTHON_CLIENT_PREALLOCATE", "false"),),  # JAX (the envs) shares the GPU with torch
)


def build_parser():
    return _cli.build_parser(FRAMEWORK)


def main(argv=None) -> int:
    return _cli.main(FRAMEWORK, argv)


if __name__ == "__main__":
    sys.exit(main())
