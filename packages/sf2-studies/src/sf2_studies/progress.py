"""The one progress view of a study run: runs done of total, env steps done of total (summed over runs and
seeds, read from the runs' metrics.jsonl), elapsed time and an ETA from the env-step rate of this
command. On a terminal it is one line rewritten in place; otherwise (a log file, CI) a line every
`interval` seconds. Events (a run finished or failed) are printed as their own lines."""

from __future__ import annotations

import sys
import time

__all__ = ["Progress", "duration", "steps_text"]


def duration(seconds: float) -> str:
    """'42s', '5m12s', '3h07m'."""
    s = int(round(seconds))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{(s % 3600) // 60:02d}m"


def steps_text(n: float) -> str:
    """'950', '12.4k', '3.20M'."""
    if n < 1e3:
        return f"{n:.0f}"
    if n < 1e6:
        return f"{n / 1e3:.1f}k"
    return f"{n / 1e6:.2f}M"


class Progress:
    def __init__(self, name: str, total_runs: int, total_steps: int, *, enabled: bool = True,
                 stream=None, interval: float | None = None):
        self.name, self.total_runs, self.total_steps = name, total_runs, max(int(total_steps), 1)
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval = interval if interval is not None else (1.0 if self.tty else 30.0)
        self.t0 = time.monotonic()
        self.start_steps: int | None = None
        self._last_shown = -1e9
        self._width = 0

    def line(self, runs_done: int, running: int, steps: int, failed: int = 0) -> str:
        if self.start_steps is None:
            self.start_steps = steps
        elapsed = time.monotonic() - self.t0
        rate = (steps - self.start_steps) / elapsed if elapsed > 0 else 0.0
        remaining = max(self.total_steps - steps, 0)
        eta = duration(remaining / rate) if rate > 0 and runs_done < self.total_runs else "—"
        text = (f"{self.name}: runs {runs_done}/{self.total_runs} done, {running} running"
                + (f", {failed} failed" if failed else "")
                + f" | env steps {steps_text(steps)}/{steps_text(self.total_steps)} "
                f"({100 * steps / self.total_steps:.0f}%) | {duration(elapsed)} elapsed, ETA {eta}")
        return text

    def update(self, runs_done: int, running: int, steps: int, failed: int = 0, force: bool = False) -> None:
        text = self.line(runs_done, running, steps, failed)
        now = time.monotonic()
        if not self.enabled or (not force and now - self._last_shown < self.interval):
            return
        self._last_shown = now
        if self.tty:
            pad = max(self._width - len(text), 0)
            self.stream.write("\r" + text + " " * pad)
            self._width = len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def event(self, text: str) -> None:
        """A line of its own (a run started, finished or failed), above the progress line."""
        if self.tty and self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self._width = 0
        self.stream.write(text + "\n")
        self.stream.flush()
        self._last_shown = -1e9   # redraw the progress line at the next update

    def close(self) -> None:
        if self.tty and self._width:
            self.stream.write("\n")
            self.stream.flush()
