"""The batched evaluation (`Program.evaluate_many`, used by the host loop between checkpoints when
`checkpoint_every` > 1) against the plain per-epoch evaluation it replaces: the same returns, the same
rows, the same resume and NaN-guard behaviour. CPU, float32 (the trainer's dtype); the programs alone
also in float64."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sf2_jax.agents import trainer
from sf2_jax.agents.checkpoint import Checkpointer
from sf2_jax.agents.trainer import TrainingDiverged, get_program, train
from sf2_testing import kill_and_resume, strip_wall

# Vmapping over the snapshot axis changes the shapes of the policy's matmuls (a batch dimension more),
# which may round differently in the last bit; a 60-step episode keeps such a difference near float32
# resolution (measured here: equal).
RTOL = 1e-5
# With x64 on and the policy's parameters in float64 the two programs must agree to float64 resolution
# (the trainer sums the returns in float32, so in effect exactly).
RTOL_F64 = 1e-10


def _assert_rows_match(batched, plain):
    """Same rows; training metrics exactly (the evaluation does not touch training), returns to RTOL."""
    assert [(r["epoch"], r["seed"]) for r in batched] == [(r["epoch"], r["seed"]) for r in plain]
    for a, b in zip(strip_wall(batched), strip_wall(plain)):
        assert set(a) == set(b)
        for k in a:
            if k.startswith("eval_return"):
                np.testing.assert_allclose(a[k], b[k], rtol=RTOL, atol=1e-6, err_msg=k)
            else:
                assert a[k] == b[k], k


@pytest.fixture(scope="module")
def cfg(tiny_cfg):
    """tiny_cfg with a checkpoint every 2 epochs: epochs 1-2 are evaluated in one program before
    checkpoint 2, epoch 3 alone before the last checkpoint. The evaluation acts with exploration noise
    (the paper preset's, unlike the quick preset's deterministic one), so each epoch's keys count."""
    return tiny_cfg.replace(checkpoint_every=2, deterministic_eval=False)


@pytest.fixture(scope="module")
def plain(cfg, tmp_path_factory):
    """The run with the per-epoch evaluation (a session without `evaluate_many`)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.delattr(trainer.BatchedSeedsSession, "evaluate_many")
        return train(cfg, (0, 1), tmp_path_factory.mktemp("plain"), progress=False)


@pytest.fixture(scope="module")
def batched(cfg, tmp_path_factory):
    return train(cfg, (0, 1), tmp_path_factory.mktemp("batched"), progress=False)


@pytest.mark.parametrize("dtype, rtol, atol", [("float32", RTOL, 1e-6), ("float64", RTOL_F64, 0.0)])
def test_evaluate_many_equals_evaluate_of_each(tiny_cfg, dtype, rtol, atol):
    """Three different policies (scaled parameters) and epochs in one program give each policy's
    `evaluate` at its epoch (its own acting keys: the policies act with exploration noise), and the
    three really differ, as does one policy's evaluation at another epoch."""
    seeds = (0, 1)
    cfg = tiny_cfg.replace(deterministic_eval=False)   # not the run tests' program: their compiled shapes
    with jax.enable_x64(dtype == "float64"):
        program = get_program(cfg)
        state = program.init(seeds)
        acting = trainer.acting_params(state.params)
        policies = [jax.tree_util.tree_map(lambda x, s=s: (x * s).astype(dtype), acting)
                    for s in (1.0, 1.5, 3.0)]
        epochs = [4, 5, 6]
        stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *policies)
        many = np.asarray(program.evaluate_many(stacked, state.eval_start, seeds, epochs))
        one = np.stack([np.asarray(program.evaluate(p, state.eval_start, seeds, e))
                        for p, e in zip(policies, epochs)])
        other_keys = np.asarray(program.evaluate(policies[0], state.eval_start, seeds, epochs[1]))
    assert many.shape == (3, 2, cfg.num_eval_envs)
    np.testing.assert_allclose(many, one, rtol=rtol, atol=atol)
    # the test compares something: the policies act differently, and the epoch's keys count
    assert not np.allclose(one[0], one[2]) and not np.allclose(one[0], other_keys)


def test_batched_run_writes_the_per_epoch_rows(batched, plain, cfg):
    """Batches [1, 2] and [3] (padded to two epochs, so the batched program compiled once)."""
    _assert_rows_match(batched.run.read_rows(), plain.run.read_rows())
    assert [r["epoch"] for r in batched.run.read_rows() if r["seed"] == 0] == [0, 1, 2, 3]
    assert Checkpointer(batched.run.checkpoint_dir).all() == Checkpointer(plain.run.checkpoint_dir).all()
    assert get_program(cfg)._programs[("evaluate_many", 0.0, False)]._cache_size() == 1


def test_kill_between_checkpoints_resumes_to_the_same_rows(batched, cfg, tmp_path):
    """Killed as epoch 2 begins (epoch 1 trained, its evaluation pending, nothing of it written), the run
    resumes from checkpoint 0 and ends with the uninterrupted run's rows, exactly (same batches)."""
    resumed = kill_and_resume(lambda c, s, o, **kw: train(c, (0, 1), o, **kw), cfg, tmp_path / "killed",
                              "train", 2, 0)
    assert strip_wall(resumed.run.read_rows()) == strip_wall(batched.run.read_rows())


def test_stop_between_checkpoints_resumes_to_the_same_rows(batched, cfg, tmp_path):
    """`stop_after_epoch=1` evaluates epoch 1 alone (padded to two) before checkpoint 1; the resumed run's
    batches are [2] and [3]. Each epoch is a lane of the same compiled program as in the uninterrupted
    run, so its rows are those, exactly."""
    train(cfg, (0, 1), tmp_path, progress=False, stop_after_epoch=1)
    resumed = train(cfg, (0, 1), tmp_path, progress=False)
    assert resumed.resumed_from == 1
    assert strip_wall(resumed.run.read_rows()) == strip_wall(batched.run.read_rows())


def test_divergence_writes_the_pending_epochs_rows(cfg, plain, tmp_path, poison_epoch):
    """A NaN at the start of epoch 2 (`poison_epoch`, conftest.py): epoch 1's pending evaluation is
    written before the run stops, so the folder holds rows 0-1, as with per-epoch evaluation, and
    checkpoint 0 is the last good one."""
    poison_epoch(cfg, 2)
    with pytest.raises(TrainingDiverged, match=r"last good checkpoint \(epoch 0\) is kept"):
        train(cfg, (0, 1), tmp_path / "nan", progress=False)
    rows = [json.loads(line) for line in (tmp_path / "nan" / "metrics.jsonl").read_text().splitlines()]
    _assert_rows_match(rows, [r for r in plain.run.read_rows() if r["epoch"] <= 1])
