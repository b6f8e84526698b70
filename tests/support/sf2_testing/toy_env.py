"""A tiny user environment for the trainers' import-path tests (`--task sf2_testing.toy_env:make_env`).

A point on a line: position x ∈ [-1, 1], two action dimensions, x′ = clip(x + 0.1·a₀, -1, 1), reward
r = mean(a), so the best policy acts a = (1, 1) everywhere and earns 1 per step. Observations are a dict as
Playground's locomotion tasks return them: 'state' = (x, 1) for the agents, 'privileged_state' = (x, 1, 0)
(unused). It never terminates: the trainers' time limit cuts its episodes. States are Playground's
`State` (its auto-reset caches `data`). `make_brax_env` is the same env as a Brax `Env` (`pipeline_state`);
`make_image_env`, `make_discrete_env` and `make_not_env` build what the trainers refuse. `check_toy_run`
is what both cores' import-path training tests assert of a run of `TOY_OVERRIDES`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["ToyEnv", "make_env", "make_brax_env", "make_image_env", "make_discrete_env", "make_not_env",
           "TOY_TASK", "TOY_OVERRIDES", "check_toy_run"]

TOY_TASK = "sf2_testing.toy_env:make_env"
# Seconds per run: 8 envs, 20-step episodes, 3 epochs of 40 actor steps (the first 8 the prefill), 4 SGD
# steps per actor step at a high learning rate, 16-wide networks
TOY_OVERRIDES = dict(num_timesteps=8 * 120, num_evals=4, num_envs=8, num_eval_envs=8, episode_length=20,
                     batch_size=32, grad_updates_per_step=4, min_replay_size=64, max_replay_size=2048,
                     learning_rate=1e-2, feature_size=8, hidden_sizes=(16,), q_hidden_size=16,
                     zeta_hidden_sizes=(16,), embedding_size=4)


class ToyEnv:
    """The environment of the module docstring, as Playground's `MjxEnv` interface: reset(rng) and
    step(state, action) → State, observation_size {key: shape}, action_size."""

    action_size = 2
    observation_size = {"state": (2,), "privileged_state": (3,)}

    def _state(self, x, reward, done):
        from mujoco_playground import State

        obs = {"state": jnp.stack([x[0], 1.0]), "privileged_state": jnp.stack([x[0], 1.0, 0.0])}
        return State(data=x, obs=obs, reward=reward, done=done, metrics={}, info={})

    def reset(self, rng: jax.Array):
        x = jax.random.uniform(rng, (1,), minval=-0.5, maxval=0.5)
        return self._state(x, jnp.zeros(()), jnp.zeros(()))

    def step(self, state, action: jax.Array):
        x = jnp.clip(state.data + 0.1 * action[:1], -1.0, 1.0)
        new = self._state(x, jnp.mean(action), jnp.zeros(()))
        return new.replace(info=state.info, metrics=state.metrics)


def make_env() -> ToyEnv:
    """The toy environment (an import-path task's callable: no arguments)."""
    return ToyEnv()


def make_brax_env():
    """The toy environment as a Brax `Env` (its state's `pipeline_state` holds x)."""
    from brax.envs.base import Env, State

    class BraxToyEnv(Env):
        backend = "mjx"
        observation_size = 2
        action_size = 2

        def reset(self, rng):
            x = jax.random.uniform(rng, (1,), minval=-0.5, maxval=0.5)
            return State(pipeline_state=x, obs=jnp.stack([x[0], 1.0]), reward=jnp.zeros(()),
                         done=jnp.zeros(()))

        def step(self, state, action):
            x = jnp.clip(state.pipeline_state + 0.1 * action[:1], -1.0, 1.0)
            return state.replace(pipeline_state=x, obs=jnp.stack([x[0], 1.0]), reward=jnp.mean(action))

    return BraxToyEnv()


def make_image_env() -> ToyEnv:
    """The toy environment declaring Playground's vision observations (refused before it is stepped)."""
    env = ToyEnv()
    env.observation_size = {"pixels/view_0": (64, 64, 3)}
    return env


def make_discrete_env() -> ToyEnv:
    """The toy environment declaring discrete actions as pgx's envs do (`num_actions`)."""
    env = ToyEnv()
    env.num_actions = 3
    return env


def make_not_env() -> dict:
    """Not an environment: what a factory returning its config by mistake gives."""
    return {"episode_length": 20}


def check_toy_run(cfg, run, spec) -> None:
    """A run of `TOY_TASK` with `TOY_OVERRIDES` (seed 0): its folder names the task; the agents saw the
    'state' entry (2 numbers, not the privileged 3); each epoch did 40 actor steps of 8 envs; the greedy
    policy's return rose to at least 3/4 of the optimum (episode_length · 1: reward mean(a) ≤ 1 per step)."""
    import json

    assert json.loads(run.config_path.read_text())["config"]["task"] == TOY_TASK == cfg.task
    assert (spec.obs_size, spec.action_size) == (2, 2)
    rows = run.read_rows()
    assert [(r["epoch"], r["env_steps"]) for r in rows] == [(e, e * 8 * 40) for e in range(4)]
    best = cfg.episode_length * 1.0
    assert rows[-1]["eval_return"] >= 0.75 * best > rows[0]["eval_return"], [r["eval_return"] for r in rows]
