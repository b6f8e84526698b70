"""The goal-reaching Ant (`ant-goal`, docs/crl.md): JaxGCRL's `ant` task on this repository's Brax.

Ported from JaxGCRL (github.com/MichalBortkiewicz/JaxGCRL, jaxgcrl/envs/ant.py and assets/ant.xml, itself
based on Brax's Ant), Apache License 2.0, copyright its authors (docs/licenses.md). A goal (x, y) is drawn
uniformly on the circle of radius 10; the observation is the 29 joint positions and velocities then the
goal; the reward is 1 where the torso is within 0.5 of the goal, else 0; an episode ends when the torso's
height leaves [0.2, 1.0] or after `episode_length` steps. The physics is JaxGCRL's default for `ant`,
Brax's spring pipeline at 10 substeps of 0.005 s (MJX, with JaxGCRL's MJX solver settings and 5 substeps
of 0.01 s, is offered; docs/crl.md). Changes: JaxGCRL's dense reward, random start and contact-force options
are dropped; `make` replaces Brax's auto-reset, which restores each env's first state (so its first goal)
forever, by `FreshAutoReset`, which resets a finished env from a new key.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp

__all__ = ["STATE_SIZE", "GOAL_INDICES", "GOAL_DISTANCE", "GOAL_RADIUS", "BACKENDS", "SUBSTEPS",
           "ant_goal", "FreshAutoReset", "GoalEnvSpec", "make"]

STATE_SIZE = 29           # the observation's state part: q without the target's 2 joints (15), then qd (14)
GOAL_INDICES = (0, 1)     # the state entries a goal names: the torso's (x, y)
GOAL_DISTANCE = 10.0      # goals lie on the circle of this radius around the origin
GOAL_RADIUS = 0.5         # success: the torso within this distance of the goal
BACKENDS = ("spring", "mjx")   # Brax pipelines offered, the first the default (JaxGCRL's for `ant`)
SUBSTEPS = {"spring": (0.005, 10), "mjx": (0.01, 5)}   # (timestep in s, substeps per env step): JaxGCRL's
_ASSET = os.path.join(os.path.dirname(os.path.realpath(__file__)), "assets", "ant_goal.xml")


def ant_goal(backend: str = BACKENDS[0]):
    """One goal-reaching Ant (module docstring), a Brax `PipelineEnv` (Brax imported on first use).

    Args:
      backend: one of `BACKENDS`.

    Returns:
      The env: Brax's `reset(key)` and `step(state, action)` for one env.

    Raises:
      ConfigError: an unknown backend.
    """
    _check_backend(backend)
    return _ant_goal_class()(backend)


def _check_backend(backend: str) -> None:
    from sf2_common.errors import ConfigError

    if backend not in BACKENDS:
        raise ConfigError(f"ant-goal backend {backend!r} is unknown; valid backends: {', '.join(BACKENDS)}")


@functools.cache
def _ant_goal_class():
    import mujoco
    from brax import math
    from brax.envs.base import PipelineEnv, State
    from brax.io import mjcf

    class _AntGoal(PipelineEnv):
        def __init__(self, backend: str):
            timestep, n_frames = SUBSTEPS[backend]
            sys = mjcf.load(_ASSET).tree_replace({"opt.timestep": timestep})
            if backend == "mjx":   # JaxGCRL's solver settings for its MJX Ant
                sys = sys.tree_replace({"opt.solver": mujoco.mjtSolver.mjSOL_NEWTON,
                                        "opt.disableflags": mujoco.mjtDisableBit.mjDSBL_EULERDAMP,
                                        "opt.iterations": 1, "opt.ls_iterations": 4})
            super().__init__(sys=sys, backend=backend, n_frames=n_frames)
            self.state_dim = STATE_SIZE
            self.goal_indices = jnp.array(GOAL_INDICES)

        def reset(self, rng: jax.Array) -> State:
            rng, k_q, k_qd, k_goal = jax.random.split(rng, 4)
            q = self.sys.init_q + jax.random.uniform(k_q, (self.sys.q_size(),), minval=-0.1, maxval=0.1)
            qd = 0.1 * jax.random.normal(k_qd, (self.sys.qd_size(),))
            angle = 2.0 * jnp.pi * jax.random.uniform(k_goal)
            goal = GOAL_DISTANCE * jnp.array([jnp.cos(angle), jnp.sin(angle)])
            q, qd = q.at[-2:].set(goal), qd.at[-2:].set(0.0)
            pipeline_state = self.pipeline_init(q, qd)
            zero = jnp.zeros(())
            metrics = {name: zero for name in ("dist", "success", "success_easy", "distance_from_origin")}
            return State(pipeline_state, self._obs(pipeline_state), zero, zero, metrics)

        def step(self, state: State, action: jax.Array) -> State:
            pipeline_state = self.pipeline_step(state.pipeline_state, action)
            z = pipeline_state.x.pos[0, 2]
            healthy = jnp.where((z < 0.2) | (z > 1.0), 0.0, 1.0)
            obs = self._obs(pipeline_state)
            dist = jnp.linalg.norm(obs[:2] - obs[-2:])
            success = (dist < GOAL_RADIUS).astype(jnp.float32)
            state.metrics.update(dist=dist, success=success, success_easy=(dist < 2.0).astype(jnp.float32),
                                 distance_from_origin=math.safe_norm(pipeline_state.x.pos[0]))
            return state.replace(pipeline_state=pipeline_state, obs=obs, reward=success, done=1.0 - healthy)

        def _obs(self, pipeline_state) -> jax.Array:
            """[q without the target's joints, qd without them, the target's (x, y)]."""
            return jnp.concatenate([pipeline_state.q[:-2], pipeline_state.qd[:-2],
                                    pipeline_state.x.pos[-1][:2]])

    return _AntGoal


class FreshAutoReset:
    """Brax's `AutoResetWrapper` with a fresh reset: an env whose episode ended is reset from a new key (its
    own, carried in `state.info["reset_key"]` and split at every step), so it gets a new goal and start.

    Brax's wrapper (and so JaxGCRL's training) restores the state cached at the first reset instead, so
    every env pursues its first goal for the whole run. The step's obs is the new episode's first obs where
    the step ended one, as in Brax; `info["steps"]` restarts at 0 there."""

    def __init__(self, env):
        self.env = env

    def reset(self, rng: jax.Array):
        """Reset every env; rng (N, 2) one key each."""
        state = self.env.reset(rng)
        state.info["reset_key"] = jax.vmap(lambda k: jax.random.fold_in(k, 1))(rng)
        return state

    def step(self, state, action: jax.Array):
        """Step every env; those done are then reset from `split(reset_key)[1]`."""
        steps = jnp.where(state.done, jnp.zeros_like(state.info["steps"]), state.info["steps"])
        state.info.update(steps=steps)
        state = self.env.step(state.replace(done=jnp.zeros_like(state.done)), action)
        keys = jax.vmap(jax.random.split)(state.info["reset_key"])
        fresh = self.env.reset(keys[:, 1])

        def where_done(new, old):
            done = jnp.reshape(state.done, state.done.shape + (1,) * (old.ndim - state.done.ndim))
            return jnp.where(done, new, old)

        pipeline_state = jax.tree_util.tree_map(where_done, fresh.pipeline_state, state.pipeline_state)
        state.info["reset_key"] = keys[:, 0]
        return state.replace(pipeline_state=pipeline_state, obs=where_done(fresh.obs, state.obs))

    def __getattr__(self, name):     # observation_size, action_size, ...
        return getattr(self.env, name)


@dataclass(frozen=True)
class GoalEnvSpec:
    """The batched `ant-goal` env and its sizes.

    Attributes:
      env: the batched env: `reset(keys (N, 2))`, `step(state, actions (N, 8))`; Brax's `State`, with
        `info["truncation"]` 1 where the time limit ended the episode and `info["episode_metrics"]` the
        sums of the metrics over the running episode.
      obs_size: STATE_SIZE + 2.
      state_size: STATE_SIZE.
      goal_indices: GOAL_INDICES.
      action_size: 8.
      episode_length: the time limit in steps.
    """

    env: Any
    obs_size: int
    state_size: int
    goal_indices: tuple[int, ...]
    action_size: int
    episode_length: int


@functools.lru_cache(maxsize=4)
def make(episode_length: int = 1000, backend: str = BACKENDS[0]) -> GoalEnvSpec:
    """The batched `ant-goal` env: `ant_goal` under Brax's `VmapWrapper` and `EpisodeWrapper`, then
    `FreshAutoReset` and `envs.StrongTypes`.

    Args:
      episode_length: steps after which an episode is truncated.
      backend: one of `BACKENDS`.

    Returns:
      Its `GoalEnvSpec` (cached).

    Raises:
      ConfigError: an unknown backend.
    """
    from brax.envs.wrappers.training import EpisodeWrapper, VmapWrapper

    _check_backend(backend)
    from .envs import StrongTypes  # every state leaf strongly typed: a program compiles once

    ant = ant_goal(backend)
    env = StrongTypes(FreshAutoReset(EpisodeWrapper(VmapWrapper(ant), episode_length, 1)))
    return GoalEnvSpec(env=env, obs_size=int(ant.observation_size), state_size=STATE_SIZE,
                       goal_indices=GOAL_INDICES, action_size=int(ant.action_size),
                       episode_length=episode_length)
