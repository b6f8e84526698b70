"""sf2_baselines.jax: Sim, SimLap and SPR on the JAX core (`sf2_jax`).

Modules: `sim`, `simlap`, `spr` (networks, critics and their own pure losses with explicit noise;
their TD3/SAC losses are `sf2_jax.losses`' with `critic=`), `common` (shared checks, L2 normalization),
`params` (canonical interchange),
`representations` (the agents' plug-ins). Importing this package registers `sim`, `simlap`,
`simlap_authors` and `spr` with `sf2_jax.agents.representations` when the agents are importable.
"""

from __future__ import annotations

from . import common, params, sim, simlap, spr

__all__ = ["common", "params", "sim", "simlap", "spr", "REGISTERED"]

try:
    from . import representations
except ImportError:  # the core without its agents: losses and networks still work
    REGISTERED: tuple[str, ...] = ()
else:
    REGISTERED = representations.register_all()
    __all__.append("representations")
