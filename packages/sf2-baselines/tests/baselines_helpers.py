"""Shared helpers of the sf2_baselines unit tests (numpy only)."""

from __future__ import annotations

import numpy as np

D, A, B = 5, 2, 8


def small_kwargs(**overrides) -> dict:
    kw = dict(
        obs_size=D,
        action_size=A,
        feature_size=16,
        hidden_sizes=(32, 32),
        q_hidden_size=24,
        zeta_hidden_sizes=(32, 32),
        embedding_size=8,
    )
    kw.update(overrides)
    return kw


def numpy_batch(seed: int = 0, batch_size: int = B, truncation: bool = True) -> dict:
    rng = np.random.default_rng(100 + seed)
    trunc = np.zeros(batch_size)
    if truncation and batch_size > 1:
        trunc[1] = 1.0
    return dict(
        obs=rng.normal(0.5, 2.0, (batch_size, D)),
        action=rng.uniform(-1, 1, (batch_size, A)),
        reward=rng.normal(size=batch_size),
        discount=np.array([1.0, 0.0] + [1.0] * (batch_size - 2))[:batch_size],
        next_obs=rng.normal(0.5, 2.0, (batch_size, D)),
        truncation=trunc,
    )


def numpy_noise(seed: int = 0, batch_size: int = B) -> dict:
    rng = np.random.default_rng(500 + seed)
    return dict(
        next_action=rng.uniform(-1, 1, (batch_size, A)),
        smoothing=rng.normal(size=(batch_size, A)),
        noise=rng.normal(size=(batch_size, A)),
        obs_noise=rng.normal(size=(batch_size, D)),
        next_obs_noise=rng.normal(size=(batch_size, D)),
    )


def laplacian_reference(phi, phi_next, mask):
    """numpy oracle of the SimLap objective (README.md "SimLap"), loops instead of matrix algebra."""
    phi = np.asarray(phi, np.float64)
    phi_next = np.asarray(phi_next, np.float64)
    n = lambda x: x / (np.linalg.norm(x) + 1e-8)  # noqa: E731
    B, F = phi.shape
    u = [n(x) for x in phi]
    v = [n(x) for x in phi_next]
    lap = sum(mask[b] * np.sum((u[b] - v[b]) ** 2) for b in range(B)) / (B * F)
    diag = -2.0 * sum(mask[b] * u[b] @ v[b] for b in range(B)) / B
    off = sum((u[i] @ v[j]) ** 2 for i in range(B) for j in range(B) if i != j) / (B * (B - 1))
    return lap + diag + off
