"""Bad input gets a clear error (exit status 2 from the CLI) before anything is compiled. The same contract
through the API (bad input, presets, seeds, the schedule) is `sf2_testing.contract` (test_contract.py)."""

from __future__ import annotations

import pytest
from sf2_jax import cli
from sf2_jax.agents import representations, trainer
from sf2_testing import (
    BAD_TRAIN_INPUTS,
    check_baselines_resolve,
    check_cli_misuse,
    cli_error,
)


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


def test_the_backend_names_the_cli_module_under_python_m():
    """A study's children run `python -m <cli_module>`: the module by name, also when this CLI itself runs
    as `python -m sf2_jax.cli` (where its `__name__` is "__main__")."""
    import subprocess
    import sys

    code = ("import runpy; g = runpy.run_module('sf2_jax.cli', run_name='not_the_module_name'); "
            "print(g['backend']().cli_module)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "sf2_jax.cli", out.stderr[-2000:]
