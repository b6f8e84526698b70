"""The agents' framework-independent contract as pytest tests, written once and run on each core.

Each core's agents tests import these tests (test_contract.py, test_torch_contract.py) and their
conftest.py gives them the core as the `agent_core` fixture (an `AgentCore`). The contract: bad input is
refused with a `ConfigError` naming it before anything is built or written; presets, overrides, seeds
and the schedule are as documented; switching framework changes nothing of a run's shared config. The
command-line tests stay in each core's test_inputs (`sf2_testing` holds their shared cases).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType

import pytest
from sf2_common.agents import configs as common_configs
from sf2_common.errors import ConfigError

from sf2_testing import check_paper_preset

__all__ = ["AgentCore", "BAD_RUNS", "test_bad_input_is_refused_before_anything_is_built", "test_presets",
           "test_schedule_and_seeds", "test_presets_equal_across_frameworks",
           "test_ppo_presets_equal_across_frameworks"]


@dataclass(frozen=True)
class AgentCore:
    """One core's agents, as the contract tests use them."""

    framework: str                   # "jax" or "torch"
    configs: ModuleType              # TrainConfig, make_config(preset, task, algo, repr, overrides), validate
    trainer: ModuleType              # train, get_program
    envs: ModuleType                 # PAPER_TASKS, valid_tasks
    representations: ModuleType      # register, NoRepresentation, REGISTRY
    own_fields: tuple[str, ...] = ()  # TrainConfig fields of this core only (torch: device, compile, ...)


SAC_ONLY = "contract_sac_only"

# (id, make_config arguments beyond the preset, seeds, texts the ConfigError's message must contain)
BAD_RUNS = [
    ("unknown task", dict(task="CartpoleBalanse"), "0",
     ["unknown task 'CartpoleBalanse'", "Did you mean CartpoleBalance", "AcrobotSwingup", "WalkerWalk"]),
    ("unknown algo", dict(algo="ddpg"), "0", ["algo = 'ddpg'", "td3, sac"]),
    ("unknown representation", dict(representation="bogus"), "0",
     ["representation = 'bogus'", "must be one of none, sf2"]),
    ("representation without the algo", dict(representation=SAC_ONLY), "0",
     [f"algo 'td3' with representation '{SAC_ONLY}' does not exist", f"sac+{SAC_ONLY}"]),
    ("budget within the prefill", dict(overrides={"num_timesteps": 1000}), "0",
     ["num_timesteps = 1000 does not exceed the prefill", "min_replay_size = 4096"]),
    ("prefill above the buffer", dict(overrides={"min_replay_size": 300_000}), "0",
     ["min_replay_size = 300000", "max_replay_size"]),
    ("batch of 0", dict(overrides={"batch_size": 0}), "0", ["batch_size = 0", ">= 1"]),
    ("batch of 1.5", dict(overrides={"batch_size": "1.5"}), "0", ["batch_size", "integer"]),
    ("unknown field", dict(overrides={"bogus": 1}), "0", ["unknown config fields ['bogus']"]),
    ("gamma_su of 1", dict(overrides={"gamma_su": 1.0}), "0", ["gamma_su = 1.0", "0 <= gamma_su < 1"]),
    ("odd embedding", dict(overrides={"embedding_size": 7}), "0", ["embedding_size = 7", "even"]),
    ("unknown integrator", dict(overrides={"integrator": "rk4"}), "0", ["integrator = 'rk4'", "midpoint"]),
    ("negative learning rate", dict(overrides={"learning_rate": -1e-3}), "0",
     ["learning_rate = -0.001 is invalid", "> 0"]),
    ("negative augmentation", dict(overrides={"spr_augmentation_std": -0.05}), "0",
     ["spr_augmentation_std = -0.05 is invalid", ">= 0"]),
    ("fpo on a MinAtar task", dict(task="minatar-breakout", algo="fpo"), "0",
     ["task 'minatar-breakout' is a MinAtar task", "(--algo ppo); --algo fpo is the"]),
    ("ppo on a Playground task", dict(algo="ppo"), "0",
     ["task 'CartpoleBalance' is a Playground DM Control task", "--algo ppo is the MinAtar tasks'"]),
    ("td3 on a MinAtar task", dict(task="minatar-breakout"), "0",
     ["task 'minatar-breakout' is a MinAtar task: MinAtar tasks take the on-policy trainer (--algo ppo)"]),
    ("seeds backwards", dict(), "3-1", ["seeds '3-1' are invalid"]),
    ("seeds repeated", dict(), "0,0", ["duplicates"]),
    ("negative seed", dict(), -1, ["seeds (-1,) are invalid"]),
]


def _register_sac_only(reps: ModuleType) -> None:
    """A representation for SAC only, in the core's registry (registering it again replaces it)."""

    class SacOnly(reps.NoRepresentation):
        name = SAC_ONLY
        supported_algos = ("sac",)

    reps.register(SacOnly)


@pytest.mark.parametrize("changes,seeds,texts", [c[1:] for c in BAD_RUNS], ids=[c[0] for c in BAD_RUNS])
def test_bad_input_is_refused_before_anything_is_built(agent_core, monkeypatch, tmp_path, changes, seeds,
                                                       texts):
    """`make_config` then `train` raise a `ConfigError` naming the bad value, before a program is built
    (the first step that builds networks, envs or compiled code) and before the run folder is created."""

    def refuse(cfg):
        raise AssertionError("a program was built: validation did not stop the bad input first")

    monkeypatch.setattr(agent_core.trainer, "get_program", refuse)
    _register_sac_only(agent_core.representations)
    kwargs = {"task": "CartpoleBalance", "algo": "td3", "representation": "sf2", "overrides": None, **changes}
    out = tmp_path / "run"
    with pytest.raises(ConfigError) as err:
        cfg = agent_core.configs.make_config("quick", kwargs.pop("task"), **kwargs)
        agent_core.trainer.train(cfg, seeds, out, progress=False)
    for text in texts:
        assert text in str(err.value), str(err.value)
    assert not out.exists()


def test_presets(agent_core):
    """The `paper` preset as docs/core-contract.md gives it; `quick` with string overrides; the config the
    core validates is the one it was given; the SF² fields reach `SF2Config` unchanged."""
    configs = agent_core.configs
    check_paper_preset(configs.make_config, agent_core.envs)
    quick = configs.make_config("quick", "CartpoleBalance", overrides={"hidden_sizes": "64,64",
                                                                       "deterministic_eval": "false"})
    assert quick.hidden_sizes == (64, 64) and quick.deterministic_eval is False
    assert configs.validate(quick, "0-3") is quick   # against the core's own representations
    sf2 = quick.sf2_config(5, 1)
    for name in common_configs.SF2_FIELDS:
        assert getattr(sf2, name) == getattr(quick, name)


def test_schedule_and_seeds(agent_core):
    """The schedule covers the budget with whole epochs after the prefill; seeds parse as documented."""
    cfg = agent_core.configs.make_config("quick", "CartpoleBalance")
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


@pytest.mark.parametrize("preset", ["paper", "quick"])
@pytest.mark.parametrize("task", ["CartpoleBalance", "PendulumSwingup", "CheetahRun"])
def test_presets_equal_across_frameworks(agent_core, preset, task):
    """Switching framework changes nothing of a run's config: the core's config is sf2_common's, field for
    field, plus the core's own run fields (`AgentCore.own_fields`) at the end."""
    shared = common_configs.make_config(preset, task, "sac", "sf2").to_dict()
    mine = agent_core.configs.make_config(preset, task, "sac", "sf2").to_dict()
    assert set(mine) - set(shared) == set(agent_core.own_fields)
    assert {k: v for k, v in mine.items() if k not in agent_core.own_fields} == shared


@pytest.mark.parametrize("preset", ["paper", "quick"])
@pytest.mark.parametrize("representation", ["none", "sf2"])
@pytest.mark.parametrize("algo,task", [("ppo", "minatar-breakout"), ("fpo", "CheetahRun")])
def test_ppo_presets_equal_across_frameworks(agent_core, preset, representation, algo, task):
    """`--algo ppo` configs (MinAtar, docs/minatar.md) and `--algo fpo` configs (Playground, docs/fpo.md) are
    sf2_common's in every core, field for field, with the PPO or FPO fields of the preset (pgx's example,
    the FPO authors' config for `paper`)."""
    shared = common_configs.make_config(preset, task, algo, representation).to_dict()
    mine = agent_core.configs.make_config(preset, task, algo, representation).to_dict()
    assert {k: v for k, v in mine.items() if k not in agent_core.own_fields} == shared
    values = (common_configs.PPO_VALUES if algo == "ppo" else common_configs.FPO_VALUES)[preset]
    assert {k: shared[k] for k in values} == {k: list(v) if isinstance(v, tuple) else v
                                              for k, v in values.items()}
