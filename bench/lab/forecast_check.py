"""How close the study runner's forecasts come to the wall times runs took.

    python -m bench.lab.forecast_check results/fig7-td3 results/fig7-sac \\
        --runs results/fig7-sac/runs/AcrobotSwingup/*/seeds-* [--markdown]
    python -m bench.lab.forecast_check results/fig7-sac --by-task [--new-task-rule seed-count]

The runs named by `--runs` (finished run folders of the study folders given) are forecast as the runner
would have before any of them ran (`--dry-run`, `--finish-within`, `--forecast-from`): from every *other*
finished run there, by sf2_studies/runner.py `Forecast`; with `--leave-one-out` each from all runs but
itself; with `--by-task` each task's runs (all runs without `--runs`) from the other tasks' alone, as for a
task with no finished run (`--new-task-rule`: the runner's rule, `method-scaled`, or one it replaced or kept
out, docs/decisions/forecasts.md). Per run: the forecast, the wall time taken (its last `walltime`,
restarts included) and their ratio, then the sums and the ratios' spread; a ratio above 1 is a run
`--finish-within` could have started too late. results/fig7-sac/README.md "Cost per run" uses it.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

from sf2_studies import runner
from sf2_studies.spec import StudyError

from bench.report import print_rows

FIELDS = ("run", "seeds", "forecast_s", "actual_s", "ratio")


class AnySeedCount(runner.Forecast):
    """`runner.Forecast` with a task with no finished run at the largest finished rate of any seed count,
    each scaled to the job's seed count by `scale`, whatever the job's method (kept out)."""

    def rate(self, task: str, folder: str, seeds: int = 1) -> float:
        if self.has_task(task):   # the runner's first three preferences, and its last over the task's runs
            return super().rate(task, folder, seeds)
        return max(r * self.scale(m, seeds) for t, f in self.rates for m, r in self._rates(t, f))


class SeedCount(runner.Forecast):
    """`runner.Forecast` without its fourth preference: a task with no finished run at the slowest run of
    the job's seed count (else of any, scaled), whatever the job's method; the runner's rule before
    docs/decisions/forecasts.md "Added: a new task scaled to the job's method"."""

    def scaled_slowest(self, folder: str, seeds: int) -> float | None:
        return None


RULES = {"method-scaled": runner.Forecast, "seed-count": SeedCount, "any-seed-count": AnySeedCount}


def check(history: list[runner.Job], targets: list[runner.Job], each: bool = False,
          forecast_cls: type[runner.Forecast] = runner.Forecast) -> list[dict]:
    """One row of FIELDS per target job, forecast from `history` (the targets themselves left out of it) as
    a job with none of its env steps done. With `each` (leave one out) every target is forecast from all
    of `history` but itself: how the forecasts of a study's next runs fare, now that it has the others.
    `forecast_cls` is the forecaster (`RULES`)."""
    def forecast_without(left_out: list[runner.Job]) -> runner.Forecast:
        names = {t.path.resolve() for t in left_out}
        forecast = forecast_cls([j for j in history if j.path.resolve() not in names])
        if not forecast.known:
            raise StudyError("no finished run outside --runs to forecast from: give more study folders or "
                             "fewer --runs")
        return forecast

    shared = None if each else forecast_without(targets)
    rows = []
    for job in targets:
        forecast = shared if shared is not None else forecast_without([job])
        predicted = forecast.seconds(runner.Job(job.run, job.path, [], job.total_steps, 0))
        actual = runner.Forecast.wall(job)
        rows.append({"run": job.name, "seeds": len(getattr(job.run, "seeds", None) or (0,)),
                     "forecast_s": round(predicted, 1), "actual_s": round(actual, 1),
                     "ratio": round(actual / predicted, 3)})
    return rows


def check_by_task(history: list[runner.Job], targets: list[runner.Job],
                  forecast_cls: type[runner.Forecast] = runner.Forecast) -> list[dict]:
    """`check` task by task: each task's targets forecast from every run of `history` on other tasks."""
    rows = []
    for task in sorted({t.run.task for t in targets}):
        rows += check([j for j in history if j.run.task != task], [t for t in targets if t.run.task == task],
                      forecast_cls=forecast_cls)
    return rows


def summary(rows: list[dict]) -> str:
    """The sums and the spread of the ratios (actual / forecast) of `check`'s rows."""
    ratios = [r["ratio"] for r in rows]
    forecast, actual = sum(r["forecast_s"] for r in rows), sum(r["actual_s"] for r in rows)
    return (f"{len(rows)} run(s): forecast {forecast / 60:.1f} min in all, took {actual / 60:.1f} min "
            f"({actual / forecast:.2f}x); actual / forecast per run: min {min(ratios):.2f}, median "
            f"{statistics.median(ratios):.2f}, max {max(ratios):.2f}; "
            f"{sum(x > 1 for x in ratios)} took longer than forecast")


def main(argv=None) -> int:
    from sf2_jax.cli import backend as jax_backend
    from sf2_studies import commands

    parser = argparse.ArgumentParser(prog="python -m bench.lab.forecast_check",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("studies", nargs="+", type=Path, help="study folders (their finished runs)")
    parser.add_argument("--runs", nargs="+", type=Path,
                        help="finished run folders of those studies to forecast from all the others "
                             "(required without --by-task; with it, all finished runs by default)")
    parser.add_argument("--by-task", action="store_true",
                        help="forecast each task's runs from the other tasks' runs alone")
    parser.add_argument("--new-task-rule", choices=sorted(RULES), default="method-scaled",
                        help="the forecast of a task with no finished run: the runner's (method-scaled), the "
                             "one it replaced (seed-count) or one kept out (any-seed-count); "
                             "docs/decisions/forecasts.md")
    parser.add_argument("--leave-one-out", action="store_true",
                        help="forecast each of --runs from every other finished run (the others of --runs "
                             "included), not all of them from the runs outside --runs")
    parser.add_argument("--markdown", action="store_true", help="a Markdown table instead of JSON lines")
    args = parser.parse_args(argv)
    if args.runs is None and not args.by_task:
        parser.error("--runs is required without --by-task")
    if args.by_task and args.leave_one_out:
        parser.error("--by-task and --leave-one-out are two ways of choosing the history: give one")
    try:
        backend = jax_backend()
        history = [j for s in args.studies for j in commands.finished_runs(backend, s)]
        by_path = {j.path.resolve(): j for j in history}
        missing = [str(p) for p in args.runs or () if p.resolve() not in by_path]
        if missing:
            raise StudyError(f"--runs: not a finished run of {', '.join(map(str, args.studies))}: "
                             f"{', '.join(missing)}")
        targets = history if args.runs is None else [by_path[p.resolve()] for p in args.runs]
        rule = RULES[args.new_task_rule]
        rows = (check_by_task(history, targets, rule) if args.by_task
                else check(history, targets, each=args.leave_one_out, forecast_cls=rule))
    except StudyError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print_rows(rows, FIELDS, args.markdown)
    print(summary(rows), file=sys.stdout if args.markdown else sys.stderr)   # JSON lines stay parseable
    return 0


if __name__ == "__main__":
    sys.exit(main())
