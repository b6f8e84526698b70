"""Helpers of the sf2_jax unit tests (sizes, configs, non-trivial parameters, batches), imported by the
tests and by conftest.py's fixtures (a module of its own: `from conftest import` resolves to whichever
conftest pytest loaded last)."""

from __future__ import annotations

import numpy as np
from sf2_jax import SF2Config, losses, params

D, A, B = 3, 2, 5


def small_cfg(**overrides) -> SF2Config:
    return SF2Config.small(D, A, **overrides)


def perturbed_params(nets, seed: int = 0) -> dict:
    """Canonical shapes (no initialisation run), every entry drawn with numpy so that LayerNorm, the
    normalizer and the targets are all non-trivial and differ from their online networks."""
    rng = np.random.default_rng(seed)
    out = {}
    for name, shape in params.expected_shapes(nets).items():
        if name.endswith("obs_norm.std"):
            v = rng.uniform(0.5, 2.0, shape)
        elif name.endswith("obs_norm.count"):
            v = np.asarray(100.0)
        elif name.endswith(".scale"):
            v = rng.uniform(0.5, 1.5, shape)
        elif name.endswith(".kernel"):
            v = rng.uniform(-1.0, 1.0, shape) * np.sqrt(3.0 / shape[0])
        else:
            v = rng.normal(0.0, 0.1, shape)
        out[name] = v
    return params.from_canonical(out, nets, dtype=np.float64)


def make_batch(seed: int = 0, batch_size: int = B, truncation: bool = True):
    rng = np.random.default_rng(100 + seed)
    trunc = np.zeros(batch_size)
    if truncation:
        trunc[1] = 1.0
    batch = losses.Batch(
        obs=rng.normal(0.5, 2.0, (batch_size, D)),
        action=rng.uniform(-1, 1, (batch_size, A)),
        reward=rng.normal(size=batch_size),
        discount=np.array([1.0, 0.0] + [1.0] * (batch_size - 2)),
        next_obs=rng.normal(0.5, 2.0, (batch_size, D)),
        truncation=trunc,
    )
    noise = dict(
        eps=rng.normal(size=(batch_size, D)),
        flow_time=rng.uniform(size=batch_size),
        next_action=rng.uniform(-1, 1, (batch_size, A)),
        smoothing=rng.normal(size=(batch_size, A)),
        noise=rng.normal(size=(batch_size, A)),
    )
    return batch, noise
