"""Pure losses of SF² with explicit noise (docs/core-contract.md "Losses"); `ema_update`.

Every random draw is an argument: the flow loss takes ε (`eps`, (B, D)), flow time k (`flow_time`, (B,))
and the next action ā′ (`next_action`, (B, A)); TD3's critic takes the smoothing noise ξ (B, A); SAC's
losses take the action noise ξ (B, A). Same inputs → same numbers, in `sf2_jax` and here.

Conventions shared by all losses:
- `Batch(obs, action, reward, discount, next_obs, truncation)`; `discount` is 1 − terminal and the mask
  is m_b = 1 − truncation_b. Every batch mean divides by B (masked samples count as zeros).
- Each loss returns `(loss, aux)`: a 0-d tensor with a graph, and a dict of detached 0-d tensors.
- Targets (ψ̄, ζ̄, Q̄, π̄) are evaluated under `torch.no_grad()`; gradients land only in the `.grad` of
  the online modules a loss trains (the actor losses read ψ and Q through detached parameters, so a
  backward pass leaves ψ's and Q's `.grad` untouched). No host synchronization happens inside a loss.

Flow loss (eq. 3–4, Algorithm 1), s̄′ = normalize(s′), x_k = k s̄′ + (1 − k) ε:
    ℓ_P = Σ_d (ζ(x_k, k)ψ(s, a) − (s̄′ − ε))²_d
    ℓ_B = Σ_d (ζ(x̂, k)ψ(s, a) − sg(ζ̄(x̂, k)ψ̄(s′, ā′)))²_d,   x̂ = ODE of ζ̄(·,·)ψ̄′ from ε over [0, k]
    loss = mean_b m_b[(1 − γ_su)ℓ_P + γ_su ℓ_B]
With `cfg.contract_zeta` the fast path of DESIGN.md §6 is used: (M, c) = contract(ψ) once for the online
field (shared by both online evaluations, which run as one batch), (M̄, c̄) once for the target field
(shared by every ODE evaluation and the target velocity); the (B, D, F) tensor ζ is never built. With
γ_su = 0 the bootstrap branch is skipped and `loss_boot` is 0.
"""

from __future__ import annotations

import numbers
from collections.abc import Callable, Iterable
from typing import NamedTuple

import torch
from torch import nn
from torch.func import functional_call

from . import ode
from .errors import ConfigError, ShapeError
from .networks import (
    SF2Networks,
    contract,
    normalize,
    psi,
    q_values,
    sac_sample,
    td3_action,
    velocity,
    velocity_contracted,
    zeta_hidden,
)

__all__ = [
    "Batch",
    "flow_loss",
    "transition_loss",
    "bootstrap_loss",
    "explicit_mixture_loss",
    "td3_critic_loss",
    "td3_actor_loss",
    "sac_critic_loss",
    "sac_actor_loss",
    "sac_alpha_loss",
    "ema_update",
]


class Batch(NamedTuple):
    """A batch of transitions: obs (B, D), action (B, A), reward (B,), discount (B,) = 1 − terminal,
    next_obs (B, D), truncation (B,) ∈ {0, 1}."""

    obs: torch.Tensor
    action: torch.Tensor
    reward: torch.Tensor
    discount: torch.Tensor
    next_obs: torch.Tensor
    truncation: torch.Tensor


# ------------------------------------------------------------------------------------------------ helpers
def _check_same(name: str, tensor: torch.Tensor, shape: tuple[int, ...], what: str) -> None:
    if tuple(tensor.shape) != tuple(shape):
        raise ShapeError(f"{name} must have shape {tuple(shape)} ({what}), found {tuple(tensor.shape)}")


def _check_batch(batch: Batch, nets: SF2Networks) -> int:
    cfg = nets.cfg
    if batch.obs.ndim != 2 or batch.obs.shape[-1] != cfg.obs_size:
        raise ShapeError(f"batch.obs must have shape (B, {cfg.obs_size}), found {tuple(batch.obs.shape)}")
    b = batch.obs.shape[0]
    _check_same("batch.action", batch.action, (b, cfg.action_size), "(B, action_size)")
    _check_same("batch.next_obs", batch.next_obs, (b, cfg.obs_size), "(B, obs_size)")
    for name in ("reward", "discount", "truncation"):
        _check_same(f"batch.{name}", getattr(batch, name), (b,), "(B,)")
    return b


def _mask(batch: Batch) -> torch.Tensor:
    return 1.0 - batch.truncation


def _frozen(module: nn.Module, *args: torch.Tensor) -> torch.Tensor:
    """module(*args) through detached parameters: gradients reach the inputs, never the module."""
    return functional_call(module, {n: p.detach() for n, p in module.named_parameters()}, args)


def _sq_norm(x: torch.Tensor) -> torch.Tensor:
    return x.square().sum(-1)


def _flow_inputs(nets, batch, next_action, eps, flow_time):
    b = _check_batch(batch, nets)
    _check_same("eps", eps, (b, nets.cfg.obs_size), "(B, obs_size)")
    _check_same("flow_time", flow_time, (b,), "(B,)")
    _check_same("next_action", next_action, (b, nets.cfg.action_size), "(B, action_size)")
    next_n = normalize(batch.next_obs, nets.obs_norm)
    k_col = flow_time[:, None]
    x_k = k_col * next_n + (1.0 - k_col) * eps
    return next_n, x_k


@torch.no_grad()
def _bootstrap_target(nets, batch, next_action, eps, flow_time, contracted: bool):
    """(x̂, sg(ζ̄(x̂, k)ψ̄′)): the target field ζ̄ψ̄′ integrated from ε to k, and its velocity at (x̂, k)."""
    cfg = nets.cfg
    feats_bar = psi(nets, batch.next_obs, next_action.detach(), target=True)
    if contracted:
        m_bar, c_bar = contract(nets, feats_bar, target=True)

        def field(x, k):
            return velocity_contracted(nets, x, k, m_bar, c_bar, target=True)
    else:

        def field(x, k):
            return velocity(nets, x, k, feats_bar, target=True)

    x_hat = ode.integrate(field, eps, flow_time, cfg.denoising_steps, cfg.integrator)
    return x_hat, field(x_hat, flow_time)


# --------------------------------------------------------------------------------------------- flow loss
def transition_loss(
    nets: SF2Networks, batch: Batch, eps: torch.Tensor, flow_time: torch.Tensor
) -> torch.Tensor:
    """Per-sample ℓ_P (B,) = Σ_d (ζ(x_k, k)ψ(s, a) − (s̄′ − ε))²_d, plain formulation (the oracle)."""
    next_n, x_k = _flow_inputs(nets, batch, torch.zeros_like(batch.action), eps, flow_time)
    feats = psi(nets, batch.obs, batch.action)
    return _sq_norm(velocity(nets, x_k, flow_time, feats) - (next_n - eps))


def bootstrap_loss(
    nets: SF2Networks, batch: Batch, next_action: torch.Tensor, eps: torch.Tensor, flow_time: torch.Tensor
) -> torch.Tensor:
    """Per-sample ℓ_B (B,) = Σ_d (ζ(x̂, k)ψ(s, a) − sg(ζ̄(x̂, k)ψ̄(s′, ā′)))²_d, plain formulation (oracle)."""
    _flow_inputs(nets, batch, next_action, eps, flow_time)
    x_hat, u_bar = _bootstrap_target(nets, batch, next_action, eps, flow_time, contracted=False)
    feats = psi(nets, batch.obs, batch.action)
    return _sq_norm(velocity(nets, x_hat, flow_time, feats) - u_bar)


def flow_loss(
    nets: SF2Networks, batch: Batch, next_action: torch.Tensor, eps: torch.Tensor, flow_time: torch.Tensor
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """L_flow = mean_b m_b[(1 − γ_su)ℓ_P + γ_su ℓ_B]; aux {"loss_p", "loss_boot"} (masked means over B).

    Trains online ψ and ζ. Fast contracted path when `cfg.contract_zeta`, else the plain oracle.
    """
    cfg = nets.cfg
    gamma = cfg.gamma_su
    next_n, x_k = _flow_inputs(nets, batch, next_action, eps, flow_time)
    target_p = next_n - eps
    bootstrap = gamma > 0.0
    feats = psi(nets, batch.obs, batch.action)
    u_b = u_bar = None
    if cfg.contract_zeta:
        m, c = contract(nets, feats)
        if bootstrap:
            x_hat, u_bar = _bootstrap_target(nets, batch, next_action, eps, flow_time, contracted=True)
            b = x_k.shape[0]
            h = zeta_hidden(nets, torch.cat([x_k, x_hat]), torch.cat([flow_time, flow_time]))
            u = torch.einsum("nbh,bdh->nbd", h.view(2, b, h.shape[-1]), m) + c
            u_p, u_b = u[0], u[1]
        else:
            u_p = velocity_contracted(nets, x_k, flow_time, m, c)
    else:
        u_p = velocity(nets, x_k, flow_time, feats)
        if bootstrap:
            x_hat, u_bar = _bootstrap_target(nets, batch, next_action, eps, flow_time, contracted=False)
            u_b = velocity(nets, x_hat, flow_time, feats)
    mask = _mask(batch)
    l_p = _sq_norm(u_p - target_p)
    loss_p = torch.mean(mask * l_p)
    if bootstrap:
        l_b = _sq_norm(u_b - u_bar)
        loss = torch.mean(mask * ((1.0 - gamma) * l_p + gamma * l_b))
        loss_boot = torch.mean(mask * l_b).detach()
    else:
        loss = torch.mean(mask * ((1.0 - gamma) * l_p))
        loss_boot = torch.zeros((), dtype=loss.dtype, device=loss.device)
    return loss, {"loss_p": loss_p.detach(), "loss_boot": loss_boot}


def explicit_mixture_loss(
    velocity_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    x1: torch.Tensor,
    x2: torch.Tensor,
    eps1: torch.Tensor,
    eps2: torch.Tensor,
    k1: torch.Tensor,
    k2: torch.Tensor,
    weight: float | torch.Tensor,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Appendix A.3: weight·L_1 + (1 − weight)·L_2, L_i = mean_b ‖v(φ_ki(εi, xi), ki) − (xi − εi)‖².

    φ_k(ε, x) = k x + (1 − k) ε. aux {"loss_1", "loss_2"}.
    """

    def term(x, e, k):
        _check_same("eps", e, tuple(x.shape), "same as x")
        _check_same("k", k, tuple(x.shape[:-1]), "(B,)")
        k_col = k[..., None]
        return torch.mean(_sq_norm(velocity_fn(k_col * x + (1.0 - k_col) * e, k) - (x - e)))

    l1, l2 = term(x1, eps1, k1), term(x2, eps2, k2)
    return weight * l1 + (1.0 - weight) * l2, {"loss_1": l1.detach(), "loss_2": l2.detach()}


# ------------------------------------------------------------------------------------------- TD3 / SAC
def _critic(nets: SF2Networks, batch: Batch, y: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """½ mean_{b,j}(m_b(Q_j(ψ(s, a)) − sg(y)))²; trains Q and ψ."""
    q = q_values(nets, psi(nets, batch.obs, batch.action))
    err = _mask(batch)[:, None] * (q - y.detach()[:, None])
    loss = 0.5 * torch.mean(err.square())
    return loss, {"q": q.mean().detach(), "target_q": y.mean().detach()}


def td3_critic_loss(
    nets: SF2Networks, batch: Batch, smoothing: torch.Tensor
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """TD3 critic on features (Algorithm 2); `smoothing` ξ (B, A) standard normal.

    ã′ = clip(π̄(s′) + clip(σ_s ξ, −c, c), −1, 1); y = rs·r + discount·γ·min_j Q̄_j(ψ̄(s′, ã′));
    loss = ½ mean_{b,j}(m_b(Q_j(ψ(s, a)) − sg(y)))². aux {"q" (mean Q), "target_q" (mean y)}.
    """
    cfg = nets.cfg
    b = _check_batch(batch, nets)
    _check_same("smoothing", smoothing, (b, cfg.action_size), "(B, action_size)")
    with torch.no_grad():
        noise = torch.clamp(cfg.smoothing_noise * smoothing, -cfg.noise_clip, cfg.noise_clip)
        next_action = torch.clamp(td3_action(nets, batch.next_obs, target=True) + noise, -1.0, 1.0)
        q_next = q_values(nets, psi(nets, batch.next_obs, next_action, target=True), target=True)
        y = cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * q_next.min(-1).values
    return _critic(nets, batch, y)


def td3_actor_loss(nets: SF2Networks, batch: Batch) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """−mean_b Q_0(ψ(s, π(s))); only the policy is differentiated. aux {"q" (mean Q_0)}."""
    _check_batch(batch, nets)
    action = td3_action(nets, batch.obs)
    feats = _frozen(nets.psi, normalize(batch.obs, nets.obs_norm), action)
    q0 = _frozen(nets.q.head_0, feats)[:, 0]
    loss = -torch.mean(q0)
    return loss, {"q": -loss.detach()}


def _alpha(nets: SF2Networks) -> torch.Tensor:
    if nets.algo != "sac":
        raise ConfigError(f"SAC losses need networks built with algo='sac', found algo={nets.algo!r}")
    return torch.exp(nets.log_alpha.detach())


def sac_critic_loss(
    nets: SF2Networks, batch: Batch, noise: torch.Tensor
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """SAC critic on features (Algorithm 3); `noise` ξ′ (B, A) draws a′ ~ π(s′) from the online policy.

    y = rs·r + discount·γ·(min_j Q̄_j(ψ̄(s′, a′)) − α log π(a′|s′)), α = exp(log_alpha) constant;
    loss = ½ mean_{b,j}(m_b(Q_j(ψ(s, a)) − sg(y)))². aux {"q" (mean Q), "target_q" (mean y)}.
    """
    cfg = nets.cfg
    alpha = _alpha(nets)
    b = _check_batch(batch, nets)
    _check_same("noise", noise, (b, cfg.action_size), "(B, action_size)")
    with torch.no_grad():
        next_action, next_log_prob = sac_sample(nets, batch.next_obs, noise)
        q_next = q_values(nets, psi(nets, batch.next_obs, next_action, target=True), target=True)
        soft = q_next.min(-1).values - alpha * next_log_prob
        y = cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * soft
    return _critic(nets, batch, y)


def sac_actor_loss(
    nets: SF2Networks, batch: Batch, noise: torch.Tensor
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """mean_b(α log π(a|s) − min_j Q_j(ψ(s, a))), a ~ π(s) with `noise` ξ (B, A); trains the policy only.

    aux {"entropy"} (= −mean_b log π(a|s)).
    """
    cfg = nets.cfg
    alpha = _alpha(nets)
    b = _check_batch(batch, nets)
    _check_same("noise", noise, (b, cfg.action_size), "(B, action_size)")
    action, log_prob = sac_sample(nets, batch.obs, noise)
    feats = _frozen(nets.psi, normalize(batch.obs, nets.obs_norm), action)
    q = _frozen(nets.q, feats).min(-1).values
    loss = torch.mean(alpha * log_prob - q)
    return loss, {"entropy": -log_prob.mean().detach()}


def sac_alpha_loss(
    nets: SF2Networks, batch: Batch, noise: torch.Tensor
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """mean_b(exp(log_alpha)·sg(−log π(a|s) − target_entropy)), target_entropy = −target_entropy_scale·A.

    Trains `log_alpha` only. aux {"alpha"} (= exp(log_alpha)).
    """
    cfg = nets.cfg
    _alpha(nets)
    b = _check_batch(batch, nets)
    _check_same("noise", noise, (b, cfg.action_size), "(B, action_size)")
    with torch.no_grad():
        _, log_prob = sac_sample(nets, batch.obs, noise)
    target_entropy = -cfg.target_entropy_scale * cfg.action_size
    alpha = torch.exp(nets.log_alpha)
    loss = torch.mean(alpha * (-log_prob - target_entropy))
    return loss, {"alpha": alpha.detach()}


# ---------------------------------------------------------------------------------------------------- EMA
def _tensors(x: nn.Module | Iterable[torch.Tensor]) -> list[torch.Tensor]:
    return list(x.parameters()) if isinstance(x, nn.Module) else list(x)


@torch.no_grad()
def ema_update(
    target: nn.Module | Iterable[torch.Tensor], online: nn.Module | Iterable[torch.Tensor], tau: float
) -> None:
    """target ← (1 − τ)·target + τ·online, parameter by parameter, in place.

    `target` and `online` are modules of the same architecture (or matching sequences of tensors).
    """
    if isinstance(tau, numbers.Real) and not 0.0 <= float(tau) <= 1.0:
        raise ConfigError(f"tau={tau!r} is invalid: must satisfy 0 <= tau <= 1")
    t, o = _tensors(target), _tensors(online)
    if len(t) != len(o) or any(a.shape != b.shape for a, b in zip(t, o)):
        raise ShapeError(
            "ema_update needs target and online of the same architecture, found parameter shapes "
            f"{[tuple(a.shape) for a in t]} and {[tuple(b.shape) for b in o]}"
        )
    if not t:
        return
    torch._foreach_mul_(t, 1.0 - float(tau))
    torch._foreach_add_(t, o, alpha=float(tau))
