"""Canonical parameters of the baselines (PyTorch): the core's functions, which walk any module tree.

`to_canonical(nets)` / `from_canonical(flat, nets)` / `validate(flat, nets)` / `expected_shapes(nets)` /
`save` / `load` are `sf2_torch.params`'s; on `SimNetworks` and `SPRNetworks` they give the names of
`sf2_baselines.jax.params` (kernels (in, out), LayerNorm `scale`, `task.w` of shape (F,)).
"""

from __future__ import annotations

from sf2_torch.params import expected_shapes, from_canonical, load, save, to_canonical, validate

__all__ = ["to_canonical", "from_canonical", "validate", "expected_shapes", "save", "load"]
