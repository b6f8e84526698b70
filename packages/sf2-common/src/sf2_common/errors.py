"""Errors raised by sf2_jax and sf2_torch (docs/core-contract.md, "Modules"), re-exported by both cores
(`sf2_jax.ConfigError is sf2_torch.ConfigError`); all subclass `ValueError`."""

from __future__ import annotations

__all__ = ["SF2Error", "ConfigError", "ShapeError", "ParamsError"]


class SF2Error(ValueError):
    """Base class of every error the sf2 packages raise on purpose."""


class ConfigError(SF2Error):
    """An invalid configuration value or option (the message names the field, the value, what is valid)."""


class ShapeError(SF2Error):
    """An input whose shape does not fit the networks (the message names the expected and found sizes)."""


class ParamsError(SF2Error):
    """Canonical parameters that do not fit the networks, or a parameter file that cannot be read."""
