"""Tests of the harness itself: the torch step it times is the JAX agents' step, the reports render."""

from __future__ import annotations

import csv
import json
import time

import numpy as np
import pytest

from bench import report, sizes, timing
from bench.sizes import Case


# ----------------------------------------------------------------------------- the torch step timed
@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_torch_runner_times_the_agents_step(algo):
    """The torch update timed here is `sf2_torch.agents`' `step_noise` + `sgd_step` (equal to the JAX
    agents' step: tests/test_step_agents_cross.py): two updates move every trained group and target and
    stay finite; FlopCounterMode counts the SF² update above the vanilla one."""
    torch = pytest.importorskip("torch")
    from sf2_torch import params

    from bench import torch_steps

    flops = {}
    for rep in ("none", "sf2"):
        case = Case("torch", algo, rep, "HopperHop", "small", 2 if rep == "sf2" else 0,
                    "midpoint" if rep == "sf2" else "")
        upd = torch_steps.AgentsUpdate(case, "cpu", seed=0, dtype=torch.float64)
        before = params.to_canonical(upd.alg.groups)
        upd.step()
        upd.step()
        after = params.to_canonical(upd.alg.groups)
        moved = {n.split(".")[0] for n in before if not np.array_equal(before[n], after[n])}
        trained = set(upd.alg.trained_groups()) | {"target_q"} | {g for g in upd.alg.groups if g in (
            "target_policy", "target_psi", "target_zeta")}
        assert trained <= moved, f"groups that did not move: {trained - moved}"
        assert upd.finite()
        flops[rep] = torch_steps.count_flops(case)
    assert flops["sf2"] > flops["none"] > 0


# ------------------------------------------------------------------------------------------ prototypes
def test_prototypes_are_the_cores_flow_loss_under_another_dot_precision():
    """A precision prototype is `sf2_jax.losses.flow_loss` itself with one networks function traced under
    a dot algorithm: with "highest" it equals flow_loss (float64, loss and (ψ, ζ) gradient), the patch is
    undone after each call, the GPU-only algorithms reach XLA (refused on a CPU), retired names are refused
    with their reason."""
    jax = pytest.importorskip("jax")
    import jax.numpy as jnp
    from sf2_common.config import SF2Config
    from sf2_jax import losses, networks
    from sf2_jax.losses import Batch

    from bench import data, prototypes

    D, A, B = 5, 2, 8
    cfg = SF2Config(obs_size=D, action_size=A, hidden_sizes=(16,), zeta_hidden_sizes=(16, 12),
                    feature_size=8, q_hidden_size=8, embedding_size=4, denoising_steps=2)
    contract = networks.contract
    with jax.enable_x64(True):
        nets = networks.make_networks(cfg, "td3")
        params = networks.init_params(nets, jax.random.key(0), dtype=jnp.float64)
        raw = data.make_batches(D, A, B, 1, seed=0)[0]
        batch = Batch(*(jnp.asarray(raw[f], jnp.float64) for f in data.FIELDS))
        rng = np.random.default_rng(1)
        inputs = (jnp.asarray(rng.uniform(-1, 1, (B, A))), jnp.asarray(rng.standard_normal((B, D))),
                  jnp.asarray(rng.uniform(size=B)))

        def run(fn):
            return jax.jit(jax.value_and_grad(lambda p: fn(nets, p, batch, *inputs)[0]))(params)

        ref, ref_grad = run(losses.flow_loss)
        for function, target_only in (("contract", False), ("velocity_contracted", True)):
            loss, grad = run(prototypes.with_precision(function, target_only, "highest"))
            assert networks.contract is contract
            np.testing.assert_array_equal(loss, ref)
            for a, b in zip(jax.tree_util.tree_leaves(grad), jax.tree_util.tree_leaves(ref_grad)):
                np.testing.assert_array_equal(a, b)
        if jax.default_backend() == "cpu":
            with pytest.raises(ValueError, match="TF32_TF32_F32_X3.*not supported by dot_general on CPU"):
                run(prototypes.variant("x3tf32"))
    assert networks.contract is contract
    with pytest.raises(ValueError, match=r"'bhd' \(a layout of M before .*valid are x3tf32"):
        prototypes.variant("bhd")
    with pytest.raises(ValueError, match="now the cores' flow_loss"):
        prototypes.variant("merged")


# ------------------------------------------------------------------------------------------ reports
def test_grid_and_keys():
    cases = sizes.grid(("jax", "torch-compile"), ("td3",), ("none", "sf2"), ["CheetahRun"], "small",
                       (1, 2, 8), ("midpoint", "euler"), compiled_steps=(1, 8))
    keys = [c.key for c in cases]
    assert len(keys) == len(set(keys))
    assert "jax/td3/sf2/T2/euler/CheetahRun/small" in keys
    assert "torch-compile/td3/sf2/T2/midpoint/CheetahRun/small" not in keys
    assert sizes.unique_sizes(list(sizes.TASKS)) == [
        "AcrobotSwingup", "CartpoleBalanceSparse", "CheetahRun", "FishSwim", "HopperHop", "PendulumSwingup"]


def test_timing_protocol_counts_every_update():
    calls = {"step": 0, "sync": 0}

    def step():
        calls["step"] += 1

    def sync():
        calls["sync"] += 1

    r = timing.Runner("x", step, sync)
    timing.calibrate(r, warmup=2, block_s=0.001, max_n=64)
    before = calls["step"]
    timing.measure([r], repeats=3, log=lambda s: None)
    assert calls["step"] - before == 3 * r.n
    assert len(r.times) == 3
    m, lo, hi = timing.paired_ratio([2.0, 4.0, 6.0], [1.0, 2.0, 2.0])
    assert m == 2.0 and lo <= m <= hi


def _fake_rows():
    rows = []
    for fw, scale in (("jax", 1.0), ("torch", 2.0)):
        rows.append(dict(framework=fw, algo="td3", rep="none", task="CheetahRun", size="small",
                         steps=0, integrator="", median_ms=1.0 * scale, q25_ms=0.9 * scale,
                         q75_ms=1.1 * scale, min_ms=0.8 * scale, times_ms=[scale] * 3, flops=1e9,
                         bytes=1e6, obs_size=17, action_size=6, batch_size=256, repeats=3, n_per_block=1))
        for T in (1, 2, 4, 8):
            t = (1.2 + 0.02 * (T - 1)) * scale
            rows.append(dict(framework=fw, algo="td3", rep="sf2", task="CheetahRun", size="small", steps=T,
                             integrator="midpoint", median_ms=t, q25_ms=t, q75_ms=t, min_ms=t,
                             times_ms=[t] * 3, flops=2e9, bytes=1e6, obs_size=17, action_size=6,
                             batch_size=256, repeats=3, n_per_block=1))
    return rows


def test_report_ratios_targets_and_rerender(tmp_path):
    rows = _fake_rows()
    idx = report._index(rows)
    assert report.per_step_pct(idx, "jax", "td3", "CheetahRun", "small", "midpoint") == pytest.approx(
        0.02 / 1.2 * 100)
    res = {r["target"]: r for r in report.targets(idx, ["CheetahRun"], ["jax"], "small", [1, 2, 4, 8],
                                                  ["midpoint"])}
    assert res["JAX (jit): SF² (T=1) / vanilla TD3 ≤ 1.3×"]["met"]
    assert res["JAX (jit): each extra denoising step (midpoint) ≤ 3% of T=1"]["met"]
    machine = {"name": "test", "command": "python -m bench", "peak": {"jax": 1.0}}
    md = report.markdown(rows, machine)
    assert "SF² T=1 / vanilla" in md and "1.20×" in md and "torch eager / JAX" in md and "2.00×" in md
    report.write_csv(rows, tmp_path / "updates.csv")
    (tmp_path / "machine.json").write_text(json.dumps(machine))
    report.render(tmp_path)
    assert (tmp_path / "updates.png").stat().st_size > 1000
    with open(tmp_path / "updates.csv") as f:
        assert len(list(csv.DictReader(f))) == len(rows)
    again = report.read_csv(tmp_path / "updates.csv")
    assert again[1]["times_ms"] == pytest.approx(rows[1]["times_ms"])


def test_cli_end_to_end(tmp_path):
    """A tiny run writes every output; `report` re-renders them."""
    pytest.importorskip("jax")
    from bench import cli

    out = tmp_path / "res"
    cli.main(["run", "--size", "small", "--tasks", "pendulum", "--frameworks", "jax,torch", "--algos", "td3",
              "--reps", "none,sf2",
              "--steps", "1,2", "--integrators", "euler", "--repeats", "3", "--warmup", "1",
              "--block-s", "0.01", "--out", str(out), "--no-peak"])
    for name in ("updates.csv", "updates.md", "updates.png", "machine.json", "log.txt"):
        assert (out / name).exists(), name
    rows = report.read_csv(out / "updates.csv")
    assert {r["framework"] for r in rows} == {"jax", "torch"} and len(rows) == 6
    assert all(r["finite"] == "True" for r in rows)
    md = (out / "updates.md").read_text()
    assert "PendulumSwingup" in md and "python -m bench run" in md
    cli.main(["report", str(out)])


@pytest.mark.parametrize("argv,message", [
    (["run", "--frameworks", "jax,tpu"], "--frameworks: 'tpu' unknown; valid: jax, jax-scan, torch"),
    (["run", "--reps", "none,bogus"], "--reps: 'bogus' unknown; valid: none, sf2"),
    (["run", "--reps", "sf2-bhd"], "--reps: 'sf2-bhd' is retired (a layout of M"),
    (["run", "--tasks", "cheetah,nope"], "--tasks: unknown task 'nope': valid are AcrobotSwingup"),
    (["run", "--steps", "1,x"], "--steps: '1,x' is not a comma list of denoising steps >= 1"),
    (["run", "--compiled-steps", "0"], "--compiled-steps: '0' is not a comma list"),
    (["run", "--algos", "ddpg"], "--algos: 'ddpg' unknown; valid: td3, sac"),
    (["run", "--integrators", "rk4"], "--integrators: 'rk4' unknown; valid: midpoint, euler"),
    (["run", "--flow-variants", "merged"], "--flow-variants: unknown prototype 'merged' (now the cores'"),
    (["flow-step", "--variants", "zz"], "--variants: unknown prototype 'zz'"),
])
def test_bad_bench_input_exits_2_before_anything_runs(argv, message, tmp_path, capsys):
    """A name the bench does not know stops it naming the flag and the valid choices, with nothing
    written (before: an unknown framework or representation was skipped silently, a task or step list
    stopped it with a traceback)."""
    pytest.importorskip("jax", reason="the bench's checks import its JAX prototypes: install the JAX core")
    from bench import cli

    out = tmp_path / "never"
    with pytest.raises(SystemExit) as exit_:
        cli.main([*argv, "--out", str(out), "--no-peak"] if argv[0] == "run" else [*argv, "--out", str(out)])
    assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("module,argv,message", [
    ("agent_throughput", ["--frameworks", "tpu"], "--frameworks: 'tpu' unknown; valid: jax, torch"),
    ("agent_throughput", ["--seeds", "1,0"], "--seeds: '1,0' is not a comma list of seed counts >= 1"),
    ("agent_throughput", ["--epochs", "0"], "--epochs 0, --env-steps 600000: each must be >= 1"),
    ("agent_throughput", ["--tasks", "Nope"], "unknown task 'Nope'"),
    ("agent_throughput", ["--precisions", "fp8"], "learner_precision = 'fp8' is invalid"),
    ("agent_throughput", ["--reps", "bogus"], "representation = 'bogus' is invalid"),
    ("agent_throughput", ["--set", "compile=off"], "unknown config field 'compile'"),
    ("agent_throughput", ["--frameworks", "torch", "--set", "compile=fast"], "compile = 'fast' is invalid"),
    ("physics", ["--tasks", "CheetahRun,Nope"], "--tasks: unknown task 'Nope'"),
    ("physics", ["--envs", "128,0"], "each must be >= 1"),
    ("eval_sensitivity", ["--task", "Nope"], "unknown task 'Nope'"),
    ("eval_sensitivity", ["--seeds", "3-1"], "seeds '3-1' are invalid"),
    ("eval_sensitivity", ["--set", "num_eval_envs=0"], "num_eval_envs = 0 is invalid"),
])
def test_bad_throughput_input_exits_2_before_anything_runs(module, argv, message, tmp_path, capsys):
    pytest.importorskip("mujoco_playground", reason="these CLIs validate against the Playground task "
                        "list and the agents' registry: install a core's [train] extra")
    import importlib

    out = tmp_path / "never"
    with pytest.raises(SystemExit) as exit_:
        importlib.import_module(f"bench.{module}").main([*argv, "--out", str(out)])
    assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("argv,message", [
    (["--programs", "init,foo"], "--programs: 'foo'; valid: init, epoch, evaluate"),
    (["--seeds", "1"], "--seeds 1: needs at least 2 to spread over devices"),
    (["--task", "Nope"], "unknown task 'Nope'"),
    (["--rep", "bogus"], "representation = 'bogus' is invalid"),
])
def test_bad_shard_probe_input_exits_2(argv, message, capsys):
    pytest.importorskip("mujoco_playground", reason="the probe validates against the Playground task list "
                        "and the agents' registry: install a core's [train] extra")
    from bench import shard_probe

    with pytest.raises(SystemExit) as exit_:
        shard_probe.main(argv)
    assert exit_.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize("framework", ["jax", "torch"])
@pytest.mark.parametrize("argv,message", [
    (["--task", "Nope"], "unknown task 'Nope'"),
    (["--reps", "bogus"], "representation = 'bogus' is invalid"),
    (["--seeds", "two"], "invalid literal for int()"),
])
def test_bad_agent_profile_input_exits_2_before_writing(framework, argv, message, capsys, tmp_path):
    pytest.importorskip("mujoco_playground", reason="the profile validates against the Playground task list: "
                        "install a core's [train] extra")
    from bench import agent_profile

    with pytest.raises(SystemExit) as exit_:
        agent_profile.main([*argv, "--framework", framework, "--out", str(tmp_path / "out")])
    assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_agent_profile_hlo_is_the_jax_trainers(capsys, tmp_path):
    """`--hlo` counts XLA's compiled kernels: with the torch trainer it exits 2 before writing anything."""
    pytest.importorskip("mujoco_playground", reason="the profile validates against the Playground task list: "
                        "install a core's [train] extra")
    from bench import agent_profile

    with pytest.raises(SystemExit) as exit_:
        agent_profile.main(["--framework", "torch", "--hlo", "--out", str(tmp_path / "out")])
    assert exit_.value.code == 2 and "--hlo counts the JAX trainer's" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_shard_probe_without_a_mesh_says_what_it_needs(monkeypatch):
    """One device, or SF2_SHARD_SEEDS unset: the probe names what is missing instead of probing nothing.
    (On two host CPU devices it runs every program: packages/sf2-core-jax/tests/agents/test_devices.py
    checks the sharded programs themselves.)"""
    pytest.importorskip("mujoco_playground", reason="the probe builds the trainer: install the JAX core's "
                        "[train] extra")
    from bench import shard_probe

    monkeypatch.delenv("SF2_SHARD_SEEDS", raising=False)
    with pytest.raises(SystemExit, match="no seed mesh: needs SF2_SHARD_SEEDS=1 and several local devices"):
        shard_probe.main(["--config", "quick", "--task", "PendulumSwingup", "--seeds", "2"])


# ----------------------------------------------------------------------------- eval_share
def test_eval_share_of_a_run_folder(tmp_path):
    """Two seeds, epochs 0-2: seed 0's rows give the run's numbers (by hand: evaluations after epoch 0
    1.5 + 1.5 = 3 s of a 10 s run; epochs 2 + 2 = 4 s; 2 seeds x 200 env steps / 10 s = 40 steps/s)."""
    from bench import eval_share

    rows = []
    for epoch, env_steps, wall in ((0, 0, 3.0), (1, 100, 6.5), (2, 200, 10.0)):
        for seed in (0, 1):
            row = {"epoch": epoch, "seed": seed, "env_steps": env_steps, "walltime": wall,
                   "eval_seconds": 3.0 if epoch == 0 else 1.5}
            if epoch:
                row["epoch_seconds"] = 2.0
            rows.append(row)
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    got = eval_share.measure(tmp_path)
    assert (got["wall_s"], got["eval_s"], got["train_s"], got["eval_share"], got["env_steps_per_s"]) == (
        10.0, 3.0, 4.0, 0.3, 40)
    # epochs 1-2 only: 10.0 - 6.5 = 3.5 s, one evaluation 1.5 s, one epoch 2 s, 2 x 100 steps / 3.5 s = 57
    got = eval_share.measure(tmp_path, (1, 2))
    assert (got["epochs"], got["wall_s"], got["eval_s"], got["train_s"], got["eval_share"],
            got["env_steps_per_s"]) == ("1-2", 3.5, 1.5, 2.0, round(1.5 / 3.5, 3), round(200 / 3.5))
    with pytest.raises(SystemExit, match="has epochs 0-2, not 1 and 5"):
        eval_share.measure(tmp_path, (1, 5))
    # a study folder in results/ keeps metrics.jsonl gzip-compressed: the same numbers
    from sf2_common.fileio import compress

    assert compress(tmp_path / "metrics.jsonl")
    assert eval_share.measure(tmp_path, (1, 2)) == got
    # seeds, the GPU and the train processes: from config.json and train.log, "not recorded" / None without
    assert (got["seeds"], got["hardware"], got["starts"], got["save_wait_s"]) == (
        2, "not recorded", None, None)
    conf = {"config": {}, "seeds": [0, 1], "hardware": "NVIDIA H200"}
    (tmp_path / "config.json").write_text(json.dumps(conf))
    (tmp_path / "train.log").write_text("\n$ python -m sf2_jax.cli train --task T --out x   # 1\nepoch 3\n"
                                        "$ python -m sf2_jax.cli eval x --save   # 2\n"
                                        "$ python -m sf2_jax.cli train --task T --out x   # 3\nresuming\n"
                                        "2026-11-26 12:49:38 absl WARNING: Waiting for previous save to "
                                        "complete took 2.853596 seconds. If this number is high, ...\n"
                                        "12:50:03 absl WARNING: Waiting for previous save to complete "
                                        "took 3.1 seconds.\n")
    got = eval_share.measure(tmp_path)
    assert (got["seeds"], got["hardware"], got["starts"]) == (2, "NVIDIA H200", 2)
    # checkpoint waits 2.853596 + 3.1 = 5.95 s (whole runs only)
    assert got["save_wait_s"] == 6.0 and eval_share.measure(tmp_path, (1, 2))["save_wait_s"] is None
    # a damaged config.json is named (RunFolder's check), not read as "not recorded"
    (tmp_path / "config.json").write_text('{"config": {')
    with pytest.raises(SystemExit, match=r"config.json is not valid JSON"):
        eval_share.measure(tmp_path)
    with pytest.raises(SystemExit, match="no metrics.jsonl"):
        eval_share.measure(tmp_path / "missing")


@pytest.mark.parametrize("env_steps,epochs,prefill,expected", [
    (16_000, 3, 8_192, (5_334, 2)),   # 8,192 // 5,334 = 1 whole prefill epoch, the next holds SGD step 1
    (32_000, 2, 8_192, (16_000, 1)),  # the prefill ends inside epoch 1
    (10_000, 2, 5_000, (5_000, 2)),   # epoch 1 is all prefill; SGD starts at env step 5,001, in epoch 2
    (10_000, 2, 0, (5_000, 1)),       # no prefill: epoch 1 still holds the compilation and SGD step 1
])
def test_throughput_warm_up_holds_the_first_sgd_step(env_steps, epochs, prefill, expected):
    """The timed epochs of `bench.agent_throughput` start after the epoch of the first SGD step (where the
    torch trainer compiles its update): before, one fixed first epoch left the compile inside a timed
    epoch when the prefill outlasted it (H100, 2026-11-25: torch epochs 22.9, 0.82, 0.91 s)."""
    from bench.agent_throughput import warm_up

    assert warm_up(env_steps, epochs, prefill) == expected


def test_throughput_config_times_only_whole_sgd_epochs():
    pytest.importorskip("mujoco_playground", reason="the paper preset's config needs the Playground "
                        "task list: install a core's [train] extra")
    from sf2_common.agents.configs import schedule

    from bench.agent_throughput import config_for

    cfg, warm = config_for("AcrobotSwingup", "td3", "sf2", 1, 16_000, 3, {})
    sched = schedule(cfg)
    per = sched.env_steps_per_epoch
    assert sched.num_epochs == warm + 3
    assert (warm - 1) * per <= sched.prefill_env_steps < warm * per   # the first SGD step is in the warm-up


# ----------------------------------------------------------------------------- forecast_check
def test_forecast_check_against_hand_derived_forecasts(tmp_path):
    """Finished runs of 1,000 env steps, 5 seeds each: A/m 100 s (0.1 s per env step), A/q 200 s, B/m 50 s.
    Checking A/q and B/m leaves A/m alone to forecast from (runner.Forecast's preference 4: the slowest
    run of the task, else of all): A/q 0.1 x 1000 = 100 s (took 200: ratio 2.0), B/m (no other run of B)
    100 s (took 50: 0.5). Sums 200 s forecast against 250 s taken (1.25x); median of the ratios 1.25."""
    from types import SimpleNamespace

    from sf2_common.studies import runner
    from sf2_common.studies.spec import StudyError

    from bench import forecast_check

    def job(task, name, wall):
        path = tmp_path / task / name
        path.mkdir(parents=True)
        (path / "metrics.jsonl").write_text(json.dumps({"epoch": 1, "seed": 0, "env_steps": 1000,
                                                        "walltime": wall}) + "\n")
        run = SimpleNamespace(task=task, folder=name, rel=name, seeds=tuple(range(5)))
        return runner.Job(run, path, [], 1000, 1000)

    history = [job("A", "m", 100.0), job("A", "q", 200.0), job("B", "m", 50.0)]
    rows = forecast_check.check(history, history[1:])
    assert [(r["run"], r["seeds"], r["forecast_s"], r["actual_s"], r["ratio"]) for r in rows] == [
        ("A/q", 5, 100.0, 200.0, 2.0), ("B/m", 5, 100.0, 50.0, 0.5)]
    assert forecast_check.summary(rows) == (
        "2 run(s): forecast 3.3 min in all, took 4.2 min (1.25x); actual / forecast per run: min 0.50, "
        "median 1.25, max 2.00; 1 took longer than forecast")
    with pytest.raises(StudyError, match="no finished run outside --runs"):
        forecast_check.check(history, history)
    # leave one out: A/m from A/q and B/m (preference 4, the slowest run of A: A/q, 0.2 s per env step) 200 s,
    # A/q from A/m and B/m 100 s as above, B/m from A/m and A/q (no run of B: the slowest of all, A/q) 200 s
    rows = forecast_check.check(history, history, each=True)
    assert [(r["run"], r["forecast_s"], r["ratio"]) for r in rows] == [
        ("A/m", 200.0, 0.5), ("A/q", 100.0, 2.0), ("B/m", 200.0, 0.25)]
    assert forecast_check.summary(rows) == (
        "3 run(s): forecast 8.3 min in all, took 5.8 min (0.70x); actual / forecast per run: min 0.25, "
        "median 0.50, max 2.00; 1 took longer than forecast")
    # a folder that is not a study folder is named, exit status 2, no traceback
    assert forecast_check.main([str(tmp_path / "nope"), "--runs", str(tmp_path / "A" / "m")]) == 2


def test_checkpoint_cost_timings_are_medians_after_the_warm_up(monkeypatch):
    """`checkpoint_cost._timings` on a fake clock: an awaited save takes 10 s, a background save returns
    after 1 s and its `finish` takes 5 s, a restore 3 s, except in the warm-up (epochs 0 and 1), where each
    takes 100 s more. Two timed repeats: every median is the steady value, the warm-up left out; the
    background save's epoch is the one restored (2i + 1)."""
    from bench import checkpoint_cost

    clock = [0.0]
    monkeypatch.setattr(checkpoint_cost.time, "perf_counter", lambda: clock[0])
    restored = []

    def advance(seconds, epoch):
        clock[0] += seconds + (100.0 if epoch < 2 else 0.0)

    def save(epoch, wait):
        advance(10.0 if wait else 1.0, epoch)
        return lambda: advance(5.0, epoch)

    def restore(epoch):
        restored.append(epoch)
        advance(3.0, epoch)

    times = checkpoint_cost._timings(save, restore, repeats=2)
    assert times == {"save_awaited_s": 10.0, "save_returns_s": 1.0, "finish_s": 5.0, "restore_s": 3.0}
    assert restored == [1, 3, 5]


def test_machine_records_the_settings_that_change_numbers(monkeypatch):
    """machine.json names the switches a rate depends on (a sharded run's SF2_SHARD_SEEDS, TF32 and cuBLAS
    overrides), and leaves the rest of the environment out."""
    from bench import machine

    monkeypatch.setenv("SF2_SHARD_SEEDS", "1")
    monkeypatch.setenv("NVIDIA_TF32_OVERRIDE", "0")
    monkeypatch.setenv("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    monkeypatch.setenv("HOME_TEST_NOT_RECORDED", "y")
    env = machine.describe(".", "python -m bench")["env"]
    assert env["SF2_SHARD_SEEDS"] == "1"
    assert env["NVIDIA_TF32_OVERRIDE"] == "0"
    assert env["CUBLAS_WORKSPACE_CONFIG"] == ":4096:8"
    assert "HOME_TEST_NOT_RECORDED" not in env


def test_torch_profile_lists_the_calls_that_can_wait_first():
    """bench.agent_profile's summary of a torch trace's CUDA runtime calls, per update (2 here): the
    synchronizations first (3 ms over 2 updates = 1.5 ms, 0.5 calls each), then the others."""
    from bench.agent_profile import _runtime_calls

    events = [{"ph": "X", "cat": "cuda_runtime", "name": "cudaLaunchKernel", "dur": 100.0},
              {"ph": "X", "cat": "cuda_runtime", "name": "cudaLaunchKernel", "dur": 100.0},
              {"ph": "X", "cat": "cuda_runtime", "name": "cudaDeviceSynchronize", "dur": 3000.0},
              {"ph": "X", "cat": "kernel", "name": "gemm", "dur": 5000.0}]
    rows = _runtime_calls(events, updates=2)
    assert [(r["name"], r["count"], r["ms"]) for r in rows] == [
        ("cudaDeviceSynchronize", 0.5, 1.5), ("cudaLaunchKernel", 1.0, 0.1)]


def test_idle_gaps_attributes_each_idle_interval_to_the_kernels_around_it():
    """bench.profile.idle_gaps on a hand-made trace (µs), 2 updates. Kernels: a [0, 10) stream 7, b [5, 30)
    stream 7 (inside nothing: it ends last), c [40, 50) stream 9, d [50, 60) stream 9 (no gap), e [62, 70)
    stream 7, f [100, 101) stream 7. Gaps: b→c 10 µs (streams 7→9), d→e 2 µs (9→7), e→f 30 µs (7→7): idle
    42 µs = 0.021 ms per update in 1.5 gaps, 12 µs = 0.006 ms of it across streams; the longest first."""
    from bench.profile import idle_gaps

    def k(name, ts, dur, stream):
        return {"name": name, "ts": ts, "dur": dur, "args": {"stream": stream}}

    ks = [k("c", 40, 10, 9), k("a", 0, 10, 7), k("b", 5, 25, 7), k("d", 50, 10, 9), k("e", 62, 8, 7),
          k("f", 100, 1, 7)]
    g = idle_gaps(ks, updates=2)
    assert abs(g["idle_ms_per_update"] - 0.021) < 1e-12 and g["gaps_per_update"] == 1.5
    assert abs(g["cross_stream_ms_per_update"] - 0.006) < 1e-12
    assert [(t["after"], t["before"], t["count"], t["ms"]) for t in g["top"]] == [
        ("e (stream 7)", "f (stream 7)", 0.5, 0.015), ("b (stream 7)", "c (stream 9)", 0.5, 0.005),
        ("d (stream 9)", "e (stream 7)", 0.5, 0.001)]


def test_torch_profile_phase_timer_splits_the_wall_time():
    """`_PhaseTimer` adds up each phase's host time; `take` gives ms per update and the rest of the wall
    time, and starts again from zero; synchronized, it drains the device before and after each call."""
    from bench.agent_profile import _PhaseTimer

    syncs = []
    timer = _PhaseTimer(lambda: syncs.append(1))
    slow = timer.wrap("slow", lambda: time.sleep(0.02))
    for _ in range(2):
        slow()
    assert syncs == []
    got = timer.take(updates=4, wall=0.1)
    assert got["wall_ms"] == 25.0
    assert 10.0 <= got["phases_ms"]["slow"] < 25.0            # 2 × ≥ 20 ms over 4 updates
    assert abs(got["rest_ms"] - (25.0 - got["phases_ms"]["slow"])) < 1e-9
    timer.synced = True
    slow()
    assert syncs == [1, 1] and timer.take(updates=1, wall=1.0)["phases_ms"]["slow"] >= 20.0


def test_shardy_repro_cases_compute_what_they_say():
    """bench.shardy_repro's cases on this host's devices give the sums of what they compute, derived here
    with NumPy from the same inputs: the Cholesky factors (under Shardy, GSPMD and without shard_map), M·M,
    and 2M beside an empty array plus one (whose sum is 0)."""
    import jax

    from bench import shardy_repro

    m = np.asarray(shardy_repro.matrices(len(jax.local_devices()), 4, 2), dtype=np.float64)
    for case in ("cholesky-shard-map", "cholesky-shard-map-gspmd", "cholesky-jit"):
        assert shardy_repro.run(case, envs=4) == pytest.approx(np.linalg.cholesky(m).sum(), rel=1e-5)
    assert shardy_repro.run("matmul-shard-map", envs=4) == pytest.approx((m @ m).sum(), rel=1e-5)
    assert shardy_repro.run("zero-size-shard-map", envs=4) == pytest.approx(2 * m.sum(), rel=1e-5)
    with pytest.raises(SystemExit, match="unknown case 'nope'"):
        shardy_repro.run("nope")


_HLO = """HloModule jit__epoch_one, is_scheduled=true

%fused_computation (p0: f32[4]) -> f32[4] {
  %p0 = f32[4]{0} parameter(0)
  ROOT %m = f32[4]{0} multiply(%p0, %p0), metadata={op_name="w/critic_grad/mul"}
}

%body (t: (s32[], f32[4])) -> (s32[], f32[4]) {
  %t = (s32[], f32[4]{0}) parameter(0)
  %x = f32[4]{0} get-tuple-element(%t), index=1
  %f1 = f32[4]{0} fusion(%x), calls=%fused_computation, metadata={op_name="w/sgd/critic_grad/mul"}
  %f2 = f32[4]{0} fusion(%f1), calls=%fused_computation, metadata={op_name="w/critic_grad/x/policy_adam/add"}
  %f3 = f32[4]{0} fusion(%f2), calls=%fused_computation, metadata={op_name="w/critic_grad/sum"}, \
kind=kCustom, \
backend_config={"fusion_backend_config":{"block_level_fusion_config":{"num_warps":"4"},"kind":"__triton"}}
  %f4 = f32[4]{0} fusion(%f3), calls=%fused_computation, metadata={op_name="w/critic_adam/dot"}, \
kind=kCustom, backend_config={"fusion_backend_config":{"kind":"__triton_nested_gemm_fusion"}}
  %g = f32[4]{0} custom-call(%f4), custom_call_target="__cublas$gemm", metadata={op_name="w/critic_adam/dot"}
  %c = f32[4]{0} copy(%g), metadata={op_name="w/targets/copy"}
  %i = s32[] get-tuple-element(%t), index=0
  ROOT %r = (s32[], f32[4]{0}) tuple(%i, %c)
}

%cond (t: (s32[], f32[4])) -> pred[] {
  %t = (s32[], f32[4]{0}) parameter(0)
  %i = s32[] get-tuple-element(%t), index=0
  %n = s32[] constant(4)
  ROOT %lt = pred[] compare(%i, %n), direction=LT
}

%branch_a (x: f32[4]) -> f32[4] {
  %x = f32[4]{0} parameter(0)
  ROOT %e = f32[4]{0} fusion(%x), calls=%fused_computation, metadata={op_name="e/explore/cond/mul"}
}

%branch_b (x: f32[4]) -> f32[4] {
  %x = f32[4]{0} parameter(0)
  ROOT %z = f32[4]{0} fusion(%x), calls=%fused_computation, metadata={op_name="e/zeros"}
}

ENTRY %main (a: f32[4], p: pred[]) -> f32[4] {
  %a = f32[4]{0} parameter(0)
  %p = pred[] parameter(1)
  %k = s32[] constant(0)
  %t = (s32[], f32[4]{0}) tuple(%k, %a)
  %w = (s32[], f32[4]{0}) while(%t), condition=%cond, body=%body, \
backend_config={"known_trip_count":{"n":"4"}}
  %y = f32[4]{0} get-tuple-element(%w), index=1
  ROOT %o = f32[4]{0} conditional(%p, %y, %y), branch_computations={%branch_a, %branch_b}
}
"""


@pytest.mark.parametrize("branches", ["branch_computations={%branch_a, %branch_b}",
                                      "true_computation=%branch_a, false_computation=%branch_b"])
def test_hlo_phases_counts_kernels_per_phase_weighted_by_trip_counts(branches):
    """By hand from `_HLO`: the while body runs 4 times (its known trip count) and launches 4 fusions, one
    cuBLAS call and one copy (the fusions' own computation is no launch of its own; get-tuple-element,
    tuple, constant and parameter launch nothing). Of the two Triton fusions (`kind=kCustom`) the
    block-level reduction `f3` is a fusion and the nested GEMM `f4` a GEMM. The loop condition's compare is
    one launch, counted once (the condition is not weighted by the trip count), and each conditional
    branch's fusion once. A fusion's phase is the last phase its op_name names (`f2`: policy_adam, though
    critic_grad comes first); the compare and branch_b's fusion name none: (other). All: 4 × 6 + 1 + 1 + 1
    = 27 launches, 13.5 per SGD step for 2 SGD steps."""
    from bench import hlo_phases

    phases = ("explore", "critic_grad", "critic_adam", "policy_adam", "targets")
    # the two spellings of a conditional's branches (an index conditional's; the GPU's for a predicate)
    got = hlo_phases.count(_HLO.replace("branch_computations={%branch_a, %branch_b}", branches), phases)
    assert got["by_phase"] == {"critic_grad": {"fusion": 8}, "policy_adam": {"fusion": 4},
                               "critic_adam": {"gemm": 8}, "targets": {"copy": 4},
                               "explore": {"fusion": 1}, "(other)": {"fusion": 1, "other": 1}}
    assert got["conditional_branches"] == 2 and got["unknown_trip_count_loops"] == 0
    table = hlo_phases.markdown(got, phases, sgd_steps=2)
    assert "| critic_grad | 4.0 | 0.0 | 4.0 |" in table and "| **all** | **13.5** |" in table


def test_hlo_phases_finds_the_newest_epoch_module_of_a_dump(tmp_path):
    """In a dump folder: the most recently written `*epoch_one*after_optimizations.txt` (whatever its
    module number), never XLA's buffer-assignment report beside it."""
    import os

    from bench import hlo_phases

    old, new = tmp_path / "module_9999.jit__epoch_one.after_optimizations.txt", \
        tmp_path / "module_10000.jit__epoch_one.after_optimizations.txt"
    report = tmp_path / "module_10000.jit__epoch_one.after_optimizations-buffer-assignment.txt"
    for i, f in enumerate((old, new, report)):
        f.write_text(_HLO)
        os.utime(f, ns=(10**18 + i, 10**18 + i))
    assert hlo_phases.find_module(tmp_path) == new
    os.utime(old, ns=(2 * 10**18, 2 * 10**18))
    assert hlo_phases.find_module(tmp_path) == old


def test_hlo_phases_refuses_what_is_not_a_dump(tmp_path, capsys):
    from bench import hlo_phases

    with pytest.raises(SystemExit) as err:
        hlo_phases.main([str(tmp_path)])
    assert err.value.code == 2 and "after_optimizations.txt" in capsys.readouterr().err
    (tmp_path / "x.txt").write_text("not hlo")
    with pytest.raises(SystemExit):
        hlo_phases.main([str(tmp_path / "x.txt")])
    assert "no ENTRY computation" in capsys.readouterr().err


def test_set_takes_the_torch_trainers_fields_with_the_torch_framework_alone():
    """`--set compile=…` (a field of the torch trainer only) is typed by the torch config with `--frameworks
    torch`; with the JAX trainer too it is refused, naming the torch fields and what they need."""
    pytest.importorskip("sf2_torch", reason="the torch trainer's config: install the torch core")
    from sf2_common.errors import ConfigError

    from bench.agent_throughput import parse_sets

    items = ["compile=max-autotune-no-cudagraphs", "batch_size=64"]
    assert parse_sets(items, ["torch"]) == {"compile": "max-autotune-no-cudagraphs", "batch_size": 64}
    assert parse_sets(["batch_size=64"], ["jax", "torch"]) == {"batch_size": 64}
    assert parse_sets([], ["jax"]) == {}
    with pytest.raises(ConfigError, match=r"unknown config field 'compile'.*need the torch framework alone"):
        parse_sets(items, ["jax", "torch"])


_DOT_HLO = """\
HloModule m, entry_computation_layout={(f32[8,3]{1,0}, f32[3,5]{1,0})->f32[8,5]{1,0}}

%fused_dot (p0: f32[8,3], p1: f32[3,5]) -> f32[8,5] {
  %p0 = f32[8,3]{1,0} parameter(0)
  %p1 = f32[3,5]{1,0} parameter(1)
  ROOT %d = f32[8,5]{1,0} dot(f32[8,3]{1,0} %p0, f32[3,5]{1,0} %p1), lhs_contracting_dims={1}, \
rhs_contracting_dims={0}, metadata={op_name="jit(f)/critic_grad/dot_general"}
}

%body (t: (s32[], f32[8,3])) -> (s32[], f32[8,3]) {
  %t = (s32[], f32[8,3]{1,0}) parameter(0)
  %i = s32[] get-tuple-element(%t), index=0
  %x = f32[8,3]{1,0} get-tuple-element(%t), index=1
  %w = f32[3,3]{1,0} constant({...})
  %y = f32[8,3]{1,0} dot(%x, %w), lhs_contracting_dims={1}, rhs_contracting_dims={0}, \
metadata={op_name="jit(f)/targets/dot_general"}
  ROOT %r = (s32[], f32[8,3]{1,0}) tuple(%i, %y)
}

%cond (t: (s32[], f32[8,3])) -> pred[] {
  %t = (s32[], f32[8,3]{1,0}) parameter(0)
  ROOT %c = pred[] constant(true)
}

ENTRY %main (a: f32[8,3], b: f32[3,5]) -> f32[8,5] {
  %a = f32[8,3]{1,0} parameter(0)
  %b = f32[3,5]{1,0} parameter(1)
  %k = s32[] constant(0)
  %t = (s32[], f32[8,3]{1,0}) tuple(%k, %a)
  %l = (s32[], f32[8,3]{1,0}) while(%t), condition=%cond, body=%body, \
backend_config={"known_trip_count":{"n":"3"}}
  %x = f32[8,3]{1,0} get-tuple-element(%l), index=1
  %o = f32[8,5]{1,0} fusion(%x, %b), kind=kOutput, calls=%fused_dot
  %c = f32[5,4]{1,0} constant({...})
  %g = (f32[8,4]{1,0}, s8[64]{0}) custom-call(f32[8,5]{1,0} %o, f32[5,4]{1,0} %c), \
custom_call_target="__cublas$gemm", backend_config={"gemm_backend_config":{"dot_dimension_numbers":\
{"lhs_contracting_dimensions":["1"],"rhs_contracting_dimensions":["0"],"lhs_batch_dimensions":[],\
"rhs_batch_dimensions":[]}}}, metadata={op_name="jit(f)/vmap(policy_grad)/dot_general"}
  ROOT %r = f32[8,4]{1,0} get-tuple-element(%g), index=0
}
"""


def test_step_cost_counts_dot_flops_in_fusions_and_loops():
    """By hand from `_DOT_HLO`: the fused dot (operand types written inline) is 8×5 outputs × 3 products ×
    2 = 240 flops, once; the loop body's dot (operands named, their shapes looked up) is 8×3 × 3 × 2 = 144
    flops, run 3 times (the loop's known trip count) = 432; the cuBLAS call (a GPU's library GEMM: its
    contracting dimension from its backend config, its result the tuple's first element) 8×4 × 5 × 2 = 320.
    Phases from the op_names (`vmap(policy_grad)` unwrapped)."""
    from bench import step_cost

    got = step_cost.dot_flops(_DOT_HLO, ("critic_grad", "policy_grad", "targets"))
    assert got == {"dots": 5.0, "flops": 992.0, "unparsed": 0.0,
                   "by_phase": {"critic_grad": 240.0, "targets": 432.0, "policy_grad": 320.0}}


def test_step_cost_counts_the_dots_of_a_compiled_jax_program():
    """A real compiled module: (8×3)·(3×5) under `critic_grad` = 2·8·5·3 = 240 flops; (8×5)·(5×4) under
    `policy_grad` = 2·8·4·5 = 320; a 4-trip `lax.scan` of (8×4)·(4×4) under `targets` = 4 · 2·8·4·4 = 1024."""
    jax = pytest.importorskip("jax")
    import jax.numpy as jnp

    from bench import step_cost

    def f(x, w1, w2, w3):
        with jax.named_scope("critic_grad"):
            h = jnp.tanh(x @ w1)
        with jax.named_scope("policy_grad"):
            y = jnp.tanh(h @ w2)
        with jax.named_scope("targets"):
            y, _ = jax.lax.scan(lambda c, _: (jnp.tanh(c @ w3), None), y, None, length=4)
        return y

    args = [jnp.ones(s, jnp.float32) for s in ((8, 3), (3, 5), (5, 4), (4, 4))]
    text = jax.jit(f).lower(*args).compile().as_text()
    got = step_cost.dot_flops(text, ("critic_grad", "policy_grad", "targets"))
    assert got["by_phase"] == {"critic_grad": 240.0, "policy_grad": 320.0, "targets": 1024.0}
    assert got["flops"] == 1584.0 and got["dots"] == 6.0


def test_step_cost_per_seed_arithmetic_does_not_change_with_the_seed_vmap():
    """The SGD step vmapped over 3 seeds does 3 times one seed's products: per seed, its dot flops equal
    the one-seed program's, phase by phase; and the SF² step's products are the vanilla step's plus its
    flow loss's (`aux_grad`, absent from the vanilla step)."""
    pytest.importorskip("jax")
    from sf2_common.agents.configs import make_config

    from bench import step_cost

    cost = {(rep, n): step_cost.step_cost(make_config("quick", "CartpoleBalance", "td3", rep), n)
            for rep in ("none", "sf2") for n in (1, 3)}
    for rep in ("none", "sf2"):
        one, three = cost[(rep, 1)], cost[(rep, 3)]
        assert three["dot_flops"] == pytest.approx(one["dot_flops"], rel=1e-12)
        assert three["dot_by_phase"] == pytest.approx(one["dot_by_phase"], rel=1e-12)
    assert "aux_grad" not in cost[("none", 1)]["dot_by_phase"]
    assert cost[("sf2", 1)]["dot_by_phase"]["aux_grad"] > 0


def test_hlo_phases_unwraps_transformations_around_the_scopes():
    """`jax.vmap` (the several-seed program) and autodiff wrap each scope traced under them in their
    name; the phase is still the last scope of the list the path names."""
    from bench import hlo_phases

    phases = ("critic_grad", "policy_adam")
    line = 'metadata={op_name="jit(epoch)/vmap(critic_grad)/%s/dot_general"}'
    assert hlo_phases.phase_of(line % "mlp", phases) == "critic_grad"
    assert hlo_phases.phase_of(line % "transpose(jvp(policy_adam))", phases) == "policy_adam"
    assert hlo_phases.phase_of('metadata={op_name="jit(epoch)/vmap(explore)/add"}', phases) == "(other)"


# ----------------------------------------------------------------------------- issue 12's targets
_THROUGHPUT_HEADER = ("framework,task,algo,rep,seeds,learner_precision,env_steps_per_epoch,"
                      "sgd_steps_per_epoch,timed_epochs,warmup_epochs,warmup_s,median_epoch_s,sps_per_seed,sps_total,epoch_s\n")


def _throughput_csv(folder, rows):
    folder.mkdir(parents=True)
    (folder / "throughput.csv").write_text(_THROUGHPUT_HEADER + "".join(
        f"{fw},{task},td3,{rep},{seeds},{prec},8064,504,3,2,20.0,0.5,{sps / seeds},{sps},0.5;0.5;0.5\n"
        for fw, task, rep, seeds, prec, sps in rows))


def _physics_csv(folder, rates):
    folder.mkdir(parents=True)
    (folder / "physics.csv").write_text(
        "task,num_envs,steps_per_call,compilations,type_changes,first_call_s,median_call_s,env_steps_per_s,"
        "call_s,state_checksum\n" + "".join(f"{task},{n},50,1,none,1.0,0.01,{sps},0.01,0x0\n"
                                             for task, n, sps in rates))


def test_targets_from_result_folders(tmp_path):
    """By hand: physics' lowest task at 1024 envs is HopperHop's 150,000 (its 128-env 9,000 is another
    row) → reached; the one-seed SF² row at TF32 16,000 → reached; the best several-seed row 48,000 → not
    reached; no CheetahRun row → not measured; two processes 47,000 + 46,000 = 93,000 against 48,000 on one
    GPU = 1.9375× → reached; SF²/TD3 in one folder 22,400 / 16,000 = 1.40× (TF32) and 17,000 / 10,000 =
    1.70× (fp32) → not reached, met at one seed TF32; torch 12,800 against JAX 16,000 in the same process
    = 0.80× → reached."""
    from sf2_common.agents.tasks import PAPER_TASKS

    from bench import targets

    acro, tf32, fp32 = "AcrobotSwingup", "tensorfloat32", "highest"
    _physics_csv(tmp_path / "physics", [(t, 1024, 150_000 if t == "HopperHop" else 10**6)
                                        for t in PAPER_TASKS] + [("HopperHop", 128, 9_000)])
    _throughput_csv(tmp_path / "jax-1", [
        ("jax", acro, "sf2", 1, tf32, 16_000), ("jax", acro, "none", 1, tf32, 22_400),
        ("jax", acro, "sf2", 1, fp32, 10_000), ("jax", acro, "none", 1, fp32, 17_000),
        ("torch", acro, "sf2", 1, tf32, 12_800)])
    _throughput_csv(tmp_path / "jax-16", [("jax", acro, "sf2", 16, tf32, 48_000)])
    _throughput_csv(tmp_path / "two-gpus-0", [("jax", acro, "sf2", 16, tf32, 47_000)])
    _throughput_csv(tmp_path / "two-gpus-1", [("jax", acro, "sf2", 16, tf32, 46_000)])
    rows, physics = targets.read([tmp_path])
    got = targets.evaluate(rows, physics, PAPER_TASKS, tf32)
    assert [t.reached for t in got] == [True, True, False, None, True, False, True]
    assert got[0].measured == "lowest HopperHop 150,000 (7 tasks)"
    assert got[2].measured.startswith("48,000 at 16 seed(s)")
    assert got[4].measured.startswith("1.94×: 93,000 on two / 48,000 on one")
    assert got[5].measured == "1.70× (x1 highest); 1.40× (x1 tensorfloat32); met at x1 tensorfloat32"
    assert got[6].measured == "0.80× (tensorfloat32, one process)"
    # a task without its 1024-env row: the physics target is not reached, and says which
    (tmp_path / "physics" / "physics.csv").unlink()
    _physics_csv(tmp_path / "physics2", [(t, 1024, 10**6) for t in PAPER_TASKS[1:]])
    rows, physics = targets.read([tmp_path])
    first = targets.evaluate(rows, physics, PAPER_TASKS, tf32)[0]
    assert first.reached is False and first.measured.endswith(f"missing {PAPER_TASKS[0]}")


def test_targets_cli_names_a_missing_folder(tmp_path, capsys):
    from bench import targets

    with pytest.raises(SystemExit) as exc:
        targets.main([str(tmp_path / "nowhere")])
    assert exc.value.code == 2 and f"no result folder {tmp_path / 'nowhere'}" in capsys.readouterr().err


def test_targets_names_the_file_and_line_of_a_corrupt_row(tmp_path, capsys):
    from bench import targets

    _throughput_csv(tmp_path / "jax-1", [("jax", "AcrobotSwingup", "sf2", 1, "tensorfloat32", 16_000)])
    f = tmp_path / "jax-1" / "throughput.csv"
    f.write_text(f.read_text().replace("16000", "fast"))
    with pytest.raises(SystemExit) as exc:
        targets.main([str(tmp_path)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"{f}, line 2: not a row of `python -m bench.agent_throughput`" in err
