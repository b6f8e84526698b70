"""Atomic file writes for everything a run or study folder holds (config.json, metrics.jsonl, study.json,
study.toml, checkpoint manifests, evaluation results, files that come back from another host): the data
goes to a temporary file in the same folder, is synced, then renamed over the final name, so a crash or a
`kill -9` never leaves a half-written file under that name (docs/run-folders.md)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["atomic_write"]


def atomic_write(path, data: str | bytes) -> Path:
    """Write `data` (text as UTF-8, or bytes) to `path` atomically, creating its folder; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(raw)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
