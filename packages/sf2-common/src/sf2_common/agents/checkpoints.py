"""What both cores' checkpointers share: `CheckpointDamaged` (its files are not what was written: resume
sets it aside), `CheckpointMismatch` (intact but not this program's: bad input), and the manifest
(`sf2-manifest.json`, written last: each file's size and CRC-32) that `verify` checks before a framework
reads anything."""

from __future__ import annotations

import json
import zlib
from pathlib import Path

from ..fileio import atomic_write
from .runfolder import RunFolderError

__all__ = ["CheckpointDamaged", "CheckpointMismatch", "MANIFEST", "write_manifest", "verify"]

MANIFEST = "sf2-manifest.json"
_CHUNK = 1 << 22


class CheckpointMismatch(RunFolderError):
    """The checkpoint does not fit the program (a different config, seed count or code version)."""


class CheckpointDamaged(RunFolderError):
    """Checkpoint `epoch` at `path` cannot be restored: `reason` (a file truncated, garbled or missing)."""

    def __init__(self, epoch: int, path, reason: str):
        self.epoch, self.path, self.reason = int(epoch), Path(path), reason
        super().__init__(f"checkpoint {epoch} ({path}) is damaged: {reason}")


def _crc32(path: Path) -> int:
    crc = 0
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            crc = zlib.crc32(chunk, crc)
    return crc


def write_manifest(folder) -> None:
    """List every file under `folder` (size, CRC-32) in `folder/sf2-manifest.json`: a save's last step."""
    folder = Path(folder)
    files = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file() and p.name != MANIFEST:
            files[p.relative_to(folder).as_posix()] = {"size": p.stat().st_size, "crc32": _crc32(p)}
    atomic_write(folder / MANIFEST, json.dumps({"version": 1, "files": files}, indent=1, sort_keys=True))


def verify(folder, epoch: int) -> bool:
    """Check checkpoint `epoch` in `folder` against its manifest: True if intact, False without a manifest
    (the framework's reader decides), `CheckpointDamaged` naming the first missing or garbled file."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CheckpointDamaged(epoch, folder, "its folder is missing")
    path = folder / MANIFEST
    if not path.exists():
        return False
    try:
        files = json.loads(path.read_text())["files"]
        items = [(name, int(v["size"]), int(v["crc32"])) for name, v in files.items()]
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, AttributeError) as err:
        raise CheckpointDamaged(epoch, folder, f"its file list {MANIFEST} is unreadable ({err})") from None
    for name, size, crc in items:
        p = folder / name
        if not p.is_file():
            raise CheckpointDamaged(epoch, folder, f"{name} is missing")
        actual = p.stat().st_size
        if actual != size:
            short = " (truncated)" if actual < size else ""
            raise CheckpointDamaged(epoch, folder, f"{name} has {actual} bytes, {size} were written{short}")
        try:
            ok = _crc32(p) == crc
        except OSError as err:
            raise CheckpointDamaged(epoch, folder, f"{name} cannot be read ({err.strerror})") from None
        if not ok:
            raise CheckpointDamaged(epoch, folder, f"{name} does not hold the bytes that were written "
                                    f"(CRC-32 differs: garbled)")
    return True
