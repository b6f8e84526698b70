"""A trajectory replay buffer for goal-conditioned learners: every env's last `capacity` steps in time order,
with hindsight goals sampled from the same episode's future (CRL, docs/crl.md).

The state is a pytree on the device: per step and env the state part of the observation, the action and
the env's episode counter (which changes exactly where an episode ended), a ring over time written in
place. `sample` draws (env, step) uniformly over the stored steps and a goal k ≥ 1 steps ahead in the same
episode with P(k) ∝ γ^k, truncated at the episode's last stored step (`losses_crl.future_offset`; k = 0
where the step is the last stored one); the end is found by a binary search over the episode counters. It
also returns the next step (s′, a′) and whether it belongs to the same episode. Every draw comes from the
key argument.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from sf2_jax.losses_crl import future_offset

__all__ = ["GoalSample", "TrajectoryBuffer"]


class GoalSample(NamedTuple):
    """A batch of B stored steps with their hindsight goals.

    Attributes:
      state: s (B, S).
      action: a (B, A).
      goal_state: the state k steps ahead in the same episode (B, S) (s itself where k = 0).
      next_state: s′, the next stored step of the env (B, S).
      next_action: a′, the action taken there (B, A).
      last: 1 where s′ is not the same episode's (the episode ended at s, or s is the newest step), else 0.
    """

    state: Any
    action: Any
    goal_state: Any
    next_state: Any
    next_action: Any
    last: Any


class TrajectoryBuffer:
    """Steps of `num_envs` envs, the newest `capacity` of each (module docstring)."""

    def __init__(self, capacity: int, num_envs: int, state_size: int, action_size: int, dtype=jnp.float32):
        """Set the sizes (the buffer's state is made by `init`).

        Args:
          capacity: steps kept per env.
          num_envs: N.
          state_size: S.
          action_size: A.
          dtype: of the stored states and actions.
        """
        self.capacity, self.num_envs = int(capacity), int(num_envs)
        self.state_size, self.action_size, self.dtype = state_size, action_size, dtype
        self.search_steps = max(int(self.capacity).bit_length(), 1)   # ⌈log2(capacity + 1)⌉

    def init(self) -> dict[str, Any]:
        """An empty buffer: {"state", "action", "episode" (capacity, N, ·), "position": 0, "size": 0}."""
        T, N = self.capacity, self.num_envs
        return {"state": jnp.zeros((T, N, self.state_size), self.dtype),
                "action": jnp.zeros((T, N, self.action_size), self.dtype),
                "episode": jnp.zeros((T, N), jnp.int32),
                "position": jnp.zeros((), jnp.int32), "size": jnp.zeros((), jnp.int32)}

    def insert(self, buf: dict[str, Any], state, action, episode) -> dict[str, Any]:
        """Write one step of every env over the oldest.

        Args:
          buf: the buffer.
          state: (N, S) the states acted in.
          action: (N, A) the actions taken.
          episode: (N,) int32, each env's episode counter at that step.

        Returns:
          The new buffer.
        """
        p = buf["position"]
        return {"state": buf["state"].at[p].set(state.astype(self.dtype)),
                "action": buf["action"].at[p].set(action.astype(self.dtype)),
                "episode": buf["episode"].at[p].set(episode.astype(jnp.int32)),
                "position": (p + 1) % self.capacity, "size": jnp.minimum(buf["size"] + 1, self.capacity)}

    def steps_left(self, buf: dict[str, Any], env, index):
        """n: how many stored steps after logical step `index` (0 = the oldest) of env `env` belong to the
        same episode; a binary search, the counters being nondecreasing in time.

        Args:
          buf: the buffer.
          env: (B,) env indices.
          index: (B,) logical step indices in [0, size).

        Returns:
          n (B,) int32.
        """
        size = buf["size"]
        start = (buf["position"] - size) % self.capacity
        episode = buf["episode"][(start + index) % self.capacity, env]

        def same(j):
            return buf["episode"][(start + j) % self.capacity, env] == episode

        def body(_, bounds):   # invariant: `lo` is in the episode; `hi` is past its end (or past `size`)
            lo, hi = bounds
            mid = (lo + hi) // 2
            inside = (mid < size) & same(jnp.minimum(mid, size - 1))
            return jnp.where(inside, mid, lo), jnp.where(inside, hi, mid)

        # unrolled: the ⌈log2(capacity + 1)⌉ steps become straight-line code XLA fuses, not a loop whose
        # every iteration a GPU host launches apart
        lo, _ = jax.lax.fori_loop(0, self.search_steps, body, (index, jnp.full_like(index, size)),
                                  unroll=True)
        return lo - index

    def sample(self, buf: dict[str, Any], key: jax.Array, n: int, gamma: float) -> GoalSample:
        """Draw `n` stored steps uniformly, each with a goal from its episode's future.

        Args:
          buf: the buffer (at least one step inserted).
          key: a PRNG key: split in three (env, step, the goal's uniform draw).
          n: B.
          gamma: γ of the goals' geometric law.

        Returns:
          A `GoalSample`.
        """
        k_env, k_step, k_goal = jax.random.split(key, 3)
        size = jnp.maximum(buf["size"], 1)
        env = jax.random.randint(k_env, (n,), 0, self.num_envs)
        index = jax.random.randint(k_step, (n,), 0, size)
        left = self.steps_left(buf, env, index)
        offset = future_offset(jax.random.uniform(k_goal, (n,)), left, gamma)
        start = (buf["position"] - buf["size"]) % self.capacity

        def at(field, j):
            return buf[field][(start + jnp.minimum(j, size - 1)) % self.capacity, env]

        return GoalSample(state=at("state", index), action=at("action", index),
                          goal_state=at("state", index + offset), next_state=at("state", index + 1),
                          next_action=at("action", index + 1), last=(left == 0).astype(self.dtype))
