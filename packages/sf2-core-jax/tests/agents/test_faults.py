"""Run-folder faults on real sf2-jax runs (docs/run-folders.md, the fault matrix): each kind of file a
run folder holds truncated, garbled or deleted, and kills in the middle of a save, the in-process one and
a real `kill -9` of the CLI. Each case ends in the documented recovery (rows and state equal to the
uninterrupted run's) or in an error naming the path with the folder unchanged. The resume rule itself is
framework-free and tested once in packages/sf2-common/tests/test_runfolders.py; here: that Orbax's files
map onto it."""

from __future__ import annotations

import re
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sf2_common.agents.checkpoints import CheckpointDamaged
from sf2_common.agents.runfolder import RunFolderError
from sf2_jax import cli
from sf2_jax.agents.checkpoint import Checkpointer
from sf2_jax.agents.trainer import get_program, train
from sf2_testing import (
    FAULTS,
    check_cli_resume,
    check_two_writers,
    cli_args,
    damage,
    folder_digest,
    kill9,
    kill_and_resume,
    strip_wall,
)


def _assert_same_state(a, b):
    for x, y in zip(jax.tree_util.tree_leaves(a.state), jax.tree_util.tree_leaves(b.state), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.fixture(scope="module")
def reference(tiny_cfg, tmp_path_factory):
    """An uninterrupted single-seed run: rows 0-3, checkpoints 2 and 3 (keep_checkpoints = 2)."""
    return train(tiny_cfg, (0,), tmp_path_factory.mktemp("ref"), progress=False)


def _copy(reference, tmp_path):
    return shutil.copytree(reference.run.path, tmp_path / "run")


def _checkpoint_file(folder, kind):
    """The data (the largest file of Orbax's array store) or our JSON metadata item of checkpoint 3."""
    if kind == "data":
        return max((folder / "checkpoints" / "3" / "state" / "d").iterdir(), key=lambda p: p.stat().st_size)
    return folder / "checkpoints" / "3" / "meta" / "metadata"


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("kind", ["data", "metadata"])
def test_each_damaged_checkpoint_file_is_named(reference, tiny_cfg, tmp_path, kind, fault):
    """Every file fault is one `CheckpointDamaged` naming the file (no Orbax reader errors), which the
    resume rule sets aside (test_a_damaged_newest_checkpoint_falls_back_to_the_last_good_one)."""
    shutil.copytree(reference.run.checkpoint_dir, tmp_path / "checkpoints")
    path = _checkpoint_file(tmp_path, kind)
    damage(path, fault)
    ckpt = Checkpointer(tmp_path / "checkpoints")
    try:
        with pytest.raises(CheckpointDamaged) as err:
            ckpt.restore(3, get_program(tiny_cfg).abstract_state((0,)))
    finally:
        ckpt.close()
    name = path.relative_to(tmp_path / "checkpoints" / "3").as_posix()
    assert err.value.epoch == 3 and err.value.reason.startswith(name), err.value


def test_a_damaged_newest_checkpoint_falls_back_to_the_last_good_one(reference, tiny_cfg, tmp_path, capfd):
    out = _copy(reference, tmp_path)
    data = _checkpoint_file(out, "data")
    damage(data, "truncate")
    damaged = folder_digest(out / "checkpoints" / "3")
    resumed = train(tiny_cfg, (0,), out, progress=False, plot=False)
    assert resumed.resumed_from == 2
    assert strip_wall(resumed.run.read_rows()) == strip_wall(reference.rows)
    _assert_same_state(resumed, reference)
    (aside,) = (out / "damaged").iterdir()
    assert folder_digest(aside / "checkpoints" / "3") == damaged          # set aside, not deleted
    assert (aside / "metrics.jsonl").read_text() == (reference.run.metrics_path).read_text()
    err = capfd.readouterr().err
    assert f"checkpoint 3 ({out / 'checkpoints' / '3'}) is damaged: state/d/{data.name} has" in err
    assert f"resuming {out} from checkpoint 2 (epoch 2 of 3, env step 96)" in err
    assert "absl" not in err and "Traceback" not in err


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("name", ["config.json", "metrics.jsonl"])
def test_a_damaged_config_or_metrics_file_is_an_error_and_changes_nothing(reference, tiny_cfg, tmp_path,
                                                                         name, fault):
    out = _copy(reference, tmp_path)
    damage(out / name, fault)
    before = folder_digest(out)
    misses = get_program.cache_info().misses
    with pytest.raises(RunFolderError, match=re.escape(str(out / name) if name == "metrics.jsonl" or
                                                       fault != "delete" else str(out))) as err:
        train(tiny_cfg.replace(hidden_sizes=(8,)), (0,), out, progress=False)  # a config not compiled yet
    assert "Nothing was changed" in str(err.value) or "nothing was changed" in str(err.value)
    assert folder_digest(out) == before
    assert get_program.cache_info().misses == misses                      # refused before compiling


def test_a_background_save_holds_the_state_it_was_given(reference, tiny_cfg, tmp_path):
    """The trainer saves with `wait=False`: Orbax writes the files while the next epoch trains, and that
    epoch's program donates (overwrites) the state's device buffers. The checkpoint must still hold the
    state as it was when saved, and `finish` write its manifest. (On a GPU, Orbax copies the arrays to the
    host before `save` returns; on the CPU its host arrays are views of the buffers, and JAX declines to
    donate a buffer that has a view. Either way the checkpoint is the state that was given.)"""
    from sf2_common.agents import checkpoints

    state = jax.tree_util.tree_map(jnp.copy, reference.state)   # reference's own state stays as it is
    # host copies (a CPU device_get is a view, and a buffer with a view is never donated)
    expected = jax.tree_util.tree_map(lambda x: np.array(x, copy=True), state)
    ckpt = Checkpointer(tmp_path / "checkpoints")
    try:
        ckpt.save(1, state, {"env_steps": 0}, wait=False)
        numeric = [x for x in jax.tree_util.tree_leaves(state) if jnp.issubdtype(x.dtype, jnp.number)]
        overwritten = jax.jit(lambda xs: [x + 1 for x in xs], donate_argnums=0)(numeric)
        jax.block_until_ready(overwritten)
        ckpt.finish()
        assert checkpoints.verify(ckpt.path(1), 1)    # complete, with its manifest
        restored, meta = ckpt.restore(1, get_program(tiny_cfg).abstract_state((0,)))
    finally:
        ckpt.close()
    assert meta["env_steps"] == 0
    for x, y in zip(jax.tree_util.tree_leaves(expected), jax.tree_util.tree_leaves(restored), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_a_background_save_says_how_long_its_whole_write_took(tmp_path, monkeypatch):
    """`write_seconds` times a checkpoint from `save` until its files are complete, a background one's too
    (the deadline of hostloop.checkpoint_now uses it): Orbax made to report its write in progress for 10
    polls of 0.05 s gives at least 0.5 s, though `save` returned at once; a fresh Checkpointer takes its
    restore's time until it has written one."""
    state = {"a": jnp.arange(1000.0), "b": jnp.ones((10, 10), jnp.int32)}
    ckpt = Checkpointer(tmp_path / "checkpoints")
    assert ckpt.write_seconds is None
    in_progress, polls = ckpt.manager.is_saving_in_progress, []
    monkeypatch.setattr(ckpt.manager, "is_saving_in_progress",
                        lambda: polls.append(1) or len(polls) <= 10 or in_progress())
    try:
        ckpt.save(1, state, {"env_steps": 0}, wait=False)
        ckpt.finish()
        assert len(polls) > 10 and ckpt.write_seconds >= 10 * 0.05
    finally:
        ckpt.close()
    fresh = Checkpointer(tmp_path / "checkpoints")
    try:
        restored, _ = fresh.restore(1, state)
        assert fresh.write_seconds is not None and fresh.write_seconds >= 0.0
    finally:
        fresh.close()
    np.testing.assert_array_equal(np.asarray(restored["a"]), np.arange(1000.0))


def test_killed_in_the_middle_of_a_save(reference, tiny_cfg, tmp_path):
    """Orbax had finished checkpoint 2 when the kill came, only its manifest is missing: checkpoint 2
    restores completely (the reader checks it without the manifest), so the run resumes from it."""
    resumed = kill_and_resume(train, tiny_cfg, tmp_path / "killed", "mid-save", 2, 2)
    assert strip_wall(resumed.run.read_rows()) == strip_wall(reference.rows)
    _assert_same_state(resumed, reference)


def test_cli_kill9_during_a_save_then_the_same_command_resumes(reference, tiny_cfg, tmp_path, capfd,
                                                               request):
    """A real SIGKILL of `sf2-jax train` while it saves checkpoint 0; the same command then resumes from
    it, says so without library noise, and a third run says the run is complete and shows the training's
    own wall time."""
    out = tmp_path / "cli"
    cache = getattr(request.config, "cache", None)  # JAX's persistent cache: faster on a second run
    cache = str(cache.mkdir("sf2-jax-compile-cache")) if cache is not None else ""
    args = cli_args(tiny_cfg, out) + ["--compile-cache", cache]
    kill9("sf2_jax.cli", args, ("mid-save", 0))
    check_cli_resume(cli.main, args, out, capfd, "checkpoint 0 (epoch 0 of 3, env step 0)", reference.rows)


@pytest.mark.parametrize("where,expected", [
    ("file", "run folder {file} is a file, not a folder"),
    ("under-file", "run folder {file}/run cannot be created: {file} is a file, not a folder"),
    ("sys", "run folder /sys/sf2-run cannot be created (in /sys): "),
])
def test_cli_unusable_out_is_an_error_before_compiling(tiny_cfg, tmp_path, capsys, where, expected):
    file = tmp_path / "file"
    file.write_text("mine")
    out = {"file": file, "under-file": file / "run", "sys": "/sys/sf2-run"}[where]
    misses = get_program.cache_info().misses
    assert cli.main(cli_args(tiny_cfg.replace(hidden_sizes=(8,)), out)) == 2
    assert expected.format(file=file) in capsys.readouterr().err
    assert file.read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["file"]
    assert get_program.cache_info().misses == misses


def test_cli_eval_of_a_damaged_checkpoint_names_the_file(reference, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SF2_JAX_COMPILE_CACHE", "")  # no persistent cache from inside the tests
    out = _copy(reference, tmp_path)
    damage(out / "checkpoints" / "3" / "meta" / "metadata", "garble")
    assert cli.main(["eval", str(out)]) == 2
    assert f"checkpoint 3 ({out / 'checkpoints' / '3'}) is damaged: meta/metadata does not hold the bytes" \
        in capsys.readouterr().err


def test_two_trains_on_one_folder(reference, tiny_cfg, tmp_path):
    """One writer per run folder: a second `sf2-jax train` on a folder that a train is writing exits with
    status 2 naming it, and the first run's rows, checkpoints and state are the uninterrupted run's."""
    out = tmp_path / "run"
    first = check_two_writers(train, "sf2_jax.cli", tiny_cfg, out, reference.rows)
    _assert_same_state(first, reference)
    again = train(tiny_cfg, (0,), out, progress=False, plot=False)   # checkpoint 3 restores: nothing to train
    assert again.resumed_from == 3
    _assert_same_state(again, reference)
