"""MinAtar games from pgx as batched, functional environments for the on-policy trainer (docs/minatar.md).

`make(task)` builds one of `MINATAR_TASKS` with pgx's defaults (minimal action set, sticky actions 0.1).
`reset(keys)` and `step(state, action, key)` are pure functions of arrays over a batch of envs, so a
trainer can `jit`, `vmap` and `lax.scan` them with no host sync. Each step returns a `Transition`: the
float32 10×10×C observation after the step (before any reset, for bootstrapping), the reward, `terminal`
(the game ended) and `truncation` (the episode reached `episode_length` agent steps, 10,000 by default: not
a termination), and the episode's return and length so far; an env whose episode ended is then reset.

pgx (the `[minatar]` extra; its MinAtar games are GPL-3.0, depended on, never vendored) is imported by
`make` only. `pgx.experimental.auto_reset` is not used: it drops the final observation of a truncation.
"""

from __future__ import annotations

import difflib
import functools
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from sf2_common.agents.tasks import KINDS, MINATAR_TASKS, check_installed
from sf2_common.errors import ConfigError

__all__ = ["MINATAR_TASKS", "EPISODE_LENGTH", "MinAtarSpec", "EnvState", "Transition", "MinAtarEnv", "make",
           "env_spec"]

EPISODE_LENGTH = KINDS["minatar"].episode_length


@dataclass(frozen=True)
class MinAtarSpec:
    """What a trainer needs to know of a MinAtar env before stepping it.

    Attributes:
      task: the game's id, e.g. 'minatar-breakout'.
      obs_shape: the observation's shape, (10, 10, C).
      num_actions: the size of the (minimal) action set; actions are int32 in [0, num_actions).
      episode_length: agent steps after which an episode is truncated.
      sticky_action_prob: the probability that the game repeats the previous action instead.
    """

    task: str
    obs_shape: tuple[int, int, int]
    num_actions: int
    episode_length: int
    sticky_action_prob: float


class EnvState(NamedTuple):
    """The state of a batch of envs (leading axis: the env).

    Attributes:
      game: pgx's state of each game.
      obs: the current observation, float32 (..., 10, 10, C) in {0, 1}.
      episode_return: the undiscounted return of the running episode so far, float32.
      episode_length: agent steps of the running episode so far, int32.
    """

    game: Any
    obs: jax.Array
    episode_return: jax.Array
    episode_length: jax.Array


class Transition(NamedTuple):
    """What one step of a batch of envs produced (leading axis: the env).

    Attributes:
      next_obs: the observation after the step, before the reset of an ended episode, float32.
      reward: float32.
      terminal: the game ended (no bootstrap).
      truncation: the episode reached the episode limit and the game did not end (bootstrap from
        `next_obs`).
      episode_return: the episode's return including this step (a completed episode's where
        `terminal | truncation`), float32.
      episode_length: the episode's agent steps including this step, int32.
    """

    next_obs: jax.Array
    reward: jax.Array
    terminal: jax.Array
    truncation: jax.Array
    episode_return: jax.Array
    episode_length: jax.Array


@dataclass(frozen=True, eq=False)
class MinAtarEnv:
    """A MinAtar game with auto-reset and a truncation, batched over envs. Build it with `make`.

    Attributes:
      spec: its `MinAtarSpec`.
      game: pgx's environment.
    """

    spec: MinAtarSpec
    game: Any

    def reset(self, keys: jax.Array) -> EnvState:
        """Fresh episodes, one per key.

        Args:
          keys: PRNG keys, shape (N, ...) for N envs.

        Returns:
          The `EnvState` of N new episodes.
        """
        return jax.vmap(self._reset_one)(keys)

    def step(self, state: EnvState, action: jax.Array, key: jax.Array) -> tuple[EnvState, Transition]:
        """One agent step of every env; an env whose episode ends starts a new one.

        Args:
          state: the `EnvState` of N envs.
          action: int32 (N,), each in [0, num_actions).
          key: one PRNG key for the step (sticky actions, the games' randomness, the resets).

        Returns:
          The next `EnvState` (reset where the episode ended) and the step's `Transition`.
        """
        keys = jax.random.split(key, action.shape[0])
        return jax.vmap(self._step_one)(state, action.astype(jnp.int32), keys)

    def _reset_one(self, key: jax.Array) -> EnvState:
        game = self.game.init(key)
        return EnvState(game, game.observation.astype(jnp.float32), jnp.zeros((), jnp.float32),
                        jnp.zeros((), jnp.int32))

    def _step_one(self, state: EnvState, action: jax.Array, key: jax.Array) -> tuple[EnvState, Transition]:
        step_key, reset_key = jax.random.split(key)
        game = self.game.step(state.game, action, step_key)
        next_obs = game.observation.astype(jnp.float32)
        reward = game.rewards[0].astype(jnp.float32)
        terminal = game.terminated
        length = state.episode_length + 1
        truncation = (length >= self.spec.episode_length) & ~terminal
        ret = state.episode_return + reward
        stepped = EnvState(game, next_obs, ret, length)
        fresh = self._reset_one(reset_key)
        done = terminal | truncation
        state = jax.tree.map(lambda f, s: jnp.where(done, f, s), fresh, stepped)
        return state, Transition(next_obs, reward, terminal, truncation, ret, length)


@functools.lru_cache(maxsize=16)
def make(task: str, episode_length: int = EPISODE_LENGTH) -> MinAtarEnv:
    """A MinAtar game with pgx's defaults: minimal action set, sticky actions with probability 0.1.

    Args:
      task: one of `MINATAR_TASKS`, e.g. 'minatar-breakout'.
      episode_length: agent steps after which an episode is truncated.

    Returns:
      Its `MinAtarEnv`, cached per (task, episode_length): the same object for the same arguments.

    Raises:
      ConfigError: not a MinAtar task, a bad `episode_length`, or pgx not installed.
    """
    if task not in MINATAR_TASKS:
        close = difflib.get_close_matches(str(task), MINATAR_TASKS, n=1)
        hint = f" Did you mean {close[0]}?" if close else ""
        raise ConfigError(f"task {task!r} is not a MinAtar task.{hint} MinAtar tasks: "
                          f"{', '.join(MINATAR_TASKS)}")
    if isinstance(episode_length, bool) or not isinstance(episode_length, int) or episode_length < 1:
        raise ConfigError(f"episode_length = {episode_length!r} is invalid: must be an int >= 1")
    check_installed(task)
    import pgx

    game = pgx.make(task)
    shape = jax.eval_shape(game.init, jax.random.key(0)).observation.shape
    spec = MinAtarSpec(task, tuple(int(n) for n in shape), int(game.num_actions), episode_length,
                       float(game.sticky_action_prob))
    return MinAtarEnv(spec, game)


def env_spec(task: str, episode_length: int = EPISODE_LENGTH) -> MinAtarSpec:
    """The `MinAtarSpec` of `make(task, episode_length)`; nothing is stepped.

    Args:
      task: one of `MINATAR_TASKS`.
      episode_length: agent steps after which an episode is truncated.

    Returns:
      Its `MinAtarSpec`.
    """
    return make(task, episode_length).spec
