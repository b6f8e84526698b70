"""The report's figures, each written as PNG and SVG: the aggregate interval plot (paper Fig. 1 and 7), the
per-task learning curves (Fig. 6 and 8), the hyperparameter sweeps (Fig. 2 a/b/d) and the observation-noise
plot (Fig. 9 right). Every band and bar says what it is; where a method has fewer than `stats.MIN_SEEDS`
seeds no interval is drawn and the legend says so. The numbers come from `report` (rliable); this module
only draws. matplotlib is imported lazily with the Agg backend."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import stats
from .spec import kind

__all__ = ["aggregate", "learning_curves", "sweeps", "obs_noise", "grid", "seeds_title"]

_CI = f"95% bootstrap CI ({stats.RESAMPLES} resamples)"


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _kind(label: str) -> str:
    """The method without its family (`spec.kind`: 'TD3+SF² (γ=0)' → 'SF² (γ=0)'), so both families share
    colors."""
    family = next((f for f in ("TD3", "SAC") if label.startswith(f)), "")
    return kind(label, family)


class _Colors:
    """One color per method kind (both families share it), or with `by_label` per whole label (for a panel
    that holds both families' lines)."""

    def __init__(self, by_label: bool = False):
        self.map: dict[str, tuple] = {}
        self.cycle = list(_plt().get_cmap("tab10").colors)
        self.by_label = by_label

    def __call__(self, label: str):
        k = label if self.by_label else _kind(label)
        if k not in self.map:
            self.map[k] = self.cycle[len(self.map) % len(self.cycle)]
        return self.map[k]


def _save(fig, stem: Path) -> dict[str, Path]:
    """`stem`.png and `stem`.svg. The SVG is the same bytes for the same figure (no date, clip-path ids from
    a fixed salt), so a report made again from unchanged runs changes no file in the repository."""
    import matplotlib

    plt = _plt()
    out = {}
    for ext in ("png", "svg"):
        path = stem.with_suffix(f".{ext}")
        fixed = {"metadata": {"Date": None}} if ext == "svg" else {}
        with matplotlib.rc_context({"svg.hashsalt": "sf2"}):
            fig.savefig(path, dpi=150, bbox_inches="tight", **fixed)
        out[path.name] = path
    plt.close(fig)
    return out


def _steps_formatter():
    """Env-step ticks as 200k, 1M, ..."""
    from matplotlib.ticker import EngFormatter

    return EngFormatter(sep="")


def _tasks_over(study, counts: set[int]) -> str:
    """'4 task(s)', or for an interim report '1 of 4 tasks (interim: summary.md says which)': the number of
    tasks the families' aggregates cover (`counts`, one per family)."""
    over = (f"{min(counts)}" if len(counts) == 1 else "–".join(map(str, (min(counts), max(counts)))))
    return over + (" task(s)" if over == str(len(study.tasks)) else
                   f" of {len(study.tasks)} tasks (interim: summary.md says which)")


def _dodge(xs: np.ndarray, j: int, m: int, log: bool) -> np.ndarray:
    """Series j of m drawn at shared x values, shifted apart by 2.5% of the x span per series (of its
    decades on a log axis) so that their error bars do not overlap."""
    if m == 1 or len(xs) == 0:
        return xs
    shift = (j - (m - 1) / 2) * 0.025
    if log:
        return xs * 10 ** (shift * max(np.log10(xs.max() / xs.min()), 1.0))
    return xs + shift * (float(xs.max() - xs.min()) or 1.0)


def _seed_note(ns) -> str:
    few = sorted({n for n in ns if not stats.informative(n)})
    return (f"; no interval where n < {stats.MIN_SEEDS} seeds (not informative)" if few else "")


# ------------------------------------------------------------------------------------------- Fig. 1 / 7
def aggregate(table: dict, stem: Path, study, covers: dict | None = None) -> dict[str, Path]:
    """table: {family: [(label, n_seeds, points (4,), intervals (2, 4) or None)]} → one row of four panels
    (median, IQM, mean, optimality gap) per family; `covers` ({family: report.Coverage}): the tasks each
    family's aggregate covers (default: every task of the study)."""
    plt = _plt()
    colors = _Colors()
    families = list(table)
    rows = max(len(v) for v in table.values())
    fig, axes = plt.subplots(len(families), 4, squeeze=False,
                             figsize=(13, 0.9 + 0.42 * rows * len(families) + 0.5 * len(families)))
    for r, family in enumerate(families):
        entries = table[family]
        for c, metric in enumerate(stats.METRICS):
            ax = axes[r][c]
            for y, (label, _, p, ci) in enumerate(entries):
                color = colors(label)
                if ci is not None:
                    ax.barh(y, ci[1][c] - ci[0][c], left=ci[0][c], height=0.6, color=color, alpha=0.75)
                    ax.vlines(p[c], y - 0.3, y + 0.3, color="k", lw=1.5)
                else:
                    ax.plot([p[c]], [y], marker="|", ms=14, mew=2, color=color)
            ax.set_yticks(range(len(entries)))
            ax.set_yticklabels([e[0] for e in entries] if c == 0 else [])
            ax.set_ylim(-0.6, len(entries) - 0.4)
            ax.invert_yaxis()
            ax.grid(True, axis="x", alpha=0.3)
            for side in ("top", "right", "left"):
                ax.spines[side].set_visible(False)
            ax.tick_params(axis="y", length=0)
            ax.set_title(metric + (" (lower is better)" if metric == "Optimality Gap" else ""), fontsize=10)
            if c == 0:   # the family names its row once, left of the methods (a long name fits there)
                ax.set_ylabel(family, fontsize=11, fontweight="bold")
            if r == len(families) - 1:
                ax.set_xlabel("normalized AUC" if metric != "Optimality Gap" else "1 − mean normalized AUC")
    ns = [n for v in table.values() for _, n, _, _ in v]
    over = _tasks_over(study, {len(covers[f].tasks) for f in table} if covers else {len(study.tasks)})
    fig.suptitle(f"{study.name}: aggregate normalized AUC over {over}, "
                 + (f"{max(ns)} seeds per task" if min(ns) == max(ns) else
                    f"{min(ns)}–{max(ns)} seeds per task (unequal: see summary.md)")
                 + f"\nbar: {_CI}, stratified over tasks; tick: point estimate"
                 + _seed_note(ns), fontsize=10)
    fig.tight_layout()
    return _save(fig, stem)


# ------------------------------------------------------------------------------------------- Fig. 6 / 8
CURVE_COLUMNS = 4   # panels per row of the learning curves: seven tasks take two rows, not one 27-inch row


def grid(n_panels: int, columns: int = CURVE_COLUMNS) -> tuple[int, int]:
    """(rows, columns) of a family's panels: at most `columns` per row, as few rows as hold them."""
    cols = max(1, min(columns, n_panels))
    return -(-n_panels // cols), cols


def seeds_title(counts: dict[str, int]) -> str:
    """A panel's seed counts, {method label: seeds}: 'n=15' where every method has the same, else the count
    most methods have and the others by name, 'n=15 (TD3+SPR: 5)'."""
    if not counts:
        return ""
    values = list(counts.values())
    common = max(sorted(set(values), reverse=True), key=values.count)
    others = ", ".join(f"{label}: {n}" for label, n in counts.items() if n != common)
    return f"n={common}" + (f" ({others})" if others else "")


def learning_curves(study, data: list, stem: Path) -> dict[str, Path]:
    """data: finished `report.RunData`; one panel per (family, task), `CURVE_COLUMNS` to a row: per method
    the mean (or, with the study's `[report] curve_statistic = "median"`, the median: paper Fig. 8) eval
    return over seeds and its 95% bootstrap band, point by point. The legend names each
    method once per family (one color per method across tasks and families); each panel's title gives its
    seed counts (`seeds_title`), which may differ between tasks while a study is in progress."""
    plt = _plt()
    colors = _Colors()
    families = list(dict.fromkeys(d.method.family for d in data))
    tasks = [t for t in study.tasks if any(d.task == t for d in data)]
    rows, cols = grid(len(tasks))
    fig, axes = plt.subplots(rows * len(families), cols, squeeze=False,
                             figsize=(3.6 * cols + 2.4, 2.9 * rows * len(families)))
    ns = []
    statistic = study.report.curve_statistic
    for f, family in enumerate(families):
        panels = [axes[f * rows + i // cols][i % cols] for i in range(rows * cols)]
        handles: dict[str, object] = {}
        for i, task in enumerate(tasks):
            ax, counts = panels[i], {}
            for d in (d for d in data if d.task == task and d.method.family == family):
                mat = d.matrix()
                center, lo, hi = stats.column_interval(mat, statistic)
                ns.append(mat.shape[0])
                counts[d.method.label] = mat.shape[0]
                color = colors(d.method.label)
                (line,) = ax.plot(d.steps, center, color=color, lw=1.6)
                handles.setdefault(d.method.label, line)
                if lo is not None:
                    ax.fill_between(d.steps, lo, hi, color=color, alpha=0.2, lw=0)
            ax.set_title(f"{task} · {family}" + (f" · {seeds_title(counts)}" if counts else ""), fontsize=9)
            ax.grid(alpha=0.3)
            ax.xaxis.set_major_formatter(_steps_formatter())
            if i + cols >= len(tasks):   # nothing below it in this family
                ax.set_xlabel("env steps")
            if i % cols == 0:
                ax.set_ylabel("eval return")
        for ax in panels[len(tasks):]:
            ax.axis("off")
        spare = panels[len(tasks):]   # the legend in the first empty panel, else right of the top row
        where = (dict(loc="center left", bbox_to_anchor=(0.0, 0.5)) if spare else
                 dict(loc="upper left", bbox_to_anchor=(1.02, 1.0)))
        (spare[0] if spare else panels[cols - 1]).legend(list(handles.values()), list(handles), fontsize=8,
                                                         frameon=False, **where)
    fig.suptitle(f"{study.name}: learning curves (n = seeds)\nline: {statistic} eval return over seeds; "
                 f"band: {_CI} of the {statistic} at each evaluation" + _seed_note(ns), fontsize=10)
    fig.tight_layout()
    return _save(fig, stem)


# ------------------------------------------------------------------------------------------- Fig. 2
def sweeps(study, points: dict, stem: Path, tasks: set[int] | None = None) -> dict[str, Path]:
    """points: {field: {base label: [(text, value, n, score, lo, hi)]}} → one panel per swept field (the
    score `study.report.sweep_score`'s: `report.sweep_points`); each base label its own color and marker,
    the lines shifted apart a little along x (`_dodge`). `tasks`: the number of tasks each family's IQM
    covers (`report.Coverage`; default every task of the study), named in the title when fewer."""
    plt = _plt()
    colors = _Colors(by_label=True)
    markers = "osD^v<>"
    titles = dict(study.report.sweeps)
    fields = list(points)
    fig, axes = plt.subplots(1, len(fields), squeeze=False, figsize=(4.4 * len(fields), 3.6))
    ns = []
    for ax, field in zip(axes[0], fields):
        numeric = all(isinstance(v, float) for entries in points[field].values() for _, v, *_ in entries)
        values = [v for entries in points[field].values() for _, v, *_ in entries]
        log = numeric and min(values) > 0 and max(values) / min(values) >= 10
        for j, (base, entries) in enumerate(points[field].items()):
            entries = sorted(entries, key=lambda e: e[1]) if numeric else entries
            ticks = np.array([e[1] if numeric else i for i, e in enumerate(entries)], dtype=float)
            xs = _dodge(ticks, j, len(points[field]), log)
            means = np.array([e[3] for e in entries])
            ns += [e[2] for e in entries]
            color = colors(base)
            ax.plot(xs, means, marker=markers[j % len(markers)], color=color,
                    label=f"{base} (n={max(e[2] for e in entries)})")
            have = [i for i, e in enumerate(entries) if e[4] is not None]
            if have:
                lo = means[have] - np.array([entries[i][4] for i in have])
                hi = np.array([entries[i][5] for i in have]) - means[have]
                ax.errorbar(xs[have], means[have], yerr=[lo, hi], fmt="none", ecolor=color, capsize=3)
            if not numeric:
                ax.set_xticks(ticks)
                ax.set_xticklabels([e[0] for e in entries])
        if log:
            ax.set_xscale("log")
        if numeric:
            ax.set_xticks(sorted(set(values)))
            ax.set_xticklabels([f"{v:g}" for v in sorted(set(values))])
            ax.minorticks_off()
        ax.set_title(titles.get(field, field), fontsize=10)
        ax.set_xlabel(field)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")   # named: matplotlib warns of its cost only when defaulted
    if study.report.sweep_score == "iqm_auc":
        over = _tasks_over(study, tasks or {len(study.tasks)})
        axes[0][0].set_ylabel(f"IQM of normalized AUC over {over.split(' (')[0]}")
        fig.suptitle(f"{study.name}: IQM over {over} and seeds\nerror bar: {_CI}, stratified over tasks"
                     + _seed_note(ns), fontsize=10)
    else:
        axes[0][0].set_ylabel(f"mean eval return, final {study.report.final_window:,} env steps")
        fig.suptitle(f"{study.name}: mean over seeds; error bar: {_CI} of the mean" + _seed_note(ns),
                     fontsize=10)
    fig.tight_layout()
    return _save(fig, stem)


# ------------------------------------------------------------------------------------------- Fig. 9 right
def obs_noise(study, points: dict, stem: Path) -> dict[str, Path]:
    """points: {family: {label: [(noise, n, iqm, lo, hi)]}} → one panel per family."""
    plt = _plt()
    colors = _Colors()
    families = list(points)
    fig, axes = plt.subplots(1, len(families), squeeze=False, figsize=(5.2 * len(families), 3.8),
                             sharey=True)
    ns = []
    for ax, family in zip(axes[0], families):
        for label, entries in points[family].items():
            entries = sorted(entries)
            x = np.array([e[0] for e in entries])
            y = np.array([e[2] for e in entries])
            ns += [e[1] for e in entries]
            color = colors(label)
            ax.plot(x, y, marker="o", color=color, label=f"{label} (n={max(e[1] for e in entries)})")
            if all(e[3] is not None for e in entries):
                ax.fill_between(x, [e[3] for e in entries], [e[4] for e in entries], color=color, alpha=0.2,
                                lw=0)
        ax.set_title(family)
        ax.set_xlabel("observation noise std (Gaussian, added to the observations)")
        ax.grid(alpha=0.3)
    checkpoints = study.evaluation.checkpoints
    axes[0][0].set_ylabel(f"IQM over seeds of the AUC\nover {checkpoints} checkpoint(s)")
    fig.suptitle(f"{study.name}: band: {_CI} of the IQM" + _seed_note(ns), fontsize=10)
    fig.tight_layout()
    # Legends below the panels, placed after the layout (the saved image grows to hold them): six curves
    # and their bands fill a panel, and a legend inside would cover some of them.
    for ax in axes[0]:
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, frameon=False)
    return _save(fig, stem)
