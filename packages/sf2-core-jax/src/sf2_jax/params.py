"""Canonical parameters: the framework-neutral interchange format of SF² (docs/params.md).

A canonical mapping is a flat ``dict[str, numpy.ndarray]`` whose keys are dot-joined paths. Loading the
same canonical mapping into `sf2_jax` and `sf2_torch` gives networks that compute the same numbers.

Groups (top-level names)
------------------------
==================  ===================================================================  ==========
group               content                                                              algo
==================  ===================================================================  ==========
``obs_norm``        running statistics ``count`` (), ``mean`` (D,), ``summed_var`` (D,),  both
                    ``std`` (D,)
``psi``             ψ: MLP(hidden_sizes → F) on [normalize(s), a]                        both
``zeta``            ζ: MLP(zeta_hidden_sizes → F·D) on [x, embedding(k)]                  both
``q``               twin Q heads ``q.head_0.*`` and ``q.head_1.*``                        both
``policy``          TD3: MLP(hidden_sizes → A); SAC: MLP(hidden_sizes → 2A)              both
``target_psi``      EMA copy of ``psi``                                                  both
``target_zeta``     EMA copy of ``zeta``                                                 both
``target_q``        EMA copy of ``q``                                                    both
``target_policy``   EMA copy of ``policy``                                               TD3 only
``log_alpha``       SAC temperature log α, shape ()                                       SAC only
==================  ===================================================================  ==========

Inside a network, layer i (counted from 0, input side first) has
``dense_{i}.kernel`` (in, out), ``dense_{i}.bias`` (out,) and, for each hidden layer when
``cfg.layer_norm``, ``layer_norm_{i}.scale`` (out,) and ``layer_norm_{i}.bias`` (out,). The last layer is
Dense only; Q heads have no LayerNorm. Kernels are always stored (in, out): JAX/flax layout; torch
transposes its ``weight``. ζ's last kernel (H, F·D) has output column d·F + f for entry (d, f) of ζ.

Examples with D = 5, A = 1 and the default sizes: ``psi.dense_0.kernel`` (6, 512),
``psi.layer_norm_0.scale`` (512,), ``psi.dense_3.kernel`` (512, 512), ``zeta.dense_0.kernel`` (69, 512),
``zeta.dense_2.kernel`` (512, 2560), ``q.head_1.dense_1.bias`` (1,), ``obs_norm.count`` ().

Files
-----
``save(path, flat)`` writes ``.npz`` (numpy only, `numpy.savez`) or ``.safetensors`` (needs the
`safetensors` package: ``pip install sf2-core-jax[safetensors]``), chosen by the suffix; ``load(path)``
reads either back as a flat mapping. Arrays keep their dtype (float32 or float64). A missing, unreadable
or corrupt file raises `ParamsError`.

Checking
--------
``validate(flat, nets)`` (or ``validate(flat, cfg, algo)``) compares a mapping with the names and shapes
that `networks.init_params` produces for that config and algorithm, and raises `ParamsError` listing every
missing, unexpected and misshaped entry (expected and found shapes). ``from_canonical`` validates first.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from sf2_common import paramfile
from sf2_common.config import SF2Config
from sf2_common.errors import ParamsError

from sf2_jax import networks as nw

__all__ = ["to_canonical", "from_canonical", "validate", "expected_shapes", "save", "load", "FORMATS",
           "canonical_shapes", "unflatten"]

FORMATS = paramfile.FORMATS


def _flatten(tree) -> dict:
    """{dot-joined path: leaf} of a nested mapping, keys sorted."""
    flat = {}

    def walk(prefix: str, node):
        if isinstance(node, Mapping):
            for key in sorted(node):
                walk(f"{prefix}.{key}" if prefix else str(key), node[key])
        else:
            flat[prefix] = node

    walk("", tree)
    return flat


def to_canonical(params: Mapping) -> dict[str, np.ndarray]:
    """Flatten a `params` dict of canonical groups to {dot-joined name: numpy array} (copies)."""
    return {name: np.array(value) for name, value in _flatten(params).items()}


def canonical_shapes(tree) -> dict[str, tuple[int, ...]]:
    """The canonical name and shape of every leaf of a nested params dict.

    Args:
      tree: nested mappings of arrays, or of `jax.ShapeDtypeStruct`s (`jax.eval_shape` of an init).

    Returns:
      {dot-joined name: shape}, names sorted as `to_canonical` orders them.
    """
    return {name: tuple(leaf.shape) for name, leaf in _flatten(tree).items()}


@functools.lru_cache(maxsize=64)
def _expected(nets: nw.Networks) -> dict[str, tuple[int, ...]]:
    return canonical_shapes(jax.eval_shape(lambda: nw.init_params(nets, jax.random.key(0))))


def _networks(nets_or_cfg, algo: str | None) -> nw.Networks:
    if isinstance(nets_or_cfg, nw.Networks):
        if algo is not None and algo != nets_or_cfg.algo:
            raise ParamsError(f"algo={algo!r} given with networks made for algo={nets_or_cfg.algo!r}")
        return nets_or_cfg
    if isinstance(nets_or_cfg, SF2Config):
        if algo is None:
            raise ParamsError("validate(flat, cfg, algo) needs `algo` when given an SF2Config")
        return nw.make_networks(nets_or_cfg, algo)
    raise ParamsError(f"expected Networks or SF2Config, got {type(nets_or_cfg).__name__}")


def expected_shapes(nets_or_cfg, algo: str | None = None) -> dict[str, tuple[int, ...]]:
    """{canonical name: shape} that `init_params` gives for these networks (or this config and algo)."""
    return dict(_expected(_networks(nets_or_cfg, algo)))


def validate(flat: Mapping, nets_or_cfg, algo: str | None = None) -> None:
    """Raise `ParamsError` naming every missing, unexpected and misshaped entry of `flat`.

    Accepts `validate(flat, nets)` or `validate(flat, cfg, algo)`.
    """
    nets = _networks(nets_or_cfg, algo)
    cfg = nets.cfg
    paramfile.check_shapes(flat, _expected(nets), f"the networks (algo {nets.algo!r}, obs_size "
                           f"{cfg.obs_size}, action_size {cfg.action_size}, feature_size {cfg.feature_size})")


def from_canonical(flat: Mapping, nets: nw.Networks, dtype=None) -> dict:
    """Validate `flat` against `nets`, then build the nested `params` dict of JAX arrays.

    `dtype` (e.g. `jnp.float64`) casts every array; None keeps each array's dtype (as JAX canonicalizes it).
    """
    validate(flat, nets)
    return unflatten(flat, _expected(nets), dtype)


def unflatten(flat: Mapping, names=None, dtype=None) -> dict:
    """The nested params dict of a canonical mapping (the inverse of `to_canonical`), unchecked.

    `from_canonical` is `validate` and then this; the baselines' `from_canonical` is the same with their
    own expected names.

    Args:
      flat: {canonical name: array}.
      names: the names to take (default: every name of `flat`).
      dtype: cast every array to it; None keeps each array's dtype (as JAX canonicalizes it).

    Returns:
      {group: {...: jax array}}, nested along the names' dots.
    """
    params: dict = {}
    for name in (flat if names is None else names):
        *path, leaf = name.split(".")
        node = params
        for key in path:
            node = node.setdefault(key, {})
        value = np.asarray(flat[name])
        node[leaf] = jnp.asarray(value, dtype=dtype) if dtype is not None else jnp.asarray(value)
    return params


# ------------------------------------------------------------------------------------------------ files
def save(path, flat: Mapping) -> Path:
    """Write a canonical mapping to `path` (.npz or .safetensors by suffix), atomically. Returns the path
    (`sf2_common.paramfile`: the same files for both cores)."""
    return paramfile.save_arrays(path, {str(name): np.asarray(value) for name, value in flat.items()})


def load(path) -> dict[str, np.ndarray]:
    """Read a canonical mapping written by `save` (either core). `ParamsError` if missing or corrupt."""
    return paramfile.load_arrays(path)
