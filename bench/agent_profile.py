"""Where the device time of a training epoch goes: a `jax.profiler` trace of the JAX trainer's epochs.

    python -m bench.agent_profile --task AcrobotSwingup --algo td3 --reps none,sf2 --seeds 1,8 \
        --out bench/results/h200/11-agent-profile

Each case builds the trainer's own program (`sf2_jax.agents.trainer.get_program` of the `paper` preset
with the budget cut so an epoch holds `--actor-steps` actor steps), runs one epoch (compilation and the
random prefill), then traces `--epochs` epochs with `bench.profile.trace`. Everything is reported per SGD
step (an actor step = one vectorized env step, a buffer insert, `grad_updates_per_step` batches and SGD
steps), so kernel counts and device time compare directly with `bench run --profile`'s single updates.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


class _EpochRunner:
    """`bench.profile.trace`'s runner protocol over the trainer's epochs."""

    def __init__(self, program, state, sgd_per_epoch: int):
        self.program, self.state, self.epoch = program, state, 2
        self.per_call = sgd_per_epoch

    def step(self):
        self.state, self.means, _ = self.program.epoch(self.state, self.epoch)
        self.epoch += 1

    def sync(self):
        import jax

        jax.block_until_ready((self.state, self.means))


def profile_case(task, algo, rep, n_seeds, actor_steps, epochs, overrides, log=print) -> dict:
    import jax
    from sf2_common.agents import configs
    from sf2_jax.agents.trainer import get_program

    from .profile import trace

    base = configs.make_config("paper", task, algo, rep, overrides)
    per_actor = base.num_envs * base.action_repeat
    prefill_steps = -(-base.min_replay_size // base.num_envs)
    per_epoch = max(actor_steps, prefill_steps)
    total = per_epoch * (epochs + 4)
    cfg = base.replace(num_timesteps=total * per_actor, num_evals=epochs + 5)
    seeds = tuple(range(n_seeds))
    program = get_program(cfg)
    state = program.init(seeds)
    state, means, _ = program.epoch(state, 1)
    jax.block_until_ready((state, means))
    sgd = program.sched.actor_steps_per_epoch * cfg.grad_updates_per_step
    label = f"{task} {algo}+{rep}, {n_seeds} seed{'s' * (n_seeds > 1)} (vmapped), per SGD step"
    log(f"  tracing {label}: {epochs} epochs of {program.sched.actor_steps_per_epoch} actor steps")
    return trace(_EpochRunner(program, state, sgd), updates=epochs, label=label)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.agent_profile", description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="AcrobotSwingup")
    p.add_argument("--algo", default="td3")
    p.add_argument("--reps", default="none,sf2")
    p.add_argument("--seeds", default="1,8", help="numbers of vmapped seeds, e.g. 1,8")
    p.add_argument("--actor-steps", type=int, default=64, help="actor steps per traced epoch")
    p.add_argument("--epochs", type=int, default=2, help="traced epochs per case")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    from sf2_common.agents import configs

    from .machine import describe
    from .profile import markdown

    overrides = configs.parse_overrides(args.set) if args.set else {}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = "python -m bench.agent_profile " + " ".join(argv if argv is not None else sys.argv[1:])
    summaries = []
    for n in (int(x) for x in args.seeds.split(",")):
        for rep in (r for r in args.reps.split(",") if r):
            summaries.append(profile_case(args.task, args.algo, rep, n, args.actor_steps, args.epochs,
                                          overrides))
            (out / "agent_profile.md").write_text(f"Command: `{command}`\n\n" + markdown(summaries))
    (out / "agent_profile.json").write_text(json.dumps(summaries, indent=1))
    (out / "machine.json").write_text(json.dumps(describe(str(Path(__file__).resolve().parents[1]), command),
                                                 indent=2))
    print((out / "agent_profile.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
