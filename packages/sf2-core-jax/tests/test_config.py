import pytest
from sf2_jax import ConfigError, SF2Config, networks


def test_defaults_and_small():
    cfg = SF2Config(obs_size=5, action_size=1)
    assert (cfg.feature_size, cfg.hidden_sizes, cfg.zeta_hidden_sizes, cfg.embedding_size) == (
        512, (512, 512, 512), (512, 512), 64)
    assert (cfg.gamma_su, cfg.denoising_steps, cfg.integrator, cfg.contract_zeta) == (
        0.99, 1, "midpoint", True)
    small = SF2Config.small(5, 1, gamma_su=0.0)
    assert (small.feature_size, small.hidden_sizes, small.q_hidden_size, small.zeta_hidden_sizes,
            small.embedding_size, small.gamma_su) == (16, (32, 32), 32, (32, 32), 8, 0.0)
    assert hash(small) == hash(SF2Config.small(5, 1, gamma_su=0.0))
    assert SF2Config(obs_size=2, action_size=1, hidden_sizes=[4, 4]).hidden_sizes == (4, 4)


@pytest.mark.parametrize("field, value, words", [
    ("denoising_steps", 0, "int >= 1"),
    ("denoising_steps", 1.5, "int >= 1"),
    ("gamma_su", 1.0, "0 <= gamma_su < 1"),
    ("gamma_su", -0.1, "0 <= gamma_su < 1"),
    ("integrator", "rk4", "midpoint"),
    ("embedding_size", 7, "even"),
    ("feature_size", 0, ">= 1"),
    ("hidden_sizes", (32, 0), ">= 1"),
    ("tau", 0.0, "0 < value <= 1"),
    ("tau_zeta", 1.5, "0 < value <= 1"),
    ("learning_rate", 0.0, "> 0"),
    ("discount", 0.0, "0 < discount <= 1"),
])
def test_config_errors_name_field_value_and_rule(field, value, words):
    with pytest.raises(ConfigError) as err:
        SF2Config.small(3, 2, **{field: value})
    msg = str(err.value)
    assert field in msg and repr(value) in msg and words in msg
    assert isinstance(err.value, ValueError)


def test_unknown_algo():
    with pytest.raises(ConfigError, match="'td3', 'sac'"):
        networks.make_networks(SF2Config.small(3, 2), "ppo")
