"""Canonical parameter interchange: one flat mapping name → numpy array, shared with the JAX core.

The scheme (docs/core-contract.md "Canonical parameters")
--------------------------------------------------------
Names are dot-joined paths, grouped by network:

=====================================  ==========================================================
`obs_norm.count`                       () running count of observations (float)
`obs_norm.mean`, `.summed_var`, `.std`  (D,) Brax running statistics
`psi.*`, `zeta.*`, `policy.*`          online MLPs (`policy` is the TD3 or SAC head)
`q.head_0.*`, `q.head_1.*`             the twin Q heads (no LayerNorm)
`target_psi.*`, `target_zeta.*`,       target copies, same layout as their online networks
`target_q.*`, `target_policy.*`        (`target_policy` only for TD3)
`log_alpha`                            () SAC temperature (SAC only)
=====================================  ==========================================================

Inside a network, layer i is `dense_{i}.kernel` (in, out), `dense_{i}.bias` (out,) and, after each hidden
layer when LayerNorm is on, `layer_norm_{i}.scale` and `layer_norm_{i}.bias` (width,). Kernels are always
stored (in, out), as flax does: torch's `nn.Linear.weight` is (out, in) and is transposed on the way in
and out; LayerNorm's `weight` is called `scale`. Examples with D = 5, A = 1, F = 16, hidden (32, 32):
`psi.dense_0.kernel` (6, 32), `psi.dense_2.kernel` (32, 16), `zeta.dense_2.kernel` (32, 80) whose output
index d·F + f is entry (d, f) of ζ's (D, F) matrix, `q.head_0.dense_1.kernel` (32, 1).

Functions
---------
Every function takes `nets` as one module (the core's `Networks`, a baseline's networks) or as a mapping
{group: module or parameter} (an agent's groups, e.g. {"obs_norm": ..., "q": ..., "log_alpha": ...}):
a group's entries are named `<group>.<path>`, a parameter group (`log_alpha`) is named by its group. The
modules use the canonical layer names, so this one converter serves every representation.

- `to_canonical(nets, grads=False)`: the flat dict (numpy copies, never views of the module's memory).
  With `grads=True`, the `.grad` of every parameter in the same layout (zeros where `.grad` is None;
  the normalizer's buffers, which are not parameters, are left out).
- `from_canonical(flat, nets)`: `validate` first, then copy every entry into `nets` in place, cast to
  the dtype and device `nets` already has. Returns `nets`.
- `validate(flat, nets)` or `validate(flat, cfg, algo)`: raise `ParamsError` listing every missing,
  unexpected and misshaped entry (expected and found shapes, canonical layout).
- `expected_shapes(nets)` / `expected_shapes(cfg, algo)`: name → canonical shape.
- `save(path, flat)`: `.npz` (numpy only) or `.safetensors` (needs the `safetensors` package), chosen by
  the suffix (any other suffix is a `ParamsError`); written atomically (temporary file, then rename),
  arrays keep their dtype. `load(path)`: the flat dict back; a missing, unreadable or corrupt file
  raises `ParamsError`. Files are interchangeable with the JAX core's `params` (docs/params.md).
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

__all__ = ["to_canonical", "from_canonical", "validate", "expected_shapes", "save", "load"]

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


def _slots(nets, buffers: bool = True) -> Iterator[tuple[str, torch.Tensor, bool]]:
    """(canonical name, tensor, stored transposed) for every parameter (and buffer) of `nets`.

    Order: module registration order, the root's own entries (`log_alpha`) last.
    """
    modules = list(_module(nets).named_modules())
    for mod_name, module in modules[1:] + modules[:1]:
        prefix = f"{mod_name}." if mod_name else ""
        for leaf, p in module.named_parameters(recurse=False):
            if isinstance(module, nn.Linear) and leaf == "weight":
                yield f"{prefix}kernel", p, True
            elif isinstance(module, nn.LayerNorm) and leaf == "weight":
                yield f"{prefix}scale", p, False
            else:
                yield f"{prefix}{leaf}", p, False
        if buffers:
            for leaf, b in module.named_buffers(recurse=False):
                yield f"{prefix}{leaf}", b, False


def _canonical_shape(tensor: torch.Tensor, transposed: bool) -> tuple[int, ...]:
    shape = tuple(tensor.shape)
    return shape[::-1] if transposed else shape


def _to_numpy(tensor: torch.Tensor, transposed: bool) -> np.ndarray:
    arr = tensor.detach().cpu().numpy()
    return arr.T.copy() if transposed else arr.copy()  # a copy even where .T is already contiguous


def to_canonical(nets, grads: bool = False) -> dict[str, np.ndarray]:
    """The canonical flat dict of `nets` (or, with `grads=True`, of its parameters' `.grad`)."""
    out: dict[str, np.ndarray] = {}
    for name, tensor, transposed in _slots(nets, buffers=not grads):
        if grads:
            g = tensor.grad
            out[name] = _to_numpy(torch.zeros_like(tensor) if g is None else g, transposed)
        else:
            out[name] = _to_numpy(tensor, transposed)
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
    """Canonical name → shape for networks `nets`, or for `make_networks(cfg, algo)` (built on 'meta')."""
    nets = _networks_for(nets_or_cfg, algo)
    return {name: _canonical_shape(t, tr) for name, t, tr in _slots(nets)}


def _describe(nets: nn.Module) -> str:
    cfg, algo = getattr(nets, "cfg", None), getattr(nets, "algo", None)
    if cfg is None:
        return type(nets).__name__
    return (
        f"algo={algo!r}, obs_size={cfg.obs_size}, action_size={cfg.action_size}, "
        f"feature_size={cfg.feature_size}"
    )


def validate(flat: Mapping[str, object], nets_or_cfg, algo: str | None = None) -> None:
    """Raise `ParamsError` naming every missing, unexpected and misshaped entry of `flat`.

    `nets_or_cfg` is the networks the parameters are meant for, or an `SF2Config` with `algo`.
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
    """Copy canonical `flat` into `nets` in place (validated first; nets keep their dtype and device)."""
    validate(flat, nets)
    with torch.no_grad():
        for name, tensor, transposed in _slots(nets):
            src = torch.tensor(np.asarray(flat[name]))
            tensor.copy_(src.T if transposed else src)
    return nets


def _arrays(flat: Mapping[str, object]) -> dict[str, np.ndarray]:
    return {str(name): (value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else value)
            for name, value in flat.items()}


def save(path: str | os.PathLike, flat: Mapping[str, object]) -> Path:
    """Write `flat` to `path` (.npz or .safetensors, by suffix) atomically; returns the path
    (`sf2_common.paramfile`: the same files for both cores)."""
    return paramfile.save_arrays(path, _arrays(flat))


def load(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a canonical parameter file written by `save` (either core); `ParamsError` if it cannot."""
    return paramfile.load_arrays(path)
