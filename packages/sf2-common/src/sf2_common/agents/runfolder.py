"""A run folder (the same layout for both cores; docs/run-folders.md): `config.json` identifies the run,
`metrics.jsonl` holds one row per evaluation and seed, `checkpoints/`, `learning_curve.png`, `final/`,
`train.log` and, after a recovery, `damaged/`. Nothing a user made is deleted implicitly: a folder holding a
run's files without a readable `config.json` is a `RunFolderError`; only `clear()` (`--fresh`) discards,
and it says what. metrics.jsonl is append-safe (flush + fsync per row; a torn last line is skipped; the
first row of each (epoch, seed) is kept), and a resume drops the rows after its checkpoint, saying so."""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from sf2_common.errors import ConfigError
from sf2_common.fileio import GZ, atomic_write, expand, read_text, stored

from .configs import ADDED_FIELDS, superseded_values

__all__ = ["RunFolder", "RunFolderError", "RunFolderMismatch"]


class RunFolderError(ConfigError):
    """A run folder that cannot be used as it is: the message names the path and what is wrong with it,
    and nothing in the folder was changed (the CLIs exit with status 2)."""


class RunFolderMismatch(RunFolderError):
    """The folder holds a run with another config or other seeds."""


def framework_of(conf: dict) -> str:
    """"torch" or "jax": the core that wrote a run folder's config.json (sf2-jax writes no "framework"
    entry; sf2-torch's versions name torch). Each core's train and eval refuse the other's folders."""
    if "framework" in conf:
        return conf["framework"]
    return "torch" if "torch" in conf.get("versions", {}) else "jax"


class RunFolder:
    CONFIG = "config.json"
    METRICS = "metrics.jsonl"
    METRICS_GZ = METRICS + GZ   # a study folder's finished run keeps it compressed (sf2_common.fileio)
    CHECKPOINTS = "checkpoints"
    CURVE = "learning_curve.png"
    FINAL = "final"
    LOG = "train.log"
    DAMAGED = "damaged"
    # what a run writes besides config.json: a folder holding any of these holds a run
    RUN_FILES = (METRICS, METRICS_GZ, CHECKPOINTS, FINAL, CURVE)

    def __init__(self, path):
        self.path = Path(path)

    # ------------------------------------------------------------------ paths
    @property
    def config_path(self) -> Path:
        return self.path / self.CONFIG

    @property
    def metrics_path(self) -> Path:
        return self.path / self.METRICS

    @property
    def checkpoint_dir(self) -> Path:
        return self.path / self.CHECKPOINTS

    @property
    def curve_path(self) -> Path:
        return self.path / self.CURVE

    @property
    def final_dir(self) -> Path:
        return self.path / self.FINAL

    @property
    def log_path(self) -> Path:
        return self.path / self.LOG

    @property
    def damaged_dir(self) -> Path:
        return self.path / self.DAMAGED

    # ------------------------------------------------------------------ the folder itself
    def check_usable(self) -> None:
        """Raise `RunFolderError` unless the folder exists and can be written, or can be created: the path
        is a regular file, lies under one, or is on a read-only or forbidden location. Leaves nothing
        behind (a probe folder is created and removed); the run folder itself is created later."""
        path = self.path
        if path.exists() and not path.is_dir():
            raise RunFolderError(f"run folder {path} is a file, not a folder; pass a folder (a new one "
                                 f"is created)")
        probe_in = path
        while not probe_in.exists():
            if probe_in.parent == probe_in:
                break
            probe_in = probe_in.parent
        if probe_in.exists() and not probe_in.is_dir():
            raise RunFolderError(f"run folder {path} cannot be created: {probe_in} is a file, not a folder")
        try:
            os.rmdir(tempfile.mkdtemp(prefix=".sf2-probe-", dir=probe_in))
        except OSError as err:
            what = "written" if probe_in == path else f"created (in {probe_in})"
            raise RunFolderError(f"run folder {path} cannot be {what}: {err.strerror or err}") from None

    def run_files(self) -> list[str]:
        """The names of `RUN_FILES` that exist in the folder."""
        return [name for name in self.RUN_FILES if (self.path / name).exists()]

    def clear(self, say=None) -> list[str]:
        """Delete what a run wrote here (config, metrics, curve, log, checkpoints, final parameters and
        set-aside damaged checkpoints: `--fresh`); other files in the folder stay. Says what it discards
        (`say`, default: print to stderr) and returns the names."""
        if not self.path.exists():
            return []
        self.check_usable()
        gone = [name for name in (self.CONFIG, *self.RUN_FILES, self.LOG, self.DAMAGED)
                if (self.path / name).exists()]
        if not gone:
            return []
        detail = {self.CHECKPOINTS: _listing(self.checkpoint_dir),
                  self.METRICS: _row_count(self.metrics_path),
                  self.METRICS_GZ: _row_count(self.metrics_path)}
        what = ", ".join(n + detail.get(n, "") for n in gone)
        (say or _stderr)(f"--fresh: discarding {what} in {self.path}")
        for name in gone:
            p = self.path / name
            if p.is_dir():
                shutil.rmtree(p)
            else:
                p.unlink()
        return gone

    # ------------------------------------------------------------------ config
    def read_config(self) -> dict | None:
        """The parsed config.json, or None if there is none. `RunFolderError` if it cannot be read or is
        not a run's config (truncated, garbled, not JSON)."""
        path = self.config_path
        if path.is_dir():
            raise RunFolderError(f"{path} is a folder, not the run's config file")
        try:
            text = path.read_text()
        except FileNotFoundError:
            return None
        except NotADirectoryError:
            self.check_usable()  # names the file the folder's path runs through
            raise
        except (OSError, UnicodeDecodeError) as err:
            raise RunFolderError(f"{path} cannot be read: {getattr(err, 'strerror', None) or err}") from None
        fix = (f"it identifies the run in {self.path}: restore it, use another --out, or pass --fresh to "
               f"discard the folder's run; nothing was changed")
        if not text.strip():
            raise RunFolderError(f"{path} is empty; {fix}")
        try:
            conf = json.loads(text)
        except json.JSONDecodeError as err:
            raise RunFolderError(f"{path} is not valid JSON ({err.msg}: line {err.lineno} column "
                                 f"{err.colno}); {fix}") from None
        if not (isinstance(conf, dict) and isinstance(conf.get("config"), dict)
                and isinstance(conf.get("seeds"), list)):
            raise RunFolderError(f"{path} is not a run's config (it needs a 'config' object and a 'seeds' "
                                 f"list); {fix}")
        return conf

    def preflight(self) -> dict | None:
        """Everything checkable about the folder without the run's config: raises `RunFolderError` if it
        cannot be used (`check_usable`), if its config.json cannot be read, if it holds a run's files
        without a config.json, if a line of metrics.jsonl other than a torn last one is not a row, or if
        metrics.jsonl lacks rows that even the oldest checkpoint was written after. Returns the folder's
        config (None: the folder holds no run). Changes nothing."""
        self.check_usable()
        old = self.read_config()
        if old is None:
            found = self.run_files()
            if found:
                raise RunFolderError(
                    f"{self.path} holds a run's files ({', '.join(found)}) but no {self.CONFIG}, which "
                    f"identifies the run; nothing was changed. Restore {self.CONFIG}, use another --out, or "
                    f"pass --fresh to discard these files.")
            return None
        rows = self.read_rows(strict=True)
        epochs = self.checkpoint_epochs()
        if epochs:
            self.check_rows(rows, epochs[0], old["seeds"])
        return old

    def check_framework(self, framework: str) -> None:
        """`RunFolderMismatch` if the folder holds a run another core ("jax", "torch") trained: each core's
        train refuses the other's folders (`framework_of`)."""
        conf = self.read_config()
        if conf is not None and framework_of(conf) != framework:
            raise RunFolderMismatch(f"run folder {self.path} holds a run of sf2-{framework_of(conf)}; use "
                                    f"another --out (or --fresh to overwrite it)")

    def check_compatible(self, config: dict, seeds) -> bool:
        """True if the folder already holds this run (resume), False if it is new or holds no run. Raises
        what `preflight` raises, and `RunFolderMismatch` naming the differing fields if the folder holds
        another run."""
        old = self.preflight()
        if old is None:
            return False
        # a field the folder's config predates has the value that run trained with (configs.ADDED_FIELDS);
        # a preset value that changed since the folder was written is the folder's (configs.SUPERSEDED)
        known = {**{k: v for k, v in ADDED_FIELDS.items() if k in config}, **old["config"]}
        kept = superseded_values(known, config)
        diffs = [f"{k}: {known.get(k)!r} (folder) vs {v!r} (now)"
                 for k, v in config.items() if known.get(k) != v and k not in kept]
        diffs += [f"{k}: missing now" for k in old["config"] if k not in config]
        if list(old.get("seeds", [])) != list(seeds):
            diffs.append(f"seeds: {old.get('seeds')} (folder) vs {list(seeds)} (now)")
        if diffs:
            raise RunFolderMismatch(
                f"run folder {self.path} holds a different run; differences: " + "; ".join(diffs)
                + ". Use another --out, or --fresh to overwrite it.")
        return True

    def kept_values(self, config: dict) -> dict:
        """The fields whose preset value changed since this folder's run was written and that the run
        keeps (`configs.superseded_values`): {field: the folder's value}; {} for a new folder."""
        old = self.read_config()
        return {} if old is None else superseded_values(old["config"], config)

    def keep_trained_values(self, cfg):
        """`cfg` (a `TrainConfig`) with the values this folder's run keeps (`kept_values`), said in one
        line; `cfg` itself when there are none or the folder's config cannot be read (`preflight` names
        that problem)."""
        try:
            kept = self.kept_values(cfg.to_dict())
        except RunFolderError:
            return cfg
        if kept:
            now = cfg.to_dict()
            self.say(f"{self.path} was trained with " + ", ".join(
                f"{k} = {v!r} (the preset now gives {now[k]!r})" for k, v in kept.items())
                + "; it keeps its values (another --out, or --fresh, trains with the preset's)")
            cfg = cfg.replace(**kept)
        return cfg

    def write_config(self, payload: dict) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        atomic_write(self.config_path, json.dumps(payload, indent=2, sort_keys=True) + "\n")

    # ------------------------------------------------------------------ metrics
    def read_rows(self, strict: bool = False) -> list[dict]:
        """The rows of metrics.jsonl or of its compressed form metrics.jsonl.gz (none if neither exists),
        the first of each (epoch, seed). A torn last line (a kill mid-write) is skipped. Any other line that
        is not a row is skipped too, or, with `strict`, a `RunFolderError` naming the file and the line."""
        path = stored(self.metrics_path)
        if path is None:
            return []
        try:
            lines = read_text(path).splitlines()
        except (OSError, UnicodeDecodeError) as err:
            if not strict:
                return []
            detail = str(getattr(err, "strerror", None) or err)
            raise RunFolderError((detail if str(path) in detail else f"{path} cannot be read ({detail})")
                                 + "; nothing was changed") from None
        rows, seen = [], set()
        last = max((i for i, line in enumerate(lines) if line.strip()), default=-1)
        for i, line in enumerate(lines):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
                problem = None if isinstance(row, dict) and "epoch" in row and "seed" in row else \
                    "a JSON value without 'epoch' and 'seed'"
            except json.JSONDecodeError as err:
                row, problem = None, f"not JSON: {err.msg}"
                if i == last:
                    continue  # a torn line from a kill mid-write
            if problem:
                if strict:
                    raise RunFolderError(
                        f"{path} line {i + 1} is not a metrics row ({problem}); the file was edited or "
                        f"damaged. Nothing was changed: repair or delete that line, or pass --fresh to "
                        f"train again from scratch.")
                continue
            key = (row["epoch"], row["seed"])
            if key in seen:
                continue
            seen.add(key)
            rows.append(row)
        return rows

    def check_rows(self, rows: list[dict], epoch: int, seeds) -> None:
        """`RunFolderError` unless `rows` hold every seed's row of epochs 0..`epoch` (those that checkpoint
        `epoch` was written after)."""
        have = {(r["epoch"], r["seed"]) for r in rows}
        missing = sorted({e for e in range(epoch + 1) for s in seeds if (e, s) not in have})
        if not missing:
            return
        state = "is missing" if stored(self.metrics_path) is None else \
            f"lacks the rows of epoch{'s' if len(missing) > 1 else ''} {_ranges(missing)}"
        raise RunFolderError(
            f"{self.metrics_path} {state}, which checkpoint {epoch} was written after (truncated or "
            f"deleted?). Nothing was changed; restore it, or pass --fresh to train again from scratch.")

    def truncate_rows(self, last_epoch: int) -> list[dict]:
        """Keep the (deduplicated, well-formed) rows of epochs ≤ `last_epoch`; rewrite atomically. What the
        rewrite drops is said in one line (`say`): rows of later epochs, duplicates, a torn last line."""
        unique = self.read_rows()
        rows = [r for r in unique if r.get("epoch", 1 << 62) <= last_epoch]
        lines = self._line_count()
        self.path.mkdir(parents=True, exist_ok=True)
        expand(self.metrics_path)   # a compressed one becomes plain (and the .gz goes) before the rewrite
        atomic_write(self.metrics_path, "".join(json.dumps(r, sort_keys=True) + "\n" for r in rows))
        if lines > len(rows):
            later, other = len(unique) - len(rows), lines - len(unique)
            parts = ([f"{later} of epochs after {last_epoch} (they are trained again)"] if later else []) + \
                ([f"{other} duplicate or unreadable"] if other else [])
            self.say(f"{self.metrics_path}: {lines - len(rows)} of {lines} rows dropped "
                     f"({'; '.join(parts)}); {len(rows)} kept")
        return rows

    def _line_count(self) -> int:
        """The non-blank lines of metrics.jsonl (or its .gz); 0 if it cannot be read."""
        path = stored(self.metrics_path)
        try:
            return 0 if path is None else sum(1 for line in read_text(path).splitlines() if line.strip())
        except (OSError, UnicodeDecodeError):
            return 0

    def append_rows(self, rows: list[dict]) -> None:
        expand(self.metrics_path)   # appending continues a compressed file's rows, never a new file
        text = "".join(json.dumps(r, sort_keys=True) + "\n" for r in rows)
        with open(self.metrics_path, "a") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())

    # ------------------------------------------------------------------ notices, set-aside
    def say(self, message: str) -> None:
        """Tell the user (stderr) and keep it in the run's log."""
        _stderr(message)
        self.log(message)

    def log(self, message: str) -> None:
        """Append a timestamped line to train.log (a failure to write it is ignored)."""
        try:
            with open(self.log_path, "a") as f:
                f.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {message}\n")
        except OSError:
            pass

    def checkpoint_epochs(self) -> list[int]:
        """The epochs of the checkpoint folders (`checkpoints/<epoch>/`, both cores' layout)."""
        if not self.checkpoint_dir.is_dir():
            return []
        return sorted(int(p.name) for p in self.checkpoint_dir.iterdir() if p.name.isdigit() and p.is_dir())

    def set_aside_folder(self) -> Path:
        """A new folder `damaged/<UTC time>[-n]/` for what a recovery sets aside."""
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        for n in range(1000):
            dest = self.damaged_dir / (stamp if n == 0 else f"{stamp}-{n}")
            try:
                dest.mkdir(parents=True)
                return dest
            except FileExistsError:
                continue
        raise RunFolderError(f"cannot create a new folder in {self.damaged_dir}")


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _listing(folder: Path) -> str:
    names = sorted((p.name for p in folder.iterdir()), key=lambda n: (not n.isdigit(), n.zfill(12))) \
        if folder.is_dir() else []
    return f" ({', '.join(names)})" if names else ""


def _row_count(path: Path) -> str:
    try:
        n = sum(1 for line in read_text(path).splitlines() if line.strip())
    except (OSError, UnicodeDecodeError):
        return ""
    return f" ({n} row{'s' if n != 1 else ''})"


def _ranges(epochs: list[int]) -> str:
    """[0, 1, 2, 5] -> "0-2, 5"."""
    out, i = [], 0
    while i < len(epochs):
        j = i
        while j + 1 < len(epochs) and epochs[j + 1] == epochs[j] + 1:
            j += 1
        out.append(str(epochs[i]) if i == j else f"{epochs[i]}-{epochs[j]}")
        i = j + 1
    return ", ".join(out)

