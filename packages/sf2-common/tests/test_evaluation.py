"""`sf2_common.agents.evaluation`, the framework-free half of both cores' `eval`: every user mistake is an
error naming the folder and the valid choices, with the folder unchanged; the result rows keep each
seed's returns under each noise std, in order. The cores' own eval (restore, act) is tested in their
packages (test_training.py, test_torch_training.py)."""

from __future__ import annotations

import pytest
from sf2_common.agents.configs import TrainConfig
from sf2_common.agents.evaluation import EVAL_KEY_BASE, CheckpointEvaluator, open_evaluation
from sf2_common.agents.runfolder import RunFolder
from sf2_common.errors import ConfigError
from sf2_testing import folder_digest

CFG = TrainConfig(num_timesteps=96, num_envs=4, num_evals=4, min_replay_size=4, num_eval_envs=3)


def _run(tmp_path, versions=None, seeds=(0, 2)):
    folder = tmp_path / "run"
    RunFolder(folder).write_config({"config": CFG.to_dict(), "seeds": list(seeds),
                                    "versions": versions or {"jax": "0"}})
    return folder


def test_open_reads_config_seeds_and_checks_noise(tmp_path):
    ev = open_evaluation(_run(tmp_path), "jax", TrainConfig, (0, 0.5))
    assert ev.cfg == CFG and ev.seeds == (0, 2) and ev.noises == (0.0, 0.5)
    with pytest.raises(ConfigError, match=r"obs_noise = -0.1 is invalid"):
        open_evaluation(_run(tmp_path), "jax", TrainConfig, (0.0, -0.1))


def test_wrong_folder_or_core_is_named_and_nothing_changes(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nothing is not a run folder \(no config.json\)"):
        open_evaluation(tmp_path / "nothing", "jax", TrainConfig)
    assert not (tmp_path / "nothing").exists()
    torch_run = _run(tmp_path, versions={"torch": "2"})
    before = folder_digest(torch_run)
    with pytest.raises(ConfigError, match=r"was trained by sf2-torch; evaluate it with that CLI"):
        open_evaluation(torch_run, "jax", TrainConfig)
    assert folder_digest(torch_run) == before
    assert open_evaluation(torch_run, "torch", TrainConfig).seeds == (0, 2)


def test_checkpoint_choice(tmp_path):
    ev = open_evaluation(_run(tmp_path), "jax", TrainConfig)
    assert ev.checkpoint([1, 3, 2], None) == 3   # the latest
    assert ev.checkpoint([1, 3, 2], 2) == 2
    with pytest.raises(FileNotFoundError, match=r"has no checkpoint 5; available: \[1, 3, 2\]"):
        ev.checkpoint([1, 3, 2], 5)
    with pytest.raises(FileNotFoundError, match=r"has no checkpoint yet"):
        ev.checkpoint([], None)


def test_episodes_default_to_the_runs_own_starts(tmp_path):
    ev = open_evaluation(_run(tmp_path), "jax", TrainConfig)
    assert ev.episodes(None) is None and ev.episodes(CFG.num_eval_envs) is None
    assert ev.episodes(7) == 7
    for bad in (0, -1, 2.5, True, "3"):
        with pytest.raises(ConfigError, match=r"episodes = .* is invalid: must be an integer >= 1"):
            ev.episodes(bad)


def test_eval_config_and_results(tmp_path):
    ev = open_evaluation(_run(tmp_path), "jax", TrainConfig, (0.0, 1.0))
    assert ev.eval_config(None) is ev.cfg
    assert ev.eval_config(False).deterministic_eval is False and ev.eval_config(True).deterministic_eval
    # returns[k][i]: seed i (seeds 0 and 2) under noise k
    rows = ev.results(3, {"env_steps": 72}, [[[1, 2], [3, 4]], [[5, 6], [7, 8]]], True, [1, 2, 3])
    assert rows == [
        {"epoch": 3, "env_steps": 72, "returns": {0: [1.0, 2.0], 2: [3.0, 4.0]}, "deterministic": True,
         "obs_noise": 0.0, "checkpoints": [1, 2, 3]},
        {"epoch": 3, "env_steps": 72, "returns": {0: [5.0, 6.0], 2: [7.0, 8.0]}, "deterministic": True,
         "obs_noise": 1.0, "checkpoints": [1, 2, 3]},
    ]
    with pytest.raises(ValueError):   # one result per noise std, never silently fewer
        ev.results(3, {}, [[[1], [2]]], True, [3])


class _Checkpointer:
    """A core's checkpointer as `CheckpointEvaluator` uses it: the epochs on disk, whether it is closed."""

    opened: list = []

    def __init__(self, folder, keep):
        self.folder, self.keep, self.closed = folder, keep, False
        _Checkpointer.opened.append(self)

    def all(self):
        return [1, 3]

    def close(self):
        self.closed = True


def _evaluator(restore=None):
    def default_restore(ckpt, job):
        return f"agents of {job.epoch}", {"env_steps": 10 * job.epoch}

    def act(restored, job):
        assert restored == f"agents of {job.epoch}" and job.key == EVAL_KEY_BASE + job.epoch
        return [[[noise + i] * (job.episodes or job.cfg.num_eval_envs) for i, _ in enumerate(job.seeds)]
                for noise in job.noises]

    return CheckpointEvaluator("jax", TrainConfig, _Checkpointer, restore or default_restore, act)


def test_checkpoint_evaluator_results_and_closes_its_checkpointer(tmp_path):
    """The framework-free half of both cores' `evaluate_checkpoint(_noises)`: the chosen checkpoint, the
    episodes, one result per std; the core's checkpointer is closed on every path, a bad request is refused
    before anything is restored."""
    _Checkpointer.opened.clear()
    run = _run(tmp_path)
    ev = _evaluator()
    res = ev.evaluate_checkpoint(run, obs_noise=0.5, deterministic=False)
    assert res == {"epoch": 3, "env_steps": 30, "returns": {0: [0.5] * 3, 2: [1.5] * 3},
                   "deterministic": False, "obs_noise": 0.5, "checkpoints": [1, 3]}
    both = ev.evaluate_checkpoint_noises(run, 1, 2, None, (0.0, 1.0))
    assert [(r["epoch"], r["obs_noise"], r["returns"][2]) for r in both] == [(1, 0.0, [1.0, 1.0]),
                                                                               (1, 1.0, [2.0, 2.0])]
    assert all(c.closed and c.keep == CFG.keep_checkpoints for c in _Checkpointer.opened)

    def refuse(ckpt, job):
        raise AssertionError("restored a checkpoint of a bad request")

    for kwargs, error in ((dict(epoch=2), FileNotFoundError), (dict(num_eval_envs=0), ConfigError)):
        _Checkpointer.opened.clear()
        with pytest.raises(error):
            _evaluator(refuse).evaluate_checkpoint(run, **kwargs)
        assert [c.closed for c in _Checkpointer.opened] == [True]

    def broken(ckpt, job):
        raise ConfigError("checkpoint 3 does not fit this program")

    _Checkpointer.opened.clear()
    with pytest.raises(ConfigError, match="does not fit"):
        _evaluator(broken).evaluate_checkpoint(run)
    assert [c.closed for c in _Checkpointer.opened] == [True]
