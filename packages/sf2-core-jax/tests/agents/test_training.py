"""Training runs (tiny, seconds each): determinism, vmapped seeds == seeds one by one, kill-and-resume ==
uninterrupted, the NaN guard, `sf2-jax eval` and `plot` on a run folder."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
from sf2_jax import cli
from sf2_jax.agents.trainer import TrainingDiverged, train
from sf2_testing import KILL_POINTS, check_cli_eval, check_obs_noise_eval, kill_and_resume, strip_wall


def _seed_rows(rows, seed):
    return [r for r in strip_wall(rows) if r["seed"] == seed]


def _assert_same_params(a, b, index_a=None, index_b=None):
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb):
        x = np.asarray(x if index_a is None else x[index_a])
        y = np.asarray(y if index_b is None else y[index_b])
        np.testing.assert_array_equal(x, y)


@pytest.fixture(scope="module")
def reference(tiny_cfg, tmp_path_factory):
    """An uninterrupted single-seed run."""
    return train(tiny_cfg, (0,), tmp_path_factory.mktemp("ref"), progress=False)


def test_reference_run_folder(reference, tiny_cfg):
    run = reference.run
    assert json.loads(run.config_path.read_text())["config"]["representation"] == "sf2"
    rows = run.read_rows()
    assert [r["epoch"] for r in rows] == [0, 1, 2, 3]
    assert rows[-1]["env_steps"] >= tiny_cfg.num_timesteps
    assert [r["env_steps"] for r in rows] == [0, 48, 96, 144]
    assert [r.get("sgd_steps") for r in rows] == [None, 8, 24, 24]
    for name in ("critic_loss", "flow_loss", "loss_p", "loss_boot", "actor_loss", "sps"):
        assert np.isfinite(rows[-1][name])
    assert run.curve_path.exists() and (run.final_dir / "params_seed0.npz").exists()
    flat = np.load(run.final_dir / "params_seed0.npz")
    assert "psi.dense_0.kernel" in flat and "target_zeta.dense_1.bias" in flat


def test_same_seed_same_metrics(reference, tiny_cfg, tmp_path):
    again = train(tiny_cfg, (0,), tmp_path / "again", progress=False)
    assert strip_wall(again.rows) == strip_wall(reference.rows)
    _assert_same_params(again.state.params, reference.state.params)


def _assert_close_rows(a, b):
    assert [(r["epoch"], r["seed"], r["env_steps"]) for r in a] == [(r["epoch"], r["seed"], r["env_steps"])
                                                                    for r in b]
    for ra, rb in zip(a, b):
        assert set(ra) == set(rb)
        for k in ra:
            np.testing.assert_allclose(ra[k], rb[k], rtol=1e-4, atol=1e-5, err_msg=k)


def _assert_close_params(a, b, index_a, index_b):
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        np.testing.assert_allclose(np.asarray(x)[index_a], np.asarray(y)[index_b], rtol=1e-4, atol=1e-6)


def test_vmapped_seeds_equal_seeds_one_by_one(reference, tiny_cfg, tmp_path):
    """Seeds 0 and 1 in one vmapped program equal seed 0 alone and seed 1 alone.

    Exactly equal across vmapped programs of >= 2 seeds (a seed's numbers do not depend on its batch
    mates or its position: (0, 1) vs (2, 0)); equal up to float32 rounding against a one-seed program,
    where XLA drops the unit seed axis and sums bias gradients in another order (last-bit differences,
    checked here on a short run; like any chaotic dynamics they grow over long runs)."""
    both = train(tiny_cfg, (0, 1), tmp_path / "both", progress=False)
    swapped = train(tiny_cfg, (2, 0), tmp_path / "swapped", progress=False)
    one = train(tiny_cfg, (1,), tmp_path / "one", progress=False)
    assert _seed_rows(both.rows, 0) == _seed_rows(swapped.rows, 0)
    _assert_same_params(both.state.params, swapped.state.params, 0, 1)
    _assert_same_params(both.state.opt_state, swapped.state.opt_state, 0, 1)
    assert _seed_rows(both.rows, 0) != _seed_rows(both.rows, 1)  # the seeds really differ
    _assert_close_rows(_seed_rows(both.rows, 0), _seed_rows(reference.rows, 0))
    _assert_close_rows(_seed_rows(both.rows, 1), _seed_rows(one.rows, 1))
    _assert_close_params(both.state.params, reference.state.params, 0, 0)
    _assert_close_params(both.state.params, one.state.params, 1, 0)


@pytest.mark.parametrize("kill,expected_resume", KILL_POINTS)
def test_kill_and_resume_equals_uninterrupted(reference, tiny_cfg, tmp_path, kill, expected_resume):
    """Killed at each of `KILL_POINTS` (a torn last metrics line too), the resumed run has exactly the
    uninterrupted run's rows and final state."""
    resumed = kill_and_resume(train, tiny_cfg, tmp_path / "killed", *kill, expected_resume)
    assert strip_wall(resumed.run.read_rows()) == strip_wall(reference.rows)
    _assert_same_params(resumed.state.params, reference.state.params)
    _assert_same_params(resumed.state.opt_state, reference.state.opt_state)


def test_finished_run_is_not_retrained(reference, tiny_cfg):
    again = train(tiny_cfg, (0,), reference.run.path, progress=False)
    assert again.resumed_from == 3 and strip_wall(again.rows) == strip_wall(reference.rows)


def test_nan_stops_the_run_and_keeps_the_last_good_checkpoint(tiny_cfg, tmp_path, poison_epoch):
    """A NaN in the Q heads at the start of epoch 3 (as if an update had diverged there) makes every loss
    of that epoch's first SGD step non-finite; the run stops naming the loss, the SGD step (32: epochs
    1 and 2 hold SGD steps 0-31) and the epoch, and keeps checkpoint 2 and rows 0-2 (`poison_epoch`:
    conftest.py)."""
    from sf2_jax.agents.checkpoint import Checkpointer

    poison_epoch(tiny_cfg, 3)
    with pytest.raises(TrainingDiverged) as err:
        train(tiny_cfg, (0,), tmp_path / "nan", progress=False)
    msg = str(err.value)
    assert "loss 'critic_loss' became NaN/inf" in msg and "actor_loss (seed 0)" in msg, msg
    assert "gradient step 32 (env step 100, epoch 3, seed 0)" in msg, msg
    assert "last good checkpoint (epoch 2) is kept" in msg, msg
    assert Checkpointer(tmp_path / "nan" / "checkpoints").latest() == 2
    rows = [json.loads(line) for line in (tmp_path / "nan" / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [0, 1, 2]


def test_cli_eval_and_plot(reference, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SF2_JAX_COMPILE_CACHE", "")  # no persistent cache from inside the tests
    assert reference.rows[-1]["epoch"] == 3
    check_cli_eval(cli.main, capsys, reference.run.path, 2, reference.rows[-1]["eval_return"])
    png = tmp_path / "curves.png"
    assert cli.main(["plot", str(reference.run.path), "--out", str(png)]) == 0
    assert png.exists() and "TD3+SF²" in capsys.readouterr().out


def test_a_torch_run_folder_is_refused(tiny_cfg, tmp_path, capsys):
    """A folder written by sf2-torch (its config.json says "framework": "torch") is neither resumed nor
    evaluated by sf2-jax, and stays as it was."""
    from sf2_common.agents.runfolder import RunFolderMismatch

    folder = tmp_path / "torch-run"
    folder.mkdir()
    text = json.dumps({"config": tiny_cfg.to_dict(), "seeds": [0], "framework": "torch",
                       "versions": {"torch": "2.9", "torchrl": "0.14"}})
    (folder / "config.json").write_text(text)
    with pytest.raises(RunFolderMismatch, match="sf2-torch"):
        train(tiny_cfg, (0,), folder, progress=False)
    assert cli.main(["eval", str(folder)]) == 2
    assert "trained by sf2-torch" in capsys.readouterr().err
    assert sorted(p.name for p in folder.iterdir()) == ["config.json"]
    assert (folder / "config.json").read_text() == text


def test_evaluation_under_observation_noise(reference, tmp_path, capsys, monkeypatch):
    """`sf2_testing.check_obs_noise_eval` on a copy of the reference run (paper App. C.2.2)."""
    import shutil

    from sf2_jax.agents import trainer as trainer_module

    monkeypatch.setenv("SF2_JAX_COMPILE_CACHE", "")
    run = tmp_path / "run"
    shutil.copytree(reference.run.path, run)
    check_obs_noise_eval(trainer_module, cli.main, capsys, monkeypatch, run)


def _cond_program(cfg):
    """A `Program` with the plain formulation that `Program._actor_step` replaced: the prefill and training
    branches as `lax.cond`s, so only the taken one runs."""
    import jax.numpy as jnp
    from sf2_jax import networks
    from sf2_jax.agents.trainer import Program

    class CondProgram(Program):
        def _actor_step(self, state, actor_step):
            cfg, A = self.cfg, self.spec.action_size
            prefill = actor_step < self.sched.prefill_actor_steps
            key, k_act, k_sgd = jax.random.split(state.key, 3)
            obs = state.env_state.obs

            def explore():
                with self.learner_precision():
                    return self.algo.explore(state.params, obs, k_act).astype(jnp.float32)

            action = jax.lax.cond(prefill, lambda: jax.random.uniform(
                k_act, (cfg.num_envs, A), jnp.float32, -1.0, 1.0), explore)
            env_state, batch = self._env_step(state.env_state, action)
            params = state.params
            if cfg.normalize_observations:
                params = {**params, "obs_norm": networks.update_normalizer(params["obs_norm"], batch.obs,
                                                                           self.sf2)}
            state = state._replace(params=params, env_state=env_state, key=key,
                                   replay=self.buffer.insert(state.replay, batch),
                                   env_steps=state.env_steps + self.sched.env_steps_per_actor_step)
            zeros = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype),
                                           jax.eval_shape(self._sgd_steps, state, k_sgd)[1])
            state, metrics = jax.lax.cond(prefill, lambda s, k: (s, zeros), self._sgd_steps, state, k_sgd)
            return state, (metrics, ~prefill)

    return CondProgram(cfg)


def _assert_same_epoch(epoch, new, old):
    """Two programs' (state, epoch means) after `epoch`: equal shapes, integers (keys, counters, buffer
    cursors) exactly, floats up to float32 rounding (two programs fuse differently:
    `test_vmapped_seeds_equal_seeds_one_by_one`'s tolerance)."""
    (s_new, m_new), (s_old, m_old) = new, old
    for name in m_old:
        np.testing.assert_allclose(np.asarray(m_new[name]), np.asarray(m_old[name]), rtol=1e-4, atol=1e-5,
                                   err_msg=f"epoch {epoch} {name}")
    for (path, a), b in zip(jax.tree_util.tree_leaves_with_path(s_new), jax.tree_util.tree_leaves(s_old),
                            strict=True):
        a, b, where = np.asarray(a), np.asarray(b), f"epoch {epoch} {jax.tree_util.keystr(path)}"
        assert a.shape == b.shape, where
        if np.issubdtype(a.dtype, np.floating):
            np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5, err_msg=where)
        else:
            np.testing.assert_array_equal(a, b, err_msg=where)


def test_branchless_actor_step_equals_the_cond_formulation(tiny_cfg):
    """`Program._actor_step` computes both the prefill's and the training step's action and SGD steps and
    selects with `jnp.where` (no `lax.cond`, whose GPU form copies every array passing through it). Over
    epoch 1 (8 prefill actor steps, then 4 training ones: the boundary) and epoch 2, from one initial
    state, its whole state (parameters, Adam states, SGD count, env state, buffer, key) and epoch means
    equal the `lax.cond` formulation's: integers (keys, counters, cursors) exactly, floats up to float32
    rounding (the two programs fuse differently: `test_vmapped_seeds_equal_seeds_one_by_one`'s tolerance),
    and the SGD count holds only the training steps'."""
    from sf2_jax.agents.trainer import Program

    seeds = (0, 1)
    new, old = Program(tiny_cfg), _cond_program(tiny_cfg)
    assert new.sched.prefill_actor_steps == 8 and new.sched.actor_steps_per_epoch == 12
    init = new.init(seeds)
    s_new, s_old = init, jax.tree_util.tree_map(lambda x: x.copy(), init)
    for epoch in (1, 2):
        s_new, m_new, _ = new.epoch(s_new, epoch)
        s_old, m_old, _ = old.epoch(s_old, epoch)
        _assert_same_epoch(epoch, (s_new, m_new), (s_old, m_old))
        if epoch == 1:
            assert int(np.asarray(m_new["sgd_steps"]).max()) == 4 * tiny_cfg.grad_updates_per_step
    # 4 + 12 training actor steps, none of the prefill's SGD steps counted
    assert np.asarray(s_new.grad_steps).tolist() == [16 * tiny_cfg.grad_updates_per_step] * len(seeds)


def test_one_seed_program_without_vmap_equals_the_vmapped_one(tiny_cfg, monkeypatch):
    """At one seed the programs run the per-seed functions on the seed's slice instead of under `jax.vmap`
    (`trainer._seed_map`). From one initial state, over epoch 1 (prefill and training steps) and epoch 2,
    the state and epoch means equal those of the vmapped one-seed programs: integers (keys, counters, buffer
    cursors) exactly, floats to float32 rounding (`test_branchless_actor_step_equals_the_cond_formulation`'s
    tolerance); and the program XLA receives has fewer products with a batch dimension (the seed axis's)."""
    import sf2_jax.agents.trainer as trainer

    def vmapped(fn, in_axes, n_seeds):   # the programs as before `_seed_map`: a vmap at any seed count
        return jax.vmap(fn, in_axes=in_axes)

    new, old = trainer.Program(tiny_cfg), trainer.Program(tiny_cfg)
    s_new = new.init((0,))
    s_old = jax.tree_util.tree_map(lambda x: x.copy(), s_new)
    for epoch in (1, 2):
        s_new, m_new, _ = new.epoch(s_new, epoch)
        with monkeypatch.context() as m:
            m.setattr(trainer, "_seed_map", vmapped)
            s_old, m_old, _ = old.epoch(s_old, epoch)
        assert all(x.shape[:1] == (1,) for x in jax.tree_util.tree_leaves(s_new))   # the seed axis kept
        _assert_same_epoch(epoch, (s_new, m_new), (s_old, m_old))

    def batched_products(program):   # dot_generals with a batch dimension in the epoch program XLA receives
        text = program._program("epoch", 1).lower(s_new, np.int32(0)).as_text()
        return sum("batching_dims" in line for line in text.splitlines() if "dot_general" in line)

    with monkeypatch.context() as m:
        m.setattr(trainer, "_seed_map", vmapped)
        n_vmapped = batched_products(old)
    # without the vmap only the flow loss's own batched products remain (53 lines against 117 for this
    # config on the CPU, 2026-11-27)
    assert batched_products(new) < n_vmapped
