"""SF² agents: TD3 and SAC, vanilla or on SF² features, trained on MuJoCo Playground DM Control tasks.

Needs the `[train]` extra (brax, playground, orbax-checkpoint, matplotlib, tqdm). Modules:
`envs` (tasks), `configs` (TrainConfig, presets, validation), `representations` (the pluggable
interface: `none`, `sf2`), `algorithms` (TD3, SAC), `replay`, `trainer` (the one training loop),
`checkpoint` (Orbax), `runfolder`, `plotting`. The CLI is `sf2_jax.cli` (`sf2-jax`).

    from sf2_jax.agents import make_config, train
    cfg = make_config("quick", "CartpoleBalance", algo="td3", representation="sf2")
    result = train(cfg, seeds="0-3", out="runs/cartpole-td3-sf2")

Names are imported lazily, so importing a light module (e.g. `configs`) does not pull in the trainer.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "TrainConfig": "configs", "make_config": "configs", "parse_seeds": "configs", "validate": "configs",
    "Representation": "representations", "register": "representations",
    "TrainingDiverged": "trainer", "evaluate_checkpoint": "trainer", "get_program": "trainer",
    "train": "trainer",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
