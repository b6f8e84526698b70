"""Sim (PyTorch): successor features learned "the simple way" (Chua et al., 2024), as the SF² paper adapts
them to TD3 and SAC (TD3Sim, SACSim; paper §4.2). Mirror of `sf2_baselines.jax.sim`; README.md "Sim".

`SimNetworks` holds every module of a Sim agent under its canonical group name: `obs_norm`, `policy`,
`target_policy` (TD3) or `log_alpha` (SAC) — the core's — and `phi`, `q` (successor-feature heads),
`task` (parameter `w`, shape (F,)), `target_phi`, `target_q` (targets have `requires_grad=False`).

Q_j(s, a) = wᵀψ_j(φ(s, a, ŵ)), φ on concat[normalize(s), a, ŵ], ŵ = sg(w)/(‖w‖ + 1e-8). The TD loss
trains ψ_j and φ; the reward-prediction loss (wᵀφ(s′, ā′, ŵ) − rs·r)² trains w only, every
`REWARD_EVERY[algo]` gradient steps. The target critic uses φ̄, ψ̄ and the current w.
"""

from __future__ import annotations

import torch
from sf2_common.config import SF2Config
from sf2_torch import networks as core_nw
from sf2_torch.losses import Batch
from torch import nn

from . import common

__all__ = [
    "GROUPS",
    "REWARD_EVERY",
    "SFHeads",
    "Task",
    "SimNetworks",
    "make_networks",
    "task_vector",
    "features",
    "successor_features",
    "critic",
    "reward_loss",
]

GROUPS = ("phi", "q", "task", "target_phi", "target_q")
REWARD_EVERY = {"td3": 10, "sac": 16}


class SFHeads(nn.Module):
    """Twin successor-feature heads `head_0`, `head_1`: the core `MLP(F, (hidden,), F)` without LayerNorm.

    Args:
      feature_size: F.
      hidden_size: q_hidden_size.
      **kw: dtype, device.

    `forward(φ)` → (..., 2, F).
    """

    def __init__(self, feature_size: int, hidden_size: int, **kw) -> None:
        super().__init__()
        self.feature_size = int(feature_size)
        self.head_0 = core_nw.MLP(feature_size, (hidden_size,), feature_size, False, **kw)
        self.head_1 = core_nw.MLP(feature_size, (hidden_size,), feature_size, False, **kw)

    def forward(self, phi: torch.Tensor) -> torch.Tensor:
        common.check_last("phi", phi, self.feature_size, "feature_size")
        return torch.stack([self.head_0(phi), self.head_1(phi)], dim=-2)


class Task(nn.Module):
    """The task vector: the parameter `w` (F,) ~ N(0, 1), canonical name `task.w`.

    Args:
      feature_size: F.
      dtype, device: of `w`.
    """

    def __init__(self, feature_size: int, *, dtype=None, device=None) -> None:
        super().__init__()
        self.w = nn.Parameter(
            torch.randn(feature_size, dtype=dtype or torch.get_default_dtype(), device=device)
        )


class SimNetworks(nn.Module):
    """All modules of a Sim agent: φ, the SF heads, the task vector, their targets and the core's part.

    Args:
      cfg: the `SF2Config`.
      algo: "td3" or "sac".
      dtype, device: of every parameter.

    Attributes:
      cfg, algo: as given.
      phi, target_phi: φ on [normalize(s), a, ŵ] and its EMA target.
      q, target_q: the `SFHeads` and their EMA target.
      task: the `Task` (w).
      obs_norm, policy, target_policy (TD3) / log_alpha (SAC): the core agent's (`common.init_core`).
    """

    def __init__(self, cfg: SF2Config, algo: str = "td3", *, dtype=None, device=None) -> None:
        super().__init__()
        kw = dict(dtype=dtype, device=device)
        common.init_core(self, cfg, algo, **kw)
        D, A, F = cfg.obs_size, cfg.action_size, cfg.feature_size
        self.phi = core_nw.MLP(D + A + F, cfg.hidden_sizes, F, cfg.layer_norm, **kw)
        self.q = SFHeads(F, cfg.q_hidden_size, **kw)
        self.task = Task(F, **kw)
        self.target_phi = common.frozen_copy(self.phi)
        self.target_q = common.frozen_copy(self.q)

    def extra_repr(self) -> str:
        return f"algo={self.algo!r}"


def make_networks(cfg: SF2Config, algo: str = "td3", *, dtype=None, device=None, core=None) -> SimNetworks:
    """Build and initialise a Sim agent's modules (seed with `torch.manual_seed` first). `core`: an agent's
    `Networks` whose `obs_norm`, `policy`, `target_policy` / `log_alpha` are shared, not copied."""
    return common.share_core(SimNetworks(cfg, algo, dtype=dtype, device=device), core)


# ------------------------------------------------------------------------------------------ networks
def task_vector(nets: SimNetworks) -> torch.Tensor:
    """w (F,)."""
    return nets.task.w


def _input(nets: SimNetworks, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    cfg = nets.cfg
    common.check_last("obs", obs, cfg.obs_size, "obs_size")
    common.check_last("action", action, cfg.action_size, "action_size")
    x = core_nw.normalize(obs, nets.obs_norm)
    w_hat = common.l2_normalize(task_vector(nets).detach()).to(x.dtype)
    return torch.cat([x, action, w_hat.expand(*x.shape[:-1], w_hat.shape[-1])], dim=-1)


def features(
    nets: SimNetworks, obs: torch.Tensor, action: torch.Tensor, target: bool = False
) -> torch.Tensor:
    """Basis features φ(s, a, ŵ) (B, F); `target` uses φ̄."""
    return (nets.target_phi if target else nets.phi)(_input(nets, obs, action))


def successor_features(nets: SimNetworks, phi: torch.Tensor, target: bool = False) -> torch.Tensor:
    """ψ_j(φ) (B, 2, F); `target` uses ψ̄."""
    return (nets.target_q if target else nets.q)(phi)


def critic(nets: SimNetworks, obs: torch.Tensor, action: torch.Tensor, target: bool = False) -> torch.Tensor:
    """Q_j(s, a) = wᵀψ_j(φ(s, a, ŵ)) (B, 2); `target` uses φ̄, ψ̄ and the current w."""
    psi = successor_features(nets, features(nets, obs, action, target), target)
    return torch.einsum("...jf,f->...j", psi, task_vector(nets))


# ------------------------------------------------------------------------------------------ losses
def reward_loss(nets: SimNetworks, batch: Batch, next_action: torch.Tensor):
    """Sim's reward prediction (Chua et al. 2024; the authors' `task_loss`), trained on w only.

    loss = mean_b m_b (wᵀφ(s′, ā′, ŵ) − rs·r)².

    Args:
      nets: the `SimNetworks`.
      batch: the transitions.
      next_action: ā′ (B, A) from the base algorithm (TD3: the target policy at s′; SAC: a policy sample);
        gets no gradient.

    Returns:
      (loss, {"predicted_reward_rms": √mean_b (wᵀφ′)²}).

    Raises:
      ShapeError: a field of `batch` or `next_action` of another shape.
    """
    cfg = nets.cfg
    b = common.check_batch(cfg, batch)
    common.check_noise("next_action", next_action, b, cfg.action_size, "action_size")
    with torch.no_grad():
        phi_next = features(nets, batch.next_obs, next_action.detach())
    pred = phi_next @ task_vector(nets)
    err = pred - cfg.reward_scaling * batch.reward
    loss = torch.mean((1.0 - batch.truncation) * err.square())
    return loss, {"predicted_reward_rms": pred.detach().square().mean().sqrt()}
