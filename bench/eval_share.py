"""How much of a finished run's wall time its evaluations took, from its run folder alone.

    python -m bench.eval_share results/fig7-td3/runs/HopperHop/*/seeds-0-4 [--markdown]

Per run folder (metrics.jsonl of the first seed: every seed of a run shares one program and one clock):
the whole run's wall time (the last row's `walltime`, resumptions included), the evaluations after
epoch 0 (`eval_seconds` summed; with the batched evaluation each row holds its share of its batch's
time, so the sum is the batches' time), the training epochs (`epoch_seconds` summed), the evaluations'
share, and the run's env steps/s over all seeds. docs/physics.md "Evaluation latency" uses it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

FIELDS = ("run", "wall_s", "eval_s", "train_s", "eval_share", "env_steps_per_s")


def measure(folder: Path) -> dict:
    """The row of FIELDS for one finished run folder; a folder without metrics is an error naming it."""
    path = folder / "metrics.jsonl"
    if not path.is_file():
        raise SystemExit(f"error: {folder} holds no metrics.jsonl (not a run folder)")
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    if not rows:
        raise SystemExit(f"error: {path} is empty")
    seeds = sorted({r["seed"] for r in rows})
    first = [r for r in rows if r["seed"] == seeds[0]]
    wall = first[-1]["walltime"]
    evals = sum(r["eval_seconds"] for r in first if r["epoch"] >= 1)
    train = sum(r.get("epoch_seconds", 0.0) for r in first)
    return {"run": str(folder), "wall_s": round(wall, 1), "eval_s": round(evals, 1),
            "train_s": round(train, 1), "eval_share": round(evals / wall, 3),
            "env_steps_per_s": round(first[-1]["env_steps"] * len(seeds) / wall)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.eval_share", description=__doc__.split("\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="finished run folders")
    parser.add_argument("--markdown", action="store_true", help="a Markdown table instead of JSON lines")
    args = parser.parse_args(argv)
    rows = [measure(f) for f in args.folders]
    if args.markdown:
        print("| " + " | ".join(FIELDS) + " |\n|" + "---|" * len(FIELDS))
        for r in rows:
            print("| " + " | ".join(str(r[k]) for k in FIELDS) + " |")
    else:
        for r in rows:
            print(json.dumps(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
