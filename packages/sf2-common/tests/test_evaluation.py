"""`sf2_common.agents.evaluation`, the framework-free half of both cores' `eval`: every user mistake is an
error naming the folder and the valid choices, with the folder unchanged; the result rows keep each
seed's returns under each noise std, in order. The cores' own eval (restore, act) is tested in their
packages (test_training.py, test_torch_training.py)."""

from __future__ import annotations

import pytest
from sf2_common.agents.configs import TrainConfig
from sf2_common.agents.evaluation import open_evaluation
from sf2_common.agents.runfolder import RunFolder
from sf2_common.errors import ConfigError
from sf2_common.testing import folder_digest

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
