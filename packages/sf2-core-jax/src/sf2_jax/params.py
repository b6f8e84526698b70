"""Canonical parameters: the framework-neutral interchange format of SF² (docs/params.md), JAX side.

A canonical mapping is a flat ``dict[str, numpy.ndarray]``: dot-joined names (``psi.dense_0.kernel``,
``q.head_1.dense_0.bias``, ``obs_norm.mean``, ``log_alpha``), kernels stored (in, out), LayerNorm
``scale``/``bias``, conv kernels (height, width, in, out) (HWIO); the groups are `networks.init_params`'s
(`networks_image.init_image_params`' for the MinAtar system's `ImageNetworks`). Loading one mapping into
`sf2_jax` and `sf2_torch` (`sf2_torch.params`, the same functions) gives networks that compute the same
numbers.
`to_canonical` / `from_canonical` convert, `validate` and `expected_shapes` check against networks, `save`
and `load` read and write ``.npz`` or ``.safetensors`` files (`sf2_common.paramfile`, shared by both cores).
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
from sf2_jax import networks_image as nwi

__all__ = ["to_canonical", "from_canonical", "validate", "expected_shapes", "save", "load", "FORMATS",
           "canonical_shapes", "unflatten", "check_shapes"]

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
    """The canonical mapping of a params dict.

    Args:
      params: nested params of canonical groups (`networks.init_params`, an agent's parameters).

    Returns:
      {dot-joined name: numpy array}, copies, names sorted.
    """
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
def _expected(nets) -> dict[str, tuple[int, ...]]:
    init = nwi.init_image_params if isinstance(nets, nwi.ImageNetworks) else nw.init_params
    return canonical_shapes(jax.eval_shape(lambda: init(nets, jax.random.key(0))))


def _networks(nets_or_cfg, algo: str | None):
    if isinstance(nets_or_cfg, nwi.ImageNetworks):
        if algo is not None:
            raise ParamsError(f"algo={algo!r} given with image networks (method {nets_or_cfg.method!r})")
        return nets_or_cfg
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
    """The canonical names and shapes of networks' parameters.

    Args:
      nets_or_cfg: the `networks.Networks` or `networks_image.ImageNetworks`, or an `SF2Config` with `algo`.
      algo: "td3" or "sac", with a config (with networks: None or theirs; None with image networks).

    Returns:
      {canonical name: shape}, as `networks.init_params` gives them.

    Raises:
      ParamsError: a config without `algo`, an `algo` other than the networks', or neither networks nor
        a config.
    """
    return dict(_expected(_networks(nets_or_cfg, algo)))


def validate(flat: Mapping, nets_or_cfg, algo: str | None = None) -> None:
    """Check a canonical mapping against networks' names and shapes.

    Args:
      flat: {canonical name: array}.
      nets_or_cfg, algo: as `expected_shapes`'.

    Raises:
      ParamsError: naming every missing, unexpected and misshaped entry (expected and found shapes).
    """
    nets = _networks(nets_or_cfg, algo)
    cfg = nets.cfg
    kind = (f"method {nets.method!r}, obs_shape {nets.obs_shape}" if isinstance(nets, nwi.ImageNetworks)
            else f"algo {nets.algo!r}, obs_size {cfg.obs_size}")
    check_shapes(flat, _expected(nets), f"the networks ({kind}, action_size {cfg.action_size}, "
                 f"feature_size {cfg.feature_size})")


def check_shapes(flat: Mapping, expected: Mapping[str, tuple[int, ...]], what: str) -> None:
    """Check a canonical mapping against expected names and shapes (the baselines' `validate` uses it too).

    Args:
      flat: {canonical name: array}.
      expected: {canonical name: shape}.
      what: what `flat` should match, the head of the message ("the networks (algo 'td3', ...)").

    Raises:
      ParamsError: naming every missing, unexpected and misshaped entry (expected and found shapes).
    """
    if not isinstance(flat, Mapping):
        raise ParamsError(f"canonical parameters must be a mapping name → array, got {type(flat).__name__}")
    missing = [name for name in expected if name not in flat]
    unexpected = sorted(name for name in flat if name not in expected)
    misshaped = [(name, shape, tuple(np.shape(flat[name]))) for name, shape in expected.items()
                 if name in flat and tuple(np.shape(flat[name])) != tuple(shape)]
    if not (missing or unexpected or misshaped):
        return
    lines = [f"canonical parameters do not match {what}:"]
    if missing:
        lines.append(f"  missing ({len(missing)}):")
        lines += [f"    {name} (expected shape {expected[name]})" for name in missing]
    if unexpected:
        lines.append(f"  unexpected ({len(unexpected)}):")
        lines += [f"    {name} (shape {tuple(np.shape(flat[name]))})" for name in unexpected]
    if misshaped:
        lines.append(f"  misshaped ({len(misshaped)}):")
        lines += [f"    {name}: expected shape {shape}, found {found}" for name, shape, found in misshaped]
    raise ParamsError("\n".join(lines))


def from_canonical(flat: Mapping, nets, dtype=None) -> dict:
    """The params dict of a canonical mapping, validated against the networks first.

    Args:
      flat: {canonical name: array}.
      nets: the `networks.Networks` (or `networks_image.ImageNetworks`) the parameters are for.
      dtype: cast every array to it (e.g. `jnp.float64`); None keeps each array's dtype (as JAX
        canonicalizes it).

    Returns:
      The nested params dict of JAX arrays, as `networks.init_params` returns it.

    Raises:
      ParamsError: as `validate`.
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
    """Write a canonical mapping to a file, atomically; either core reads it back.

    Args:
      path: a ``.npz`` (numpy only) or ``.safetensors`` (the `safetensors` package) path.
      flat: {canonical name: array}; arrays keep their dtype.

    Returns:
      The path written.

    Raises:
      ParamsError: another suffix, a non-numeric array, or ``.safetensors`` without the package.
    """
    return paramfile.save_arrays(path, {str(name): np.asarray(value) for name, value in flat.items()})


def load(path) -> dict[str, np.ndarray]:
    """Read a canonical mapping written by `save` (either core).

    Args:
      path: a ``.npz`` or ``.safetensors`` file.

    Returns:
      {canonical name: numpy array}.

    Raises:
      ParamsError: the file is missing, unreadable or corrupt.
    """
    return paramfile.load_arrays(path)
