"""sf2_jax: the JAX core of Successor Flow Features (SF², ICLR 2026).

Modules (docs/core-contract.md): `networks` (ψ, ζ, Q, policies, normalizer, flow-time embedding), `ode`
(midpoint and Euler), `losses` (pure losses, explicit noise), `params` (canonical interchange);
`networks_image` and `losses_onpolicy`: the MinAtar system's (docs/minatar.md). `SF2Config`
and the errors are `sf2_common.config` / `sf2_common.errors` (one class for both cores), named here too.
"""

from sf2_common.config import SF2Config
from sf2_common.errors import ConfigError, ParamsError, ShapeError

from sf2_jax import losses, losses_onpolicy, networks, networks_image, ode, params

__version__ = "0.2.0"

__all__ = ["SF2Config", "ConfigError", "ShapeError", "ParamsError", "networks", "ode", "losses", "params",
           "networks_image", "losses_onpolicy", "__version__"]
