"""Canonical parameters of the baselines (JAX): the core's scheme (docs/params.md) for Sim's and SPR's groups.

Names are dot-joined paths, kernels (in, out), LayerNorm `scale`/`bias`, exactly as the core's:
``phi.dense_0.kernel`` (D + A + F, h₀), ``q.head_0.dense_1.kernel`` (q_hidden_size, F) for Sim's SF heads,
``task.w`` (F,), ``encoder.dense_0.kernel`` (D + A, h₀), ``projection.dense_0.kernel`` (F, q_hidden_size),
``prediction.dense_0.kernel`` (q_hidden_size, q_hidden_size), plus the core's ``obs_norm.*``,
``policy.*``, ``target_policy.*`` (TD3) / ``log_alpha`` (SAC). `save` and `load` are the core's.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import jax
from sf2_common.errors import ParamsError
from sf2_jax.params import canonical_shapes, check_shapes, load, save, to_canonical, unflatten

from . import sim, spr

__all__ = ["to_canonical", "from_canonical", "validate", "expected_shapes", "save", "load"]


def _init_fn(nets):
    if isinstance(nets, sim.SimNetworks):
        return sim.init_params
    if isinstance(nets, spr.SPRNetworks):
        return spr.init_params
    raise ParamsError(f"expected SimNetworks or SPRNetworks, got {type(nets).__name__}")


@functools.lru_cache(maxsize=64)
def _expected(nets) -> dict[str, tuple[int, ...]]:
    init = _init_fn(nets)
    return canonical_shapes(jax.eval_shape(lambda: init(nets, jax.random.key(0))))


def expected_shapes(nets) -> dict[str, tuple[int, ...]]:
    """{canonical name: shape} of every group `init_params` gives for these networks."""
    return dict(_expected(nets))


def validate(flat: Mapping, nets) -> None:
    """Raise `ParamsError` naming every missing, unexpected and misshaped entry of `flat`."""
    cfg = nets.cfg
    check_shapes(flat, _expected(nets), f"the {type(nets).__name__} (algo {nets.algo!r}, obs_size "
                 f"{cfg.obs_size}, action_size {cfg.action_size}, feature_size {cfg.feature_size})")


def from_canonical(flat: Mapping, nets, dtype=None) -> dict:
    """Validate `flat` against `nets`, then build the nested params dict (cast to `dtype` if given)."""
    validate(flat, nets)
    return unflatten(flat, _expected(nets), dtype)
