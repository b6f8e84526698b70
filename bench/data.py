"""Random transition batches, the same numbers for both frameworks.

Never zeros: a zero batch would let the frameworks skip work (multiplications by zero, denormals) and
time something else than an update on real data.
"""

from __future__ import annotations

import numpy as np


def make_batches(obs_size: int, action_size: int, batch_size: int, count: int = 4, seed: int = 0):
    """Draw random transition batches.

    obs/next_obs ~ N(0, 1); action ~ U(−1, 1); reward ~ N(0, 1); discount 1 − terminal with 1% terminals;
    truncation 1% ones. A timing loop cycles through several so it does not reuse one input.

    Args:
        obs_size: observation size D.
        action_size: action size A.
        batch_size: transitions per batch.
        count: batches.
        seed: numpy seed.

    Returns:
        `count` dicts of float32 numpy arrays, keyed by `FIELDS` (the fields of `losses.Batch`).
    """
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        b = batch_size
        out.append(dict(
            obs=rng.standard_normal((b, obs_size), np.float32),
            action=rng.uniform(-1, 1, (b, action_size)).astype(np.float32),
            reward=rng.standard_normal(b, np.float32),
            discount=(rng.uniform(size=b) > 0.01).astype(np.float32),
            next_obs=rng.standard_normal((b, obs_size), np.float32),
            truncation=(rng.uniform(size=b) < 0.01).astype(np.float32),
        ))
    return out


FIELDS = ("obs", "action", "reward", "discount", "next_obs", "truncation")
