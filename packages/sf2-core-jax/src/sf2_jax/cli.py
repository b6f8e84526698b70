"""`sf2-jax`: train, evaluate and plot TD3/SAC agents, vanilla, with SF² or a baseline, on MuJoCo Playground.

    sf2-jax train --task CartpoleBalance --algo td3 --repr sf2 --config quick --seeds 0-3 --out runs/cp
    sf2-jax train --task CartpoleBalance --algo td3 --repr sf2,none --config quick --seeds 0-1 --out runs/cmp
    sf2-jax eval runs/cp [--epoch N] [--episodes 20] [--stochastic]
    sf2-jax plot runs/cmp/td3-sf2 runs/cmp/td3-none --out curves.png
    sf2-jax tasks

Every `TrainConfig` field can be overridden, either with its own flag (`--batch-size 128`,
`--hidden-sizes 64,64`) or with `--set batch_size=128` (repeatable). `--repr` takes none, sf2 and, with
sf2-baselines installed (`pip install packages/sf2-baselines`), sim, simlap, simlap_authors, spr. Bad input
(unknown task, algo or representation, a combination that does not exist, a budget smaller than the
prefill, ...) is reported before anything is compiled; exit status 2. A NaN/inf loss stops the run with
exit status 3. `study` comes with sf2-studies. The parts shared with `sf2-torch` are `sf2_common.cli`.
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
    """`sf2-jax train`: the JAX trainer on every config of the arguments."""
    cfgs, seeds = resolve_configs(args)
    from sf2_common.agents.plotting import method_label

    from sf2_jax.agents import representations
    from sf2_jax.agents.trainer import train as train_run

    return common.train_runs(args, cfgs, seeds, train_run,
                             lambda algo, rep: method_label(algo, rep, representations.REGISTRY))


def evaluate(args) -> int:
    """`sf2-jax eval`: a checkpoint of a run folder the JAX trainer wrote."""
    from sf2_jax.agents import trainer

    return common.eval_command(args, trainer.evaluate_checkpoint, trainer.evaluate_checkpoint_noises,
                               common.compile_cache(PROG, CACHE_ENV))


def main(argv=None) -> int:
    """Run one command of `sf2-jax` (`argv`: default sys.argv[1:]); returns the exit status."""
    commands = {"train": train, "eval": evaluate, "plot": common.plot_command, "tasks": common.tasks_command}
    return common.run(PROG, build_parser(), commands, backend, argv)


if __name__ == "__main__":
    sys.exit(main())
