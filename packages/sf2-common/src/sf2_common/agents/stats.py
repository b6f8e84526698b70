"""95% percentile-bootstrap intervals over seeds by rliable (Agarwal et al., 2021), for a run's table and
curve and the studies: none below `MIN_SEEDS` seeds, each under a fixed global seed
(docs/decisions/intervals.md); rliable (from sf2-studies) is imported when an interval is computed."""

from __future__ import annotations

import contextlib

import numpy as np

__all__ = ["MIN_SEEDS", "RESAMPLES", "CONFIDENCE", "SEED", "RLIABLE_INSTALL", "require_rliable",
           "informative", "global_seed", "interval_over_seeds", "mean_interval"]

MIN_SEEDS = 3          # fewer seeds: no interval
RESAMPLES = 5000       # paper §4.2: "95th percentiles confidence intervals computed using 5000 samples"
CONFIDENCE = 0.95
SEED = 0
RLIABLE_INSTALL = "pip install packages/sf2-studies"


def require_rliable():
    """(rliable.library, rliable.metrics), or an ImportError that says how to install rliable."""
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


def interval_over_seeds(values, fn, resamples: int = RESAMPLES, seed: int = SEED):
    """A statistic over seeds of each column with its 95% percentile-bootstrap interval.

    Args:
        values: (n_seeds,) or (n_seeds, n_points) scores; each column is resampled over its seeds.
        fn: the statistic, (n_seeds, n_points) -> (n_points,).
        resamples: bootstrap resamples.
        seed: seed of NumPy's global generator while rliable resamples.

    Returns:
        (fn(values), lower, upper); lower = upper = None below `MIN_SEEDS` seeds (rliable not needed).
    """
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        v = v[:, None]
    point = fn(v)
    if not informative(v.shape[0]):
        return point, None, None
    library, _ = require_rliable()
    with global_seed(seed):
        _, i = library.get_interval_estimates({"x": v}, fn, reps=resamples,
                                              confidence_interval_size=CONFIDENCE)
    return point, i["x"][0], i["x"][1]


def _mean(x):
    return np.mean(x, axis=0)


def mean_interval(values, resamples: int = RESAMPLES, seed: int = SEED):
    """`interval_over_seeds` of the mean: (mean of each column, lower, upper), a learning curve's band."""
    return interval_over_seeds(values, _mean, resamples, seed)
