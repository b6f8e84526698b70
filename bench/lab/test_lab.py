"""Tests of the lab's modules (bench/lab): what they compute, on hand-made inputs."""

from __future__ import annotations

import json

import numpy as np
import pytest


def test_variants_are_the_cores_flow_loss_under_another_dot_precision():
    """A precision variant is `sf2_jax.losses.flow_loss` itself with one networks function traced under a
    dot algorithm: with "highest" it equals flow_loss (float64, loss and (ψ, ζ) gradient), the patch is
    undone after each call, the GPU-only algorithms reach XLA (refused on a CPU); importing the module
    registers its variants with the product (`python -m bench` times them)."""
    jax = pytest.importorskip("jax")
    import jax.numpy as jnp
    from sf2_common.config import SF2Config
    from sf2_jax import losses, networks
    from sf2_jax.losses import Batch

    from bench import data, jax_steps, sizes
    from bench.lab import variants

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
            loss, grad = run(variants.with_precision(function, target_only, "highest"))
            assert networks.contract is contract
            np.testing.assert_array_equal(loss, ref)
            for a, b in zip(jax.tree_util.tree_leaves(grad), jax.tree_util.tree_leaves(ref_grad)):
                np.testing.assert_array_equal(a, b)
        if jax.default_backend() == "cpu":
            with pytest.raises(ValueError, match="TF32_TF32_F32_X3.*not supported by dot_general on CPU"):
                run(variants.VARIANTS["x3tf32"])
    assert networks.contract is contract
    assert set(variants.VARIANTS) <= set(jax_steps.FLOW_VARIANTS)
    assert {"psi-only", "sf2-x3tf32"} <= sizes.VARIANT_REPS


@pytest.mark.parametrize("argv,message", [
    (["--programs", "init,foo"], "--programs: 'foo'; valid: init, epoch, evaluate"),
    (["--seeds", "1"], "--seeds 1: needs at least 2 to spread over devices"),
    (["--task", "Nope"], "unknown task 'Nope'"),
    (["--rep", "bogus"], "representation = 'bogus' is invalid"),
])
def test_bad_shard_probe_input_exits_2(argv, message, capsys):
    pytest.importorskip("mujoco_playground", reason="the probe validates against the Playground task list "
                        "and the agents' registry: install a core's [train] extra")
    from bench.lab import shard_probe

    with pytest.raises(SystemExit) as exit_:
        shard_probe.main(argv)
    assert exit_.value.code == 2 and message in capsys.readouterr().err


def test_shard_probe_without_a_mesh_says_what_it_needs(monkeypatch):
    """One device, or SF2_SHARD_SEEDS unset: the probe names what is missing instead of probing nothing.
    (On two host CPU devices it runs every program: packages/sf2-core-jax/tests/agents/test_devices.py
    checks the sharded programs themselves.)"""
    pytest.importorskip("mujoco_playground", reason="the probe builds the trainer: install the JAX core's "
                        "[train] extra")
    from bench.lab import shard_probe

    monkeypatch.delenv("SF2_SHARD_SEEDS", raising=False)
    with pytest.raises(SystemExit, match="no seed mesh: needs SF2_SHARD_SEEDS=1 and several local devices"):
        shard_probe.main(["--config", "quick", "--task", "PendulumSwingup", "--seeds", "2"])


def test_eval_share_of_a_run_folder(tmp_path):
    """Two seeds, epochs 0-2: seed 0's rows give the run's numbers (by hand: evaluations after epoch 0
    1.5 + 1.5 = 3 s of a 10 s run; epochs 2 + 2 = 4 s; 2 seeds x 200 env steps / 10 s = 40 steps/s)."""
    from bench.lab import eval_share

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


def test_forecast_check_against_hand_derived_forecasts(tmp_path):
    """Finished runs of 1,000 env steps, 5 seeds each: A/m 100 s (0.1 s per env step), A/q 200 s, B/m 50 s.
    Checking A/q and B/m leaves A/m alone to forecast from (runner.Forecast's preferences 5 and 4: the
    slowest run of the task; on a task without one the slowest pair scaled to the method): A/q 0.1 x 1000
    = 100 s (took 200: ratio 2.0), B/m (no other run of B) A/m's 100 s (took 50: 0.5). Sums 200 s
    forecast against 250 s taken (1.25x); median of the ratios 1.25."""
    from types import SimpleNamespace

    pytest.importorskip("sf2_studies", reason="the forecasts are the study runner's: install sf2-studies")
    from sf2_studies import runner
    from sf2_studies.spec import StudyError

    from bench.lab import forecast_check

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
    # leave one out: A/m from A/q and B/m (preference 5, the slowest run of A: A/q, 0.2 s per env step) 200 s,
    # A/q from A/m and B/m 100 s as above, B/m from A/m and A/q (no run of B, preference 4: A/m's 0.1, and
    # A/q's 0.2 x m / q on A, 0.5) 100 s; without preference 4 the slowest of all, A/q, 200 s
    rows = forecast_check.check(history, history, each=True)
    assert [(r["run"], r["forecast_s"], r["ratio"]) for r in rows] == [
        ("A/m", 200.0, 0.5), ("A/q", 100.0, 2.0), ("B/m", 100.0, 0.5)]
    assert forecast_check.summary(rows) == (
        "3 run(s): forecast 6.7 min in all, took 5.8 min (0.88x); actual / forecast per run: min 0.50, "
        "median 0.50, max 2.00; 1 took longer than forecast")
    rows = forecast_check.check(history, history, each=True, forecast_cls=forecast_check.SeedCount)
    assert [(r["run"], r["forecast_s"]) for r in rows] == [("A/m", 200.0), ("A/q", 100.0), ("B/m", 200.0)]
    # a folder that is not a study folder is named, exit status 2, no traceback
    assert forecast_check.main([str(tmp_path / "nope"), "--runs", str(tmp_path / "A" / "m")]) == 2


def test_forecast_check_by_task_and_the_new_task_rules(tmp_path):
    """1,000 env steps per seed. A/m: 5 seeds 100 s (0.02 s per env step), 10 seeds 140 s (0.014); B/m: 10
    seeds 100 s (0.01); B/q: 5 seeds 200 s (0.04). C (5 seeds 60 s, 10 seeds 90 s) forecast from A and B
    alone (`--by-task`; no run of C). The runner's rule (method-scaled) takes the slowest pair of the job's
    seed count scaled to its method: at 5 seeds A/m's 0.02 (B/q's 0.04 is not related to m: no task ran
    both at 5 seeds), 100 s; at 10 A/m's 0.014 (B/m 0.01), 140 s. The one it replaced (seed-count) takes the
    slowest run of the job's seed count whatever its method, 0.04 x 5,000 = 200 s at 5 seeds, 0.014 x
    10,000 = 140 s at 10 (shorter than at 5); the one kept out (any-seed-count) scales every run to the
    job's seed count (A/m's 5 -> 10 ratio 0.7, 10 -> 5 1/0.7) and takes the largest, 200 s at 5 seeds
    (0.04) and 0.04 x 0.7 x 10,000 = 280 s at 10."""
    from types import SimpleNamespace

    pytest.importorskip("sf2_studies", reason="the forecasts are the study runner's: install sf2-studies")
    from sf2_studies import runner

    from bench.lab import forecast_check

    def job(task, name, seeds, wall):
        path = tmp_path / task / name / f"seeds-{seeds}"
        path.mkdir(parents=True)
        (path / "metrics.jsonl").write_text(json.dumps({"epoch": 1, "seed": 0, "env_steps": 1000,
                                                        "walltime": wall}) + "\n")
        run = SimpleNamespace(task=task, folder=name, rel=f"{name}/seeds-{seeds}", seeds=tuple(range(seeds)))
        return runner.Job(run, path, [], 1000 * seeds, 1000 * seeds)

    history = [job("A", "m", 5, 100.0), job("A", "m", 10, 140.0), job("B", "m", 10, 100.0),
               job("B", "q", 5, 200.0), job("C", "m", 5, 60.0), job("C", "m", 10, 90.0)]
    expected = {"method-scaled": [100.0, 140.0], "seed-count": [200.0, 140.0],
                "any-seed-count": [200.0, 280.0]}
    for rule, seconds in expected.items():
        rows = forecast_check.check_by_task(history, history[4:], forecast_check.RULES[rule])
        assert [(r["run"], r["forecast_s"]) for r in rows] == [
            ("C/m/seeds-5", seconds[0]), ("C/m/seeds-10", seconds[1])], rule
    # every task in turn: A/m at 5 seeds from B and C; the runner's rule, m's slowest 5-seed run (C/m: 60 s
    # for 5,000 env steps; B/q's is not related to m), 60 s
    rows = forecast_check.check_by_task(history, history)
    assert [r["run"] for r in rows] == [j.name for j in history] and rows[0]["forecast_s"] == 60.0


def test_checkpoint_cost_timings_are_medians_after_the_warm_up(monkeypatch):
    """`checkpoint_cost._timings` on a fake clock: an awaited save takes 10 s, a background save returns
    after 1 s and its `finish` takes 5 s, a restore 3 s, except in the warm-up (epochs 0 and 1), where each
    takes 100 s more. Two timed repeats: every median is the steady value, the warm-up left out; the
    background save's epoch is the one restored (2i + 1)."""
    from bench.lab import checkpoint_cost

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


def test_shardy_repro_cases_compute_what_they_say():
    """bench.lab.shardy_repro's cases on this host's devices give the sums of what they compute, derived here
    with NumPy from the same inputs: the Cholesky factors (under Shardy, GSPMD and without shard_map), M·M,
    and 2M beside an empty array plus one (whose sum is 0)."""
    import jax

    from bench.lab import shardy_repro

    m = np.asarray(shardy_repro.matrices(len(jax.local_devices()), 4, 2), dtype=np.float64)
    for case in ("cholesky-shard-map", "cholesky-shard-map-gspmd", "cholesky-jit"):
        assert shardy_repro.run(case, envs=4) == pytest.approx(np.linalg.cholesky(m).sum(), rel=1e-5)
    assert shardy_repro.run("matmul-shard-map", envs=4) == pytest.approx((m @ m).sum(), rel=1e-5)
    assert shardy_repro.run("zero-size-shard-map", envs=4) == pytest.approx(2 * m.sum(), rel=1e-5)
    with pytest.raises(SystemExit, match="unknown case 'nope'"):
        shardy_repro.run("nope")



@pytest.mark.parametrize("argv,message", [
    (["--task", "Nope"], "unknown task 'Nope'"),
    (["--seeds", "3-1"], "seeds '3-1' are invalid"),
    (["--set", "num_eval_envs=0"], "num_eval_envs = 0 is invalid"),
])
def test_bad_eval_sensitivity_input_exits_2_before_anything_runs(argv, message, tmp_path, capsys):
    pytest.importorskip("mujoco_playground", reason="it validates against the Playground task list and the "
                        "agents' registry: install a core's [train] extra")
    from bench.lab import eval_sensitivity

    out = tmp_path / "never"
    with pytest.raises(SystemExit) as exit_:
        eval_sensitivity.main([*argv, "--out", str(out)])
    assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert not out.exists()


def test_minatar_gate_has_a_row_per_method_and_marks_unfinished_runs(tmp_path, capsys):
    """Every method with rows under a game gets a row, `METHODS` first in their order; a run short of its
    last epoch is marked; a game without runs is left out. By hand: the example's two seeds end at 2 and 6
    (range [2, 6]); ppo-pgx's at 4 and 5 after the paper preset's 39 epochs (mean 4.5: within); ppo-v-shared's
    at 7 and 9 after epoch 2 (mean 8: above, unfinished)."""
    import gzip

    from sf2_common.agents import configs

    from bench.lab import minatar_gate

    cfg = configs.make_config("paper", "minatar-breakout", "ppo", "none").to_dict()
    for method, epochs, last in (("ppo-v-shared", 2, (7.0, 9.0)), ("ppo-pgx", 39, (4.0, 5.0))):
        run = tmp_path / "runs" / "minatar-breakout" / method
        run.mkdir(parents=True)
        (run / "config.json").write_text(json.dumps({"config": cfg, "seeds": [0, 1]}))
        rows = [{"epoch": e, "seed": s, "env_steps": e * 524_288, "walltime": 10.0 * e,
                 "eval_return": last[s] if e == epochs else 1.0, **({"epoch_seconds": 10.0} if e else {})}
                for e in range(epochs + 1) for s in (0, 1)]
        with gzip.open(run / "metrics.jsonl.gz", "wt") as f:
            f.writelines(json.dumps(r) + "\n" for r in rows)
    example = tmp_path / "pgx-example"
    example.mkdir()
    for seed, end in ((0, 2.0), (1, 6.0)):
        (example / f"breakout-seed{seed}.log").write_text(
            f"{{'sec': 0.0, 'minatar-breakout/eval_R': 1.0, 'steps': 0}}\n"
            f"{{'sec': 1.0, 'minatar-breakout/eval_R': {end}, 'steps': 524288}}\n")
    (example / "times.txt").write_text("breakout seed 0 rc 0 wall 30.0 s\nbreakout seed 1 rc 0 wall 40.0 s\n")
    assert minatar_gate.main([str(tmp_path)]) == 0
    rows = [[c.strip() for c in line.split("|")[1:-1]] for line in capsys.readouterr().out.splitlines()[2:]]
    assert [r[:5] for r in rows] == [
        ["breakout", "ppo-pgx", "4.0, 5.0 (4.5)", "2.0, 6.0 [2.0, 6.0]", "within"],
        ["breakout", "ppo-v-shared", "7.0, 9.0 (8.0)", "2.0, 6.0 [2.0, 6.0]",
         "above (unfinished: epoch 2 of 39)"]]
    assert [r[5] for r in rows] == ["+0.5 [too few seeds]", "+4.0 [too few seeds]"]   # 4.5 − 4, 8 − 4


def test_minatar_pgx_cost_counts_opcodes_of_every_computation():
    """`opcode_counts` counts each instruction once by its opcode, a tuple-typed one (whose type carries
    /*index=N*/ comments) and a ROOT one included, and nothing in attributes or metadata."""
    from bench.lab.minatar_pgx_cost import opcode_counts

    hlo = """HloModule m
%body (p: (s32[], f32[4])) -> (s32[], f32[4]) {
  %p = (s32[], f32[4]{0}) parameter(0)
  %c = f32[4,8]{1,0} convolution(%a, %b), window={size=2x2}, metadata={op_name="dot(x)"}
  ROOT %t = (s32[], f32[4]{0}) tuple(%i, %x)
}
ENTRY %main {
  %w = (s32[], f32[4]{0}, /*index=2*/f32[4]{0}) while(%init), condition=%cond, body=%body
  %d = f32[4,4]{1,0} dot(%x, %y), lhs_contracting_dims={1}, rhs_contracting_dims={0}
  ROOT %f = f32[4]{0} fusion(%d), kind=kLoop, calls=%fused
}"""
    counts = opcode_counts(hlo)
    assert counts["convolution"] == counts["while"] == counts["dot"] == counts["fusion"] == 1
    assert counts["instructions"] == 6 and counts["sort"] == 0


def test_torch_eval_env_ways_step_the_same_envs_to_the_same_states(capsys):
    """`torch_eval_env` times like with like: TorchRL's step, `step_actions`, `_step` and the jitted JAX step
    reach the same observations from one reset and one action sequence, the compiled scan the same up to
    its own fusion's rounding; a bad size or task exits 2."""
    pytest.importorskip("torchrl", reason="the torch trainer's env: install sf2-core-torch[train]")
    import jax
    import jax.numpy as jnp
    import torch
    from sf2_torch.agents import envs

    from bench.lab import torch_eval_env

    n, steps = 3, 4
    env = envs.make_env("CartpoleBalance", 1000, 1, n, "cpu")
    keys = jax.random.split(jax.random.PRNGKey(1), n)
    g = torch.Generator().manual_seed(2)
    actions = [torch.rand(n, env._spec.action_size, generator=g) * 2 - 1 for _ in range(steps)]
    jax_actions = jnp.stack([jnp.asarray(a.numpy()) for a in actions])
    last = {}
    for way in torch_eval_env.WAYS:
        env.reset_from_keys(keys)
        fn = torch_eval_env.stepper(way, env, actions, jax_actions)
        obs = [np.asarray(fn(i)) for i in range(steps)]
        last[way] = obs[-1]
        assert not np.array_equal(obs[0], obs[-1])   # the envs moved
    np.testing.assert_array_equal(last["own_step"], last["torchrl_step"])
    np.testing.assert_array_equal(last["step_actions"], last["torchrl_step"])
    np.testing.assert_array_equal(last["jax_step"], last["torchrl_step"])
    np.testing.assert_allclose(np.asarray(torch_eval_env.scan_steps(env, keys, jax_actions)()),
                               last["torchrl_step"], rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="unknown way 'nope'"):
        torch_eval_env.stepper("nope", env, actions, jax_actions)
    assert torch_eval_env.main(["--envs", "0"]) == 2
    assert torch_eval_env.main(["--task", "Nope", "--device", "cpu"]) == 2
    assert "unknown task 'Nope'" in capsys.readouterr().err
