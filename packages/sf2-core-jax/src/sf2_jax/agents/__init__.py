"""SF² agents: TD3 and SAC, vanilla or on SF² features, trained on MuJoCo Playground DM Control tasks.

Needs the `[train]` extra (brax, playground, orbax-checkpoint, matplotlib, tqdm). Modules:
`envs` (tasks), `configs` (TrainConfig, presets, validation), `representations` (the pluggable
interface: `none`, `sf2`; sf2-baselines adds `sim`, `simlap`, `spr`), `algorithms` (TD3, SAC),
`replay`, `trainer` (the one training loop), `checkpoint` (Orbax), `runfolder`, `plotting`. The
framework-free parts live in `sf2_common.agents`. The CLI is `sf2_jax.cli` (`sf2-jax`).

    from sf2_jax.agents import make_config, train
    cfg = make_config("quick", "CartpoleBalance", algo="td3", representation="sf2")
    result = train(cfg, seeds="0-3", out="runs/cartpole-td3-sf2")

Names are imported lazily (`sf2_common.agents.lazy_getattr`), so importing a light module (e.g.
`configs`) does not pull in the trainer.
"""

from __future__ import annotations

from sf2_common.agents import EXPORTS as _EXPORTS
from sf2_common.agents import lazy_getattr

__all__ = sorted(_EXPORTS)

__getattr__ = lazy_getattr(__name__)
