"""A short TD3+SF² run on CartpoleBalance learns: its evaluation return beats a uniform-random policy's
by a wide, justified margin.

The run is the `quick` preset itself (the method's hyperparameters: γ 0.99, τ 0.005, lr 1e-3, γ_su
0.99, one midpoint step) cut to 44k env steps (~20k SGD steps, about a minute of training on a 2-core
CPU). The training trajectory does not depend on the budget or the number of evaluations (keys are
split per actor step), so this is exactly the start of `sf2-jax train --config quick`; with seed 0
that run evaluates at 883 after 43k steps on the machine these tests were written on.

The margin: the random policy's return is measured here with the same evaluation protocol (same
env wrapper, one 1000-step episode per env, 64 episodes): about 354 ± 58 (mean ± std of one episode,
maximum ~500). The trained policy's mean over 10 episodes must exceed random mean + 5 std (≈ 640):
above every random episode observed and 5 standard deviations of a single random episode above the
random mean (the standard error of a 10-episode mean is ~3x smaller still), while leaving room for
the run-to-run differences of XLA's CPU numerics across machines (the expected value is ~880)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sf2_jax.agents import envs, make_config
from sf2_jax.agents.trainer import train


def _random_policy_returns(cfg, n=64, seed=123):
    spec = envs.env_spec(cfg.task, cfg.episode_length, cfg.action_repeat)

    @jax.jit
    def run(key):
        k_reset, k_act = jax.random.split(key)
        state = spec.eval_env.reset(jax.random.split(k_reset, n))

        def step(carry, k):
            state, ret, alive = carry
            action = jax.random.uniform(k, (n, spec.action_size), minval=-1.0, maxval=1.0)
            state = spec.eval_env.step(state, action)
            return (state, ret + state.reward * alive, alive * (1.0 - state.done)), None

        (_, ret, _), _ = jax.lax.scan(step, (state, jnp.zeros(n), jnp.ones(n)),
                                      jax.random.split(k_act, cfg.episode_length))
        return ret

    return np.asarray(run(jax.random.PRNGKey(seed)))


@pytest.mark.slow
def test_td3_sf2_learns_cartpole_balance(tmp_path):
    cfg = make_config("quick", "CartpoleBalance", algo="td3", representation="sf2",
                      overrides=dict(num_timesteps=44_000, num_evals=2))
    random_returns = _random_policy_returns(cfg)
    threshold = random_returns.mean() + 5 * random_returns.std()
    assert threshold > random_returns.max()
    result = train(cfg, (0,), tmp_path / "learn", progress=False)
    final = result.rows[-1]
    assert final["env_steps"] >= 44_000
    assert final["eval_return"] > threshold, (final["eval_return"], threshold)
