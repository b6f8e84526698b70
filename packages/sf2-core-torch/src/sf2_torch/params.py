"""Canonical parameters: the framework-neutral interchange format of SF² (docs/params.md), torch side.

A canonical mapping is a flat ``dict[str, numpy.ndarray]``: dot-joined names (``psi.dense_0.kernel``,
``q.head_1.dense_0.bias``, ``obs_norm.mean``, ``log_alpha``), kernels stored (in, out) as flax does
(`nn.Linear.weight` is transposed on the way in and out), conv kernels (height, width, in, out) (HWIO,
`nn.Conv2d.weight` permuted), LayerNorm ``scale``/``bias``. The modules use the canonical layer names, so
one converter serves the core's `Networks` and `ImageNetworks`, the baselines' networks and an agent's
groups. Loading one mapping into `sf2_torch` and the JAX core (its `params`, the same functions)
gives networks that compute the same numbers. `save` and `load` read and write ``.npz`` or
``.safetensors`` files (`sf2_common.paramfile`, shared by both cores).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np
import torch
from sf2_common import paramfile
from sf2_common.config import SF2Config
from sf2_common.errors import ParamsError
from torch import nn

__all__ = ["to_canonical", "from_canonical", "validate", "expected_shapes", "save", "load", "FORMATS"]

FORMATS = paramfile.FORMATS


class _Groups(nn.Module):
    """{group: module or parameter} as one module tree (shared, not copied)."""

    def __init__(self, groups: Mapping[str, nn.Module | torch.Tensor]):
        super().__init__()
        for name, value in groups.items():
            if isinstance(value, nn.Module):
                self.add_module(name, value)
            elif isinstance(value, nn.Parameter):
                self.register_parameter(name, value)
            else:
                raise TypeError(f"group {name!r} must be an nn.Module or an nn.Parameter, found "
                                f"{type(value).__name__}")


def _module(nets) -> nn.Module:
    return _Groups(nets) if isinstance(nets, Mapping) else nets


# The canonical axes of a torch tensor, by layout: a Linear weight (out, in) is stored (in, out), a Conv2d
# weight (out, in, kh, kw) is stored HWIO (kh, kw, in, out); torch's tensor is canonical.permute(_TO_TORCH).
_TO_CANONICAL = {"linear": (1, 0), "conv": (2, 3, 1, 0)}
_TO_TORCH = {"linear": (1, 0), "conv": (3, 2, 0, 1)}


def _slots(nets, buffers: bool = True) -> Iterator[tuple[str, torch.Tensor, str | None]]:
    """(canonical name, tensor, layout: "linear", "conv" or None (stored as is)) for every parameter (and
    buffer) of `nets`.

    Order: module registration order, the root's own entries (`log_alpha`) last.
    """
    modules = list(_module(nets).named_modules())
    for mod_name, module in modules[1:] + modules[:1]:
        prefix = f"{mod_name}." if mod_name else ""
        for leaf, p in module.named_parameters(recurse=False):
            if isinstance(module, nn.Linear) and leaf == "weight":
                yield f"{prefix}kernel", p, "linear"
            elif isinstance(module, nn.Conv2d) and leaf == "weight":
                yield f"{prefix}kernel", p, "conv"
            elif isinstance(module, nn.LayerNorm) and leaf == "weight":
                yield f"{prefix}scale", p, None
            else:
                yield f"{prefix}{leaf}", p, None
        if buffers:
            for leaf, b in module.named_buffers(recurse=False):
                yield f"{prefix}{leaf}", b, None


def _canonical_shape(tensor: torch.Tensor, layout: str | None) -> tuple[int, ...]:
    shape = tuple(tensor.shape)
    return shape if layout is None else tuple(shape[i] for i in _TO_CANONICAL[layout])


def _to_numpy(tensor: torch.Tensor, layout: str | None) -> np.ndarray:
    arr = tensor.detach().cpu().numpy()
    # a copy even where the transpose is already contiguous
    return arr.copy() if layout is None else arr.transpose(_TO_CANONICAL[layout]).copy()


def to_canonical(nets, grads: bool = False) -> dict[str, np.ndarray]:
    """The canonical mapping of networks' parameters (or of their gradients).

    Args:
      nets: the core's `Networks`, a baseline's networks, or a mapping {group: module or parameter} (an
        agent's groups, e.g. {"obs_norm": ..., "q": ..., "log_alpha": ...}).
      grads: the `.grad` of every parameter instead (zeros where None; the normalizer's buffers, not
        parameters, left out).

    Returns:
      {dot-joined name: numpy array}, copies (never views of the modules' memory), kernels (in, out), conv
      kernels HWIO.
    """
    out: dict[str, np.ndarray] = {}
    for name, tensor, layout in _slots(nets, buffers=not grads):
        if grads:
            g = tensor.grad
            out[name] = _to_numpy(torch.zeros_like(tensor) if g is None else g, layout)
        else:
            out[name] = _to_numpy(tensor, layout)
    return out


def _networks_for(nets_or_cfg, algo: str | None) -> nn.Module:
    if isinstance(nets_or_cfg, SF2Config):
        from .networks import make_networks

        return make_networks(nets_or_cfg, algo if algo is not None else "td3", device="meta")
    if isinstance(nets_or_cfg, (nn.Module, Mapping)):
        return _module(nets_or_cfg)
    raise TypeError(f"expected Networks, a mapping of groups or an SF2Config, found "
                    f"{type(nets_or_cfg).__name__}")


def expected_shapes(nets_or_cfg, algo: str | None = None) -> dict[str, tuple[int, ...]]:
    """The canonical names and shapes of networks' parameters.

    Args:
      nets_or_cfg: networks (as `to_canonical` takes them), or an `SF2Config` with `algo`.
      algo: "td3" or "sac", with a config (default "td3"; built on the 'meta' device, no memory).

    Returns:
      {canonical name: shape}, kernels (in, out).

    Raises:
      TypeError: neither networks, a mapping of groups nor a config.
    """
    nets = _networks_for(nets_or_cfg, algo)
    return {name: _canonical_shape(t, layout) for name, t, layout in _slots(nets)}


def _describe(nets: nn.Module) -> str:
    cfg, algo = getattr(nets, "cfg", None), getattr(nets, "algo", None)
    if cfg is None:
        return type(nets).__name__
    kind = (f"method={nets.method!r}, obs_shape={nets.obs_shape}" if hasattr(nets, "method")
            else f"algo={algo!r}, obs_size={cfg.obs_size}")
    return f"{kind}, action_size={cfg.action_size}, feature_size={cfg.feature_size}"


def validate(flat: Mapping[str, object], nets_or_cfg, algo: str | None = None) -> None:
    """Check a canonical mapping against networks' names and shapes.

    Args:
      flat: {canonical name: array}.
      nets_or_cfg, algo: as `expected_shapes`'.

    Raises:
      ParamsError: naming every missing, unexpected, misshaped and non-numeric entry (expected and found
        shapes).
    """
    if not isinstance(flat, Mapping):
        raise ParamsError(
            f"canonical parameters must be a mapping name -> array, found {type(flat).__name__}"
        )
    nets = _networks_for(nets_or_cfg, algo)
    expected = expected_shapes(nets)
    missing, unexpected, misshaped, invalid = [], [], [], []
    for name, shape in expected.items():
        if name not in flat:
            missing.append(f"  missing    {name}: expected shape {shape}")
            continue
        try:
            arr = np.asarray(flat[name])
        except Exception as exc:  # noqa: BLE001 - any conversion failure is reported, not raised
            invalid.append(f"  invalid    {name}: not convertible to an array ({exc})")
            continue
        if arr.dtype.kind not in "fiub":
            invalid.append(f"  invalid    {name}: expected a real numeric array, found dtype {arr.dtype}")
        elif tuple(arr.shape) != shape:
            misshaped.append(f"  misshaped  {name}: expected shape {shape}, found {tuple(arr.shape)}")
    for name in flat:
        if name not in expected:
            unexpected.append(f"  unexpected {name}: found shape {tuple(np.shape(flat[name]))}")
    problems = missing + unexpected + misshaped + invalid
    if problems:
        counts = f"{len(missing)} missing, {len(unexpected)} unexpected, {len(misshaped)} misshaped" + (
            f", {len(invalid)} invalid" if invalid else ""
        )
        raise ParamsError(
            f"canonical parameters do not match the networks ({_describe(nets)}): {counts}\n"
            + "\n".join(problems)
        )


def from_canonical(flat: Mapping[str, object], nets):
    """Load a canonical mapping into networks, in place, validated against them first.

    Args:
      flat: {canonical name: array}.
      nets: networks as `to_canonical` takes them; they keep their dtype and device.

    Returns:
      `nets`.

    Raises:
      ParamsError: as `validate`.
    """
    validate(flat, nets)
    with torch.no_grad():
        for name, tensor, layout in _slots(nets):
            src = torch.tensor(np.asarray(flat[name]))
            tensor.copy_(src if layout is None else src.permute(_TO_TORCH[layout]))
    return nets


def _arrays(flat: Mapping[str, object]) -> dict[str, np.ndarray]:
    return {str(name): (value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else value)
            for name, value in flat.items()}


def save(path: str | os.PathLike, flat: Mapping[str, object]) -> Path:
    """Write a canonical mapping to a file, atomically; either core reads it back.

    Args:
      path: a ``.npz`` (numpy only) or ``.safetensors`` (the `safetensors` package) path.
      flat: {canonical name: array or tensor}; arrays keep their dtype.

    Returns:
      The path written.

    Raises:
      ParamsError: another suffix, a non-numeric array, or ``.safetensors`` without the package.
    """
    return paramfile.save_arrays(path, _arrays(flat))


def load(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a canonical mapping written by `save` (either core).

    Args:
      path: a ``.npz`` or ``.safetensors`` file.

    Returns:
      {canonical name: numpy array}.

    Raises:
      ParamsError: the file is missing, unreadable or corrupt.
    """
    return paramfile.load_arrays(path)
