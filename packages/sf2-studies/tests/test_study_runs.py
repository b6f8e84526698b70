"""`sf2-jax study run` end to end on the CPU with the shipped smoke study (studies/smoke.toml: 2 tasks × 2
methods × 2 seeds, tiny budget): the local runner, a study folder that merges runs trained elsewhere, a run
killed with its runner (kill -9) and resumed by the Ray runner on a local CPU-only instance, the report,
and bad study files refused before anything is compiled. Needs sf2-core-jax[train] and
sf2-studies[ray]: tox -e agents."""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("sf2_jax.agents.trainer", reason="needs sf2-core-jax[train] (tox -e agents)")
pytest.importorskip("rliable", reason="needs sf2-studies (tox -e agents)")

from sf2_common.agents.hostloop import WALL_FIELDS  # noqa: E402
from sf2_jax import cli  # noqa: E402
from sf2_studies import spec  # noqa: E402
from sf2_studies.folder import StudyFolder  # noqa: E402
from sf2_studies.runner import LOCK, plan  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
SMOKE = ROOT / "studies" / "smoke.toml"
RUNS = [("CartpoleBalance", "td3-none"), ("CartpoleBalance", "td3-sf2"), ("CartpoleSwingup", "td3-none"),
        ("CartpoleSwingup", "td3-sf2")]
EPOCHS, SEEDS = 5, (0, 1)


def _argv(*args):
    return [sys.executable, "-m", "sf2_jax.cli", *map(str, args)]


def _env():
    return {**os.environ, "JAX_PLATFORMS": "cpu"}


def _lines(run: Path) -> list[dict]:
    """metrics.jsonl line by line (not deduplicated), wall-clock fields dropped."""
    return [{k: v for k, v in json.loads(x).items() if k not in WALL_FIELDS}
            for x in (run / "metrics.jsonl").read_text().splitlines() if x.strip()]


@pytest.fixture(scope="module", autouse=True)
def compile_cache(tmp_path_factory):
    """One JAX compilation cache for this module's runs (the children inherit it): the smoke study's four
    programs compile once and the later runs load them; the user's cache is left alone."""
    old = os.environ.get(cli.CACHE_ENV)
    os.environ[cli.CACHE_ENV] = str(tmp_path_factory.mktemp("xla"))
    yield
    if old is None:
        os.environ.pop(cli.CACHE_ENV)
    else:
        os.environ[cli.CACHE_ENV] = old


def _main(capsys, *args) -> tuple[str, str]:
    """`sf2-jax study ...` in this process (the runs are child processes all the same)."""
    capsys.readouterr()
    assert cli.main(["study", *map(str, args)]) == 0
    return capsys.readouterr()


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The smoke study, uninterrupted, two runs at a time."""
    out = tmp_path_factory.mktemp("smoke") / "study"
    assert cli.main(["study", "run", str(SMOKE), "--out", str(out), "--workers", "2", "--no-progress"]) == 0
    return out


def test_smoke_study_runs_and_reports(reference, capsys):
    folder = StudyFolder(reference)
    assert folder.study_path.read_text() == SMOKE.read_text()
    for task, method in RUNS:
        lines = _lines(folder.run_path(task, method))
        want = [(e, s) for e in range(EPOCHS + 1) for s in SEEDS]
        assert sorted((r["epoch"], r["seed"]) for r in lines) == want
    out, err = _main(capsys, "run", SMOKE, "--out", reference, "--no-progress")   # finished: skipped
    assert "0 run(s) to do, 4 done" in err and "started" not in err and "smoke: 4 of 4 run(s) done" in out
    out, _ = _main(capsys, "report", reference)
    assert "summary.md" in out
    out = reference / "report"
    rows = (out / "results.csv").read_text().splitlines()
    assert len(rows) == 1 + len(RUNS) * len(SEEDS)
    summary = (out / "summary.md").read_text()
    assert "(n < 3: no CI)" in summary and "sf2-jax study run" in summary and "Incomplete" not in summary
    for name in ("aggregate", "curves"):
        assert (out / f"{name}.png").stat().st_size > 1000 and (out / f"{name}.svg").exists()


def test_killed_runner_resumes_through_ray_to_the_same_results(reference, tmp_path):
    """Three runs finished elsewhere are merged into a new study folder (copied run folders); the local
    runner trains the fourth and is killed (kill -9) in the middle of it; its child dies with it. The
    study then resumes as Ray tasks on a local CPU-only instance (the node sees the study folder, so the
    task resumes the run in place from its last checkpoint). Every run's rows equal the uninterrupted
    study's, none missing, none duplicated. (A node without the study folder: test_study_runner.py.)"""
    pytest.importorskip("ray", reason="needs sf2-studies[ray] (tox -e agents)")
    from sf2_studies.rayrun import run_ray

    out = tmp_path / "study"
    ref = StudyFolder(reference)
    folder = StudyFolder(out)
    out.mkdir()
    shutil.copy(ref.study_path, folder.study_path)   # the same study file, started on another machine
    for task, method in RUNS[:3]:
        shutil.copytree(ref.run_path(task, method), folder.run_path(task, method))
    last = folder.run_path(*RUNS[3])
    runner = subprocess.Popen(_argv("study", "run", SMOKE, "--out", out, "--no-progress"), cwd=ROOT,
                              env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not (last.exists() and (last / "metrics.jsonl").exists()
               and any(r["epoch"] >= 2 for r in _lines(last))):
        assert runner.poll() is None, runner.stderr.read()
        assert time.monotonic() < deadline
        time.sleep(0.05)
    runner.send_signal(signal.SIGKILL)
    runner.wait()
    # the child trainer died with the runner: the run folder's lock is free again
    fd = os.open(last / LOCK, os.O_RDWR)
    for _ in range(100):
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            time.sleep(0.1)
    else:
        pytest.fail("the trainer outlived its runner")
    os.close(fd)
    assert max(r["epoch"] for r in _lines(last)) < EPOCHS

    study = spec.load(SMOKE)
    backend = cli.backend()
    runs = spec.resolve(study, backend.make_config, backend.validate)
    folder.open(study, "jax", runs, command="test")
    jobs, done = plan(study, folder, runs)
    assert [j.name for j in jobs] == ["CartpoleSwingup/td3-sf2"] and len(done) == 3
    outcome = run_ray(study, folder, jobs, done, backend=backend, address="local", num_gpus=0, progress=False)
    assert outcome.ok and len(outcome.done) == 4
    assert (last / "checkpoints").exists()              # trained in place
    for task, method in RUNS:
        assert _lines(folder.run_path(task, method)) == _lines(ref.run_path(task, method)), (task, method)
    assert folder.run_state(jobs[0].run, study).status == "done"


def _bad(tmp_path, capsys, text: str, *more) -> str:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    out = tmp_path / "out"
    assert cli.main(["study", "run", str(path), "--out", str(out), *more]) == 2
    assert not out.exists()                      # nothing written
    return capsys.readouterr().err


def test_bad_study_files_exit_2_before_anything_runs(tmp_path, capsys):
    smoke = SMOKE.read_text()
    err = _bad(tmp_path, capsys, smoke.replace('"CartpoleSwingup"]', '"CartpoleSwingUp"]'))
    assert "bad.toml: tasks[1]: unknown task 'CartpoleSwingUp'" in err
    assert "Did you mean CartpoleSwingup" in err
    err = _bad(tmp_path, capsys, smoke.replace('representation = "sf2"', 'representation = "sf3"'))
    assert "bad.toml: method 'TD3+SF²' on task CartpoleBalance" in err and "must be one of none, sf2" in err
    err = _bad(tmp_path, capsys, smoke.replace('algo = "td3"\nrepresentation = "sf2"',
                                               'algo = "dqn"\nrepresentation = "sf2"'))
    assert "method 'TD3+SF²'" in err and "algo = 'dqn'" in err and "td3, sac" in err
    err = _bad(tmp_path, capsys, smoke.replace("num_envs = 4", "num_env = 4"))
    assert "unknown config field 'num_env'" in err and "num_envs" in err
    err = _bad(tmp_path, capsys, smoke.replace('\nname = "smoke"', '\nname = "smoke"\nframework = "torch"'))
    assert "framework = 'torch'" in err and "sf2-torch study run" in err
    err = _bad(tmp_path, capsys, smoke, "--methods", "td3-sf3")
    assert "'td3-sf3' is not a method of study 'smoke'" in err and "td3-none, td3-sf2" in err


def test_study_folder_of_another_file_is_kept(reference, tmp_path, capsys):
    other = tmp_path / "other.toml"
    other.write_text(SMOKE.read_text().replace('seeds = "0-1"', 'seeds = "0-2"'))
    before = {p: p.stat().st_mtime_ns for p in reference.rglob("*")}
    assert cli.main(["study", "run", str(other), "--out", str(reference)]) == 2
    err = capsys.readouterr().err
    assert str(reference / "study.toml") in err and str(other) in err and "differ in seeds" in err
    assert {p: p.stat().st_mtime_ns for p in reference.rglob("*")} == before


def test_sf2_torch_study_dry_run(tmp_path, capsys):
    """`sf2-torch study run` plans the same runs as children of `sf2-torch train`; nothing is written."""
    torch_cli = pytest.importorskip("sf2_torch.cli", reason="needs sf2-core-torch[train] (tox -e agents)")
    out = tmp_path / "study"
    assert torch_cli.main(["study", "run", str(SMOKE), "--out", str(out), "--dry-run"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("smoke (") and "4 run(s) selected of 4" in lines[0]
    assert all(" new " in x and "sf2-torch train --task" in x for x in lines[1:]) and len(lines) == 5
    assert not out.exists()
