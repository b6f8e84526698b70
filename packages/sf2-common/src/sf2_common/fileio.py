"""Atomic writes (a synced temporary file renamed over the final name: a kill leaves no half-written file)
and gzip-compressed files (a study folder's finished runs, `compress`) that `stored`/`read_text` read."""

from __future__ import annotations

import gzip
import os
import tempfile
import zlib
from pathlib import Path

__all__ = ["GZ", "atomic_write", "compress", "expand", "read_text", "stored"]

GZ = ".gz"


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


def _gz(path: Path) -> Path:
    return path.with_name(path.name + GZ)


def stored(path) -> Path | None:
    """The file that holds `path`'s content: `path` itself, else `path.gz`; None if neither exists."""
    path = Path(path)
    if path.is_file():
        return path
    return _gz(path) if _gz(path).is_file() else None


def read_text(path) -> str:
    """The text of `path` or `path.gz` (`stored`); `FileNotFoundError` if neither exists, `OSError` naming
    the file if its gzip data is damaged."""
    found = stored(path)
    if found is None:
        raise FileNotFoundError(f"{path} does not exist (nor {_gz(Path(path)).name})")
    if found.name.endswith(GZ):
        try:
            return gzip.decompress(found.read_bytes()).decode("utf-8")
        except (EOFError, zlib.error, gzip.BadGzipFile) as err:
            raise OSError(f"{found} is damaged gzip data ({err or type(err).__name__})") from None
    return found.read_text(encoding="utf-8")


def compress(path) -> bool:
    """Replace `path` by `path.gz` (level 9, no timestamp: reproducible bytes; atomic, then `path`
    removed); False if `path` does not exist."""
    path = Path(path)
    if not path.is_file():
        return False
    atomic_write(_gz(path), gzip.compress(path.read_bytes(), compresslevel=9, mtime=0))
    path.unlink()
    return True


def expand(path) -> bool:
    """The inverse of `compress` (before a writer appends); False if there was nothing to expand."""
    path = Path(path)
    if path.is_file() or not _gz(path).is_file():
        return False
    atomic_write(path, read_text(path))
    _gz(path).unlink()
    return True
