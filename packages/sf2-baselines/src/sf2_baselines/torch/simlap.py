"""SimLap (PyTorch): Sim without the Q-alignment of the features, plus a graph-Laplacian orthogonality
objective on L2-normalized features (TD3SimLap, SACSimLap; SF² paper §4.2). Mirror of
`sf2_baselines.jax.simlap`; README.md "SimLap".

Who trains φ is the critic groups of the agents' representations: the paper's (`simlap`) TD loss trains
the SF heads only; the authors' code (`simlap_authors`) also trains φ with it.
"""

from __future__ import annotations

import torch
from sf2_common.errors import ShapeError
from sf2_torch.losses import Batch

from . import common
from .sim import (
    GROUPS,
    REWARD_EVERY,
    SimNetworks,
    critic,
    features,
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
    "task_vector",
    "features",
    "successor_features",
    "critic",
    "reward_loss",
    "laplacian_loss",
    "simlap_loss",
]


def laplacian_loss(nets: SimNetworks, batch: Batch, next_action: torch.Tensor):
    """SimLap's graph-Laplacian orthogonality objective, trained on φ only (through φ(s, a) and φ(s′, ā′)).

    With φ̂ = φ(s, a, ŵ)/(‖·‖ + 1e-8) and φ̂′ = φ(s′, ā′, ŵ)/(‖·‖ + 1e-8), both online:
        L_lap  = (1/(B·F)) Σ_b m_b ‖φ̂_b − φ̂′_b‖²          (graph-Laplacian smoothness)
        L_diag = −(2/B) Σ_b m_b φ̂_bᵀφ̂′_b                   (orthogonality: positive pairs)
        L_off  = (1/(B(B−1))) Σ_{i≠j} (φ̂_iᵀφ̂′_j)²           (orthogonality: other pairs)
        laplacian_loss = L_lap + L_diag + L_off

    Args:
      nets: the `SimNetworks`.
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
    phi = common.l2_normalize(features(nets, batch.obs, batch.action))
    phi_next = common.l2_normalize(features(nets, batch.next_obs, next_action.detach()))
    mask = 1.0 - batch.truncation
    lap = torch.sum(mask * (phi - phi_next).square().sum(-1)) / (B * cfg.feature_size)
    cov = phi @ phi_next.T
    diag = -2.0 * torch.mean(mask * torch.diagonal(cov))
    off = torch.sum(cov.square() * (1.0 - torch.eye(B, dtype=cov.dtype, device=cov.device))) / (B * (B - 1))
    loss = lap + diag + off
    return loss, {"lap_term": lap.detach(), "orth_diag": diag.detach(), "orth_offdiag": off.detach()}


def simlap_loss(nets: SimNetworks, batch: Batch, next_action: torch.Tensor):
    """The SimLap representation step: `laplacian_loss` (trains φ) + Sim's `reward_loss` (trains w).

    Args:
      nets: the `SimNetworks`.
      batch: the transitions.
      next_action: ā′ (B, A) from the base algorithm (TD3: the target policy at s′; SAC: a policy sample);
        gets no gradient.

    Returns:
      (loss, the Laplacian terms, "laplacian_loss", "reward_loss" and reward_loss's aux).

    Raises:
      ShapeError: as `laplacian_loss`.
    """
    lap, aux = laplacian_loss(nets, batch, next_action)
    rew, rew_aux = reward_loss(nets, batch, next_action)
    return lap + rew, {**aux, **rew_aux, "laplacian_loss": lap.detach(), "reward_loss": rew.detach()}
