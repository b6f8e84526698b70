"""Explicit ODE integrators for the bootstrap sample x̂ of SF² (Algorithm 1, lines 6–10).

`integrate` solves dx/dk = velocity_fn(x, k) from flow time k = 0 to a per-sample end time `k_end` in
exactly `steps` equal steps h = k_end / steps (T = `denoising_steps`). The authors' loop runs T + 1 steps,
the last of zero width; that changes nothing but costs two evaluations, so it is not reproduced.
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
from sf2_common.config import INTEGRATORS
from sf2_common.errors import ConfigError, ShapeError

__all__ = ["integrate", "INTEGRATORS"]


def integrate(velocity_fn: Callable, x0, k_end, steps: int, method: str = "midpoint"):
    """Integrate dx/dk = velocity_fn(x, k), x(0) = x0 (B, D), up to k = k_end (B,) in `steps` steps.

    With h = k_end / steps and k_i = i·h:
      - "midpoint" (2 evaluations/step, Algorithm 1):
        x_mid = x + (h/2)·v(x, k_i); x ← x + h·v(x_mid, k_i + h/2)
      - "euler" (1 evaluation/step): x ← x + h·v(x, k_i)
    `velocity_fn(x, k)` takes x (B, D) and k (B,). `steps` is a static Python int (the loop is unrolled).
    """
    if method not in INTEGRATORS:
        raise ConfigError(f"integrator method = {method!r} is invalid: must be one of {INTEGRATORS}")
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ConfigError(f"steps = {steps!r} is invalid: must be a Python int >= 1")
    x = jnp.asarray(x0)
    k_end = jnp.asarray(k_end)
    if k_end.ndim == 0:
        k_end = jnp.broadcast_to(k_end, x.shape[:-1])
    if k_end.shape != x.shape[:-1]:
        raise ShapeError(f"k_end: expected shape {x.shape[:-1]} (the batch shape of x0), found {k_end.shape}")
    h = k_end / steps
    h_col = h[..., None]
    for i in range(steps):
        k_i = i * h
        if method == "midpoint":
            x_mid = x + (h_col / 2) * velocity_fn(x, k_i)
            x = x + h_col * velocity_fn(x_mid, k_i + h / 2)
        else:
            x = x + h_col * velocity_fn(x, k_i)
    return x
