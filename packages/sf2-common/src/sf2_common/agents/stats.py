"""Bootstrap intervals over seeds for one run's table and learning curve (and the studies' statistics).

Percentile-bootstrap intervals of a statistic over seeds, each column resampled over seeds, computed by
rliable (Agarwal et al., 2021; `get_interval_estimates`). Below `MIN_SEEDS` seeds none is computed: such
an interval covers the truth far less often than it claims (docs/decisions/intervals.md). rliable draws
from NumPy's global generator, so every interval is computed under a fixed global seed, restored after.
rliable is imported when an interval is computed; it comes with sf2-studies.
"""

from __future__ import annotations

import contextlib

import numpy as np

__all__ = ["MIN_SEEDS", "RESAMPLES", "CONFIDENCE", "SEED", "COLUMN_STATISTICS", "RLIABLE_INSTALL",
           "require_rliable", "informative", "global_seed", "column_interval", "mean_interval"]

MIN_SEEDS = 3          # fewer seeds: no interval
RESAMPLES = 5000       # paper §4.2: "95th percentiles confidence intervals computed using 5000 samples"
CONFIDENCE = 0.95
SEED = 0
COLUMN_STATISTICS = ("mean", "median", "iqm")   # over seeds, per column (`column_interval`)
RLIABLE_INSTALL = "pip install packages/sf2-studies"


def require_rliable():
    """rliable's modules, or an ImportError that says how to install it.

    Returns:
        (rliable.library, rliable.metrics).
    """
    try:
        from rliable import library, metrics
    except ImportError as err:
        raise ImportError(f"the bootstrap intervals need rliable ({err}); install it with sf2-studies: "
                          f"{RLIABLE_INSTALL}") from err
    return library, metrics


def informative(n_seeds: int) -> bool:
    """Whether an interval over `n_seeds` seeds is worth computing (at least `MIN_SEEDS`)."""
    return n_seeds >= MIN_SEEDS


@contextlib.contextmanager
def global_seed(seed: int):
    """NumPy's global generator seeded with `seed` inside the block, its state restored afterwards."""
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


def column_interval(values, statistic: str = "mean", resamples: int = RESAMPLES, seed: int = SEED):
    """A statistic over seeds of each column with its 95% percentile-bootstrap interval.

    Args:
        values: (n_seeds,) or (n_seeds, n_points) scores.
        statistic: one of `COLUMN_STATISTICS`: "mean", "median" (np.median: the mean of the two middle
            seeds for an even count) or "iqm" (rliable's aggregate_iqm, the 25% trimmed mean).
        resamples: bootstrap resamples.
        seed: seed of NumPy's global generator while rliable resamples.

    Returns:
        (statistic of each column, lower, upper); lower = upper = None below `MIN_SEEDS` seeds.
    """
    if statistic not in COLUMN_STATISTICS:
        raise ValueError(f"statistic {statistic!r}: one of {', '.join(COLUMN_STATISTICS)}")
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        v = v[:, None]
    plain = {"mean": np.mean, "median": np.median}.get(statistic)
    if plain is not None and not informative(v.shape[0]):
        return plain(v, axis=0), None, None     # no rliable needed (a trainer's plot of 1 or 2 seeds)
    library, metrics = require_rliable()
    if plain is not None:
        def fn(x):
            return plain(x, axis=0)
    else:
        def fn(x):  # rliable's IQM of each column's seeds
            return np.array([metrics.aggregate_iqm(x[:, j]) for j in range(x.shape[1])])
    point = fn(v)
    if not informative(v.shape[0]):
        return point, None, None
    with global_seed(seed):
        _, i = library.get_interval_estimates({"x": v}, fn, reps=resamples,
                                              confidence_interval_size=CONFIDENCE)
    return point, i["x"][0], i["x"][1]


def mean_interval(values, resamples: int = RESAMPLES, seed: int = SEED):
    """The mean over seeds of each column with its 95% percentile-bootstrap interval (a curve's band).

    Args:
        values: (n_seeds,) or (n_seeds, n_points) scores.
        resamples: bootstrap resamples.
        seed: seed of NumPy's global generator while rliable resamples.

    Returns:
        (mean of each column, lower, upper); lower = upper = None below `MIN_SEEDS` seeds.
    """
    return column_interval(values, "mean", resamples, seed)
