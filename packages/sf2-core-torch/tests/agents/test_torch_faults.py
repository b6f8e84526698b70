"""Run-folder faults on real sf2-torch runs (docs/run-folders.md, the fault matrix): each kind of file a
run folder holds truncated, garbled or deleted, and a real `kill -9` of the CLI in the middle of a save.
Each case ends in the documented recovery (rows and state equal to the uninterrupted run's) or in an
error naming the path with the folder unchanged. The resume rule itself is framework-free and tested
once in packages/sf2-common/tests/test_runfolders.py; here: that the torch checkpoint's files map onto
it."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest
import torch
from sf2_common.agents.checkpoints import CheckpointDamaged
from sf2_common.agents.runfolder import RunFolderError
from sf2_testing import (
    FAULTS,
    check_cli_resume,
    check_two_writers,
    cli_args,
    damage,
    folder_digest,
    kill9,
    strip_wall,
)
from sf2_torch import cli
from sf2_torch.agents import trainer
from sf2_torch.agents.checkpoint import Checkpointer
from sf2_torch.agents.trainer import train


def _tensors(tree, prefix=""):
    if isinstance(tree, torch.Tensor):
        return {prefix: tree.detach().cpu().numpy()}
    if isinstance(tree, dict):
        items = tree.items()
    else:
        items = enumerate(tree) if isinstance(tree, list | tuple) else ()
    out = {}
    for k, v in items:
        out.update(_tensors(v, f"{prefix}.{k}"))
    return out


def _assert_same_state(a, b):
    """Every tensor of the agents (parameters, targets, Adam states) is equal."""
    sa, sb = _tensors(a.state.agents[0].algo.state_dict()), _tensors(b.state.agents[0].algo.state_dict())
    assert set(sa) == set(sb) and sa
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)


@pytest.fixture(scope="module")
def reference(tiny_cfg, tmp_path_factory):
    """An uninterrupted single-seed run: rows 0-3, checkpoints 2 and 3 (keep_checkpoints = 2)."""
    return train(tiny_cfg, (0,), tmp_path_factory.mktemp("ref"), progress=False)


def _copy(reference, tmp_path):
    return shutil.copytree(reference.run.path, tmp_path / "run")


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("name", [Checkpointer.STATE, Checkpointer.ENV, Checkpointer.META])
def test_each_damaged_checkpoint_file_is_named(reference, tmp_path, name, fault):
    """Every file fault is one `CheckpointDamaged` naming the file, which the resume rule sets aside
    (test_a_damaged_newest_checkpoint_falls_back_to_the_last_good_one)."""
    shutil.copytree(reference.run.checkpoint_dir, tmp_path / "checkpoints")
    damage(tmp_path / "checkpoints" / "3" / name, fault)
    with pytest.raises(CheckpointDamaged) as err:
        Checkpointer(tmp_path / "checkpoints").restore(3)
    assert err.value.epoch == 3 and err.value.reason.startswith(name), err.value


def test_a_background_save_holds_the_state_it_was_given(reference, tiny_cfg, tmp_path):
    """The trainer saves with `wait=False`: a thread writes the files while the next epoch trains, and
    that epoch updates the parameters, Adam states, replay buffer and generator in place. The checkpoint
    must still hold the state as it was when saved (`save` copies it to the host first), and restore it."""
    import copy

    program = trainer.get_program(tiny_cfg)
    state = copy.deepcopy(program.state_dict(reference.state))   # reference's own state stays as it is
    leaves = [np.array(x, copy=True) for x in reference.state.env.get_state_leaves()]
    expected = {k: np.array(v, copy=True) for k, v in _tensors(state).items()}
    ckpt = Checkpointer(tmp_path / "checkpoints")
    try:
        ckpt.save(1, state, leaves, {"env_steps": 0}, wait=False)
        for t in _tensors_of(state):
            t.add_(1) if t.dtype != torch.bool else t.logical_not_()
        for x in leaves:
            x[...] = 0
        ckpt.finish()
        saved, restored_leaves, meta = ckpt.restore(1)
    finally:
        ckpt.close()
    assert meta["env_steps"] == 0 and expected
    got = _tensors(saved)
    assert set(got) == set(expected)
    for k in expected:
        np.testing.assert_array_equal(got[k], expected[k], err_msg=k)
    originals = reference.state.env.get_state_leaves()
    for x, y in zip(originals, restored_leaves, strict=True):
        np.testing.assert_array_equal(np.asarray(x), y)


def test_a_background_save_says_how_long_its_whole_write_took(tmp_path, monkeypatch):
    """`write_seconds` times a checkpoint from `save` until its files are complete, a background one's too
    (the deadline of hostloop.checkpoint_now uses it): a `torch.save` made to take 0.5 s in the writer's
    thread gives at least 0.5 s, though `save` returned before it; a fresh Checkpointer takes its restore's
    time until it has written one."""
    import time

    from sf2_torch.agents import checkpoint

    real = checkpoint.torch.save

    def slow(*args, **kw):
        time.sleep(0.5)
        return real(*args, **kw)

    ckpt = Checkpointer(tmp_path / "checkpoints")
    assert ckpt.write_seconds is None
    monkeypatch.setattr(checkpoint.torch, "save", slow)
    ckpt.save(1, {"x": torch.arange(1000.0)}, [np.ones((10, 10), np.int32)], {"env_steps": 0}, wait=False)
    ckpt.finish()
    monkeypatch.undo()
    assert ckpt.write_seconds >= 0.5
    ckpt.close()
    fresh = Checkpointer(tmp_path / "checkpoints")
    state, leaves, _ = fresh.restore(1)
    assert fresh.write_seconds is not None and fresh.write_seconds >= 0.0
    assert torch.equal(state["x"], torch.arange(1000.0)) and leaves[0].shape == (10, 10)
    fresh.close()


def test_a_background_save_that_fails_raises_in_the_caller(tmp_path):
    """A write that fails in the thread is raised by the next call (`finish` here), not lost."""
    (tmp_path / "taken").write_text("a file where the checkpoint folder should be")
    ckpt = Checkpointer(tmp_path / "taken")
    ckpt.save(1, {"x": torch.zeros(3)}, [np.zeros(2)], {"env_steps": 0}, wait=False)
    with pytest.raises(OSError):
        ckpt.finish()
    ckpt.close()     # the error was raised once; nothing is left to wait for


def _tensors_of(tree):
    if isinstance(tree, torch.Tensor):
        return [tree]
    values = tree.values() if isinstance(tree, dict) else tree if isinstance(tree, list | tuple) else ()
    return [t for v in values for t in _tensors_of(v)]


def test_a_damaged_newest_checkpoint_falls_back_to_the_last_good_one(reference, tiny_cfg, tmp_path, capfd):
    out = _copy(reference, tmp_path)
    damage(out / "checkpoints" / "3" / Checkpointer.STATE, "garble")
    damaged = folder_digest(out / "checkpoints" / "3")
    resumed = train(tiny_cfg, (0,), out, progress=False, plot=False)
    assert resumed.resumed_from == 2
    assert strip_wall(resumed.run.read_rows()) == strip_wall(reference.rows)
    _assert_same_state(resumed, reference)
    (aside,) = (out / "damaged").iterdir()
    assert folder_digest(aside / "checkpoints" / "3") == damaged          # set aside, not deleted
    assert (aside / "metrics.jsonl").read_text() == reference.run.metrics_path.read_text()
    err = capfd.readouterr().err
    assert f"checkpoint 3 ({out / 'checkpoints' / '3'}) is damaged: state.pt does not hold the bytes" in err
    assert f"resuming {out} from checkpoint 2 (epoch 2 of 3, env step 96)" in err


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("name", ["config.json", "metrics.jsonl"])
def test_a_damaged_config_or_metrics_file_is_an_error_and_changes_nothing(reference, tiny_cfg, tmp_path,
                                                                         name, fault):
    out = _copy(reference, tmp_path)
    damage(out / name, fault)
    before = folder_digest(out)
    cfg = tiny_cfg.replace(hidden_sizes=(8,))                             # a config not built yet
    with pytest.raises(RunFolderError, match=re.escape(str(out / name) if name == "metrics.jsonl" or
                                                       fault != "delete" else str(out))) as err:
        train(cfg, (0,), out, progress=False)
    assert "nothing was changed" in str(err.value).lower()
    assert folder_digest(out) == before
    assert cfg not in trainer._PROGRAMS                                   # refused before building it


def test_cli_kill9_during_a_save_then_the_same_command_resumes(reference, tiny_cfg, tmp_path, capfd,
                                                               request):
    """A real SIGKILL of `sf2-torch train` while it saves checkpoint 2 (its files are written into a
    temporary folder, not yet renamed): the same command resumes from checkpoint 1, says so, and its rows
    and state equal the uninterrupted run's; a third run says the run is complete and shows the training's
    own wall time."""
    out = tmp_path / "cli"
    cache = getattr(request.config, "cache", None)  # the conftest's JAX cache: the envs compiled once
    cache = str(cache.mkdir("jax-compile-cache")) if cache is not None else ""
    args = cli_args(tiny_cfg, out) + ["--compile-cache", cache]
    kill9("sf2_torch.cli", args, ("mid-save", 2), env={"OMP_NUM_THREADS": "1"})  # one thread, as here
    left = sorted(p.name for p in (out / "checkpoints").iterdir())
    assert left[1:] == ["0", "1"] and re.fullmatch(r"\.2\.tmp-\d+", left[0]), left  # 2: files, no rename
    check_cli_resume(cli.main, args, out, capfd, "checkpoint 1 (epoch 1 of 3, env step 48)", reference.rows)
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["2", "3"]  # the partial save is gone


@pytest.mark.parametrize("where,expected", [
    ("file", "run folder {file} is a file, not a folder"),
    ("under-file", "run folder {file}/run cannot be created: {file} is a file, not a folder"),
    ("sys", "run folder /sys/sf2-run cannot be created (in /sys): "),
])
def test_cli_unusable_out_is_an_error_before_building(tiny_cfg, tmp_path, capsys, where, expected):
    file = tmp_path / "file"
    file.write_text("mine")
    out = {"file": file, "under-file": file / "run", "sys": "/sys/sf2-run"}[where]
    programs = dict(trainer._PROGRAMS)
    assert cli.main(cli_args(tiny_cfg.replace(hidden_sizes=(8,)), out)) == 2
    assert expected.format(file=file) in capsys.readouterr().err
    assert file.read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["file"]
    assert trainer._PROGRAMS == programs


def test_cli_eval_of_a_damaged_checkpoint_names_the_file(reference, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SF2_TORCH_COMPILE_CACHE", "")  # keep the conftest's JAX cache folder
    out = _copy(reference, tmp_path)
    damage(out / "checkpoints" / "3" / Checkpointer.ENV, "truncate")
    assert cli.main(["eval", str(out)]) == 2
    assert f"checkpoint 3 ({out / 'checkpoints' / '3'}) is damaged: env.npz has" in capsys.readouterr().err


def test_two_trains_on_one_folder(reference, tiny_cfg, tmp_path):
    """One writer per run folder: a second `sf2-torch train` on a folder that a train is writing exits with
    status 2 naming it, and the first run's rows, checkpoints and state are the uninterrupted run's."""
    out = tmp_path / "run"
    first = check_two_writers(train, "sf2_torch.cli", tiny_cfg, out, reference.rows)
    _assert_same_state(first, reference)
    again = train(tiny_cfg, (0,), out, progress=False, plot=False)   # checkpoint 3 restores: nothing to train
    assert again.resumed_from == 3
    _assert_same_state(again, reference)
