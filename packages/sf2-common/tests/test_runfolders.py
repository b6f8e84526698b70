"""Run folders that survive faults, without a framework (docs/run-folders.md): unusable paths and damaged
files are errors naming the path with the folder unchanged; the resume rule (newest checkpoint that
restores completely; damaged ones set aside with the rows they invalidate) on a stand-in checkpointer
whose checkpoints are folders of files with the same manifest the cores write; library noise goes to
train.log."""

from __future__ import annotations

import gc
import json
import logging
import os
import sys
from pathlib import Path

import pytest
from sf2_common.agents import checkpoints
from sf2_common.agents.checkpoints import CheckpointDamaged, CheckpointMismatch
from sf2_common.agents.configs import TrainConfig, schedule
from sf2_common.agents.resume import resume_run
from sf2_common.agents.runfolder import RunFolder, RunFolderError, RunFolderMismatch
from sf2_common.agents.runlog import library_log
from sf2_testing import FAULTS, damage, folder_digest

SEEDS = (0, 1)
# 3 epochs (96 env steps / 4 envs over num_evals − 1 = 3 epochs)
SCHED = schedule(TrainConfig(num_timesteps=96, num_envs=4, num_evals=4, min_replay_size=4))


class _Checkpointer:
    """Checkpoints as the cores lay them out: checkpoints/<epoch>/ holding files and the manifest."""

    def __init__(self, directory):
        self.directory = Path(directory)

    def path(self, epoch):
        return self.directory / str(epoch)

    def all(self):
        return RunFolder(self.directory.parent).checkpoint_epochs()

    def save(self, epoch):
        folder = self.path(epoch)
        (folder / "state").mkdir(parents=True)
        (folder / "state" / "data.bin").write_bytes(bytes(range(256)) * (epoch + 1))
        (folder / "meta.json").write_text(json.dumps({"epoch": epoch}))
        checkpoints.write_manifest(folder)

    def restore(self, epoch):
        checkpoints.verify(self.path(epoch), epoch)
        return f"state of epoch {epoch}"


def _rows(last_epoch):
    return [{"epoch": e, "seed": s, "env_steps": 32 * e, "eval_return": float(e), "walltime": 10.0 * e}
            for e in range(last_epoch + 1) for s in SEEDS]


def _run_folder(path, epochs=(2, 3), rows=3) -> tuple[RunFolder, _Checkpointer]:
    """A run folder as a run that wrote rows up to epoch `rows` and kept checkpoints `epochs` leaves it."""
    run = RunFolder(path)
    run.write_config({"config": {"a": 1}, "seeds": list(SEEDS)})
    run.append_rows(_rows(rows))
    ckpt = _Checkpointer(run.checkpoint_dir)
    for e in epochs:
        ckpt.save(e)
    run.final_dir.mkdir()
    return run, ckpt


def _resume(run, ckpt, **kw):
    return resume_run(run, ckpt, ckpt.restore, seeds=SEEDS, sched=SCHED, existing=True, **kw)


# ------------------------------------------------------------------------------------------- --out
def test_unusable_paths_are_errors_naming_the_path(tmp_path):
    file = tmp_path / "file"
    file.write_text("mine")
    with pytest.raises(RunFolderError, match=f"run folder {file} is a file, not a folder"):
        RunFolder(file).check_usable()
    with pytest.raises(RunFolderError, match=f"run folder {file}/run cannot be created: {file} is a file"):
        RunFolder(file / "run").check_usable()
    assert file.read_text() == "mine" and sorted(os.listdir(tmp_path)) == ["file"]
    RunFolder(tmp_path / "new" / "deeper").check_usable()  # creatable: nothing is created yet
    assert sorted(os.listdir(tmp_path)) == ["file"]


@pytest.mark.skipif(not Path("/sys/kernel").is_dir(), reason="needs Linux's /sys (unwritable, even by root)")
def test_a_location_that_cannot_be_written_is_an_error():
    with pytest.raises(RunFolderError, match="run folder /sys/sf2-run cannot be created \\(in /sys\\): "):
        RunFolder("/sys/sf2-run").check_usable()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders (the /sys case runs)")
def test_a_read_only_folder_is_an_error(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    with pytest.raises(RunFolderError, match="cannot be written: Permission denied"):
        RunFolder(ro).check_usable()


# ------------------------------------------------------------------------------------------- config, metrics
@pytest.mark.parametrize("fault", FAULTS)
def test_a_damaged_config_is_an_error_and_changes_nothing(tmp_path, fault):
    run, _ = _run_folder(tmp_path / "run")
    damage(run.config_path, fault)
    before = folder_digest(run.path)
    expected = {"truncate": f"{run.config_path} is not valid JSON",
                "garble": f"{run.config_path} is not valid JSON",
                "delete": f"{run.path} holds a run's files \\(metrics.jsonl, checkpoints, final\\) but no "
                          f"config.json"}[fault]
    with pytest.raises(RunFolderError, match=expected) as err:
        run.check_compatible({"a": 1}, SEEDS)
    assert "nothing was changed" in str(err.value) and "--fresh" in str(err.value)
    assert folder_digest(run.path) == before


@pytest.mark.parametrize("text,expected", [("", "is empty"), ("[1, 2]", "is not a run's config"),
                                           ('{"config": {}}', "is not a run's config")])
def test_a_config_that_is_not_a_runs_is_an_error(tmp_path, text, expected):
    run = RunFolder(tmp_path)
    run.config_path.write_text(text)
    with pytest.raises(RunFolderError, match=expected):
        run.read_config()


@pytest.mark.parametrize("old,new", [('"task": "CartpoleBalance"', '"task": "CartpoleBalancf"'),
                                     ('"hidden_sizes"', '"hidden_s;zes"'), ('"seeds"', '"seedx"')])
def test_a_config_damaged_into_other_valid_json_is_an_error_and_changes_nothing(tmp_path, old, new):
    """A byte flipped inside a name or a string leaves valid JSON (as `damage`'s garble did on a GPU host,
    whose config.json names its GPU): the checksum written with config.json names it damaged, not "a
    different run", and nothing changes; a config.json from before checksums (none in it) still reads."""
    run, _ = _run_folder(tmp_path / "run")
    conf = {"config": TrainConfig(task="CartpoleBalance").to_dict(), "seeds": list(SEEDS), "hardware": "GPU"}
    run.write_config(conf)
    assert run.read_config() == json.loads(json.dumps(conf))
    text = run.config_path.read_text()
    assert text.count(old) == 1 and json.loads(text.replace(old, new))      # still valid JSON
    run.config_path.write_text(text.replace(old, new))
    before = folder_digest(run.path)
    with pytest.raises(RunFolderError, match=f"{run.config_path} is damaged: its content does not match the "
                                             f"sha256 checksum") as err:
        run.check_compatible(conf["config"], SEEDS)
    assert "nothing was changed" in str(err.value) and "--fresh" in str(err.value)
    assert folder_digest(run.path) == before
    unsummed = {k: v for k, v in json.loads(text).items() if k != "sha256"}
    run.config_path.write_text(json.dumps(unsummed))
    assert run.read_config() == unsummed and run.check_compatible(conf["config"], SEEDS)


@pytest.mark.parametrize("fault", FAULTS)
def test_damaged_metrics_are_an_error_and_change_nothing(tmp_path, fault):
    run, _ = _run_folder(tmp_path / "run")
    damage(run.metrics_path, fault)
    before = folder_digest(run.path)
    # 8 rows of equal length: half keeps epochs 0-1 (the oldest checkpoint, 2, needs 0-2); the garbled
    # bytes, a third of the way in, hit line 3
    expected = {"truncate": "metrics.jsonl lacks the rows of epoch 2, which checkpoint 2 was written after",
                "garble": "metrics.jsonl line 3 is not a metrics row",
                "delete": "metrics.jsonl is missing, which checkpoint 2 was written after"}[fault]
    with pytest.raises(RunFolderError, match=expected):
        run.check_compatible({"a": 1}, SEEDS)
    assert folder_digest(run.path) == before


def test_damage_inside_a_key_is_an_error_though_the_row_is_json(tmp_path):
    """Bytes flipped (`damage`'s XOR 0x5A) across a key's closing quote and the value after it can leave
    valid JSON with one odd key in place of a metric: still damage, and said as such."""
    run, _ = _run_folder(tmp_path / "run")
    lines = run.metrics_path.read_text().splitlines()
    lines[4] = lines[4].replace('"eval_return": 2.0', '"eval_return' + "".join(
        chr(ord(c) ^ 0x5A) for c in '": 2.0') + '": 2.0')
    assert "eval_returnx`z" in lines[4] and json.loads(lines[4])
    run.metrics_path.write_text("\n".join(lines) + "\n")
    before = folder_digest(run.path)
    with pytest.raises(RunFolderError, match="metrics.jsonl line 5 is not a metrics row .a key that is no "
                                             "metric name: 'eval_returnx`zhtj'."):
        run.check_compatible({"a": 1}, SEEDS)
    assert folder_digest(run.path) == before
    assert len(run.read_rows()) == len(_rows(3)) - 1     # read leniently, the row is left out


def test_a_torn_last_row_is_a_kill_not_damage(tmp_path):
    run, _ = _run_folder(tmp_path / "run")
    with open(run.metrics_path, "a") as f:
        f.write('{"epoch": 4, "se')
    assert run.check_compatible({"a": 1}, SEEDS) is True
    assert run.read_rows(strict=True) == _rows(3)


def test_fresh_says_what_it_discards_and_keeps_other_files(tmp_path, capsys):
    run, _ = _run_folder(tmp_path / "run")
    (run.path / "notes.txt").write_text("mine")
    assert run.clear() == ["config.json", "metrics.jsonl", "checkpoints", "final"]
    err = capsys.readouterr().err
    assert "--fresh: discarding config.json, metrics.jsonl (8 rows), checkpoints (2, 3), final in" in err
    assert sorted(os.listdir(run.path)) == ["notes.txt"]


# ------------------------------------------------------------------------------------------- manifest
@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("name", ["state/data.bin", "meta.json", checkpoints.MANIFEST])
def test_the_manifest_names_the_damaged_file(tmp_path, name, fault):
    ckpt = _Checkpointer(tmp_path / "checkpoints")
    ckpt.save(3)
    assert checkpoints.verify(ckpt.path(3), 3) is True
    damage(ckpt.path(3) / name, fault)
    if name == checkpoints.MANIFEST and fault == "delete":
        assert checkpoints.verify(ckpt.path(3), 3) is False  # an older checkpoint: the framework decides
        return
    expected = (f"its file list {checkpoints.MANIFEST} is unreadable" if name == checkpoints.MANIFEST else
                {"truncate": f"{name} has \\d+ bytes, \\d+ were written \\(truncated\\)",
                 "garble": f"{name} does not hold the bytes that were written",
                 "delete": f"{name} is missing"}[fault])
    with pytest.raises(CheckpointDamaged, match=f"checkpoint 3 \\({ckpt.path(3)}\\) is damaged: {expected}"):
        checkpoints.verify(ckpt.path(3), 3)


# ------------------------------------------------------------------------------------------- resume rule
def test_a_damaged_newest_checkpoint_is_set_aside_and_its_rows_dropped(tmp_path, capsys):
    run, ckpt = _run_folder(tmp_path / "run")
    damage(ckpt.path(3) / "state" / "data.bin", "truncate")
    metrics_before = run.metrics_path.read_bytes()
    damaged_files = folder_digest(ckpt.path(3))
    res = _resume(run, ckpt)
    assert (res.epoch, res.restored, res.start, res.walltime) == (2, "state of epoch 2", 3, 20.0)
    assert res.rows == _rows(2) == run.read_rows()        # epoch 3's rows are written again by the run
    assert ckpt.all() == [2]
    assert folder_digest(res.set_aside / "checkpoints" / "3") == damaged_files   # moved, not deleted
    assert (res.set_aside / "metrics.jsonl").read_bytes() == metrics_before
    assert res.set_aside.parent == run.damaged_dir
    reasons = (res.set_aside / "reasons.txt").read_text()
    assert "checkpoint 3" in reasons and "state/data.bin has" in reasons
    assert "resumed from checkpoint 2" in reasons
    err = capsys.readouterr().err
    # data.bin of checkpoint 3 holds 4 · 256 bytes, truncated to half
    assert f"checkpoint 3 ({ckpt.path(3)}) is damaged: state/data.bin has 512 bytes, 1024 were written" in err
    assert f"resuming {run.path} from checkpoint 2 (epoch 2 of 3, env step 64)" in err
    assert "resuming" in run.log_path.read_text()


def test_a_recovery_interrupted_midway_ends_the_same(tmp_path, monkeypatch):
    """A kill between setting aside and rewriting metrics.jsonl: the next resume reaches the same end."""
    run, ckpt = _run_folder(tmp_path / "run")
    damage(ckpt.path(3) / "meta.json", "garble")

    def killed(self, last_epoch):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(RunFolder, "truncate_rows", killed)
        with pytest.raises(KeyboardInterrupt):
            _resume(run, ckpt)
    assert ckpt.all() == [2] and run.read_rows() == _rows(3)
    res = _resume(run, ckpt)
    assert res.epoch == 2 and run.read_rows() == _rows(2)


def test_no_checkpoint_that_restores_is_an_error_and_changes_nothing(tmp_path):
    run, ckpt = _run_folder(tmp_path / "run")
    damage(ckpt.path(3) / "meta.json", "delete")
    damage(ckpt.path(2) / "state" / "data.bin", "garble")
    before = folder_digest(run.path)
    with pytest.raises(RunFolderError, match="cannot be resumed: no checkpoint restores \\(checkpoint 3: "
                       "meta.json is missing; checkpoint 2: state/data.bin does not hold.*rows of epochs up "
                       "to 3. Nothing was changed; pass --fresh"):
        _resume(run, ckpt)
    assert folder_digest(run.path) == before
    # checkpoints/ deleted by hand: the same refusal, never a silent start from scratch
    run2, ckpt2 = _run_folder(tmp_path / "run2", epochs=())
    with pytest.raises(RunFolderError, match="no checkpoint restores \\(.*checkpoints holds none\\)"):
        _resume(run2, ckpt2)


def test_rows_a_checkpoint_needs_are_checked_before_anything_changes(tmp_path):
    run, ckpt = _run_folder(tmp_path / "run", rows=1)
    damage(ckpt.path(3) / "meta.json", "truncate")
    before = folder_digest(run.path)
    with pytest.raises(RunFolderError, match="metrics.jsonl lacks the rows of epoch 2, which checkpoint 2"):
        _resume(run, ckpt)
    assert folder_digest(run.path) == before


def test_a_mismatch_is_never_worked_around(tmp_path):
    run, ckpt = _run_folder(tmp_path / "run")
    before = folder_digest(run.path)

    def restore(epoch):
        raise CheckpointMismatch(f"checkpoint {epoch} has 7 arrays, this program has 9")

    with pytest.raises(CheckpointMismatch, match="checkpoint 3 has 7 arrays"):
        resume_run(run, ckpt, restore, seeds=SEEDS, sched=SCHED, existing=True)
    assert folder_digest(run.path) == before


def test_complete_runs_resume_nothing_and_kills_before_the_first_checkpoint_start_over(tmp_path, capsys):
    run, ckpt = _run_folder(tmp_path / "done")
    res = _resume(run, ckpt)
    assert (res.epoch, res.start, res.set_aside) == (3, 4, None) and res.rows == _rows(3)
    assert "the run is complete (epoch 3 of 3, 96 env steps, trained in 30 s); nothing to train" in \
        capsys.readouterr().err
    with pytest.raises(RunFolderMismatch, match="already holds checkpoints; pass --fresh"):
        _resume(run, ckpt, resume=False)
    early, ckpt0 = _run_folder(tmp_path / "early", epochs=(), rows=0)  # killed after rows 0, before save 0
    res = _resume(early, ckpt0)
    assert (res.epoch, res.start, res.rows) == (None, 0, []) and early.read_rows() == []


# ------------------------------------------------------------------------------------------- train.log
class _RaisesOnDel:
    def __del__(self):
        raise RuntimeError("Event loop is closed")


def test_library_noise_goes_to_the_run_log(tmp_path, capfd):
    run = RunFolder(tmp_path)
    hook = sys.unraisablehook
    with library_log(run):
        logging.getLogger("absl").warning("Waiting for previous save to complete took 1.2 seconds.")
        _RaisesOnDel()
        gc.collect()
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    log = run.log_path.read_text()
    assert "absl WARNING: Waiting for previous save" in log and "RuntimeError: Event loop is closed" in log
    assert sys.unraisablehook is hook and logging.getLogger("absl").propagate


@pytest.fixture
def cheetah_only(monkeypatch):
    """The task table without Playground (not installed in this package's tests): CheetahRun alone."""
    from sf2_common.agents import tasks

    monkeypatch.setattr(tasks, "playground_tasks", lambda: {"CheetahRun": "playground"})


def test_the_paper_preset_gives_each_family_its_authors_adam_eps(cheetah_only):
    from sf2_common.agents.configs import make_config

    assert make_config("paper", "CheetahRun", "td3", "sf2").adam_eps == 1e-5
    assert make_config("paper", "CheetahRun", "sac", "sf2").adam_eps == 1e-8
    assert make_config("paper", "CheetahRun", "sac", "none").adam_eps == 1e-8
    assert make_config("quick", "CheetahRun", "sac", "sf2").adam_eps == 1e-5   # the quick preset is ours


def test_a_folder_trained_with_a_superseded_preset_value_keeps_it(tmp_path, capsys, cheetah_only):
    from sf2_common.agents.configs import make_config

    now = make_config("paper", "CheetahRun", "sac", "sf2")
    before = now.replace(adam_eps=1e-5)   # what the paper preset gave SAC when the folder was written
    run = RunFolder(tmp_path / "run")
    run.write_config({"config": before.to_dict(), "seeds": [0]})
    capsys.readouterr()
    kept = run.keep_trained_values(now)
    assert kept == before
    assert "adam_eps = 1e-05 (the preset now gives 1e-08)" in capsys.readouterr().err
    assert run.check_compatible(now.to_dict(), (0,)) is True    # a study's check of the folder passes too
    with pytest.raises(RunFolderMismatch, match="adam_eps: 1e-05 .folder. vs 1e-08 .now."):   # not the same
        run.check_compatible(now.to_dict(), (0,), exact=True)                            # config, exactly
    # any other value is another run, and so is TD3's ε in a TD3 folder changed by hand
    with pytest.raises(RunFolderMismatch, match="adam_eps: 1e-05 .folder. vs 0.001 .now."):
        run.check_compatible(now.replace(adam_eps=1e-3).to_dict(), (0,))
    assert run.keep_trained_values(now.replace(adam_eps=1e-3)).adam_eps == 1e-3
    td3 = RunFolder(tmp_path / "td3")
    td3.write_config({"config": before.replace(algo="td3").to_dict(), "seeds": [0]})
    with pytest.raises(RunFolderMismatch, match="adam_eps"):
        td3.check_compatible(now.replace(algo="td3").to_dict(), (0,))
    assert RunFolder(tmp_path / "new").keep_trained_values(now) == now


def test_a_folder_from_before_the_physics_field_trained_on_mjx(tmp_path, cheetah_only):
    """Every run before `physics` existed trained on MJX: an old CRL folder is another run for the presets'
    spring and resumes with `physics = "mjx"`; an old TD3 (or MinAtar PPO) folder resumes as before."""
    from sf2_common.agents.configs import make_config

    for preset in ("paper", "quick"):
        crl = make_config(preset, "ant-goal", "crl", "none")
        run = RunFolder(tmp_path / preset / "crl")
        run.write_config({"config": {k: v for k, v in crl.to_dict().items() if k != "physics"}, "seeds": [0]})
        with pytest.raises(RunFolderMismatch, match="differences: physics: 'mjx' .folder. vs 'spring' .now.. "
                           "Use another --out"):
            run.check_compatible(crl.to_dict(), (0,))
        assert run.check_compatible(crl.replace(physics="mjx").to_dict(), (0,)) is True
        for task, algo in (("CheetahRun", "td3"), ("minatar-breakout", "ppo")):
            now = make_config(preset, task, algo, "none")
            old = RunFolder(tmp_path / preset / algo)
            old.write_config({"config": {k: v for k, v in now.to_dict().items() if k != "physics"},
                              "seeds": [0]})
            assert old.check_compatible(now.to_dict(), (0,)) is True
            assert old.keep_trained_values(now) == now


def test_an_fpo_folder_trained_with_rollout_time_advantages_keeps_them(tmp_path, capsys, cheetah_only):
    """FPO's `paper` preset refreshes its advantages at every pass; a folder that trained with the
    rollout-time critic resumes with it, and `quick` (ours) keeps the rollout-time scheme."""
    from sf2_common.agents.configs import make_config

    now = make_config("paper", "CheetahRun", "fpo", "none", {"critic": "v"})
    assert now.advantage_refresh == "pass"
    assert make_config("quick", "CheetahRun", "fpo", "none").advantage_refresh == "rollout"
    assert make_config("paper", "minatar-breakout", "ppo", "none").advantage_refresh == "rollout"
    before = now.replace(advantage_refresh="rollout")
    run = RunFolder(tmp_path / "run")
    run.write_config({"config": before.to_dict(), "seeds": [0]})
    capsys.readouterr()
    assert run.keep_trained_values(now) == before
    assert "advantage_refresh = 'rollout' (the preset now gives 'pass')" in capsys.readouterr().err
    assert run.check_compatible(now.to_dict(), (0,)) is True


def test_a_crl_sf2_folder_trained_with_the_wide_zeta_keeps_it(tmp_path, capsys, cheetah_only):
    """The `paper` preset's CRL+SF² narrowed ζ to (128, 64): a folder trained at 256 × 256 (its config.json
    holds a list) resumes with the tuple (256, 256), the config it was trained with, and passes a study's
    check; a folder of another width is another run."""
    from sf2_common.agents.configs import make_config

    now = make_config("paper", "ant-goal", "crl", "sf2")
    before = now.replace(zeta_hidden_sizes=(256, 256))
    run = RunFolder(tmp_path / "run")
    run.write_config({"config": before.to_dict(), "seeds": [0]})
    capsys.readouterr()
    kept = run.keep_trained_values(now)
    assert kept == before and kept.zeta_hidden_sizes == (256, 256)
    assert "zeta_hidden_sizes = [256, 256] (the preset now gives [128, 64])" in capsys.readouterr().err
    assert run.check_compatible(now.to_dict(), (0,)) is True
    other = RunFolder(tmp_path / "other")
    other.write_config({"config": now.replace(zeta_hidden_sizes=(128, 128)).to_dict(), "seeds": [0]})
    with pytest.raises(RunFolderMismatch, match=r"zeta_hidden_sizes: \[128, 128\] .folder. vs \[128, 64\]"):
        other.check_compatible(now.to_dict(), (0,))


def test_what_a_rerun_drops_from_metrics_is_said_in_one_line(tmp_path, capsys):
    """Rows written twice (two writers before the lock) and rows of epochs after the checkpoint resumed from
    are dropped by the rewrite, and one line says what and how many."""
    run, ckpt = _run_folder(tmp_path / "twice")
    run.append_rows(_rows(3))   # every (epoch, seed) twice: 16 lines
    capsys.readouterr()
    res = _resume(run, ckpt)
    err = capsys.readouterr().err
    assert res.rows == _rows(3) and len(run.metrics_path.read_text().splitlines()) == 8
    assert f"{run.metrics_path}: 8 of 16 rows dropped (8 duplicate or unreadable); 8 kept" in err
    late, ckpt2 = _run_folder(tmp_path / "late", epochs=(2,), rows=3)   # killed before checkpoint 3
    with open(late.metrics_path, "a") as f:
        f.write('{"epoch": 4, "se')                                    # and mid-write
    capsys.readouterr()
    _resume(late, ckpt2)
    assert f"{late.metrics_path}: 3 of 9 rows dropped (2 of epochs after 2 (they are trained again); 1 " \
        f"duplicate or unreadable); 6 kept" in capsys.readouterr().err
    capsys.readouterr()
    _resume(late, ckpt2)
    assert "rows dropped" not in capsys.readouterr().err   # nothing to repair: nothing said


# ------------------------------------------------------------------------------------------- the lock
_HOLD = """
import sys, time
from sf2_common.agents.lock import FolderLock
lock = FolderLock(sys.argv[1], "test holder").acquire()
print("held", flush=True)
time.sleep(600)
"""


def _holder(folder):
    import subprocess

    proc = subprocess.Popen([sys.executable, "-c", _HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_writer_is_refused_naming_the_holder_and_a_dead_ones_lock_is_taken_over(tmp_path, capsys):
    import signal
    import socket

    from sf2_common.agents.lock import FolderLock, RunFolderBusy, holder_of

    folder = tmp_path / "run"
    proc = _holder(folder)
    try:
        expected = f"pid {proc.pid} on host {socket.gethostname()} (test holder, since "
        assert holder_of(folder).startswith(expected)
        with pytest.raises(RunFolderBusy) as err:
            FolderLock(folder, "sf2-jax train").acquire()
        assert f"run folder {folder} is in use by {expected}" in str(err.value)
        assert "nothing was changed" in str(err.value) and isinstance(err.value, RunFolderError)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert holder_of(folder) is None   # the kernel released it with the process
    capsys.readouterr()
    lock = FolderLock(folder, "sf2-jax train").acquire()
    err = capsys.readouterr().err
    assert f"{folder}: taking over the lock of {expected}" in err and err.rstrip().endswith("which is gone")
    # flock belongs to an open file: this process's own second look sees the lock held, by itself
    assert holder_of(folder).startswith(f"pid {os.getpid()} on host {socket.gethostname()} (sf2-jax train")
    lock.release()
    assert not (folder / FolderLock.NAME).exists()   # a clean release leaves no lock file
    with FolderLock(folder, "again"):
        pass
    assert "taking over" not in capsys.readouterr().err


def test_a_child_inherits_its_parents_lock_and_a_missing_folder_is_not_created(tmp_path):
    import subprocess

    from sf2_common.agents.lock import FolderLock

    folder = tmp_path / "run"
    with FolderLock(folder, "study run") as lock:
        child = ("import sys; from sf2_common.agents.lock import FolderLock\n"
                 "l = FolderLock(sys.argv[1], 'train').acquire(); print(l.owned); l.release()")
        out = subprocess.run([sys.executable, "-c", child, str(folder)], capture_output=True, text=True,
                             env={**os.environ, **lock.child_env()}, pass_fds=(lock.fd,))
        assert out.returncode == 0 and out.stdout.strip() == "False", out.stderr
        alone = subprocess.run([sys.executable, "-c", child, str(folder)], capture_output=True, text=True)
        assert alone.returncode != 0 and "is in use by pid" in alone.stderr
    missing = FolderLock(tmp_path / "missing", "eval --save", create=False).acquire()
    assert missing.fd is None and not (tmp_path / "missing").exists()
