"""sf2_torch: PyTorch core of Successor Flow Features (SF², ICLR 2026).

Modules (same names as the JAX core; docs/core-contract.md): `networks` (ψ, ζ, twin Q, TD3 and SAC
policies, observation normalizer, flow-time embedding), `ode` (`integrate`), `losses` (pure losses with
explicit noise, `ema_update`), `params` (canonical interchange); `networks_image` and `losses_onpolicy`:
the MinAtar system's (docs/minatar.md); `objectives`: SF²'s losses as TorchRL loss modules (docs/torchrl.md),
imported on first use (it needs torchrl). `SF2Config` and the errors are `sf2_common`'s, shared with the JAX
core.
"""

from sf2_common.config import SF2Config
from sf2_common.errors import ConfigError, ParamsError, ShapeError

from . import losses, losses_onpolicy, networks, networks_image, ode, params
from .losses import Batch
from .networks import Networks, make_networks

__version__ = "0.2.0"

__all__ = [
    "SF2Config", "ConfigError", "ShapeError", "ParamsError", "Batch", "Networks", "make_networks",
    "networks", "ode", "losses", "params", "networks_image", "losses_onpolicy", "__version__",
]


def __getattr__(name: str):
    """`sf2_torch.objectives` on first use: it imports torchrl, which `import sf2_torch` does not."""
    if name == "objectives":
        import importlib

        return importlib.import_module(".objectives", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
