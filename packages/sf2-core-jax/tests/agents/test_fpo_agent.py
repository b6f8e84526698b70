"""FPO on the on-policy trainer (`--algo fpo`, docs/fpo.md): `--config quick` on CartpoleBalance learns on
a CPU, and the FPO configs are refused where they do not apply.

The learning run is the `quick` preset itself (FPO + Q(λ): 64 envs × 32 steps per update, 8 passes of
minibatches of 256, lr 1e-4, 786,432 env steps: 384 updates in 6 epochs); with seed 0 its evaluations
rose 403 (the initial policy), 459, 427, 532, 537, 573, 587 on the machine this test was written on. The
margin: the uniform-random policy's return, measured here with the trainer's own env and evaluation
protocol (one 1000-step episode per env, 64 envs), is ~354 ± 58; the trained policy's mean over 16
episodes must exceed random mean + 3 std (≈ 528): 3 standard deviations of a single random episode, 12
standard errors of a 16-episode random mean. (With lr 3e-4 single seeds learned faster or collapsed,
depending on XLA's rounding: docs/fpo.md.)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sf2_common.agents.configs import schedule
from sf2_common.errors import ConfigError
from sf2_jax.agents import make_config, onpolicy, playground_onpolicy, validate


def _random_policy_returns(cfg, n=64, seed=123):
    env = playground_onpolicy.make(cfg.task, cfg.episode_length)

    @jax.jit
    def run(key):
        k_reset, k_act = jax.random.split(key)
        state = env.reset(jax.random.split(k_reset, n))

        def step(carry, k):
            state, ret, alive = carry
            action = jax.random.uniform(k, (n, env.spec.action_size), minval=-1.0, maxval=1.0)
            state, tr = env.step(state, action, k)
            return (state, ret + tr.reward * alive, alive * (1.0 - (tr.terminal | tr.truncation))), None

        (_, ret, _), _ = jax.lax.scan(step, (state, jnp.zeros(n), jnp.ones(n)),
                                      jax.random.split(k_act, cfg.episode_length))
        return ret

    return np.asarray(run(jax.random.key(seed)))


@pytest.mark.slow
def test_quick_fpo_learns_cartpole_balance(tmp_path):
    cfg = make_config("quick", "CartpoleBalance", algo="fpo", representation="none")
    assert (cfg.critic, cfg.clip_eps, cfg.fpo_samples, cfg.fpo_flow_steps) == ("q", 0.05, 8, 10)
    random_returns = _random_policy_returns(cfg)
    threshold = random_returns.mean() + 3 * random_returns.std()
    result = onpolicy.train(cfg, (0,), tmp_path / "learn", progress=False, plot=False)
    rows = result.run.read_rows()
    assert rows[-1]["env_steps"] == 786_432 and rows[0]["eval_return"] < threshold
    assert rows[-1]["eval_return"] > threshold, ([r["eval_return"] for r in rows], threshold)
    assert set(result.state.params) == {"actor", "obs_norm", "psi", "q"}
    assert onpolicy.method_label(cfg) == "FPO+Q(λ)"


@pytest.mark.parametrize("task,algo,representation,overrides,text", [
    ("CartpoleBalance", "fpo", "sf2-ae", {}, "algo 'fpo' with representation 'sf2-ae' does not exist"),
    ("CartpoleBalance", "fpo", "sf2", {"critic": "v"}, "representation 'sf2' takes critic 'q'"),
    ("CartpoleBalance", "fpo", "none", {"fpo_samples": 0}, "fpo_samples = 0"),
    ("CartpoleBalance", "fpo", "none", {"fpo_flow_steps": 1.5}, "fpo_flow_steps"),
    ("CartpoleBalance", "fpo", "none", {"fpo_log_ratio_clip": 0.0}, "fpo_log_ratio_clip = 0.0"),
    ("CartpoleBalance", "fpo", "none", {"minibatch_size": 1000}, "must divide the rollout's"),
    ("minatar-breakout", "fpo", "none", {}, "task 'minatar-breakout' is a MinAtar task"),
])
def test_bad_fpo_configs_are_refused(task, algo, representation, overrides, text):
    with pytest.raises(ConfigError) as err:
        validate(make_config("quick", task, algo=algo, representation=representation, overrides=overrides))
    assert text in str(err.value)


def test_fpo_presets():
    """`paper` is the authors' FpoConfig: 2048 envs × 480 steps (their 32 minibatches of 1024 sequences of
    30 steps), 16 passes, lr 3e-4, clip 0.05, γ 0.995, reward scaling 10, their 60M env steps as the 61
    whole updates their loop runs, an evaluation after each."""
    cfg = make_config("paper", "CheetahRun", algo="fpo", representation="sf2")
    assert (cfg.num_envs, cfg.rollout_length, cfg.minibatch_size) == (2048, 480, 30_720)
    assert cfg.update_epochs == 16
    assert (cfg.learning_rate, cfg.clip_eps, cfg.discount, cfg.reward_scaling) == (3e-4, 0.05, 0.995, 10.0)
    assert (cfg.adam_eps, cfg.episode_length, cfg.action_repeat) == (1e-8, 1000, 1)
    sched = schedule(validate(cfg))
    assert (sched.num_epochs, sched.actor_steps_per_epoch, sched.total_env_steps) == (61, 1, 59_965_440)
    assert sched.sgd_steps_per_actor_step == 16 * 32
