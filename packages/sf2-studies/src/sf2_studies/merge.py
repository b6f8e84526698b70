"""`study merge SOURCE... --into DEST`: the runs of study folders that ran elsewhere (other commands,
machines, sessions), or .tar.gz archives of them, joined into one study folder.

Per run folder the merge copies only what a study folder keeps in git (`KEPT`), gzip-compressed
(`COMPRESSED`); a finished run that differs from DEST's is refused, or with `reruns` kept beside it.
Every check of every SOURCE comes before the first write; each run folder is written into a temporary
sibling and renamed into place, study.json last. The rules: docs/study-files.md "Merging"."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import tarfile
import tempfile
import time
import zlib
from collections.abc import Callable
from pathlib import Path, PurePosixPath

from sf2_common.agents.hostloop import WALL_FIELDS
from sf2_common.agents.lock import FolderLock, holder_of
from sf2_common.agents.runfolder import RunFolder, RunFolderError, RunFolderMismatch
from sf2_common.fileio import GZ, atomic_write, compress, stored

from .folder import FROM, OBS_NOISE, ReadingRun, StudyFolder, command_entry, read_obs_noise, run_entry
from .spec import Run, Study, StudyError, load, loads, only_adds, same_runs, seeds_text

__all__ = ["KEPT", "Outcome", "first_difference", "merge", "rows_difference"]

KEPT = (RunFolder.CONFIG, RunFolder.METRICS, RunFolder.LOG, OBS_NOISE)
COMPRESSED = (RunFolder.METRICS, OBS_NOISE)   # DEST keeps these gzip-compressed (sf2_common.fileio)
_KEPT_NAMES = {*KEPT, *(name + GZ for name in COMPRESSED)}   # a source's, in either form
_NEVER = {RunFolder.CHECKPOINTS, RunFolder.FINAL, RunFolder.DAMAGED}   # folders never read from a source
_LOCKS = (FolderLock.NAME, ".study-lock")   # the run folder's lock, and the one runners held before it


@dataclasses.dataclass
class _Side:
    """One run folder as the merge sees it."""

    path: Path
    status: str          # "new", "partial", "trained", "done" (`StudyFolder.run_state`)
    steps: int           # env steps done, summed over seeds
    rows: list[dict]
    noise: object        # obs_noise.json's results, or None
    where: str           # the source's name for messages ("DEST" for the destination)

    @property
    def finished(self) -> bool:
        return self.status == "done"

    def same_metrics(self, other: _Side) -> bool:
        return _key_rows(self.rows) == _key_rows(other.rows) and self.noise == other.noise

    def progress(self, total: int) -> str:
        return {"new": "not started", "done": "finished"}.get(
            self.status, f"unfinished, {self.steps:,} of {total:,} env steps"
            + (" (evaluation missing)" if self.status == "trained" else ""))


@dataclasses.dataclass
class Outcome:
    merged: list[str] = dataclasses.field(default_factory=list)
    replaced: list[str] = dataclasses.field(default_factory=list)
    skipped: list[str] = dataclasses.field(default_factory=list)
    reruns: list[str] = dataclasses.field(default_factory=list)   # DEST-relative folders written
    commands_added: int = 0
    created: bool = False


def merge(sources, into, runs_of: Callable[[Study], list[Run]], *, framework: str, partial: bool = False,
          reruns: bool = False, study_file=None, command: str | None = None,
          say: Callable[[str], None] = print) -> Outcome:
    """Merge the study folders or archives `sources` into the study folder `into` (module docstring).
    `runs_of(study)`: the study's runs resolved against the framework's configs (`spec.resolve`);
    `framework`: its name ("jax"). Raises `StudyError` (nothing written) for a source that is not a study
    folder or archive of one, another study, another framework, a run whose config is not the study's, or
    a finished run that DEST holds with other metrics (unless `reruns`: module docstring).
    With `study_file` the sources may hold other studies: DEST holds that file's study, and takes of each
    source only the run folders at one of its runs' paths whose config is that run's (the runs two studies
    share); the rest is ignored, the sources' commands are not joined, and `command` is recorded instead."""
    if not sources:
        raise StudyError("study merge: name at least one SOURCE (a study folder or a .tar.gz archive of one)")
    dest = StudyFolder(into)
    foreign = study_file is not None
    with contextlib.ExitStack() as stack:
        opened = [_open_source(str(s), stack) for s in sources]
        study = _study_of_file(study_file, opened, dest, framework, runs_of) if foreign else _check_studies(
            opened, dest, framework)
        runs = runs_of(study)
        expected = {f"{r.task}/{r.rel}": r for r in runs}
        outcome = Outcome(created=not dest.study_path.exists())
        # ---- every check before the first write
        current = {name: _look(dest, run, study, "DEST") for name, run in expected.items()}
        chosen: dict[str, _Side] = {}
        kept_reruns: dict[Path, _Side] = {}
        conflicts, lines = [], []
        for name_src, src in opened:
            strays = _stray_runs(src, expected)
            if foreign and strays:
                lines.append(f"  ignored   {len(strays)} run folder(s) in {name_src}: no run of study "
                             f"{study.name!r} has their path")
            for extra in [] if foreign else strays:
                lines.append(f"  ignored   {extra} in {name_src}: not a run folder of study {study.name!r}")
            for name, run in expected.items():
                other = _other_config(src, run) if foreign else None
                if other:
                    lines.append(f"  ignored   {name} in {name_src}: not this study's run ({other})")
                    continue
                new = _look(src, run, study, name_src)
                if new.status == "new":
                    continue
                old = current[name]
                total = _total(run, study)
                if old.finished and new.finished:
                    if old.same_metrics(new):
                        outcome.skipped.append(name)
                        lines.append(f"  skipped   {name}: identical to {old.where}'s")
                    elif reruns:
                        target = _rerun_target(dest, expected[name], new, kept_reruns)
                        if target is None:
                            outcome.skipped.append(name)
                            lines.append(f"  skipped   {name} in {name_src}: identical to a rerun DEST keeps")
                        else:
                            kept_reruns[target] = new
                            outcome.reruns.append(target.relative_to(dest.path).as_posix())
                            lines.append(f"  rerun     {name} from {name_src}: finished with other metrics "
                                         f"than {old.where}'s ({_difference(old, new)}); kept as "
                                         f"{outcome.reruns[-1]}, out of the report")
                    else:
                        conflicts.append(f"{name}: {old.where} and {name_src} both hold it finished with "
                                         f"different metrics ({_difference(old, new)})")
                    continue
                if old.finished:
                    outcome.skipped.append(name)
                    lines.append(f"  kept      {name}: {old.where}'s is finished ({name_src}'s: "
                                 f"{new.progress(total)})")
                    continue
                if not new.finished and not partial:
                    outcome.skipped.append(name)
                    lines.append(f"  skipped   {name} in {name_src}: {new.progress(total)} (--partial "
                                 f"merges unfinished runs)")
                    continue
                if not new.finished and old.status != "new" and new.steps <= old.steps:
                    outcome.skipped.append(name)
                    lines.append(f"  kept      {name}: {old.where}'s is as far ({old.progress(total)})")
                    continue
                current[name] = chosen[name] = new
                lines.append(f"  {'replaced' if old.status != 'new' else 'merged':9} {name} from {name_src}: "
                             f"{new.progress(total)}, seeds {seeds_text(run.seeds)}"
                             + (f" ({old.where}'s was {old.progress(total)})" if old.status != "new" else ""))
        if conflicts:
            raise StudyError(
                f"study merge into {dest.path} refused; nothing was written:\n  " + "\n  ".join(conflicts)
                + "\nA finished run is never overwritten: remove DEST's run folder first if the source's "
                "should win, leave that source out, or keep the source's as a rerun (--keep-reruns).")
        for name in chosen:
            _check_not_running(dest.run_path(expected[name].task, expected[name].rel))
        # ---- writes
        for line in lines:
            say(line)
        if outcome.created:
            dest.path.mkdir(parents=True, exist_ok=True)
            atomic_write(dest.study_path, study.text)
        elif dest.load_study().data != study.data:
            say(f"  study.toml of {dest.path}: replaced by {study_file if foreign else 'a source'}'s, which "
                f"changes what no run depends on (description, report, claims), adds tasks or methods, "
                f"rewrites a method whose runs DEST holds as they are, or groups the seeds otherwise, "
                f"keeping every run folder DEST holds")
            atomic_write(dest.study_path, study.text)
        for name, side in chosen.items():
            target = dest.run_path(expected[name].task, expected[name].rel)
            existed = target.exists() and any(target.iterdir())
            aside = _install(side.path, target)
            (outcome.replaced if existed else outcome.merged).append(name)
            if aside is not None:
                say(f"  set aside {name}: DEST's run folder held more than {', '.join(KEPT)}; it is now "
                    f"{aside}")
        for target, side in kept_reruns.items():
            _install(side.path, target)
        outcome.commands_added = _merge_state(dest, [] if foreign else [src for _, src in opened], study,
                                              framework, [expected[n] for n in chosen],
                                              command if foreign and chosen else None)
    say(f"{study.name} → {dest.path}{' (new)' if outcome.created else ''}: {len(outcome.merged)} run(s) "
        f"merged, {len(outcome.replaced)} replaced, {len(outcome.skipped)} skipped"
        + (f", {len(outcome.reruns)} kept as rerun(s)" if outcome.reruns else "") + "; "
        f"{outcome.commands_added} command(s) added to study.json")
    return outcome


# ------------------------------------------------------------------------------------------- sources
def _open_source(text: str, stack: contextlib.ExitStack) -> tuple[str, StudyFolder]:
    """(the name messages use, the study folder) of a SOURCE argument; an archive is unpacked (only the
    files a merge reads) into a temporary folder that lives as long as `stack`."""
    path = Path(text)
    if not path.exists():
        raise StudyError(f"merge source {path} does not exist (a study folder or a .tar.gz archive of one)")
    root = path if path.is_dir() else _unpack(path, Path(stack.enter_context(
        tempfile.TemporaryDirectory(prefix="sf2-merge-"))))
    if not (root / StudyFolder.STUDY).is_file():
        inner = [d for d in root.iterdir() if d.is_dir() and (d / StudyFolder.STUDY).is_file()]
        if len(inner) != 1:
            what = "study folder archive" if root != path else "study folder"
            raise StudyError(f"merge source {path} is not a {what}: it holds no {StudyFolder.STUDY} "
                             "(`study run FILE --out DIR` makes one; scripts/gpu-host/gpu_study.sh archives "
                             "one)")
        root = inner[0]
    return text, _Source(root)


def _unpack(path: Path, into: Path) -> Path:
    """The study files of the archive `path` (study.toml, study.json, runs/**/`KEPT`) written under `into`;
    members with absolute paths or '..' are ignored. `StudyError` if it cannot be read."""
    try:
        with tarfile.open(path, "r:gz" if path.name.endswith(("gz", ".tgz")) else "r:*") as archive:
            for member in archive:
                parts = [p for p in PurePosixPath(member.name).parts if p != "."]
                if (not member.isfile() or not parts or member.name.startswith("/") or ".." in parts
                        or _NEVER.intersection(parts)):
                    continue
                wanted = (parts[-1] in (StudyFolder.STUDY, StudyFolder.STATE) and len(parts) <= 2) or (
                    "runs" in parts and parts[-1] in _KEPT_NAMES)
                if wanted:
                    out = into.joinpath(*parts)
                    out.parent.mkdir(parents=True, exist_ok=True)
                    out.write_bytes(archive.extractfile(member).read())
    except (tarfile.TarError, EOFError, zlib.error, OSError) as err:
        why = str(err).splitlines()[0] if str(err) else type(err).__name__
        if "empty file" in str(err):
            why = "an empty archive"
        raise StudyError(f"merge source {path} is not a readable .tar.gz archive of a study folder ({why}); "
                         f"nothing was merged") from None
    return into


def _state(folder: StudyFolder, name: str) -> dict:
    try:
        return folder.read_state()
    except StudyError as err:
        raise StudyError(f"{name}: {str(err).replace('nothing was changed', 'nothing was merged')}") from None


def _check_studies(opened, dest: StudyFolder, framework: str) -> Study:
    """The study every source and DEST hold; `StudyError` naming the first that differs."""
    studies = []
    for name, src in opened:
        try:
            study = loads(src.study_path.read_text(encoding="utf-8"), src.study_path)
        except (OSError, UnicodeDecodeError) as err:
            raise StudyError(f"merge source {name}: {src.study_path} cannot be read ({err})") from None
        except StudyError as err:
            raise StudyError(f"merge source {name}: {err}") from None
        studies.append((name, study, src))
        got = _state(src, name).get("framework") or study.framework
        if got is not None and got != framework:
            raise StudyError(f"merge source {name} holds runs of sf2-{got}; merge it with `sf2-{got} study "
                             f"merge` (runs of two frameworks do not mix)")
    held = _dest_study(dest, framework, "the same study")
    if held is not None:
        studies.insert(0, (f"--into {dest.path}", held, dest))
    # The study of the merge: the one every other holds runs of (spec.same_runs: description, report, claims
    # may differ; seed groups while every group a folder holds is one of its, or a folder holds no run; it
    # may add tasks and methods). DEST's copy first; else a source's study that holds every folder's runs,
    # DEST's included, becomes DEST's copy.
    first_name, first, _ = studies[0]
    for _, candidate, _ in studies:
        if all(not same_runs(study, candidate, folder.groups_on_disk(study)) for _, study, folder in studies):
            return candidate
    for name, study, folder in studies[1:]:
        keys = same_runs(study, first, folder.groups_on_disk(study))
        if keys and not only_adds(first, study):
            raise StudyError(f"{name} holds study {study.name!r}, not the study of {first_name} "
                             f"({first.name!r}): their study.toml differ in {', '.join(keys)}; nothing was "
                             f"merged")
    # every source holds the first's study or adds to it, but no one study holds them all
    adders = [name for name, study, _ in studies[1:] if only_adds(first, study)]
    raise StudyError(f"{', '.join(adders)} add different tasks or methods to the study of {first_name}; "
                     f"merge them into a folder whose study.toml holds all of them; nothing was merged")


def _study_of_file(path, opened, dest: StudyFolder, framework: str, runs_of: Callable) -> Study:
    """The study of `path` for a merge of other studies' runs (`merge`'s `study_file`); `StudyError` for a
    source of another framework, or a DEST that holds another study (a method the file rewrites passes when
    DEST's runs of it are runs of the file's: `StudyFolder.refit`)."""
    study = load(Path(path))
    if study.framework is not None and study.framework != framework:
        raise StudyError(f"{path} is a study of sf2-{study.framework}; merge with "
                         f"`sf2-{study.framework} study merge`")
    for name, src in opened:
        got = _state(src, name).get("framework")
        if got is not None and got != framework:
            raise StudyError(f"merge source {name} holds runs of sf2-{got}; runs of two frameworks do not "
                             f"mix")
    held = _dest_study(dest, framework, f"{path}'s study")
    if held is not None:
        refit = dest.refit(held, study, runs_of(study))
        keys = same_runs(held, study, dest.groups_on_disk(held), refit)
        if keys and not only_adds(held, study, refit):
            raise StudyError(f"--into {dest.path} holds study {held.name!r}, not the study of {path} "
                             f"({study.name!r}): their study.toml differ in {', '.join(keys)}; nothing was "
                             f"merged")
    return study


def _dest_study(dest: StudyFolder, framework: str, which: str) -> Study | None:
    """The study DEST holds, or None for a new or empty folder; `StudyError` for a file, a folder of other
    files, or runs of another framework (`which`: the study a folder should hold, for the message)."""
    if dest.path.exists() and not dest.path.is_dir():
        raise StudyError(f"--into {dest.path} is a file, not a study folder")
    if dest.study_path.exists():
        got = _state(dest, str(dest.path)).get("framework")
        if got is not None and got != framework:
            raise StudyError(f"--into {dest.path} holds runs of sf2-{got}; merge with `sf2-{got} study "
                             f"merge`")
        return dest.load_study()
    if dest.path.exists() and any(dest.path.iterdir()):
        raise StudyError(f"--into {dest.path} is not empty and holds no study ({StudyFolder.STUDY}); "
                         f"choose a study folder of {which}, or a new folder")
    return None


def _other_config(src: StudyFolder, run: Run) -> str | None:
    """Why the source's run folder at `run`'s path is not `run` (its config or seeds differ), or None (it
    is, or there is none)."""
    path = src.path_of(run)
    if not (path / RunFolder.CONFIG).is_file():
        return None
    try:
        ReadingRun(path).check_compatible(run.config.to_dict(), run.seeds)
    except RunFolderMismatch as err:
        return str(err).replace(" Use another --out, or --fresh to overwrite it.", "").rstrip(".")
    except RunFolderError:
        return None   # `_look` names a damaged folder and refuses the merge
    return None


def _stray_runs(src: StudyFolder, expected) -> list[str]:
    """Run folders (a config.json) under the source's runs/ that are not runs of the study."""
    base = src.path / StudyFolder.RUNS
    if not base.is_dir():
        return []
    found = []
    for cfg in base.rglob(RunFolder.CONFIG):
        rel = cfg.parent.relative_to(base)
        if not _NEVER.intersection(rel.parts) and rel.as_posix() not in expected:
            found.append(rel.as_posix())
    return sorted(found)


# ------------------------------------------------------------------------------------------- runs
def _look(folder: StudyFolder, run: Run, study: Study, where: str) -> _Side:
    path = folder.path_of(run)
    try:
        ReadingRun(path).check_compatible(run.config.to_dict(), run.seeds)
        state = folder.run_state(run, study)
        rows = RunFolder(path).read_rows(strict=True)
    except RunFolderMismatch as err:
        why = str(err).replace(" Use another --out, or --fresh to overwrite it.", "")
        raise StudyError(f"{where}: {why} (a study folder's runs must come from its study file); nothing "
                         f"was merged") from None
    except RunFolderError as err:
        fix = (f"move the run folder {path} out of DEST (a source's finished run then takes its place) or "
               f"restore the file" if where == "DEST" else
               "restore the file, or merge without this source")
        raise StudyError(f"{where}: {str(err).replace('; nothing was changed', '')}; nothing was merged: "
                         f"{fix}") from None
    try:
        data = read_obs_noise(path)
        noise = None if data is None else data["results"]
    except ValueError:
        noise = "unreadable"
    return _Side(path, state.status, state.env_steps, rows, noise, where)


class _Source(StudyFolder):
    """A SOURCE: only the runs in its own runs/ (a run it borrows from another study folder is that one's to
    merge; an archive holds no other folder)."""

    def borrowed(self) -> dict:
        return {}


def _total(run: Run, study: Study) -> int:
    from sf2_common.agents.configs import schedule

    return schedule(run.config).total_env_steps * len(run.seeds)


def _key_rows(rows: list[dict]) -> list[str]:
    return sorted(json.dumps(r, sort_keys=True) for r in rows)


def _difference(a: _Side, b: _Side) -> str:
    """Why two finished runs are not the same: their metrics (`rows_difference`), else obs_noise.json."""
    return rows_difference(a.rows, b.rows) or "their obs_noise.json results differ"


def rows_difference(a: list[dict], b: list[dict]) -> str | None:
    """The first (epoch, seed) row where two runs' metrics differ, naming a learned value (return, loss)
    before a timing field ("epoch 9 seed 0: actor_loss 0.5345 vs 0.5334"; "equal learned values, only timing
    differs; first ..." when only timing does), None when every row is equal. Two hosts' runs of one config
    differ in timing always, and on GPUs in their values too unless XLA's deterministic ops are on
    (results/fig7-td3/README.md; scripts/gpu-host/gpu_determinism.sh compares its pairs with this)."""
    first = first_difference(a, b)
    if first is not None:
        epoch, seed, field, x, y = first
        where = f"epoch {epoch} seed {seed}"
        return f"{where}: a row in one only" if field is None else f"{where}: {field} {x!r} vs {y!r}"
    timing = first_difference(a, b, learned=False)
    if timing is not None:
        epoch, seed, field, x, y = timing
        return (f"equal learned values, only timing differs; first epoch {epoch} seed {seed}: {field} {x!r} "
                f"vs {y!r}")
    return None


def first_difference(a: list[dict], b: list[dict], learned: bool = True) -> tuple | None:
    """(epoch, seed, field, value in a, value in b) of the first row, in (epoch, seed) order, where two runs'
    metrics differ in a learned value (`learned`; field None: a row in one run only), or else (not
    `learned`) in a timing field (`WALL_FIELDS`); None when there is none."""
    ra = {(r["epoch"], r["seed"]): r for r in a}
    rb = {(r["epoch"], r["seed"]): r for r in b}
    for key in sorted(set(ra) | set(rb)):
        x, y = ra.get(key), rb.get(key)
        if x is None or y is None:
            if learned:
                return (*key, None, None, None)
            continue
        fields = [k for k in sorted(set(x) | set(y))
                  if x.get(k) != y.get(k) and (k in WALL_FIELDS) != learned]
        if fields:
            return (*key, fields[0], x.get(fields[0]), y.get(fields[0]))
    return None


def _rerun_target(dest: StudyFolder, run: Run, side: _Side, planned: dict[Path, _Side]) -> Path | None:
    """Where DEST keeps `side` as a rerun of `run` (`StudyFolder.rerun_path`): the first such folder neither
    taken nor planned by this merge; None when one of them holds the same metrics."""
    for k in range(1, 1000):
        target = dest.rerun_path(run.task, run.folder, run.seeds, k)
        if target in planned:
            if planned[target].same_metrics(side):
                return None
            continue
        if not target.exists():
            return target
        try:
            rows = RunFolder(target).read_rows(strict=True)
            data = read_obs_noise(target)
        except (RunFolderError, ValueError):
            continue   # an unreadable folder there is left as it is; the next name is tried
        kept = _Side(target, "done", 0, rows, None if data is None else data["results"], "rerun")
        if kept.same_metrics(side):
            return None
    raise StudyError(f"{target.parent}: 999 reruns of {run.task}/{run.rel} already; nothing was merged")


def _check_not_running(target: Path) -> None:
    holder = holder_of(target)
    if holder is not None:
        raise StudyError(f"{target} is being written now by {holder}; merge after it stops; nothing was "
                         f"merged")


def _install(source: Path, target: Path) -> Path | None:
    """Copy `KEPT` of `source` into a temporary sibling of `target`, then rename it into place. A run folder
    that was at `target` is renamed away first; it is removed if it held only `KEPT` (the lock file
    aside), else it stays next to `target` and its path is returned."""
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.merge-", dir=target.parent))
    old = None
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)
        for name in KEPT:
            found = stored(source / name)
            if found is not None:
                _copy(found, tmp / found.name)
        for name in COMPRESSED:
            compress(tmp / name)
        if target.exists():
            old = target.with_name(f".{target.name}.replaced-{os.getpid()}")
            os.rename(target, old)
        os.rename(tmp, target)
    except BaseException:
        if old is not None and not target.exists():
            os.rename(old, target)
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if old is None:
        return None
    if {p.name for p in old.iterdir()} <= {*_KEPT_NAMES, *_LOCKS}:
        shutil.rmtree(old)
        return None
    aside = target.with_name(f"{target.name}.before-merge-{time.strftime('%Y%m%d-%H%M%S')}")
    os.rename(old, aside)
    return aside


def _copy(src: Path, dst: Path) -> None:
    """Content only (a source may be read-only; DEST's runs stay writable for the trainer), synced."""
    with open(src, "rb") as f, open(dst, "wb") as g:
        shutil.copyfileobj(f, g)
        g.flush()
        os.fsync(g.fileno())


# ------------------------------------------------------------------------------------------- study.json
def _merge_state(dest: StudyFolder, sources: list[StudyFolder], study: Study, framework: str,
                 merged: list[Run], command: str | None = None) -> int:
    """DEST's study.json with every source's runs entries and commands joined in (module docstring), and
    `command` (the merge's own, where given) recorded; written only if it changed. Returns the number of
    commands added."""
    old = dest.read_state()
    state = json.loads(json.dumps(old))
    states = [s.read_state() for s in sources]
    if not state:
        first = next((s for s in states if s), {})
        state = {"id": first.get("id") or os.urandom(16).hex(), "name": study.name, "framework": framework}
    state.setdefault("name", study.name)
    state.setdefault("framework", framework)
    runs = state["runs"] = [r for r in state.get("runs", []) if _entry_of(study, r)]
    have = {(r.get("task"), r.get("folder")) for r in runs}
    for run in merged:   # written into DEST's runs/ now: no longer read from another folder
        for r in runs:
            if (r.get("task"), r.get("folder")) == (run.task, run.rel):
                r.pop(FROM, None)
    for entry in (e for s in states for e in s.get("runs", []) if _entry_of(study, e)):
        if (entry.get("task"), entry.get("folder")) not in have:
            have.add((entry.get("task"), entry.get("folder")))
            runs.append({k: v for k, v in entry.items() if k != FROM})   # a source's borrowing is its own
    for run in merged:   # a source whose study.json lacks the entry (hand-made): the run's own
        if (run.task, run.rel) not in have:
            have.add((run.task, run.rel))
            runs.append(run_entry(run))
    commands = list(state.get("commands", []))
    if command is not None:
        commands.append(command_entry(command))
    seen = {json.dumps(c, sort_keys=True) for c in commands}
    for c in (c for s in states for c in s.get("commands", [])):
        key = json.dumps(c, sort_keys=True)
        if key not in seen:
            seen.add(key)
            commands.append(c)
    added = len(commands) - len(state.get("commands", []))
    if commands:
        state["commands"] = sorted(commands, key=lambda c: str(c.get("time", "")))
    if state != old:
        dest.path.mkdir(parents=True, exist_ok=True)
        dest.write_state(state)
    return added


def _entry_of(study: Study, entry: dict) -> bool:
    """True when a study.json runs entry names a run folder of `study`'s layout: its seeds one of the seed
    groups and its folder that group's (runs/<task>/<method>/seeds-0-4, or runs/<task>/<method> without
    `seeds_per_run`); DEST's entries from before a regrouping it took (it held no run folder) are not."""
    seeds = tuple(entry.get("seeds", study.seeds))
    if seeds not in study.seed_groups():
        return False
    sub, folder = study.group_folder(seeds), str(entry.get("folder", ""))
    return folder.endswith("/" + sub) if sub else "/" not in folder
