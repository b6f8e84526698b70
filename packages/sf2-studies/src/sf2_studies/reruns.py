"""Reruns: runs trained again with the same config and seeds, kept by `study merge --keep-reruns` under
<study>/rerun/ (`StudyFolder.rerun_path`), each compared seed by seed with the run the report uses (its
"Reruns" section and reruns.csv; report.py).

On GPUs two trainings of one config and seeds differ from the first epoch on (XLA picks its kernels by
timing them in each process, and they round differently), so a rerun is a second draw of the same seeds:
how far the two draws lie apart is spread that more seeds average out but that no single run shows
(results/fig7-td3/README.md, "reproducible in distribution"). Reruns stay out of results.csv, the
aggregates and the claims, which read `runs/` only. The AUC is the report's (`stats.auc`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from sf2_common.agents.plotting import curves
from sf2_common.agents.runfolder import RunFolder, RunFolderError

from . import stats
from .folder import StudyFolder
from .merge import first_difference
from .spec import StudyError

__all__ = ["CSV_FIELDS", "Rerun", "collect", "csv_rows"]

CSV_FIELDS = ["task", "method", "seed", "run", "rerun", "auc_run", "auc_rerun", "final_return_run",
              "final_return_rerun"]


@dataclasses.dataclass
class Rerun:
    """One rerun folder against the run folder it repeats (same task, method folder and seed group)."""

    task: str
    method: str                 # the method's label
    run: Path                   # the run folder in runs/
    path: Path                  # the rerun folder in rerun/
    seeds: list[int]
    auc_run: np.ndarray         # per seed, as results.csv has it
    auc_rerun: np.ndarray
    final_run: np.ndarray       # final evaluation return per seed
    final_rerun: np.ndarray
    method_auc: float           # the method's mean AUC over all its finished seeds on the task (the report's)
    method_auc_rerun: float     # the same with this rerun's seeds in place of the run's
    method_seeds: int
    first_difference: tuple | None   # (epoch, seed, field, run's value, rerun's) of the first learned
                                     # value that differs (merge.first_difference); None: none differs

    @property
    def difference(self) -> np.ndarray:
        """AUC rerun − run, per seed."""
        return self.auc_rerun - self.auc_run


def collect(folder: StudyFolder, data) -> tuple[list[Rerun], list[Path]]:
    """(the reruns of the finished run folders of `data` (report.RunData), every folder under rerun/ that
    repeats none of them: ignored, and named by the report). `StudyError` naming a rerun folder that
    cannot be read, or whose seeds are not its run's."""
    found, matched = [], set()
    for d in data:
        for g in (g for g in d.groups if g.finished):
            # runs/<task>/<folder>[/seeds-…] of this study folder, or of another that it borrows the run from
            task_dir = next(p for p in g.path.parents
                            if p.name == d.task and p.parent.name == StudyFolder.RUNS)
            run_folder = g.path.relative_to(task_dir).parts[0]
            k = 1
            while (path := folder.rerun_path(d.task, run_folder, g.seeds, k)).is_dir():
                matched.add(path)
                found.append(_compare(d, g, path))
                k += 1
    base = folder.path / StudyFolder.RERUN
    ignored = [] if not base.is_dir() else sorted(
        p for method in base.iterdir() if method.is_dir() for p in method.iterdir() if p not in matched)
    return found, ignored


def _compare(d, group, path: Path) -> Rerun:
    try:
        rows = RunFolder(path).read_rows(strict=True)
        run_rows = RunFolder(group.path).read_rows(strict=True)
    except RunFolderError as err:
        raise StudyError(f"rerun {path} or its run {group.path}: {err}. Restore the file, or move the "
                         f"folder out of the study folder") from None
    steps, per_seed = curves(rows)
    seeds = list(group.seeds)
    if sorted(per_seed) != sorted(seeds):
        raise StudyError(f"rerun {path} holds seeds {sorted(per_seed)}, its run {group.path} seeds {seeds}: "
                         f"not a rerun of it; move it out of the study folder")
    auc = {s: stats.auc(d.steps, d.returns[s]) for s in d.seeds()}
    auc_rerun = {s: stats.auc(steps, per_seed[s]) for s in seeds}
    return Rerun(d.task, d.method.label, group.path, path, seeds,
                 np.array([auc[s] for s in seeds]), np.array([auc_rerun[s] for s in seeds]),
                 np.array([d.returns[s][-1] for s in seeds]), np.array([per_seed[s][-1] for s in seeds]),
                 float(np.mean(list(auc.values()))), float(np.mean(list({**auc, **auc_rerun}.values()))),
                 len(auc), first_difference(run_rows, rows))


def csv_rows(reruns: list[Rerun], root: Path) -> list[dict]:
    """One row per rerun and seed (`CSV_FIELDS`); folders relative to the study folder `root`."""
    return [{"task": r.task, "method": r.method, "seed": s, "run": r.run.relative_to(root).as_posix(),
             "rerun": r.path.relative_to(root).as_posix(), "auc_run": float(r.auc_run[i]),
             "auc_rerun": float(r.auc_rerun[i]), "final_return_run": float(r.final_run[i]),
             "final_return_rerun": float(r.final_rerun[i])}
            for r in reruns for i, s in enumerate(r.seeds)]
