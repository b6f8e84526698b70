"""The JAX agents' `TrainConfig`: `sf2_common.agents.configs.TrainConfig` as it is (the JAX agents add no
run fields; the same fields, defaults, presets, parsing and messages as the torch agents'), with
`make_config` and `validate` bound to it and to the JAX agents' representation registries (the off-policy
trainer's, and the on-policy trainer's for `--algo ppo`). Everything else
(parsing, seeds, the schedule) is `sf2_common.agents.configs`.
"""

from __future__ import annotations

from sf2_common.agents import configs as _configs
from sf2_common.agents.configs import TrainConfig

__all__ = ["TrainConfig", "make_config", "validate"]


def make_config(preset: str, task: str, algo: str = "td3", representation: str = "sf2",
                overrides: dict | None = None) -> TrainConfig:
    """The `preset` for `task` with `overrides` (field → value, already typed or strings) applied.
    Raises `ConfigError` for an unknown preset, task or field; call `validate` for the rest."""
    return _configs.make_config(preset, task, algo, representation, overrides, config_class=TrainConfig)


def validate(cfg: TrainConfig, seeds=(0,)) -> TrainConfig:
    """Check everything that can be checked without building a program (the representation against the
    registry of the algorithm's trainer: the off-policy `representations.REGISTRY`, or for `--algo ppo`
    `representations_onpolicy.REGISTRY`, whose representations also name the critics they take). Raises
    `ConfigError`."""
    if cfg.algo == "crl":   # the goal-conditioned trainer's own registry and fields
        from . import crl

        return crl.validate(cfg, seeds)
    if cfg.algo not in _configs.ONPOLICY_ALGOS:
        from . import representations

        return _configs.validate(cfg, seeds, representations.REGISTRY)
    from . import representations_onpolicy as onpolicy_reprs

    _configs.validate(cfg, seeds, onpolicy_reprs.REGISTRY)
    rep = onpolicy_reprs.get(cfg.representation)
    if cfg.critic not in rep.critics:
        _configs.bad_field("critic", cfg.critic, f"representation {cfg.representation!r} takes critic "
                           f"{' or '.join(repr(c) for c in rep.critics)} (SF² trains ψ through Q(s, a))")
    return cfg
