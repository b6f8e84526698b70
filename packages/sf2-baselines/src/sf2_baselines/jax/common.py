"""Pieces every baseline shares (JAX): the core's shape checks, L2 normalization, gradient stops, tree casts.

The baselines' TD3 and SAC losses are the core's (`sf2_jax.losses.td3_critic_loss`, ..., paper
Appendix D, Algorithms 2–3) with `critic=` the baseline's critic (`sim.critic`, `spr.critic`, or a
representation's `critic`); the agents pass it. Their own losses (reward prediction, Laplacian, SPR)
take 2-D batches (B, ·), as the core's do.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from sf2_jax.losses import check_batch, check_noise
from sf2_jax.networks import check_last

__all__ = ["NORM_EPS", "l2_normalize", "trainable", "check_last", "check_batch", "check_noise", "cast_tree",
           "copy_tree"]

# check_last, check_batch, check_noise: the core's public shape checks (`sf2_jax.networks`, `sf2_jax.losses`),
# the same the core's losses run, re-exported for the baselines' modules
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
