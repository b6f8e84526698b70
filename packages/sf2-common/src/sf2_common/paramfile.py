"""Canonical parameter files (docs/params.md): a flat {dot-name: array} mapping as .npz or .safetensors (by
suffix), written atomically by both cores' `params.save`; every reader failure is a `ParamsError`."""

from __future__ import annotations

import io
import zipfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .errors import ParamsError
from .fileio import atomic_write

__all__ = ["FORMATS", "save_arrays", "load_arrays"]

FORMATS = (".npz", ".safetensors")


def _format(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ParamsError(f"parameter file {str(path)!r} has suffix {suffix!r}: must be one of {FORMATS}")
    return suffix


def _safetensors_numpy():
    try:
        import safetensors.numpy as st
    except ImportError as err:
        raise ParamsError("reading or writing .safetensors needs the `safetensors` package (pip install "
                          "safetensors, or a core's [safetensors] extra); or use .npz") from err
    return st


def save_arrays(path, arrays: Mapping[str, np.ndarray]) -> Path:
    """Write `arrays` (name → real numeric numpy array) to `path` atomically; returns the path."""
    path = Path(path)
    fmt = _format(path)
    out = {}
    for name, value in arrays.items():
        arr = np.array(value, order="C")  # (np.ascontiguousarray would turn a 0-d array into (1,))
        if arr.dtype.kind not in "fiub":
            raise ParamsError(f"cannot save {name}: expected a real numeric array, found dtype {arr.dtype}")
        out[str(name)] = arr
    if fmt == ".safetensors":
        raw = _safetensors_numpy().save(out)
    else:
        buf = io.BytesIO()
        np.savez(buf, **out)
        raw = buf.getvalue()
    return atomic_write(path, raw)


def load_arrays(path) -> dict[str, np.ndarray]:
    """Read a parameter file written by `save_arrays`; `ParamsError` if it is missing or unreadable."""
    path = Path(path)
    fmt = _format(path)
    if not path.is_file():
        raise ParamsError(f"no parameter file at {str(path)!r} (not found)")
    try:
        if fmt == ".safetensors":
            return dict(_safetensors_numpy().load_file(str(path)))
        with np.load(path, allow_pickle=False) as data:
            return {name: np.array(data[name]) for name in data.files}
    except ParamsError:
        raise
    except (Exception, zipfile.BadZipFile) as err:  # noqa: BLE001 - every reader failure is a ParamsError
        raise ParamsError(f"cannot read parameter file {str(path)!r} (corrupt or not a {fmt} parameter "
                          f"file): {err}") from err
