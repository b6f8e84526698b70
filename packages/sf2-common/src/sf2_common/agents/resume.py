"""Where a run folder resumes, for both trainers (docs/run-folders.md, "Recovery rules"): the newest
checkpoint that restores (`restore(epoch)` raises `CheckpointDamaged`; `CheckpointMismatch` propagates).
A damaged newer one is set aside in `damaged/<time>/` with a copy of metrics.jsonl, never deleted, and
metrics.jsonl keeps the rows up to the checkpoint used. Every check precedes any change, and the changes
are ordered so that a kill between any two leads the next resume to the same result."""

from __future__ import annotations

import dataclasses
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from sf2_common.fileio import stored

from .checkpoints import CheckpointDamaged
from .runfolder import RunFolder, RunFolderError, RunFolderMismatch
from .runlog import library_log

__all__ = ["Checkpoints", "Resumed", "resume_run"]


class Checkpoints(Protocol):
    def all(self) -> list[int]:
        """The epochs of the checkpoints on disk now (read again at every call)."""

    def path(self, epoch: int) -> Path:
        """The folder of checkpoint `epoch`."""


@dataclasses.dataclass
class Resumed:
    epoch: int | None        # the checkpoint restored (None: the run starts from scratch)
    restored: Any            # what restore(epoch) returned (None when starting from scratch)
    rows: list[dict]         # metrics.jsonl's rows after the resume point was applied
    walltime: float          # wall time the run had spent up to the checkpoint
    start: int               # first epoch to run (0: evaluate the initial policy first)
    set_aside: Path | None   # where damaged checkpoints were moved, if any


def resume_run(run: RunFolder, ckpt: Checkpoints, restore: Callable[[int], Any], *, seeds, sched,
           existing: bool, resume: bool = True) -> Resumed:
    """Apply the rule (module docstring) to `run`. `existing`: the folder holds this run
    (`RunFolder.check_compatible`); `resume=False` refuses a folder with checkpoints; `sched` is the run's
    `configs.Schedule` (for the notices)."""
    if not existing:
        run.truncate_rows(-1)
        return Resumed(None, None, [], 0.0, 0, None)
    steps = sorted(ckpt.all())
    if steps and not resume:
        raise RunFolderMismatch(f"{run.path} already holds checkpoints; pass --fresh to start over")
    rows = run.read_rows(strict=True)
    damaged: list[CheckpointDamaged] = []
    epoch = restored = None
    with library_log(run):
        for e in reversed(steps):
            try:
                restored, epoch = restore(e), e
                break
            except CheckpointDamaged as err:
                damaged.append(err)
    _check_rows(run, rows, epoch, damaged, seeds)
    dest = _set_aside(run, damaged, epoch) if damaged else None
    if damaged:
        ckpt.all()
    rows = run.truncate_rows(-1 if epoch is None else epoch)
    walltime = max((r.get("walltime", 0.0) for r in rows), default=0.0)
    if epoch is not None:
        n = sched.num_epochs
        if epoch >= n:
            run.say(f"{run.path}: the run is complete (epoch {n} of {n}, {sched.env_steps_after(n):,} env "
                    f"steps, trained in {walltime:.0f} s); nothing to train")
        else:
            run.say(f"resuming {run.path} from checkpoint {epoch} (epoch {epoch} of {n}, env step "
                    f"{sched.env_steps_after(epoch):,})")
    return Resumed(epoch, restored, rows, walltime, 0 if epoch is None else epoch + 1, dest)


def _check_rows(run: RunFolder, rows, epoch, damaged, seeds) -> None:
    """Refuse (nothing changed) a folder whose rows cannot be those of a resume from `epoch`."""
    trained = sorted({r["epoch"] for r in rows if isinstance(r["epoch"], int) and r["epoch"] >= 1})
    if epoch is None and trained:
        why = ("; ".join(f"checkpoint {d.epoch}: {d.reason}" for d in damaged) if damaged
               else f"{run.checkpoint_dir} holds none")
        raise RunFolderError(
            f"{run.path} cannot be resumed: no checkpoint restores ({why}), but {run.METRICS} holds the "
            f"rows of epochs up to {trained[-1]}. Nothing was changed; pass --fresh to train again from "
            f"scratch (it discards the folder's run).")
    if epoch is not None:
        run.check_rows(rows, epoch, seeds)


def _set_aside(run: RunFolder, damaged: list[CheckpointDamaged], epoch) -> Path:
    dest = run.set_aside_folder()
    kept = stored(run.metrics_path)   # metrics.jsonl, or its compressed form
    if kept is not None:
        shutil.copy2(kept, dest / kept.name)
    used = f"checkpoint {epoch}" if epoch is not None else "no checkpoint (a fresh start)"
    (dest / "reasons.txt").write_text("".join(f"{d}\n" for d in damaged) + f"resumed from {used}\n")
    (dest / run.CHECKPOINTS).mkdir()
    for d in damaged:
        shutil.move(str(d.path), str(dest / run.CHECKPOINTS / str(d.epoch)))
        run.say(f"{d}; set aside in {dest / run.CHECKPOINTS / str(d.epoch)}")
    if kept is not None:
        run.say(f"{kept.name} as it was is kept in {dest / kept.name}")
    return dest
