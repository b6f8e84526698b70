"""The host loop's batched evaluation (`hostloop.BatchedEvaluation`) without a framework: a fake session
whose "policy" is the number of the last trained epoch, on a fake clock, against the per-epoch loop (the
same session without `evaluate_many`). What the JAX trainer's batched program returns is tested in
packages/sf2-core-jax/tests/agents/test_batched_eval.py."""

from __future__ import annotations

import types

import numpy as np
import pytest
from sf2_common.agents import configs, hostloop
from sf2_common.agents.runfolder import RunFolder
from sf2_common.errors import ConfigError

TRAIN_S, EVAL_S, BATCH_S = 2.0, 1.0, 1.5   # wall seconds of an epoch, an evaluation, a batched evaluation


class _Clock:
    def __init__(self):
        self.now = 100.0

    def time(self):
        return self.now


class _PerEpoch:
    """Two seeds; training epoch e makes the policy e, whose evaluation returns 10·e; `bad_epoch` makes
    seed 1's loss non-finite. Each call advances the clock by what it costs."""

    def __init__(self, clock, bad_epoch=None):
        self.clock, self.bad_epoch, self.policy, self.log = clock, bad_epoch, 0, []

    def start(self):
        self.log.append("start")

    def train_epoch(self, epoch):
        self.clock.now += TRAIN_S
        self.policy = epoch
        first_bad = {"loss": np.array([-1, 0 if epoch == self.bad_epoch else -1])}
        return {"sgd_steps": np.full(2, 4), "loss": np.full(2, float(epoch))}, first_bad

    def evaluate(self, epoch):
        self.clock.now += EVAL_S
        self.log.append(f"evaluate {epoch}")
        return np.full((2, 3), 10.0 * self.policy)

    def save(self, epoch, env_steps):
        self.log.append(f"save {epoch}")

    def loss_order(self):
        return ("loss",)

    def finish(self):
        self.log.append("finish")


class _Batched(_PerEpoch):
    def __init__(self, clock, bad_epoch=None):
        super().__init__(clock, bad_epoch)
        self.snapshots = {}

    def snapshot(self, epoch):
        self.snapshots[epoch] = self.policy

    def evaluate_many(self, epochs):
        self.clock.now += BATCH_S
        self.log.append(f"evaluate_many {epochs}")
        return np.stack([np.full((2, 3), 10.0 * self.snapshots.pop(e)) for e in epochs])


@pytest.fixture
def clock(monkeypatch):
    clock = _Clock()
    monkeypatch.setattr(hostloop, "time", types.SimpleNamespace(time=clock.time))
    return clock


def _loop(session, run, last=None, checkpoint_every=2, plot=False, **kw):
    """3 epochs of 32 env steps; checkpoints at 0, every `checkpoint_every` epochs and the last."""
    cfg = configs.TrainConfig(num_timesteps=96, num_envs=4, num_evals=4, min_replay_size=4,
                              checkpoint_every=checkpoint_every)
    rows = run.truncate_rows(-1 if last is None else last)     # the rows a resume from `last` keeps
    walltime = max((r.get("walltime", 0.0) for r in rows), default=0.0)
    return hostloop.run_epochs(session, cfg=cfg, sched=configs.schedule(cfg), seeds=(3, 4), run=run,
                               title="t", rows=rows, start=0 if last is None else last + 1, last=last,
                               walltime=walltime, progress=False, plot=plot, **kw)


def _strip(rows):
    return [{k: v for k, v in r.items() if k not in hostloop.WALL_FIELDS} for r in rows]


def test_batched_loop_writes_the_per_epoch_rows_before_each_checkpoint(tmp_path, clock):
    plain = _loop(_PerEpoch(clock), RunFolder(tmp_path / "plain"))
    events, session = [], _Batched(clock)
    clock.now = 100.0
    rows = _loop(session, RunFolder(tmp_path / "batched"), hook=lambda e, n: events.append(f"{e} {n}"))
    assert _strip(rows) == _strip(plain)
    assert [(r["epoch"], r["eval_return"]) for r in rows[::2]] == [(e, 10.0 * e) for e in range(4)]
    assert session.log == ["start", "evaluate 0", "save 0", "evaluate_many [1, 2]", "save 2",
                           "evaluate_many [3]", "save 3", "finish"]
    # "evaluate" and "rows" once per batch, with its last epoch; "train" per epoch
    assert events == ["evaluate 0", "rows 0", "save 0", "checkpoint 0", "train 1",
                      "train 2", "evaluate 2", "rows 2", "save 2", "checkpoint 2",
                      "train 3", "evaluate 3", "rows 3", "save 3", "checkpoint 3"]
    # wall fields: a batch's time shared by its epochs, walltime when the rows are written (run start at
    # 100: epoch 0 evaluated by 101, epochs 1 and 2 trained by 105, their batch done at 106.5, ...)
    wall = [(r["epoch"], r["eval_seconds"], r["walltime"], r.get("epoch_seconds")) for r in rows[::2]]
    assert wall == [(0, EVAL_S, 1.0, None), (1, BATCH_S / 2, 6.5, TRAIN_S), (2, BATCH_S / 2, 6.5, TRAIN_S),
                    (3, BATCH_S, 10.0, TRAIN_S)]
    assert rows[2]["sps"] == 32 / TRAIN_S
    assert RunFolder(tmp_path / "batched").read_rows() == rows


def test_batched_loop_only_with_checkpoints_apart(tmp_path, clock):
    """checkpoint_every = 1: the per-epoch loop, even for a session that can batch."""
    session = _Batched(clock)
    _loop(session, RunFolder(tmp_path / "run"), checkpoint_every=1)
    assert session.snapshots == {} and not any(x.startswith("evaluate_many") for x in session.log)
    assert [x for x in session.log if x.startswith("evaluate")] == [f"evaluate {e}" for e in range(4)]


def test_batched_loop_stop_resume_and_nan_guard(tmp_path, clock):
    full = _strip(_loop(_PerEpoch(clock), RunFolder(tmp_path / "full")))

    stopped, first = RunFolder(tmp_path / "stopped"), _Batched(clock)
    _loop(first, stopped, stop_after_epoch=1)          # a stop between checkpoints: batch [1], checkpoint 1
    again = _Batched(clock)
    again.policy = 1                                   # as restored from checkpoint 1
    assert _strip(_loop(again, stopped, 1)) == full
    assert first.log[-2:] == ["evaluate_many [1]", "save 1"]
    assert again.log == ["evaluate_many [2]", "save 2", "evaluate_many [3]", "save 3", "finish"]

    # epoch 2 diverges with epoch 1 pending: epoch 1's rows are written first, the message is unchanged
    nan, session = RunFolder(tmp_path / "nan"), _Batched(clock, bad_epoch=2)
    with pytest.raises(hostloop.TrainingDiverged, match="epoch 2, seed 4.*the last good checkpoint "
                       r"\(epoch 0\) is kept"):
        _loop(session, nan)
    assert session.log[-1] == "evaluate_many [1]" and session.snapshots == {}
    assert _strip(nan.read_rows()) == full[:4]


class _Shares(_Batched):
    """A session whose evaluations also report the share of episodes above 15 (`eval_metrics`)."""

    @staticmethod
    def eval_metrics(returns):
        return {"eval_share": float(np.mean(returns > 15.0))}


@pytest.mark.parametrize("checkpoint_every", [1, 2])
def test_eval_metrics_add_columns_to_every_evaluation_row(tmp_path, clock, checkpoint_every):
    """Epoch e's policy returns 10·e on every episode: the share above 15 is 0 for epochs 0 and 1, 1 after;
    per-epoch and batched evaluations alike, and a session without `eval_metrics` writes no such column."""
    rows = _loop(_Shares(clock), RunFolder(tmp_path / "run"), checkpoint_every=checkpoint_every)
    expected = [(e, float(e >= 2)) for e in range(4) for _seed in (3, 4)]
    assert [(r["epoch"], r["eval_share"]) for r in rows] == expected
    plain = _loop(_Batched(clock), RunFolder(tmp_path / "plain"), checkpoint_every=checkpoint_every)
    assert not any("eval_share" in r for r in plain)


@pytest.mark.parametrize("session_type", [_PerEpoch, _Batched])
def test_a_deadline_checkpoints_the_last_epoch_that_ends_before_it(tmp_path, clock, monkeypatch,
                                                                   session_type):
    """Checkpoints 0 and the last only (`checkpoint_every` 100), epochs of 2 s, evaluations of 1 s, saves of
    0 s, from t = 100 (epoch 0 evaluated by 101). With the deadline at 108: after epoch 1 (t = 103) the next
    checkpoint could still come by 103 + 2 + 2·1 = 107; after epoch 2 (t = 106 per epoch, 105 batched) it
    could not (110, 111 with two epochs to evaluate), so epoch 2 is checkpointed. Read from `SF2_DEADLINE`
    as well; without a deadline, none."""
    session = session_type(clock)
    _loop(session, RunFolder(tmp_path / "deadline"), checkpoint_every=100, deadline=108.0)
    assert [x for x in session.log if x.startswith("save")] == ["save 0", "save 2", "save 3"]

    clock.now = 100.0
    monkeypatch.setenv(hostloop.DEADLINE_VARIABLE, "108")
    session = session_type(clock)
    _loop(session, RunFolder(tmp_path / "environment"), checkpoint_every=100)
    assert [x for x in session.log if x.startswith("save")] == ["save 0", "save 2", "save 3"]

    clock.now = 100.0
    monkeypatch.delenv(hostloop.DEADLINE_VARIABLE)
    session = session_type(clock)
    _loop(session, RunFolder(tmp_path / "none"), checkpoint_every=100)
    assert [x for x in session.log if x.startswith("save")] == ["save 0", "save 3"]


@pytest.mark.parametrize("session_type", [_PerEpoch, _Batched])
def test_a_deadline_counts_a_checkpoints_background_write(tmp_path, clock, session_type):
    """The same timings with saves that return at once but write for 2 s more (`write_seconds`): after
    epoch 1 (t = 103) the next checkpoint would be complete only by 103 + 2 + 2·(1 + 2) = 111, past 108, so
    epoch 1 is checkpointed (epoch 2's, the one the save's own 0 s chose, would still be writing at a kill at
    108), and so is every epoch after it."""
    session = session_type(clock)
    session.write_seconds = lambda: 2.0
    _loop(session, RunFolder(tmp_path / "run"), checkpoint_every=100, deadline=108.0)
    assert [x for x in session.log if x.startswith("save")] == ["save 0", "save 1", "save 2", "save 3"]
    clock.now = 100.0
    session = session_type(clock)
    session.write_seconds = lambda: None    # no write measured yet: the save's own time (0 s) as before
    _loop(session, RunFolder(tmp_path / "unmeasured"), checkpoint_every=100, deadline=108.0)
    assert [x for x in session.log if x.startswith("save")] == ["save 0", "save 2", "save 3"]


@pytest.mark.parametrize("session_type", [_PerEpoch, _Batched])
def test_a_resumed_run_prices_its_first_evaluation_from_its_rows(tmp_path, clock, session_type):
    """A run stopped at checkpoint 1 (its rows: epoch 0's evaluation 1 s, epoch 1's 1 s per epoch, or 1.5 s
    batched) resumes at t = 200 with the deadline at 205. Epoch 2 ends at 202: its checkpoint's evaluation
    priced at 0 s (nothing run in this process yet) would put the next checkpoint by 202 + 2 = 204, before
    205, and leave epochs 2 and 3 to a kill at 205 (epoch 3 trains until 205 or later); priced from the rows
    it would come by 202 + 2 + 2·1 = 206 (207 batched), after 205, so epoch 2 is checkpointed."""
    run, first = RunFolder(tmp_path / "run"), session_type(clock)
    _loop(first, run, stop_after_epoch=1, checkpoint_every=100)
    assert first.log[-1] == "save 1"
    clock.now = 200.0
    again = session_type(clock)
    again.policy = 1
    _loop(again, run, 1, checkpoint_every=100, deadline=205.0)
    assert [x for x in again.log if x.startswith("save")] == ["save 2", "save 3"]
    rows = [{"epoch": 0, "eval_seconds": 9.0}, {"epoch": 1, "eval_seconds": 2.0},
            {"epoch": 2, "eval_seconds": 0.5}, {"epoch": 2}]
    assert hostloop._resumed_eval_seconds(rows) == 2.0        # the largest after epoch 0
    assert hostloop._resumed_eval_seconds(rows[:1]) == 9.0    # epoch 0's where no later one has it
    assert hostloop._resumed_eval_seconds([]) == 0.0


def test_a_malformed_deadline_is_refused_naming_the_variable(monkeypatch):
    monkeypatch.setenv(hostloop.DEADLINE_VARIABLE, "soon")
    with pytest.raises(ConfigError, match="SF2_DEADLINE='soon' is invalid: must be a Unix time"):
        hostloop.deadline_from_environment()
    monkeypatch.setenv(hostloop.DEADLINE_VARIABLE, " ")
    assert hostloop.deadline_from_environment() is None


@pytest.mark.parametrize("session_type", [_PerEpoch, _Batched])
def test_the_curve_is_drawn_after_each_checkpoints_rows_and_never_twice(tmp_path, clock, monkeypatch,
                                                                        session_type):
    """Checkpoints at 0, 2 and 3 (two rows, one per seed, an epoch): the per-epoch loop draws after epochs
    1, 2 and 3's rows, the batched one after 2 and 3's; the last holds every row and is not drawn again at
    the end. A rerun of a finished run trains nothing and draws its curve once."""
    drawn = []
    monkeypatch.setattr(hostloop, "write_curve", lambda rows, run, title: drawn.append(len(rows)))
    run = RunFolder(tmp_path / "run")
    _loop(session_type(clock), run, plot=True)
    assert drawn == ([4, 6, 8] if session_type is _PerEpoch else [6, 8])
    drawn.clear()
    assert len(_loop(session_type(clock), run, last=3, plot=True)) == 8
    assert drawn == [8]
