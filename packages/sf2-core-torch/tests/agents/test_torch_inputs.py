"""Bad input gets a clear error (exit status 2 from the CLI) before anything is built; presets, overrides
and seeds parse as documented; `sf2-torch` takes the same configs and flags as `sf2-jax`."""

from __future__ import annotations

import dataclasses
import importlib.util

import pytest
from sf2_common.agents import configs as common_configs
from sf2_common.errors import ConfigError
from sf2_common.testing import (
    BAD_TRAIN_INPUTS,
    check_baselines_resolve,
    check_cli_misuse,
    check_paper_preset,
    cli_error,
)
from sf2_torch import cli
from sf2_torch.agents import configs, envs, representations, trainer


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


def test_presets():
    paper = check_paper_preset(configs.make_config, envs)
    assert (paper.device, paper.compile, paper.cudagraphs) == ("auto", "auto", "auto")
    quick = configs.make_config("quick", "CartpoleBalance", overrides={"hidden_sizes": "64,64",
                                                                       "deterministic_eval": "false"})
    assert quick.hidden_sizes == (64, 64) and quick.deterministic_eval is False
    configs.validate(quick, "0-3")
    sf2 = quick.sf2_config(5, 1)
    for name in common_configs.SF2_FIELDS:
        assert getattr(sf2, name) == getattr(quick, name)


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


def test_schedule_and_seeds():
    cfg = configs.make_config("quick", "CartpoleBalance")
    s = common_configs.schedule(cfg)
    assert s.prefill_env_steps >= cfg.min_replay_size and s.total_env_steps >= cfg.num_timesteps
    assert s.total_env_steps - cfg.num_timesteps < s.num_epochs * s.env_steps_per_actor_step
    assert s.env_steps_after(s.num_epochs) == s.total_env_steps
    assert s.grad_steps_before(s.prefill_actor_steps + 3) == 3 and s.grad_steps_before(1) == 0
    assert common_configs.parse_seeds("0-3") == (0, 1, 2, 3)
    assert common_configs.parse_seeds("0-2,9") == (0, 1, 2, 9)
    assert common_configs.parse_seeds(7) == (7,)
    with pytest.raises(ConfigError):
        common_configs.parse_seeds("-1")


def test_cli_tasks_lists_paper_tasks(capsys):
    assert cli.main(["tasks"]) == 0
    out = capsys.readouterr().out
    assert "PendulumSwingup" in out and "10,000,000" in out


# ------------------------------------------------------------------------------- the same as sf2-jax
_JAX_AGENTS = importlib.util.find_spec("sf2_jax") is not None


@pytest.mark.parametrize("preset", ["paper", "quick"])
@pytest.mark.parametrize("task", ["CartpoleBalance", "PendulumSwingup", "CheetahRun"])
def test_presets_equal_sf2_jax(preset, task):
    """Switching framework changes nothing of a run's config (the torch-only fields aside): the JAX agents
    use sf2_common's TrainConfig as it is."""
    j = common_configs.make_config(preset, task, "sac", "sf2").to_dict()
    t = configs.make_config(preset, task, "sac", "sf2").to_dict()
    assert set(t) - set(j) == set(configs.TORCH_FIELDS)
    assert {k: v for k, v in t.items() if k not in configs.TORCH_FIELDS} == j


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
