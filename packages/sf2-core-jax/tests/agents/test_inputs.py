"""Bad input gets a clear error (exit status 2 from the CLI) before anything is compiled; presets,
overrides and seeds parse as documented."""

from __future__ import annotations

import pytest
from sf2_common.agents import configs
from sf2_common.errors import ConfigError
from sf2_common.testing import (
    BAD_TRAIN_INPUTS,
    check_baselines_resolve,
    check_cli_misuse,
    check_paper_preset,
    cli_error,
)
from sf2_jax import cli
from sf2_jax.agents import envs, representations, trainer


@pytest.fixture(autouse=True)
def no_compilation(monkeypatch):
    """Building a program (the first step that compiles anything) fails the test."""
    def refuse(cfg):
        raise AssertionError("a program was built: validation did not stop the bad input first")

    monkeypatch.setattr(trainer, "get_program", refuse)


@representations.register
class _SacOnly(representations.NoRepresentation):
    name = "test_sac_only"
    supported_algos = ("sac",)


def _cli_error(capsys, *args):
    return cli_error(cli.main, capsys, *args)


@pytest.mark.parametrize("args,expected", BAD_TRAIN_INPUTS)
def test_bad_train_input(capsys, args, expected):
    err = _cli_error(capsys, *args)
    for text in expected:
        assert text in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize("reprs", ["sim", "simlap", "spr", "sf2,none,sim,simlap,spr"])
def test_baseline_representations_resolve(reprs):
    """`--repr sim|simlap|spr` select sf2-baselines' classes (entry points of "sf2.representations.jax")
    and validate like sf2, for both algorithms."""
    pytest.importorskip("sf2_baselines", reason="sf2-baselines is not installed")
    check_baselines_resolve(cli, representations, reprs)


def test_cli_misuse(capsys, tmp_path):
    check_cli_misuse(cli.main, capsys, tmp_path)


def test_presets():
    check_paper_preset(configs.make_config, envs)
    quick = configs.make_config("quick", "CartpoleBalance", overrides={"hidden_sizes": "64,64",
                                                                       "deterministic_eval": "false"})
    assert quick.hidden_sizes == (64, 64) and quick.deterministic_eval is False
    assert cli.backend().validate(quick, "0-3") is quick   # against the JAX agents' representations
    sf2 = quick.sf2_config(5, 1)
    for name in configs.SF2_FIELDS:
        assert getattr(sf2, name) == getattr(quick, name)


def test_schedule_and_seeds():
    cfg = configs.make_config("quick", "CartpoleBalance")
    s = configs.schedule(cfg)
    assert s.prefill_env_steps >= cfg.min_replay_size and s.total_env_steps >= cfg.num_timesteps
    assert s.total_env_steps - cfg.num_timesteps < s.num_epochs * s.env_steps_per_actor_step
    assert s.env_steps_after(s.num_epochs) == s.total_env_steps
    assert s.grad_steps_before(s.prefill_actor_steps + 3) == 3 and s.grad_steps_before(1) == 0
    assert configs.parse_seeds("0-3") == (0, 1, 2, 3)
    assert configs.parse_seeds("0-2,9") == (0, 1, 2, 9)
    assert configs.parse_seeds(7) == (7,)
    with pytest.raises(ConfigError):
        configs.parse_seeds("-1")


def test_cli_tasks_lists_paper_tasks(capsys):
    assert cli.main(["tasks"]) == 0
    out = capsys.readouterr().out
    assert "PendulumSwingup" in out and "10,000,000" in out


def test_checkpoint_of_another_program_is_bad_input(capsys, monkeypatch):
    """A checkpoint that does not fit (CheckpointMismatch, a ConfigError) exits with status 2 and a message,
    through the CLI's handle on the trainer (`sf2_jax.cli` imports it when the command runs)."""
    from sf2_jax.agents.checkpoint import CheckpointMismatch

    def mismatch(*args, **kwargs):
        raise CheckpointMismatch("checkpoint 3 does not fit this program")

    monkeypatch.setattr(trainer, "evaluate_checkpoint", mismatch)
    assert cli.main(["eval", "/nonexistent"]) == 2
    assert "sf2-jax eval: error: checkpoint 3 does not fit this program" in capsys.readouterr().err
