"""A short TD3+SF² run on CartpoleBalance learns: an evaluation in its second half beats a uniform-random
policy by a wide, justified margin.

The run is the `quick` preset itself (γ 0.99, τ 0.005, lr 1e-3, γ_su 0.99, one midpoint step) cut to 44k
env steps (~20k SGD steps, about a minute and a half on a 2-core CPU), evaluated nine times (the first at
the start). The random policy's return, measured with the same protocol (one 1000-step episode per env, 64
episodes): about 354 ± 58 (mean ± std of one episode, maximum ~500). The best evaluation (10 episodes) of
the second half must exceed random mean + 5 std (≈ 640): above every random episode observed. The best,
not the last: one seed's late policy swings between evaluations, and XLA's CPU numerics differ across
machines (vector widths), so its trajectory does too; on one 2-core CPU seed 0's last three evaluations
were 987, 904, 744, and the run evaluated only at its start and end (44,000 env steps) ended at 450.
A policy that reaches a return no random episode reaches has learned; the second half's mean must also
exceed the best random episode (≈ 500; 770 in that run), so one lucky evaluation does not pass."""

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
                      overrides=dict(num_timesteps=44_000, num_evals=9))
    random_returns = _random_policy_returns(cfg)
    threshold = random_returns.mean() + 5 * random_returns.std()
    assert threshold > random_returns.max()
    result = train(cfg, (0,), tmp_path / "learn", progress=False)
    rows = result.rows
    assert rows[-1]["env_steps"] >= 44_000 and len(rows) == 9
    late = [r["eval_return"] for r in rows if r["env_steps"] >= rows[-1]["env_steps"] / 2]
    assert len(late) >= 4 and max(late) > threshold, ([r["eval_return"] for r in rows], threshold)
    # and the second half as a whole stays above every random episode: learned, not one lucky evaluation
    assert np.mean(late) > random_returns.max(), ([r["eval_return"] for r in rows], random_returns.max())
