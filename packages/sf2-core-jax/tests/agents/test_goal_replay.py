"""The trajectory buffer (sf2_jax.agents.goal_replay): the steps left in an episode found by the binary
search against a Python count, after the ring wrapped; sampled goals always in the same episode and ahead of
the step, the next step and its flag; the geometric law of the offsets when episodes are long.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sf2_jax.agents.goal_replay import TrajectoryBuffer

T, N = 8, 2
# two envs over 11 steps: the episode counter of each step (env 0 ends episodes after steps 2 and 6, env 1
# after step 9); only the last 8 steps (3..10) stay
EPISODES = np.array([[0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2], [0] * 10 + [1]]).T


def _filled():
    buf = TrajectoryBuffer(T, N, state_size=1, action_size=1)
    state = buf.init()
    code = 1000.0 * jnp.arange(N)[:, None]   # the state is 1000 · env + the step's time; the action + 100
    for t, ep in enumerate(EPISODES):
        state = buf.insert(state, code + t, code + t + 100.0, jnp.asarray(ep))
    return buf, state


def test_steps_left_after_the_ring_wrapped():
    buf, state = _filled()
    kept = EPISODES[-T:]
    env, index = np.repeat(np.arange(N), T), np.tile(np.arange(T), N)
    by_hand = [sum(1 for j in range(i + 1, T) if kept[j, e] == kept[i, e]
                   and all(kept[m, e] == kept[i, e] for m in range(i, j))) for e, i in zip(env, index)]
    np.testing.assert_array_equal(buf.steps_left(state, jnp.asarray(env), jnp.asarray(index)), by_hand)


def test_goals_stay_in_the_episode_and_ahead():
    buf, state = _filled()
    s = buf.sample(state, jax.random.PRNGKey(0), 4096, 0.9)
    env, t = np.divmod(np.asarray(s.state)[:, 0].astype(int), 1000)
    goal_env, goal = np.divmod(np.asarray(s.goal_state)[:, 0].astype(int), 1000)
    nxt = np.asarray(s.next_state)[:, 0].astype(int) % 1000
    assert set(env) == {0, 1} and (goal_env == env).all()
    np.testing.assert_array_equal(np.asarray(s.action)[:, 0], 1000 * env + t + 100)
    assert (t >= 3).all() and (goal >= t).all() and (goal <= 10).all()
    assert (EPISODES[goal, env] == EPISODES[t, env]).all()
    last = np.asarray(s.last) > 0
    # a goal is the step itself only where the step is its episode's last stored one
    np.testing.assert_array_equal(goal == t, last)
    ends = EPISODES[np.minimum(t + 1, 10), env] != EPISODES[t, env]
    np.testing.assert_array_equal(last, (t == 10) | ends)
    np.testing.assert_array_equal(nxt[~last], t[~last] + 1)
    np.testing.assert_array_equal(np.asarray(s.next_action)[~last, 0] % 1000, t[~last] + 101)


def test_offsets_follow_the_geometric_law():
    buf = TrajectoryBuffer(256, 1, state_size=1, action_size=1)
    state = buf.init()
    for t in range(256):   # one episode of 256 steps
        state = buf.insert(state, jnp.full((1, 1), float(t)), jnp.zeros((1, 1)), jnp.zeros(1, jnp.int32))
    s = buf.sample(state, jax.random.PRNGKey(1), 20_000, 0.9)
    k = np.asarray(s.goal_state - s.state)[:, 0]
    far = np.asarray(s.state)[:, 0] < 200          # steps with ≥ 55 steps left: 0.9^55 < 0.004 truncated
    assert np.mean(k[far] == 1) == pytest.approx(0.1, abs=0.01)
    assert np.mean(k[far]) == pytest.approx(10.0, rel=0.05)   # E k = 1 / (1 − γ)
