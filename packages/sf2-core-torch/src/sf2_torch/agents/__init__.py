"""SF² agents on PyTorch (TorchRL for the env and the replay buffer): TD3 and SAC, vanilla or on SF²
features, trained on MuJoCo Playground DM Control tasks; the torch mirror of the JAX agents (same module
names, configs, presets, representation interface, run folders and CLI, `sf2-torch` ↔ `sf2-jax`).

Needs the `[train]` extra. Modules: `envs`, `configs` (TrainConfig with the torch-only fields),
`representations`, `algorithms`, `replay`, `trainer`, `checkpoint`, `graphs` (the step's CUDA graph); the
framework-free parts (run folders, plots, the host loop) are `sf2_common.agents`.

    from sf2_torch.agents import make_config, train
    cfg = make_config("quick", "CartpoleBalance", algo="td3", representation="sf2")
    result = train(cfg, seeds="0-3", out="runs/cartpole-td3-sf2-torch")

Names are imported lazily (`sf2_common.agents.lazy_getattr`), so importing a light module (e.g.
`configs`) does not pull in the trainer.
"""

from __future__ import annotations

from sf2_common.agents import EXPORTS, lazy_getattr

# TrainConfig, make_config, validate: this package's `configs` (the torch-only fields); parse_seeds:
# sf2_common's
_EXPORTS = {**EXPORTS, "parse_seeds": "sf2_common.agents.configs"}

__all__ = sorted(_EXPORTS)

__getattr__ = lazy_getattr(__name__, _EXPORTS)
