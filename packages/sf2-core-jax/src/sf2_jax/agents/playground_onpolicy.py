"""Playground DM Control tasks as batched, functional environments for the on-policy trainer (docs/fpo.md).

The interface of `sf2_jax.agents.minatar` (`reset(keys)`, `step(state, action, key)` → (state,
`minatar.Transition`)), so the on-policy trainer drives both alike. The task is loaded with the pure-JAX
MJX backend (`config_overrides={'impl': 'jax'}`, as `envs.env_spec`); each env is vmapped, its episode
truncated after `episode_length` steps, and an ended episode restarts from that env's cached first state
(Brax's and FPO's auto-reset), while the transition keeps s′ before the reset (for the bootstrap at a
truncation). Actions are boxes in [−1, 1]^A, one physics step each (no action repeat).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from sf2_common.errors import ConfigError

from .envs import strong_types, validate_task
from .minatar import Transition

__all__ = ["PlaygroundSpec", "EnvState", "PlaygroundEnv", "make"]


@dataclass(frozen=True)
class PlaygroundSpec:
    """What a trainer needs to know of a Playground env before stepping it.

    Attributes:
      task: the task's name, e.g. 'CheetahRun'.
      obs_shape: (D,).
      num_actions: 0 (the actions are continuous).
      action_size: A, the action box's dimension.
      episode_length: agent steps after which an episode is truncated.
    """

    task: str
    obs_shape: tuple[int]
    num_actions: int
    action_size: int
    episode_length: int


class EnvState(NamedTuple):
    """The state of a batch of envs (leading axis: the env).

    Attributes:
      inner: Playground's state of each env.
      first: each env's first state, where an ended episode restarts.
      obs: the current observation, float32 (N, D).
      episode_return: the running episode's undiscounted return, float32.
      episode_length: the running episode's steps, int32.
    """

    inner: Any
    first: Any
    obs: jax.Array
    episode_return: jax.Array
    episode_length: jax.Array


@dataclass(frozen=True, eq=False)
class PlaygroundEnv:
    """A Playground task with a truncation and auto-reset, batched over envs. Build it with `make`.

    Attributes:
      spec: its `PlaygroundSpec`.
      env: Playground's environment.
    """

    spec: PlaygroundSpec
    env: Any

    def reset(self, keys: jax.Array) -> EnvState:
        """Fresh episodes, one per key (each becomes its env's first state).

        Args:
          keys: PRNG keys (N, ...).

        Returns:
          The `EnvState` of N new episodes.
        """
        inner = strong_types(jax.vmap(self.env.reset)(keys))
        n = inner.obs.shape[0]
        return EnvState(inner, inner, inner.obs.astype(jnp.float32), jnp.zeros((n,), jnp.float32),
                        jnp.zeros((n,), jnp.int32))

    def step(self, state: EnvState, action: jax.Array, key: jax.Array) -> tuple[EnvState, Transition]:
        """One step of every env with `action` in [−1, 1]^A; an env whose episode ended restarts.

        Args:
          state: the `EnvState` of N envs.
          action: float32 (N, A).
          key: unused (the physics is deterministic); the argument of `minatar.MinAtarEnv.step`.

        Returns:
          The next `EnvState` and the step's `minatar.Transition` (s′ before any reset).
        """
        del key
        stepped = strong_types(jax.vmap(self.env.step)(state.inner, action))
        next_obs = stepped.obs.astype(jnp.float32)
        reward = stepped.reward.astype(jnp.float32)
        terminal = stepped.done > 0
        length = state.episode_length + 1
        truncation = (length >= self.spec.episode_length) & ~terminal
        ret = state.episode_return + reward
        done = terminal | truncation

        def where(first, now):
            return jnp.where(done.reshape(done.shape + (1,) * (now.ndim - 1)), first, now)

        inner = jax.tree_util.tree_map(where, state.first, stepped)
        new = EnvState(inner, state.first, inner.obs.astype(jnp.float32), jnp.where(done, 0.0, ret),
                       jnp.where(done, 0, length))
        return new, Transition(next_obs, reward, terminal, truncation, ret, length)


@functools.lru_cache(maxsize=16)
def make(task: str, episode_length: int = 1000) -> PlaygroundEnv:
    """A Playground DM Control task for the on-policy trainer.

    Args:
      task: a Playground task name (`envs.valid_tasks`).
      episode_length: agent steps after which an episode is truncated.

    Returns:
      Its `PlaygroundEnv`, cached per (task, episode_length).

    Raises:
      ConfigError: an unknown task, a bad `episode_length`, or structured observations.
    """
    validate_task(task)
    if isinstance(episode_length, bool) or not isinstance(episode_length, int) or episode_length < 1:
        raise ConfigError(f"episode_length = {episode_length!r} is invalid: must be an int >= 1")
    from mujoco_playground import registry

    env = registry.load(task, config_overrides={"impl": "jax"})
    if not isinstance(env.observation_size, int):
        raise ConfigError(f"task {task!r} has structured observations {env.observation_size}; only flat "
                          f"state observations are supported")
    spec = PlaygroundSpec(task, (int(env.observation_size),), 0, int(env.action_size), episode_length)
    return PlaygroundEnv(spec, env)
