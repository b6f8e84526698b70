"""The `study` subcommand of `sf2-jax` and `sf2-torch`: `COMMAND`, the entry point `study` of the group
`sf2.commands`, which each core's command line finds; it adds its parser with `add_parser` and runs with
`main(backend, args)`:

    PROG study run FILE --out DIR [--tasks A,B] [--methods m1,m2] [--seeds 0-4] [--workers N]
                   [--ray ADDRESS] [--finish-within SECONDS] [--forecast-from DIR] [--skip-done-in DIR]
                   [--dry-run]
    PROG study report DIR [--out REPORT_DIR]
    PROG study merge SOURCE... --into DIR [--partial] [--study STUDY.toml]
    PROG study borrow DIR --from OTHER [--dry-run]  |  PROG study compress DIR
    PROG study compare DIR... --out DIR
    PROG study export DIR --out FILE.csv|FILE.parquet

Bad input exits with status 2 and writes nothing; `run` exits 0 when every selected run is done, 1 if one
failed or was held by another process. FILE may also name a file in ./studies/ (`smoke`)."""

from __future__ import annotations

import functools
import os
import shlex
import sys
import types
from pathlib import Path

from sf2_common.cli import Backend
from sf2_common.errors import ConfigError

from .progress import duration
from .spec import StudyError

__all__ = ["COMMAND", "add_parser", "main", "finished_runs"]


def add_parser(sub, prog: str) -> None:
    s = sub.add_parser("study", help="tasks × methods × seeds from a study file: run, report (paper §4.2)",
                       description="Train a study file's tasks × methods × seeds (resumable, on every local "
                       "GPU or a Ray cluster) and report them the way the paper does (§4.2, Appendix C).")
    ssub = s.add_subparsers(dest="study_command", required=True)
    r = ssub.add_parser("run", help="train a study's runs (resumable; skips finished runs)")
    r.add_argument("file", help="study file (TOML), e.g. studies/fig7-td3.toml, or its name in ./studies/")
    r.add_argument("--out", required=True, help="study folder (created, or continued if it holds this study)")
    r.add_argument("--tasks", default=None, help="only these tasks (comma-separated)")
    r.add_argument("--methods", default=None, help="only these methods (names or labels, comma-separated)")
    r.add_argument("--seeds", default=None,
                   help="only the seed groups wholly inside these seeds (e.g. 0-4; the study file's "
                   "seeds_per_run makes the groups)")
    r.add_argument("--workers", type=int, default=None,
                   help="runs at a time on this host (default: one per visible GPU, else 1); with "
                   "--dry-run, the workers its estimate plans for")
    r.add_argument("--finish-within", metavar="SECONDS", type=float, default=None,
                   help="start a run only if the forecast from the finished runs' rates ends it within "
                   "SECONDS from now (e.g. the time left on a leased machine); runs started are never "
                   "stopped")
    r.add_argument("--forecast-from", metavar="DIR", action="append", default=[],
                   help="another study folder whose finished runs also feed the forecasts (--dry-run, "
                   "--finish-within), e.g. results/fig7-td3 for fig7-sac's first runs, which have no "
                   "finished run of their own to forecast from; read only (repeatable)")
    r.add_argument("--skip-done-in", metavar="DIR", action="append", default=[],
                   help="another study folder: a run it holds finished with exactly this run's config "
                   "(no superseded preset value) and seeds is not run here, e.g. the study's own results "
                   "folder when --out is a second one to merge back into it; read only (repeatable)")
    r.add_argument("--ray", metavar="ADDRESS", default=None,
                   help="dispatch each run as a Ray task to this cluster ('local': start one here, 'auto')")
    r.add_argument("--ray-gpus", type=float, default=1.0,
                   help="GPUs each Ray task requests (default 1; 0 on a CPU-only cluster)")
    r.add_argument("--ray-cpus", type=float, default=1.0, help="CPUs each Ray task requests (default 1)")
    r.add_argument("--dry-run", action="store_true", help="print the runs and their state; train nothing")
    r.add_argument("--no-progress", action="store_true", help="no progress line (events only)")
    r.add_argument("--log", default=None, metavar="SINKS",
                   help="passed to each run's `train --log` (tensorboard, wandb or both, comma-separated)")
    p = ssub.add_parser("report", help="results.csv, summary.md and figures of a study folder")
    p.add_argument("dir", help="study folder")
    p.add_argument("--out", default=None, help="report folder (default: DIR/report)")
    k = ssub.add_parser("compare", help="several study folders' aggregates and claim verdicts side by side",
                        description="Write summary.md (each study's aggregate per family and its claims' "
                        "comparisons, a column per folder) and aggregate.png/svg (every family's panels in "
                        "one figure, as the paper's Fig. 7) into OUT. Each study keeps its own "
                        "normalization and intervals; nothing is pooled. One study file run into two "
                        "folders (e.g. at two settings) compares too.")
    k.add_argument("dirs", nargs="+", metavar="DIR", help="study folder (two or more)")
    k.add_argument("--out", required=True, help="folder for summary.md and the figure")
    g = ssub.add_parser("merge", help="join the runs of study folders or their .tar.gz archives into one "
                        "study folder", description="Copy the finished runs of each SOURCE (a study folder "
                        "or a .tar.gz archive of one, e.g. from scripts/gpu-host/gpu_study.sh) into the "
                        "study folder DIR: config.json, metrics.jsonl, train.log and evaluation results "
                        "only. Refuses (nothing written) another study, a run whose config is not the "
                        "study's, or a finished run DIR holds with other metrics (unless --keep-reruns); "
                        "skips identical ones.")
    g.add_argument("sources", nargs="+", metavar="SOURCE", help="study folder or .tar.gz archive of one")
    g.add_argument("--into", required=True, metavar="DIR",
                   help="the study folder to merge into (created if it does not exist)")
    g.add_argument("--partial", action="store_true",
                   help="also merge unfinished runs (where DIR has none or less of it); without checkpoints "
                   "they cannot resume: `study run` then needs the run folder removed to train it again")
    g.add_argument("--study", default=None, metavar="STUDY.toml",
                   help="take runs of other studies: DIR holds this study file's study, and of each SOURCE "
                   "(any study) only the run folders at one of its runs' paths whose config and seeds are "
                   "that run's are merged (e.g. the baselines two studies share), the rest ignored; DIR's "
                   "study.json records this command instead of the sources' commands")
    g.add_argument("--keep-reruns", action="store_true",
                   help="a finished run DIR already holds with other metrics (the same config and seeds "
                   "run twice: GPU runs differ) is kept in DIR/rerun/<task>-<method>/<seeds>/, out of the "
                   "results (the report compares it with the run it repeats), and the rest is merged; "
                   "without it the merge is refused")
    b = ssub.add_parser("borrow", help="read the runs another study folder holds finished there, keeping no "
                        "copy", description="Of DIR's runs, those the study folder OTHER holds finished with "
                        "exactly their config and seeds, and DIR identically (every file equal) or not at "
                        "all, are read in OTHER from now on: DIR's study.json names OTHER for each, and "
                        "DIR's copy is removed. `study run`, `report`, `compare`, `export` and `merge` read "
                        "them there and never write them; a run DIR holds with other contents stays DIR's.")
    b.add_argument("dir", metavar="DIR", help="study folder whose runs are borrowed")
    b.add_argument("--from", dest="lender", required=True, metavar="OTHER",
                   help="the study folder that holds the runs (e.g. results/fig7-td3 for results/own-adam)")
    b.add_argument("--dry-run", action="store_true", help="say what would be borrowed; change nothing")
    c = ssub.add_parser("compress", help="gzip the metrics.jsonl and obs_noise.json of a study folder's "
                        "finished runs", description="Replace each finished run's metrics.jsonl and "
                        "obs_noise.json by a .gz of it (4-5x smaller; `study report`, `study run` and "
                        "`study merge` read either form, as do zcat and pandas). `study merge` does this to "
                        "the runs it writes. Unfinished runs are left as they are.")
    c.add_argument("dir", help="study folder")
    x = ssub.add_parser("export", help="every run of a study folder as one long table (CSV or Parquet)",
                        description="Write one row per task, method, seed and evaluation (env step, eval "
                        "return) of every run folder, finished or not (column `finished`), with the study's "
                        "name, the commit of the git repository the folder lies in and the config fields "
                        "that differ between runs: the table rliable and openrlbenchmark users load. "
                        "Parquet needs pyarrow.")
    x.add_argument("dir", help="study folder")
    x.add_argument("--out", required=True, metavar="FILE", help="the table: FILE.csv or FILE.parquet")


def _study_file(text: str) -> Path:
    path = Path(text)
    if not path.exists() and not path.suffix and (Path("studies") / f"{text}.toml").exists():
        return Path("studies") / f"{text}.toml"
    return path


def _names(text):
    return [x.strip() for x in text.split(",") if x.strip()] if text else None


def main(backend: Backend, args) -> int:
    """Run `PROG study ...`.

    Args:
        backend: what the core that runs the command gives (sf2_common.cli.Backend).
        args: the parsed arguments; `args.argv`, the command's arguments, is recorded in the study folder
            and summary.md.

    Returns:
        The exit status: 0 done, 1 a run failed or was held by another runner (`study run`).
    """
    command = " ".join([backend.prog, *map(shlex.quote, getattr(args, "argv", []))])
    try:
        if args.study_command == "report":
            return _report(args, command)
        if args.study_command == "compare":
            return _compare(args, command)
        if args.study_command == "merge":
            return _merge(backend, args, command)
        if args.study_command == "borrow":
            return _borrow(backend, args)
        if args.study_command == "compress":
            return _compress(backend, args)
        if args.study_command == "export":
            return _export(args)
        return _run(backend, args, command)
    except ImportError as err:   # an extra that is not installed: the message names it
        raise StudyError(str(err)) from None


def _run(backend, args, command: str) -> int:
    from . import runner, spec
    from .folder import StudyFolder

    base_env = dict(os.environ)
    study = spec.load(_study_file(args.file))
    if study.framework is not None and study.framework != backend.name:
        raise StudyError(f"{study.path}: framework = {study.framework!r}: run it with "
                         f"`sf2-{study.framework} study run`, not {backend.prog}")
    if args.workers is not None and args.workers < 1:
        raise StudyError(f"--workers {args.workers} is invalid: an int >= 1")
    if args.finish_within is not None and not args.finish_within > 0:
        raise StudyError(f"--finish-within {args.finish_within} is invalid: seconds > 0")
    if args.log is not None:   # refused before any run starts: an unknown sink, or one not installed
        from sf2_common.agents.loggers import parse_log

        try:
            parse_log(args.log)
        except ConfigError as err:
            raise StudyError(str(err)) from None
    if args.finish_within is not None and args.ray is not None:
        raise StudyError("--finish-within is for this host's runner, not --ray")
    if args.ray is not None:
        from .rayrun import _ray

        _ray()
    runs = _resolve(backend, study)
    selected = spec.select_runs(study, runs, _names(args.tasks), _names(args.methods), args.seeds)
    folder = StudyFolder(args.out)
    folder.check(study, backend.name, runs)
    jobs, done = runner.plan(study, folder, selected, args.log)
    elsewhere = _done_elsewhere(study, folder, jobs, getattr(args, "skip_done_in", []))
    jobs = [job for job in jobs if job.name not in elsewhere]
    # Forecasts (the dry run's estimate, --finish-within) draw on every finished run of the folder, and of
    # the --forecast-from folders.
    history = done if len(selected) == len(runs) else runner.plan(study, folder, runs)[1]
    history = history + _finished_elsewhere(backend, args.forecast_from, folder)
    if args.dry_run:
        groups = study.select_groups(args.seeds)
        print(f"{study.name} ({study.path}) → {folder.path}: {len(selected)} run(s) selected of {len(runs)}"
              + (f"; seed groups {', '.join(spec.seeds_text(g) for g in groups)}"
                 if study.seeds_per_run else ""))
        for job in done:
            print(f"  done     {job.name}")
        _say_elsewhere(elsewhere)
        forecast = runner.Forecast(history)
        for job in jobs:
            state = "partial" if job.done_steps else "new"
            eta = f" (≈ {duration(forecast.seconds(job))})" if forecast.known else ""
            module = job.run.cli_module
            prog = backend.prog if module is None else "sf2-" + module.split(".")[0].removeprefix("sf2_")
            steps = " ; ".join(f"{prog} {' '.join(c)}" for c in job.commands)
            print(f"  {state:8} {job.name}{eta}: {steps}")
        where = "here" + "".join(f" and in {p}" for p in args.forecast_from)
        workers = args.workers or len(runner.visible_gpus(base_env)) or 1   # as run_local's slots
        total = runner.estimate(history, jobs, forecast, where, workers)
        if total:
            print(total)
        return 0
    folder.open(study, backend.name, runs, command)
    _say_elsewhere(elsewhere)
    if args.ray is not None:
        from .rayrun import run_ray

        outcome = run_ray(study, folder, jobs, done, backend=backend, address=args.ray,
                          num_gpus=args.ray_gpus, num_cpus=args.ray_cpus, progress=not args.no_progress)
    else:
        outcome = runner.run_local(study, folder, jobs, done, backend=backend, base_env=base_env,
                                   workers=args.workers, progress=not args.no_progress,
                                   finish_within=args.finish_within, history=history)
    print(f"{study.name}: {len(outcome.done)} of {len(selected)} run(s) done"
          + (f", {len(elsewhere)} finished elsewhere (--skip-done-in)" if elsewhere else "")
          + (f", {len(outcome.failed)} failed" if outcome.failed else "")
          + (f", {len(outcome.busy)} held by another runner" if outcome.busy else "")
          + (f", {len(outcome.deferred)} not started (would not end within --finish-within)"
             if outcome.deferred else ""))
    for name, rc, log in outcome.failed:
        print(f"  FAILED {name} (exit status {rc}): see {log}", file=sys.stderr)
    print(f"report: {backend.prog} study report {folder.path}")
    return 0 if outcome.ok else 1


def _finished_elsewhere(backend, paths, folder) -> list:
    """The finished runs (`runner.Job`s) of the study folders `paths` (--forecast-from), read only; a path
    that is not a study folder, or is the folder being run, is refused by name."""
    from .folder import StudyFolder

    jobs = []
    for path in paths:
        if StudyFolder(path).path.resolve() == folder.path.resolve():
            raise StudyError(f"--forecast-from {path} is the study folder being run (--out): its finished "
                             "runs are already the forecast's; give another study's folder")
        jobs += finished_runs(backend, path, "--forecast-from")
    return jobs


def _done_elsewhere(study, folder, jobs, paths) -> dict:
    """Of the runs `jobs` that have not begun here, those a study folder of `paths` (--skip-done-in) holds
    finished with exactly their config (every field but `configs.EXECUTION_FIELDS`; a preset value it
    kept as superseded is another config) and seeds: {job name: that run folder}. Read only; a path that
    is not a study folder, or is the folder being run, is refused by name."""
    from sf2_common.agents.runfolder import RunFolder, RunFolderError

    from .folder import StudyFolder

    found = {}
    for path in paths:
        other = StudyFolder(path)
        if not other.path.is_dir():
            raise StudyError(f"--skip-done-in {path}: no such folder; give a study folder that `study run` "
                             "or `study merge` wrote (e.g. results/fig10-minatar)")
        if other.path.resolve() == folder.path.resolve():
            raise StudyError(f"--skip-done-in {path} is the study folder being run (--out): its finished "
                             "runs are never run again anyway; give another folder")
        other.load_study()     # a folder that is not a study folder is refused by name
        for job in jobs:
            if job.name in found or job.done_steps:
                continue
            there = other.path_of(job.run)
            try:       # another config or seeds, or a damaged run there, is no finished one: it runs here
                same = RunFolder(there).check_compatible(job.run.config.to_dict(), job.run.seeds, exact=True)
            except RunFolderError:
                continue
            if same and other.run_state(job.run, study).status == "done":
                found[job.name] = there
    return found


def _say_elsewhere(elsewhere: dict) -> None:
    for name, there in elsewhere.items():
        print(f"  elsewhere {name}: finished in {there}, not run here (--skip-done-in)")


def finished_runs(backend, path, what: str = "study folder") -> list:
    """The finished runs (`runner.Job`s) of the study folder `path`, read only (`--forecast-from`,
    bench/lab/forecast_check.py); a path that is not a folder is refused by name (`what`: the option that
    gave it)."""
    from . import runner
    from .folder import StudyFolder

    other = StudyFolder(path)
    if not other.path.is_dir():
        raise StudyError(f"{what} {path}: no such folder; give a study folder that `study run` "
                         "or `study merge` wrote (e.g. results/fig7-td3)")
    study = other.load_study()
    return runner.plan(study, other, _resolve(backend, study))[1]


def _resolve(backend, study):
    """The study's runs (`spec.resolve`). The runner only checks configs: its JAX (Playground imports it)
    stays off the GPUs the runs use."""
    from . import spec

    platforms = os.environ.get("JAX_PLATFORMS")
    os.environ["JAX_PLATFORMS"] = "cpu"
    try:
        from sf2_common.cli import backend_of

        return spec.resolve(study, backend.make_config, backend.validate,
                            functools.partial(backend_of, running=backend))
    finally:
        if platforms is None:
            os.environ.pop("JAX_PLATFORMS")
        else:
            os.environ["JAX_PLATFORMS"] = platforms


def _merge(backend, args, command: str) -> int:
    from .merge import merge

    merge(args.sources, args.into, functools.partial(_resolve, backend), framework=backend.name,
          partial=args.partial, reruns=args.keep_reruns,
          study_file=None if args.study is None else _study_file(args.study), command=command)
    return 0


def _borrow(backend, args) -> int:
    from .borrow import borrow

    borrow(args.dir, args.lender, functools.partial(_resolve, backend), framework=backend.name,
           dry_run=args.dry_run)
    return 0


def _compress(backend, args) -> int:
    from .folder import StudyFolder

    folder = StudyFolder(args.dir)
    study = folder.load_study()
    names = folder.compress_runs(_resolve(backend, study), study)
    print(f"{folder.path}: compressed the metrics of {len(names)} finished run(s)"
          + ("" if names else " (none was left uncompressed)"))
    return 0


def _compare(args, command: str) -> int:
    from .compare import compare

    for path in compare(args.dirs, args.out, command).values():
        print(f"wrote {path}")
    return 0


def _export(args) -> int:
    from .export import export

    done = export(args.dir, args.out)
    where = (f"commit {done.commit} (HEAD of the git repository holding {args.dir})" if done.commit else
             f"no commit ({args.dir} lies in no git repository)")
    print(f"wrote {done.path}: {done.rows} rows of {done.runs} run folder(s)"
          + (f", {done.unfinished} unfinished" if done.unfinished else "") + f"; {where}")
    return 0


def _report(args, command: str) -> int:
    from .report import report

    written = report(args.dir, args.out, command)
    for path in written.values():
        print(f"wrote {path}")
    return 0


COMMAND = types.SimpleNamespace(add_parser=add_parser, main=main)
