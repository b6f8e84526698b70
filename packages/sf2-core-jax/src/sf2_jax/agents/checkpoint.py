"""Orbax checkpoints of the complete training state (all seeds): parameters, optimizer states, env
states, replay buffers, keys and counters, so a resumed run continues bit for bit.

The state is stored as a flat dict of its leaves ("00000", ...) and rebuilt on restore with the tree
structure of a freshly initialised state of the same program (zero-size leaves, which Orbax refuses, come
from that template); a JSON `meta` item holds the epoch, env steps and leaf count. Orbax writes into a
temporary folder and renames it when complete, so a kill mid-save leaves the previous checkpoint intact.
`save(wait=False)` returns once the arrays are on the host and Orbax writes in the background; every
other method waits for it first (docs/decisions/background-checkpoints.md). The file manifest
(`sf2_common.agents.checkpoints`) is written last and checked first by `restore`: a damaged file is one
`CheckpointDamaged` naming it, intact files that do not fit the program a `CheckpointMismatch`.
`write_seconds`: how long the last checkpoint took from `save` until complete (a background save's is
watched; before one, the restore's time stands in).
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np
from sf2_common.agents import checkpoints
from sf2_common.agents.checkpoints import CheckpointDamaged, CheckpointMismatch

__all__ = ["Checkpointer", "CheckpointMismatch", "CheckpointDamaged"]


def _size(x) -> int:
    return math.prod(np.shape(x))


def _first_line(err: BaseException, limit: int = 300) -> str:
    text = (str(err).strip().splitlines() or [type(err).__name__])[0]
    return text if len(text) <= limit else text[:limit] + " ..."


class Checkpointer:
    def __init__(self, directory, keep: int = 2):
        import orbax.checkpoint as ocp

        self._ocp = ocp
        self.directory = Path(directory).absolute()
        self.manager = ocp.CheckpointManager(
            self.directory, options=ocp.CheckpointManagerOptions(
                max_to_keep=keep, create=True, cleanup_tmp_directories=True))
        self._writing: int | None = None   # the epoch whose files Orbax is still writing
        self._watcher: threading.Thread | None = None
        self.write_seconds: float | None = None     # module docstring

    def path(self, epoch: int) -> Path:
        """The folder of checkpoint `epoch`."""
        return self.directory / str(int(epoch))

    def latest(self) -> int | None:
        self.finish()
        self.manager.reload()
        return self.manager.latest_step()

    def all(self) -> list[int]:
        """The epochs of the checkpoints on disk now."""
        self.finish()
        self.manager.reload()
        return sorted(self.manager.all_steps())

    def save(self, epoch: int, state: Any, meta: dict, wait: bool = True) -> None:
        """Write `state` as checkpoint `epoch`. With `wait` return when it is complete on disk, manifest
        included; without, once its arrays are on the host: the files are written in the background and
        `finish` (which the next call of any method makes) completes it."""
        ocp = self._ocp
        self.finish()
        leaves = jax.tree_util.tree_leaves(state)
        flat = {f"{i:05d}": x for i, x in enumerate(leaves) if _size(x)}
        meta = {**meta, "epoch": int(epoch), "num_leaves": len(leaves)}
        called = time.monotonic()
        self.manager.save(int(epoch), args=ocp.args.Composite(
            state=ocp.args.StandardSave(flat), meta=ocp.args.JsonSave(meta)), force=True)
        self._writing = int(epoch)
        if wait:
            self.finish()
            self.write_seconds = time.monotonic() - called
        elif hasattr(self.manager, "is_saving_in_progress"):
            self._watcher = threading.Thread(target=self._watch, args=(called,), daemon=True,
                                             name=f"checkpoint-{int(epoch)}-watch")
            self._watcher.start()

    def _watch(self, called: float) -> None:
        """Record when a background save is complete (polled: Orbax offers no callback)."""
        while self.manager.is_saving_in_progress():
            time.sleep(0.05)
        self.write_seconds = time.monotonic() - called

    def finish(self) -> None:
        """Wait for a background save (`save(wait=False)`) to be complete on disk and write its manifest."""
        if self._writing is not None:
            self.manager.wait_until_finished()
            if self._watcher is not None:
                self._watcher.join()
                self._watcher = None
            checkpoints.write_manifest(self.path(self._writing))
            self._writing = None

    def restore(self, epoch: int, template: Any) -> tuple[Any, dict]:
        """The state saved as `epoch`, with the structure, dtypes and shapes of `template` (arrays or
        `jax.ShapeDtypeStruct`s, e.g. from `jax.eval_shape`). Raises `CheckpointDamaged` if its files are
        not what was written, `CheckpointMismatch` if they do not fit `template`."""
        ocp = self._ocp
        self.finish()
        started = time.monotonic()
        folder = self.path(epoch)
        intact = checkpoints.verify(folder, epoch)
        leaves, treedef = jax.tree_util.tree_flatten(template)
        try:
            args = ocp.args.Composite(meta=ocp.args.JsonRestore())
            meta = self.manager.restore(int(epoch), args=args)["meta"]
        except Exception as err:  # Orbax raises many types (FileNotFoundError, JSONDecodeError, ...)
            reason = f"its metadata cannot be read: {_first_line(err)}"
            raise CheckpointDamaged(epoch, folder, reason) from None
        if not isinstance(meta, dict) or meta.get("num_leaves") != len(leaves):
            raise CheckpointMismatch(
                f"checkpoint {epoch} in {self.directory} has {_get(meta, 'num_leaves')} arrays, this program "
                f"has {len(leaves)}: it was written by a different config, seed count or version")
        # NumPy targets: Orbax reads into host memory and each array then makes one trip to the device
        # (jnp.asarray below, uncommitted); device targets would read to the host, copy to the device, and
        # the uncommitted copy below would go device -> host -> device again (np.empty allocates lazily)
        flat = {f"{i:05d}": np.empty(x.shape, x.dtype) for i, x in enumerate(leaves) if _size(x)}
        try:
            restored = self.manager.restore(int(epoch), args=ocp.args.Composite(
                state=ocp.args.StandardRestore(flat)))["state"]
        except Exception as err:  # tensorstore's errors reach here as Exception or ValueError
            if intact:
                raise CheckpointMismatch(f"checkpoint {epoch} in {self.directory} does not fit this program: "
                                         f"{_first_line(err)}") from None
            raise CheckpointDamaged(epoch, folder, f"Orbax cannot read it: {_first_line(err)}") from None
        out = []
        for i, x in enumerate(leaves):
            key = f"{i:05d}"
            if key in flat:
                got = restored[key]
                if got.shape != x.shape or got.dtype != x.dtype:
                    raise CheckpointMismatch(f"checkpoint {epoch}: array {key} is {got.shape} {got.dtype}, "
                                             f"expected {x.shape} {x.dtype}")
                out.append(jax.numpy.asarray(got))
            else:  # zero-size leaf: not stored
                out.append(jax.numpy.zeros(x.shape, x.dtype))
        if self.write_seconds is None:
            self.write_seconds = time.monotonic() - started
        # Uncommitted arrays, like a jitted function's outputs: committed ones would make every jitted
        # function compile again for the resumed state.
        return jax.tree_util.tree_unflatten(treedef, out), meta

    def close(self) -> None:
        try:
            self.finish()
        finally:
            self.manager.close()


def _get(meta, key):
    return meta.get(key) if isinstance(meta, dict) else None
