"""`study report DIR`: a study folder's numbers (paper §4.2, Appendix C) as DIR/report/results.csv,
claims.csv, summary.md and figures (`figures.py`); framework-free, from the run folders' files.

Per run and seed: the AUC of the evaluation-return curve, normalized per task by the min and max over every
finished run and seed of the study, the final return and wall time. Per family (TD3, SAC) and method: the
median, IQM, mean and optimality gap with 95% stratified-bootstrap intervals, every method on the same tasks
and seeds (an interim study's aggregate is named as such). Only finished runs enter the numbers; the
others are listed as incomplete. The claims get verdicts (claims.py)."""

from __future__ import annotations

import csv
import dataclasses
from collections import Counter
from pathlib import Path

import numpy as np
from sf2_common.agents.hostloop import environment_text
from sf2_common.agents.plotting import curves
from sf2_common.agents.runfolder import RunFolder, RunFolderError

from . import claims, reruns, stats
from .folder import StudyFolder, read_obs_noise
from .spec import Method, Study, StudyError, seeds_text

__all__ = ["RunData", "collect", "report", "results_rows", "CSV_FIELDS"]

CSV_FIELDS = ("task", "method", "family", "seed", "auc", "normalized_auc", "final_return",
              "final_window_return", "env_steps", "wall_time_s")


@dataclasses.dataclass
class GroupData:
    """One run folder of a (task, method): a seed group, or all seeds without `seeds_per_run`; its curves
    whether finished or not (`study export`, export.py, writes them all)."""

    seeds: tuple[int, ...]
    path: Path
    finished: bool
    progress: str                     # "partial (epoch 3 of 5)" or "not started" for an incomplete run
    hardware: str = ""                # config.json's "hardware" (its first session's), "" if not recorded
    environment: dict | None = None   # config.json's "environment" (None: not recorded)
    config: dict = dataclasses.field(default_factory=dict)      # config.json's "config" ({}: none yet)
    steps: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))   # its evaluations' env steps
    returns: dict[int, np.ndarray] = dataclasses.field(default_factory=dict)   # seed → eval returns at steps


@dataclasses.dataclass
class RunData:
    """A (task, method): the seeds of its finished run folders joined."""

    task: str
    method: Method
    path: Path                        # the method's run folder (the groups' parent with seed groups)
    finished: bool                    # some seeds finished (every seed, without seed groups)
    progress: str                     # its first unfinished group's (`GroupData.progress`)
    steps: np.ndarray                 # env steps of the evaluations every seed has
    returns: dict[int, np.ndarray]    # seed → eval returns at `steps` (finished groups only)
    wall_time: float                  # summed over the finished groups
    obs_noise: list[dict] | None      # obs_noise.json's results (the groups' joined)
    groups: list[GroupData] = dataclasses.field(default_factory=list)
    wall_times: dict[int, float] = dataclasses.field(default_factory=dict)   # seed → its run's wall time
    expected: tuple[int, ...] = ()    # the study's seeds

    def seeds(self) -> list[int]:
        return sorted(self.returns)

    def missing(self) -> list[int]:
        """The study's seeds without a finished run."""
        return [s for s in self.expected if s not in self.returns]

    def matrix(self) -> np.ndarray:
        """(n_seeds, n_evaluations) eval returns."""
        return np.stack([self.returns[s] for s in self.seeds()])


def _group(seeds, path: Path):
    """(GroupData, steps, {seed: returns}, wall time, obs-noise results) of one run folder."""
    run = RunFolder(path)
    try:
        conf = run.read_config() or {}
        rows = run.read_rows(strict=True)
    except RunFolderError as err:
        raise StudyError(_damaged(err, path)) from None
    epochs = (conf.get("schedule") or {}).get("num_epochs")
    steps, per_seed = curves([r for r in rows if r["seed"] in seeds])
    last = {s: max((r["epoch"] for r in rows if r["seed"] == s), default=-1) for s in seeds}
    finished = bool(conf) and epochs is not None and all(e == epochs for e in last.values())
    first = min(last.values())
    progress = ("not started" if not conf else f"partial (epoch {first} of {epochs})" if first >= 0 else
                "partial (no evaluation yet)")
    try:
        data = read_obs_noise(path)
    except ValueError as err:
        raise StudyError(_damaged(err, path)) from None
    noise = None if data is None else data["results"]
    wall = max((r.get("walltime", 0.0) for r in rows), default=0.0)
    env = conf.get("environment")
    group = GroupData(tuple(seeds), path, finished, progress, str(conf.get("hardware", "")),
                      env if isinstance(env, dict) else None, dict(conf.get("config") or {}), steps, per_seed)
    return group, steps, per_seed, wall, noise


def _damaged(err, path: Path) -> str:
    """A run folder file the report cannot read: it leaves no run out silently."""
    return (f"{err}. The report leaves no run out silently: restore the file (e.g. `git checkout` it, or "
            f"`study merge` the run again from the archive it came in), or move the run folder {path} out "
            f"of the study folder to report without it")


def _join_noise(parts: list[list[dict]]) -> list[dict] | None:
    """The obs-noise results of several seed groups as one list: per (noise, epoch) the seeds' returns
    joined."""
    if not parts:
        return None
    joined: dict[tuple, dict] = {}
    for results in parts:
        for r in results:
            key = (r["noise"], r["epoch"])
            if key not in joined:
                joined[key] = {**r, "returns": dict(r["returns"])}
            else:
                joined[key]["returns"].update(r["returns"])
    return list(joined.values())


def collect(study: Study, folder: StudyFolder) -> list[RunData]:
    """Every (task, method) of the study with what its run folders hold (task-major, file order)."""
    paths = folder.method_runs(study)
    out = []
    for task in study.tasks:
        for m in study.methods:
            groups, steps, returns, walls, noises = [], None, {}, {}, []
            for seeds, path in paths[(task, m.name)].items():
                g, g_steps, g_returns, wall, noise = _group(seeds, path)
                groups.append(g)
                if noise is not None:
                    noises.append(noise)
                if not g.finished:
                    continue
                if steps is not None and not np.array_equal(steps, g_steps):   # evaluations all groups have
                    common = np.intersect1d(steps, g_steps)
                    returns = {s: r[np.isin(steps, common)] for s, r in returns.items()}
                    g_returns = {s: r[np.isin(g_steps, common)] for s, r in g_returns.items()}
                    g_steps = common
                steps = g_steps
                returns.update(g_returns)
                walls.update({s: wall for s in g_returns})
            first_open = next((g for g in groups if not g.finished), None)
            grouped = study.seeds_per_run is not None
            out.append(RunData(
                task, m, groups[0].path.parent if grouped else groups[0].path,
                finished=bool(returns) and (grouped or first_open is None),
                progress=first_open.progress if first_open else "finished",
                steps=steps if steps is not None else np.zeros(0), returns=dict(sorted(returns.items())),
                wall_time=sum(walls[g.seeds[0]] for g in groups if g.finished), obs_noise=_join_noise(noises),
                groups=groups, wall_times=walls, expected=study.seeds))
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
                         "env_steps": int(d.steps[-1]),
                         "wall_time_s": round(d.wall_times.get(s, d.wall_time), 1)})
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


@dataclasses.dataclass
class Coverage:
    """What a family's aggregate covers: tasks on which every method of the family has finished seeds, and
    seeds every one of those methods finished on every one of those tasks (`coverage` says which)."""

    family: str
    tasks: list[str]                  # in the aggregate (study order)
    seeds: list[int]                  # in the aggregate
    left_out: dict[str, list[str]]    # task not in it → the family's methods with finished seeds there
    extra_seeds: list[int]            # finished on the covered tasks by some methods only: left out
    # task every method has finished seeds on, left out because some lack the aggregate's seeds there →
    # [(method label, the seeds it has there)] of those methods
    fewer_seeds: dict[str, list[tuple[str, str]]] = dataclasses.field(default_factory=dict)

    def complete(self, study: Study) -> bool:
        return len(self.tasks) == len(study.tasks) and list(self.seeds) == sorted(study.seeds)


def coverage(family: str, tasks: list[str], methods: list[str], got: dict) -> Coverage:
    """The tasks and seeds of a family's aggregate from `got` ({(task, method label): {seed: score}} for
    every task of `tasks`, in study order, and every method label of the family in `methods`). Of the
    tasks on which every method has finished seeds, each has the seeds all of them finished there (its
    common seeds); the aggregate takes the seed set S, among the seeds common to all those tasks and each
    task's own common seeds, that scores the most seeds × tasks (every task whose common seeds include
    S), ties to more tasks, then to the first candidate. So one method's first seed group on a new task
    does not cut a study's interim aggregate to that group's seeds on every task (in fig7-sac,
    SAC+SPR's seeds 0-4 on HopperHop would have turned 5 tasks × 15 seeds into 6 × 5); the task is left
    out and named, until its seeds catch up."""
    common = {t: set.intersection(*(set(got[(t, m)]) for m in methods)) for t in tasks
              if all(got[(t, m)] for m in methods)}
    candidates = ([set.intersection(*common.values()), *common.values()] if common else [set()])

    def covered(seeds: set) -> list[str]:
        return [t for t in common if common[t] >= seeds]

    best = max(candidates, key=lambda c: (len(covered(c)) * len(c), len(covered(c))))
    chosen = covered(best)
    left = {t: [m for m in methods if got[(t, m)]] for t in tasks if t not in common}
    fewer = {t: [(m, seeds_text(sorted(got[(t, m)]))) for m in methods if not set(got[(t, m)]) >= best]
             for t in common if t not in chosen}
    union = set().union(*(got[(t, m)] for t in chosen for m in methods))
    return Coverage(family, chosen, sorted(best), left, sorted(union - best), fewer)


def _family_cover(study: Study, rows: list[dict], family: str):
    """(the family's methods, {(task, label): {seed: normalized AUC}}, its `Coverage`)."""
    methods = [m for m in study.methods if m.family == family]
    got = {(t, m.label): {r["seed"]: r["normalized_auc"] for r in rows
                          if r["method"] == m.label and r["task"] == t}
           for t in study.tasks for m in methods}
    return methods, got, coverage(family, list(study.tasks), [m.label for m in methods], got)


def aggregate_table(study: Study, rows: list[dict]):
    """({family: [(method label, n_seeds, points (4,), intervals (2, 4) or None)]}, {family: `Coverage`}).
    Every method of a family is scored on the same tasks and seeds (`coverage`: an interim study
    aggregates what it has; summary.md states the coverage). A family without such a task or seed is left
    out of the table."""
    out, covers = {}, {}
    for family in _families(study):
        methods, got, cover = _family_cover(study, rows, family)
        covers[family] = cover
        tasks, seeds = cover.tasks, cover.seeds
        if not seeds:
            continue
        scores = {m.label: np.array([[got[(t, m.label)][s] for t in tasks] for s in seeds]) for m in methods}
        points, intervals = stats.aggregate_intervals(scores)   # (n_seeds, n_tasks) each
        out[family] = [(label, len(seeds), points[label], intervals[label]) for label in scores]
    return out, covers


def _md_coverage(study: Study, cover: Coverage) -> list[str]:
    """One plain sentence: which tasks and seeds a family's aggregate covers, and what it leaves out."""
    n = len(study.tasks)
    if not cover.seeds:
        why = ("no task on which every method has finished seeds" if not cover.tasks else
               f"no seed finished by every method on any one of {', '.join(cover.tasks)}")
        return [f"**{cover.family}**: not aggregated yet ({why}; the aggregate scores every method of the "
                f"family on the same tasks and seeds).", ""]
    seeds = f"seeds {seeds_text(cover.seeds)} ({len(cover.seeds)} of {len(study.seeds)})"
    if cover.complete(study):
        return [f"**{cover.family}**: over all {n} tasks, {seeds}.", ""]
    tasks = "all the" if len(cover.tasks) == n else f"{len(cover.tasks)} of the"
    text = (f"**{cover.family}: interim aggregate** over {tasks} study's {n} tasks "
            f"({', '.join(cover.tasks)}), {seeds}"
            + (f": not the study's {n}-task aggregate" if len(cover.tasks) < n else "") + ".")
    partly = [f"{t} (finished by {', '.join(have)} only)" for t, have in cover.left_out.items() if have]
    idle = [t for t, have in cover.left_out.items() if not have]
    if partly:
        text += " Left out: " + "; ".join(partly) + "."
    if cover.fewer_seeds:
        short = [f"{t} ({', '.join(f'{m} has seeds {have}' for m, have in lacking)})"
                 for t, lacking in cover.fewer_seeds.items()]
        text += (" Left out until its seeds catch up (with it, every task would be scored on fewer seeds): "
                 + "; ".join(short) + ".")
    if idle:
        text += f" No finished run yet: {', '.join(idle)}."
    if cover.extra_seeds:
        text += (f" Seeds {seeds_text(cover.extra_seeds)} are finished on these tasks by some methods only "
                 f"and left out, so that every method is scored on the same seeds.")
    return [text, ""]


def _md_per_task(study: Study, data: list[RunData], rows: list[dict]) -> list[str]:
    lines = ["| task | method | seeds | AUC: mean [95% CI] | normalized AUC: mean | final return: mean "
             "[95% CI] | env steps | wall time, runs summed |", "|---|---|---|---|---|---|---|---|"]
    for d in data:
        if not d.finished:
            continue
        mine = [r for r in rows if r["task"] == d.task and r["method"] == d.method.label]
        auc = stats.mean_interval([r["auc"] for r in mine])
        fin = stats.mean_interval([r["final_return"] for r in mine])
        norm = np.mean([r["normalized_auc"] for r in mine])
        seeds = f"{len(mine)}" + (f" of {len(study.seeds)}" if d.missing() else "")
        lines.append(f"| {d.task} | {d.method.label} | {seeds} | {_with_ci(auc[0][0], *_lohi(auc))} | "
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
    """{sweep field: {base label: [(value text, value, seeds, score, lo, hi)]}}: the mean over seeds of the
    final-window return (paper Fig. 2 a/b/d), or with `report.sweep_score = "iqm_auc"` each method's IQM of
    the normalized AUC over the study's tasks, `aggregate_table`'s (paper Fig. 9 left)."""
    iqm = _iqm_by_label(study, rows) if study.report.sweep_score == "iqm_auc" else None
    out = {}
    for m in study.methods:
        if m.sweep is None:
            continue
        field, text, base = m.sweep
        if iqm is not None:
            if m.label not in iqm:
                continue
            point = iqm[m.label]
        else:
            vals = [r["final_window_return"] for r in rows if r["method"] == m.label]
            if not vals:
                continue
            mean, lo, hi = stats.mean_interval(vals)
            point = (len(vals), float(mean[0]), None if lo is None else float(lo[0]),
                     None if hi is None else float(hi[0]))
        out.setdefault(field, {}).setdefault(base, []).append((text, _number(text), *point))
    return out


def _iqm_by_label(study: Study, rows: list[dict]) -> dict[str, tuple]:
    """{method label: (seeds, IQM, lower, upper)} of the normalized AUC from `aggregate_table` (bounds None
    where it has no interval)."""
    table, _ = aggregate_table(study, rows)
    i = stats.METRICS.index("IQM")
    return {label: (n, float(p[i]), *((None, None) if ci is None else (float(ci[0][i]), float(ci[1][i]))))
            for entries in table.values() for label, n, p, ci in entries}


def _number(text: str):
    try:
        return float(text)
    except ValueError:
        return text


def obs_noise_rows(data: list[RunData]) -> list[dict]:
    """One row per (task, method, noise level, seed) evaluated under observation noise: the seed's AUC of
    the return over the evaluated checkpoints (`stats.auc` over their env steps; each checkpoint's return
    the mean over its episodes), for the seeds evaluated at every checkpoint of that level."""
    rows = []
    for d in data:
        if not d.obs_noise:
            continue
        for noise in sorted({r["noise"] for r in d.obs_noise}):
            at = sorted((r for r in d.obs_noise if r["noise"] == noise), key=lambda r: r["env_steps"])
            seeds = sorted(set.intersection(*(set(r["returns"]) for r in at)), key=int)
            steps = [r["env_steps"] for r in at]
            for s in seeds:
                rows.append({"task": d.task, "method": d.method.label, "family": d.method.family,
                             "noise": noise, "seed": int(s),
                             "auc": stats.auc(steps, [np.mean(r["returns"][s]) for r in at])})
    return rows


def obs_noise_points(study: Study, data: list[RunData]):
    """{family: {method label: [(noise, seeds, IQM, lo, hi)]}}: per seed the AUC of the return over the
    evaluated checkpoints (`obs_noise_rows`), then the IQM over seeds with its 95% bootstrap interval
    (paper App. C.2.2, Fig. 9 right)."""
    out = {}
    rows = obs_noise_rows(data)
    for key in dict.fromkeys((r["family"], r["method"], r["task"], r["noise"]) for r in rows):
        family, label, task, noise = key
        aucs = [r["auc"] for r in rows if (r["family"], r["method"], r["task"], r["noise"]) == key]
        iqm, lo, hi = stats.iqm_interval(aucs)
        name = label + (f" · {task}" if len(study.tasks) > 1 else "")
        out.setdefault(family, {}).setdefault(name, []).append(
            (noise, len(aucs), float(iqm[0]), None if lo is None else float(lo[0]),
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
    blocking = next((p for p in (out, *out.parents) if p.exists()), None)
    if blocking is not None and not blocking.is_dir():
        raise StudyError(f"report folder {out}: {blocking} is a file, not a folder; nothing was written")
    data = collect(study, folder)   # every run read before anything is written
    found, ignored = reruns.collect(folder, data)
    out.mkdir(parents=True, exist_ok=True)
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
    complete = sum(d.finished and not d.missing() for d in data)
    partial = sum(d.finished and bool(d.missing()) for d in data)
    groups = study.seed_groups()
    md += [f"Runs: {complete} of {len(data)} (task, method) pairs have all {len(study.seeds)} of the study's "
           f"seeds" + (f", {partial} some of them" if partial else "") + f"; seeds "
           f"{', '.join(map(str, study.seeds))}"
           + (f" in seed groups ({', '.join(seeds_text(g) for g in groups)}), one run each"
              if study.seeds_per_run else "") + f"; preset `{study.preset}`.", ""]
    md += _md_hardware(data)
    md += _md_definitions(study)
    md += _md_seed_counts(study, data)

    figs = study.report.figures
    if "aggregate" in figs:
        table, covers = aggregate_table(study, rows)
        md += ["## Aggregate normalized AUC per family (paper Fig. 1 / 7)", ""]
        for cover in covers.values():
            md += _md_coverage(study, cover)
        md += _md_aggregate(table, {f: len(c.tasks) for f, c in covers.items()})
        if table:
            written.update(figures.aggregate(table, out / "aggregate", study, covers))
            md += ["![aggregate](aggregate.png)", ""]
    if study.claims:
        checked = claims.check(study, rows, obs_noise_rows(data))
        md += claims.markdown(checked)
        with open(out / "claims.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=claims.CSV_FIELDS)
            w.writeheader()
            w.writerows(claims.csv_rows(checked))
        written["claims.csv"] = out / "claims.csv"
    md += ["## Per task", ""] + _md_per_task(study, data, rows) + [""]
    if "curves" in figs and finished:
        written.update(figures.learning_curves(study, finished, out / "curves"))
        md += ["![learning curves](curves.png)", ""]
    if "sweeps" in figs:
        points = sweep_points(study, rows)
        md += (["## Sweeps: IQM of the normalized AUC over the tasks (paper Fig. 9 left)", "",
                "| sweep | method | value | seeds | IQM [95% CI] |"]
               if study.report.sweep_score == "iqm_auc" else
               [f"## Sweeps: mean return over the final {study.report.final_window:,} env steps "
                f"(paper Fig. 2 a/b/d)", "", "| sweep | method | value | seeds | mean [95% CI] |"])
        md.append("|---|---|---|---|---|")
        titles = dict(study.report.sweeps)
        for field, by_base in points.items():
            for base, entries in by_base.items():
                for text, _, n, mean, lo, hi in entries:
                    md.append(f"| {titles.get(field, field)} | {base} | {text} | {n} | "
                              f"{_with_ci(mean, lo, hi)} |")
        md.append("")
        if points:
            covered = {len(c.tasks) for c in (_family_cover(study, rows, f)[2] for f in _families(study))
                       if c.seeds}
            written.update(figures.sweeps(study, points, out / "sweeps", tasks=covered or None))
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
    if found or ignored:
        md += _md_reruns(found, ignored, folder.path)
    if found:
        with open(out / "reruns.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=reruns.CSV_FIELDS)
            w.writeheader()
            w.writerows(reruns.csv_rows(found, folder.path))
        written["reruns.csv"] = out / "reruns.csv"
    md += _md_incomplete(study, data)
    (out / "summary.md").write_text("\n".join(md))
    written["summary.md"] = out / "summary.md"
    return written


def _md_reruns(found: list, ignored: list[Path], root: Path) -> list[str]:
    """The "Reruns" section (reruns.py): each rerun against the run it repeats, by AUC."""
    lines = ["## Reruns: the same config and seeds trained again (not in the results above)", "",
             "A rerun repeats a run of `runs/` with its config and seeds (`study merge --keep-reruns` keeps "
             "it in `rerun/`): on GPUs the two differ from the first epoch on, so it is a second draw of the "
             "same seeds. Per seed AUC as above; the difference rerun − run is a mean over the seeds with "
             "its 95% bootstrap interval; \"first difference\" is the first metric row, in epoch and seed "
             "order, where a learned value differs (epoch 0's evaluation: the two processes' evaluation "
             "programs already rounded differently, bench/lab/eval_sensitivity.py; a later epoch: their "
             "training did); the last column is the method's mean AUC over all its finished seeds on the "
             "task, as reported and with the rerun's seeds in place of the run's (reruns.csv: every "
             "seed).", ""]
    if found:
        lines += ["| task | method | seeds | rerun | AUC run: mean | AUC rerun: mean | rerun − run: mean "
                  "[95% CI] | largest seed difference | first difference | method's AUC (seeds): reported → "
                  "with the rerun |", "|---|---|---|---|---|---|---|---|---|---|"]
        for r in found:
            diff = stats.mean_interval(r.difference)
            big = int(np.argmax(np.abs(r.difference)))
            lines.append(f"| {r.task} | {r.method} | {seeds_text(r.seeds)} | "
                         f"`{r.path.relative_to(root).as_posix()}` | {_fmt(float(r.auc_run.mean()))} | "
                         f"{_fmt(float(r.auc_rerun.mean()))} | {_with_ci(diff[0][0], *_lohi(diff))} | "
                         f"seed {r.seeds[big]}: {_fmt(float(r.auc_run[big]))} → "
                         f"{_fmt(float(r.auc_rerun[big]))} | {_first_difference(r.first_difference)} | "
                         f"{_fmt(r.method_auc)} → "
                         f"{_fmt(r.method_auc_rerun)} ({r.method_seeds}) |")
        lines.append("")
    if ignored:
        lines += ["Ignored (under `rerun/` but repeating no finished run of this study): "
                  + ", ".join(f"`{p.relative_to(root).as_posix()}`" for p in ignored) + ".", ""]
    return lines


def _first_difference(first: tuple | None) -> str:
    """A rerun's first differing metric (`reruns.Rerun.first_difference`) as a table cell."""
    if first is None:
        return "none: equal learned values"
    epoch, seed, field, x, y = first
    if field is None:
        return f"epoch {epoch}, seed {seed}: a row in one only"
    def value(v):   # six significant digits: enough to show a difference in the fourth
        return f"{v:.6g}" if isinstance(v, int | float) else repr(v)
    return f"epoch {epoch}, seed {seed}: {field} {value(x)} → {value(y)}"


def _md_seed_counts(study: Study, data: list[RunData]) -> list[str]:
    """Seeds finished per (task, method) of the study's seeds, the missing ones named; a flag where
    methods of a family have unequal seed counts on a task, and one where a task's normalization rests on
    some of the study's methods only (in fig7-sac, SAC+SPR's first seeds on HopperHop raised the
    task's largest AUC from SAC's best to its own, and SAC+SF² − SAC there went from −0.171 to −0.048 in
    normalized AUC, −2.95 to −3.46 in returns)."""
    tasks = list(study.tasks)
    lines = ["## Seeds finished per (task, method)", "",
             f"Of the study's {len(study.seeds)} seeds ({seeds_text(study.seeds)}); a run's seeds count "
             "once every one of them has its last evaluation.", "",
             "| method | " + " | ".join(tasks) + " |", "|---|" + "---|" * len(tasks)]
    by = {(d.task, d.method.label): d for d in data}
    for m in study.methods:
        cells = []
        for t in tasks:
            d = by[(t, m.label)]
            n, miss = len(d.returns), d.missing()
            cells.append(f"{n}" if not miss else f"{n} (missing {seeds_text(miss)})")
        lines.append(f"| {m.label} | " + " | ".join(cells) + " |")
    lines.append("")
    unequal = []
    for family in _families(study):
        for t in tasks:
            counts = {m.label: len(by[(t, m.label)].returns) for m in study.methods
                      if m.family == family and by[(t, m.label)].returns}
            if len(set(counts.values())) > 1:
                unequal.append(f"{t} ({family}: " + ", ".join(f"{k} {v}" for k, v in counts.items()) + ")")
    if unequal:
        lines += ["**Unequal seed counts**: methods are compared at different numbers of seeds on "
                  + "; ".join(unequal) + ". Their intervals and means rest on different seeds; finish the "
                  "missing seed groups before comparing them.", ""]
    provisional = []
    for t in tasks:
        have = [m.label for m in study.methods if by[(t, m.label)].returns]
        if have and len(have) < len(study.methods):
            provisional.append(f"{t} ({len(have)} of {len(study.methods)} methods: {', '.join(have)})")
    if provisional:
        lines += ["**Provisional normalization**: a task's normalized AUC is scaled by the smallest and "
                  "largest AUC of every finished run on it, so on a task where some methods have no finished "
                  "run yet a later run can move that scale: every normalized score there changes, and with "
                  "them the aggregates and claims that include the task (the order of the methods on it "
                  "does not): " + "; ".join(provisional) + ".", ""]
    return lines


def _md_aggregate(table, n_tasks: dict) -> list[str]:
    lines = []
    for family, entries in table.items():
        lines += [f"### {family}", "", "| method | seeds × tasks | " + " | ".join(stats.METRICS) + " |",
                  "|---|---|" + "---|" * len(stats.METRICS)]
        for label, n, p, ci in entries:
            cells = [_with_ci(p[k], None if ci is None else ci[0][k], None if ci is None else ci[1][k])
                     for k in range(len(stats.METRICS))]
            lines.append(f"| {label} | {n} × {n_tasks[family]} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def _md_incomplete(study: Study, data: list[RunData]) -> list[str]:
    """The run folders not in the numbers, compact: a line naming the tasks no method has started, then
    one row per (task, method) with its unfinished seed groups and their state."""
    open_ = [(d, [g for g in d.groups if not g.finished]) for d in data]
    open_ = [(d, gs) for d, gs in open_ if gs]
    if not open_:
        return []
    idle = [t for t in study.tasks
            if all(g.progress == "not started" for d in data if d.task == t for g in d.groups)]
    lines = ["## Incomplete runs (not in the numbers above)", ""]
    if idle:
        lines += [f"Not started by any method: {', '.join(idle)} ({len(idle)} of {len(study.tasks)} tasks"
                  + (", every seed group" if study.seeds_per_run else "") + ").", ""]
    rows = [(d, gs) for d, gs in open_ if d.task not in idle]
    if rows:
        lines += ["| task | method | seeds not finished: state |", "|---|---|---|"]
        for d, gs in rows:
            new = [seeds_text(g.seeds) for g in gs if g.progress == "not started"]
            parts = [f"{seeds_text(g.seeds)}: {g.progress}" for g in gs if g.progress != "not started"]
            if new:
                parts.append(f"{', '.join(new)}: not started")
            lines.append(f"| {d.task} | {d.method.label} | {'; '.join(parts)} |")
        lines.append("")
    return lines


def _md_hardware(data: list[RunData]) -> list[str]:
    """What the finished run folders trained on (config.json's "hardware", the first session's), counted:
    wall times, and so the per-task table's, are those of that hardware; and, once any run set one, the
    environment variables that change the numbers (config.json's "environment")."""
    unknown = "not recorded (trained before run folders named it)"
    counts = Counter(g.hardware or unknown for d in data for g in d.groups if g.finished)
    if not counts:
        return []
    if list(counts) == [unknown]:
        lines = [f"Hardware: not recorded in the config.json of the {counts[unknown]} finished run folder(s) "
                 f"(they trained before run folders named it)."]
    else:
        parts = [f"{name}: {n} run{'s' * (n > 1)}" for name, n in counts.most_common()]
        lines = [f"Hardware of the finished run folders (their config.json): {'; '.join(parts)}. Wall times "
                 f"are those of that hardware."]
    # The environment variables that change the numbers (hostloop.numerics_environment), once any run set one:
    # e.g. XLA_FLAGS=--xla_gpu_deterministic_ops=true, under which GPU runs repeat bit for bit.
    envs = [g.environment for d in data for g in d.groups if g.finished]
    if any(envs):
        counts = Counter(unknown if e is None else environment_text(e) for e in envs)
        parts = [f"{e}: {n} run{'s' * (n > 1)}" for e, n in counts.most_common()]
        lines.append(f"Their environment (config.json's \"environment\"): {'; '.join(parts)}.")
    return lines + [""]


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
        "range); with 3–5 seeds it still covers only about 75–84% (docs/decisions/intervals.md). Wall "
        "time (per task): the wall times of the method's finished runs on that task added up (one run per "
        "seed group; a resumed run's includes its restarts); a run's own is in results.csv. Learning "
        f"curves: the {study.report.curve_statistic} eval return over seeds at each evaluation.", ""]
