"""Checkpoints of the complete training state (all seeds): networks, targets, Adam states, replay
buffers, generators, env states and counters, so that a resumed run continues bit for bit.

Layout (the torch counterpart of the JAX trainer's Orbax checkpoints, in the same `checkpoints/` folder
of a run): `checkpoints/<epoch>/state.pt` (`torch.save` of the torch state, loaded with
`weights_only=True`), `env.npz` (the JAX env state's arrays, in tree order) and `meta.json` (epoch, env
steps, seeds, array count). Each checkpoint is written into a temporary folder and renamed when complete,
so a run killed mid-save leaves the previous checkpoint intact; the `keep` newest are kept.

The file manifest of `sf2_common.agents.checkpoints` is written into the temporary folder last; `restore`
checks it first, so a truncated, garbled or missing file is one `CheckpointDamaged` naming the file (which
the resume rule of `sf2_common.agents.resume` sets aside), and intact files that do not load are
`CheckpointMismatch`.
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from sf2_common.agents import checkpoints
from sf2_common.agents.checkpoints import CheckpointDamaged, CheckpointMismatch

__all__ = ["Checkpointer", "CheckpointMismatch", "CheckpointDamaged"]

_READ_ERRORS = (OSError, KeyError, ValueError, RuntimeError, EOFError, pickle.UnpicklingError,
                zipfile.BadZipFile)


class Checkpointer:
    STATE, ENV, META = "state.pt", "env.npz", "meta.json"

    def __init__(self, directory, keep: int = 2):
        self.directory = Path(directory).absolute()
        self.keep = int(keep)

    def path(self, epoch: int) -> Path:
        """The folder of checkpoint `epoch`."""
        return self.directory / str(int(epoch))

    def all(self) -> list[int]:
        """The epochs of the checkpoint folders on disk now (complete or not: `restore` tells)."""
        if not self.directory.exists():
            return []
        return sorted(int(p.name) for p in self.directory.iterdir() if p.is_dir() and p.name.isdigit())

    def latest(self) -> int | None:
        steps = self.all()
        return steps[-1] if steps else None

    def save(self, epoch: int, state: dict[str, Any], env_leaves: list[np.ndarray], meta: dict) -> None:
        """Write checkpoint `epoch` (complete on disk when this returns) and drop the oldest ones."""
        self.directory.mkdir(parents=True, exist_ok=True)
        final = self.directory / str(int(epoch))
        tmp = self.directory / f".{int(epoch)}.tmp-{os.getpid()}"
        for stale in self.directory.glob(".*.tmp-*"):  # this or a killed process's unfinished saves
            shutil.rmtree(stale, ignore_errors=True)
        tmp.mkdir()
        torch.save(state, tmp / self.STATE)
        with open(tmp / self.ENV, "wb") as f:
            np.savez(f, **{f"{i:05d}": x for i, x in enumerate(env_leaves)})
        meta = {**meta, "epoch": int(epoch), "num_env_arrays": len(env_leaves)}
        (tmp / self.META).write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
        for name in (self.STATE, self.ENV, self.META):
            with open(tmp / name, "rb") as f:
                os.fsync(f.fileno())
        checkpoints.write_manifest(tmp)
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
        for old in self.all()[:-self.keep] if self.keep > 0 else []:
            shutil.rmtree(self.directory / str(old), ignore_errors=True)

    def restore(self, epoch: int, map_location=None) -> tuple[dict, list[np.ndarray], dict]:
        """(torch state, env arrays, meta) of checkpoint `epoch`. Raises `CheckpointDamaged` if its files
        are not what was written, `CheckpointMismatch` if intact files do not load."""
        path = self.path(epoch)
        intact = checkpoints.verify(path, epoch)
        try:
            meta = json.loads((path / self.META).read_text())
            state = torch.load(path / self.STATE, map_location=map_location, weights_only=True)
            with np.load(path / self.ENV) as data:
                leaves = [data[f"{i:05d}"] for i in range(meta["num_env_arrays"])]
        except _READ_ERRORS as err:
            reason = f"{type(err).__name__}: {str(err).strip().splitlines()[0] if str(err).strip() else ''}"
            if intact:
                raise CheckpointMismatch(f"checkpoint {epoch} in {self.directory} cannot be loaded by this "
                                         f"program: {reason}") from err
            raise CheckpointDamaged(epoch, path, f"it cannot be read ({reason})") from None
        return state, leaves, meta

    def close(self) -> None:
        pass
