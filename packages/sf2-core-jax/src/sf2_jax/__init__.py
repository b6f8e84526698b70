"""sf2_jax: the JAX core of Successor Flow Features (SF², ICLR 2026).

Modules (docs/core-contract.md): `config` (`SF2Config`), `errors`, `networks` (ψ, ζ, Q, policies,
normalizer, flow-time embedding), `ode` (midpoint and Euler), `losses` (pure losses, explicit noise),
`params` (canonical interchange).
"""

from sf2_jax import config, errors, losses, networks, ode, params
from sf2_jax.config import SF2Config
from sf2_jax.errors import ConfigError, ParamsError, ShapeError

__version__ = "0.1.0"

__all__ = [
    "SF2Config", "ConfigError", "ShapeError", "ParamsError",
    "config", "errors", "networks", "ode", "losses", "params", "__version__",
]
