"""The MinAtar environments (sf2_jax.agents.minatar): shapes and dtypes per game, the truncation at the
episode limit (not a termination, its last observation kept, the env reset after), terminations, episode
returns against a plain Python loop over pgx's own `step`, determinism, and one jitted `lax.scan` of a
batch of envs that also vmaps over seeds.

pgx (the `[minatar]` extra) must be installed: without it every test here fails saying so, except the one
that asserts the "not installed" message (pgx hidden by an import monkeypatch).
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sf2_common.agents.tasks import MINATAR_TASKS
from sf2_common.errors import ConfigError

INSTALL = 'pip install "packages/sf2-core-jax[minatar]"'


@pytest.fixture(scope="module")
def minatar():
    """The env module, or a failure (never a skip) that says how to install pgx."""
    try:
        import pgx  # noqa: F401
    except ImportError:
        pytest.fail(f"pgx is not installed; the MinAtar env tests need the [minatar] extra: {INSTALL}",
                    pytrace=False)
    from sf2_jax.agents import minatar

    return minatar


def _rollout(env, key, num_envs: int, steps: int):
    """`steps` uniform random actions in `num_envs` envs, one `lax.scan`: (the actions, the transitions)."""
    reset_key, run_key = jax.random.split(key)
    state = env.reset(jax.random.split(reset_key, num_envs))

    def body(state, key):
        action_key, step_key = jax.random.split(key)
        action = jax.random.randint(action_key, (num_envs,), 0, env.spec.num_actions)
        state, transition = env.step(state, action, step_key)
        return state, (action, transition)

    return jax.lax.scan(body, state, jax.random.split(run_key, steps))


@pytest.fixture(scope="module")
def breakout_rollout(minatar):
    """A jitted rollout of Breakout (random episodes of 10 to 30 steps) truncated at 20 steps."""
    env = minatar.make("minatar-breakout", 20)
    return env, jax.jit(lambda key: _rollout(env, key, 8, 100))


def _types(tree):
    return [(x.shape, x.dtype, x.weak_type) for x in jax.tree.leaves(tree)]


@pytest.mark.parametrize("task", list(MINATAR_TASKS))
def test_shapes_dtypes_and_spec_per_game(minatar, task):
    import pgx

    env = minatar.make(task)
    shape, actions = MINATAR_TASKS[task].obs_shape, MINATAR_TASKS[task].num_actions
    game = pgx.make(task)
    assert env.spec == minatar.env_spec(task) == minatar.MinAtarSpec(task, shape, actions, 10_000, 0.1)
    assert (game.observation_shape, game.num_actions) == (shape, actions)   # the table agrees with pgx
    state = jax.jit(env.reset)(jax.random.split(jax.random.key(0), 3))
    state, tr = jax.jit(env.step)(state, jnp.array([0, 1, actions - 1]), jax.random.key(1))
    for obs in (state.obs, tr.next_obs):
        assert obs.shape == (3, *shape) and obs.dtype == jnp.float32
        assert set(np.unique(np.asarray(obs))) <= {0.0, 1.0}
    assert [(x.shape, x.dtype) for x in (tr.reward, tr.episode_return, tr.episode_length)] == [
        ((3,), jnp.float32), ((3,), jnp.float32), ((3,), jnp.int32)]
    assert tr.terminal.dtype == tr.truncation.dtype == jnp.bool_
    keys = jax.ShapeDtypeStruct((3,), jax.random.key(0).dtype)
    reset = jax.eval_shape(env.reset, keys)   # the scan's carry keeps its types: one compilation
    stepped, _ = jax.eval_shape(env.step, reset, jax.ShapeDtypeStruct((3,), jnp.int32), jax.random.key(0))
    assert _types(stepped) == _types(reset) and not any(weak for _, _, weak in _types(reset))


def test_truncation_keeps_the_last_observation_and_resets(minatar):
    """Freeway never ends before its own 2,500-step limit: every episode is cut at the 7th step. The same
    keys without the limit give the observation the truncated step must keep."""
    keys, actions = jax.random.split(jax.random.key(3), 2), jnp.array([1, 2])
    cut, uncut = minatar.make("minatar-freeway", 7), minatar.make("minatar-freeway", 100)
    state, free = cut.reset(keys), uncut.reset(keys)
    step, step_free = jax.jit(cut.step), jax.jit(uncut.step)
    for t in range(1, 8):
        state, tr = step(state, actions, jax.random.key(t))
        free, _ = step_free(free, actions, jax.random.key(t))
        assert not tr.terminal.any() and tr.truncation.all() == (t == 7) and (tr.episode_length == t).all()
    np.testing.assert_array_equal(tr.next_obs, free.obs)
    reset_keys = jnp.stack([jax.random.split(k)[1] for k in jax.random.split(jax.random.key(7), 2)])
    np.testing.assert_array_equal(state.obs, cut.reset(reset_keys).obs)
    assert (np.asarray(tr.next_obs) != np.asarray(state.obs)).any()
    assert (state.episode_length == 0).all() and (state.episode_return == 0).all()
    assert (state.game._step_count == 0).all() and (free.game._step_count == 7).all()


def test_termination_is_a_termination_also_at_the_limit(minatar, breakout_rollout):
    env, rollout = breakout_rollout
    _, (_, tr) = rollout(jax.random.key(0))
    terminal, truncation = np.asarray(tr.terminal), np.asarray(tr.truncation)
    assert terminal.any() and truncation.any() and not (terminal & truncation).any()
    assert (np.asarray(tr.episode_length)[truncation] == 20).all()
    # the first episode of env 0 ends at step L; with the limit at L it still is a termination
    first = int(np.argmax(terminal[:, 0] | truncation[:, 0]))
    assert terminal[first, 0], "env 0's first episode was truncated: pick another key"
    limit = first + 1
    at_limit = jax.jit(lambda key: _rollout(minatar.make("minatar-breakout", limit), key, 8, limit))
    _, (_, tr_limit) = at_limit(jax.random.key(0))
    assert tr_limit.terminal[-1, 0] and not tr_limit.truncation[-1, 0]
    assert int(tr_limit.episode_length[-1, 0]) == limit


def test_returns_are_the_sums_of_pgx_rewards(minatar, breakout_rollout):
    """The reference: pgx's own `init` and `step` in a Python loop, with the keys `step` derives."""
    import pgx

    env, rollout = breakout_rollout
    key = jax.random.key(5)
    _, (actions, tr) = rollout(key)
    game = pgx.make("minatar-breakout")
    init, step = jax.jit(game.init), jax.jit(game.step)
    reset_key, run_key = jax.random.split(key)
    n, limit = 8, env.spec.episode_length
    states = [init(k) for k in jax.random.split(reset_key, n)]
    ret, length, ended = np.zeros(n, np.float32), np.zeros(n, int), []
    for t, step_key in enumerate(jax.random.split(run_key, 100)):
        env_keys = jax.random.split(jax.random.split(step_key)[1], n)
        for i in range(n):
            game_key, new_key = jax.random.split(env_keys[i])
            states[i] = step(states[i], actions[t, i], game_key)
            ret[i] += float(states[i].rewards[0])
            length[i] += 1
            np.testing.assert_array_equal(tr.next_obs[t, i], states[i].observation.astype(np.float32))
            assert float(tr.reward[t, i]) == float(states[i].rewards[0])
            assert bool(tr.terminal[t, i]) == bool(states[i].terminated)
            assert bool(tr.truncation[t, i]) == (length[i] == limit and not bool(states[i].terminated))
            assert float(tr.episode_return[t, i]) == ret[i] and int(tr.episode_length[t, i]) == length[i]
            if states[i].terminated or length[i] == limit:
                ended.append(ret[i])
                states[i], ret[i], length[i] = init(new_key), 0.0, 0
    done = np.asarray(tr.terminal | tr.truncation)
    np.testing.assert_array_equal(np.sort(np.asarray(tr.episode_return)[done]), np.sort(ended))
    assert sum(ended) > 0


def test_deterministic_under_the_same_keys(breakout_rollout):
    _, rollout = breakout_rollout
    first, again, other = rollout(jax.random.key(7)), rollout(jax.random.key(7)), rollout(jax.random.key(8))
    jax.tree.map(np.testing.assert_array_equal, first, again)
    assert (np.asarray(first[1][1].next_obs) != np.asarray(other[1][1].next_obs)).any()


def test_one_scan_of_100_steps_of_8_envs_jits_and_vmaps_over_seeds(breakout_rollout):
    env, rollout = breakout_rollout
    keys = jax.random.split(jax.random.key(11), 2)
    batched = jax.jit(jax.vmap(lambda key: _rollout(env, key, 8, 100)))(keys)
    assert batched[1][1].next_obs.shape == (2, 100, 8, 10, 10, 4)
    for seed in range(2):
        jax.tree.map(np.testing.assert_array_equal, jax.tree.map(lambda x, s=seed: x[s], batched),
                     rollout(keys[seed]))


def test_bad_input_and_pgx_not_installed(monkeypatch):
    from sf2_jax.agents import minatar

    with pytest.raises(ConfigError, match="'CheetahRun' is not a MinAtar task. MinAtar tasks: minatar-"):
        minatar.make.__wrapped__("CheetahRun")   # Playground's tasks are not read
    with pytest.raises(ConfigError, match=r"'minatar-freway' is not a MinAtar task. Did you mean minatar-fr"):
        minatar.make.__wrapped__("minatar-freway")
    with pytest.raises(ConfigError, match="episode_length = 0 is invalid"):
        minatar.make.__wrapped__("minatar-breakout", 0)
    monkeypatch.setitem(sys.modules, "pgx", None)   # `import pgx` now raises ImportError
    with pytest.raises(ConfigError) as err:
        minatar.make.__wrapped__("minatar-breakout")
    assert "needs 'pgx', which is not installed" in str(err.value) and INSTALL in str(err.value)
