"""`sf2-torch`: train, evaluate and plot TD3/SAC agents, vanilla, with SF² or a baseline, on MuJoCo
Playground, with PyTorch. The same commands, flags, run folders and exit statuses as `sf2-jax` (the parts
they share are `sf2_common.cli`): switch framework by changing that one word. Torch-only flags:
`--device`, `--compile`, `--cudagraphs`. JAX still runs the Playground envs, so `--compile-cache` (JAX's
persistent compilation cache) applies here too.

    sf2-torch train --task CartpoleBalance --algo td3 --repr sf2 --config quick --seeds 0-3 --out runs/cp
    sf2-torch train --task CartpoleBalance --algo td3 --repr sf2,none --config quick --seeds 0-1 \
        --out runs/cmp
    sf2-torch eval runs/cp [--epoch N] [--episodes 20] [--stochastic]
    sf2-torch plot runs/cmp/td3-sf2 runs/cmp/td3-none --out curves.png
    sf2-torch tasks

`--repr` takes none, sf2 and, with sf2-baselines installed (`pip install packages/sf2-baselines`), sim,
simlap, simlap_authors, spr; `study` comes with sf2-studies. Heavy imports (torch, torchrl, jax,
playground) happen after the arguments are parsed.
"""

from __future__ import annotations

import os
import sys

from sf2_common import cli as common

from sf2_torch.agents.configs import TrainConfig, make_config, validate

__all__ = ["PROG", "CACHE_ENV", "build_parser", "backend", "resolve_configs", "train", "evaluate", "main"]

PROG = "sf2-torch"
CACHE_ENV = "SF2_TORCH_COMPILE_CACHE"
SEEDS_HELP = "the seeds' envs step in one batch, their SGD steps one after the other"


def build_parser():
    """The parser of `sf2-torch`: the commands of `sf2-jax`, and the torch-only config fields as flags."""
    parser, sub = common.new_parser(PROG, __doc__)
    common.add_train_parser(sub, PROG, TrainConfig, SEEDS_HELP, CACHE_ENV)
    common.add_shared_parsers(sub, PROG)
    return parser


def backend() -> common.Backend:
    """What a plugin command (`study`) gets from this core: its TrainConfig, with the torch fields."""
    return common.Backend(prog=PROG, name="torch", cli_module="sf2_torch.cli", make_config=make_config,
                          validate=validate)


def resolve_configs(args):
    """The configs and seeds of parsed `train` arguments, each validated against the torch agents'
    representations and the torch-only fields (`sf2_common.cli.resolve_configs`)."""
    return common.resolve_configs(args, TrainConfig, make_config, validate)


def train(args) -> int:
    """`sf2-torch train`: the torch trainer on every config of the arguments."""
    cfgs, seeds = resolve_configs(args)
    from sf2_common.agents import plotting

    from sf2_torch.agents.representations import REGISTRY
    from sf2_torch.agents.trainer import train as train_run

    def label(algo, representation):
        return plotting.method_label(algo, representation, REGISTRY)

    return common.train_runs(args, cfgs, seeds, train_run, label)


def evaluate(args) -> int:
    """`sf2-torch eval`: a checkpoint of a run folder the torch trainer wrote."""
    from sf2_torch.agents.trainer import evaluate_checkpoint, evaluate_checkpoint_noises

    cache = common.compile_cache(PROG, CACHE_ENV)
    return common.eval_command(args, evaluate_checkpoint, evaluate_checkpoint_noises, cache)


def main(argv=None) -> int:
    """Run one command of `sf2-torch` (`argv`: default sys.argv[1:]); returns the exit status. JAX (the
    envs) shares the GPU with torch, so it does not preallocate GPU memory unless told to."""
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    handlers = dict(train=train, eval=evaluate, plot=common.plot_command, tasks=common.tasks_command)
    return common.run(PROG, build_parser(), handlers, backend, argv)


if __name__ == "__main__":
    sys.exit(main())
