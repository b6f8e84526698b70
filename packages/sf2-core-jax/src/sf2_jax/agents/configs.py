"""The JAX agents' `TrainConfig`: `sf2_common.agents.configs.TrainConfig` as it is (the JAX agents add no
run fields; the same fields, defaults, presets, parsing and messages as the torch agents'), with
`make_config` and `validate` bound to it and to the JAX agents' representation registry. Everything else
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
    JAX agents' registry). Raises `ConfigError`."""
    from . import representations

    return _configs.validate(cfg, seeds, representations.REGISTRY)
