"""Running a study's runs on this host: each run (a task, a method and a seed group, one program) is a
child process of the framework's own CLI (`python -m sf2_jax.cli train ... --no-progress`, then `eval ...
--obs-noise --save` with an [evaluation]), so resuming and `kill -9` are the trainer's.

Children run one per visible GPU (CUDA_VISIBLE_DEVICES set to that GPU alone), or on a CPU one at a time
unless `workers` says more; a child dies with the runner and inherits its lock on the run folder
(sf2_common.agents.lock). Children get PYTHONHASHSEED=0 unless the caller set it: the JAX program's
compilation-cache key depends on Python's string hashing. docs/study-files.md "Running"."""

from __future__ import annotations

import dataclasses
import functools
import heapq
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from sf2_common.agents.lock import FolderLock, RunFolderBusy, holder_of
from sf2_common.agents.runfolder import RunFolder
from sf2_common.cli import Backend

from .folder import LOG, StudyFolder
from .progress import Progress, duration
from .spec import Run, Study, StudyError

__all__ = ["Backend", "Job", "plan", "Forecast", "estimate", "makespan", "eval_argv", "child_env",
           "visible_gpus", "run_local", "Outcome", "LOCK", "LINEAR_COST"]

LOCK = FolderLock.NAME
# Config fields whose value a run's time per env step grows with linearly, a + b × value with a, b ≥ 0 (the
# flow steps per SGD step): a sweep over one prices a value not run yet on a task from the values run there.
LINEAR_COST = ("aux_steps_per_sgd_step",)


@dataclasses.dataclass
class Job:
    run: Run
    path: Path                      # the run folder
    commands: list[list[str]]       # CLI arguments of each child, in order (train, eval)
    total_steps: int
    done_steps: int

    @property
    def name(self) -> str:
        return f"{self.run.task}/{self.run.rel}"


@dataclasses.dataclass
class Outcome:
    done: list[str]
    failed: list[tuple[str, int, Path]]     # (run, exit status, log)
    busy: list[str]                         # locked by another runner
    deferred: list[str] = dataclasses.field(default_factory=list)   # would not end by --finish-within

    @property
    def ok(self) -> bool:
        return not self.failed and not self.busy


def eval_argv(study: Study, path: Path) -> list[str]:
    """The `eval` arguments of the study's [evaluation] (observation noise, paper App. C.2.2)."""
    e = study.evaluation
    argv = ["eval", str(path), "--obs-noise", ",".join(repr(x) for x in e.obs_noise),
            "--checkpoints", str(e.checkpoints), "--save"]
    if e.episodes is not None:
        argv += ["--episodes", str(e.episodes)]
    if e.deterministic is not None:
        argv.append("--deterministic" if e.deterministic else "--stochastic")
    return argv


def plan(study: Study, folder: StudyFolder, runs: list[Run], log: str | None = None
         ) -> tuple[list[Job], list[Job]]:
    """(jobs to run, runs already done) of `runs`; raises `StudyError` if a run folder holds another run.
    `log` (e.g. "tensorboard,wandb") is passed to each `train` as `--log` (docs/agents.md, Loggers).
    The jobs keep the study's order, except that runs already begun (partly trained, or trained and not
    yet evaluated) come first: `run_local` starts them in this order, so a run that a command's time limit
    cut resumes before new runs take the GPUs. On a leased host whose disk goes back with it, its
    checkpoints are then not left waiting behind runs that start from zero (results/fig7-sac/README.md
    "Device time", twenty-fourth session: HopperHop SAC+SPR, cut by one command, resumed first in the next
    instead of behind FishSwim's twelve new runs)."""
    todo, done = [], []
    for run in runs:
        folder.check_run(run)
        state = folder.run_state(run, study)
        path = folder.path_of(run)
        if state.status != "done" and folder.is_borrowed(run):
            raise StudyError(f"{run.task}/{run.rel}: {folder.path}'s study.json reads it from {path}, "
                             f"where it is {state.status}, not finished; nothing was run. A study folder "
                             f"never trains another's run: finish it in its own study, or remove the "
                             f"entry's \"from\" in {folder.path / folder.STATE} to train it here")
        commands = []
        if state.status in ("new", "partial"):
            commands.append(["train", *run.argv, "--out", str(path), "--no-progress",
                             *(["--log", log] if log else [])])
        if state.status != "done" and study.evaluation is not None:
            commands.append(eval_argv(study, path))
        job = Job(run, path, commands, state.total_env_steps, state.env_steps)
        (todo if commands else done).append(job)
    return sorted(todo, key=lambda j: j.done_steps == 0), done     # stable: begun first, then study order


class Forecast:
    """Seconds of training a job still needs: its remaining env steps at the wall-clock seconds per env step
    of finished runs (1: its own task and method at its seed count; 2: another method on its task scaled
    by the largest ratio between the two; 3: its own runs at other seed counts, scaled; 4: on a task with
    no finished run, the slowest (task, method) pair scaled to its method by the largest ratio between the
    two; 5: the slowest run of its task, else of any task). A sweep's method over a `LINEAR_COST` field with
    no run of its own on the task is priced from the sweep's values run there (`swept`) before the rest.
    `known` is False without any finished run. docs/decisions/forecasts.md."""

    def __init__(self, done: list[Job]):
        self.rates: dict[tuple[str, str], list[tuple[int, float]]] = {}   # (seeds, s per env step)
        # (task, field, base label) -> {folder: value} of finished runs of a sweep over a LINEAR_COST field
        self.sweeps: dict[tuple[str, str, str], dict[str, float]] = {}
        for job in done:
            self.add(job)

    @staticmethod
    def wall(job: Job) -> float:
        """A finished job's wall time: its metrics rows' largest `walltime` (restarts included), 0 without."""
        return max((r.get("walltime", 0.0) for r in RunFolder(job.path).read_rows()), default=0.0)

    def add(self, job: Job) -> None:
        wall = self.wall(job)
        if wall > 0 and job.total_steps > 0:
            self.rates.setdefault((job.run.task, job.run.folder), []).append(
                (_seed_count(job), wall / job.total_steps))
            for field, value, base in _linear_sweeps(job):
                self.sweeps.setdefault((job.run.task, field, base), {})[job.run.folder] = value

    @property
    def known(self) -> bool:
        return bool(self.rates)

    def has_task(self, task: str) -> bool:
        return any(t == task for t, _ in self.rates)

    def scale(self, k: int, n: int) -> float:
        """The factor from a rate measured at k seeds to one at n (class docstring)."""
        if k == n:
            return 1.0
        pairs = [(self._at(t, f, n), self._at(t, f, k)) for t, f in self.rates]
        ratios = [at_n / at_k for at_n, at_k in pairs if at_n is not None and at_k is not None]
        return max(ratios) if ratios else (1.0 if n > k else k / n)

    def _rates(self, task: str, folder: str) -> list[tuple[int, float]]:
        """(seeds, rate) of (task, folder)'s finished runs, each capped by its runs of more seeds (class
        docstring)."""
        runs = self.rates.get((task, folder), [])
        return [(k, min([r, *(q * m / k for m, q in runs if m > k)])) for k, r in runs]

    def _at(self, task: str, folder: str, seeds: int) -> float | None:
        """The mean rate of (task, folder)'s finished runs of `seeds` seeds, or None."""
        same = [r for m, r in self._rates(task, folder) if m == seeds]
        return sum(same) / len(same) if same else None

    def ratio(self, folder: str, other: str, seeds: int, tasks: set[str]) -> float | None:
        """The largest ratio of `folder`'s rate to `other`'s at `seeds` seeds on the `tasks` where both
        finished runs, or None where none did."""
        pairs = [(self._at(t, folder, seeds), self._at(t, other, seeds)) for t in tasks]
        ratios = [mine / theirs for mine, theirs in pairs if mine is not None and theirs is not None]
        return max(ratios, default=None)

    def relative(self, task: str, folder: str, seeds: int) -> float | None:
        """Preference 2 of the class docstring, or None where no other method and task give it."""
        tasks = {t for t, _ in self.rates} - {task}
        estimates = []
        for other in {f for t, f in self.rates if t == task and f != folder}:
            base, ratio = self._at(task, other, seeds), self.ratio(folder, other, seeds, tasks)
            if base is not None and ratio is not None:
                estimates.append(base * ratio)
        return max(estimates, default=None)

    def rate(self, task: str, folder: str, seeds: int = 1) -> float:
        own = self._at(task, folder, seeds)
        if own is not None:
            return own
        relative = self.relative(task, folder, seeds)
        if relative is not None:
            return relative
        mine = self._rates(task, folder)
        if mine:
            scaled = [r * self.scale(m, seeds) for m, r in mine]
            return sum(scaled) / len(scaled)
        if not self.has_task(task):
            scaled = self.scaled_slowest(folder, seeds)
            if scaled is not None:
                return scaled
        return self.slowest(task, seeds)

    def scaled_slowest(self, folder: str, seeds: int) -> float | None:
        """Preference 4 of the class docstring, for a task with no finished run: the largest rate at `seeds`
        seeds of a finished (task, method) pair times the largest ratio of `folder` to that method on the
        tasks both ran (1 for `folder` itself); with no such pair at `seeds` seeds, the largest at another
        seed count scaled to `seeds` (`scale`); None where no pair relates to `folder`."""
        here = self._scaled_slowest_at(folder, seeds)
        if here is not None:
            return here
        counts = {k for runs in self.rates.values() for k, _ in runs} - {seeds}
        return max((rate * self.scale(k, seeds) for k in counts
                    if (rate := self._scaled_slowest_at(folder, k)) is not None), default=None)

    def _scaled_slowest_at(self, folder: str, seeds: int) -> float | None:
        tasks = {t for t, _ in self.rates}
        estimates = []
        for task, other in self.rates:
            base = self._at(task, other, seeds)
            ratio = 1.0 if other == folder else self.ratio(folder, other, seeds, tasks)
            if base is not None and ratio is not None:
                estimates.append(base * ratio)
        return max(estimates, default=None)

    def slowest(self, task: str, seeds: int) -> float:
        """Preference 5 of the class docstring: the slowest finished run of `task` (else of any task) at
        `seeds` seeds, else the slowest at any seed count scaled to `seeds`."""
        pool = ([(m, r) for t, f in self.rates if t == task for m, r in self._rates(t, f)]
                or [(m, r) for t, f in self.rates for m, r in self._rates(t, f)])
        exact = [r for m, r in pool if m == seeds]
        return max(exact) if exact else max(r * self.scale(m, seeds) for m, r in pool)

    def swept(self, task: str, field: str, base: str, value: float, seeds: int) -> float | None:
        """The rate of the sweep (`field`, `base`)'s `value` on `task` at `seeds` seeds from its values run
        there (None without one): a single run value v0 at rate r0 bounds it by r0 × max(1, value / v0) (a
        line a + b × v through the origin or above it); with several, each run value's rate plus the steepest
        slope between two neighbouring ones times the distance, the largest (for a value below every run
        one, the rate of the smallest)."""
        run = sorted((v, r) for f, v in self.sweeps.get((task, field, base), {}).items()
                     if (r := self._at(task, f, seeds)) is not None)
        if not run:
            return None
        if len({v for v, _ in run}) == 1:
            v0, r0 = max(run, key=lambda p: p[1])
            return r0 * max(1.0, value / v0) if v0 > 0 else r0
        slope = max(0.0, *((r2 - r1) / (v2 - v1) for (v1, r1), (v2, r2) in zip(run, run[1:]) if v2 > v1))
        below = [r + slope * (value - v) for v, r in run if v <= value]
        return max(below) if below else run[0][1]

    def job_rate(self, job: Job) -> float:
        """`rate` of the job's task, folder and seed count; for a point of a sweep over a `LINEAR_COST` field
        with no run of its own on the task, `swept` from the sweep's runs there, else `relative`, else `rate`
        times value / the smallest value of the sweep run on any task (at least 1: `rate` then prices a run
        of the task, not of this value)."""
        task, folder, seeds = job.run.task, job.run.folder, _seed_count(job)
        sweeps = _linear_sweeps(job)
        if not sweeps or self._rates(task, folder):
            return self.rate(task, folder, seeds)
        for field, value, base in sweeps:
            rate = self.swept(task, field, base, value, seeds)
            if rate is not None:
                return rate
        relative = self.relative(task, folder, seeds)
        if relative is not None:
            return relative
        field, value, base = sweeps[0]
        ref = [v for (_, f, b), run in self.sweeps.items() if (f, b) == (field, base) for v in run.values()]
        return self.rate(task, folder, seeds) * (max(1.0, value / min(ref)) if ref and min(ref) > 0 else 1.0)

    def seconds(self, job: Job) -> float:
        return (job.total_steps - job.done_steps) * self.job_rate(job)


def _seed_count(job: Job) -> int:
    return len(getattr(job.run, "seeds", None) or (0,))


def _linear_sweeps(job: Job) -> list[tuple[str, float, str]]:
    """(field, value, base label) of each method of the job's run that a sweep over a `LINEAR_COST` field
    generated."""
    out = []
    for method in getattr(job.run, "methods", ()):
        sweep = getattr(method, "sweep", None)
        if sweep is not None and sweep[0] in LINEAR_COST:
            try:
                out.append((sweep[0], float(sweep[1]), sweep[2]))
            except ValueError:
                continue
    return out


def estimate(done: list[Job], todo: list[Job], forecast: Forecast | None = None,
             where: str = "here", workers: int = 1) -> str | None:
    """A dry run's forecast of the training time left (`Forecast`, of `done` unless given), summed as if one
    worker ran every job, and with `workers` > 1 the time `run_local` would take on that many (`makespan`);
    `where` says whose finished runs the rates are. None without a finished run or without a job."""
    forecast = Forecast(done) if forecast is None else forecast
    if not forecast.known or not todo:
        return None
    each = [forecast.seconds(j) for j in todo]
    guessed = sorted({j.run.task for j in todo if not forecast.has_task(j.run.task)})
    finished = sum(len(v) for v in forecast.rates.values())
    return (f"estimate: {len(todo)} run(s) to do ≈ {duration(sum(each))} of training on one worker"
            + (f", ≈ {duration(makespan(each, workers))} on {workers} workers" if workers > 1 else "")
            + f" (at the wall time per env step of the {finished} finished run(s) {where}"
            + (f"; {', '.join(guessed)}: no finished run yet, the slowest" if guessed else "") + ")")


def makespan(seconds: list[float], workers: int) -> float:
    """When the last of jobs taking `seconds` (in `run_local`'s order) ends on `workers` slots: each job
    starts, in order, on the slot that frees first, as `run_local` starts them (process starts and
    compilation are in the jobs' forecasts only as far as the finished runs' wall times hold them)."""
    free = [0.0] * workers
    for s in seconds:
        heapq.heapreplace(free, free[0] + s)
    return max(free)


def child_env(base: dict, **extra) -> dict:
    env = dict(base)
    env.setdefault("PYTHONHASHSEED", "0")
    env.update(extra)
    return env


def visible_gpus(env: dict) -> list[str]:
    """The GPUs children may use: CUDA_VISIBLE_DEVICES's entries when it is set, else those `nvidia-smi -L`
    lists, else none."""
    if "CUDA_VISIBLE_DEVICES" in env:
        ids = [x.strip() for x in env["CUDA_VISIBLE_DEVICES"].split(",") if x.strip()]
        return [] if ids and ids[0].startswith("-") else ids
    if shutil.which("nvidia-smi") is None:
        return []
    try:
        out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    return [str(i) for i, line in enumerate(out.splitlines()) if line.startswith("GPU ")]


# ------------------------------------------------------------------------------------------- children
@functools.cache
def _prctl():
    try:
        import ctypes

        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


def _die_with_parent(parent: int, prctl) -> None:   # runs in the child between fork and exec
    if prctl is not None:
        prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
        if os.getppid() != parent:
            os._exit(1)


def spawn(cli_module: str, argv: list[str], env: dict, log: Path, pass_fds=()) -> subprocess.Popen:
    """`python -m cli_module *argv`, output appended to `log`, killed when this process dies."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "ab") as f:
        f.write(f"\n$ python -m {cli_module} {' '.join(argv)}   # {time.strftime('%F %T')}\n".encode())
        return subprocess.Popen([sys.executable, "-m", cli_module, *argv], stdout=f, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, env=env, pass_fds=pass_fds,
                                preexec_fn=functools.partial(_die_with_parent, os.getpid(), _prctl()))


def run_commands(cli_module: str, commands: list[list[str]], env: dict, log: Path, held: FolderLock) -> int:
    """Run a job's children one after the other (stop at the first failure), each inheriting the run
    folder's lock `held`; the exit status."""
    for argv in commands:
        rc = spawn(cli_module, argv, {**env, **held.child_env()}, log, pass_fds=(held.fd,)).wait()
        if rc != 0:
            return rc
    return 0


def lock(path: Path) -> FolderLock | None:
    """The run folder's lock (`sf2_common.agents.lock`), or None if another process holds it."""
    try:
        return FolderLock(path, "study run").acquire()
    except RunFolderBusy:
        return None


# ------------------------------------------------------------------------------------------- local runner
class _Slot:
    def __init__(self, env: dict, label: str):
        self.env, self.label = env, label
        self.job: Job | None = None
        self.proc: subprocess.Popen | None = None
        self.fd: FolderLock | None = None
        self.queue: list[list[str]] = []
        self.started = 0.0                     # time.monotonic() when its job started
        self.forecast: float | None = None     # the job's Forecast then (seconds), None without one


def run_local(study: Study, folder: StudyFolder, jobs: list[Job], done: list[Job], *, backend: Backend,
              base_env: dict, workers: int | None = None, progress: bool = True, poll: float = 1.0,
              stream=None, finish_within: float | None = None, history: list[Job] | None = None) -> Outcome:
    """Run `jobs` on this host (module docstring); `done` counts towards the progress view. With
    `finish_within` (seconds from now) a job starts only if its `Forecast` ends by then (a leased machine
    that goes back at a known time then spends none of it on runs that would be cut and lost); every job
    starts while no run has finished to forecast from. `history`: the finished runs the forecast draws on
    (default `done`; `study run` passes every finished run of the study folder, not only the selected ones).
    Runs already started are never stopped by it. A finished run's line gives the time it took here and
    its forecast at its start ("done after 5m23s (forecast 7m32s)"): each session's log checks the
    forecasts."""
    stream = stream or sys.stderr
    deadline = None if finish_within is None else time.monotonic() + finish_within
    forecast = Forecast(done if history is None else history)
    gpus = visible_gpus(base_env)
    if gpus:
        if workers is not None and workers > len(gpus):
            raise StudyError(f"--workers {workers}: this host has {len(gpus)} visible GPU(s) "
                             f"({','.join(gpus)}) and a run never shares a GPU; use --workers <= {len(gpus)}")
        slots = [_Slot(child_env(base_env, CUDA_VISIBLE_DEVICES=g), f"GPU {g}") for g in gpus[:workers]]
    else:
        slots = [_Slot(child_env(base_env), f"worker {i}") for i in range(workers or 1)]
    total_steps = sum(j.total_steps for j in jobs + done)
    view = Progress(study.name, len(jobs) + len(done), total_steps, enabled=progress, stream=stream)
    view.event(f"{study.name}: {len(jobs)} run(s) to do, {len(done)} done; "
               f"{len(slots)} at a time ({', '.join(s.label for s in slots)})")
    pending = list(jobs)
    outcome = Outcome([j.name for j in done], [], [])
    steps = {j.name: j.done_steps for j in jobs + done}

    def start(slot: _Slot, job: Job) -> bool:
        if deadline is not None and forecast.known:
            left, need = deadline - time.monotonic(), forecast.seconds(job)
            if need > left:
                outcome.deferred.append(job.name)
                view.event(f"  {job.name}: not started, its forecast {duration(need)} exceeds the "
                           f"{duration(max(left, 0))} left of --finish-within")
                return False
        fd = lock(job.path)
        if fd is None:
            outcome.busy.append(job.name)
            view.event(f"  {job.name}: skipped, {holder_of(job.path) or 'another process'} holds "
                       f"{job.path / LOCK}")
            return False
        slot.job, slot.fd, slot.queue = job, fd, list(job.commands)
        slot.started, slot.forecast = time.monotonic(), forecast.seconds(job) if forecast.known else None
        _next(slot)
        view.event(f"  {job.name}: started on {slot.label} ({' then '.join(c[0] for c in job.commands)})")
        return True

    def _next(slot: _Slot) -> None:
        argv = slot.queue.pop(0)
        # the child inherits the lock: the folder stays locked between a job's commands
        cli_module = slot.job.run.cli_module or backend.cli_module
        slot.proc = spawn(cli_module, argv, {**slot.env, **slot.fd.child_env()}, slot.job.path / LOG,
                          pass_fds=(slot.fd.fd,))

    def release(slot: _Slot) -> None:
        slot.fd.release()
        slot.job = slot.proc = slot.fd = None

    try:
        while pending or any(s.job for s in slots):
            for slot in slots:
                if slot.job is None:
                    while pending and not start(slot, pending.pop(0)):
                        pass
                    continue
                rc = slot.proc.poll()
                if rc is None:
                    continue
                job = slot.job
                if rc == 0 and slot.queue:
                    _next(slot)
                    continue
                steps[job.name] = folder.run_state(job.run, study).env_steps
                if rc == 0:
                    outcome.done.append(job.name)
                    forecast.add(job)
                    took = duration(time.monotonic() - slot.started)
                    said = "" if slot.forecast is None else f" (forecast {duration(slot.forecast)})"
                    view.event(f"  {job.name}: done after {took}{said}")
                else:
                    outcome.failed.append((job.name, rc, job.path / LOG))
                    view.event(f"  {job.name}: FAILED (exit status {rc}); log: {job.path / LOG}")
                release(slot)
            for slot in slots:
                if slot.job is not None:
                    steps[slot.job.name] = folder.run_state(slot.job.run, study).env_steps
            view.update(len(outcome.done), sum(s.job is not None for s in slots), sum(steps.values()),
                        len(outcome.failed))
            time.sleep(poll)
        view.update(len(outcome.done), 0, sum(steps.values()), len(outcome.failed), force=True)
    except KeyboardInterrupt:
        view.event("interrupted: stopping the runs (each resumes from its last checkpoint next time)")
        for slot in slots:
            if slot.proc is not None and slot.proc.poll() is None:
                slot.proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 60
        for slot in slots:
            if slot.proc is not None:
                try:
                    slot.proc.wait(timeout=max(deadline - time.monotonic(), 0.1))
                except subprocess.TimeoutExpired:
                    slot.proc.kill()
        raise
    finally:
        view.close()
    return outcome
