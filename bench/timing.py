"""Timing protocol shared by every framework.

A `Runner` wraps one compiled or eager update with `step()` (dispatch one update) and `sync()` (wait for
the device). `calibrate` warms a runner up (compilation and autotuning excluded) and picks the block
length n so that one block lasts about `block_s` seconds; `measure` then times every runner of a run in
interleaved rounds (the order rotated by one per round), each block of n updates between two device
synchronizations, so it measures device work, not dispatch. Per runner: the median over rounds, the
quartiles, the minimum. Ratios (SF²/vanilla, T=8/T=1, torch/JAX) are taken per round and their median
reported: both numbers come from the same seconds of the same machine.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import time
from collections.abc import Callable, Sequence


@dataclasses.dataclass
class Runner:
    """One timed update: `step()` dispatches it, `sync()` waits until the device has finished."""

    name: str
    step: Callable[[], None]
    sync: Callable[[], None]
    n: int = 1                      # updates per timed block (calibrated)
    times: list[float] = dataclasses.field(default_factory=list)   # seconds per update, one per round
    compile_s: float = float("nan")
    probe_s: float = 0.0            # seconds per call seen during calibration
    per_call: int = 1               # updates done by one `step()` (JAX lax.scan of several updates)

    def block(self, n: int) -> float:
        """Time one block.

        Args:
            n: calls of `step()` between the two synchronizations.

        Returns:
            Seconds per update over the block.
        """
        self.sync()
        t0 = time.perf_counter()
        for _ in range(n):
            self.step()
        self.sync()
        return (time.perf_counter() - t0) / (n * self.per_call)


def calibrate(runner: Runner, warmup: int, block_s: float, max_n: int = 10_000) -> None:
    """Warm a runner up and set its block length `runner.n`.

    Args:
        runner: the runner; its `n` and `probe_s` are set.
        warmup: calls before the calibration.
        block_s: the seconds one timed block should last.
        max_n: the most calls per block.
    """
    for _ in range(warmup):
        runner.step()
    runner.sync()
    # grow n until one block takes ≥ block_s/4, then scale to block_s
    n, t = 1, runner.block(1)
    while t * n < block_s / 4 and n < max_n:
        n = min(max_n, n * 4)
        t = runner.block(n)
    t *= runner.per_call   # seconds per call
    runner.n = max(1, min(max_n, math.ceil(block_s / max(t, 1e-9))))
    runner.probe_s = t


def measure(runners: Sequence[Runner], repeats: int, log: Callable[[str], None] = print) -> None:
    """Time every runner in interleaved rounds, appending one time per round to `runner.times`.

    Args:
        runners: calibrated runners.
        repeats: rounds; each times one block of every runner, in an order rotated by one per round.
        log: called with one line per round.
    """
    k = len(runners)
    for r in range(repeats):
        order = [runners[(i + r) % k] for i in range(k)]
        for runner in order:
            runner.times.append(runner.block(runner.n))
        log(f"  round {r + 1}/{repeats} done")


def quantile(xs: Sequence[float], q: float) -> float:
    """Linearly interpolated quantile.

    Args:
        xs: values.
        q: quantile in [0, 1].

    Returns:
        The quantile, NaN for no values.
    """
    xs = sorted(xs)
    if not xs:
        return float("nan")
    pos = (len(xs) - 1) * q
    lo, hi = math.floor(pos), math.ceil(pos)
    return xs[lo] + (xs[hi] - xs[lo]) * (pos - lo)


def summary(times: Sequence[float]) -> dict:
    """Summarize a runner's times.

    Args:
        times: seconds per update, one per round.

    Returns:
        {"median", "q25", "q75", "min"} (NaN for no times).
    """
    if not times:
        return dict(median=float("nan"), q25=float("nan"), q75=float("nan"), min=float("nan"))
    return dict(median=statistics.median(times), q25=quantile(times, 0.25), q75=quantile(times, 0.75),
                min=min(times))


def paired_ratio(num: Sequence[float], den: Sequence[float]) -> tuple[float, float, float]:
    """Ratio of two runners' times, paired per round.

    Args:
        num: the numerator runner's times, one per round.
        den: the denominator runner's times of the same rounds.

    Returns:
        (median, first quartile, third quartile) of num[r] / den[r] over the rounds.
    """
    ratios = [a / b for a, b in zip(num, den) if b > 0]
    if not ratios:
        return float("nan"), float("nan"), float("nan")
    return statistics.median(ratios), quantile(ratios, 0.25), quantile(ratios, 0.75)
