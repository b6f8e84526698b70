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
    (["run", "--tasks", "cheetah,nope"], "--tasks: unknown task 'nope': valid are AcrobotSwingup"),
    (["run", "--steps", "1,x"], "--steps: '1,x' is not a comma list of denoising steps >= 1"),
    (["run", "--compiled-steps", "0"], "--compiled-steps: '0' is not a comma list"),
    (["run", "--algos", "ddpg"], "--algos: 'ddpg' unknown; valid: td3, sac"),
    (["run", "--integrators", "rk4"], "--integrators: 'rk4' unknown; valid: midpoint, euler"),
    (["flow-step", "--variants", "zz"], "--variants: 'zz' unknown; valid:"),
])
def test_bad_bench_input_exits_2_before_anything_runs(argv, message, tmp_path, capsys):
    """A name the bench does not know stops it naming the flag and the valid choices, with nothing
    written (not skipped silently, not a traceback after the machine description)."""
    pytest.importorskip("jax", reason="the bench's checks import the JAX core's steps: install it")
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
    ("agent_throughput", ["--reps", "none,sf2@nope=1"], "unknown config field 'nope'"),
    ("agent_throughput", ["--reps", "sf2@"], "'sf2@' is not REP or REP@FIELD=VALUE"),
    ("agent_throughput", ["--frameworks", "torch", "--set", "compile=fast"], "compile = 'fast' is invalid"),
    ("physics", ["--tasks", "CheetahRun,Nope"], "--tasks: unknown task 'Nope'"),
    ("physics", ["--envs", "128,0"], "each must be >= 1"),
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


@pytest.mark.parametrize("framework", ["jax", "torch"])
@pytest.mark.parametrize("argv,message", [
    (["--task", "Nope"], "unknown task 'Nope'"),
    (["--reps", "bogus"], "representation = 'bogus' is invalid"),
    (["--seeds", "two"], "invalid literal for int()"),
    (["--reps", "sf2@contract_zeta=maybe"], "contract_zeta"),
])
def test_bad_agent_profile_input_exits_2_before_writing(framework, argv, message, capsys, tmp_path):
    pytest.importorskip("mujoco_playground", reason="the profile validates against the Playground task list: "
                        "install a core's [train] extra")
    from bench import agent_profile

    with pytest.raises(SystemExit) as exit_:
        agent_profile.main([*argv, "--framework", framework, "--out", str(tmp_path / "out")])
    assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_agent_profile_epochs_are_whole_actor_steps_of_either_trainer():
    """`agent_profile._config` cuts the `paper` preset to epochs of `--actor-steps` actor steps: on MinAtar's
    on-policy trainer an actor step is one update (num_envs × rollout_length env steps), with no prefill;
    off-policy the random prefill (min_replay_size / num_envs, rounded up) is cut to at most one epoch: CRL's
    paper prefill, 1000 actor steps, to `--actor-steps`, TD3's, shorter than the epoch, kept."""
    pytest.importorskip("pgx", reason="the MinAtar case needs pgx: pip install "
                        "\"packages/sf2-core-jax[minatar]\"")
    pytest.importorskip("mujoco_playground", reason="the off-policy case's Playground task: install a core's "
                        "[train] extra")
    from sf2_common.agents.configs import make_config, schedule

    from bench import agent_profile

    ppo = make_config("paper", "minatar-breakout", "ppo", "sf2")
    td3 = make_config("paper", "AcrobotSwingup", "td3", "sf2")
    crl = make_config("paper", "ant-goal", "crl", "sf2")
    td3_prefill, crl_prefill = (-(-c.min_replay_size // c.num_envs) for c in (td3, crl))
    assert td3_prefill <= 64 < crl_prefill, (td3_prefill, crl_prefill)   # the cases below: one kept, one cut
    for base, steps, per_actor, pre in ((ppo, 2, ppo.num_envs * ppo.rollout_length, 0),
                                        (td3, 64, td3.num_envs * td3.action_repeat, td3_prefill),
                                        (crl, 64, crl.num_envs * crl.action_repeat, 64)):
        cfg = agent_profile._config(base.task, base.algo, "sf2", 2, steps, 3, {})
        sched = schedule(cfg)
        assert (sched.actor_steps_per_epoch, sched.env_steps_per_actor_step, sched.prefill_actor_steps,
                sched.num_epochs) == (steps, per_actor, pre, 2 * 3 + 4), base.task


def test_agent_profile_hlo_is_the_jax_trainers(capsys, tmp_path):
    """`--hlo` counts XLA's compiled kernels: with the torch trainer it exits 2 before writing anything."""
    pytest.importorskip("mujoco_playground", reason="the profile validates against the Playground task list: "
                        "install a core's [train] extra")
    from bench import agent_profile

    with pytest.raises(SystemExit) as exit_:
        agent_profile.main(["--framework", "torch", "--hlo", "--out", str(tmp_path / "out")])
    assert exit_.value.code == 2 and "--hlo counts the JAX trainer's" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_agent_profile_times_the_torch_evaluation_per_env_step(monkeypatch):
    """`agent_profile.time_evaluation` splits `Program.evaluate`'s wall time per env step into the seeds'
    policies (`act`, the function `Program.eval_policy` returns) and the env step, as trained and synced,
    leaves the program's own `eval_policy` in place after, and `profile.markdown` shows both ways. A fake
    program whose policies and env sleep known times."""
    trainer = pytest.importorskip("sf2_torch.agents.trainer", reason="the torch trainer: install "
                                  "\"packages/sf2-core-torch[train]\"")
    from types import SimpleNamespace

    from bench import agent_profile, profile

    act_s, env_s, steps, seeds = 0.002, 0.001, 5, (0, 1)

    class Env:
        def step_actions(self, action):
            time.sleep(env_s)

    class Program:
        sched = SimpleNamespace(eval_actor_steps=steps)

        def eval_policy(self, agents, generators):
            return lambda obs: time.sleep(len(agents) * act_s)

        def evaluate(self, agents, start_keys, seeds_, epoch, env):
            policy = self.eval_policy(agents, None)
            for _ in range(steps):
                policy(None)
                env.step_actions(None)

    monkeypatch.setattr(trainer, "_eval_env", lambda program, seeds_: Env())
    state = SimpleNamespace(seeds=seeds, eval_keys=None, agents=[object() for _ in seeds])
    program = Program()
    drained = []
    out = agent_profile.time_evaluation(program, state, 3, lambda: drained.append(1))
    assert set(out) == {"as trained", "synced"} and drained
    for h in out.values():
        assert set(h["phases_ms"]) == {"act", "env_step"}
        assert h["phases_ms"]["act"] >= len(seeds) * act_s * 1e3 and h["phases_ms"]["env_step"] >= env_s * 1e3
        assert h["wall_ms"] >= sum(h["phases_ms"].values()) and h["rest_ms"] >= 0
    assert "eval_policy" not in vars(program)
    md = profile.markdown([{"label": "fake", "wall_ms_per_update": 1.0, "evaluation": out, "devices": []}])
    assert "evaluation as trained: wall" in md and "evaluation synced: wall" in md and "ms per env step" in md


@pytest.mark.parametrize("env_steps,epochs,prefill,expected", [
    (16_000, 3, 8_192, (5_334, 2)),   # 8,192 // 5,334 = 1 whole prefill epoch, the next holds SGD step 1
    (32_000, 2, 8_192, (16_000, 1)),  # the prefill ends inside epoch 1
    (10_000, 2, 5_000, (5_000, 2)),   # epoch 1 is all prefill; SGD starts at env step 5,001, in epoch 2
    (10_000, 2, 0, (5_000, 1)),       # no prefill: epoch 1 still holds the compilation and SGD step 1
])
def test_throughput_warm_up_holds_the_first_sgd_step(env_steps, epochs, prefill, expected):
    """The timed epochs of `bench.agent_throughput` start after the epoch of the first SGD step (where the
    torch trainer compiles its update), so no compilation falls inside a timed epoch when the prefill
    outlasts the first epoch."""
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
def test_hlo_counts_kernels_per_phase_weighted_by_trip_counts(branches):
    """By hand from `_HLO`: the while body runs 4 times (its known trip count) and launches 4 fusions, one
    cuBLAS call and one copy (the fusions' own computation is no launch of its own; get-tuple-element,
    tuple, constant and parameter launch nothing). Of the two Triton fusions (`kind=kCustom`) the
    block-level reduction `f3` is a fusion and the nested GEMM `f4` a GEMM. The loop condition's compare is
    one launch, counted once (the condition is not weighted by the trip count), and each conditional
    branch's fusion once. A fusion's phase is the last phase its op_name names (`f2`: policy_adam, though
    critic_grad comes first); the compare and branch_b's fusion name none: (other). All: 4 × 6 + 1 + 1 + 1
    = 27 launches, 13.5 per SGD step for 2 SGD steps."""
    from bench import hlo

    phases = ("explore", "critic_grad", "critic_adam", "policy_adam", "targets")
    # the two spellings of a conditional's branches (an index conditional's; the GPU's for a predicate)
    got = hlo.count(_HLO.replace("branch_computations={%branch_a, %branch_b}", branches), phases)
    assert got["by_phase"] == {"critic_grad": {"fusion": 8}, "policy_adam": {"fusion": 4},
                               "critic_adam": {"gemm": 8}, "targets": {"copy": 4},
                               "explore": {"fusion": 1}, "(other)": {"fusion": 1, "other": 1}}
    assert got["conditional_branches"] == 2 and got["unknown_trip_count_loops"] == 0
    table = hlo.markdown(got, phases, sgd_steps=2)
    assert "| critic_grad | 4.0 | 0.0 | 4.0 |" in table and "| **all** | **13.5** |" in table


def test_hlo_finds_the_newest_epoch_module_of_a_dump(tmp_path):
    """In a dump folder: the most recently written `*epoch_one*after_optimizations.txt` (whatever its
    module number), never XLA's buffer-assignment report beside it."""
    import os

    from bench import hlo

    old, new = tmp_path / "module_9999.jit__epoch_one.after_optimizations.txt", \
        tmp_path / "module_10000.jit__epoch_one.after_optimizations.txt"
    report = tmp_path / "module_10000.jit__epoch_one.after_optimizations-buffer-assignment.txt"
    for i, f in enumerate((old, new, report)):
        f.write_text(_HLO)
        os.utime(f, ns=(10**18 + i, 10**18 + i))
    assert hlo.find_module(tmp_path) == new
    os.utime(old, ns=(2 * 10**18, 2 * 10**18))
    assert hlo.find_module(tmp_path) == old


def test_hlo_refuses_what_is_not_a_dump(tmp_path, capsys):
    from bench import hlo

    with pytest.raises(SystemExit) as err:
        hlo.main([str(tmp_path)])
    assert err.value.code == 2 and "after_optimizations.txt" in capsys.readouterr().err
    (tmp_path / "x.txt").write_text("not hlo")
    with pytest.raises(SystemExit):
        hlo.main([str(tmp_path / "x.txt")])
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


def test_an_arm_of_reps_carries_its_own_fields_and_its_ratio_to_the_plain_arm():
    """`--reps none,sf2,sf2@contract_zeta=false` is three arms: the third SF² with the oracle ζ (its own
    fields typed like `--set`, applied after it), reported under its label and as a time per env step
    against the plain `sf2` arm of the same run. A size list's commas inside brackets do not split arms."""
    pytest.importorskip("mujoco_playground", reason="the paper preset's config needs the Playground "
                        "task list: install a core's [train] extra")
    from sf2_common.errors import ConfigError

    from bench.agent_throughput import config_for, markdown, parse_reps

    arms = parse_reps("none,sf2,sf2@contract_zeta=false@batch_size=64", ["jax"])
    assert arms == [("none", "none", {}), ("sf2", "sf2", {}), ("sf2@contract_zeta=false@batch_size=64", "sf2",
                                                                {"contract_zeta": False, "batch_size": 64})]
    cfg, _ = config_for("AcrobotSwingup", "td3", "sf2", 1, 1000, 1, {"batch_size": 32, **arms[2][2]})
    assert cfg.contract_zeta is False and cfg.batch_size == 64
    sized = parse_reps("none,sf2@zeta_hidden_sizes=(128,128)@batch_size=64,sf2@zeta_hidden_sizes=[64]",
                       ["jax"])
    assert sized == [("none", "none", {}),
                     ("sf2@zeta_hidden_sizes=(128,128)@batch_size=64", "sf2",
                      {"zeta_hidden_sizes": (128, 128), "batch_size": 64}),
                     ("sf2@zeta_hidden_sizes=[64]", "sf2", {"zeta_hidden_sizes": (64,)})]
    with pytest.raises(ConfigError, match="unknown config field 'nope'"):
        parse_reps("sf2@nope=1", ["jax"])
    with pytest.raises(ValueError, match="not REP or REP@FIELD=VALUE"):
        parse_reps("sf2@@batch_size=64", ["jax"])
    row = dict(framework="jax", task="T", algo="td3", learner_precision="highest", seeds=1,
               env_steps_per_epoch=1000, sgd_steps_per_epoch=10, warmup_s=1.0, warmup_epochs=1,
               median_epoch_s=1.0)
    rows = [{**row, "rep": rep, "sps_per_seed": sps, "sps_total": sps}
            for rep, sps in (("none", 1000.0), ("sf2", 400.0), ("sf2@contract_zeta=false", 500.0))]
    text = markdown(rows, {"command": "c"})
    assert "| sf2@contract_zeta=false |" in text
    assert "td3+sf2@contract_zeta=false / td3 (highest, 1 seed): time per env step 2.00×" in text
    assert "td3+sf2@contract_zeta=false / td3+sf2 (highest, 1 seed): time per env step 0.80×" in text
    assert "Paper (§4.4" in text and "JaxGCRL" not in text   # each family's published reference only
    crl_text = markdown([{**r, "algo": "crl"} for r in rows], {"command": "c"})
    assert "JaxGCRL's README" in crl_text and "Paper (§4.4" not in crl_text
    from bench.agent_profile import _file_part

    assert _file_part(arms[2][0]) == "sf2+contract_zeta-false+batch_size-64"   # the profile's file names
    assert _file_part(sized[1][0]) == "sf2+zeta_hidden_sizes-128x128+batch_size-64"


def test_the_report_names_the_presets_learner_precision_where_a_row_times_another():
    """`--precisions` defaults to `highest` whatever the preset trains at: `preset_precisions` reads each
    case's `paper` config (a `--set learner_precision` counts as the runs'), and throughput.md names it for
    a row timed at another precision, and says nothing where every row times the preset's."""
    pytest.importorskip("mujoco_playground", reason="the paper preset's config needs the Playground "
                        "task list: install a core's [train] extra")
    from sf2_common.agents.configs import PRESETS

    from bench.agent_throughput import markdown, parse_reps, preset_precisions

    arms = parse_reps("sf2", ["jax"])
    paper = PRESETS["paper"]["learner_precision"]
    assert preset_precisions(["CheetahRun"], ["td3"], arms, ["jax"], {}) == {"jax CheetahRun td3+sf2": paper}
    assert preset_precisions(["CheetahRun"], ["td3"], arms, ["jax"], {"learner_precision": "bfloat16"}) == {
        "jax CheetahRun td3+sf2": "bfloat16"}
    row = dict(framework="jax", task="CheetahRun", algo="td3", rep="sf2", seeds=1, env_steps_per_epoch=1000,
               sgd_steps_per_epoch=10, warmup_s=1.0, warmup_epochs=1, median_epoch_s=1.0, sps_per_seed=1000.0,
               sps_total=1000.0)
    info = {"command": "c", "preset_learner_precision": {"jax CheetahRun td3+sf2": paper}}
    other = "highest" if paper != "highest" else "tensorfloat32"
    text = markdown([{**row, "learner_precision": other}], info)
    assert f"the `paper` preset trains jax CheetahRun td3+sf2: {paper}; rows at another precision" in text
    assert "not the preset's learner precision" not in markdown([{**row, "learner_precision": paper}], info)
    assert "not the preset's learner precision" not in markdown([{**row, "learner_precision": other}],
                                                                 {"command": "c"})


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


# TD3+SF²'s critic reads ψ(s, a), TD3's (s, a); CRL's encoders and actor are the same with and without SF²
@pytest.mark.parametrize("task,algo,same_heads",
                         [("CartpoleBalance", "td3", False), ("ant-goal", "crl", True)])
def test_step_cost_per_seed_arithmetic_does_not_change_with_the_seed_vmap(task, algo, same_heads):
    """The SGD step vmapped over 3 seeds does 3 times one seed's products: per seed, its dot flops equal
    the one-seed program's, phase by phase; and the SF² step's products are the vanilla step's plus its
    flow loss's (`aux_grad`, absent from the vanilla step); where the heads are the same networks (CRL,
    whose trainer scopes its parts with the same names) the critic's and actor's phases match."""
    pytest.importorskip("jax")
    from sf2_common.agents.configs import make_config

    from bench import step_cost

    cost = {(rep, n): step_cost.step_cost(make_config("quick", task, algo, rep), n)
            for rep in ("none", "sf2") for n in (1, 3)}
    for rep in ("none", "sf2"):
        one, three = cost[(rep, 1)], cost[(rep, 3)]
        assert three["dot_flops"] == pytest.approx(one["dot_flops"], rel=1e-12)
        assert three["dot_by_phase"] == pytest.approx(one["dot_by_phase"], rel=1e-12)
    none, sf2 = cost[("none", 1)]["dot_by_phase"], cost[("sf2", 1)]["dot_by_phase"]
    assert "aux_grad" not in none
    assert sf2["aux_grad"] > 0
    for phase in ("critic_grad", "policy_grad"):
        assert none[phase] > 0 and sf2[phase] > 0
        assert (sf2[phase] == pytest.approx(none[phase], rel=1e-12)) == same_heads


def test_update_cost_composes_the_on_policy_update_of_its_parts():
    """An on-policy update is `rollout_length` rollout steps and update_epochs × (num_envs ·
    rollout_length / minibatch_size) SGD steps, each the critic's, the flow loss's and the actor's Adam
    steps and the targets' EMA: the parts compiled alone add up to the whole SGD step's arithmetic (the
    same operations, one program), and the update is the parts times their counts. Each part's kernels
    carry its trainer scopes (what `bench.hlo` and `bench.agent_profile --hlo` sort by): the rollout step's
    actor phases, each loss's `*_grad` and `*_adam`, every SGD phase in the whole step."""
    pytest.importorskip("pgx", reason="MinAtar needs pgx: install sf2-core-jax[minatar]")
    from sf2_common.agents.configs import make_config
    from sf2_jax.agents.algorithms import PHASES

    from bench import step_cost

    cfg = make_config("quick", "minatar-breakout", "ppo", "sf2")
    got = step_cost.update_cost(cfg, 1)
    sgd_steps = cfg.update_epochs * cfg.num_envs * cfg.rollout_length // cfg.minibatch_size
    parts = got["parts"]
    assert list(parts) == ["rollout step", "critic", "flow_loss", "actor", "targets"]
    assert [r["per_update"] for r in parts.values()] == [cfg.rollout_length] + [sgd_steps] * 4
    sgd = sum(r["flops"] for name, r in parts.items() if name != "rollout step")
    assert sgd == pytest.approx(got["sgd_step"]["flops"], rel=0.01)
    assert parts["flow_loss"]["flops"] > parts["critic"]["flops"] > 0
    assert got["update_flops"] == pytest.approx(cfg.rollout_length * parts["rollout step"]["flops"]
                                                + sgd_steps * sgd, rel=1e-12)
    scopes = {part: set(r["kernels_by_phase"]) - {"(other)"} for part, r in parts.items()}
    assert scopes["rollout step"] == {"explore", "env_step", "observe"}
    assert (scopes["critic"], scopes["flow_loss"], scopes["actor"], scopes["targets"]) == (
        {"critic_grad", "critic_adam"}, {"aux_grad", "aux_adam"}, {"policy_grad", "policy_adam"}, {"targets"})
    assert set(got["sgd_step"]["kernels_by_phase"]) - {"(other)"} == set(PHASES)


_KERNEL_HLO = """HloModule m

%fused (p: f32[4]) -> f32[4] {
  %p = f32[4]{0} parameter(0)
  ROOT %m.1 = f32[4]{0} multiply(%p, %p), metadata={op_name="jit(e)/vmap(critic_grad)/mul"}
}

ENTRY %main (a: f32[4]) -> f32[4] {
  %a = f32[4]{0} parameter(0)
  %loop_multiply_fusion.11 = f32[4]{0} fusion(%a), kind=kLoop, calls=%fused, \
metadata={op_name="jit(e)/vmap(critic_grad)/mul"}
  %custom-call.3 = f32[4]{0} custom-call(%loop_multiply_fusion.11), custom_call_target="__cublas$gemm", \
metadata={op_name="jit(e)/aux_grad/dot"}
  ROOT %copy.2 = f32[4]{0} copy(%custom-call.3)
}
"""


def test_profile_sums_kernel_time_per_phase_by_the_compiled_instructions():
    """By hand, two updates traced: the GPU kernel `loop_multiply_fusion_11` is the instruction
    `loop_multiply_fusion.11` (critic_grad); a cuBLAS kernel names its instruction `custom-call.3`
    (aux_grad) in `hlo_op`, but inside a command buffer only the buffer (unmatched); the CPU's `copy.2`
    has no scope ((other)); the parameter launches nothing and is not a kernel. Per update: one kernel
    each, of 3, 5, 4 and 1 µs."""
    from bench import hlo, profile

    phases = ("critic_grad", "aux_grad")
    kernel_phase = hlo.kernel_phases(_KERNEL_HLO, phases)
    assert kernel_phase == {"m_1": "critic_grad", "loop_multiply_fusion_11": "critic_grad",
                            "custom_call_3": "aux_grad", "copy_2": "(other)"}
    ks = [e for t in (0, 100) for e in (
        {"name": "loop_multiply_fusion_11", "ts": t, "dur": 3},
        {"name": "sm90_xmma_gemm_f32f32", "ts": t + 10, "dur": 5, "args": {"hlo_op": "custom-call.3"}},
        {"name": "sm90_xmma_gemm_f32f32", "ts": t + 20, "dur": 4, "args": {"hlo_op": "command_buffer_6"}},
        {"name": "copy.2", "ts": t + 30, "dur": 1})]
    got = profile.phase_times(ks, 2, kernel_phase)
    assert got == {"critic_grad": {"count": 1.0, "ms": 0.003}, "aux_grad": {"count": 1.0, "ms": 0.005},
                   "(unmatched)": {"count": 1.0, "ms": 0.004}, "(other)": {"count": 1.0, "ms": 0.001}}
    summary = profile.summarize_kernels(ks, 2, "gpu", kernel_phase)
    assert summary["by_phase"] == got
    assert [(k["name"], k["phase"]) for k in summary["kernels"]] == [
        ("sm90_xmma_gemm_f32f32 [custom-call.3]", "aux_grad"), ("sm90_xmma_gemm_f32f32 [command_buffer_6]",
                                                                 "(unmatched)"),
        ("loop_multiply_fusion_11", "critic_grad"), ("copy.2", "(other)")]
    assert sum(k["ms"] for k in summary["kernels"]) == pytest.approx(summary["kernel_ms_per_update"])
    assert "by_phase" not in profile.summarize_kernels(ks, 2, "gpu")
    text = profile.markdown([{"label": "case", "wall_ms_per_update": 1.0, "devices": [summary]}])
    assert "| aux_grad | 1.0 | 0.0050 | 38.5% |" in text   # 5 of 13 µs
    assert "The costliest kernels of aux_grad:" in text
    assert "| `sm90_xmma_gemm_f32f32 [custom-call.3]` | 1 | 0.0050 |" in text


def test_hlo_unwraps_transformations_around_the_scopes():
    """`jax.vmap` (the several-seed program) and autodiff wrap each scope traced under them in their
    name; the phase is still the last scope of the list the path names."""
    from bench import hlo

    phases = ("critic_grad", "policy_adam")
    line = 'metadata={op_name="jit(epoch)/vmap(critic_grad)/%s/dot_general"}'
    assert hlo.phase_of(line % "mlp", phases) == "critic_grad"
    assert hlo.phase_of(line % "transpose(jvp(policy_adam))", phases) == "policy_adam"
    assert hlo.phase_of('metadata={op_name="jit(epoch)/vmap(explore)/add"}', phases) == "(other)"


@pytest.mark.parametrize("task,algo,rep,module", [
    ("minatar-breakout", "ppo", "sf2", "onpolicy"),
    ("CartpoleBalance", "fpo", "sf2", "onpolicy"),
    ("ant-goal", "crl", "sf2", "crl"),
    ("CartpoleBalance", "td3", "sf2", "trainer"),
])
def test_throughput_times_every_jax_trainer_in_whole_actor_steps(task, algo, rep, module):
    """`bench.agent_throughput` builds the on-policy and goal-conditioned cases with their own trainer, and
    rounds `--env-steps` up so that each timed epoch is whole updates (FPO's `paper` update is 983,040 env
    steps per seed; fewer would leave an epoch empty)."""
    pytest.importorskip("mujoco_playground", reason="the paper preset's config needs the Playground "
                        "task list: install a core's [train] extra")
    from sf2_common.agents.configs import schedule
    from sf2_jax.agents.trainers import trainer_module

    from bench.agent_throughput import config_for

    cfg, warm = config_for(task, algo, rep, 2, 1_000_000, 3, {})
    sched = schedule(cfg)
    assert sched.num_epochs == warm + 3
    assert sched.env_steps_per_epoch % sched.env_steps_per_actor_step == 0
    assert 3 * sched.env_steps_per_epoch >= 1_000_000
    assert trainer_module(task, algo).__name__ == f"sf2_jax.agents.{module}"


def test_throughput_measures_the_onpolicy_trainer(tmp_path):
    """A tiny PPO-Q case on MinAtar end to end: its row counts the update's SGD steps in every timed epoch
    (3 passes × 2 minibatches × 2 updates) and its rate is the epoch's env steps over its time."""
    pytest.importorskip("pgx", reason="MinAtar needs pgx: install sf2-core-jax[minatar]")
    from bench.agent_throughput import measure

    row = measure("minatar-breakout", "ppo", "none", 1, 256, 2, {
        "num_envs": 8, "rollout_length": 8, "minibatch_size": 32, "update_epochs": 3,
        "learner_precision": "highest"}, log=lambda line: None)
    assert row["env_steps_per_epoch"] == 128 and row["sgd_steps_per_epoch"] == 3 * 2 * 2
    assert row["warmup_epochs"] == 1 and row["timed_epochs"] == 2
    # median_epoch_s is rounded to 1e-4 s, sps_per_seed to 0.1: the rate off by at most 128/m² · 0.5e-4 + 0.05
    m = row["median_epoch_s"]
    assert row["sps_per_seed"] == pytest.approx(128 / m, abs=128 / m**2 * 0.5e-4 + 0.05)
