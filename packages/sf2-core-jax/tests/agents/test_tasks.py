"""Tasks from anywhere: a user's environment by import path trains (sf2_testing.toy_env: dict observations,
the agents reading 'state') through the CLI and the API with equal rows, to the toy's optimum; a Brax env
is wrapped by Brax's wrappers; every Playground registry name is a task of its suite's kind whose preset
values are Playground's env config (read without building the envs: locomotion and manipulation need
Menagerie's assets); the names, once listed, are read in another process without importing Playground."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import pytest
from sf2_common.agents import tasks
from sf2_common.agents.runfolder import RunFolder
from sf2_jax import cli
from sf2_jax.agents import envs, make_config
from sf2_jax.agents.trainer import train
from sf2_testing import cli_args, cli_error, strip_wall
from sf2_testing.toy_env import TOY_OVERRIDES, TOY_TASK, check_toy_run


def test_a_user_environment_by_import_path_trains_through_the_cli_and_the_api_and_learns(tmp_path):
    cfg = make_config("quick", TOY_TASK, algo="td3", representation="sf2", overrides=TOY_OVERRIDES)
    assert cli.main(cli_args(cfg, tmp_path / "cli")) == 0     # `--task module:callable`
    first = RunFolder(tmp_path / "cli")
    again = train(cfg, (0,), tmp_path / "api", progress=False)
    check_toy_run(cfg, first, envs.env_spec(cfg.task, cfg.episode_length, cfg.action_repeat))
    assert strip_wall(again.rows) == strip_wall(first.read_rows())


def test_a_brax_environment_is_wrapped_by_braxs_wrappers():
    """Brax's auto-reset restores `pipeline_state` (Playground's restores `data`); the time limit cuts
    after `episode_length` env steps (action repeat 2: the third agent step) and the episode restarts."""
    spec = envs.env_spec("sf2_testing.toy_env:make_brax_env", 5, 2)
    assert (spec.obs_size, spec.action_size) == (2, 2)
    first = spec.train_env.reset(jax.random.split(jax.random.PRNGKey(0), 3))
    state, step = first, jax.jit(spec.train_env.step)
    for t in range(3):
        state = step(state, jnp.ones((3, 2)))
        assert (state.reward == 2.0).all()    # two physics steps of mean(a) = 1
        assert (state.done == (t == 2)).all() and (state.info["truncation"] == (t == 2)).all()
    assert (state.obs == first.obs).all()     # reset to the first state


def test_every_playground_registry_name_is_a_task_with_playgrounds_env_config():
    from mujoco_playground import registry

    suites = {"playground": registry.dm_control_suite, "locomotion": registry.locomotion,
              "manipulation": registry.manipulation}
    assert set(envs.valid_tasks()) >= set(registry.ALL_ENVS)
    for kind, suite in suites.items():
        for task in suite.ALL_ENVS:
            assert tasks.task_kind(task) is tasks.KINDS[kind]
            conf = registry.get_default_config(task)
            paper = make_config("paper", task, "sac")
            repeat = tasks.PAPER_ACTION_REPEAT.get(task, conf.action_repeat)
            assert (paper.episode_length, paper.action_repeat) == (conf.episode_length, repeat), task
            assert paper.num_timesteps == tasks.paper_budget(task)
            if kind != "playground":
                assert paper.num_timesteps == tasks.OFF_POLICY_BUDGET


def test_playgrounds_task_names_are_read_back_in_another_process_without_importing_it(tmp_path, monkeypatch):
    from mujoco_playground import registry

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    tasks.playground_tasks.cache_clear()
    try:
        listed = tasks.playground_tasks()
    finally:
        tasks.playground_tasks.cache_clear()
    assert set(listed) == set(registry.ALL_ENVS)
    assert (tmp_path / "sf2" / "playground-tasks.json").exists()
    probe = ("import json, sys; from sf2_common.agents import tasks; listed = tasks.playground_tasks(); "
             "print(json.dumps([list(listed.items()), 'mujoco_playground' in sys.modules]))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True,
                          env={**os.environ, "XDG_CACHE_HOME": str(tmp_path)})
    again, imported = json.loads(done.stdout)
    assert [tuple(pair) for pair in again] == list(listed.items()) and not imported


@pytest.mark.parametrize("task", ["Go1JoystickFlatTerrain", "PandaPickCube"])
def test_locomotion_and_manipulation_names_are_accepted_by_the_api_and_the_cli(task, capsys):
    """Config and validation take them (the env is not built: no Menagerie assets in CI); the CLI gets past
    the task to the next bad input."""
    from mujoco_playground import registry
    from sf2_jax.agents import configs

    cfg = configs.validate(make_config("quick", task, "td3", "sf2"))
    assert cfg.episode_length == registry.get_default_config(task).episode_length
    err = cli_error(cli.main, capsys, "--task", task, "--seeds", "3-1")
    assert "seeds '3-1' are invalid" in err and "unknown task" not in err
