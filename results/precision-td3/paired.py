"""Paired precision differences (TF32 − fp32, the same seed in both) of this study's report/results.csv:
the mean over seeds with a 95% percentile bootstrap interval (rliable, through
sf2_common.agents.stats.mean_interval). Run from the repository root:
    python results/precision-td3/paired.py
"""
import csv
from collections import defaultdict
from pathlib import Path

import numpy as np
from sf2_common.agents.stats import mean_interval

rows = list(csv.DictReader(open(Path(__file__).parent / "report" / "results.csv")))
value = defaultdict(dict)                       # (task, method) -> {seed: row}
for r in rows:
    value[r["task"], r["method"]][int(r["seed"])] = r
print("| task | method | AUC difference | final-return difference |")
print("|---|---|---|---|")
for task in sorted({r["task"] for r in rows}):
    for base in ("TD3", "TD3+SF²"):
        lo, hi = value[task, f"{base} (fp32)"], value[task, f"{base} (TF32)"]
        seeds = sorted(lo)
        assert seeds == sorted(hi), (task, base)
        cells = []
        for key in ("auc", "final_return"):
            d = np.array([float(hi[s][key]) - float(lo[s][key]) for s in seeds])
            m, a, b = (float(np.squeeze(x)) for x in mean_interval(d[:, None]))
            cells.append(f"{m:+.2f} [{a:+.2f}, {b:+.2f}]")
        print(f"| {task} | {base} | " + " | ".join(cells) + " |")
