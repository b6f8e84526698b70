"""95% percentile-bootstrap intervals over seeds, rliable's (Agarwal et al., 2021), for a run's table and
curve and the studies: none below `MIN_SEEDS` seeds, each under a fixed global seed
(docs/decisions/intervals.md). `stratified_bootstrap` draws rliable's resamples and takes arch's percentile
interval of a statistic computed on all of them at once; equal to `rliable.library.get_interval_estimates`
to the last bit, without its Python call per resample (docs/decisions/bootstrap-fast-path.md)."""

from __future__ import annotations

import contextlib

import numpy as np

__all__ = ["MIN_SEEDS", "RESAMPLES", "CONFIDENCE", "SEED", "CHUNK_ENTRIES", "informative", "global_seed",
           "stratified_bootstrap", "interval_over_seeds", "mean_interval"]

MIN_SEEDS = 3          # fewer seeds: no interval
RESAMPLES = 5000       # paper §4.2: "95th percentiles confidence intervals computed using 5000 samples"
CONFIDENCE = 0.95
SEED = 0
CHUNK_ENTRIES = 1 << 22   # resampled scores held at once by `stratified_bootstrap` (32 MiB of float64)


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


def stratified_bootstrap(arrays, statistic, resamples: int = RESAMPLES, seed: int = SEED,
                         confidence: float = CONFIDENCE):
    """rliable's stratified percentile-bootstrap interval of a statistic, computed on every resample at once.

    Resample r draws, for each array in turn, `np.random.choice(n_seeds, array.shape)` from NumPy's global
    generator seeded with `seed` (rliable's `StratifiedBootstrap` and `StratifiedIndependentBootstrap`):
    each entry takes the row it names in its own column, so every column (a task, an evaluation) is
    resampled over its own seeds and every array on its own. The bounds are arch's percentile interval,
    the (1 − confidence)/2 and (1 + confidence)/2 percentiles of the statistic over the resamples. The
    resamples are drawn and scored in consecutive chunks of at most `CHUNK_ENTRIES` scores.

    Args:
        arrays: a (n_seeds, n_columns) array, or a sequence of them with the same columns.
        statistic: the arrays, each with a leading resample axis (resamples, n_seeds, n_columns) → an
            array (resamples, k).
        resamples: bootstrap resamples.
        seed: seed of NumPy's global generator while drawing (the caller's state is restored).
        confidence: the interval's coverage.

    Returns:
        (lower, upper), each (k,).

    Raises:
        ValueError: an array is not 2-D, or the arrays' columns differ.
    """
    arrays = [np.asarray(a, dtype=float) for a in ([arrays] if isinstance(arrays, np.ndarray) else arrays)]
    if not arrays or any(a.ndim != 2 or a.shape[1] != arrays[0].shape[1] for a in arrays):
        raise ValueError(f"stratified_bootstrap: (n_seeds, n_columns) arrays with the same columns, got "
                         f"{[a.shape for a in arrays]}")
    chunk = max(1, min(resamples, CHUNK_ENTRIES // max(1, sum(a.size for a in arrays))))
    values = []
    with global_seed(seed):
        for start in range(0, resamples, chunk):   # consecutive draws: the stream of one draw per resample
            m = min(chunk, resamples - start)
            if len(arrays) == 1:
                rows = [np.random.choice(arrays[0].shape[0], (m, *arrays[0].shape), replace=True)]
            else:
                rows = [np.empty((m, *a.shape), dtype=int) for a in arrays]
                for r in range(m):
                    for a, idx in zip(arrays, rows, strict=True):
                        idx[r] = np.random.choice(a.shape[0], a.shape, replace=True)
            drawn = [a[idx, np.arange(a.shape[1])] for a, idx in zip(arrays, rows, strict=True)]
            values.append(np.asarray(statistic(*drawn), dtype=float).reshape(m, -1))
    alpha = (1.0 - confidence) / 2
    lower, upper = np.percentile(np.concatenate(values), [100 * alpha, 100 * (1.0 - alpha)], axis=0)
    return lower, upper


def interval_over_seeds(values, fn, resamples: int = RESAMPLES, seed: int = SEED):
    """A statistic over seeds of each column with its 95% percentile-bootstrap interval.

    Args:
        values: (n_seeds,) or (n_seeds, n_points) scores; each column is resampled over its seeds.
        fn: the statistic over the seeds axis, the second to last: (..., n_seeds, n_points) →
            (..., n_points), for the scores and for every resample at once (`stratified_bootstrap`).
        resamples: bootstrap resamples.
        seed: seed of NumPy's global generator while resampling.

    Returns:
        (fn(values), lower, upper); lower = upper = None below `MIN_SEEDS` seeds.
    """
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        v = v[:, None]
    point = fn(v)
    if not informative(v.shape[0]):
        return point, None, None
    lower, upper = stratified_bootstrap(v, fn, resamples, seed)
    return point, lower, upper


def _mean(x):
    return np.mean(x, axis=-2)


def mean_interval(values, resamples: int = RESAMPLES, seed: int = SEED):
    """`interval_over_seeds` of the mean: (mean of each column, lower, upper), a learning curve's band."""
    return interval_over_seeds(values, _mean, resamples, seed)
