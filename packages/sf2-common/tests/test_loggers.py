"""`--log tensorboard,wandb` (sf2_common.agents.loggers): what each sink holds, read back with TensorBoard's
event reader and from W&B's offline run files, equals metrics.jsonl (TensorBoard keeps float32), across a
stop and resume and a kill between an epoch's rows and its checkpoint: no step twice, the same runs; bad
input and missing packages are exit status 2 before anything trains."""

from __future__ import annotations

import json
import struct
import time

import numpy as np
import pytest
from sf2_common import cli
from sf2_common.agents import configs, hostloop, loggers
from sf2_common.agents.runfolder import RunFolder
from sf2_common.errors import ConfigError

SEEDS = (3, 4)


class _Session:
    """Two seeds; epoch e trains "loss" = e + seed index / 4 and evaluates to 10·e + seed index."""

    def start(self):
        pass

    def train_epoch(self, epoch):
        loss = float(epoch) + np.arange(2) / 4
        return {"sgd_steps": np.full(2, 4), "loss": loss}, {"loss": np.full(2, -1)}

    def evaluate(self, epoch):
        return np.full((2, 3), 10.0 * epoch) + np.arange(2)[:, None]

    def save(self, epoch, env_steps):
        pass

    def loss_order(self):
        return ("loss",)

    def finish(self):
        pass


def _loop(run, last, log, **kw):
    """3 epochs of 32 env steps, checkpoints 0, 2, 3; resumed after checkpoint `last` (None: new)."""
    cfg = configs.TrainConfig(num_timesteps=96, num_envs=4, num_evals=4, min_replay_size=4,
                              checkpoint_every=2)
    rows = run.truncate_rows(-1 if last is None else last)
    if last is None:
        run.write_config({"config": cfg.to_dict(), "seeds": list(SEEDS)})
    return hostloop.run_epochs(_Session(), cfg=cfg, sched=configs.schedule(cfg), seeds=SEEDS, run=run,
                               title="t", rows=rows, start=0 if last is None else last + 1, last=last,
                               progress=False, plot=False, log=log, **kw)


def _tensorboard(run, seed) -> dict:
    """{step: {tag: value}} of RUN/tensorboard/seed<S>/, by TensorBoard's reader; a step twice fails."""
    from tensorboard.backend.event_processing import event_accumulator as ea

    acc = ea.EventAccumulator(str(run.path / "tensorboard" / f"seed{seed}"), size_guidance={ea.SCALARS: 0})
    acc.Reload()
    out: dict = {}
    for tag in acc.Tags()["scalars"]:
        for event in acc.Scalars(tag):
            assert tag not in out.setdefault(event.step, {}), f"step {event.step} of {tag} twice"
            out[event.step][tag] = event.value
    return out


def _wandb_records(path):
    """The records of a W&B offline run file (LevelDB log format: 7-byte file header, 32 KiB blocks,
    each chunk a 7-byte header of CRC, length, type: 1 full, 2 first, 3 middle, 4 last)."""
    from wandb.proto import wandb_internal_pb2 as pb

    data, pos, chunks = path.read_bytes(), 7, b""
    while pos + 7 <= len(data):
        left = 32768 - pos % 32768
        _, n, kind = struct.unpack("<IHB", data[pos:pos + 7]) if left >= 7 else (0, 0, 0)
        if kind == 0:
            pos += left
            continue
        if pos + 7 + n > len(data):   # a chunk still being written
            return
        chunks, pos = chunks + data[pos + 7:pos + 7 + n], pos + 7 + n
        if kind in (1, 4):
            record = pb.Record()
            record.ParseFromString(chunks)
            yield record
            chunks = b""


def _wandb(run, seed):
    """({step: {key: value}}, the run ids of its sessions) of seed `seed`'s W&B runs in RUN/wandb/."""
    run_id = json.loads((run.path / loggers.RECORD).read_text())["wandb_ids"][str(seed)]
    history, ids = {}, []
    for path in run.path.glob(f"wandb/offline-run-*-{run_id}*/run-{run_id}.wandb"):   # "-1": same second
        records = list(_wandb_records(path))
        for _ in range(100):   # W&B's service may still be writing the file after `finish()` returned
            if records and records[-1].WhichOneof("record_type") == "exit":
                break
            time.sleep(0.1)
            records = list(_wandb_records(path))
        for r in records:
            if r.WhichOneof("record_type") == "run":
                ids.append(r.run.run_id)
            elif r.WhichOneof("record_type") == "history":
                item = {i.key or "/".join(i.nested_key): json.loads(i.value_json) for i in r.history.item}
                item = {k: v for k, v in item.items() if not k.startswith("_")}   # W&B's own: _step, ...
                assert r.history.step.num not in history, f"step {r.history.step.num} twice"
                history[r.history.step.num] = item
    return history, ids


def _expected(run, seed, float32=False):
    """{env step: {name: value}} of metrics.jsonl's rows of `seed` (`loggers.scalars`)."""
    cast = (lambda v: float(np.float32(v))) if float32 else float
    return {r["env_steps"]: {k: cast(v) for k, v in loggers.scalars(r).items()}
            for r in run.read_rows() if r["seed"] == seed}


@pytest.fixture
def wandb_home(tmp_path, monkeypatch):
    """W&B's own folders in tmp_path, WANDB_MODE unset (the sink's default: offline, no network)."""
    pytest.importorskip("wandb", reason="the [wandb] extra: pip install \"packages/sf2-common[wandb]\"")
    pytest.importorskip("tensorboard", reason="the [tensorboard] extra")
    for name in ("WANDB_CONFIG_DIR", "WANDB_CACHE_DIR", "WANDB_DATA_DIR"):
        monkeypatch.setenv(name, str(tmp_path / "wandb-home"))
    for name in ("WANDB_MODE", "WANDB_PROJECT", "WANDB_API_KEY"):
        monkeypatch.delenv(name, raising=False)


def test_sinks_equal_metrics_jsonl_across_a_resume_and_a_kill(tmp_path, wandb_home):
    """Stop after checkpoint 1 (`stop_after_epoch`), resume; a kill between epoch 3's rows and its
    checkpoint, resume from checkpoint 2 (epoch 3 trained again): each sink holds every env step once and
    the values of metrics.jsonl, and each seed has one W&B run id in all three sessions."""
    run = RunFolder(tmp_path / "run")
    both = "tensorboard,wandb"
    _loop(run, None, both, stop_after_epoch=1)

    def kill(event, epoch):
        if (event, epoch) == ("save", 3):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _loop(run, 1, both, hook=kill)
    assert json.loads((run.path / loggers.RECORD).read_text())["logged_epoch"] == {"tensorboard": 3,
                                                                                  "wandb": 3}
    first = {s: _tensorboard(run, s)[96] for s in SEEDS}      # epoch 3 as the killed session logged it
    rows = _loop(run, 2, ("wandb", "tensorboard"))
    assert [(r["epoch"], r["seed"]) for r in rows] == [(e, s) for e in range(4) for s in SEEDS]
    for i, seed in enumerate(SEEDS):
        tb, (wb, ids) = _tensorboard(run, seed), _wandb(run, seed)
        assert sorted(tb) == sorted(wb) == [0, 32, 64, 96]
        assert tb[64]["eval_return"] == 20.0 + i and wb[64]["loss"] == 2.0 + i / 4
        want, want32 = _expected(run, seed), _expected(run, seed, float32=True)
        # epoch 3 is not logged again: its wall times are the killed session's, the rest equal
        assert tb[96] == first[seed]
        for step in want:
            same = hostloop.WALL_FIELDS if step == 96 else ()
            assert {k: v for k, v in tb[step].items() if k not in same} == \
                {k: v for k, v in want32[step].items() if k not in same}
            assert {k: v for k, v in wb[step].items() if k not in same} == \
                {k: v for k, v in want[step].items() if k not in same}
        assert len(ids) == 3 and set(ids) == {ids[0]}, ids
    assert sorted(p.name for p in (run.path / "tensorboard").iterdir()) == ["seed3", "seed4"]

    assert set(run.clear(say=lambda m: None)) >= {"loggers.json", "tensorboard", "wandb"}   # --fresh


def test_a_sink_first_used_on_a_resume_logs_the_earlier_rows(tmp_path, wandb_home):
    run = RunFolder(tmp_path / "run")
    _loop(run, None, None, stop_after_epoch=2)
    assert not (run.path / "tensorboard").exists() and not (run.path / loggers.RECORD).exists()
    _loop(run, 2, "tensorboard")
    for seed in SEEDS:
        assert _tensorboard(run, seed) == _expected(run, seed, float32=True)
    (run.path / loggers.RECORD).write_text('{"logged_epoch": {"tenso')      # damaged: refused, not guessed
    with pytest.raises(ConfigError, match="loggers.json is not a loggers record .*Delete it with"):
        loggers.Sinks("tensorboard", run, SEEDS, None, [])


def test_wandb_that_cannot_start_is_a_config_error(tmp_path, wandb_home, monkeypatch):
    run = RunFolder(tmp_path / "run")
    monkeypatch.setenv("WANDB_MODE", "onlin")
    with pytest.raises(ConfigError, match="W&B cannot start the run of seed 3 with WANDB_MODE=onlin "
                       ".*unset WANDB_MODE to log offline"):
        _loop(run, None, "tensorboard,wandb")
    assert not (run.path / loggers.RECORD).exists() and run.read_rows() == []


def test_bad_or_missing_logger_is_exit_status_2_before_training(tmp_path, monkeypatch, capsys):
    parser, sub = cli.new_parser("sf2-x", "A test program.")
    cli.add_train_parser(sub, "sf2-x", configs.TrainConfig, "one after the other", "SF2_X_CACHE")
    trained = []

    def train(args):
        cfg = configs.TrainConfig(task="CartpoleBalance")
        return cli.train_runs(args, [cfg], (0,), lambda *a, **k: trained.append(k), lambda *a: "X")

    assert loggers.parse_log(None) == loggers.parse_log(" ,") == ()
    assert loggers.parse_log(["wandb", "tensorboard", "wandb"]) == ("wandb", "tensorboard")
    argv = ["train", "--task", "CartpoleBalance", "--out", str(tmp_path / "r"), "--log"]
    assert cli.run("sf2-x", parser, {"train": train}, lambda: None, argv + ["mlflow,tensorboard"]) == 2
    assert capsys.readouterr().err == ("sf2-x train: error: --log 'mlflow' is not a logger; choose from "
                                       "tensorboard, wandb (comma-separated for both)\n")
    monkeypatch.setattr(loggers.importlib.util, "find_spec", lambda name: None)
    assert cli.run("sf2-x", parser, {"train": train}, lambda: None, argv + ["wandb"]) == 2
    assert capsys.readouterr().err == ("sf2-x train: error: --log wandb needs the package wandb, which is "
                                       "not installed: pip install \"packages/sf2-common[wandb]\" (from the "
                                       "repository root)\n")
    assert trained == [] and not (tmp_path / "r").exists()
    with pytest.raises(ConfigError, match="needs the package tensorboard"):   # the API checks the same
        loggers.parse_log(("tensorboard",))
