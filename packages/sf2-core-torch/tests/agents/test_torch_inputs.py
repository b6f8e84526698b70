"""Bad input gets a clear error (exit status 2 from the CLI) before anything is built; `sf2-torch` takes the
same flags as `sf2-jax`; the torch-only fields. The same contract through the API (bad input, presets,
seeds, the schedule, configs equal across frameworks) is `sf2_testing.contract` (test_torch_contract.py)."""

from __future__ import annotations

import dataclasses
import importlib.util

import pytest
from sf2_testing import (
    BAD_TRAIN_INPUTS,
    check_baselines_resolve,
    check_cli_misuse,
    cli_error,
)
from sf2_torch import cli
from sf2_torch.agents import configs, representations, trainer


@pytest.fixture(autouse=True)
def no_program(monkeypatch):
    """Building a program (the first step that builds networks or envs) fails the test."""
    def refuse(cfg):
        raise AssertionError("a program was built: validation did not stop the bad input first")

    monkeypatch.setattr(trainer, "get_program", refuse)


@representations.register
class _SacOnly(representations.NoRepresentation):
    name = "test_sac_only"
    supported_algos = ("sac",)


def _cli_error(capsys, *args):
    return cli_error(cli.main, capsys, *args)


TORCH_ONLY = [
    (["--task", "CartpoleBalance", "--compile", "fast"], ["compile = 'fast'", "max-autotune-no-cudagraphs"]),
    (["--task", "CartpoleBalance", "--cudagraphs", "maybe"], ["cudagraphs = 'maybe'", "auto, on, off"]),
    (["--task", "CartpoleBalance", "--device", "tpu"], ["device = 'tpu'", "cpu, cuda"]),
    (["--task", "CartpoleBalance", "--device", "cpu", "--cudagraphs", "on"], ["CUDA graphs need a CUDA"]),
    (["--task", "CartpoleBalance", "--algo", "fpo"], ["algo = 'fpo'", "this core trains td3, sac"]),
]


@pytest.mark.parametrize("args,expected", BAD_TRAIN_INPUTS + TORCH_ONLY)
def test_bad_train_input(capsys, args, expected):
    err = _cli_error(capsys, *args)
    for text in expected:
        assert text in err, err
    assert "Traceback" not in err and err.startswith("sf2-torch train: error:")


def test_cuda_requested_without_cuda(capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    err = _cli_error(capsys, "--task", "CartpoleBalance", "--device", "cuda")
    assert "CUDA is not available" in err


@pytest.mark.parametrize("reprs", ["sim", "simlap", "spr", "sf2,none,sim,simlap,spr"])
def test_baseline_representations_resolve(reprs):
    """`--repr sim|simlap|spr` select sf2-baselines' classes (entry points of "sf2.representations.torch")
    and validate like sf2, for both algorithms."""
    pytest.importorskip("sf2_baselines", reason="sf2-baselines is not installed")
    check_baselines_resolve(cli, representations, reprs)


def test_cli_misuse(capsys, tmp_path):
    check_cli_misuse(cli.main, capsys, tmp_path)


def test_presets_torch_fields():
    paper = configs.make_config("paper", "PendulumSwingup", "sac", "sf2")
    assert (paper.device, paper.compile, paper.cudagraphs) == ("auto", "auto", "auto")


def test_compile_and_device_resolution():
    import torch

    cfg = configs.make_config("quick", "CartpoleBalance")
    cpu, cuda = torch.device("cpu"), torch.device("cuda", 0)
    assert configs.resolve_compile(cfg, cpu) is None and configs.resolve_compile(cfg, cuda) == "default"
    assert not configs.resolve_cudagraphs(cfg, cpu) and configs.resolve_cudagraphs(cfg, cuda)
    cfg = cfg.replace(compile="max-autotune-no-cudagraphs", cudagraphs="off")
    assert configs.resolve_compile(cfg, cpu) == "max-autotune-no-cudagraphs"
    assert not configs.resolve_cudagraphs(cfg, cuda)
    assert configs.resolve_compile(cfg.replace(compile="off"), cuda) is None
    assert configs.resolve_device(cfg.replace(device="cpu")) == cpu


def test_cli_tasks_lists_paper_tasks(capsys):
    assert cli.main(["tasks"]) == 0
    out = capsys.readouterr().out
    assert "PendulumSwingup" in out and "10,000,000" in out


# ------------------------------------------------------------------------------- the same as sf2-jax
_JAX_AGENTS = importlib.util.find_spec("sf2_jax") is not None


@pytest.mark.skipif(not _JAX_AGENTS, reason="sf2_jax is not installed")
def test_cli_flags_equal_sf2_jax():
    jcli = pytest.importorskip("sf2_jax.cli")

    def flags(parser):
        sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
        return {name: {opt for a in p._actions for opt in a.option_strings}
                for name, p in sub.choices.items()}

    j, t = flags(jcli.build_parser()), flags(cli.build_parser())
    assert set(j) == set(t)
    torch_only = {f"--{f}" for f in configs.TORCH_FIELDS}
    for command in j:
        assert t[command] - j[command] <= torch_only, command
        assert j[command] <= t[command], command


def test_train_config_fields_are_documented():
    names = [f.name for f in dataclasses.fields(configs.TrainConfig)]
    assert names[-3:] == list(configs.TORCH_FIELDS)


def test_the_backend_names_the_cli_module_under_python_m():
    """A study's children run `python -m <cli_module>`: the module by name, also when this CLI itself runs
    as `python -m sf2_torch.cli` (where its `__name__` is "__main__")."""
    import subprocess
    import sys

    code = ("import runpy; g = runpy.run_module('sf2_torch.cli', run_name='not_the_module_name'); "
            "print(g['backend']().cli_module)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "sf2_torch.cli", out.stderr[-2000:]


def test_crl_is_refused_naming_the_jax_trainer(capsys):
    """`--algo crl` (ant-goal) trains with sf2-jax's goal-conditioned trainer: the torch CLI says so."""
    err = _cli_error(capsys, "--task", "ant-goal", "--algo", "crl", "--repr", "none")
    assert "sf2-jax's goal-conditioned trainer" in err and "use sf2-jax" in err, err
