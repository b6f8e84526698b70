from __future__ import annotations

import dataclasses

import pytest
import sf2_torch
from sf2_torch import ConfigError, ParamsError, SF2Config, ShapeError

TABLE = dict(
    feature_size=512,
    hidden_sizes=(512, 512, 512),
    q_hidden_size=512,
    zeta_hidden_sizes=(512, 512),
    embedding_size=64,
    layer_norm=True,
    gamma_su=0.99,
    denoising_steps=1,
    integrator="midpoint",
    contract_zeta=True,
    discount=0.99,
    reward_scaling=1.0,
    tau=0.005,
    tau_zeta=0.05,
    learning_rate=1e-3,
    alpha_learning_rate=3e-4,
    adam_eps=1e-5,
    shared_adam=True,
    aux_steps_per_sgd_step=1,
    smoothing_noise=0.2,
    noise_clip=0.3,
    exploration_noise=0.2,
    policy_delay=1,
    min_std=0.001,
    target_entropy_scale=0.5,
    init_log_alpha=0.0,
    normalizer_std_min=1e-6,
    normalizer_std_max=1e6,
    spr_augmentation_std=0.05,
)


def test_fields_and_defaults_follow_the_contract():
    cfg = SF2Config(obs_size=5, action_size=1)
    names = [f.name for f in dataclasses.fields(SF2Config)]
    assert names == ["obs_size", "action_size", *TABLE]
    for name, value in TABLE.items():
        assert getattr(cfg, name) == value, name
    assert sf2_torch.__version__


def test_small_and_frozen():
    cfg = SF2Config.small(4, 2, gamma_su=0.5)
    assert (cfg.feature_size, cfg.hidden_sizes, cfg.q_hidden_size) == (16, (32, 32), 32)
    assert (cfg.zeta_hidden_sizes, cfg.embedding_size, cfg.gamma_su) == ((32, 32), 8, 0.5)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.obs_size = 3  # type: ignore[misc]
    assert SF2Config(2, 1, hidden_sizes=[8, 8]).hidden_sizes == (8, 8)
    assert cfg.replace(denoising_steps=3).denoising_steps == 3


@pytest.mark.parametrize(
    "field, value, hint",
    [
        ("obs_size", 0, ">= 1"),
        ("action_size", 1.5, "int >= 1"),
        ("feature_size", True, "int >= 1"),
        ("hidden_sizes", (32, 0), ">= 1"),
        ("zeta_hidden_sizes", "32", ">= 1"),
        ("q_hidden_size", -1, ">= 1"),
        ("embedding_size", 7, "even"),
        ("embedding_size", 0, ">= 1"),
        ("denoising_steps", 0, ">= 1"),
        ("denoising_steps", 2.0, "int >= 1"),
        ("gamma_su", 1.0, "gamma_su < 1"),
        ("gamma_su", -0.1, "0 <= gamma_su"),
        ("integrator", "rk4", "('midpoint', 'euler')"),
        ("tau", 0.0, "0 < value <= 1"),
        ("tau_zeta", 1.5, "0 < value <= 1"),
        ("learning_rate", 0.0, "> 0"),
        ("alpha_learning_rate", -1e-3, "> 0"),
        ("discount", 0.0, "0 < discount <= 1"),
        ("discount", 1.01, "0 < discount <= 1"),
        ("contract_zeta", 1, "must be a bool"),
        ("policy_delay", 0, ">= 1"),
    ],
)
def test_validation_names_field_value_and_rule(field, value, hint):
    with pytest.raises(ConfigError) as info:
        SF2Config(**{"obs_size": 3, "action_size": 1, field: value})
    msg = str(info.value)
    assert f"SF2Config.{field} = {value!r} is invalid" in msg and hint in msg, msg


def test_boundaries_accepted():
    SF2Config(3, 1, gamma_su=0.0, tau=1.0, tau_zeta=1.0, discount=1.0, integrator="euler")


def test_errors_are_value_errors():
    for err in (ConfigError, ShapeError, ParamsError):
        assert issubclass(err, ValueError)
