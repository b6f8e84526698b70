"""`study report DIR`: a study folder's numbers (paper §4.2, Appendix C) as DIR/report/results.csv,
summary.md and figures (`figures.py`). Framework-free: it reads the study file's copy, study.json and the
run folders' config.json, metrics.jsonl and obs_noise.json. Only finished runs (every seed evaluated after
the last epoch) enter the numbers; the others are listed as incomplete.

Per run and seed (results.csv): AUC of the evaluation-return curve (`stats.auc`: return units), AUC
normalized per task by the min and max over every finished run and seed of the study on that task, the
final evaluation return, the mean return over the final `final_window` env steps, env steps, wall time
(the run's: its seeds train in one program). Per family (TD3, SAC) and method: median, IQM, mean and
optimality gap of the normalized AUCs with 95% stratified-bootstrap intervals (`stats.aggregate_intervals`).
"""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np

from sf2_common.agents.plotting import curves
from sf2_common.agents.runfolder import RunFolder

from . import stats
from .folder import OBS_NOISE, StudyFolder
from .spec import Method, Study

__all__ = ["RunData", "collect", "report", "results_rows", "CSV_FIELDS"]

CSV_FIELDS = ("task", "method", "family", "seed", "auc", "normalized_auc", "final_return",
              "final_window_return", "env_steps", "wall_time_s")


@dataclasses.dataclass
class RunData:
    task: str
    method: Method
    path: Path
    finished: bool
    progress: str                     # "epoch 3 of 5" for an incomplete run
    steps: np.ndarray                 # env steps of the evaluations every seed has
    returns: dict[int, np.ndarray]    # seed → eval returns at `steps`
    wall_time: float
    obs_noise: list[dict] | None      # obs_noise.json's results

    def seeds(self) -> list[int]:
        return sorted(self.returns)

    def matrix(self) -> np.ndarray:
        """(n_seeds, n_evaluations) eval returns."""
        return np.stack([self.returns[s] for s in self.seeds()])


def collect(study: Study, folder: StudyFolder) -> list[RunData]:
    """Every (task, method) of the study with what its run folder holds (task-major, file order)."""
    paths = folder.method_folders(study)
    out = []
    for task in study.tasks:
        for m in study.methods:
            path = paths[(task, m.name)]
            run = RunFolder(path)
            conf = run.read_config() or {}
            rows = run.read_rows()
            epochs = (conf.get("schedule") or {}).get("num_epochs")
            steps, per_seed = curves(rows)
            last = {s: max((r["epoch"] for r in rows if r["seed"] == s), default=-1) for s in study.seeds}
            finished = bool(conf) and epochs is not None and all(e == epochs for e in last.values())
            progress = "not started" if not conf else f"epoch {min(last.values())} of {epochs}"
            noise = None
            if (path / OBS_NOISE).exists():
                noise = json.loads((path / OBS_NOISE).read_text()).get("results")
            out.append(RunData(task, m, path, finished, progress, steps, per_seed,
                               max((r.get("walltime", 0.0) for r in rows), default=0.0), noise))
    return out


def results_rows(study: Study, data: list[RunData]) -> list[dict]:
    """One row per finished run and seed (`CSV_FIELDS`)."""
    window = study.report.final_window
    raw = {}
    for d in data:
        if d.finished:
            raw.setdefault(d.task, {})[d.method.name] = np.array([stats.auc(d.steps, d.returns[s])
                                                                  for s in d.seeds()])
    norm = stats.normalize_by_task(raw)
    rows = []
    for d in data:
        if not d.finished:
            continue
        for i, s in enumerate(d.seeds()):
            ret = d.returns[s]
            rows.append({"task": d.task, "method": d.method.label, "family": d.method.family, "seed": s,
                         "auc": float(raw[d.task][d.method.name][i]),
                         "normalized_auc": float(norm[d.task][d.method.name][i]),
                         "final_return": float(ret[-1]),
                         "final_window_return": stats.final_window_mean(d.steps, ret, window),
                         "env_steps": int(d.steps[-1]), "wall_time_s": round(d.wall_time, 1)})
    return rows


# ------------------------------------------------------------------------------------------- tables
def _fmt(x: float) -> str:
    return f"{x:.3f}" if abs(x) < 10 else f"{x:.1f}"


def _with_ci(point, lo, hi) -> str:
    if lo is None:
        return f"{_fmt(point)} (n < {stats.MIN_SEEDS}: no CI)"
    return f"{_fmt(point)} [{_fmt(lo)}, {_fmt(hi)}]"


def _families(study: Study) -> list[str]:
    return list(dict.fromkeys(m.family for m in study.methods))


def aggregate_table(study: Study, rows: list[dict]):
    """{family: [(method label, n_seeds, points (4,), intervals (2, 4) or None)]}, and the labels left out
    because a task is missing. Methods need a finished run on every task of the study."""
    out, missing = {}, []
    for family in _families(study):
        scores = {}
        for m in (m for m in study.methods if m.family == family):
            by_task = [[r["normalized_auc"] for r in rows if r["method"] == m.label and r["task"] == t]
                       for t in study.tasks]
            if any(not x for x in by_task):
                missing.append(m.label)
                continue
            scores[m.label] = np.array(by_task).T      # (n_seeds, n_tasks)
        if not scores:
            continue
        points, intervals = stats.aggregate_intervals(scores)
        out[family] = [(label, scores[label].shape[0], points[label], intervals[label]) for label in scores]
    return out, missing


def _md_per_task(study: Study, data: list[RunData], rows: list[dict]) -> list[str]:
    lines = ["| task | method | seeds | AUC: mean [95% CI] | normalized AUC: mean | final return: mean "
             "[95% CI] | env steps | wall time |", "|---|---|---|---|---|---|---|---|"]
    for d in data:
        if not d.finished:
            continue
        mine = [r for r in rows if r["task"] == d.task and r["method"] == d.method.label]
        auc = stats.mean_interval([r["auc"] for r in mine])
        fin = stats.mean_interval([r["final_return"] for r in mine])
        norm = np.mean([r["normalized_auc"] for r in mine])
        lines.append(f"| {d.task} | {d.method.label} | {len(mine)} | {_with_ci(auc[0][0], *_lohi(auc))} | "
                     f"{norm:.3f} | {_with_ci(fin[0][0], *_lohi(fin))} | {int(d.steps[-1]):,} | "
                     f"{_duration(d.wall_time)} |")
    return lines


def _lohi(res):
    _, lo, hi = res
    return (None, None) if lo is None else (lo[0], hi[0])


def _duration(s: float) -> str:
    from .progress import duration

    return duration(s)


def sweep_points(study: Study, rows: list[dict]):
    """{sweep field: {base label: [(value text, value, seeds, mean, lo, hi)]}} of the final-window
    return (paper Fig. 2 a/b/d)."""
    out = {}
    for m in study.methods:
        if m.sweep is None:
            continue
        field, text, base = m.sweep
        vals = [r["final_window_return"] for r in rows if r["method"] == m.label]
        if not vals:
            continue
        mean, lo, hi = stats.mean_interval(vals)
        out.setdefault(field, {}).setdefault(base, []).append(
            (text, _number(text), len(vals), float(mean[0]), None if lo is None else float(lo[0]),
             None if hi is None else float(hi[0])))
    return out


def _number(text: str):
    try:
        return float(text)
    except ValueError:
        return text


def obs_noise_points(study: Study, data: list[RunData]):
    """{family: {method label: [(noise, seeds, IQM, lo, hi)]}}: per seed the AUC of the return over the
    evaluated checkpoints (`stats.auc` over their env steps) at each noise level, then the IQM over seeds
    with its 95% bootstrap interval (paper App. C.2.2, Fig. 9 right)."""
    out = {}
    for d in data:
        if not d.obs_noise:
            continue
        for noise in sorted({r["noise"] for r in d.obs_noise}):
            at = sorted((r for r in d.obs_noise if r["noise"] == noise), key=lambda r: r["env_steps"])
            seeds = sorted(at[0]["returns"], key=int)
            aucs = [stats.auc([r["env_steps"] for r in at], [np.mean(r["returns"][s]) for r in at])
                    for s in seeds]
            iqm, lo, hi = stats.iqm_interval(aucs)
            out.setdefault(d.method.family, {}).setdefault(f"{d.method.label}" + (
                f" · {d.task}" if len(study.tasks) > 1 else ""), []).append(
                (noise, len(seeds), float(iqm[0]), None if lo is None else float(lo[0]),
                 None if hi is None else float(hi[0])))
    return out


# ------------------------------------------------------------------------------------------- report
def report(path, out=None, command: str | None = None) -> dict[str, Path]:
    """Write results.csv, summary.md and the study's figures into `out` (default DIR/report); returns
    {name: path} of what was written."""
    from . import figures

    folder = StudyFolder(path)
    study = folder.load_study()
    out = Path(out) if out is not None else folder.path / StudyFolder.REPORT
    out.mkdir(parents=True, exist_ok=True)
    data = collect(study, folder)
    rows = results_rows(study, data)
    written = {}

    with open(out / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        w.writeheader()
        w.writerows(rows)
    written["results.csv"] = out / "results.csv"

    finished = [d for d in data if d.finished]
    md = [f"# Study `{study.name}`", ""]
    if study.description:
        md += [study.description, ""]
    md += _md_commands(folder, command)
    md += [f"Runs: {sum(d.finished for d in data)} of {len(data)} (task, method) pairs finished; seeds "
           f"{', '.join(map(str, study.seeds))}; preset `{study.preset}`.", ""]
    md += _md_definitions(study)

    figs = study.report.figures
    if "aggregate" in figs:
        table, missing = aggregate_table(study, rows)
        md += ["## Aggregate normalized AUC per family (paper Fig. 1 / 7)", ""]
        md += _md_aggregate(table, len(study.tasks))
        if missing:
            md += [f"Not in the aggregate (a task without a finished run): {', '.join(missing)}.", ""]
        if table:
            written.update(figures.aggregate(table, out / "aggregate", study))
            md += ["![aggregate](aggregate.png)", ""]
    md += ["## Per task", ""] + _md_per_task(study, data, rows) + [""]
    if "curves" in figs and finished:
        written.update(figures.learning_curves(study, finished, out / "curves"))
        md += ["![learning curves](curves.png)", ""]
    if "sweeps" in figs:
        points = sweep_points(study, rows)
        md += [f"## Sweeps: mean return over the final {study.report.final_window:,} env steps "
               f"(paper Fig. 2 a/b/d)", "", "| sweep | method | value | seeds | mean [95% CI] |",
               "|---|---|---|---|---|"]
        titles = dict(study.report.sweeps)
        for field, by_base in points.items():
            for base, entries in by_base.items():
                for text, _, n, mean, lo, hi in entries:
                    md.append(f"| {titles.get(field, field)} | {base} | {text} | {n} | "
                              f"{_with_ci(mean, lo, hi)} |")
        md.append("")
        if points:
            written.update(figures.sweeps(study, points, out / "sweeps"))
            md += ["![sweeps](sweeps.png)", ""]
    if "obs_noise" in figs:
        points = obs_noise_points(study, data)
        md += ["## Observation noise: IQM over seeds of the AUC over the evaluated checkpoints "
               "(paper App. C.2.2, Fig. 9 right)", "", "| method | noise std | seeds | IQM [95% CI] |",
               "|---|---|---|---|"]
        for by_method in points.values():
            for label, entries in by_method.items():
                for noise, n, iqm, lo, hi in entries:
                    md.append(f"| {label} | {noise:g} | {n} | {_with_ci(iqm, lo, hi)} |")
        md.append("")
        if points:
            written.update(figures.obs_noise(study, points, out / "obs_noise"))
            md += ["![observation noise](obs_noise.png)", ""]
    incomplete = [d for d in data if not d.finished]
    if incomplete:
        md += ["## Incomplete runs (not in the numbers above)", ""]
        md += [f"- {d.task} / {d.method.label}: {d.progress} (`{d.path}`)" for d in incomplete]
        md.append("")
    (out / "summary.md").write_text("\n".join(md))
    written["summary.md"] = out / "summary.md"
    return written


def _md_aggregate(table, n_tasks: int) -> list[str]:
    lines = []
    for family, entries in table.items():
        lines += [f"### {family}", "", "| method | seeds × tasks | " + " | ".join(stats.METRICS) + " |",
                  "|---|---|" + "---|" * len(stats.METRICS)]
        for label, n, p, ci in entries:
            cells = [_with_ci(p[k], None if ci is None else ci[0][k], None if ci is None else ci[1][k])
                     for k in range(len(stats.METRICS))]
            lines.append(f"| {label} | {n} × {n_tasks} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def _md_commands(folder: StudyFolder, command: str | None) -> list[str]:
    state = folder.read_state()
    lines = ["Commands:", "", "```"]
    for c in state.get("commands", []):
        lines.append(f"{c['command']}   # {c.get('time', '')} on {c.get('host', '')}")
    if command:
        lines.append(command)
    lines += ["```", ""]
    return lines


def _md_definitions(study: Study) -> list[str]:
    return [
        "Definitions. AUC: the area under a seed's evaluation-return curve divided by the env steps it spans "
        "(trapezoidal rule; the mean return over training). Normalized AUC: per task, min–max scaled by the "
        "smallest and largest AUC of every finished run and seed of this study on that task (paper §4.2). "
        "Median, IQM (the mean of the middle 50%), mean and optimality gap (1 − mean of scores clipped "
        f"at 1) come from rliable; [a, b] is the 95% percentile bootstrap confidence interval from "
        f"{stats.RESAMPLES} resamples of the seeds (stratified by task for the aggregates; rliable's "
        f"`get_interval_estimates`). With fewer than {stats.MIN_SEEDS} seeds no interval is given: a "
        "nominal 95% bootstrap interval of 2 seeds covers the true mean about half the time (it is their "
        "range); with 3–5 seeds it still covers only about 75–84% (sf2_common/studies/stats.py).", ""]
