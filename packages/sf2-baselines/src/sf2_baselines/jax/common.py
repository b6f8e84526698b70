"""Pieces every baseline shares (JAX): shape checks, L2 normalization, gradient stops, tree casts.

The baselines' TD3 and SAC losses are the core's (`sf2_jax.losses.td3_critic_loss`, ..., paper
Appendix D, Algorithms 2–3) with `critic=` the baseline's critic (`sim.critic`, `spr.critic`, or a
representation's `critic`); the agents pass it. Their own losses (reward prediction, Laplacian, SPR)
take 2-D batches (B, ·), as the core's do.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from sf2_common.errors import ShapeError
from sf2_jax.losses import Batch

__all__ = ["NORM_EPS", "l2_normalize", "trainable", "check_last", "check_batch", "check_noise", "cast_tree",
           "copy_tree"]

sg = jax.lax.stop_gradient
Params = dict[str, Any]

# x / (‖x‖ + NORM_EPS): the normalization the authors' SimLap code and Chua et al. use (both frameworks).
NORM_EPS = 1e-8


def l2_normalize(x, axis: int = -1):
    """x / (‖x‖₂ + 1e-8) along `axis`."""
    return x / (jnp.linalg.norm(x, axis=axis, keepdims=True) + NORM_EPS)


def trainable(params: Params, groups) -> Params:
    """Stop the gradient of every group not in `groups` (the core's convention for pure losses)."""
    return {name: (value if name in groups else sg(value)) for name, value in params.items()}


def cast_tree(tree, dtype):
    return jax.tree_util.tree_map(lambda v: jnp.asarray(v, dtype), tree)


def copy_tree(tree):
    return jax.tree_util.tree_map(jnp.copy, tree)


# ------------------------------------------------------------------------------------------ checks
def check_last(name: str, x, expected: int, what: str) -> None:
    shape = tuple(jnp.shape(x))
    if not shape or shape[-1] != expected:
        found = shape[-1] if shape else "a scalar"
        raise ShapeError(
            f"{name}: expected last dimension {expected} ({what}), found {found} (shape {shape})"
        )


def check_batch(cfg, batch: Batch) -> tuple[int]:
    """Validate a 2-D `Batch` against the config; returns the batch shape (B,)."""
    check_last("batch.obs", batch.obs, cfg.obs_size, "obs_size")
    if jnp.ndim(batch.obs) != 2:
        raise ShapeError(f"batch.obs: expected shape (B, {cfg.obs_size}) (a 2-D batch; vmap the loss for "
                         f"more batch dimensions), found shape {tuple(jnp.shape(batch.obs))}")
    check_last("batch.next_obs", batch.next_obs, cfg.obs_size, "obs_size")
    check_last("batch.action", batch.action, cfg.action_size, "action_size")
    b = tuple(jnp.shape(batch.obs)[:-1])
    for name in ("next_obs", "action"):
        found = tuple(jnp.shape(getattr(batch, name))[:-1])
        if found != b:
            raise ShapeError(f"batch.{name}: expected batch shape {b} (that of batch.obs), found {found}")
    for name in ("reward", "discount", "truncation"):
        found = tuple(jnp.shape(getattr(batch, name)))
        if found != b:
            raise ShapeError(
                f"batch.{name}: expected shape {b} (the batch shape of batch.obs), found {found}"
            )
    return b


def check_noise(name: str, x, batch_shape, size: int, what: str) -> None:
    check_last(name, x, size, what)
    found = tuple(jnp.shape(x)[:-1])
    if found != tuple(batch_shape):
        raise ShapeError(
            f"{name}: expected batch shape {tuple(batch_shape)} (that of batch.obs), found {found}"
        )
