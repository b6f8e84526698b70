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
exit status 3. The command line is `sf2_common.cli`, shared with `sf2-torch`.
"""

from __future__ import annotations

import sys

from sf2_common import cli as _cli
from sf2_common.agents import configs

__all__ = ["main", "build_parser", "FRAMEWORK"]


# The JAX agents' functions the commands call, imported on first use (`sf2-jax tasks` imports no JAX).
def _registry():
    from sf2_jax.agents import representations

    return representations.REGISTRY


def _validate(cfg, seeds):
    return configs.validate(cfg, seeds, _registry())


def _train(*args, **kwargs):
    from sf2_jax.agents.trainer import train

    return train(*args, **kwargs)


def _evaluate_checkpoint(*args, **kwargs):
    from sf2_jax.agents.trainer import evaluate_checkpoint

    return evaluate_checkpoint(*args, **kwargs)


def _evaluate_checkpoint_noises(*args, **kwargs):
    from sf2_jax.agents.trainer import evaluate_checkpoint_noises

    return evaluate_checkpoint_noises(*args, **kwargs)


FRAMEWORK = _cli.Framework(
    prog="sf2-jax", package="sf2_jax", doc=__doc__,
    seeds_help="all seeds run in one vmapped program", cache_env="SF2_JAX_COMPILE_CACHE",
    config_class=configs.TrainConfig, registry=_registry, validate=_validate, train=_train,
    evaluate_checkpoint=_evaluate_checkpoint,
    evaluate_checkpoint_noises=_evaluate_checkpoint_noises,
)


def build_parser():
    return _cli.build_parser(FRAMEWORK)


def main(argv=None) -> int:
    return _cli.main(FRAMEWORK, argv)


if __name__ == "__main__":
    sys.exit(main())
