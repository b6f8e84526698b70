"""Tasks from anywhere, as the JAX core's test_tasks.py: a user's environment by import path trains
(sf2_testing.toy_env: dict observations, the agents reading 'state') through the CLI and the API with
equal rows, to the toy's optimum; Playground's locomotion and manipulation names are accepted by the API
and the CLI."""

from __future__ import annotations

import pytest
from sf2_common.agents.runfolder import RunFolder
from sf2_testing import cli_args, cli_error, strip_wall
from sf2_testing.toy_env import TOY_OVERRIDES, TOY_TASK, check_toy_run
from sf2_torch import cli
from sf2_torch.agents import envs, make_config
from sf2_torch.agents.trainer import train


def test_a_user_environment_by_import_path_trains_through_the_cli_and_the_api_and_learns(tmp_path):
    cfg = make_config("quick", TOY_TASK, algo="td3", representation="sf2",
                      overrides={**TOY_OVERRIDES, "compile": "off"})
    assert cli.main(cli_args(cfg, tmp_path / "cli")) == 0     # `--task module:callable`
    first = RunFolder(tmp_path / "cli")
    again = train(cfg, (0,), tmp_path / "api", progress=False)
    check_toy_run(cfg, first, envs.env_spec(cfg.task, cfg.episode_length, cfg.action_repeat))
    assert strip_wall(again.rows) == strip_wall(first.read_rows())


@pytest.mark.parametrize("task", ["Go1JoystickFlatTerrain", "PandaPickCube"])
def test_locomotion_and_manipulation_names_are_accepted_by_the_api_and_the_cli(task, capsys):
    """Config and validation take them (the env is not built: no Menagerie assets in CI); the CLI gets past
    the task to the next bad input."""
    from mujoco_playground import registry
    from sf2_torch.agents import configs

    cfg = configs.validate(make_config("quick", task, "td3", "sf2"))
    assert cfg.episode_length == registry.get_default_config(task).episode_length
    err = cli_error(cli.main, capsys, "--task", task, "--seeds", "3-1")
    assert "seeds '3-1' are invalid" in err and "unknown task" not in err
