"""The local runner's placement without a GPU or a framework: a stand-in CLI (a module written here) records
the CUDA_VISIBLE_DEVICES each child gets and when it runs, so the test sees that runs spread over the
visible GPUs, one GPU each, never two at once on one GPU; and that the optional extras name themselves
when missing."""

from __future__ import annotations

import functools
import io
import json
import re
import sys
import textwrap

import pytest
from sf2_common.agents.configs import TrainConfig
from sf2_studies import runner, spec
from sf2_studies.folder import StudyFolder

FAKE_CLI = textwrap.dedent('''
    """Stands in for `python -m sf2_jax.cli train ... --out DIR`: records its GPU and its time span."""
    import json, os, sys, time
    out = sys.argv[sys.argv.index("--out") + 1]
    t0 = time.time()
    time.sleep(0.6)
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "child.json"), "w") as f:
        json.dump({"gpu": os.environ.get("CUDA_VISIBLE_DEVICES"), "start": t0, "end": time.time(),
                   "hashseed": os.environ.get("PYTHONHASHSEED")}, f)
''')

STUDY = """
name = "placement"
seeds = "0-1"
tasks = ["A", "B", "C"]
[[methods]]
label = "TD3"
algo = "td3"
representation = "none"
[[methods]]
label = "SAC"
algo = "sac"
representation = "none"
"""


def _setup(tmp_path, monkeypatch):
    (tmp_path / "fake_sf2_cli.py").write_text(FAKE_CLI)
    monkeypatch.syspath_prepend(str(tmp_path))
    study = spec.loads(STUDY, tmp_path / "s.toml")
    backend = runner.Backend("sf2-fake", "jax", "fake_sf2_cli", None, None)

    def make(preset, task, algo, rep, overrides):
        return TrainConfig(task=task, algo=algo, representation=rep, num_timesteps=1000, num_envs=4,
                           min_replay_size=8, num_evals=3)

    runs = _resolve_without_tasks(study, make)
    folder = StudyFolder(tmp_path / "study")
    folder.open(study, "jax", runs)
    return study, backend, folder, runs


def _resolve_without_tasks(study, make):
    """spec.resolve checks task names against Playground; these runs need no task."""
    out = []
    for task, m in study.select():
        cfg = make(study.preset, task, m.algo, m.representation, {})
        out.append(spec.Run(task=task, folder=m.name, methods=(m,), config=cfg,
                            argv=("--task", task, "--algo", m.algo), seeds=study.seeds))
    return out


def test_runs_spread_over_visible_gpus_one_each(tmp_path, monkeypatch):
    study, backend, folder, runs = _setup(tmp_path, monkeypatch)
    jobs, done = runner.plan(study, folder, runs)
    assert len(jobs) == 6 and not done
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(tmp_path) + ":" + ":".join(sys.path),
           "CUDA_VISIBLE_DEVICES": "3,5"}
    outcome = runner.run_local(study, folder, jobs, done, backend=backend, base_env=env, progress=False,
                               poll=0.05)
    assert outcome.ok and len(outcome.done) == 6
    spans = [json.loads((j.path / "child.json").read_text()) for j in jobs]
    assert {s["gpu"] for s in spans} == {"3", "5"}                    # both GPUs used, one id each
    assert all(s["hashseed"] == "0" for s in spans)
    for gpu in ("3", "5"):
        mine = sorted((s["start"], s["end"]) for s in spans if s["gpu"] == gpu)
        assert all(a_end <= b_start for (_, a_end), (b_start, _) in zip(mine, mine[1:]))   # never two at once
    with pytest.raises(spec.StudyError, match="--workers 3: this host has 2 visible GPU"):
        runner.run_local(study, folder, jobs, done, backend=backend, base_env=env, workers=3, progress=False)


def test_runs_begun_start_first(tmp_path, monkeypatch):
    """A run that an earlier command's time limit cut (config and some evaluation rows in its folder)
    starts before the new ones; the rest keep the study's order (tasks A, B, C × TD3, SAC). One worker
    runs them in that order: the child spans say so."""
    from sf2_common.agents.runfolder import RunFolder

    study, backend, folder, runs = _setup(tmp_path, monkeypatch)
    cut = runs[4]                                                     # C / TD3: last but one in study order
    assert (cut.task, cut.methods[0].label) == ("C", "TD3")
    rf = RunFolder(folder.path_of(cut))
    rf.write_config({"config": cut.config.to_dict(), "seeds": list(cut.seeds)})
    (rf.path / "metrics.jsonl").write_text(json.dumps({"epoch": 1, "seed": 0, "env_steps": 250}) + "\n")
    jobs, done = runner.plan(study, folder, runs)
    assert folder.run_state(cut, study).status == "partial" and not done
    assert [j.run for j in jobs] == [cut] + [r for r in runs if r is not cut]
    assert jobs[0].done_steps == 250 and all(j.done_steps == 0 for j in jobs[1:])
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(tmp_path) + ":" + ":".join(sys.path),
           "CUDA_VISIBLE_DEVICES": ""}
    outcome = runner.run_local(study, folder, jobs, done, backend=backend, base_env=env, progress=False,
                               poll=0.05)
    assert outcome.ok
    starts = [json.loads((j.path / "child.json").read_text())["start"] for j in jobs]
    assert starts == sorted(starts)


def test_visible_gpus():
    assert runner.visible_gpus({"CUDA_VISIBLE_DEVICES": "0,2"}) == ["0", "2"]
    assert runner.visible_gpus({"CUDA_VISIBLE_DEVICES": ""}) == []
    assert runner.visible_gpus({"CUDA_VISIBLE_DEVICES": "-1"}) == []


def test_missing_extras_are_named(monkeypatch):
    from sf2_studies import rayrun, stats

    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ImportError, match=r'pip install "packages/sf2-studies\[ray\]"'):
        rayrun._ray()
    monkeypatch.setitem(sys.modules, "rliable", None)
    with pytest.raises(ImportError, match=r'pip install packages/sf2-studies'):
        stats.require_rliable()


FAKE_TRAIN = textwrap.dedent('''
    """Stands in for `python -m sf2_jax.cli train ... --out DIR`: a finished run folder with checkpoints."""
    import json, os, sys
    out = sys.argv[sys.argv.index("--out") + 1]
    os.makedirs(os.path.join(out, "checkpoints", "3"), exist_ok=True)
    os.makedirs(os.path.join(out, "final"), exist_ok=True)
    open(os.path.join(out, "config.json"), "w").write(json.dumps({"argv": sys.argv[1:]}))
    open(os.path.join(out, "metrics.jsonl"), "w").write('{"epoch": 0, "seed": 0}\\n')
    open(os.path.join(out, "final", "params_seed0.npz"), "wb").write(b"params")
    open(os.path.join(out, "checkpoints", "3", "state"), "wb").write(b"big")
''')


def test_ray_task_on_a_host_without_the_study_folder(tmp_path, monkeypatch):
    """A Ray task whose node does not see the study folder (no study.json with the driver's id there)
    trains in its scratch folder and returns the run folder's files but its checkpoints; the driver
    writes them into the study folder (rayrun.remote_job and rayrun.land, without Ray itself)."""
    from sf2_studies import rayrun

    (tmp_path / "fake_sf2_train.py").write_text(FAKE_TRAIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    monkeypatch.setenv("SF2_STUDY_SCRATCH", str(tmp_path / "scratch"))
    rel = "runs/A/td3"
    result = rayrun.remote_job("fake_sf2_train", [["train", "--task", "A", "--out", "{out}"]],
                               str(tmp_path / "driver-study"), "id123", rel)
    assert result["rc"] == 0 and result["shared"] is False
    scratch = tmp_path / "scratch" / "id123" / rel
    assert (scratch / "checkpoints" / "3" / "state").exists()          # stays on the node
    assert sorted(result["files"]) == ["config.json", "final/params_seed0.npz", "metrics.jsonl", "train.log"]
    assert json.loads(result["files"]["config.json"])["argv"][-1] == str(scratch)
    path = tmp_path / "driver-study" / rel
    (path / "checkpoints" / "1").mkdir(parents=True)                      # a partial run's, from before
    rayrun.land(path, result)
    assert (path / "final" / "params_seed0.npz").read_bytes() == b"params"
    assert (path / "metrics.jsonl").exists() and not (path / "checkpoints").exists()


def test_dry_run_estimate_from_the_finished_runs(tmp_path):
    """Finished runs of 1,000 env steps: task A's took 100 s and 300 s (0.1 and 0.3 s per env step), B's 50 s
    (0.05).
    To do: A with 2,000 env steps of which 500 are done (1,500 × 0.2 = 300 s), B with 1,000 (50 s), C
    with none finished (1,000 × the mean of the three rates, (0.1 + 0.3 + 0.05) / 3 = 0.15: 150 s): 500 s."""
    from types import SimpleNamespace

    def job(task, name, total, done=0, wall=None):
        path = tmp_path / task / name
        path.mkdir(parents=True)
        if wall is not None:
            (path / "metrics.jsonl").write_text(json.dumps({"epoch": 1, "seed": 0, "env_steps": total,
                                                            "walltime": wall}) + "\n")
        return runner.Job(SimpleNamespace(task=task, folder=name, rel=name), path, [], total, done)

    # Rates (s per env step): A/a1 0.1, A/a2 0.3, B/b 0.05. A/a1 again (a second draw) uses its own mean
    # 0.1: 1000 steps -> 100 s; A/a3 (no A/a3 finished) A's slowest 0.3: 1500 steps left -> 450 s; B/b2
    # B's slowest 0.05 -> 50 s; C/c (no C finished) the slowest of all 0.3 -> 300 s; 900 s in all.
    done = [job("A", "a1", 1000, 1000, 100.0), job("A", "a2", 1000, 1000, 300.0),
            job("B", "b", 1000, 1000, 50.0)]
    todo = [job("A", "a3", 2000, 500), job("B", "b2", 1000), job("C", "c", 1000)]
    again = runner.Job(SimpleNamespace(task="A", folder="a1", rel="a1"), tmp_path / "A" / "a1", [], 1000, 0)
    assert runner.estimate(done, todo + [again]) == (
        "estimate: 4 run(s) to do ≈ 15m00s of training on one worker (at the wall time per env step of the 3 "
        "finished run(s) here; C: no finished run yet, the slowest)")
    assert runner.estimate([], todo) is None and runner.estimate(done, []) is None
    # on 2 workers, in this order (100, 450, 50, 300 s): 100 on w0, 450 on w1, 50 on w0 (free at 100, ends
    # 150), 300 on w0 (free at 150, ends 450): both end at 450 s
    assert runner.estimate(done, [again] + todo, workers=2) == (
        "estimate: 4 run(s) to do ≈ 15m00s of training on one worker, ≈ 7m30s on 2 workers (at the wall time "
        "per env step of the 3 finished run(s) here; C: no finished run yet, the slowest)")


def test_makespan_follows_the_runners_order():
    """Jobs start in order on the slot that frees first (run_local). 3 workers, jobs 10, 1, 1, 1, 5 s: 10,
    1 and 1 start at 0; the fourth at 1 (ends 2); the fifth at 1 on the other slot freed then (ends 6): the
    last ends at 10. In the order 1, 1, 1, 10, 5 the 10 s job starts at 1 (ends 11), the 5 s at 1 (ends 6):
    11. One worker: the sum, 18; more workers than jobs: the longest, 10."""
    assert runner.makespan([10, 1, 1, 1, 5], 3) == 10
    assert runner.makespan([1, 1, 1, 10, 5], 3) == 11
    assert runner.makespan([10, 1, 1, 1, 5], 1) == 18
    assert runner.makespan([10, 1, 1, 1, 5], 8) == 10


def _forecast_job(root, task, name, seeds, total=1000, wall=None, sweep=None):
    """A `runner.Job` of `seeds` seeds and `total` env steps under `root`: finished in `wall` seconds (its
    metrics.jsonl says so), or to do without `wall`; `sweep`: its method's (field, value, base label)."""
    from types import SimpleNamespace

    path = root / ("done" if wall is not None else "todo") / task / f"{name}-{seeds}"
    path.mkdir(parents=True, exist_ok=True)
    if wall is not None:
        (path / "metrics.jsonl").write_text(json.dumps({"epoch": 1, "seed": 0, "env_steps": total,
                                                        "walltime": wall}) + "\n")
    run = SimpleNamespace(task=task, folder=name, rel=name, seeds=tuple(range(seeds)),
                          methods=(SimpleNamespace(sweep=sweep),))
    return runner.Job(run, path, [], total, total if wall is not None else 0)


def test_forecast_scales_rates_between_seed_counts(tmp_path):
    """Rates in s per env step (all seeds' steps). A/m finished with 5 seeds at 0.1 and with 10 at 0.07;
    A/q with 5 seeds at 0.2, B/m with 5 at 0.04. The only measured 5 -> 10 ratio is A/m's 0.7, so A/q at 10
    seeds forecasts 0.2 x 0.7 = 0.14 and B/m at 10 seeds 0.04 x 0.7 = 0.028; A/m at 10 seeds uses its own
    0.07. No run measures 5 -> 2 or 5 -> 20: 2 seeds scale by 5/2 (B/m: 0.1, a run no longer than its
    5-seed run), 20 by 1 (B/m: 0.04, as if the time doubled with the seeds). A new method on B at 10 seeds
    (B/q): B's slowest run, none of 10 seeds, so B/m's 0.04 scaled, 0.028. A task with no finished run (C):
    the slowest (task, method) pair of its seed count scaled to its method, at 10 seeds A/m's own 0.07 (not
    A/q's 0.2 scaled to 10 by the largest ratio, 0.14: runs of its own seed count come first), at 5 seeds
    the largest of A/m's 0.1, A/q's 0.2 x m / q on A (0.1 / 0.2) = 0.1 and B/m's 0.04: 0.1."""
    job = functools.partial(_forecast_job, tmp_path)

    forecast = runner.Forecast([job("A", "m", 5, wall=100.0), job("A", "m", 10, wall=70.0),
                                job("A", "q", 5, wall=200.0), job("B", "m", 5, wall=40.0)])
    assert forecast.scale(5, 10) == pytest.approx(0.7)
    expected = {("A", "q", 10): 0.14, ("B", "m", 10): 0.028, ("A", "m", 10): 0.07, ("A", "m", 5): 0.1,
                ("B", "m", 2): 0.1, ("B", "m", 20): 0.04, ("B", "q", 10): 0.028, ("C", "m", 10): 0.07,
                ("C", "m", 5): 0.1}
    for (task, name, seeds), rate in expected.items():
        assert forecast.seconds(job(task, name, seeds)) == pytest.approx(1000 * rate), (task, name, seeds)


def test_forecast_prefers_the_same_task_at_the_same_seed_count(tmp_path):
    """A method's first 10-seed run on a task is forecast from another method's 10-seed runs on that task,
    times the largest ratio between the two methods' 10-seed rates on the other tasks; not from its own
    5-seed run (which may have shared its GPU). Rates in s per env step:
        A: td3 @10 0.02, sf2 @5 0.5 (the shared-GPU run), spr @10 0.01
        B: td3 @10 0.03, sf2 @10 0.045 (sf2/td3 1.5), sf2 @5 0.06
        C: td3 @10 0.01, sf2 @10 0.012 (sf2/td3 1.2), spr @10 0.008 (sf2/spr 1.5)
    A/sf2 @10: from td3, 0.02 x max(1.5, 1.2) = 0.03; from spr, 0.01 x 1.5 (C only) = 0.015; the larger,
    0.03 (not 0.5 x 0.75 = 0.375 from its own 5-seed run scaled by B's 5 -> 10 ratio 0.045 / 0.06).
    A/sf2 @5: its own 0.5. B/spr @10: from td3 0.03 x max(0.01 / 0.02 (A), 0.008 / 0.01 (C)) = 0.024, from
    sf2 0.045 x 0.008 / 0.012 (C) = 0.03: the larger, 0.03. C/sim @10 (sim never finished anywhere): no
    ratio, C's slowest, 0.012. A/sf2 @20: no run of 20 seeds, so no relative rate: A/sf2 @5 x scale(5, 20)
    = 0.5 x 1."""
    job = functools.partial(_forecast_job, tmp_path)

    finished = {("A", "td3", 10): 20.0, ("A", "sf2", 5): 500.0, ("A", "spr", 10): 10.0,
                ("B", "td3", 10): 30.0, ("B", "sf2", 10): 45.0, ("B", "sf2", 5): 60.0,
                ("C", "td3", 10): 10.0, ("C", "sf2", 10): 12.0, ("C", "spr", 10): 8.0}
    forecast = runner.Forecast([job(t, m, n, wall=w) for (t, m, n), w in finished.items()])
    assert forecast.relative("A", "sf2", 10) == pytest.approx(0.03)
    expected = {("A", "sf2", 10): 0.03, ("A", "sf2", 5): 0.5, ("B", "spr", 10): 0.03, ("C", "sim", 10): 0.012,
                ("A", "sf2", 20): 0.5}
    for (task, name, seeds), rate in expected.items():
        assert forecast.seconds(job(task, name, seeds)) == pytest.approx(1000 * rate), (task, name, seeds)


def test_forecast_prices_a_new_task_from_the_slowest_pair_scaled_to_its_method(tmp_path):
    """A task with no finished run (C), 10 seeds, rates in s per env step. A: td3 0.02, sf2 0.03, spr 0.01;
    B (slower physics): td3 0.05. Each finished pair's rate times the largest ratio of the job's method to
    that pair's method on a task both ran (A only), the largest:
        C/td3: A/td3 0.02, A/sf2 0.03 x 2/3 = 0.02, A/spr 0.01 x 2 = 0.02, B/td3 0.05: 0.05
        C/sf2: A/td3 0.02 x 1.5 = 0.03, A/sf2 0.03, A/spr 0.01 x 3 = 0.03, B/td3 0.05 x 1.5 = 0.075
        C/spr: A/td3 0.02 x 0.5, A/sf2 0.03 x 1/3, A/spr 0.01, B/td3 0.05 x 0.5 = 0.025
    C/sim (no run anywhere, nothing relates it): the slowest run of all, 0.05. Without the scaling every one
    of them would be 0.05 (`bench.lab.forecast_check --new-task-rule seed-count`). At 1 seed (no run of 1
    seed; no measured 10 -> 1 ratio, so `scale` gives 10 / 1): C/spr 0.025 x 10 = 0.25, C/sim 0.05 x 10."""
    job = functools.partial(_forecast_job, tmp_path)

    finished = {("A", "td3"): 20.0, ("A", "sf2"): 30.0, ("A", "spr"): 10.0, ("B", "td3"): 50.0}
    forecast = runner.Forecast([job(t, m, 10, wall=w) for (t, m), w in finished.items()])
    expected = {"td3": 0.05, "sf2": 0.075, "spr": 0.025, "sim": 0.05}
    for name, rate in expected.items():
        assert forecast.seconds(job("C", name, 10)) == pytest.approx(1000 * rate), name
    assert forecast.scaled_slowest("sim", 10) is None
    assert forecast.seconds(job("C", "spr", 1)) == pytest.approx(1000 * 0.25)
    assert forecast.seconds(job("C", "sim", 1)) == pytest.approx(1000 * 0.5)


def test_forecast_caps_a_run_of_fewer_seeds_by_one_of_more(tmp_path):
    """A run of fewer seeds never takes longer than one of more seeds of its task and method (`Forecast`
    docstring). 100 env steps per seed. A/m: 5 seeds took 500 s (a shared GPU), 10 seeds 200 s: the
    5-seed rate 500 / 500 = 1.0 is capped at the 10-seed run's 200 / 1000 x 10 / 5 = 0.4, so another
    5-seed run of A/m is forecast at 500 x 0.4 = 200 s, the 10-seed run's wall time. B/m: 5 seeds 150 s,
    10 seeds 200 s, so 0.3 stays (under 0.4). B/q (no run) at 5 seeds is forecast from B/m at 5 seeds times
    q / m on A (A/q 5 seeds took 100 s: 0.2 / 0.4 = 0.5): 0.3 x 0.5 x 500 = 75 s; uncapped, the ratio
    would be 0.2 / 1.0 and B/q 30 s. C (no run): the slowest capped 5-seed rate of all, A/m's 0.4 (B/m 0.3,
    A/q 0.2): 0.4 x 500 = 200 s, not A/m's uncapped 1.0 x 500."""
    def job(task, name, seeds, wall=None):
        return _forecast_job(tmp_path, task, name, seeds, total=100 * seeds, wall=wall)

    finished = {("A", "m", 5): 500.0, ("A", "m", 10): 200.0, ("A", "q", 5): 100.0,
                ("B", "m", 5): 150.0, ("B", "m", 10): 200.0}
    forecast = runner.Forecast([job(t, m, n, wall=w) for (t, m, n), w in finished.items()])
    expected = {("A", "m", 5): 200.0, ("B", "m", 5): 150.0, ("B", "q", 5): 75.0, ("C", "m", 5): 200.0}
    for (task, name, seeds), seconds in expected.items():
        assert forecast.seconds(job(task, name, seeds)) == pytest.approx(seconds), (task, name, seeds)


def test_forecast_prices_a_linear_cost_sweep_from_its_run_values(tmp_path):
    """Points of a sweep over `aux_steps_per_sgd_step` (`runner.LINEAR_COST`; base "TD3+SF²", folders k1, k2,
    ...), 10 seeds, rates in s per env step. A: k1 0.1, k2 0.15, td3 0.05; B: k1 0.2; C: td3 0.05 only.
    A/k4: slope (0.15 - 0.1) / (2 - 1) = 0.05, from k2 0.15 + 0.05 x 2 = 0.25 (from k1 the same); A/k8:
    0.15 + 0.05 x 6 = 0.45; A/k0.5, below every run value: k1's 0.1. B/k2 with one run value: the bound
    0.2 x 2 / 1 = 0.4, B/k8 1.6. C has no run of the sweep: C/k2 from C/td3 times k2 / td3 on A (`relative`),
    0.05 x 3 = 0.15; C/k8 (no run anywhere): C's slowest run times 8 / 1 (the smallest value run), 0.4. A
    sweep over another field (tau_zeta) on C: C's slowest, 0.05, unscaled. A/k1 its own 0.1."""
    def job(task, name, value=None, wall=None, field="aux_steps_per_sgd_step"):
        sweep = None if value is None else (field, str(value), "TD3+SF²")
        return _forecast_job(tmp_path, task, name, 10, wall=wall, sweep=sweep)

    forecast = runner.Forecast([job("A", "k1", 1, 100.0), job("A", "k2", 2, 150.0),
                                job("A", "td3", None, 50.0), job("B", "k1", 1, 200.0),
                                job("C", "td3", None, 50.0)])
    expected = {("A", "k4", 4): 0.25, ("A", "k8", 8): 0.45, ("A", "k0.5", 0.5): 0.1, ("B", "k2", 2): 0.4,
                ("B", "k8", 8): 1.6, ("C", "k2", 2): 0.15, ("C", "k8", 8): 0.4, ("A", "k1", 1): 0.1}
    for (task, name, value), rate in expected.items():
        assert forecast.seconds(job(task, name, value)) == pytest.approx(1000 * rate), (task, name, value)
    assert forecast.seconds(job("C", "t", 0.1, field="tau_zeta")) == pytest.approx(1000 * 0.05)


def test_finish_within_starts_only_runs_forecast_to_end_in_time(tmp_path, monkeypatch):
    """Finished runs of 1,000 env steps took 1e6 s on task A (1,000 s per env step) and 0.001 s on B: with
    60 s to go, B's runs start (forecast ≈ 0 s), A's do not, nor C's (no finished run: the slowest rate,
    1,000 s per env step); a selection with no finished run of its own is forecast from `history` (the
    folder's other finished runs); every run starts without a finished run to forecast from."""
    from types import SimpleNamespace

    study, backend, folder, runs = _setup(tmp_path, monkeypatch)
    jobs, done = runner.plan(study, folder, runs)
    finished = []
    for task, wall in (("A", 1e6), ("B", 1e-3)):
        path = tmp_path / "finished" / task
        path.mkdir(parents=True)
        (path / "metrics.jsonl").write_text(json.dumps({"epoch": 1, "seed": 0, "env_steps": 1000,
                                                        "walltime": wall}) + "\n")
        finished.append(runner.Job(SimpleNamespace(task=task, folder="m", rel="m"), path, [], 1000, 1000))
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(tmp_path) + ":" + ":".join(sys.path),
           "CUDA_VISIBLE_DEVICES": ""}
    log = io.StringIO()
    outcome = runner.run_local(study, folder, jobs, finished, backend=backend, base_env=env, progress=False,
                               poll=0.05, finish_within=60, stream=log)
    assert outcome.ok
    # each finished run's line: the time it took and its forecast at its start (B's: 1e-6 s per env step)
    for j in jobs:
        if j.run.task == "B":
            assert re.search(rf"  {re.escape(j.name)}: done after \d+s \(forecast 0s\)\n", log.getvalue())
    assert sorted(outcome.deferred) == sorted(j.name for j in jobs if j.run.task in ("A", "C"))
    assert sorted(outcome.done) == sorted([j.name for j in jobs if j.run.task == "B"] + ["A/m", "B/m"])
    assert all((j.path / "child.json").exists() == (j.run.task == "B") for j in jobs)
    only_a = [j for j in jobs if j.run.task == "A"]
    outcome = runner.run_local(study, folder, only_a, [], backend=backend, base_env=env, progress=False,
                               poll=0.05, finish_within=60, history=finished)
    assert sorted(outcome.deferred) == sorted(j.name for j in only_a) and not outcome.done
    log = io.StringIO()
    outcome = runner.run_local(study, folder, only_a, [], backend=backend,
                               base_env=env, progress=False, poll=0.05, finish_within=60, stream=log)
    assert not outcome.deferred and len(outcome.done) == 2            # nothing to forecast from: all start
    # the first to finish had no forecast at its start (no finished run then): its line says none
    assert re.search(r": done after \d+s\n", log.getvalue()), log.getvalue()


MIXED = """
name = "two-cores"
seeds = "0-1"
tasks = ["A"]
[[methods]]
label = "TD3 (jax)"
name = "td3"
algo = "td3"
representation = "none"
[[methods]]
label = "TD3 (torch)"
name = "td3-torch"
algo = "td3"
representation = "none"
framework = "torch"
"""


def test_a_method_with_its_own_framework_trains_on_that_core(tmp_path, monkeypatch):
    """Two methods of one config, one on the running core and one on another: two runs (not one shared
    folder), each run by its own core's CLI; the other core's Backend comes from `backend_of`, and a core that
    is not installed is an error naming the method."""
    from sf2_common.agents import tasks as task_table
    from sf2_common.errors import ConfigError

    (tmp_path / "fake_sf2_cli.py").write_text(FAKE_CLI)
    (tmp_path / "fake_torch_cli.py").write_text(FAKE_CLI.replace("child.json", "torch-child.json"))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(task_table, "validate_task", lambda task: task)

    def make(preset, task, algo, rep, overrides):
        return TrainConfig(task=task, algo=algo, representation=rep, num_timesteps=1000, num_envs=4,
                           min_replay_size=8, num_evals=3)

    jax_core = runner.Backend("sf2-fake", "jax", "fake_sf2_cli", make, lambda cfg, seeds: cfg)
    torch_core = runner.Backend("sf2-faketorch", "torch", "fake_torch_cli", make, lambda cfg, seeds: cfg)
    study = spec.loads(MIXED, tmp_path / "s.toml")
    assert [m.framework for m in study.methods] == [None, "torch"]
    runs = spec.resolve(study, make, jax_core.validate, {"torch": torch_core}.__getitem__)
    assert [(r.folder, r.cli_module) for r in runs] == [("td3", None), ("td3-torch", "fake_torch_cli")]
    folder = StudyFolder(tmp_path / "study")
    folder.open(study, "jax", runs)
    jobs, done = runner.plan(study, folder, runs)
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(tmp_path) + ":" + ":".join(sys.path),
           "CUDA_VISIBLE_DEVICES": ""}
    assert runner.run_local(study, folder, jobs, done, backend=jax_core, base_env=env, progress=False,
                            poll=0.05).ok
    assert (folder.path_of(runs[0]) / "child.json").exists()
    assert (folder.path_of(runs[1]) / "torch-child.json").exists()

    def missing(name):
        raise ConfigError(f"framework {name!r} is not installed")

    with pytest.raises(spec.StudyError, match="method 'TD3 \\(torch\\)' on task A: framework 'torch' is not"):
        spec.resolve(study, make, jax_core.validate, missing)
    bad = MIXED.replace('framework = "torch"', 'framework = "tf"')
    with pytest.raises(spec.StudyError, match="framework = 'tf' is not one of jax, torch"):
        spec.loads(bad, tmp_path / "bad.toml")


def test_log_reaches_every_train_command(tmp_path, monkeypatch):
    """`study run --log SINKS` becomes each run's `train --log SINKS`; none without it."""
    study, backend, folder, runs = _setup(tmp_path, monkeypatch)
    plain, _ = runner.plan(study, folder, runs)
    logged, _ = runner.plan(study, folder, runs, "tensorboard,wandb")
    assert all("--log" not in job.commands[0] for job in plain)
    assert [job.commands[0] for job in logged] == [[*job.commands[0], "--log", "tensorboard,wandb"]
                                                   for job in plain]
