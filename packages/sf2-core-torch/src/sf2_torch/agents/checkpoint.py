"""Checkpoints of the complete training state (all seeds): networks, targets, Adam states, replay
buffers, generators, env states and counters, so a resumed run continues bit for bit.

Layout, in the run's `checkpoints/` folder as the JAX core's: `<epoch>/state.pt` (`torch.save` of the
torch state, loaded with `weights_only=True`), `env.npz` (the JAX env state's arrays, in tree order) and
`meta.json` (epoch, env steps, seeds, array count). Each checkpoint is written into a temporary folder and
renamed when complete, so a kill mid-save leaves the previous one intact; the `keep` newest are kept.
`save(wait=False)` returns once the state is copied to the host and a thread writes the files; every other
method waits for it first (docs/decisions/background-checkpoints.md). The file manifest
(`sf2_common.agents.checkpoints`) is written last and checked first by `restore`: a damaged file is one
`CheckpointDamaged` naming it, intact files that do not load a `CheckpointMismatch`. `write_seconds`: how
long the last checkpoint took from `save` until complete (before one, the restore's time stands in).
"""

from __future__ import annotations

import copy
import json
import os
import pickle
import shutil
import threading
import time
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
        self._writer: threading.Thread | None = None
        self._error: BaseException | None = None
        self._called = 0.0                          # when the last `save` began (time.monotonic)
        self.write_seconds: float | None = None     # module docstring

    def path(self, epoch: int) -> Path:
        """The folder of checkpoint `epoch`."""
        return self.directory / str(int(epoch))

    def all(self) -> list[int]:
        """The epochs of the checkpoint folders on disk now (complete or not: `restore` tells)."""
        self.finish()
        return self._on_disk()

    def _on_disk(self) -> list[int]:
        if not self.directory.exists():
            return []
        return sorted(int(p.name) for p in self.directory.iterdir() if p.is_dir() and p.name.isdigit())

    def latest(self) -> int | None:
        steps = self.all()
        return steps[-1] if steps else None

    def save(self, epoch: int, state: dict[str, Any], env_leaves: list[np.ndarray], meta: dict,
             wait: bool = True) -> None:
        """Write checkpoint `epoch` and drop the oldest ones. With `wait` return when it is complete on
        disk; without, once `state` and `env_leaves` are copied to the host: a thread writes the files and
        `finish` (which the next call of any method makes) waits for it and raises what it raised."""
        self.finish()
        self._called = time.monotonic()
        if wait:
            self._write(epoch, state, env_leaves, meta)
            return
        args = (epoch, _to_host(state), [np.array(x, copy=True) for x in env_leaves], dict(meta))
        self._writer = threading.Thread(target=self._write_in_background, args=args,
                                        name=f"checkpoint-{int(epoch)}")
        self._writer.start()

    def _write_in_background(self, *args) -> None:
        try:
            self._write(*args)
        except BaseException as err:  # raised in the caller's thread by `finish`
            self._error = err

    def finish(self) -> None:
        """Wait for a background save (`save(wait=False)`) to be complete on disk; raise its error."""
        if self._writer is not None:
            self._writer.join()
            self._writer = None
        if self._error is not None:
            err, self._error = self._error, None
            raise err

    def _write(self, epoch: int, state: dict[str, Any], env_leaves: list[np.ndarray], meta: dict) -> None:
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
        for old in self._on_disk()[:-self.keep] if self.keep > 0 else []:
            shutil.rmtree(self.directory / str(old), ignore_errors=True)
        self.write_seconds = time.monotonic() - self._called

    def restore(self, epoch: int, map_location=None) -> tuple[dict, list[np.ndarray], dict]:
        """(torch state, env arrays, meta) of checkpoint `epoch`. Raises `CheckpointDamaged` if its files
        are not what was written, `CheckpointMismatch` if intact files do not load."""
        self.finish()
        started = time.monotonic()
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
        if self.write_seconds is None:
            self.write_seconds = time.monotonic() - started
        return state, leaves, meta

    def close(self) -> None:
        self.finish()


def _to_host(tree):
    """A copy of a state dict's tree whose tensors are on the CPU and owned by it (nothing the trainer
    updates in place afterwards is shared). A dict keeps its type and attributes: a `state_dict`'s
    `_metadata` (TensorDict's holds each entry's batch size) is what loads it back."""
    if isinstance(tree, torch.Tensor):
        return tree.detach().to("cpu", copy=True)
    if isinstance(tree, np.ndarray):
        return tree.copy()
    if isinstance(tree, dict):
        out = copy.copy(tree)
        for k, v in tree.items():
            out[k] = _to_host(v)
        return out
    if type(tree) in (list, tuple):
        return type(tree)(_to_host(v) for v in tree)
    return copy.deepcopy(tree)
