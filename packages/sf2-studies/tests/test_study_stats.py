"""sf2_studies.stats: the numbers of the paper's protocol (§4.2) against values derived by hand and
against rliable's own functions."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rliable", reason="sf2-studies' dependencies: pip install packages/sf2-studies")

from rliable import library, metrics  # noqa: E402
from sf2_common.agents import stats as common_stats  # noqa: E402
from sf2_studies import stats  # noqa: E402


def test_auc_of_known_curves():
    # ramp 0 → 10 over [0, 10], flat 10 over [10, 20]: area 50 + 100 = 150 over 20 env steps
    assert stats.auc([0, 10, 20], [0, 10, 10]) == pytest.approx(7.5)
    # a constant curve's AUC is the constant, whatever the spacing
    assert stats.auc([0, 3, 100], [4, 4, 4]) == pytest.approx(4.0)
    # a line r = n/1000 from 0 to 1000: mean value 0.5
    assert stats.auc(np.arange(0, 1001, 100), np.arange(0, 1001, 100) / 1000) == pytest.approx(0.5)
    assert stats.auc([5], [3.0]) == 3.0
    with pytest.raises(ValueError, match="increase"):
        stats.auc([0, 10, 10], [1, 2, 3])


def test_final_window_mean():
    steps = [0, 25_000, 50_000, 75_000, 100_000]
    # the evaluations at >= 100k − 50k: 3, 4, 5
    assert stats.final_window_mean(steps, [1, 2, 3, 4, 5], 50_000) == pytest.approx(4.0)
    assert stats.final_window_mean(steps, [1, 2, 3, 4, 5], 0) == pytest.approx(5.0)


def test_normalize_by_task_shares_min_and_max_across_methods():
    out = stats.normalize_by_task({"A": {"m1": [1.0, 3.0], "m2": [5.0]}, "B": {"m1": [2.0, 2.0]}})
    np.testing.assert_allclose(out["A"]["m1"], [0.0, 0.5])
    np.testing.assert_allclose(out["A"]["m2"], [1.0])
    np.testing.assert_allclose(out["B"]["m1"], [0.0, 0.0])  # all equal: 0


def test_aggregate_of_known_scores():
    # 4 seeds × 2 tasks. Per-task means: 103/4 = 25.75 and 100/4 = 25; median and mean of the two: 25.375.
    # IQM pools the 8 scores 0 1 2 10 20 30 40 100 and drops 2 at each end: mean(2, 10, 20, 30) = 15.5.
    # Optimality gap: 1 − mean(min(x, 1)) = 1 − 7/8.
    scores = np.array([[0, 10], [1, 20], [2, 30], [100, 40]], dtype=float)
    np.testing.assert_allclose(stats.aggregate(scores), [25.375, 15.5, 25.375, 0.125])


def test_aggregate_intervals_are_rliables():
    rng = np.random.default_rng(0)
    scores = {"a": rng.random((5, 3)), "b": rng.random((5, 3)) * 0.5}
    points, intervals = stats.aggregate_intervals(scores, resamples=500)

    def fn(x):
        return np.array([metrics.aggregate_median(x), metrics.aggregate_iqm(x), metrics.aggregate_mean(x),
                         metrics.aggregate_optimality_gap(x)])

    state = np.random.get_state()
    np.random.seed(stats.SEED)
    want_p, want_i = library.get_interval_estimates({"a": scores["a"]}, fn, reps=500)
    after = np.random.get_state()
    np.random.set_state(state)
    np.testing.assert_array_equal(points["a"], want_p["a"])
    np.testing.assert_array_equal(intervals["a"], want_i["a"])
    assert np.all(intervals["b"][0] <= points["b"]) and np.all(points["b"] <= intervals["b"][1])
    # reproducible, and the caller's global NumPy generator is left alone
    state = np.random.get_state()
    again = stats.aggregate_intervals(scores, resamples=500)[1]
    np.testing.assert_array_equal(again["a"], intervals["a"])
    assert np.array_equal(np.random.get_state()[1], state[1])
    assert not np.array_equal(after[1], state[1])


def test_no_interval_below_min_seeds():
    assert stats.MIN_SEEDS == 3
    points, intervals = stats.aggregate_intervals({"two": np.array([[0.2, 0.4], [0.6, 0.8]])})
    assert intervals["two"] is None
    np.testing.assert_allclose(points["two"][2], 0.5)
    mean, lo, hi = stats.mean_interval([[1.0, 2.0], [3.0, 4.0]])
    np.testing.assert_allclose(mean, [2.0, 3.0])
    assert lo is None and hi is None


def test_mean_and_iqm_intervals_per_column():
    values = np.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0], [4.0, 40.0], [10.0, 50.0]])
    mean, lo, hi = stats.mean_interval(values, resamples=1000)
    np.testing.assert_allclose(mean, [4.0, 30.0])
    # a resampled mean lies within the seeds' range: the percentile bounds too
    assert np.all(lo >= values.min(axis=0)) and np.all(hi <= values.max(axis=0))
    assert np.all(lo < mean) and np.all(mean < hi)
    iqm, ilo, ihi = stats.iqm_interval(values[:, 0], resamples=1000)
    # rliable's IQM of 1 2 3 4 10 (trim_mean 0.25: int(1.25) = 1 cut at each end): mean(2, 3, 4) = 3
    assert iqm[0] == pytest.approx(3.0) == metrics.aggregate_iqm(values[:, 0])
    assert ilo[0] <= 3.0 <= ihi[0]


def _rliables(data, fn, reps, confidence=0.95):
    """rliable's own interval of `fn` on `data` (an array, or a tuple resampled independently) under
    `stats.SEED`, one call of `fn` per resample: the plain formulation the fast path replaces."""
    state = np.random.get_state()
    np.random.seed(stats.SEED)
    try:
        _, want = library.get_interval_estimates({"d": data}, fn, reps=reps,
                                                 confidence_interval_size=confidence)
    finally:
        np.random.set_state(state)
    return want["d"]


@pytest.mark.parametrize("chunk", [None, 200])
def test_every_interval_is_rliables_to_the_last_bit(chunk, monkeypatch):
    """The fast path (`stratified_bootstrap` with rliable's aggregates over a resample axis) against
    rliable's `get_interval_estimates` calling rliable's own statistic once per resample, at sizes where
    NumPy sums pairwise (15 seeds × 7 tasks, 15 seeds per column) and with unequal seed counts; in one
    chunk of resamples, and in chunks of 200 scores (1–6 resamples each, their draws consecutive)."""
    if chunk is not None:
        monkeypatch.setattr(common_stats, "CHUNK_ENTRIES", chunk)
    rng = np.random.default_rng(7)
    reps = 700
    scores = rng.random((15, 7))
    _, got = stats.aggregate_intervals({"a": scores}, resamples=reps)
    want = _rliables(scores, lambda x: np.array([metrics.aggregate_median(x), metrics.aggregate_iqm(x),
                                                 metrics.aggregate_mean(x),
                                                 metrics.aggregate_optimality_gap(x)]), reps)
    np.testing.assert_array_equal(got["a"], want)

    x, y = rng.random((7, 3)), rng.random((4, 3)) * 0.8
    for statistic, confidence in (("IQM", 0.95), ("Median", 0.95), ("Mean", 0.9)):
        agg = getattr(metrics, stats.STATISTICS[statistic])
        _, lo, hi = stats.difference_interval(x, y, statistic, resamples=reps, confidence=confidence)
        want = _rliables((x, y), lambda a, b, agg=agg: np.array([agg(a) - agg(b)]), reps, confidence)
        assert (lo, hi) == (float(want[0][0]), float(want[1][0])), statistic

    curves = rng.random((15, 4)) * 100
    plain = {"mean": lambda v: np.mean(v, axis=0), "median": lambda v: np.median(v, axis=0),
             "iqm": lambda v: np.array([metrics.aggregate_iqm(v[:, j]) for j in range(v.shape[1])])}
    for statistic, fn in plain.items():
        point, lo, hi = stats.column_interval(curves, statistic, resamples=reps)
        want = _rliables(curves, fn, reps)
        np.testing.assert_array_equal(point, fn(curves))
        np.testing.assert_array_equal(np.stack([lo, hi]), want, err_msg=statistic)


def test_stratified_bootstrap_refuses_arrays_it_cannot_stratify():
    with pytest.raises(ValueError, match=r"same columns, got \[\(3, 2\), \(3, 4\)\]"):
        common_stats.stratified_bootstrap((np.zeros((3, 2)), np.zeros((3, 4))), lambda a, b: a[:, 0, :1])
    with pytest.raises(ValueError, match=r"got \[\(3,\)\]"):
        common_stats.stratified_bootstrap([np.zeros(3)], lambda a: a)
