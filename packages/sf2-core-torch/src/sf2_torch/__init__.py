"""sf2_torch: PyTorch core of Successor Flow Features (SF², ICLR 2026).

Modules (same names as `sf2_jax`): `config` (`SF2Config`), `errors`, `networks` (ψ, ζ, twin Q, TD3 and
SAC policies, observation normalizer, flow-time embedding), `ode` (`integrate`), `losses` (pure losses
with explicit noise, `ema_update`), `params` (canonical interchange). The specification is
docs/core-contract.md of the sf2 repository.
"""

from . import config, errors, losses, networks, ode, params
from .config import SF2Config
from .errors import ConfigError, ParamsError, ShapeError
from .losses import Batch
from .networks import SF2Networks, make_networks

__version__ = "0.1.0"

__all__ = [
    "SF2Config",
    "ConfigError",
    "ShapeError",
    "ParamsError",
    "Batch",
    "SF2Networks",
    "make_networks",
    "config",
    "errors",
    "networks",
    "ode",
    "losses",
    "params",
    "__version__",
]
