"""A run folder: `config.json` (resolved config, seeds, schedule, versions), `metrics.jsonl` (one row per
evaluation and seed), `checkpoints/` (the framework's own format: Orbax for sf2_jax, torch files for
sf2_torch), `learning_curve.png`, and `final/params_seed{S}.npz`. The same layout for both cores.

metrics.jsonl is append-safe: every row is one JSON line written with flush + fsync; a reader skips a
torn last line (a kill mid-write) and keeps the first row of each (epoch, seed). When a run resumes from
checkpoint e, rows of epochs after e are dropped (they will be produced again, identically), so no row is
lost or duplicated whatever moment the run was killed at.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from sf2_common.errors import ConfigError

__all__ = ["RunFolder", "RunFolderMismatch"]


class RunFolderMismatch(ConfigError):
    """The folder holds a run with another config or other seeds."""


class RunFolder:
    CONFIG = "config.json"
    METRICS = "metrics.jsonl"
    CHECKPOINTS = "checkpoints"
    CURVE = "learning_curve.png"
    FINAL = "final"

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

    def clear(self) -> None:
        """Delete what a run wrote here (config, metrics, curve, checkpoints, final parameters; `--fresh`);
        other files in the folder stay."""
        import shutil

        if not self.path.exists():
            return
        for name in (self.CONFIG, self.METRICS, self.CURVE):
            (self.path / name).unlink(missing_ok=True)
        shutil.rmtree(self.checkpoint_dir, ignore_errors=True)
        shutil.rmtree(self.final_dir, ignore_errors=True)

    # ------------------------------------------------------------------ config
    def read_config(self) -> dict | None:
        if not self.config_path.exists():
            return None
        return json.loads(self.config_path.read_text())

    def check_compatible(self, config: dict, seeds) -> bool:
        """True if the folder already holds this run (resume), False if it is new or empty. Raises
        `RunFolderMismatch` naming the differing fields if it holds another run."""
        old = self.read_config()
        if old is None:
            return False
        diffs = [f"{k}: {old['config'].get(k)!r} (folder) vs {v!r} (now)"
                 for k, v in config.items() if old["config"].get(k) != v]
        diffs += [f"{k}: missing now" for k in old["config"] if k not in config]
        if list(old.get("seeds", [])) != list(seeds):
            diffs.append(f"seeds: {old.get('seeds')} (folder) vs {list(seeds)} (now)")
        if diffs:
            raise RunFolderMismatch(
                f"run folder {self.path} holds a different run; differences: " + "; ".join(diffs)
                + ". Use another --out, or --fresh to overwrite it.")
        return True

    def write_config(self, payload: dict) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        _atomic_write(self.config_path, json.dumps(payload, indent=2, sort_keys=True) + "\n")

    # ------------------------------------------------------------------ metrics
    def read_rows(self) -> list[dict]:
        if not self.metrics_path.exists():
            return []
        rows, seen = [], set()
        for line in self.metrics_path.read_text().splitlines():
            line = line.strip()
            if not line:
                continue
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue  # a torn line from a kill mid-write
            key = (row.get("epoch"), row.get("seed"))
            if key in seen:
                continue
            seen.add(key)
            rows.append(row)
        return rows

    def truncate_rows(self, last_epoch: int) -> list[dict]:
        """Keep the (deduplicated, well-formed) rows of epochs ≤ `last_epoch`; rewrite atomically."""
        rows = [r for r in self.read_rows() if r.get("epoch", 1 << 62) <= last_epoch]
        self.path.mkdir(parents=True, exist_ok=True)
        _atomic_write(self.metrics_path, "".join(json.dumps(r, sort_keys=True) + "\n" for r in rows))
        return rows

    def append_rows(self, rows: list[dict]) -> None:
        text = "".join(json.dumps(r, sort_keys=True) + "\n" for r in rows)
        with open(self.metrics_path, "a") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
