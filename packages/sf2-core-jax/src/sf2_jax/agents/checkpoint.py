"""Orbax checkpoints of the complete training state (all seeds): parameters, optimizer states, env
states, replay buffers, keys and counters, so a resumed run continues bit for bit.

The state is stored as a flat dict of its leaves ("00000", "00001", ...) and rebuilt on restore with the
tree structure of a freshly initialised state of the same program; zero-size leaves (MJX keeps a few
empty arrays) are not written (Orbax refuses them) and come from that template. Orbax writes each
checkpoint into a temporary folder and renames it when complete, so a run killed mid-save leaves the
previous checkpoint intact. A JSON `meta` item stores the epoch, env steps and the leaf count.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import jax
import numpy as np
from sf2_common.errors import ConfigError

__all__ = ["Checkpointer", "CheckpointMismatch"]


def _size(x) -> int:
    return math.prod(np.shape(x))


class CheckpointMismatch(ConfigError):
    """The checkpoint does not fit the program (a different config, seed count or code version): bad
    input, like a run folder of another run (the CLIs exit with status 2)."""


class Checkpointer:
    def __init__(self, directory, keep: int = 2):
        import orbax.checkpoint as ocp

        self._ocp = ocp
        self.directory = Path(directory).absolute()
        self.manager = ocp.CheckpointManager(
            self.directory, options=ocp.CheckpointManagerOptions(
                max_to_keep=keep, create=True, cleanup_tmp_directories=True))

    def latest(self) -> int | None:
        self.manager.reload()
        return self.manager.latest_step()

    def all(self) -> list[int]:
        self.manager.reload()
        return list(self.manager.all_steps())

    def save(self, epoch: int, state: Any, meta: dict) -> None:
        """Write `state` as checkpoint `epoch` and wait until it is complete on disk."""
        ocp = self._ocp
        leaves = jax.tree_util.tree_leaves(state)
        flat = {f"{i:05d}": x for i, x in enumerate(leaves) if _size(x)}
        meta = {**meta, "epoch": int(epoch), "num_leaves": len(leaves)}
        self.manager.save(int(epoch), args=ocp.args.Composite(
            state=ocp.args.StandardSave(flat), meta=ocp.args.JsonSave(meta)), force=True)
        self.manager.wait_until_finished()

    def restore(self, epoch: int, template: Any) -> tuple[Any, dict]:
        """The state saved as `epoch`, with the structure, dtypes and shapes of `template` (arrays or
        `jax.ShapeDtypeStruct`s, e.g. from `jax.eval_shape`)."""
        ocp = self._ocp
        leaves, treedef = jax.tree_util.tree_flatten(template)
        meta = self.manager.restore(int(epoch), args=ocp.args.Composite(meta=ocp.args.JsonRestore()))["meta"]
        if meta.get("num_leaves") != len(leaves):
            raise CheckpointMismatch(
                f"checkpoint {epoch} in {self.directory} has {meta.get('num_leaves')} arrays, this program "
                f"has {len(leaves)}: it was written by a different config, seed count or version")
        device = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
        flat = {f"{i:05d}": jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=device)
                for i, x in enumerate(leaves) if _size(x)}
        try:
            restored = self.manager.restore(int(epoch), args=ocp.args.Composite(
                state=ocp.args.StandardRestore(flat)))["state"]
        except (ValueError, KeyError) as err:
            raise CheckpointMismatch(f"checkpoint {epoch} in {self.directory} does not fit this program: "
                                     f"{err}") from err
        out = []
        for i, x in enumerate(leaves):
            key = f"{i:05d}"
            if key in flat:
                got = restored[key]
                if got.shape != x.shape or got.dtype != x.dtype:
                    raise CheckpointMismatch(f"checkpoint {epoch}: array {key} is {got.shape} {got.dtype}, "
                                             f"expected {x.shape} {x.dtype}")
                out.append(jax.numpy.asarray(np.asarray(got)))
            else:  # zero-size leaf: not stored
                out.append(jax.numpy.zeros(x.shape, x.dtype))
        # Uncommitted arrays, like a jitted function's outputs: committed ones would make every jitted
        # function compile again for the resumed state.
        return jax.tree_util.tree_unflatten(treedef, out), meta

    def close(self) -> None:
        self.manager.close()
