"""How much of a finished run's wall time its evaluations took, from its run folder alone.

    python -m bench.lab.eval_share results/fig7-td3/runs/HopperHop/*/seeds-0-4 [--markdown] [--epochs A-B]

Per run folder (metrics.jsonl of the first seed: the seeds of a run share one program and one clock): the
whole run's wall time, the evaluations after epoch 0 (`eval_seconds` summed), the training epochs
(`epoch_seconds` summed), the evaluations' share, env steps/s over all seeds, the seeds, the GPU
(config.json's "hardware"), how many times `train` started in the folder (train.log), and `save_wait_s`,
the seconds train.log says the run waited for checkpoint writes (a lower bound: Orbax logs waits over 1 s
only). `--epochs A-B`: the same over epochs A+1..B only, the rate of a stretch of a run."""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from sf2_common.agents.runfolder import RunFolder, RunFolderError
from sf2_common.fileio import read_text, stored

from bench.report import print_rows

FIELDS = ("run", "epochs", "wall_s", "eval_s", "train_s", "eval_share", "env_steps_per_s", "seeds",
          "hardware", "starts", "save_wait_s")
_SAVE_WAIT = re.compile(r"Waiting for previous save to complete took ([0-9.]+) seconds")


def measure(folder: Path, span: tuple[int, int] | None = None) -> dict:
    """The row of FIELDS for one run folder, whole (finished) or over the epochs `span` = (A, B); a folder
    without metrics, or without the span's epochs, is an error naming it."""
    path = stored(folder / "metrics.jsonl")   # a study folder in results/ keeps it as metrics.jsonl.gz
    if path is None:
        raise SystemExit(f"error: {folder} holds no metrics.jsonl (not a run folder)")
    rows = [json.loads(line) for line in read_text(path).splitlines() if line.strip()]
    if not rows:
        raise SystemExit(f"error: {path} is empty")
    seeds = sorted({r["seed"] for r in rows})
    first = {r["epoch"]: r for r in rows if r["seed"] == seeds[0]}
    a, b = span if span is not None else (0, max(first))
    if a not in first or b not in first:
        raise SystemExit(f"error: {path} has epochs {min(first)}-{max(first)}, not {a} and {b}")
    start = first[a] if span is not None else {"walltime": 0.0, "env_steps": 0}   # a whole run: from launch
    inside = [first[e] for e in range(a + 1, b + 1) if e in first]   # epoch 0 evaluates, trains none
    wall = first[b]["walltime"] - start["walltime"]
    evals = sum(r["eval_seconds"] for r in inside)
    train = sum(r.get("epoch_seconds", 0.0) for r in inside)
    steps = first[b]["env_steps"] - start["env_steps"]
    return {"run": str(folder), "epochs": f"{a}-{b}", "wall_s": round(wall, 1), "eval_s": round(evals, 1),
            "train_s": round(train, 1), "eval_share": round(evals / wall, 3),
            "env_steps_per_s": round(steps * len(seeds) / wall), "seeds": len(seeds),
            "hardware": _hardware(folder), "starts": _starts(folder),
            "save_wait_s": None if span is not None else _save_waits(folder)}


def _hardware(folder: Path) -> str:
    try:
        conf = RunFolder(folder).read_config() or {}
    except RunFolderError as err:
        raise SystemExit(f"error: {err}") from None
    return conf.get("hardware") or "not recorded"


def _log(folder: Path) -> str | None:
    path = stored(RunFolder(folder).log_path)
    return None if path is None else read_text(path)


def _starts(folder: Path) -> int | None:
    """How many `train` processes train.log records (the runner writes a `$ python -m … train …` line
    before each), None without a train.log."""
    text = _log(folder)
    if text is None:
        return None
    return sum(1 for line in text.splitlines() if line.startswith("$ python -m ") and " train " in line)


def _save_waits(folder: Path) -> float | None:
    """The checkpoint waits train.log records, summed (module docstring), None without a train.log."""
    text = _log(folder)
    return None if text is None else round(sum(float(x) for x in _SAVE_WAIT.findall(text)), 1)


def _span(text: str) -> tuple[int, int]:
    try:
        a, b = (int(x) for x in text.split("-"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: A-B, two epochs, A < B (e.g. 40-99)") from None
    if not 0 <= a < b:
        raise argparse.ArgumentTypeError(f"{text!r}: A-B with 0 <= A < B (e.g. 40-99)")
    return a, b


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.lab.eval_share",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="finished run folders")
    parser.add_argument("--epochs", type=_span, default=None, metavar="A-B",
                        help="only epochs A+1..B (the wall time between epoch A's and epoch B's rows)")
    parser.add_argument("--markdown", action="store_true", help="a Markdown table instead of JSON lines")
    args = parser.parse_args(argv)
    rows = [measure(f, args.epochs) for f in args.folders]
    print_rows(rows, FIELDS, args.markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
