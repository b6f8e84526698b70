"""SF² agents: TD3 and SAC, vanilla or on SF² features, on MuJoCo Playground DM Control; PPO on MinAtar.
Needs the `[train]` extra (brax, playground, orbax-checkpoint, matplotlib, tqdm). Modules:
`envs` (tasks), `representations` (the pluggable interface: `none`, `sf2`; sf2-baselines adds `sim`,
`simlap`, `spr`), `algorithms` (TD3, SAC), `replay`, `trainer` (the off-policy training loop), `checkpoint`
(Orbax), `minatar` (pgx's MinAtar games, batched: the `[minatar]` extra), `onpolicy` (PPO-Q and PPO,
`--algo ppo`) and its `representations_onpolicy` (`none`, `sf2`, `sf2-ae`). The framework-free parts
(TrainConfig and its presets, run folders, plots, the host loop) are `sf2_common.agents`. The CLI is
`sf2_jax.cli` (`sf2-jax`).

    from sf2_jax.agents import make_config, train
    cfg = make_config("quick", "CartpoleBalance", algo="td3", representation="sf2")
    result = train(cfg, seeds="0-3", out="runs/cartpole-td3-sf2")

Names are imported lazily (`sf2_common.agents.lazy_getattr`), so importing a light module (e.g.
`representations`) does not pull in the trainer.
"""

from __future__ import annotations

from sf2_common.agents import EXPORTS, lazy_getattr

# TrainConfig, make_config, validate: this package's `configs` (sf2_common's TrainConfig, bound to the JAX
# agents' representations); parse_seeds: sf2_common's
_EXPORTS = {**EXPORTS, "parse_seeds": "sf2_common.agents.configs"}

__all__ = sorted(_EXPORTS)

__getattr__ = lazy_getattr(__name__, _EXPORTS)
