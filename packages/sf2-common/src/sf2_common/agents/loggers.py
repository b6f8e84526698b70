"""Metric sinks beside metrics.jsonl (`train --log tensorboard,wandb`): every row `hostloop.run_epochs`
appends goes also to TensorBoard (one run per seed: RUN/tensorboard/seed<S>/) and/or Weights & Biases (one
run per seed, grouped by the run folder; offline, in RUN/wandb/, unless WANDB_MODE says otherwise), under
the row's own names, at its env step. metrics.jsonl stays the source of truth. RUN/loggers.json keeps each
sink's last logged epoch and the W&B run ids: a resume continues the same runs and logs no epoch twice, and
a sink first used on a resume starts with the folder's earlier rows (docs/agents.md, "Loggers")."""

from __future__ import annotations

import importlib.util
import json
import os
import secrets
import time

from sf2_common.errors import ConfigError
from sf2_common.fileio import atomic_write

__all__ = ["SINKS", "RECORD", "AXES", "parse_log", "scalars", "Sinks"]

SINKS = ("tensorboard", "wandb")      # each is also the package it needs and sf2-common's extra
RECORD = "loggers.json"
AXES = ("epoch", "seed", "env_steps")   # a row's coordinates (the x-axis, the run), not its metrics


def parse_log(log) -> tuple[str, ...]:
    """The sinks `log` names, checked before anything is compiled.

    Args:
      log: "tensorboard", "wandb", "tensorboard,wandb", a sequence of those names, or None / "" for none.

    Returns:
      The names, each once, in the order given.

    Raises:
      ConfigError: an unknown name (the valid ones named), or a sink whose package is not installed (the
        pip command named).
    """
    names = log.split(",") if isinstance(log, str) else list(log or ())
    names = tuple(dict.fromkeys(n.strip() for n in names if n.strip()))
    for name in names:
        if name not in SINKS:
            raise ConfigError(f"--log {name!r} is not a logger; choose from {', '.join(SINKS)} "
                              f"(comma-separated for both)")
        if importlib.util.find_spec(name) is None:
            raise ConfigError(f"--log {name} needs the package {name}, which is not installed: pip install "
                              f"\"packages/sf2-common[{name}]\" (from the repository root)")
    return names


def scalars(row: dict) -> dict:
    """{name: value} of a metrics.jsonl row's numbers but its `AXES`: what every sink logs of it."""
    return {k: float(v) for k, v in row.items()
            if k not in AXES and isinstance(v, (int, float)) and not isinstance(v, bool)}


class Sinks:
    """The sinks of one session of a run folder (a context manager): `hook(hook)` wraps `run_epochs`'
    hook so that each "rows" event first logs the rows no sink has yet, whose list is `rows` (the folder's
    rows, which `run_epochs` extends); opening logs those of them a sink has not logged before."""

    def __init__(self, log, run, seeds, cfg, rows: list[dict]):
        self.names, self.rows, self.path = parse_log(log), rows, run.path / RECORD
        self.record = self._read() if self.names else {}
        self.logged = self.record.setdefault("logged_epoch", {})
        self.writers = {}
        try:
            for name in self.names:
                self.writers[name] = (_TensorBoard if name == "tensorboard" else _WandB)(run, seeds, cfg,
                                                                                          self.record)
        except BaseException:
            self.__exit__()
            raise
        if self.writers:
            atomic_write(self.path, json.dumps(self.record, indent=2, sort_keys=True) + "\n")
            self.write()

    def _read(self) -> dict:
        try:
            record = json.loads(self.path.read_text())
        except FileNotFoundError:
            return {}
        except (OSError, ValueError) as err:
            record = err
        if not isinstance(record, dict):
            raise ConfigError(f"{self.path} is not a loggers record ({record}). Delete it with "
                              f"{self.path.parent / 'tensorboard'} and {self.path.parent / 'wandb'} to log "
                              f"every row of metrics.jsonl again, into new runs")
        return record

    def write(self) -> None:
        """Log the rows of epochs after each sink's last logged one; then record the epoch."""
        changed = False
        for name, writer in self.writers.items():
            new = [r for r in self.rows if r["epoch"] > self.logged.get(name, -1)]
            if new:
                writer.write(new)
                self.logged[name] = max(r["epoch"] for r in new)
                changed = True
        if changed:
            atomic_write(self.path, json.dumps(self.record, indent=2, sort_keys=True) + "\n")

    def hook(self, hook):
        """`hook` with the sinks' logging before its "rows" events (`hook` itself if there are none)."""
        if not self.writers:
            return hook

        def logging_hook(event: str, epoch: int) -> None:
            if event == "rows":
                self.write()
            if hook is not None:
                hook(event, epoch)

        return logging_hook

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        for writer in self.writers.values():
            writer.close()


class _TensorBoard:
    """One event file per seed and session in RUN/tensorboard/seed<S>/ (TensorBoard's own writer)."""

    def __init__(self, run, seeds, cfg, record):
        from tensorboard.summary.writer.event_file_writer import EventFileWriter

        self.files = {s: EventFileWriter(str(run.path / "tensorboard" / f"seed{s}")) for s in seeds}

    def write(self, rows) -> None:
        from tensorboard.compat.proto import event_pb2, summary_pb2

        for r in rows:
            values = [summary_pb2.Summary.Value(tag=k, simple_value=v) for k, v in scalars(r).items()]
            self.files[r["seed"]].add_event(event_pb2.Event(wall_time=time.time(), step=r["env_steps"],
                                                            summary=summary_pb2.Summary(value=values)))
        for f in self.files.values():
            f.flush()

    def close(self) -> None:
        for f in self.files.values():
            f.close()


class _WandB:
    """One W&B run per seed, its id kept in the record; offline unless WANDB_MODE is set."""

    def __init__(self, run, seeds, cfg, record):
        import wandb

        ids = record.setdefault("wandb_ids", {})
        mode, project = os.environ.get("WANDB_MODE") or "offline", os.environ.get("WANDB_PROJECT", "sf2")
        self.runs = {}
        for s in seeds:
            ids.setdefault(str(s), secrets.token_hex(4))
            try:
                self.runs[s] = wandb.init(
                    dir=run.path, id=ids[str(s)], resume="allow", reinit="create_new", mode=mode,
                    project=project, group=str(run.path), name=f"{run.path.name} seed {s}",
                    config={**cfg.to_dict(), "seed": s}, settings=wandb.Settings(silent=True, console="off"))
            except Exception as err:   # a bad WANDB_MODE, online without a login, ...
                self.close()
                raise ConfigError(f"--log wandb: W&B cannot start the run of seed {s} with WANDB_MODE={mode} "
                                  f"({str(err).splitlines()[0]}); unset WANDB_MODE to log offline") from None

    def write(self, rows) -> None:
        for r in rows:
            self.runs[r["seed"]].log(scalars(r), step=r["env_steps"])

    def close(self) -> None:
        for r in self.runs.values():
            r.finish()
