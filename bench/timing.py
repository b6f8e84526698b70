"""Timing protocol shared by every framework.

A `Runner` wraps one compiled/eager update with `step()` (dispatch one update, no sync) and `sync()`
(wait until the device finished everything dispatched). `measure` times all runners of one run in
interleaved rounds, so every ratio (SF²/vanilla, T=8/T=1, torch/JAX) compares numbers taken under the
same machine conditions:

1. warm-up: `warmup` updates per runner (compilation and autotuning excluded), then a calibration that
   picks the block length n so that one block lasts about `block_s` seconds;
2. `repeats` rounds; in each round every runner (in an order rotated by one per round) runs n updates
   between two synchronizations: t = (wall time of the block) / n. The device is synchronized before
   the clock starts and after the last update, so the block measures device work, not dispatch.

Per runner: the median over rounds, the quartiles, the minimum. Paired ratios are taken per round and
their median reported (robust to drift on a shared machine).
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import time
from collections.abc import Callable, Sequence


@dataclasses.dataclass
class Runner:
    name: str
    step: Callable[[], None]
    sync: Callable[[], None]
    n: int = 1                      # updates per timed block (calibrated)
    times: list[float] = dataclasses.field(default_factory=list)   # seconds per update, one per round
    compile_s: float = float("nan")
    probe_s: float = 0.0            # seconds per call seen during calibration
    per_call: int = 1               # updates done by one `step()` (JAX lax.scan of several updates)

    def block(self, n: int) -> float:
        """Seconds per update over n calls of `step()`."""
        self.sync()
        t0 = time.perf_counter()
        for _ in range(n):
            self.step()
        self.sync()
        return (time.perf_counter() - t0) / (n * self.per_call)


def calibrate(runner: Runner, warmup: int, block_s: float, max_n: int = 10_000) -> None:
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
    k = len(runners)
    for r in range(repeats):
        order = [runners[(i + r) % k] for i in range(k)]
        for runner in order:
            runner.times.append(runner.block(runner.n))
        log(f"  round {r + 1}/{repeats} done")


def quantile(xs: Sequence[float], q: float) -> float:
    xs = sorted(xs)
    if not xs:
        return float("nan")
    pos = (len(xs) - 1) * q
    lo, hi = math.floor(pos), math.ceil(pos)
    return xs[lo] + (xs[hi] - xs[lo]) * (pos - lo)


def summary(times: Sequence[float]) -> dict:
    if not times:
        return dict(median=float("nan"), q25=float("nan"), q75=float("nan"), min=float("nan"))
    return dict(median=statistics.median(times), q25=quantile(times, 0.25), q75=quantile(times, 0.75),
                min=min(times))


def paired_ratio(num: Sequence[float], den: Sequence[float]) -> tuple[float, float, float]:
    """Median and quartiles of per-round ratios num[r]/den[r]."""
    ratios = [a / b for a, b in zip(num, den) if b > 0]
    if not ratios:
        return float("nan"), float("nan"), float("nan")
    return statistics.median(ratios), quantile(ratios, 0.25), quantile(ratios, 0.75)
