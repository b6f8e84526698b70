"""The MinAtar sanity gate's table: this repository's PPO against pgx's own example, game by game.

    python -m bench.lab.minatar_gate results/minatar-sanity

Reads the study's run folders (`runs/minatar-<game>/<method>/metrics.jsonl.gz`: every method there, `METHODS`
first), the example's logs
`<study>/pgx-example/<game>-seed<N>.log` (one dict per update: `sec`, `<env>/eval_R`, `steps`) and its
`times.txt` (each process's wall time). Per game: each side's last evaluation per seed, its AUC, the gate
("our seeds' mean last evaluation within the example's seeds' range", docs/minatar.md), the difference of
the means with its 95% bootstrap interval (AUC and interval: `sf2_studies.stats`, the studies' own), and
wall time per seed: ours the run's last `walltime` (compile, training, evaluations) over its vmapped
seeds, the example's its process's. The example's own `sec` is no rate: it never waits for the device, so
the update's work lands in the evaluation it excludes. Ours also as training env steps/s (one update of
every seed over the median `epoch_seconds` after the first, which compiles); a run short of its last
epoch is marked unfinished. Prints a Markdown table, a row per game and method."""

from __future__ import annotations

import argparse
import ast
import gzip
import json
import statistics
from pathlib import Path

import numpy as np
from sf2_common.agents.configs import TrainConfig, schedule
from sf2_studies.stats import auc, difference_interval

GAMES = ["asterix", "breakout", "freeway", "seaquest", "space_invaders"]
# studies/minatar-sanity.toml's methods, in its order: pgx's settings; with pgx's shared torso and joint step
METHODS = ("ppo-pgx", "ppo-v-shared")


def methods(game_folder: Path) -> list[str]:
    """The methods with rows under one game's folder: `METHODS` in their order, then any other by name."""
    found = [p.name for p in game_folder.glob("*") if (p / "metrics.jsonl.gz").is_file()]
    return sorted(found, key=lambda name: (METHODS.index(name) if name in METHODS else len(METHODS), name))


def ours(run: Path) -> dict:
    """Last evaluations, AUCs and training rate of one vmapped run folder."""
    rows = [json.loads(line) for line in gzip.open(run / "metrics.jsonl.gz", "rt")]
    seeds = sorted({r["seed"] for r in rows})
    last, aucs = [], []
    for s in seeds:
        ev = [r for r in rows if r["seed"] == s and r.get("eval_return") is not None]
        last.append(ev[-1]["eval_return"])
        aucs.append(auc([r["env_steps"] for r in ev], [r["eval_return"] for r in ev]))
    first = [r for r in rows if r["seed"] == seeds[0] and r.get("epoch_seconds")]
    per_epoch = (first[-1]["env_steps"] - first[0]["env_steps"]) / (len(first) - 1)
    median = statistics.median(r["epoch_seconds"] for r in first[1:])   # epoch 1 compiles
    wall = max(r.get("walltime", 0.0) for r in rows)
    cfg = TrainConfig.from_dict(json.loads((run / "config.json").read_text())["config"])
    return {"last": last, "auc": aucs, "rate": per_epoch * len(seeds) / median, "wall": wall / len(seeds),
            "epoch": max(r["epoch"] for r in rows), "epochs": schedule(cfg).num_epochs}


def example(folder: Path, game: str) -> dict:
    """Last evaluations, AUCs and mean process wall time of the example's logs of one game (every seed)."""
    last, aucs = [], []
    for log in sorted(folder.glob(f"{game}-seed*.log")):
        rows = [ast.literal_eval(line) for line in log.read_text().splitlines() if line.startswith("{")]
        returns = [r[f"minatar-{game}/eval_R"] for r in rows]
        last.append(returns[-1])
        aucs.append(auc([r["steps"] for r in rows], returns))
    lines = (folder / "times.txt").read_text().splitlines()
    walls = [float(line.split(" wall ")[1].split()[0]) for line in lines
             if line.startswith(f"{game} seed ") and " rc 0 " in line]
    return {"last": last, "auc": aucs, "wall": statistics.mean(walls)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study", type=Path, help="the minatar-sanity study folder")
    args = parser.parse_args(argv)
    print("| game | method | ours: last evaluation per seed (mean) | pgx example: per seed [range] | gate | "
          "Δ mean [95% CI] | AUC ours / example (mean) | wall time per seed: ours / example | "
          "ours: training env steps/s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for game in GAMES:
        found = methods(args.study / "runs" / f"minatar-{game}")
        b = example(args.study / "pgx-example", game) if found else None
        for method in found:
            _row(game, method, ours(args.study / "runs" / f"minatar-{game}" / method), b)
    return 0


def _row(game: str, method: str, a: dict, b: dict) -> None:
    """One game's row of one method: `ours` of its run folder `a`, `example` of the game `b`."""
    mean = statistics.mean(a["last"])
    lo, hi = min(b["last"]), max(b["last"])
    gate = "within" if lo <= mean <= hi else ("above" if mean > hi else "below")
    if a["epoch"] < a["epochs"]:
        gate += f" (unfinished: epoch {a['epoch']} of {a['epochs']})"
    point, low, high = difference_interval(np.asarray(a["last"])[:, None], np.asarray(b["last"])[:, None],
                                           "Mean")
    interval = "too few seeds" if low is None else f"{low:+.1f}, {high:+.1f}"
    print(f"| {game} | {method} | {', '.join(f'{x:.1f}' for x in a['last'])} ({mean:.1f}) | "
          f"{', '.join(f'{x:.1f}' for x in b['last'])} [{lo:.1f}, {hi:.1f}] | {gate} | "
          f"{point:+.1f} [{interval}] | "
          f"{statistics.mean(a['auc']):.1f} / {statistics.mean(b['auc']):.1f} | "
          f"{a['wall']:.0f} s / {b['wall']:.0f} s | {a['rate'] / 1e6:.2f}M |")


if __name__ == "__main__":
    raise SystemExit(main())
