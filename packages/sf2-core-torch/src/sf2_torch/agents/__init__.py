"""SF² agents on PyTorch and TorchRL: TD3 and SAC, vanilla or on SF² features, trained on MuJoCo
Playground DM Control tasks. The torch mirror of `sf2_jax.agents`: same module names, config fields and
presets (`paper`, `quick`), representation interface, run-folder layout and CLI (`sf2-torch` ↔ `sf2-jax`).

Needs the `[train]` extra (torchrl, tensordict, playground, mujoco-mjx, jax, matplotlib, tqdm). Modules:
`envs` (tasks; a TorchRL env over Playground's JAX env), `configs` (TrainConfig, presets, validation),
`objectives` (TorchRL loss modules: SF² flow loss, TD3/SAC on SF² features, TorchRL's TD3Loss/SACLoss as
the vanilla baselines), `representations` (the pluggable interface: `none`, `sf2`), `algorithms` (TD3,
SAC: `sgd_step(td, actor_step)` with explicit noise), `replay` (TorchRL replay buffer), `trainer` (the
one training loop), `checkpoint`, `runfolder`, `plotting`, `timing` (update time: torch eager, compiled,
CUDA graphs, against sf2_jax). The CLI is `sf2_torch.cli` (`sf2-torch`).

    from sf2_torch.agents import make_config, train
    cfg = make_config("quick", "CartpoleBalance", algo="td3", representation="sf2")
    result = train(cfg, seeds="0-3", out="runs/cartpole-td3-sf2-torch")

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
