"""The numbers of a study (paper §4.2, Appendix C): per run the area under the evaluation-return curve
and the mean return over the final env steps; per task min–max normalization; per algorithm family the
median, interquartile mean (IQM), mean and optimality gap with 95% stratified-bootstrap confidence
intervals (5000 resamples). The aggregates are rliable's (Agarwal et al., 2021; `rliable.metrics`); every
interval is `rliable.library.get_interval_estimates`' own, drawn by `stratified_bootstrap` with rliable's
aggregates restated over a leading resample axis (`BATCHED`): equal to the last bit, without a call per
resample.

Intervals are percentile-bootstrap intervals over seeds (within each task: stratified), none below
`MIN_SEEDS` seeds (docs/decisions/intervals.md), each under a fixed global seed (`SEED`). The per-column
intervals and those constants are sf2_common.agents.stats', which a run's table and curve use too.
"""

from __future__ import annotations

import numpy as np
from sf2_common.agents.stats import (
    CONFIDENCE,
    MIN_SEEDS,
    RESAMPLES,
    SEED,
    informative,
    interval_over_seeds,
    mean_interval,
    stratified_bootstrap,
)

__all__ = [
    "MIN_SEEDS", "RESAMPLES", "CONFIDENCE", "SEED", "METRICS", "auc", "final_window_mean",
    "normalize_by_task", "aggregate", "aggregate_intervals", "mean_interval",
    "iqm_interval", "column_interval", "COLUMN_STATISTICS",
    "informative", "require_rliable", "STATISTICS", "BATCHED", "difference", "difference_interval",
    "probability_of_improvement",
]

STATISTICS = {"IQM": "aggregate_iqm", "Median": "aggregate_median", "Mean": "aggregate_mean"}  # of a claim
METRICS = ("Median", "IQM", "Mean", "Optimality Gap")
COLUMN_STATISTICS = ("mean", "median", "iqm")   # over seeds, per column (`column_interval`)


def require_rliable():
    """(rliable.library, rliable.metrics), or an ImportError that says how to install rliable."""
    try:
        from rliable import library, metrics
    except ImportError as err:
        raise ImportError(f"the study statistics need rliable ({err}); install it with sf2-studies: "
                          "pip install packages/sf2-studies") from err
    return library, metrics


# ------------------------------------------------------------------------------------------- per run
def auc(steps, returns) -> float:
    """Area under the evaluation-return curve (paper §4.2) divided by the env steps it spans: the
    trapezoidal integral of the return over env steps from the first evaluation to the last, / (last −
    first). The result is in return units (the average return over training); min–max normalization
    per task makes any positive scaling of the AUC irrelevant. One evaluation: its return."""
    x = np.asarray(steps, dtype=float)
    y = np.asarray(returns, dtype=float)
    if x.ndim != 1 or x.shape != y.shape or x.size == 0:
        raise ValueError(f"auc: steps and returns must be 1-D of one length > 0, got {x.shape}, {y.shape}")
    if x.size == 1:
        return float(y[0])
    if np.any(np.diff(x) <= 0):
        raise ValueError("auc: env steps must increase")
    return float(np.trapezoid(y, x) / (x[-1] - x[0]))


def final_window_mean(steps, returns, window: float) -> float:
    """Mean return of the evaluations in the final `window` env steps (paper §4.3, Fig. 2: "the mean
    episode return over the final 50k steps"): those at env steps >= last − window; at least the last."""
    x = np.asarray(steps, dtype=float)
    y = np.asarray(returns, dtype=float)
    return float(y[x >= x[-1] - window].mean())


# ------------------------------------------------------------------------------------------- per task
def normalize_by_task(scores: dict) -> dict:
    """{task: array of scores (any shape)} → the same, each task min–max scaled to [0, 1] by that
    task's minimum and maximum over every array given (paper §4.2: every run of the study on that task).
    `scores[task]` may be a dict {method: array}; all methods of a task share its min and max. A task
    whose scores are all equal maps to 0."""
    out = {}
    for task, by in scores.items():
        arrays = by if isinstance(by, dict) else {None: by}
        flat = np.concatenate([np.ravel(np.asarray(a, dtype=float)) for a in arrays.values()])
        lo, hi = float(flat.min()), float(flat.max())
        span = hi - lo
        scaled = {k: (np.asarray(a, dtype=float) - lo) / span if span > 0 else np.zeros(np.shape(a))
                  for k, a in arrays.items()}
        out[task] = scaled if isinstance(by, dict) else scaled[None]
    return out


# ------------------------------------------------------------------------------------------- aggregates
def _batched_median(x):
    return np.median(np.mean(x, axis=1), axis=1)


def _batched_iqm(x):
    from scipy.stats import trim_mean

    return trim_mean(x.reshape(x.shape[0], -1), proportiontocut=0.25, axis=1)


def _batched_mean(x):
    return np.mean(np.mean(x, axis=1), axis=1)


def _batched_optimality_gap(x, gamma=1):
    return gamma - np.mean(np.minimum(x, gamma).reshape(x.shape[0], -1), axis=1)


# rliable.metrics' aggregates of scores (n_runs, n_tasks), each restated for (resamples, n_runs, n_tasks) →
# (resamples,) with the same NumPy and SciPy calls in the same order of summation
BATCHED = {"aggregate_median": _batched_median, "aggregate_iqm": _batched_iqm,
           "aggregate_mean": _batched_mean, "aggregate_optimality_gap": _batched_optimality_gap}


def _batched_metrics(x):
    return np.stack([BATCHED[name](x) for name in ("aggregate_median", "aggregate_iqm", "aggregate_mean",
                                                   "aggregate_optimality_gap")], axis=1)


def _aggregate_fn(metrics):
    def fn(x):
        return np.array([metrics.aggregate_median(x), metrics.aggregate_iqm(x), metrics.aggregate_mean(x),
                         metrics.aggregate_optimality_gap(x)])
    return fn


def aggregate(scores) -> np.ndarray:
    """Median, IQM, mean, optimality gap (`METRICS`, rliable.metrics) of normalized scores (n_seeds,
    n_tasks). Median and mean are of the per-task means over seeds; IQM and optimality gap pool every
    (seed, task) score (rliable's definitions)."""
    _, metrics = require_rliable()
    return _aggregate_fn(metrics)(np.asarray(scores, dtype=float))


def aggregate_intervals(score_dict: dict, resamples: int = RESAMPLES, seed: int = SEED):
    """{method: (n_seeds, n_tasks) normalized scores} → ({method: point estimates of `METRICS`},
    {method: (2, 4) lower/upper bounds or None}): rliable's `get_interval_estimates`, percentile
    method, stratified over tasks, `CONFIDENCE` (`stratified_bootstrap`). None where the method has fewer
    than `MIN_SEEDS` seeds."""
    _, metrics = require_rliable()
    fn = _aggregate_fn(metrics)
    points, intervals = {}, {}
    for name, scores in score_dict.items():
        scores = np.asarray(scores, dtype=float)
        points[name] = fn(scores)
        intervals[name] = (np.stack(stratified_bootstrap(scores, _batched_metrics, resamples, seed))
                           if informative(scores.shape[0]) else None)
    return points, intervals


def column_interval(values, statistic: str = "mean", resamples: int = RESAMPLES, seed: int = SEED):
    """values (n_seeds,) or (n_seeds, n_points) → (statistic over seeds of each column, lower, upper), the
    statistic one of `COLUMN_STATISTICS`: "mean" (`mean_interval`), "median" (np.median of each column,
    the mean of the two middle seeds for an even count, the statistic of the paper's learning curves, Fig.
    8) or "iqm" (`iqm_interval`); lower = upper = None below `MIN_SEEDS` seeds."""
    if statistic not in COLUMN_STATISTICS:
        raise ValueError(f"statistic {statistic!r}: one of {', '.join(COLUMN_STATISTICS)}")
    if statistic == "iqm":
        def fn(x):  # rliable's IQM of each column's seeds, the seeds moved last and contiguous as there
            seeds_last = np.ascontiguousarray(np.moveaxis(x, -2, -1))
            return _batched_iqm(seeds_last.reshape(-1, 1, x.shape[-2])).reshape(seeds_last.shape[:-1])
    else:
        plain = {"mean": np.mean, "median": np.median}[statistic]

        def fn(x):
            return plain(x, axis=-2)
    return interval_over_seeds(values, fn, resamples, seed)


def iqm_interval(values, resamples: int = RESAMPLES, seed: int = SEED):
    """Like `mean_interval` for the interquartile mean over seeds (rliable's aggregate_iqm: the 25%
    trimmed mean)."""
    return column_interval(values, "iqm", resamples, seed)


# ------------------------------------------------------------------------------------------- two methods
def difference(x, y, statistic: str = "IQM") -> float:
    """statistic(x) − statistic(y) of scores x (n_x, n_tasks) and y (n_y, n_tasks) (`STATISTICS`: rliable's
    aggregate IQM, median or mean): `difference_interval`'s point."""
    return float(_difference(_aggregate(statistic), x, y))


def _aggregate(statistic: str):
    """rliable's aggregate function of `statistic` (`STATISTICS`)."""
    _, metrics = require_rliable()
    return getattr(metrics, STATISTICS[statistic])


def _difference(agg, x, y):
    return agg(np.asarray(x, dtype=float)) - agg(np.asarray(y, dtype=float))


def difference_interval(x, y, statistic: str = "IQM", resamples: int = RESAMPLES, seed: int = SEED,
                        confidence: float = CONFIDENCE):
    """Normalized scores x (n_x, n_tasks) and y (n_y, n_tasks) of two methods on the same tasks → (point,
    lower, upper) of statistic(x) − statistic(y) (`STATISTICS`: rliable's aggregate IQM, median or mean)
    with its `confidence` percentile bootstrap interval (95%; an equivalence test takes 90%): rliable's
    `get_interval_estimates` on the pair, i.e. its `StratifiedIndependentBootstrap` (each method's seeds
    resampled independently within each task; `stratified_bootstrap`). lower = upper = None when either
    method has fewer than `MIN_SEEDS` seeds."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    point = float(_difference(_aggregate(statistic), x, y))
    if not (informative(x.shape[0]) and informative(y.shape[0])):
        return point, None, None
    batched = BATCHED[STATISTICS[statistic]]
    lower, upper = stratified_bootstrap((x, y), lambda a, b: batched(a) - batched(b), resamples, seed,
                                        confidence)
    return point, float(lower[0]), float(upper[0])


def probability_of_improvement(x, y) -> float:
    """rliable's average probability of improvement P(X > Y) of scores x over y (n_runs, n_tasks): per task
    the Mann–Whitney U statistic / (n_x · n_y), averaged over tasks (Agarwal et al., 2021)."""
    _, metrics = require_rliable()
    return float(metrics.probability_of_improvement(np.asarray(x, dtype=float), np.asarray(y, dtype=float)))
