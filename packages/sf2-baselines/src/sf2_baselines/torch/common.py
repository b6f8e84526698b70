"""Pieces every baseline shares (PyTorch): shape checks, L2 normalization, TD3/SAC losses on any critic.

Mirror of `sf2_baselines.jax.common` (same names, same numbers). The TD3/SAC losses are the core's
(docs/core-contract.md; paper Appendix D, Algorithms 2–3) written against a critic function; the caller
passes a critic that differentiates exactly the modules the loss trains (`frozen` evaluates a module
through detached parameters, so gradients reach its inputs but never its `.grad`). Targets are
evaluated under `torch.no_grad()`. Batch means divide by B; m_b = 1 − truncation_b.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from sf2_torch import networks as core_nw
from sf2_torch.errors import ConfigError, ShapeError
from sf2_torch.losses import Batch
from torch import nn
from torch.func import functional_call

__all__ = [
    "NORM_EPS",
    "l2_normalize",
    "frozen",
    "frozen_copy",
    "share_core",
    "check_last",
    "check_batch",
    "check_noise",
    "td_loss",
    "td3_critic_loss",
    "td3_actor_loss",
    "sac_critic_loss",
    "sac_actor_loss",
    "alpha",
]

Critic = Callable[..., torch.Tensor]  # critic(obs, action, target=False) -> (B, 2)

NORM_EPS = 1e-8


def l2_normalize(x: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """x / (‖x‖₂ + 1e-8) along `dim`."""
    return x / (torch.linalg.vector_norm(x, dim=dim, keepdim=True) + NORM_EPS)


def frozen(module: nn.Module, *args: torch.Tensor) -> torch.Tensor:
    """module(*args) through detached parameters: gradients reach the inputs, never the module."""
    return functional_call(module, {n: p.detach() for n, p in module.named_parameters()}, args)


def frozen_copy(module: nn.Module) -> nn.Module:
    """A deep copy with `requires_grad=False` (a target network)."""
    import copy

    return copy.deepcopy(module).requires_grad_(False)


def share_core(nets: nn.Module, core: nn.Module | None) -> nn.Module:
    """Make `nets` use the core agent's `obs_norm`, `policy` and `target_policy` (TD3) or `log_alpha` (SAC)
    modules and parameter (the same objects), so an agent's normalizer and policy are one. Returns `nets`."""
    if core is None:
        return nets
    if core.algo != nets.algo or core.cfg != nets.cfg:
        raise ConfigError(
            f"cannot share modules of networks built for algo={core.algo!r} with networks built for "
            f"algo={nets.algo!r} (or with another config)"
        )
    nets.obs_norm = core.obs_norm
    nets.policy = core.policy
    if nets.algo == "td3":
        nets.target_policy = core.target_policy
    else:
        nets.log_alpha = core.log_alpha
    return nets


# ------------------------------------------------------------------------------------------ checks
def check_last(name: str, x: torch.Tensor, expected: int, what: str) -> None:
    shape = tuple(x.shape)
    if not shape or shape[-1] != expected:
        found = shape[-1] if shape else "a scalar"
        raise ShapeError(
            f"{name}: expected last dimension {expected} ({what}), found {found} (shape {shape})"
        )


def check_batch(cfg, batch: Batch) -> tuple[int, ...]:
    """Validate a `Batch` against the config; returns the batch shape (B,)."""
    check_last("batch.obs", batch.obs, cfg.obs_size, "obs_size")
    check_last("batch.next_obs", batch.next_obs, cfg.obs_size, "obs_size")
    check_last("batch.action", batch.action, cfg.action_size, "action_size")
    b = tuple(batch.obs.shape[:-1])
    for name in ("next_obs", "action"):
        found = tuple(getattr(batch, name).shape[:-1])
        if found != b:
            raise ShapeError(f"batch.{name}: expected batch shape {b} (that of batch.obs), found {found}")
    for name in ("reward", "discount", "truncation"):
        found = tuple(getattr(batch, name).shape)
        if found != b:
            raise ShapeError(
                f"batch.{name}: expected shape {b} (the batch shape of batch.obs), found {found}"
            )
    return b


def check_noise(name: str, x: torch.Tensor, batch_shape, size: int, what: str) -> None:
    check_last(name, x, size, what)
    found = tuple(x.shape[:-1])
    if found != tuple(batch_shape):
        raise ShapeError(
            f"{name}: expected batch shape {tuple(batch_shape)} (that of batch.obs), found {found}"
        )


def alpha(nets) -> torch.Tensor:
    """exp(log_alpha), detached (a constant in the critic and actor losses)."""
    if nets.algo != "sac":
        raise ConfigError(f"SAC losses need networks built with algo='sac', found algo={nets.algo!r}")
    return torch.exp(nets.log_alpha.detach())


# ------------------------------------------------------------------------------------------ TD3 / SAC
def td_loss(q: torch.Tensor, y: torch.Tensor, truncation: torch.Tensor) -> torch.Tensor:
    """½ mean_{b,j}(m_b(Q_j − sg(y)))², m_b = 1 − truncation_b."""
    err = (1.0 - truncation)[..., None] * (q - y.detach()[..., None])
    return 0.5 * torch.mean(err.square())


def td3_critic_loss(critic: Critic, nets, batch: Batch, smoothing: torch.Tensor):
    """TD3 critic (Algorithm 2): ã′ = clip(π̄(s′) + clip(σ_s ξ, −c, c), −1, 1),
    y = rs·r + discount·γ·min_j Q̄_j(s′, ã′), loss = ½ mean_{b,j}(m_b(Q_j(s, a) − sg(y)))².
    aux: q (mean Q), target_q (mean y)."""
    cfg = nets.cfg
    b = check_batch(cfg, batch)
    check_noise("smoothing", smoothing, b, cfg.action_size, "action_size")
    with torch.no_grad():
        noise = torch.clamp(cfg.smoothing_noise * smoothing, -cfg.noise_clip, cfg.noise_clip)
        next_action = torch.clamp(core_nw.td3_action(nets, batch.next_obs, target=True) + noise, -1.0, 1.0)
        next_q = critic(batch.next_obs, next_action, target=True)
        y = cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * next_q.min(-1).values
    q = critic(batch.obs, batch.action)
    return td_loss(q, y, batch.truncation), {"q": q.mean().detach(), "target_q": y.mean()}


def td3_actor_loss(frozen_critic: Critic, nets, batch: Batch):
    """TD3 actor: −mean_b Q_0(s, π(s)); `frozen_critic` must not train anything. aux: q (mean Q_0)."""
    check_batch(nets.cfg, batch)
    action = core_nw.td3_action(nets, batch.obs)
    loss = -torch.mean(frozen_critic(batch.obs, action)[..., 0])
    return loss, {"q": -loss.detach()}


def sac_critic_loss(critic: Critic, nets, batch: Batch, noise: torch.Tensor):
    """SAC critic (Algorithm 3): a′, log π(a′|s′) from the online policy with ξ′ = `noise`;
    y = rs·r + discount·γ·(min_j Q̄_j(s′, a′) − α log π(a′|s′)); loss = ½ mean_{b,j}(m_b(Q_j − sg(y)))².
    aux: q, target_q."""
    cfg = nets.cfg
    a = alpha(nets)
    b = check_batch(cfg, batch)
    check_noise("noise", noise, b, cfg.action_size, "action_size")
    with torch.no_grad():
        next_action, next_log_prob = core_nw.sac_sample(nets, batch.next_obs, noise)
        next_q = critic(batch.next_obs, next_action, target=True)
        y = cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * (
            next_q.min(-1).values - a * next_log_prob
        )
    q = critic(batch.obs, batch.action)
    return td_loss(q, y, batch.truncation), {"q": q.mean().detach(), "target_q": y.mean()}


def sac_actor_loss(frozen_critic: Critic, nets, batch: Batch, noise: torch.Tensor):
    """SAC actor: a ~ π(s) with ξ = `noise`; mean_b(α log π(a|s) − min_j Q_j(s, a)), α constant;
    `frozen_critic` must not train anything. aux: entropy (−mean log π)."""
    cfg = nets.cfg
    a = alpha(nets)
    b = check_batch(cfg, batch)
    check_noise("noise", noise, b, cfg.action_size, "action_size")
    action, log_prob = core_nw.sac_sample(nets, batch.obs, noise)
    q = frozen_critic(batch.obs, action).min(-1).values
    return torch.mean(a * log_prob - q), {"entropy": -log_prob.mean().detach()}
