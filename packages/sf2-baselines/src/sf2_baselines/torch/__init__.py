"""sf2_baselines.torch: Sim, SimLap and SPR on the PyTorch core (`sf2_torch`).

Modules (same names and functions as `sf2_baselines.jax`, without the `params` argument): `sim`,
`simlap`, `spr` (modules and pure losses with explicit noise), `common`, `params`. Importing this
package registers `sim`, `simlap`, `simlap_authors` and `spr` with the torch agents' representation
registry when `sf2_torch.agents` exists.
"""

from __future__ import annotations

from . import common, params, sim, simlap, spr

__all__ = ["common", "params", "sim", "simlap", "spr", "REGISTERED"]

try:
    from . import representations
except ImportError:  # no torch agents (yet): losses and networks still work
    REGISTERED: tuple[str, ...] = ()
else:
    REGISTERED = representations.register_all()
    __all__.append("representations")
