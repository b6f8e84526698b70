"""A study folder: the study file it was made from (study.toml), its state (study.json: the run folder of
every (task, method) and seed group, the commands), one run folder per training program under
runs/<task>/<method>[/seeds-0-4]/ (or, for a run `study borrow` found identical in another study folder,
that folder's, named in study.json), reruns under rerun/, and the report under report/.

A study file that differs from the copy only in what no run depends on, or only adds tasks or methods,
replaces the copy; any other difference is a `StudyError` and nothing is written. The layout:
docs/study-files.md "The study folder"."""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import time
import uuid
from pathlib import Path

from sf2_common.agents.obsnoise import OBS_NOISE
from sf2_common.agents.runfolder import RunFolder, RunFolderError, RunFolderMismatch
from sf2_common.fileio import atomic_write, compress, read_text, stored

from .spec import Run, Study, StudyError, changed_methods, loads, same_runs, seeds_folder

__all__ = ["StudyFolder", "RunState", "ReadingRun", "OBS_NOISE", "LOG", "FROM", "evaluation_settings",
           "evaluation_done", "read_obs_noise", "command_line"]

LOG = "train.log"
FROM = "from"   # a study.json runs entry's key: the study folder, relative to this one, that holds the run


class ReadingRun(RunFolder):
    """`RunFolder.check_compatible` that writes nothing: without the writability probe (a merge's source or
    another study's run may be read-only) and without the checkpoints (never copied or borrowed)."""

    def check_usable(self) -> None:
        if self.path.exists() and not self.path.is_dir():
            raise RunFolderError(f"run folder {self.path} is a file, not a folder")

    def checkpoint_epochs(self) -> list[int]:
        return []


@dataclasses.dataclass(frozen=True)
class RunState:
    status: str            # "new", "partial", "trained" (evaluation missing), "done"
    env_steps: int         # env steps done, summed over seeds
    total_env_steps: int   # the run's budget, summed over seeds


def run_entry(run: Run) -> dict:
    """A run's entry in study.json's `runs`: its task, folder under the task, methods and seeds."""
    return {"task": run.task, "folder": run.rel, "methods": [m.name for m in run.methods],
            "seeds": list(run.seeds)}


def command_entry(command: str) -> dict:
    """A command's entry in study.json's `commands`: the command line, this host and the time now."""
    return {"command": command, "host": socket.gethostname(), "time": time.strftime("%Y-%m-%d %H:%M:%S")}


class StudyFolder:
    STUDY, STATE, RUNS, REPORT = "study.toml", "study.json", "runs", "report"
    RERUN = "rerun"   # reruns kept by `study merge --keep-reruns` (merge.py), compared by reruns.py

    def __init__(self, path):
        self.path = Path(path)

    # ------------------------------------------------------------------ the study it holds
    @property
    def study_path(self) -> Path:
        return self.path / self.STUDY

    def read_state(self) -> dict:
        """study.json ({} if there is none); `StudyError` naming it and the remedy if it cannot be read."""
        p = self.path / self.STATE
        if not p.exists():
            return {}
        try:
            state = json.loads(p.read_text(encoding="utf-8"))
            problem = None if isinstance(state, dict) else "not a JSON object"
        except (json.JSONDecodeError, UnicodeDecodeError, OSError) as err:
            problem = str(getattr(err, "strerror", None) or err)
        if problem:
            raise StudyError(f"{p} is not a study's state ({problem}); nothing was changed. Restore it "
                             f"(e.g. `git checkout` it), or delete it and `study run` again, which writes "
                             f"a new one (the record of past commands is lost; the run folders stay)")
        return state

    def load_study(self) -> Study:
        """The study this folder was made from (its copy of the study file)."""
        if not self.study_path.exists():
            raise StudyError(f"{self.path} is not a study folder (no {self.STUDY}); make one with "
                             f"`study run FILE --out {self.path}`")
        return loads(self.study_path.read_text(encoding="utf-8"), self.study_path)

    def check(self, study: Study, framework: str, runs: list[Run] | None = None) -> None:
        """Raise `StudyError` if the folder holds another study or one run by another framework; write
        nothing. With `runs` (the study's, resolved), a method the file rewrites under its name passes when
        every run folder of it here is a run of the new table (`refit`)."""
        if self.path.exists() and not self.path.is_dir():
            raise StudyError(f"--out {self.path} is a file, not a folder")
        if not self.study_path.exists():
            if self.path.exists() and any(self.path.iterdir()):
                raise StudyError(f"--out {self.path} is not empty and holds no study ({self.STUDY}); choose "
                                 f"an empty or new folder")
            return
        old = self.load_study()
        keys = same_runs(old, study, self.groups_on_disk(old),
                         self.refit(old, study, runs) if runs is not None else frozenset())
        if keys:
            raise StudyError(
                f"study folder {self.path} was made from another study file: its copy {self.study_path} "
                f"(study {old.name!r}) and {study.path} (study {study.name!r}) differ in {', '.join(keys)}. "
                f"Nothing was changed; use another --out for {study.path}")
        old_framework = self.read_state().get("framework")
        if old_framework and old_framework != framework:
            raise StudyError(f"study folder {self.path} holds runs of sf2-{old_framework}; continue it with "
                             f"`sf2-{old_framework} study run` (runs of two frameworks do not mix)")

    def refit(self, old: Study, new: Study, runs: list[Run]) -> frozenset[str]:
        """The methods of `old` (this folder's copy) that `new` rewrites under their names whose run folders
        here all hold runs of `new`'s `runs` (their configs and seeds: `check_compatible`), e.g. a method
        pinned to the preset value its runs trained with after the preset changed."""
        fit = set()
        for name in changed_methods(old, new):
            mine = [r for r in runs if name in (m.name for m in r.methods)]
            try:
                ok = bool(mine) and all(
                    (ReadingRun if self.is_borrowed(r) else RunFolder)(self.path_of(r)).check_compatible(
                        r.config.to_dict(), r.seeds)
                    or not self.path_of(r).exists() for r in mine)
            except (RunFolderError, OSError, ValueError):   # another run, or one that cannot be read
                ok = False
            if ok:
                fit.add(name)
        return frozenset(fit)

    def write_state(self, state: dict) -> None:
        """Write study.json atomically (indented, UTF-8): the one way every command writes it.

        Args:
            state: the study's state, as `read_state` returns it.
        """
        atomic_write(self.path / self.STATE, json.dumps(state, indent=2, ensure_ascii=False) + "\n")

    def groups_on_disk(self, study: Study) -> set[tuple[int, ...]]:
        """The seed groups of `study` that have a run folder here (of any task and method, any state); without
        `seeds_per_run`, the one group of every seed if any method's folder is here."""
        base = self.path / self.RUNS
        lent = {tuple(r.get("seeds", study.seeds)) for r in self.read_state().get("runs", []) if r.get(FROM)}
        if study.seeds_per_run is None:
            return {tuple(study.seeds)} if lent or any(p.is_dir() for p in base.glob("*/*")) else set()
        return {g for g in study.seed_groups()
                if g in lent or any(base.glob(f"*/*/{study.group_folder(g)}"))}

    def open(self, study: Study, framework: str, runs: list[Run], command: str | None = None) -> dict:
        """`check`, then create or update the folder: its copy of the study file, and study.json (the run
        folder of every method, the command appended). Returns the state."""
        self.check(study, framework, runs)
        self.path.mkdir(parents=True, exist_ok=True)
        if not self.study_path.exists() or self.load_study().data != study.data:
            # new, or a file that differs from the copy only in what no run depends on (spec.RUN_NEUTRAL:
            # description, report, claims): the copy follows the file
            atomic_write(self.study_path, study.text)
        state = self.read_state()
        state.setdefault("id", uuid.uuid4().hex)
        state.update(name=study.name, framework=framework)
        held = {(r.get("task"), r.get("folder")): r[FROM] for r in state.get("runs", []) if r.get(FROM)}
        state["runs"] = [{**run_entry(r), **({FROM: held[r.task, r.rel]} if (r.task, r.rel) in held else {})}
                         for r in runs]
        if command is not None:
            state.setdefault("commands", []).append(command_entry(command))
        self.write_state(state)
        return state

    # ------------------------------------------------------------------ runs
    def run_path(self, task: str, folder: str) -> Path:
        """runs/<task>/<folder>; `folder` is a `Run.rel` ('<method>' or '<method>/seeds-0-4')."""
        return self.path / self.RUNS / task / folder

    def path_of(self, run: Run) -> Path:
        """The run's folder: runs/<task>/<run.rel>, or the other study folder's that study.json names."""
        return self.borrowed().get((run.task, run.rel)) or self.run_path(run.task, run.rel)

    def borrowed(self) -> dict[tuple[str, str], Path]:
        """{(task, folder): run folder} of the runs this folder reads from another study folder (study.json's
        `from`, written by `study borrow`); `StudyError` naming an entry whose study folder is missing."""
        out = {}
        for r in self.read_state().get("runs", []):
            if not r.get(FROM):
                continue
            other = Path(os.path.normpath(self.path / r[FROM]))
            if not (other / self.STUDY).is_file():
                raise StudyError(
                    f"{self.path / self.STATE}: the run {r['task']}/{r['folder']} lives in the study folder "
                    f"{r[FROM]!r} (relative to {self.path}), which is not there ({other}); nothing was "
                    f"changed. Restore that folder beside this one, or merge the run into this folder and "
                    f"remove the entry's {FROM!r}")
            out[(r["task"], r["folder"])] = other / self.RUNS / r["task"] / r["folder"]
        return out

    def rebase(self, origin) -> int:
        """After this folder was copied from `origin` (e.g. to a GPU host's /tmp): each study.json `from`
        made to name, from here, the folder it named from `origin`. Returns the entries changed.

        Args:
            origin: the study folder this one is a copy of.

        Returns:
            The number of runs entries rewritten (0 for a folder that borrows nothing).
        """
        state = self.read_state()
        changed = 0
        for r in state.get("runs", []):
            if r.get(FROM):
                r[FROM] = Path(os.path.relpath(Path(origin) / r[FROM], self.path)).as_posix()
                changed += 1
        if changed:
            self.write_state(state)
        self.borrowed()   # every folder named is there, or `StudyError` names the one that is not
        return changed

    def is_borrowed(self, run: Run) -> bool:
        """True if the run's folder is another study folder's (`borrowed`): this folder never writes it."""
        return self.path_of(run) != self.run_path(run.task, run.rel)

    def rerun_path(self, task: str, folder: str, seeds, k: int = 1) -> Path:
        """rerun/<task>-<folder>/<seeds folder>, '.k' appended for the k-th rerun (k > 1) of one run;
        `folder` is the method's run folder under runs/<task>/ (`Run.folder`)."""
        name = seeds_folder(seeds) + (f".{k}" if k > 1 else "")
        return self.path / self.RERUN / f"{task}-{folder}" / name

    def method_runs(self, study: Study) -> dict[tuple[str, str], dict[tuple[int, ...], Path]]:
        """{(task, method name): {seed group: run folder}}: study.json's map (methods sharing a config
        share its runs), else each method's own folders."""
        out = {}
        for t in study.tasks:
            for m in study.methods:
                out[(t, m.name)] = {
                    g: self.run_path(t, "/".join(filter(None, (m.name, study.group_folder(g)))))
                    for g in study.seed_groups()}
        lent = self.borrowed()
        for r in self.read_state().get("runs", []):
            seeds = tuple(r.get("seeds", study.seeds))   # study.json before seed groups: all seeds
            for name in r["methods"]:
                groups = out.get((r["task"], name))
                if groups is not None and seeds in groups:
                    key = (r["task"], r["folder"])
                    groups[seeds] = lent.get(key) or self.run_path(*key)
        return out

    def check_run(self, run: Run) -> None:
        """Raise `StudyError` if the run's folder holds another config or other seeds (the trainer would
        refuse it too, after compiling)."""
        kind = ReadingRun if self.is_borrowed(run) else RunFolder
        try:
            kind(self.path_of(run)).check_compatible(run.config.to_dict(), run.seeds)
        except RunFolderMismatch as err:
            raise StudyError(f"{err} (the study folder's runs must come from its study file)") from None

    def run_state(self, run: Run, study: Study) -> RunState:
        from sf2_common.agents.configs import schedule

        path = self.path_of(run)
        sched = schedule(run.config)
        total = sched.total_env_steps * len(run.seeds)
        rows = RunFolder(path).read_rows()
        if not (path / RunFolder.CONFIG).exists():
            return RunState("new", 0, total)
        last = {}
        for r in rows:
            last[r["seed"]] = max(last.get(r["seed"], 0), int(r.get("env_steps", 0)))
        steps = sum(last.values())
        # every seed's last evaluation row is the run's result; the final parameters are not needed
        # (a run brought back from another machine holds its metrics and config only)
        trained = all(any(r["seed"] == s and r["epoch"] == sched.num_epochs for r in rows)
                      for s in run.seeds)
        if not trained:
            return RunState("partial" if rows else "new", steps, total)
        if study.evaluation is not None and not evaluation_done(path, study):
            return RunState("trained", steps, total)
        return RunState("done", steps, total)

    def compress_runs(self, runs: list[Run], study: Study) -> list[str]:
        """gzip the metrics.jsonl and obs_noise.json of `runs` that are finished here (`study compress`;
        `study merge` does it to the runs it writes): 4-5× smaller, read as before by every reader of this
        project (sf2_common.fileio). Unfinished runs stay as they are (their trainer appends). Returns
        "<task>/<folder>" of each run it compressed a file of."""
        for run in runs:   # every check before the first change: a damaged or foreign run stops it here
            self.check_run(run)
        done = []
        for run in runs:
            if self.is_borrowed(run) or self.run_state(run, study).status != "done":
                continue
            path = self.path_of(run)
            if any([compress(path / RunFolder.METRICS), compress(path / OBS_NOISE)]):
                done.append(f"{run.task}/{run.rel}")
        return done


def evaluation_settings(study: Study) -> dict:
    e = study.evaluation
    return {"obs_noise": list(e.obs_noise), "checkpoints": e.checkpoints, "episodes": e.episodes,
            "deterministic": e.deterministic}


def read_obs_noise(run_dir) -> dict | None:
    """A run folder's obs_noise.json (or its .gz) as {"settings", "results"}; None if it has none;
    `ValueError` naming the file if it cannot be read or is not an evaluation's results."""
    found = stored(Path(run_dir) / OBS_NOISE)
    if found is None:
        return None
    try:
        data = json.loads(read_text(found))
        problem = None if isinstance(data, dict) and "results" in data else "no 'results' object"
    except (json.JSONDecodeError, OSError, UnicodeDecodeError) as err:
        problem = f"{type(err).__name__}: {err}"
    if problem:
        raise ValueError(f"{found} is not an evaluation's results ({problem})")
    return data


def evaluation_done(run_dir: Path, study: Study) -> bool:
    try:
        data = read_obs_noise(run_dir)
    except ValueError:
        return False
    return data is not None and data.get("settings") == evaluation_settings(study)


def command_line(prog: str, argv) -> str:
    """The command as a user would type it (for summary.md)."""
    import shlex

    return " ".join([prog, *map(shlex.quote, argv)])
