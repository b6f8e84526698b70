"""`sf2-jax`: train, evaluate and plot TD3/SAC agents (vanilla, SF², a baseline) and FPO agents on MuJoCo
Playground, PPO agents (PPO-Q, PPO, SF² w/o or w AE) on MinAtar and CRL agents (CRL, CRL+SF²) on ant-goal.

    sf2-jax train --task CartpoleBalance --algo td3 --repr sf2,none --config quick --seeds 0-1 --out runs/cmp
    sf2-jax train --task minatar-breakout --algo ppo --repr sf2-ae --config quick --seeds 0-1 --out runs/mb
    sf2-jax eval runs/mb [--epoch N] [--episodes 20] [--stochastic]
    sf2-jax plot runs/cmp/td3-sf2 runs/cmp/td3-none --out curves.png
    sf2-jax tasks

Every `TrainConfig` field can be overridden with its own flag (`--batch-size 128`) or `--set batch_size=128`
(repeatable). `--repr` takes none, sf2 and, with sf2-baselines installed, sim, simlap, simlap_authors, spr;
with `--algo ppo` none, sf2, sf2-ae; with `--algo fpo` or `crl` none, sf2. `--algo ppo` (MinAtar) and `fpo`
train with the on-policy trainer (`agents.onpolicy`), `--algo crl` (ant-goal) with `agents.crl`, td3 and sac
with the off-policy one; `eval` picks the folder's. Bad input is reported before anything is compiled (exit
status 2); a NaN/inf loss stops the run (3). `study` comes with sf2-studies; `sf2_common.cli` is shared.
"""

from __future__ import annotations

import sys

from sf2_common import cli as common

from sf2_jax.agents.configs import TrainConfig, make_config, validate

__all__ = ["PROG", "CACHE_ENV", "build_parser", "backend", "resolve_configs", "train", "evaluate", "main"]

PROG = "sf2-jax"
CACHE_ENV = "SF2_JAX_COMPILE_CACHE"


def build_parser():
    """The parser of `sf2-jax`: train (a flag per TrainConfig field), eval, plot, plugins, tasks."""
    parser, sub = common.new_parser(PROG, __doc__)
    common.add_train_parser(sub, PROG, TrainConfig, "all seeds run in one vmapped program", CACHE_ENV)
    common.add_shared_parsers(sub, PROG)
    return parser


def backend() -> common.Backend:
    """What a plugin command (`study`) gets from this core (its module by name: `__name__` is "__main__"
    when the command runs as `python -m sf2_jax.cli`)."""
    return common.Backend(PROG, "jax", "sf2_jax.cli", make_config, validate)


def resolve_configs(args):
    """The configs and seeds of parsed `train` arguments, validated (`sf2_common.cli.resolve_configs`)."""
    return common.resolve_configs(args, TrainConfig, make_config, validate)


def train(args) -> int:
    """`sf2-jax train`: the JAX trainer of the task's kind on every config of the arguments."""
    from sf2_jax.agents import trainer
    from sf2_jax.agents.trainers import trainer_module

    cfgs, seeds = resolve_configs(args)
    module = trainer_module(cfgs[0].task, cfgs[0].algo)
    if module is trainer:
        from sf2_common.agents.plotting import method_label

        from sf2_jax.agents import representations

        return common.train_runs(args, cfgs, seeds, trainer.train,
                                 lambda algo, rep: method_label(algo, rep, representations.REGISTRY))
    labels = {(c.algo, c.representation): module.method_label(c) for c in cfgs}
    return common.train_runs(args, cfgs, seeds, module.train, lambda algo, rep: labels[(algo, rep)])


def _trainer_of(run):
    """The trainer module that wrote the run folder `run` (the off-policy one when it holds no readable
    config: its evaluation names that problem)."""
    from sf2_common.agents.runfolder import RunFolder, RunFolderError

    from sf2_jax.agents.trainers import trainer_module

    try:
        conf = RunFolder(run).read_config()
    except (RunFolderError, OSError):
        conf = None
    config = conf["config"] if conf else {}
    return trainer_module(config.get("task"), config.get("algo"))


def evaluate(args) -> int:
    """`sf2-jax eval`: a checkpoint of a run folder a JAX trainer wrote, by that trainer."""
    module = _trainer_of(args.run)
    return common.eval_command(args, module.evaluate_checkpoint, module.evaluate_checkpoint_noises,
                               common.compile_cache(PROG, CACHE_ENV))


def main(argv=None) -> int:
    """Run one command of `sf2-jax` (`argv`: default sys.argv[1:]); returns the exit status."""
    commands = {"train": train, "eval": evaluate, "plot": common.plot_command, "tasks": common.tasks_command}
    return common.run(PROG, build_parser(), commands, backend, argv)


if __name__ == "__main__":
    sys.exit(main())
