"""Sharded against one-device training, with one-device against one-device as the yardstick (this folder's
README). Reads the three run folders here; prints per run each seed's AUC and final return, then per pair
the difference of the mean over seeds with its 95% bootstrap interval (sf2_common.studies.stats, rliable).

    python bench/results/h100x4/41-sharded-learning/compare.py
"""
import gzip
import json
from pathlib import Path

import numpy as np
from sf2_common.studies import stats

HERE = Path(__file__).parent
RUNS = ("one-a", "one-b", "sharded")


def scores(run: str) -> dict[str, np.ndarray]:
    rows = [json.loads(line) for line in gzip.open(HERE / run / "metrics.jsonl.gz", "rt")]
    by_seed: dict[int, list] = {}
    for r in rows:
        by_seed.setdefault(r["seed"], []).append((r["env_steps"], r["eval_return"]))
    auc, final = [], []
    for seed in sorted(by_seed):
        steps, ret = zip(*sorted(by_seed[seed]), strict=True)
        auc.append(stats.auc(steps, ret))
        final.append(stats.final_window_mean(steps, ret, 50_000))
    return {"AUC": np.array(auc), "final (last 50k steps)": np.array(final)}


def main() -> None:
    s = {r: scores(r) for r in RUNS}
    for what in ("AUC", "final (last 50k steps)"):
        print(f"## {what}\n")
        for r in RUNS:
            m, lo, hi = (float(np.ravel(v)[0]) for v in stats.mean_interval(s[r][what]))
            print(f"- {r}: mean {m:.1f} [{lo:.1f}, {hi:.1f}]; seeds "
                  + ", ".join(f"{v:.1f}" for v in s[r][what]))
        print()
        for a, b in (("one-b", "one-a"), ("sharded", "one-a"), ("sharded", "one-b")):
            d, lo, hi = stats.difference_interval(s[a][what][:, None], s[b][what][:, None], "Mean")
            print(f"- {a} − {b}: {d:+.1f} [{lo:+.1f}, {hi:+.1f}]")
        print()


if __name__ == "__main__":
    main()
