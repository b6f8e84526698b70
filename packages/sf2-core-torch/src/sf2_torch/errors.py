"""Errors raised by sf2_torch (docs/core-contract.md, "Modules"): the classes of `sf2_common.errors`, shared
with sf2_jax (catching `sf2_torch.ConfigError` also catches the other core's).

All of them subclass `ValueError`, so code that already catches bad values keeps working.
"""

from __future__ import annotations

from sf2_common.errors import ConfigError, ParamsError, SF2Error, ShapeError

__all__ = ["SF2Error", "ConfigError", "ShapeError", "ParamsError"]
