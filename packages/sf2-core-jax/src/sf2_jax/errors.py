"""Errors raised by sf2_jax (docs/core-contract.md, "Modules").

All three subclass `ValueError`, so code that already catches bad values keeps working.
"""

from __future__ import annotations

__all__ = ["ConfigError", "ShapeError", "ParamsError"]


class ConfigError(ValueError):
    """A configuration value (or `algo`, or integrator name) is invalid; the message names it."""


class ShapeError(ValueError):
    """An array has the wrong size; the message names the expected and the found sizes."""


class ParamsError(ValueError):
    """A canonical parameter mapping or file does not match the networks; every bad entry is named."""
