"""How close the study runner's forecasts come to the wall times runs took.

    python -m bench.lab.forecast_check results/fig7-td3 results/fig7-sac \\
        --runs results/fig7-sac/runs/AcrobotSwingup/*/seeds-* [--markdown]

The runs named by `--runs` (finished run folders inside the study folders given) are forecast as the
runner would have forecast them before any of them ran (`study run --dry-run`, `--finish-within`,
`--forecast-from`): from every *other* finished run of those study folders, by
sf2_studies/runner.py `Forecast`; with `--leave-one-out` each of them from all runs but itself (how
the forecasts of a study's next runs fare once it has the others). Per run: the forecast, the wall time it
took (its last metrics row's `walltime`, restarts included, as `Forecast` reads it) and their ratio; then
the sums and the spread of the ratios. A ratio above 1 is a run that took longer than forecast: one
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


def check(history: list[runner.Job], targets: list[runner.Job], each: bool = False) -> list[dict]:
    """One row of FIELDS per target job, forecast from `history` (the targets themselves left out of it) as
    a job with none of its env steps done. With `each` (leave one out) every target is forecast from all
    of `history` but itself: how the forecasts of a study's next runs fare, now that it has the others."""
    def forecast_without(left_out: list[runner.Job]) -> runner.Forecast:
        names = {t.path.resolve() for t in left_out}
        forecast = runner.Forecast([j for j in history if j.path.resolve() not in names])
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
    parser.add_argument("--runs", nargs="+", type=Path, required=True,
                        help="finished run folders of those studies to forecast from all the others")
    parser.add_argument("--leave-one-out", action="store_true",
                        help="forecast each of --runs from every other finished run (the others of --runs "
                             "included), not all of them from the runs outside --runs")
    parser.add_argument("--markdown", action="store_true", help="a Markdown table instead of JSON lines")
    args = parser.parse_args(argv)
    try:
        backend = jax_backend()
        history = [j for s in args.studies for j in commands.finished_runs(backend, s)]
        by_path = {j.path.resolve(): j for j in history}
        missing = [str(p) for p in args.runs if p.resolve() not in by_path]
        if missing:
            raise StudyError(f"--runs: not a finished run of {', '.join(map(str, args.studies))}: "
                             f"{', '.join(missing)}")
        rows = check(history, [by_path[p.resolve()] for p in args.runs], each=args.leave_one_out)
    except StudyError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print_rows(rows, FIELDS, args.markdown)
    print(summary(rows), file=sys.stdout if args.markdown else sys.stderr)   # JSON lines stay parseable
    return 0


if __name__ == "__main__":
    sys.exit(main())
