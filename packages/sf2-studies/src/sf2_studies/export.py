"""`study export DIR --out FILE.csv|FILE.parquet`: every run of a study folder as one long table, a row per
(task, method, seed, evaluation), the format rliable's and openrlbenchmark's users load.

The run folders are read by report.py's readers (`report.collect`), finished and unfinished alike (column
`finished`); `COLUMNS` are always there, then the config fields whose values differ between the runs of a
task. Every check comes before the first write, and the file is written atomically: bad input (not a study
folder, an unknown suffix, an --out that cannot be written, Parquet without pyarrow) writes nothing.
docs/studies.md, "study export"."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import os
import subprocess
from pathlib import Path

from sf2_common.errors import ConfigError

from .base import StudyError
from .folder import StudyFolder

__all__ = ["COLUMNS", "SUFFIXES", "Export", "commit_of", "rows", "export"]

COLUMNS = ("study", "commit", "task", "method", "method_name", "algo", "representation", "framework", "seed",
           "env_step", "return", "finished")
SUFFIXES = (".csv", ".parquet")
_NOT_CONFIG = set(COLUMNS) | {"label", "seeds"}   # config fields already a column (algo, representation, ...)


@dataclasses.dataclass
class Export:
    """What `export` wrote: the file, its rows and columns, the commit recorded, the runs it holds."""

    path: Path
    rows: int
    columns: list[str]
    commit: str           # "" when the study folder lies in no git repository
    runs: int             # run folders with at least one evaluation
    unfinished: int       # of those, the ones not finished


def commit_of(path) -> str:
    """`git rev-parse HEAD` of the git repository `path` lies in (tracked or not), "" if none (or no git)."""
    try:
        done = subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=30)
    except (OSError, subprocess.SubprocessError):
        return ""
    return done.stdout.strip() if done.returncode == 0 else ""


def _cell(value):
    """A config value as a table cell: scalars as they are, lists and mappings as JSON text."""
    return json.dumps(value, sort_keys=True) if isinstance(value, list | dict) else value


def _one_type(values: list) -> list:
    """A column's cells of one type, so that CSV and Parquet hold the same: ints among floats as floats,
    any other mixture (a bool beside a number, text beside a number) as JSON text; None stays."""
    kinds = {type(v) for v in values if v is not None}
    if kinds == {int, float}:
        return [None if v is None else float(v) for v in values]
    if len(kinds) > 1:
        return [v if v is None or isinstance(v, str) else json.dumps(v) for v in values]
    return values


def _differing(data) -> list[str]:
    """The config fields whose values differ between the run folders of some task (sorted)."""
    fields = set()
    for task in dict.fromkeys(d.task for d in data):
        configs = [g.config for d in data if d.task == task for g in d.groups if g.config]
        for name in set().union(*configs) if configs else ():
            if len({json.dumps(c.get(name), sort_keys=True) for c in configs}) > 1:
                fields.add(name)
    return sorted(fields - _NOT_CONFIG)


def rows(path) -> tuple[list[str], list[dict], Export]:
    """(columns, rows, summary) of the study folder `path`: one row per task, method, seed and evaluation of
    every run folder (study order; a seed group's rows as its folder holds them, finished or not); a method
    that shares another's run folder gets its rows under its own label. `StudyError` if `path` is not a
    study folder or a run's files cannot be read."""
    from .report import collect

    folder = StudyFolder(path)
    if not folder.path.is_dir():
        raise StudyError(f"{path}: no such folder; give a study folder that `study run` or `study merge` "
                         "wrote (e.g. results/fig7-td3)")
    study = folder.load_study()
    framework = folder.read_state().get("framework") or study.framework or ""
    data = collect(study, folder)
    extra = _differing(data)
    commit = commit_of(folder.path)
    out, runs, unfinished = [], set(), set()
    for d in data:
        m = d.method
        for g in d.groups:
            if not g.returns:
                continue
            runs.add(g.path)
            if not g.finished:
                unfinished.add(g.path)
            config = {name: _cell(g.config.get(name)) for name in extra}
            for seed, returns in sorted(g.returns.items()):
                for step, ret in zip(g.steps, returns):
                    out.append({"study": study.name, "commit": commit, "task": d.task, "method": m.label,
                                "method_name": m.name, "algo": m.algo, "representation": m.representation,
                                "framework": m.framework or framework, "seed": int(seed),
                                "env_step": int(step), "return": float(ret), "finished": g.finished,
                                **config})
    for name in extra:
        for row, cell in zip(out, _one_type([row[name] for row in out])):
            row[name] = cell
    columns = [*COLUMNS, *extra]
    return columns, out, Export(Path(), len(out), columns, commit, len(runs), len(unfinished))


def _check_out(out) -> Path:
    """--out as a Path, or `StudyError`/`ConfigError` naming what is wrong with it (nothing written)."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in SUFFIXES:
        raise StudyError(f"--out {out}: unknown suffix {out.suffix or '(none)'!r}; the table is written as "
                         f"{' or '.join(SUFFIXES)} (e.g. --out {out.with_suffix('.csv').name})")
    if suffix == ".parquet" and importlib.util.find_spec("pyarrow") is None:
        raise ConfigError(f"--out {out}: writing Parquet needs the package pyarrow, which is not installed: "
                          f"pip install pyarrow (or pip install \"packages/sf2-studies[parquet]\"), or write "
                          f"--out {out.with_suffix('.csv')}")
    if out.is_dir():
        raise StudyError(f"--out {out} is a folder; give a file name ending in {suffix}")
    parent = out.parent
    while not parent.exists():   # the folders it would create
        parent = parent.parent
    if not parent.is_dir():
        raise StudyError(f"--out {out} cannot be written: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise StudyError(f"--out {out} cannot be written: no permission to write in {parent}")
    return out


def export(path, out) -> Export:
    """Write the study folder `path`'s table (`rows`) to `out` (.csv, or .parquet through pandas and pyarrow).

    Args:
        path: the study folder.
        out: the file to write (its folders are created); an existing file is replaced.

    Returns:
        What was written (`Export`).

    Raises:
        StudyError: `path` is not a study folder, a run's files cannot be read, `out` has another suffix or
            cannot be written; nothing is written.
        ConfigError: `out` is .parquet and pyarrow is not installed.
    """
    import pandas as pd

    out = _check_out(out)
    columns, table, summary = rows(path)
    frame = pd.DataFrame(table, columns=columns)
    tmp = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")   # the user's umask, as `out` gets
        if out.suffix.lower() == ".csv":
            frame.to_csv(tmp, index=False)
        else:
            frame.to_parquet(tmp, engine="pyarrow", index=False)
        os.replace(tmp, out)
    except OSError as err:
        raise StudyError(f"--out {out} cannot be written ({err.strerror or err}); nothing was "
                         "written") from None
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
    return dataclasses.replace(summary, path=out)
