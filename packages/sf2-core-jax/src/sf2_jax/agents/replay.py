"""Device replay buffer: a fixed-size ring of transitions, uniform sampling with replacement.

Why not Brax's `UniformSamplingQueue`: its insert shifts the whole buffer with `jnp.roll` under a
`lax.cond` once it is full. Under `vmap` over seeds the predicate is batched, the cond becomes a
select, and every insert then copies the entire buffer (GBs per actor step at the paper's 4M size).
This ring buffer writes in place (a scatter at (position + i) mod capacity) and samples uniformly over
the filled part; the sampling key is an explicit argument, so all randomness flows from the trainer's
key. Statistically it is the same buffer: uniform over the last `capacity` transitions.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from sf2_jax.losses import Batch

__all__ = ["ReplayBuffer"]


class ReplayBuffer:
    """A fixed-size ring of transitions on the device; its state is a pytree the trainer carries."""

    def __init__(self, capacity: int, obs_size: int, action_size: int, dtype=jnp.float32):
        """Set the buffer's sizes (it holds no state: `init` makes it).

        Args:
          capacity: transitions kept (the newest).
          obs_size: D.
          action_size: A.
          dtype: of every stored field.
        """
        self.capacity = int(capacity)
        self.obs_size = obs_size
        self.action_size = action_size
        self.dtype = dtype

    def init(self) -> dict[str, Any]:
        """An empty buffer.

        Returns:
          {"data": a `Batch` of zeros (capacity, ·), "position": 0, "size": 0}.
        """
        n, d, a, f = self.capacity, self.obs_size, self.action_size, self.dtype
        data = Batch(obs=jnp.zeros((n, d), f), action=jnp.zeros((n, a), f), reward=jnp.zeros((n,), f),
                     discount=jnp.zeros((n,), f), next_obs=jnp.zeros((n, d), f),
                     truncation=jnp.zeros((n,), f))
        return {"data": data, "position": jnp.zeros((), jnp.int32), "size": jnp.zeros((), jnp.int32)}

    def insert(self, state: dict[str, Any], batch: Batch) -> dict[str, Any]:
        """Write transitions over the oldest ones.

        Args:
          state: the buffer's state.
          batch: n ≤ capacity transitions, every field (n, ·).

        Returns:
          The new state.
        """
        n = batch.obs.shape[0]
        idx = (state["position"] + jnp.arange(n, dtype=jnp.int32)) % self.capacity
        data = jax.tree_util.tree_map(lambda d, x: d.at[idx].set(x.astype(d.dtype)), state["data"], batch)
        return {"data": data, "position": (state["position"] + n) % self.capacity,
                "size": jnp.minimum(state["size"] + n, self.capacity)}

    def sample(self, state: dict[str, Any], key: jax.Array, n: int) -> Batch:
        """Draw transitions uniformly with replacement from the filled part.

        Args:
          state: the buffer's state (at least one transition inserted).
          key: a PRNG key.
          n: how many.

        Returns:
          A `Batch` of n transitions.
        """
        idx = jax.random.randint(key, (n,), 0, jnp.maximum(state["size"], 1))
        return jax.tree_util.tree_map(lambda d: jnp.take(d, idx, axis=0), state["data"])

    def size(self, state: dict[str, Any]):
        """The number of transitions held (a scalar array)."""
        return state["size"]
