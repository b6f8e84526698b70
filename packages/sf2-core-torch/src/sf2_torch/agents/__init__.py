"""SF² agents on PyTorch and TorchRL: TD3 and SAC, vanilla or on SF² features, trained on MuJoCo
Playground DM Control tasks. The torch mirror of `sf2_jax.agents`: same module names, config fields and
presets (`paper`, `quick`), representation interface, run-folder layout and CLI (`sf2-torch` ↔ `sf2-jax`).

Needs the `[train]` extra (torchrl, tensordict, playground, mujoco-mjx, jax, matplotlib, tqdm). Modules:
`envs` (tasks; a TorchRL env over Playground's JAX env), `configs` (TrainConfig, presets, validation),
`objectives` (TorchRL loss modules: SF² flow loss, TD3/SAC on SF² features, TorchRL's TD3Loss/SACLoss as
the vanilla baselines), `representations` (the pluggable interface: `none`, `sf2`; sf2-baselines adds
`sim`, `simlap`, `spr`), `algorithms` (TD3, SAC: `sgd_step` with explicit noise), `replay` (TorchRL
replay buffer), `trainer` (the one training loop), `checkpoint`, `runfolder`, `plotting`, `timing`
(update time: torch eager, compiled, CUDA graphs, against sf2_jax). The framework-free parts live in
`sf2_common.agents`. The CLI is `sf2_torch.cli` (`sf2-torch`).

    from sf2_torch.agents import make_config, train
    cfg = make_config("quick", "CartpoleBalance", algo="td3", representation="sf2")
    result = train(cfg, seeds="0-3", out="runs/cartpole-td3-sf2-torch")

Names are imported lazily (`sf2_common.agents.lazy_getattr`), so importing a light module (e.g.
`configs`) does not pull in the trainer.
"""

from __future__ import annotations

from sf2_common.agents import EXPORTS as _EXPORTS
from sf2_common.agents import lazy_getattr

__all__ = sorted(_EXPORTS)

__getattr__ = lazy_getattr(__name__)
