"""A run folder, one layout for both cores (docs/run-folders.md): `config.json` identifies the run,
`metrics.jsonl` holds one row per evaluation and seed (append-safe: fsync per row, a torn last line and
repeated (epoch, seed) rows skipped), then `checkpoints/`, `learning_curve.png`, `final/`, `train.log` and
`damaged/`. Nothing is deleted implicitly: only `clear()` (`--fresh`) discards, and it says what."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

from sf2_common.errors import ConfigError
from sf2_common.fileio import GZ, atomic_write, expand, read_text, stored

from .configs import ADDED_FIELDS, EXECUTION_FIELDS, superseded_values

__all__ = ["RunFolder", "RunFolderError", "RunFolderMismatch", "METRIC_NAME"]

METRIC_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")   # a metrics.jsonl key: an identifier (fullmatch)
DIGEST = "sha256"   # config.json's checksum of the rest of it (folders written before it have none)


class RunFolderError(ConfigError):
    """A run folder that cannot be used as it is (the message names the path; nothing was changed)."""


class RunFolderMismatch(RunFolderError):
    """The folder holds a run with another config or other seeds."""


def config_digest(payload: dict) -> str:
    """The SHA-256 of a run's config payload, its `DIGEST` entry left out.

    Args:
      payload: config.json's object, as written or as read back.

    Returns:
      The hex digest of its canonical JSON (sorted keys, no spaces), equal for the dict written and the
      one parsed back from the file.
    """
    body = {k: v for k, v in payload.items() if k != DIGEST}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def framework_of(conf: dict) -> str:
    """"torch" or "jax": the core that wrote a run folder's config.json (sf2-jax writes no "framework"
    entry; sf2-torch's versions name torch)."""
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
    LOGGERS = ("loggers.json", "tensorboard", "wandb")   # `--log`'s (sf2_common.agents.loggers)

    def __init__(self, path):
        self.path = Path(path)

    # ------------------------------------------------------------------ paths
    config_path = property(lambda self: self.path / self.CONFIG)
    metrics_path = property(lambda self: self.path / self.METRICS)
    checkpoint_dir = property(lambda self: self.path / self.CHECKPOINTS)
    curve_path = property(lambda self: self.path / self.CURVE)
    final_dir = property(lambda self: self.path / self.FINAL)
    log_path = property(lambda self: self.path / self.LOG)
    damaged_dir = property(lambda self: self.path / self.DAMAGED)

    # ------------------------------------------------------------------ the folder itself
    def check_usable(self) -> None:
        """Raise `RunFolderError` unless the folder can be written or created (not a file, under none,
        not read-only or forbidden); a probe folder is created and removed, nothing else."""
        path = self.path
        if path.exists() and not path.is_dir():
            raise RunFolderError(f"run folder {path} is a file, not a folder; pass a folder (a new one "
                                 f"is created)")
        probe_in = path
        while not probe_in.exists() and probe_in.parent != probe_in:
            probe_in = probe_in.parent
        if probe_in.exists() and not probe_in.is_dir():
            raise RunFolderError(f"run folder {path} cannot be created: {probe_in} is a file, not a folder")
        try:
            os.rmdir(tempfile.mkdtemp(prefix=".sf2-probe-", dir=probe_in))
        except OSError as err:
            what = "written" if probe_in == path else f"created (in {probe_in})"
            raise RunFolderError(f"run folder {path} cannot be {what}: {err.strerror or err}") from None

    def clear(self, say=None) -> list[str]:
        """Delete what a run wrote here (config, metrics, curve, log, checkpoints, final parameters,
        set-aside damaged checkpoints and the `LOGGERS`' files: `--fresh`); other files in the folder
        stay. Says what it discards (`say`, default: print to stderr) and returns the names."""
        if not self.path.exists():
            return []
        self.check_usable()
        gone = [name for name in (self.CONFIG, *self.RUN_FILES, self.LOG, self.DAMAGED, *self.LOGGERS)
                if (self.path / name).exists()]
        if not gone:
            return []
        rows = self._line_count()
        rows = "" if rows is None else f" ({rows} row{'s' if rows != 1 else ''})"
        detail = {self.CHECKPOINTS: _listing(self.checkpoint_dir), self.METRICS: rows, self.METRICS_GZ: rows}
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
        """The parsed config.json (without its checksum), or None if there is none. `RunFolderError` if it
        cannot be read, is not a run's config (truncated, garbled, not JSON) or differs from its checksum."""
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
        # a damaged file can still parse (a flipped byte inside a name or a string): its checksum tells
        if isinstance(conf, dict) and DIGEST in conf and conf.pop(DIGEST) != config_digest(conf):
            raise RunFolderError(f"{path} is damaged: its content does not match the {DIGEST} checksum "
                                 f"written with it; {fix}")
        if not (isinstance(conf, dict) and isinstance(conf.get("config"), dict)
                and isinstance(conf.get("seeds"), list)):
            raise RunFolderError(f"{path} is not a run's config (it needs a 'config' object and a 'seeds' "
                                 f"list); {fix}")
        return conf

    def preflight(self) -> dict | None:
        """The folder's config (None: it holds no run) after every check that needs no config of the run:
        `RunFolderError` if it is unusable, its config.json unreadable or missing beside a run's files, a
        metrics row (other than a torn last line) garbled, or rows missing before the oldest checkpoint."""
        self.check_usable()
        old = self.read_config()
        if old is None:
            if found := [name for name in self.RUN_FILES if (self.path / name).exists()]:
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
        """`RunFolderMismatch` if the folder holds a run another core ("jax", "torch") trained."""
        conf = self.read_config()
        if conf is not None and framework_of(conf) != framework:
            raise RunFolderMismatch(f"run folder {self.path} holds a run of sf2-{framework_of(conf)}; use "
                                    f"another --out (or --fresh to overwrite it)")

    def check_compatible(self, config: dict, seeds, exact: bool = False) -> bool:
        """True if the folder holds this run (resume), False if it holds none; raises what `preflight`
        raises, or `RunFolderMismatch` naming the differing fields (`configs.EXECUTION_FIELDS` may differ;
        with `exact`, a superseded preset value the folder kept is a difference too)."""
        old = self.preflight()
        if old is None:
            return False
        # a field the folder's config predates has the value that run trained with (configs.ADDED_FIELDS);
        # a preset value that changed since the folder was written is the folder's (configs.SUPERSEDED)
        known = {**{k: v for k, v in ADDED_FIELDS.items() if k in config}, **old["config"]}
        kept = {} if exact else superseded_values(known, config)
        diffs = [f"{k}: {known.get(k)!r} (folder) vs {v!r} (now)" for k, v in config.items()
                 if known.get(k) != v and k not in kept and k not in EXECUTION_FIELDS]
        diffs += [f"{k}: missing now" for k in old["config"] if k not in config]
        if list(old.get("seeds", [])) != list(seeds):
            diffs.append(f"seeds: {old.get('seeds')} (folder) vs {list(seeds)} (now)")
        if diffs:
            raise RunFolderMismatch(
                f"run folder {self.path} holds a different run; differences: " + "; ".join(diffs)
                + ". Use another --out, or --fresh to overwrite it.")
        return True

    def say_execution_changes(self, config: dict) -> None:
        """Say each field of `configs.EXECUTION_FIELDS` whose value in `config` differs from the one the
        folder's run started with (which its config.json keeps)."""
        old = (self.read_config() or {}).get("config", {})
        for k in EXECUTION_FIELDS:
            started = old.get(k, ADDED_FIELDS.get(k))
            if k in config and config[k] != started:
                self.say(f"{self.path} resumes with {k} = {config[k]!r}; it started with {started!r}, which "
                         f"its config.json keeps (how the program runs, not what it computes)")

    def keep_trained_values(self, cfg):
        """`cfg` (a `TrainConfig`) with the superseded preset values this folder's run keeps
        (`configs.superseded_values`), said in one line; `cfg` itself when there are none or the config
        cannot be read (`preflight` names that problem)."""
        now = cfg.to_dict()
        try:
            old = self.read_config()
        except RunFolderError:
            return cfg
        if kept := ({} if old is None else superseded_values(old["config"], now)):
            self.say(f"{self.path} was trained with " + ", ".join(
                f"{k} = {v!r} (the preset now gives {now[k]!r})" for k, v in kept.items())
                + "; it keeps its values (another --out, or --fresh, trains with the preset's)")
            cfg = cfg.replace(**{k: tuple(v) if isinstance(v, list) else v for k, v in kept.items()})
        return cfg

    def write_config(self, payload: dict) -> None:
        """Write config.json atomically, with the `DIGEST` checksum that `read_config` checks."""
        self.path.mkdir(parents=True, exist_ok=True)
        payload = json.loads(json.dumps(payload))   # as it will read back (tuples as lists)
        payload[DIGEST] = config_digest(payload)
        atomic_write(self.config_path, json.dumps(payload, indent=2, sort_keys=True) + "\n")

    # ------------------------------------------------------------------ metrics
    def read_rows(self, strict: bool = False) -> list[dict]:
        """The rows of metrics.jsonl (or .gz; none if neither exists), the first of each (epoch, seed). A
        torn last line is skipped; any other non-row (not JSON, no 'epoch' or 'seed', or a key that is not
        a `METRIC_NAME`, as damage inside a key leaves it) too, or with `strict` a `RunFolderError` naming
        it."""
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
                odd = [k for k in row if not METRIC_NAME.fullmatch(k)] if problem is None else []
                problem = problem or (f"a key that is no metric name: {odd[0]!r}" if odd else None)
            except json.JSONDecodeError as err:
                if i == last:
                    continue  # a torn line from a kill mid-write
                problem = f"not JSON: {err.msg}"
            if problem and strict:
                raise RunFolderError(
                    f"{path} line {i + 1} is not a metrics row ({problem}); the file was edited or "
                    f"damaged. Nothing was changed: repair or delete that line, or pass --fresh to "
                    f"train again from scratch.")
            if not problem and (key := (row["epoch"], row["seed"])) not in seen:
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
        lines = self._line_count() or 0
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

    def _line_count(self) -> int | None:
        """The non-blank lines of metrics.jsonl (or its .gz): 0 if neither exists, None if unreadable."""
        path = stored(self.metrics_path)
        try:
            return 0 if path is None else sum(1 for line in read_text(path).splitlines() if line.strip())
        except (OSError, UnicodeDecodeError):
            return None

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
        with contextlib.suppress(OSError), open(self.log_path, "a") as f:
            f.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {message}\n")

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
            with contextlib.suppress(FileExistsError):
                dest.mkdir(parents=True)
                return dest
        raise RunFolderError(f"cannot create a new folder in {self.damaged_dir}")


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _listing(folder: Path) -> str:
    names = sorted((p.name for p in folder.iterdir()), key=lambda n: (not n.isdigit(), n.zfill(12))) \
        if folder.is_dir() else []
    return f" ({', '.join(names)})" if names else ""


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

