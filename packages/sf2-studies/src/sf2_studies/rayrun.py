"""Running a study's runs on a Ray cluster (`study run --ray ADDRESS`): each run is one Ray task that
requests `num_gpus` GPUs (default 1; 0 on a CPU-only cluster) and runs the same children as the local
runner (`python -m <cli> train ...`, then `eval ...`). Ray places, retries and cancels the tasks: there
is no scheduler of ours. Ray is the `ray` extra of sf2-studies (`pip install "packages/sf2-studies[ray]"`);
every node needs the framework installed as on the driver.

Where a task writes: if the node sees the study folder (a shared file system: the folder's study.json
carries the id the driver gave it), the task trains in place, resuming what is there. Otherwise it trains
in a scratch folder on its node (`$SF2_STUDY_SCRATCH`, default ~/.cache/sf2-studies/<study id>/...,
kept, so a retried task on that node resumes from its checkpoints) and returns the run folder's files
except checkpoints (config.json, metrics.jsonl, final/, learning_curve.png, obs_noise.json, train.log);
the driver writes them into the study folder, so the report sees every run wherever it trained.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from sf2_common.fileio import atomic_write

from .folder import LOG, StudyFolder
from .progress import Progress
from .runner import LOCK, Backend, Job, Outcome, child_env, lock, run_commands
from .spec import Study

__all__ = ["run_ray", "remote_job", "land", "RAY_EXTRA", "RETURNED", "BUSY"]

RAY_EXTRA = 'pip install "packages/sf2-studies[ray]"'
BUSY = 75   # EX_TEMPFAIL: the run folder is locked by another runner
RETURNED = ("config.json", "metrics.jsonl", "learning_curve.png", "obs_noise.json", LOG)


def _ray():
    try:
        import ray
    except ImportError as err:
        raise ImportError(f"--ray needs Ray ({err}); install the ray extra: {RAY_EXTRA}") from err
    return ray


def remote_job(cli_module: str, commands: list[list[str]], study_dir: str, study_id: str, rel: str,
               shared_fs: bool | None = None) -> dict:
    """The body of a run's Ray task (module docstring). `commands` hold `{out}` where the run folder goes.
    Returns {"rc", "shared", "files": {relative path: bytes}} (files only when not shared)."""
    state = Path(study_dir) / StudyFolder.STATE
    if shared_fs is None:
        try:
            shared_fs = json.loads(state.read_text()).get("id") == study_id
        except (OSError, json.JSONDecodeError):
            shared_fs = False
    if shared_fs:
        out = Path(study_dir) / rel
    else:
        root = Path(os.environ.get("SF2_STUDY_SCRATCH", Path.home() / ".cache" / "sf2-studies"))
        out = root / study_id / rel
    argvs = [[a.replace("{out}", str(out)) for a in argv] for argv in commands]
    fd = lock(out)
    if fd is None:   # another runner trains this folder now
        return {"rc": BUSY, "shared": shared_fs, "files": {}}
    try:
        rc = run_commands(cli_module, argvs, child_env(dict(os.environ)), out / LOG, fd)
    finally:
        fd.release()
    files = {}
    if not shared_fs:
        names = RETURNED if rc == 0 else (LOG,)
        for name in names:
            if (out / name).exists():
                files[name] = (out / name).read_bytes()
        if rc == 0:
            for p in sorted((out / "final").glob("*")):
                files[f"final/{p.name}"] = p.read_bytes()
    return {"rc": rc, "shared": shared_fs, "files": files}


def land(path: Path, result: dict) -> None:
    """Write what a task on a host without the study folder sent back (`remote_job`) into the run folder
    `path`; its old checkpoints (of a partial run trained here before) no longer belong to it."""
    if result["shared"]:
        return
    if result["rc"] == 0:
        shutil.rmtree(path / "checkpoints", ignore_errors=True)
    for name, data in result["files"].items():
        atomic_write(path / name, data)


def run_ray(study: Study, folder: StudyFolder, jobs: list[Job], done: list[Job], *, backend: Backend,
            address: str, num_gpus: float = 1, num_cpus: float = 1, progress: bool = True,
            shared_fs: bool | None = None, poll: float = 2.0, stream=None) -> Outcome:
    """Dispatch `jobs` as Ray tasks (module docstring). `address` "local" starts a Ray instance on this
    host (ray.init()); anything else is given to ray.init(address=...). `shared_fs` None: each task
    decides (module docstring); True/False forces it (tests)."""
    import sys

    ray = _ray()
    stream = stream or sys.stderr
    if address == "local":
        ray.init(include_dashboard=False, log_to_driver=False)
    else:
        ray.init(address=address, log_to_driver=False)
    state = folder.read_state()
    task = ray.remote(remote_job).options(num_gpus=num_gpus, num_cpus=num_cpus)
    refs = {}
    for job in jobs:
        rel = str(job.path.relative_to(folder.path))
        commands = [[("{out}" if a == str(job.path) else a) for a in argv] for argv in job.commands]
        refs[task.remote(job.run.cli_module or backend.cli_module, commands, str(folder.path.absolute()),
                         state["id"], rel, shared_fs)] = job
    total_steps = sum(j.total_steps for j in jobs + done)
    view = Progress(study.name, len(jobs) + len(done), total_steps, enabled=progress, stream=stream)
    view.event(f"{study.name}: {len(jobs)} run(s) dispatched to Ray ({address}; {num_gpus} GPU and "
               f"{num_cpus} CPU each), {len(done)} done")
    outcome = Outcome([j.name for j in done], [], [])
    steps = {j.name: j.done_steps for j in jobs + done}
    pending = list(refs)
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1, timeout=poll)
            for ref in ready:
                job = refs[ref]
                result = ray.get(ref)
                land(job.path, result)
                steps[job.name] = folder.run_state(job.run, study).env_steps
                if result["rc"] == BUSY:
                    outcome.busy.append(job.name)
                    view.event(f"  {job.name}: skipped, another runner holds {job.path / LOCK}")
                elif result["rc"] == 0:
                    outcome.done.append(job.name)
                    view.event(f"  {job.name}: done")
                else:
                    outcome.failed.append((job.name, result["rc"], job.path / LOG))
                    view.event(f"  {job.name}: FAILED (exit status {result['rc']}); log: {job.path / LOG}")
            for ref in pending:   # runs training in place show their progress
                job = refs[ref]
                steps[job.name] = folder.run_state(job.run, study).env_steps
            view.update(len(outcome.done), len(pending), sum(steps.values()), len(outcome.failed))
        view.update(len(outcome.done), 0, sum(steps.values()), len(outcome.failed), force=True)
    finally:
        view.close()
        ray.shutdown()
    return outcome
