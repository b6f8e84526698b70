"""Learning curves of one run folder (per-seed lines, mean and band) or several (a line and band per method
and task), and the final-return table. The band is the 95% percentile-bootstrap interval of the mean over
seeds (`stats.mean_interval`), none below `stats.MIN_SEEDS` seeds. matplotlib (Agg) is imported when
needed; a folder's method is the `label` in its config.json, so no framework is needed."""

from __future__ import annotations

import textwrap
from collections import defaultdict
from pathlib import Path

import numpy as np

from . import stats
from .configs import ADDED_FIELDS
from .runfolder import RunFolder

__all__ = ["method_label", "mean_ci", "band_label", "curves", "plot_learning_curve", "plot_runs",
           "final_table"]


def method_label(algo: str, representation: str, registry=None) -> str:
    """'TD3+SF²', 'SAC', ... (vanilla has no suffix). The representation's label comes from `registry`
    (the framework's `Registry`); without one, its name stands for it."""
    label = (registry.label(representation) if registry is not None
             else "" if representation == "none" else representation)
    return algo.upper() + (f"+{label}" if label else "")


def mean_ci(values, resamples: int = stats.RESAMPLES) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """values (n_seeds, n_points) → (mean over seeds, lower, upper) of the 95% interval of the mean;
    lower = upper = NaN below `stats.MIN_SEEDS` seeds."""
    mean, lo, hi = stats.mean_interval(np.asarray(values, dtype=float), resamples)
    if lo is None:
        lo = hi = np.full_like(mean, np.nan)
    return mean, lo, hi


def band_label(n_seeds: int) -> str:
    """What a band (or its absence) is, for legends and footnotes."""
    if not stats.informative(n_seeds):
        return f"no CI: n={n_seeds} < {stats.MIN_SEEDS} seeds is not informative"
    return f"95% bootstrap CI of the mean (n={n_seeds})"


def curves(rows: list[dict]) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """(env_steps per evaluation, {seed: eval returns}) over the epochs every seed has reached."""
    by_seed: dict[int, dict[int, dict]] = defaultdict(dict)
    for r in rows:
        by_seed[r["seed"]][r["epoch"]] = r
    if not by_seed:
        return np.zeros(0), {}
    epochs = sorted(set.intersection(*(set(d) for d in by_seed.values())))
    first = next(iter(by_seed.values()))
    steps = np.array([first[e]["env_steps"] for e in epochs])
    return steps, {s: np.array([d[e]["eval_return"] for e in epochs]) for s, d in sorted(by_seed.items())}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_learning_curve(rows: list[dict], path, title: str) -> None:
    """One run's learning_curve.png (per-seed lines, mean, band), written atomically; none without rows."""
    steps, per_seed = curves(rows)
    if not per_seed:
        return
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    for seed, ret in per_seed.items():
        ax.plot(steps, ret, lw=0.8, alpha=0.4, label=f"seed {seed}")
    mean, lo, hi = mean_ci(np.stack(list(per_seed.values())))
    n = len(per_seed)
    ax.plot(steps, mean, color="k", lw=2, label=f"mean over {n} seed{'s' if n > 1 else ''}")
    if not np.isnan(lo).all():
        ax.fill_between(steps, lo, hi, color="k", alpha=0.15, label=band_label(n))
    elif n > 1:
        ax.plot([], [], " ", label=band_label(n))
    _finish_axes(ax, list(per_seed.values()), title, fontsize=7)
    fig.tight_layout()
    tmp = Path(path).with_name(Path(path).stem + ".tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    tmp.replace(path)


def _finish_axes(ax, lines, title: str, fontsize: int) -> None:
    """Labels, grid, legend (`loc` named: matplotlib warns of its cost only when defaulted) and the y range
    of the plotted curves `lines` (a CI band of few seeds can be far wider than any curve)."""
    values = np.concatenate([np.ravel(x) for x in lines]) if lines else np.zeros(1)
    lo, hi = float(values.min()), float(values.max())
    pad = 0.08 * max(hi - lo, 1.0)
    ax.set_ylim(lo - pad, hi + pad)
    ax.set(xlabel="env steps", ylabel="eval return", title=title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=fontsize, loc="best")


def _load(run_dirs) -> dict[tuple[str, str], list[tuple[np.ndarray, dict]]]:
    """{(task, method label): [(steps, {seed: returns}), ...]} over run folders; folders of one label and
    task with different configs are different methods, named by what differs: "SAC (adam_eps=1e-05)"; a
    field a folder predates has the value its run trained with (`configs.ADDED_FIELDS`)."""
    found = defaultdict(list)
    for d in run_dirs:
        run = RunFolder(d)
        conf = run.read_config()
        if conf is None:
            raise FileNotFoundError(f"{d} is not a run folder (no {RunFolder.CONFIG})")
        c = {**ADDED_FIELDS, **conf["config"]}
        steps, per_seed = curves(run.read_rows(strict=True))   # a damaged file: RunFolderError
        if per_seed:
            label = conf.get("label") or method_label(c["algo"], c["representation"])
            found[(c["task"], label)].append((c, steps, per_seed))
    out = defaultdict(list)
    for (task, label), items in found.items():
        fields = sorted(set().union(*(c for c, _, _ in items)))
        differ = [f for f in fields if len({repr(c.get(f)) for c, _, _ in items}) > 1]
        for c, steps, per_seed in items:
            name = f"{label} ({', '.join(f'{f}={c.get(f)}' for f in differ)})" if differ else label
            out[(task, name)].append((steps, per_seed))
    return out


def _pool(entries) -> tuple[np.ndarray, np.ndarray]:
    """(common env steps, returns (seeds, points)) of several folders of one method; `ValueError` unless
    they share their evaluation points up to the earliest end (other budgets or num_evals)."""
    common = sorted(set.intersection(*(set(steps.tolist()) for steps, _ in entries)))
    ends = sorted({int(steps[-1]) for steps, _ in entries})
    if not common or common[-1] != ends[0]:
        raise ValueError(f"run folders of the same method and task do not share their evaluation points "
                         f"(they end at env steps {ends}); plot together only runs with the same "
                         f"num_timesteps, num_evals and num_envs")
    mats = []
    for steps, per_seed in entries:
        index = [steps.tolist().index(x) for x in common]
        mats += [ret[index] for ret in per_seed.values()]
    return np.asarray(common), np.stack(mats)


def plot_runs(run_dirs, path) -> list[dict]:
    """One panel per task, one mean line and 95% CI band per method. Returns `final_table(run_dirs)`."""
    data = _load(run_dirs)
    tasks = sorted({t for t, _ in data})
    plt = _plt()
    fig, axes = plt.subplots(1, max(len(tasks), 1), figsize=(5.5 * max(len(tasks), 1), 4), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        for (t, method), entries in sorted(data.items()):
            if t != task:
                continue
            steps, mat = _pool(entries)
            mean, lo, hi = mean_ci(mat)
            line, = ax.plot(steps, mean, lw=2, label=f"{method} (n={mat.shape[0]})")
            if not np.isnan(lo).all():
                ax.fill_between(steps, lo, hi, color=line.get_color(), alpha=0.2)
        mats = [_pool(e)[1] for (t, _), e in data.items() if t == task]
        _finish_axes(ax, [m.mean(axis=0) for m in mats] + [row for m in mats for row in m], task, fontsize=8)
    caption = ("line: mean eval return over seeds; band: 95% bootstrap CI of the mean (rliable, 5000 "
               "resamples), drawn only with >= 3 seeds")
    # wrapped to the figure's width (about 12 characters of 9-point text per inch), so one panel keeps it
    fig.suptitle(textwrap.fill(caption, width=int(12 * fig.get_figwidth())), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return final_table(run_dirs)


def final_table(run_dirs) -> list[dict]:
    """Per (task, method): seeds, env steps, final eval return (mean over seeds, its 95% interval
    `ci_low`/`ci_high`, NaN below 3 seeds, and each seed's)."""
    table = []
    for (task, method), entries in sorted(_load(run_dirs).items()):
        steps, mat = _pool(entries)
        mean, lo, hi = mean_ci(mat[:, -1:])
        table.append({"task": task, "method": method, "seeds": mat.shape[0], "env_steps": int(steps[-1]),
                      "final_return": float(mean[0]), "ci_low": float(lo[0]), "ci_high": float(hi[0]),
                      "per_seed": [float(x) for x in mat[:, -1]]})
    return table
