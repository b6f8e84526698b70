"""`study borrow DIR --from OTHER`: the runs of DIR that the study folder OTHER holds finished, read there.

A study that shares runs with another (own-adam reuses fig7-td3's baselines) keeps no copy of them: its
study.json names the folder that holds each such run (`FROM`), and `study run`, `report`, `compare`,
`export` and `merge` read it there, and never write it. A run is borrowed when OTHER holds it finished with
exactly its config (no superseded preset value) and seeds, and DIR holds it identically (every file equal)
or not at all; DIR's copy is then removed, after study.json records the borrowing. A run DIR holds with
other files or contents stays. The rules: docs/study-files.md "Borrowing runs"."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

from sf2_common.agents.runfolder import RunFolderError
from sf2_common.fileio import read_text, stored

from .folder import FROM, OBS_NOISE, ReadingRun, StudyFolder, run_entry
from .merge import KEPT, _check_not_running
from .spec import Run, Study, StudyError

__all__ = ["Borrowed", "borrow"]


@dataclasses.dataclass
class Borrowed:
    """What `borrow` did (or, with `dry_run`, would do)."""

    removed: list[str] = dataclasses.field(default_factory=list)   # DIR's identical copies
    taken: list[str] = dataclasses.field(default_factory=list)     # runs DIR did not hold
    kept: list[str] = dataclasses.field(default_factory=list)      # DIR's own, different
    freed: int = 0                                                 # bytes of the copies removed


def borrow(into, other, runs_of: Callable[[Study], list[Run]], *, framework: str, dry_run: bool = False,
           say: Callable[[str], None] = print) -> Borrowed:
    """Read DIR's runs that OTHER holds finished in OTHER, removing DIR's identical copies.

    Args:
        into: the study folder DIR whose runs are borrowed.
        other: the study folder OTHER that holds them (any study; its own borrowings are followed).
        runs_of: the resolved runs of a study (`spec.resolve` with the core's configs).
        framework: the core running the command ("jax" or "torch"); both folders must hold its runs.
        dry_run: say what would be done; write and remove nothing.
        say: where the lines go.

    Returns:
        A `Borrowed`: the runs now read in OTHER, those DIR keeps, and the bytes freed.
    """
    dest, lender = StudyFolder(into), StudyFolder(other)
    for f, what in ((dest, "DIR"), (lender, "--from")):
        if not f.path.is_dir():
            raise StudyError(f"{what} {f.path}: no such folder; give a study folder that `study run` or "
                             f"`study merge` wrote (e.g. results/fig7-td3)")
    if dest.path.resolve() == lender.path.resolve():
        raise StudyError(f"--from {lender.path} is DIR itself; give the study folder that holds the runs")
    study = dest.load_study()
    lender.load_study()   # a folder that is not a study folder is refused by name
    for f in (dest, lender):
        got = f.read_state().get("framework")
        if got not in (None, framework):
            raise StudyError(f"{f.path} holds runs of sf2-{got}; borrow with `sf2-{got} study borrow`")
    runs = runs_of(study)
    lent, theirs = dest.borrowed(), lender.borrowed()
    out, entries, already = Borrowed(), {}, 0
    for run in runs:
        key, name = (run.task, run.rel), f"{run.task}/{run.rel}"
        if key in lent:
            already += 1
            continue
        there = theirs.get(key) or lender.run_path(*key)   # where OTHER reads it: followed, never chained
        try:
            same = ReadingRun(there).check_compatible(run.config.to_dict(), run.seeds, exact=True)
        except RunFolderError:
            same = False
        if not same or lender.run_state(run, study).status != "done":
            continue   # OTHER does not hold this run finished: DIR keeps or runs its own
        here = dest.run_path(*key)
        held = here.is_dir() and any(here.iterdir())
        why = _differs(here, there) if held else None
        if why:
            out.kept.append(name)
            say(f"  kept      {name}: DIR's {why}")
            continue
        entries[key] = os.path.relpath(there.parents[len(run.rel.split("/")) + 1], dest.path)
        if held:
            _check_not_running(here)
            out.removed.append(name)
            out.freed += sum(p.stat().st_size for p in here.rglob("*") if p.is_file())
        else:
            out.taken.append(name)
        say(f"  {'would borrow' if dry_run else 'borrowed'} {name} from {there}"
            + (f": DIR's identical copy {'would be ' if dry_run else ''}removed" if held else ""))
    if entries and not dry_run:
        _record(dest, study, runs, entries)   # first: a copy left by an interruption is unused, not lost
        for name in out.removed:
            _remove(dest.run_path(*name.split("/", 1)), dest.path / StudyFolder.RUNS)
    say(f"{study.name} ({dest.path}): {len(out.removed) + len(out.taken)} run(s) "
        f"{'would be ' if dry_run else ''}read in {lender.path} ({len(out.removed)} identical copies "
        f"removed, {out.freed / 1e6:.1f} MB), {len(out.kept)} kept as DIR's own"
        + (f"; {already} borrowed before" if already else ""))
    return out


def _differs(here: Path, there: Path) -> str | None:
    """How DIR's run folder differs from OTHER's (a file only one holds, or other contents), or None."""
    names = {p.relative_to(here).as_posix() for p in here.rglob("*") if p.is_file()}
    known = {str(n) for k in KEPT for n in (k, k + ".gz")}
    extra = sorted(names - known)
    if extra:
        return f"run folder holds {extra[0]}, which a borrowed run would lose"
    for name in KEPT:
        a, b = stored(here / name), stored(there / name)
        if (a is None) != (b is None):
            return f"run folder and OTHER's differ in having {name}"
        if a is not None and _content(a) != _content(b):
            return f"{name} differs from OTHER's"
    return None


def _content(path: Path):
    """A run file's content as a reader sees it (gzip or not); JSON files as their value."""
    text = read_text(path)
    return json.loads(text) if path.name.startswith(OBS_NOISE) else text


def _record(dest: StudyFolder, study: Study, runs: list[Run], entries: dict) -> None:
    """DIR's study.json with `FROM` on the entries of `entries` ({(task, folder): OTHER relative to DIR})."""
    state = dest.read_state() or {"name": study.name}
    have = {(r.get("task"), r.get("folder")): r for r in state.setdefault("runs", [])}
    for run in runs:
        key = (run.task, run.rel)
        if key in entries:
            if key not in have:
                have[key] = run_entry(run)
                state["runs"].append(have[key])
            have[key][FROM] = Path(entries[key]).as_posix()
    dest.write_state(state)


def _remove(path: Path, runs_dir: Path) -> None:
    """Remove DIR's copy and the folders it leaves empty, up to runs/."""
    shutil.rmtree(path)
    for parent in path.parents:
        if parent == runs_dir or not parent.is_relative_to(runs_dir) or any(parent.iterdir()):
            break
        parent.rmdir()
