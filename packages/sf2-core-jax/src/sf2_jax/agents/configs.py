"""`TrainConfig`: everything one training run needs, the `paper` and `quick` presets, CLI overrides, and
validation that fails before any compilation with a message naming the field, the value and what is valid.

All of it is `sf2_common.agents.configs` (shared with `sf2_torch.agents.configs`, which adds its
torch-only run fields); this module re-exports it and binds `validate` to the JAX agents' representation
registry. See that module for the presets and where the `paper` preset follows the authors' code rather
than Table 1 (DESIGN.md §5).
"""

from __future__ import annotations

from sf2_common.agents.configs import (
    ALGOS,
    PRESETS,
    SF2_FIELDS,
    ConfigError,
    Schedule,
    TrainConfig,
    make_config,
    parse_overrides,
    parse_seeds,
    parse_value,
    schedule,
)
from sf2_common.agents.configs import validate as _validate

__all__ = [
    "TrainConfig", "PRESETS", "ALGOS", "SF2_FIELDS", "make_config", "parse_overrides", "parse_value",
    "parse_seeds", "validate", "Schedule", "schedule", "ConfigError",
]


def validate(cfg: TrainConfig, seeds=(0,)) -> TrainConfig:
    """Check everything that can be checked without building a program (the representation against the
    JAX agents' registry). Raises `ConfigError`."""
    from . import representations

    return _validate(cfg, seeds, representations.REGISTRY)
