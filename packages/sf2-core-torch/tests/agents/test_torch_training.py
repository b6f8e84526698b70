"""Training runs (tiny, seconds each once the env is compiled): the run folder, determinism, several
seeds == seeds one by one, kill-and-resume == uninterrupted, the NaN guard, every algorithm ×
representation, `sf2-torch train|eval|plot`; and a small run that learns (test_learns)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from sf2_testing import KILL_POINTS, check_cli_eval, check_obs_noise_eval, kill_and_resume, strip_wall
from sf2_torch import cli
from sf2_torch.agents.trainer import TrainingDiverged, train


def _seed_rows(rows, seed):
    return [r for r in strip_wall(rows) if r["seed"] == seed]


def _state(result, i=0):
    """Every tensor of seed i's agent (parameters, targets, Adam states) as numpy, by name."""
    state = result.state.agents[i].algo.state_dict()
    out = {}
    for g, v in state["groups"].items():
        out.update({f"g.{g}": v.numpy()} if isinstance(v, torch.Tensor) else
                   {f"g.{g}.{k}": t.numpy() for k, t in v.items()})
    for g, opt in state["optimizers"].items():
        for pid, st in opt["state"].items():
            for k, v in st.items():
                out[f"o.{g}.{pid}.{k}"] = np.asarray(v)
    return out


def _assert_same_state(a, b, i=0, j=0):
    sa, sb = _state(a, i), _state(b, j)
    assert set(sa) == set(sb)
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)


@pytest.fixture(scope="module")
def reference(tiny_cfg, tmp_path_factory):
    """An uninterrupted single-seed run."""
    return train(tiny_cfg, (0,), tmp_path_factory.mktemp("ref"), progress=False)


def test_reference_run_folder(reference, tiny_cfg):
    run = reference.run
    conf = json.loads(run.config_path.read_text())
    assert conf["config"]["representation"] == "sf2" and conf["framework"] == "torch"
    assert conf["compile_mode"] is None and conf["device"] == "cpu"
    rows = run.read_rows()
    assert [r["epoch"] for r in rows] == [0, 1, 2, 3]
    assert [r.get("sgd_steps") for r in rows] == [None, 8, 24, 24]
    assert rows[-1]["env_steps"] >= tiny_cfg.num_timesteps
    for name in ("critic_loss", "q", "flow_loss", "loss_p", "loss_boot", "actor_loss", "sps"):
        assert np.isfinite(rows[-1][name])
    assert run.curve_path.exists() and (run.final_dir / "params_seed0.npz").exists()
    flat = dict(np.load(run.final_dir / "params_seed0.npz"))
    assert "psi.dense_0.kernel" in flat and "target_zeta.dense_1.bias" in flat
    from sf2_torch import params

    params.validate(flat, reference.state.agents[0].algo.groups)  # the layout both frameworks read


def test_same_seed_same_metrics(reference, tiny_cfg, tmp_path):
    again = train(tiny_cfg, (0,), tmp_path / "again", progress=False)
    assert strip_wall(again.rows) == strip_wall(reference.rows)
    _assert_same_state(again, reference)


def test_several_seeds_equal_seeds_one_by_one(reference, tiny_cfg, tmp_path):
    both = train(tiny_cfg, (0, 1), tmp_path / "both", progress=False)
    one = train(tiny_cfg, (1,), tmp_path / "one", progress=False)
    assert _seed_rows(both.rows, 0) == _seed_rows(reference.rows, 0)
    assert _seed_rows(both.rows, 1) == _seed_rows(one.rows, 1)
    assert _seed_rows(both.rows, 0) != _seed_rows(both.rows, 1)  # the seeds really differ
    _assert_same_state(both, reference, 0, 0)
    _assert_same_state(both, one, 1, 0)


@pytest.mark.parametrize("kill,expected_resume", KILL_POINTS)
def test_kill_and_resume_equals_uninterrupted(reference, tiny_cfg, tmp_path, kill, expected_resume):
    """Killed at each of `KILL_POINTS` (a torn last metrics line too), the resumed run has exactly the
    uninterrupted run's rows and final state."""
    resumed = kill_and_resume(train, tiny_cfg, tmp_path / "killed", *kill, expected_resume)
    assert strip_wall(resumed.run.read_rows()) == strip_wall(reference.rows)
    _assert_same_state(resumed, reference)


def test_finished_run_is_not_retrained(reference, tiny_cfg):
    again = train(tiny_cfg, (0,), reference.run.path, progress=False)
    assert again.resumed_from == 3 and strip_wall(again.rows) == strip_wall(reference.rows)


def test_nan_stops_the_run_and_keeps_the_last_good_checkpoint(tiny_cfg, tmp_path, monkeypatch):
    """A NaN in the Q heads at the start of epoch 3 (as if an update had diverged there) makes every loss
    of that epoch's first SGD step non-finite; the run stops naming the loss, the SGD step (32: epochs
    1 and 2 hold SGD steps 0-31) and the epoch, and keeps checkpoint 2 and rows 0-2 (the sf2_jax test)."""
    from sf2_torch.agents.checkpoint import Checkpointer
    from sf2_torch.agents.trainer import get_program

    program = get_program(tiny_cfg)
    real_epoch = program.epoch

    def poisoned_epoch(state, epoch):
        if epoch == 3:
            with torch.no_grad():
                for p in state.agents[0].algo.groups["q"].parameters():
                    p.mul_(torch.nan)
        return real_epoch(state, epoch)

    monkeypatch.setattr(program, "epoch", poisoned_epoch)
    with pytest.raises(TrainingDiverged) as err:
        train(tiny_cfg, (0,), tmp_path / "nan", progress=False)
    msg = str(err.value)
    assert "loss 'critic_loss' became NaN/inf" in msg and "actor_loss (seed 0)" in msg, msg
    assert "gradient step 32 (env step 100, epoch 3, seed 0)" in msg, msg
    assert "last good checkpoint (epoch 2) is kept" in msg, msg
    assert Checkpointer(tmp_path / "nan" / "checkpoints").latest() == 2
    rows = [json.loads(line) for line in (tmp_path / "nan" / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [0, 1, 2]


@pytest.mark.parametrize("algo,rep", [("sac", "sf2"), ("td3", "none"), ("sac", "none")])
def test_every_algorithm_and_representation_trains(tiny_cfg, tmp_path, algo, rep):
    res = train(tiny_cfg.replace(algo=algo, representation=rep, num_evals=2), (0,), tmp_path / "run",
                progress=False)
    last = res.rows[-1]
    expected = {"critic_loss", "q", "actor_loss"} | ({"flow_loss", "loss_p", "loss_boot"} if rep == "sf2"
                                                     else set()) | (
        {"alpha_loss", "alpha", "entropy"} if algo == "sac" else set())
    assert expected <= set(last) and all(np.isfinite(last[k]) for k in expected)
    flat = dict(np.load(res.run.final_dir / "params_seed0.npz"))
    assert "q.head_1.dense_0.kernel" in flat and "target_q.head_0.dense_0.bias" in flat
    assert ("log_alpha" in flat) == (algo == "sac")
    assert ("target_policy.dense_0.kernel" in flat) == (algo == "td3")


def test_cli_train_eval_and_plot(reference, tiny_cfg, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SF2_TORCH_COMPILE_CACHE", "")  # keep the conftest's JAX cache folder
    out = tmp_path / "cli"
    args = ["train", "--task", "CartpoleBalance", "--config", "quick", "--seeds", "0", "--out", str(out),
            "--no-progress", "--log", "tensorboard"]
    for name, value in tiny_cfg.to_dict().items():
        if name not in ("task", "algo", "representation"):
            args += [f"--{name.replace('_', '-')}", ",".join(map(str, value)) if isinstance(value, list)
                     else str(value)]
    assert cli.main(args) == 0
    assert "TD3+SF²" in capsys.readouterr().out
    assert strip_wall(json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()) == \
        strip_wall(reference.rows)
    assert reference.rows[-1]["epoch"] == 3
    _check_tensorboard(out)
    check_cli_eval(cli.main, capsys, reference.run.path, tiny_cfg.num_eval_envs,
                   reference.rows[-1]["eval_return"])
    png = tmp_path / "curves.png"
    assert cli.main(["plot", str(reference.run.path), str(out), "--out", str(png)]) == 0
    assert png.exists() and "TD3+SF²" in capsys.readouterr().out


def _check_tensorboard(out):
    """`--log tensorboard`: TensorBoard's reader gives every metric of metrics.jsonl at each env step
    (float32)."""
    from sf2_common.agents.loggers import scalars
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    acc = EventAccumulator(str(out / "tensorboard" / "seed0"))
    acc.Reload()
    assert sorted(acc.Tags()["scalars"]) == sorted(scalars(rows[-1]))
    for name in scalars(rows[-1]):
        assert [(e.step, e.value) for e in acc.Scalars(name)] == \
            [(r["env_steps"], float(np.float32(r[name]))) for r in rows if name in r]


# --------------------------------------------------------------------------------------------- learning
LEARN = dict(
    episode_length=1000, action_repeat=4, num_envs=8, num_eval_envs=8, num_evals=4, num_timesteps=31_000,
    batch_size=128, grad_updates_per_step=4, min_replay_size=1024, max_replay_size=100_000,
    feature_size=32, hidden_sizes=(64, 64), q_hidden_size=64, zeta_hidden_sizes=(64, 64), embedding_size=16,
    discount=0.95, tau=0.05, compile="off", device="cpu",   # a CPU test on any host, as TINY (conftest)
)


class _Fixed:
    """A stand-in agent for `Program.evaluate`: uniform random or all-zero actions."""

    def __init__(self, action_size, kind):
        self.algo = self
        self.action_size, self.kind = action_size, kind

    def act(self, obs, generator, deterministic):
        if self.kind == "zero":
            return torch.zeros(obs.shape[0], self.action_size, device=obs.device)
        return torch.rand(obs.shape[0], self.action_size, generator=generator, device=obs.device) * 2 - 1


@pytest.mark.slow
def test_learns(tmp_path):
    """TD3+SF² learns to balance CartpoleBalance (1000-step episodes, action repeat 4) in 3.4k SGD steps
    (31k env steps; one to two minutes on a shared 2-core CPU). γ = 0.95 and τ = 0.05 (instead of 0.99 and
    0.005) make it learn within a test's budget. The margin: the final deterministic evaluation (8 episodes
    from the JAX trainer's start states) must beat doing nothing (zero actions, ≈ 697: the pole starts
    upright) and the uniform random policy (≈ 300 ± 60 per episode) by far, ≥ 800; seeds 0-3 measured
    999, 973, 971, 946 at this point (max 1000)."""
    from sf2_torch.agents import make_config
    from sf2_torch.agents.trainer import get_program

    cfg = make_config("quick", "CartpoleBalance", algo="td3", representation="sf2", overrides=LEARN)
    res = train(cfg, (0,), tmp_path / "learn", progress=False)
    returns = [r["eval_return"] for r in res.rows]
    program = get_program(cfg)
    a = program.spec.action_size
    final_epoch = res.rows[-1]["epoch"]
    starts = res.state.eval_keys
    zero = program.evaluate([_Fixed(a, "zero")], starts, (0,), final_epoch).mean()
    rand = program.evaluate([_Fixed(a, "random")], starts, (0,), final_epoch)
    margin = max(zero, rand.mean() + 5 * rand.std())
    assert returns[-1] >= 800 > margin, (returns, zero, rand.mean(), rand.std())
    assert returns[-1] - returns[0] >= 300, returns


def test_a_jax_run_folder_is_refused(tiny_cfg, tmp_path, capsys):
    """A folder written by sf2-jax (its config.json has no "framework" and JAX's versions) is neither
    resumed nor evaluated by sf2-torch; `plot` reads both."""
    folder = tmp_path / "jax-run"
    folder.mkdir()
    (folder / "config.json").write_text(json.dumps({"config": tiny_cfg.to_dict(), "seeds": [0],
                                                    "versions": {"jax": "0.10", "flax": "0.12"}}))
    from sf2_common.agents.runfolder import RunFolderMismatch

    with pytest.raises(RunFolderMismatch, match="sf2-jax"):
        train(tiny_cfg, (0,), folder, progress=False)
    assert cli.main(["eval", str(folder)]) == 2
    assert "trained by sf2-jax" in capsys.readouterr().err


def test_evaluation_under_observation_noise(reference, tmp_path, capsys, monkeypatch):
    """`sf2_testing.check_obs_noise_eval` on a copy of the reference run (paper App. C.2.2)."""
    import shutil

    from sf2_torch.agents import trainer as trainer_module

    monkeypatch.setenv("SF2_JAX_COMPILE_CACHE", "")
    run = tmp_path / "run"
    shutil.copytree(reference.run.path, run)
    check_obs_noise_eval(trainer_module, cli.main, capsys, monkeypatch, run)
