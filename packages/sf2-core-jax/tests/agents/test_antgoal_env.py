"""The goal-reaching Ant (sf2_jax.agents.antgoal): the observation's layout and goals on the circle, the
sparse reward, and the auto-reset fix: with `FreshAutoReset` every env gets a new goal at each reset and keeps
it for the episode; Brax's own AutoResetWrapper (JaxGCRL's training) keeps each env's first goal forever
(shown on a toy env: compiling the Ant's physics twice would double the test's time). The physics: under
uniform random actions the Ant of JaxGCRL's pipeline stays up and walks off, as JaxGCRL's data need.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sf2_common.errors import ConfigError
from sf2_jax.agents import antgoal

N, LENGTH, STEPS = 3, 2, 5   # envs, the time limit, steps: every env is reset at least twice


def _goals_over(env, key):
    """The goal of every env before each of STEPS steps under zero actions, and whether the step before
    it ended the episode: (goals (STEPS + 1, N, 2), reset (STEPS + 1, N) bool)."""
    def step(state, _):
        nxt = env.step(state, jnp.zeros((N, 8)))
        return nxt, (nxt.obs[:, -2:], nxt.done > 0)

    first = env.reset(jax.random.split(key, N))
    _, (goals, done) = jax.jit(lambda s: jax.lax.scan(step, s, None, length=STEPS))(first)
    goals = np.concatenate([np.asarray(first.obs[None, :, -2:]), np.asarray(goals)])
    reset = np.concatenate([np.zeros((1, N), bool), np.asarray(done)])
    return goals, reset


def test_goals_change_across_resets_and_hold_within_an_episode():
    goals, reset = _goals_over(antgoal.make(LENGTH).env, jax.random.PRNGKey(0))
    assert reset.sum(axis=0).min() >= 2, "every env should have been reset at least twice"
    # on the circle of radius 10, and one goal per episode
    np.testing.assert_allclose(np.linalg.norm(goals, axis=-1), antgoal.GOAL_DISTANCE, rtol=1e-5)
    for e in range(N):
        for t in range(1, STEPS + 1):
            moved = not np.allclose(goals[t, e], goals[t - 1, e])
            assert moved == reset[t, e], f"env {e} step {t}: goal moved {moved}, episode reset {reset[t, e]}"


class _GoalOnly:
    """A one-env Brax env whose whole state is a goal drawn at reset; every step ends the episode."""

    def reset(self, rng):
        from brax.envs.base import State

        goal = jax.random.uniform(rng, (2,))
        return State(pipeline_state=goal, obs=goal, reward=jnp.zeros(()), done=jnp.zeros(()), metrics={})

    def step(self, state, action):
        return state.replace(done=jnp.ones(()))


def test_the_defect_fixed_on_a_toy_env():
    """Brax's auto-reset restores the state of the first reset, so the first goal, after every reset
    (JaxGCRL's training); `FreshAutoReset` resets from a new key each time."""
    from brax.envs.wrappers.training import EpisodeWrapper, VmapWrapper, wrap

    old, old_reset = _goals_over(wrap(_GoalOnly(), episode_length=LENGTH), jax.random.PRNGKey(0))
    new, new_reset = _goals_over(antgoal.FreshAutoReset(EpisodeWrapper(VmapWrapper(_GoalOnly()), LENGTH, 1)),
                                 jax.random.PRNGKey(0))
    assert old_reset[1:].all() and new_reset[1:].all()
    np.testing.assert_array_equal(old, np.broadcast_to(old[0], old.shape))
    assert len(np.unique(new.reshape(-1, 2), axis=0)) == new.shape[0] * N


def test_layout_and_sparse_reward():
    ant = antgoal.ant_goal()
    state = jax.jit(ant.reset)(jax.random.PRNGKey(1))
    assert state.obs.shape == (antgoal.STATE_SIZE + 2,) and ant.action_size == 8
    # the state part is q (without the target's two slide joints) then qd; the goal is the target's (x, y)
    q, qd = state.pipeline_state.q, state.pipeline_state.qd
    np.testing.assert_array_equal(state.obs[: antgoal.STATE_SIZE], jnp.concatenate([q[:-2], qd[:-2]]))
    np.testing.assert_allclose(state.obs[-2:], q[-2:], atol=1e-6)
    # a goal names the state's GOAL_INDICES: the torso's world (x, y), the frame of the target's (x, y)
    torso, target = state.pipeline_state.x.pos[0], state.pipeline_state.x.pos[-1]
    np.testing.assert_allclose(state.obs[jnp.array(antgoal.GOAL_INDICES)], torso[:2], atol=1e-6)
    np.testing.assert_allclose(state.obs[-2:], target[:2], atol=1e-6)
    step = jax.jit(ant.step)
    far = step(state, jnp.zeros(8))
    assert float(far.reward) == 0.0 and float(far.metrics["dist"]) > 9.0
    # the goal put 0.3 from the torso: within 0.5, so the reward is 1 (and 0 at 0.7)
    for offset, reward in ((0.3, 1.0), (0.7, 0.0)):
        target = q[:2] + jnp.array([offset, 0.0])
        near = state.replace(pipeline_state=ant.pipeline_init(q.at[-2:].set(target), qd))
        out = step(near, jnp.zeros(8))
        assert float(out.reward) == reward == float(out.metrics["success"]), (offset, out.metrics["dist"])


def test_random_actions_keep_the_ant_up_and_moving():
    """JaxGCRL's `ant` (spring, 10 substeps of 0.005 s) under uniform random actions: of 16 envs, 15 are
    still up after 300 steps, having walked 1.4 to 7.3 from the origin; with MJX (JaxGCRL's MJX settings)
    every one has jumped above 1.0 or fallen within 10 to 88 steps, never 2.3 away; and spring at MJX's
    0.01 s step fails within 8 steps. Episodes that short hold no goal far away to learn from. So: at
    least 3/4 of the envs up after 100 steps, and the median env's torso at least 1 from where it began."""
    n, steps = 16, 100
    env = antgoal.make(steps + 1).env

    def step(carry, key):
        state, up = carry
        state = env.step(state, jax.random.uniform(key, (n, 8), minval=-1.0, maxval=1.0))
        return (state, up * (1.0 - state.done)), None

    first = env.reset(jax.random.split(jax.random.PRNGKey(2), n))
    (last, up), _ = jax.jit(lambda s: jax.lax.scan(step, (s, jnp.ones(n)), jax.random.split(
        jax.random.PRNGKey(3), steps)))(first)
    assert antgoal.SUBSTEPS[antgoal.BACKENDS[0]] == (0.005, 10) and env.dt == pytest.approx(0.05)
    assert up.sum() >= 0.75 * n, up
    walked = np.linalg.norm(last.obs[:, :2] - first.obs[:, :2], axis=-1)[np.asarray(up) > 0]
    assert np.median(walked) >= 1.0, walked


def test_unknown_backend():
    with pytest.raises(ConfigError, match="valid backends: spring, mjx"):
        antgoal.make(10, "generalized")
    with pytest.raises(ConfigError, match="valid backends: spring, mjx"):
        antgoal.ant_goal("positional")
