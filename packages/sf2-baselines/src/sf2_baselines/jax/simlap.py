"""SimLap (JAX): Sim without the Q-alignment of the features, plus a graph-Laplacian orthogonality
objective on L2-normalized features (TD3SimLap, SACSimLap; SF² paper §4.2). README.md "SimLap".

Same networks and parameter groups as `sim`. What changes is who trains φ (the critic groups of the
agents' representations): in the paper (`simlap`) the TD loss trains the SF heads only and φ is trained
by `laplacian_loss` alone; in the authors' code (`simlap_authors`) the TD loss trains φ too, then the
Laplacian step trains φ again. w is trained by Sim's `reward_loss` on its own schedule in both.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from sf2_common.errors import ShapeError
from sf2_jax.losses import Batch

from . import common
from .sim import (
    GROUPS,
    REWARD_EVERY,
    SimNetworks,
    critic,
    features,
    init_params,
    init_representation,
    make_networks,
    reward_loss,
    successor_features,
    task_vector,
)

__all__ = [
    "GROUPS",
    "REWARD_EVERY",
    "SimNetworks",
    "make_networks",
    "init_representation",
    "init_params",
    "task_vector",
    "features",
    "successor_features",
    "critic",
    "reward_loss",
    "laplacian_loss",
    "simlap_loss",
]

sg = jax.lax.stop_gradient
Params = dict[str, Any]

def laplacian_loss(nets: SimNetworks, params: Params, batch: Batch, next_action):
    """SimLap's graph-Laplacian orthogonality objective, trained on φ only (through φ(s, a) and φ(s′, ā′)).

    With φ̂ = φ(s, a, ŵ)/(‖·‖ + 1e-8) and φ̂′ = φ(s′, ā′, ŵ)/(‖·‖ + 1e-8), both online:
        L_lap  = (1/(B·F)) Σ_b m_b ‖φ̂_b − φ̂′_b‖²          (graph-Laplacian smoothness)
        L_diag = −(2/B) Σ_b m_b φ̂_bᵀφ̂′_b                   (orthogonality: positive pairs)
        L_off  = (1/(B(B−1))) Σ_{i≠j} (φ̂_iᵀφ̂′_j)²           (orthogonality: other pairs)
        laplacian_loss = L_lap + L_diag + L_off

    Args:
      nets: the `SimNetworks`.
      params: the parameters (`init_params`).
      batch: the transitions.
      next_action: ā′ (B, A) from the base algorithm (TD3: the target policy at s′; SAC: a policy sample);
        gets no gradient.

    Returns:
      (loss, {"lap_term": L_lap, "orth_diag": L_diag, "orth_offdiag": L_off}).

    Raises:
      ShapeError: a field of `batch` or `next_action` of another shape, or B < 2.
    """
    cfg = nets.cfg
    b = common.check_batch(cfg, batch)
    common.check_noise("next_action", next_action, b, cfg.action_size, "action_size")
    if b[0] < 2:
        raise ShapeError(f"laplacian_loss needs a batch of shape (B, ...) with B >= 2, found batch shape {b}")
    B = b[0]
    p = common.trainable(params, ("phi",))
    phi = common.l2_normalize(features(nets, p, batch.obs, batch.action))
    phi_next = common.l2_normalize(features(nets, p, batch.next_obs, sg(next_action)))
    mask = 1 - batch.truncation
    lap = jnp.sum(mask * jnp.sum((phi - phi_next) ** 2, axis=-1)) / (B * cfg.feature_size)
    cov = phi @ phi_next.T
    diag = -2.0 * jnp.mean(mask * jnp.diagonal(cov))
    off = jnp.sum(cov**2 * (1 - jnp.eye(B, dtype=cov.dtype))) / (B * (B - 1))
    return lap + diag + off, {"lap_term": lap, "orth_diag": diag, "orth_offdiag": off}


def simlap_loss(nets: SimNetworks, params: Params, batch: Batch, next_action):
    """The SimLap representation step: `laplacian_loss` (trains φ) + Sim's `reward_loss` (trains w).

    Args:
      nets: the `SimNetworks`.
      params: the parameters (`init_params`).
      batch: the transitions.
      next_action: ā′ (B, A) from the base algorithm (TD3: the target policy at s′; SAC: a policy sample);
        gets no gradient.

    Returns:
      (loss, the Laplacian terms, "laplacian_loss", "reward_loss" and reward_loss's aux).

    Raises:
      ShapeError: as `laplacian_loss`.
    """
    lap, aux = laplacian_loss(nets, params, batch, next_action)
    rew, rew_aux = reward_loss(nets, params, batch, next_action)
    return lap + rew, {**aux, **rew_aux, "laplacian_loss": lap, "reward_loss": rew}
