"""Replay buffer: TorchRL's `ReplayBuffer` on a `LazyTensorStorage` on the training device, uniform
sampling with replacement (`RandomSampler`) from the filled part, round-robin writes over the oldest
transitions: statistically the JAX agents' replay buffer (a fixed-size ring, uniform over the last
`capacity` transitions). The sampling generator is an explicit argument, so all randomness of a seed flows
from that seed's `torch.Generator`. Transitions use TorchRL's layout (`observation`, `action`,
`("next", observation | reward | done | terminated | truncated)`); `to_batch` turns sampled transitions
into the core's `sf2_torch.losses.Batch` (discount = 1 − done, truncation = truncated, as the JAX trainer).
"""

from __future__ import annotations

import logging

import torch
from tensordict import TensorDictBase

from sf2_torch.losses import Batch

__all__ = ["ReplayBuffer", "to_batch"]


def to_batch(td: TensorDictBase) -> Batch:
    """The core's `Batch` of TorchRL transitions, as the JAX trainer stores them.

    Args:
      td: transitions of any batch shape (…) in TorchRL's layout.

    Returns:
      obs (…, D), action (…, A), reward, discount = 1 − done and truncation (…) in the observations'
      dtype, next_obs (…, D).
    """
    obs, nxt = td.get("observation"), td.get("next")

    def flag(x):
        return x.squeeze(-1).to(obs.dtype)

    return Batch(obs=obs, action=td.get("action"), reward=flag(nxt.get("reward")),
                 discount=1.0 - flag(nxt.get("done")), next_obs=nxt.get("observation"),
                 truncation=flag(nxt.get("truncated")))


class ReplayBuffer:
    """TorchRL's replay buffer on the training device, sampled from one seed's generator."""

    def __init__(self, capacity: int, device, generator: torch.Generator):
        """An empty buffer.

        Args:
          capacity: transitions kept (the newest).
          device: where the transitions live.
          generator: the seed's `torch.Generator`, which draws every sample.
        """
        from torchrl.data import LazyTensorStorage
        from torchrl.data import ReplayBuffer as TorchRLReplayBuffer
        from torchrl.data.replay_buffers.samplers import RandomSampler

        logging.getLogger("torchrl").setLevel(logging.WARNING)  # "Initialized LazyTensorStorage ..."
        self.capacity = int(capacity)
        # compilable: the storage keeps its last written index as a tensor where it is. Without it, every
        # insert reads that index to the host (`.item()` on the writer's device arange), which on a GPU
        # waits for all the work queued before it: once per actor step, the host stalled behind the SGD
        # steps it had just queued (docs/decisions/torch-trainer-step.md). Single-process use only,
        # which is this buffer's.
        storage = LazyTensorStorage(self.capacity, device=device, compilable=True)
        self.buffer = TorchRLReplayBuffer(storage=storage, sampler=RandomSampler(), batch_size=None)
        self.generator = generator
        self.buffer.set_rng(generator)

    def insert(self, transitions: TensorDictBase) -> None:
        """Write transitions over the oldest ones.

        Args:
          transitions: n ≤ capacity transitions, batch shape (n,).
        """
        self.buffer.extend(transitions)

    def sample(self, n: int) -> TensorDictBase:
        """Draw transitions uniformly with replacement from the filled part.

        Args:
          n: how many.

        Returns:
          n transitions (TorchRL's layout; `to_batch` makes them a `Batch`).
        """
        return self.buffer.sample(n)

    def size(self) -> int:
        """The number of transitions held."""
        return len(self.buffer)

    def state_dict(self) -> dict:
        """The transitions and the write position, for a checkpoint."""
        return self.buffer.state_dict()

    def load_state_dict(self, state: dict) -> None:
        """Restore the transitions and the write position. The generator stays the one this buffer was
        built with (TorchRL's `load_state_dict` would install a new generator object, splitting the
        seed's one random stream in two); its state is restored by the owner of the generator. The
        state's own copy of the generator state is not read: a checkpoint loaded onto a GPU holds it
        there, where no generator accepts it."""
        self.buffer.load_state_dict({k: v for k, v in state.items() if k != "_rng"})
        self.buffer.set_rng(self.generator)
