"""Losses of SF² with TD3 and SAC: pure functions of the networks, a batch and explicit noise.

Paper: eq. (3)–(4) and Algorithm 1 (flow), Appendix A.3 (explicit mixture), Appendix D Algorithms 2–3
(TD3 and SAC on features); docs/core-contract.md "Losses". Every random draw (ε, flow_time k, smoothing
ξ, SAC noise) is an argument, so the same inputs give the same numbers in JAX and torch. Each loss
returns `(loss, aux)`, `aux` a dict of detached 0-d tensors (no host synchronization inside a loss);
batches are 2-D, every field (B, ·); batch means divide by B, samples masked by m_b = 1 − truncation_b
count as zeros. The TD3 and SAC losses are written once against a `critic` (default: SF²'s Q(ψ(s, a)),
`sf2_critic`; the agents pass their representation's).

Gradient contract: the caller calls `loss.backward(inputs=...)` with the trained groups' parameters;
targets are evaluated under `torch.no_grad()`. The TD target y and SAC's α are constants in every case.
`check_batch` and `check_noise` are the losses' shape checks, public for the baselines' losses (the JAX
core's `losses` has the same functions).
"""

from __future__ import annotations

import numbers
from collections.abc import Callable, Iterable, Sequence
from typing import NamedTuple

import torch
from sf2_common.errors import ConfigError, ShapeError
from torch import nn

from . import ode
from .networks import (
    Networks,
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
    "Batch", "Critic", "sf2_critic", "flow_loss", "explicit_mixture_loss", "td3_critic_loss",
    "td3_actor_loss", "sac_critic_loss", "sac_actor_loss", "sac_alpha_loss", "ema_update", "check_batch",
    "check_noise", "flow_field_loss", "velocity_fields",
]

Critic = Callable[..., torch.Tensor]  # critic(obs, action, target=False) -> (B, 2)


class Batch(NamedTuple):
    """Transitions of a 2-D batch.

    Attributes:
      obs: (B, D) observations s.
      action: (B, A) actions a.
      reward: (B,) rewards r.
      discount: (B,) 1 − terminal.
      next_obs: (B, D) next observations s′.
      truncation: (B,) 1 where the time limit cut the episode, else 0.
    """

    obs: torch.Tensor
    action: torch.Tensor
    reward: torch.Tensor
    discount: torch.Tensor
    next_obs: torch.Tensor
    truncation: torch.Tensor


# ------------------------------------------------------------------------------------------------ checks
def _check_same(name: str, tensor: torch.Tensor, shape: tuple[int, ...], what: str) -> None:
    if tuple(tensor.shape) != tuple(shape):
        raise ShapeError(f"{name} must have shape {tuple(shape)} ({what}), found {tuple(tensor.shape)}")


def check_batch(cfg, batch: Batch) -> tuple[int]:
    """Check a 2-D batch against a config's sizes, on shapes only (no host synchronization).

    Args:
      cfg: the `SF2Config` (its `obs_size` and `action_size`).
      batch: the transitions; obs and next_obs (B, D), action (B, A), reward, discount, truncation (B,).

    Returns:
      The batch shape (B,).

    Raises:
      ShapeError: a field's shape differs, naming the field, the expected and the found shape.
    """
    if batch.obs.ndim != 2 or batch.obs.shape[-1] != cfg.obs_size:
        raise ShapeError(f"batch.obs must have shape (B, {cfg.obs_size}), found {tuple(batch.obs.shape)} "
                         f"(a 2-D batch)")
    b = batch.obs.shape[0]
    _check_same("batch.action", batch.action, (b, cfg.action_size), "(B, action_size)")
    _check_same("batch.next_obs", batch.next_obs, (b, cfg.obs_size), "(B, obs_size)")
    for name in ("reward", "discount", "truncation"):
        _check_same(f"batch.{name}", getattr(batch, name), (b,), "(B,)")
    return (b,)


def check_noise(name: str, x: torch.Tensor, batch_shape: tuple, size: int, what: str) -> None:
    """Check an explicit noise (or another per-sample input) of shape (B, size), on shapes only.

    Args:
      name: the argument's name, for the message.
      x: the tensor.
      batch_shape: (B,), the batch's (`check_batch`).
      size: its last dimension.
      what: the config field `size` is, for the message ("action_size", "obs_size").

    Raises:
      ShapeError: `x` is not of shape (*batch_shape, size), naming both.
    """
    _check_same(name, x, (*batch_shape, size), f"(B, {what})")


def _sq_norm(x: torch.Tensor) -> torch.Tensor:
    return x.square().sum(-1)


# ------------------------------------------------------------------------------------------------ flow
def flow_field_loss(
    cfg,
    online: Callable[..., Sequence[torch.Tensor]],
    target: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None,
    x1: torch.Tensor,
    eps: torch.Tensor,
    flow_time: torch.Tensor,
    truncation: torch.Tensor,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The flow loss of SF² (eq. 3–4, Algorithm 1) over any velocity field: the vector, image and latent
    flows all compute it here.

    L_flow = mean_b m_b[(1 − γ_su) ℓ_P + γ_su ℓ_B], m_b = 1 − truncation_b, with
    ℓ_P = Σ_d (u(x_k, k) − (x1 − ε))²_d, x_k = k x1 + (1 − k) ε (the transition term);
    ℓ_B = Σ_d (u(x̂, k) − sg(ū(x̂, k)))²_d, x̂ = sg(the ODE solution from ε over [0, k] under ū,
    `denoising_steps` steps of `integrator`) (the bootstrap term). With γ_su = 0 the bootstrap branch is
    skipped (loss_boot = 0).

    Args:
      cfg: the `SF2Config` (gamma_su, denoising_steps, integrator).
      online: `online(*xs)` → the online velocity u(x, k) = ζ(x, k)ψ(s, a) at each x of `xs` (each (B, D), at
        the flow time k = `flow_time`), a sequence of (B, D) (`velocity_fields`).
      target: `target(x, k)` → ū(x, k) = ζ̄(x, k)ψ̄(s′, ā′) (B, D) at any flow time, evaluated under
        `torch.no_grad()`; None when γ_su = 0.
      x1: the flow's data point (B, D): normalize(s′), a flattened grid s′, or a latent z′.
      eps: ε (B, D) ~ N(0, I).
      flow_time: k (B,) ~ U(0, 1).
      truncation: (B,) 1 where the time limit cut the episode.

    Returns:
      (loss, {"loss_p": mean_b m_b ℓ_P, "loss_boot": mean_b m_b ℓ_B}).
    """
    k = flow_time[:, None]
    x_k = k * x1 + (1.0 - k) * eps
    target_p = x1 - eps
    mask = 1.0 - truncation
    bootstrap = cfg.gamma_su > 0.0
    if bootstrap:
        with torch.no_grad():
            x_hat = ode.integrate(target, eps, flow_time, cfg.denoising_steps, cfg.integrator)
            u_bar = target(x_hat, flow_time)
        u_p, u_b = online(x_k, x_hat)
    else:
        (u_p,) = online(x_k)

    loss_p = _sq_norm(u_p - target_p)
    mean_p = torch.mean(mask * loss_p).detach()
    if not bootstrap:
        loss = torch.mean(mask * ((1.0 - cfg.gamma_su) * loss_p))
        return loss, {"loss_p": mean_p, "loss_boot": torch.zeros_like(mean_p)}
    loss_b = _sq_norm(u_b - u_bar)
    loss = torch.mean(mask * ((1.0 - cfg.gamma_su) * loss_p + cfg.gamma_su * loss_b))
    return loss, {"loss_p": mean_p, "loss_boot": torch.mean(mask * loss_b).detach()}


def velocity_fields(nets: Networks, features: torch.Tensor, next_features: torch.Tensor | None,
                    flow_time: torch.Tensor):
    """The online and target velocity fields of the vector ζ, as `flow_field_loss` takes them.

    With `cfg.contract_zeta` (the fast path, docs/core-contract.md "Networks") ζ's last layer is contracted
    with ψ once (M, c) and with ψ̄′ once (M̄, c̄), reused for every evaluation, and the online evaluations at
    several points go through ζ's hidden layers as one batch; otherwise (the oracle) ζ (B, D, F) is
    materialized at each point.

    Args:
      nets: the `Networks` (its `cfg` and ζ; `sf2_torch.networks_image.latent_networks` for the latent flow).
      features: ψ(s, a) (B, F).
      next_features: ψ̄(s′, ā′) (B, F), without gradient; None: no target field.
      flow_time: k (B,), the online field's flow time.

    Returns:
      (online, target): `online(*xs)` → ζ(x, k)ψ at each x, a sequence of (B, D); `target(x, k)` →
      ζ̄(x, k)ψ̄′ (B, D), or None.

    Raises:
      ShapeError: features of another last dimension.
    """
    if nets.cfg.contract_zeta:
        m, c = contract(nets, features)

        def online(*xs):   # ζ(x, k)ψ at every x of `xs`: one hidden-layer pass over all of them
            if len(xs) == 1:
                return (velocity_contracted(nets, xs[0], flow_time, m, c),)
            h = zeta_hidden(nets, torch.cat(xs), torch.cat([flow_time] * len(xs)))
            return tuple(torch.einsum("nbh,bdh->nbd", h.view(len(xs), -1, h.shape[-1]), m) + c)
    else:
        def online(*xs):
            return tuple(velocity(nets, x, flow_time, features) for x in xs)

    if next_features is None:
        return online, None
    if nets.cfg.contract_zeta:
        with torch.no_grad():
            m_bar, c_bar = contract(nets, next_features, target=True)

        def target(x, kk):
            return velocity_contracted(nets, x, kk, m_bar, c_bar, target=True)
    else:
        def target(x, kk):
            return velocity(nets, x, kk, next_features, target=True)
    return online, target


def flow_loss(
    nets: Networks, batch: Batch, next_action: torch.Tensor, eps: torch.Tensor, flow_time: torch.Tensor
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The flow loss of SF² (eq. 3–4, Algorithm 1), trained on ψ and ζ.

    L_flow = mean_b m_b[(1 − γ_su) ℓ_P + γ_su ℓ_B], with
    ℓ_P = Σ_d (ζ(x_k, k)ψ − (s̄′ − ε))²_d, x_k = k s̄′ + (1 − k) ε, s̄′ = normalize(s′), ψ = ψ(s, a);
    ℓ_B = Σ_d (ζ(x̂, k)ψ − sg(ζ̄(x̂, k)ψ̄′))²_d, ψ̄′ = ψ̄(s′, ā′), x̂ the ODE solution from ε over [0, k] under
    the target field ζ̄ψ̄′ (`denoising_steps` steps of `integrator`): `flow_field_loss` with x1 = s̄′ and
    the fields of `velocity_fields` (the fast path with `cfg.contract_zeta`, else the plain oracle).
    With γ_su = 0 the bootstrap branch is skipped and loss_boot = 0.

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      batch: the transitions.
      next_action: ā′ (B, A); gets no gradient.
      eps: ε (B, D) ~ N(0, I).
      flow_time: k (B,) ~ U(0, 1).

    Returns:
      (loss, {"loss_p": mean_b m_b ℓ_P, "loss_boot": mean_b m_b ℓ_B}).

    Raises:
      ShapeError: a field of `batch` or a noise of another shape.
    """
    cfg = nets.cfg
    bs = check_batch(cfg, batch)
    check_noise("next_action", next_action, bs, cfg.action_size, "action_size")
    check_noise("eps", eps, bs, cfg.obs_size, "obs_size")
    _check_same("flow_time", flow_time, bs, "(B,)")
    next_action = next_action.detach()

    next_obs_n = normalize(batch.next_obs, nets.obs_norm)
    features = psi(nets, batch.obs, batch.action)
    next_features = None
    if cfg.gamma_su > 0.0:
        with torch.no_grad():
            next_features = psi(nets, batch.next_obs, next_action, target=True)
    online, target = velocity_fields(nets, features, next_features, flow_time)
    return flow_field_loss(cfg, online, target, next_obs_n, eps, flow_time, batch.truncation)


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
    """The explicit mixture objective of the two-Gaussian study (Appendix A.3).

    With φ_k(ε, x) = kx + (1 − k)ε:
    weight·mean_b‖v(φ_k1(ε1, x1), k1) − (x1 − ε1)‖² + (1 − weight)·mean_b‖v(φ_k2(ε2, x2), k2) − (x2 − ε2)‖².

    Args:
      velocity_fn: v(x, k), x (B, D) and k (B,) → (B, D).
      x1, x2: samples of the two components, (B, D).
      eps1, eps2: ε (B, D) ~ N(0, I), one per component.
      k1, k2: flow times (B,) ~ U(0, 1), one per component.
      weight: the first component's weight.

    Returns:
      (loss, {"loss_1": the first mean, "loss_2": the second mean}).

    Raises:
      ShapeError: an ε of another shape than its x, or a k of another shape than x's batch.
    """

    def term(x, e, k):
        _check_same("eps", e, tuple(x.shape), "same as x")
        _check_same("k", k, tuple(x.shape[:-1]), "(B,)")
        x_k = k[..., None] * x + (1.0 - k[..., None]) * e
        return torch.mean(_sq_norm(velocity_fn(x_k, k) - (x - e)))

    loss_1, loss_2 = term(x1, eps1, k1), term(x2, eps2, k2)
    return weight * loss_1 + (1.0 - weight) * loss_2, {"loss_1": loss_1.detach(), "loss_2": loss_2.detach()}


# ------------------------------------------------------------------------------------------------ critic
def sf2_critic(nets: Networks) -> Critic:
    """SF²'s critic Q(ψ(s, a)) (Appendix D): the core's twin Q heads on ψ.

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).

    Returns:
      `critic(obs, action, target=False)` → (B, 2); `target=True`: Q̄(ψ̄(s, a)).
    """

    def critic(obs, action, target=False):
        return q_values(nets, psi(nets, obs, action, target=target), target=target)

    return critic


def _q(critic: Critic, batch: Batch, obs: torch.Tensor, action: torch.Tensor, target: bool = False):
    """critic(obs, action, target) in the batch's dtype: under a bf16 autocast (the trainers'
    `learner_precision`) the critic's matmuls run in bf16 while every reduction of a loss stays fp32."""
    return critic(obs, action, target=target).to(batch.obs.dtype)


def _td_loss(cfg, batch: Batch, q: torch.Tensor, next_value: torch.Tensor):
    """The TD loss of both critics: y = rs·r + discount·γ·next_value (B,), loss = ½ mean_{b,j}(m_b(Q_j −
    sg(y)))² over the twin Q (B, 2). Returns (loss, {"q": mean Q, "target_q": mean y})."""
    y = (cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * next_value).detach()
    err = (1.0 - batch.truncation)[:, None] * (q - y[:, None])
    return 0.5 * torch.mean(err.square()), {"q": q.mean().detach(), "target_q": y.mean()}


# ------------------------------------------------------------------------------------------------ TD3
def td3_critic_loss(
    nets: Networks, batch: Batch, smoothing: torch.Tensor, *, critic: Critic | None = None
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The TD3 critic loss (Algorithm 2 on features), trained on Q (and, by default, ψ).

    ã′ = clip(π̄(s′) + clip(σ_s ξ, −c, c), −1, 1), y = rs·r + discount·γ·min_j Q̄_j(s′, ã′),
    loss = ½ mean_{b,j}(m_b(Q_j(s, a) − sg(y)))².

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      batch: the transitions.
      smoothing: ξ (B, A) ~ N(0, I), the target policy's smoothing noise.
      critic: `critic(obs, action, target=False)` → (B, 2); None: SF²'s Q(ψ) (`sf2_critic`).

    Returns:
      (loss, {"q": mean Q, "target_q": mean y}).

    Raises:
      ShapeError: a field of `batch` or the noise of another shape.
    """
    cfg = nets.cfg
    critic = critic or sf2_critic(nets)
    b = check_batch(cfg, batch)
    check_noise("smoothing", smoothing, b, cfg.action_size, "action_size")
    with torch.no_grad():
        noise = torch.clamp(cfg.smoothing_noise * smoothing, -cfg.noise_clip, cfg.noise_clip)
        next_action = torch.clamp(td3_action(nets, batch.next_obs, target=True) + noise, -1.0, 1.0)
        next_value = _q(critic, batch, batch.next_obs, next_action, target=True).min(-1).values
    return _td_loss(cfg, batch, _q(critic, batch, batch.obs, batch.action), next_value)


def td3_actor_loss(
    nets: Networks, batch: Batch, *, critic: Critic | None = None
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The TD3 actor loss (Algorithm 2), trained on the policy only.

    loss = −mean_b Q_0(s, π(s)), the deterministic policy gradient (rlax's `dpg_loss`, which the authors call,
    has the same gradient for A = 1 and 1/A of it otherwise: docs/core-contract.md).

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      batch: the transitions.
      critic: `critic(obs, action, target=False)` → (B, 2); None: SF²'s Q(ψ) (`sf2_critic`).

    Returns:
      (loss, {"q": mean Q_0}).

    Raises:
      ShapeError: a field of `batch` of another shape.
    """
    critic = critic or sf2_critic(nets)
    check_batch(nets.cfg, batch)
    action = td3_action(nets, batch.obs)
    loss = -torch.mean(_q(critic, batch, batch.obs, action)[:, 0])
    return loss, {"q": -loss.detach()}


# ------------------------------------------------------------------------------------------------ SAC
def _alpha(nets: Networks) -> torch.Tensor:
    """exp(log_alpha), detached (a constant in the critic and actor losses)."""
    if nets.algo != "sac":
        raise ConfigError(f"SAC losses need networks built with algo='sac', found algo={nets.algo!r}")
    return torch.exp(nets.log_alpha.detach())


def sac_critic_loss(
    nets: Networks, batch: Batch, noise: torch.Tensor, *, critic: Critic | None = None
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The SAC critic loss (Algorithm 3 on features), trained on Q (and, by default, ψ).

    a′, log π(a′|s′) from the online policy at s′ with ξ′ = `noise`;
    y = rs·r + discount·γ·(min_j Q̄_j(s′, a′) − α log π(a′|s′)), α = exp(log_alpha) constant;
    loss = ½ mean_{b,j}(m_b(Q_j(s, a) − sg(y)))².

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      batch: the transitions.
      noise: ξ′ (B, A) ~ N(0, I), the policy's noise at s′.
      critic: `critic(obs, action, target=False)` → (B, 2); None: SF²'s Q(ψ) (`sf2_critic`).

    Returns:
      (loss, {"q": mean Q, "target_q": mean y}).

    Raises:
      ConfigError: networks built for another algorithm than SAC.
      ShapeError: a field of `batch` or the noise of another shape.
    """
    cfg = nets.cfg
    critic = critic or sf2_critic(nets)
    alpha = _alpha(nets)
    b = check_batch(nets.cfg, batch)
    check_noise("noise", noise, b, nets.cfg.action_size, "action_size")
    with torch.no_grad():
        next_action, next_log_prob = sac_sample(nets, batch.next_obs, noise)
        next_log_prob = next_log_prob.to(batch.obs.dtype)
        next_value = (_q(critic, batch, batch.next_obs, next_action, target=True).min(-1).values
                      - alpha * next_log_prob)
    return _td_loss(cfg, batch, _q(critic, batch, batch.obs, batch.action), next_value)


def sac_actor_loss(
    nets: Networks, batch: Batch, noise: torch.Tensor, *, critic: Critic | None = None
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The SAC actor loss (Algorithm 3), trained on the policy only.

    a ~ π(s) with ξ = `noise`; loss = mean_b(α log π(a|s) − min_j Q_j(s, a)), α constant.

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      batch: the transitions.
      noise: ξ (B, A) ~ N(0, I).
      critic: `critic(obs, action, target=False)` → (B, 2); None: SF²'s Q(ψ) (`sf2_critic`).

    Returns:
      (loss, {"entropy": −mean log π}).

    Raises:
      ConfigError: networks built for another algorithm than SAC.
      ShapeError: a field of `batch` or the noise of another shape.
    """
    critic = critic or sf2_critic(nets)
    alpha = _alpha(nets)
    b = check_batch(nets.cfg, batch)
    check_noise("noise", noise, b, nets.cfg.action_size, "action_size")
    action, log_prob = sac_sample(nets, batch.obs, noise)
    log_prob = log_prob.to(batch.obs.dtype)
    loss = torch.mean(alpha * log_prob - _q(critic, batch, batch.obs, action).min(-1).values)
    return loss, {"entropy": -log_prob.mean().detach()}


def sac_alpha_loss(
    nets: Networks, batch: Batch, noise: torch.Tensor
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The SAC temperature loss, trained on log_alpha only.

    loss = mean_b(exp(log_alpha)·sg(−log π(a|s) − target_entropy)), target_entropy = −target_entropy_scale·A,
    a ~ π(s) with ξ = `noise`.

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      batch: the transitions.
      noise: ξ (B, A) ~ N(0, I).

    Returns:
      (loss, {"alpha": α}).

    Raises:
      ConfigError: networks built for another algorithm than SAC.
      ShapeError: a field of `batch` or the noise of another shape.
    """
    cfg = nets.cfg
    _alpha(nets)
    b = check_batch(nets.cfg, batch)
    check_noise("noise", noise, b, nets.cfg.action_size, "action_size")
    with torch.no_grad():
        _, log_prob = sac_sample(nets, batch.obs, noise)
        log_prob = log_prob.to(batch.obs.dtype)
    target_entropy = -cfg.target_entropy_scale * cfg.action_size
    alpha = torch.exp(nets.log_alpha)
    loss = torch.mean(alpha * (-log_prob - target_entropy))
    return loss, {"alpha": alpha.detach()}


# ------------------------------------------------------------------------------------------------ EMA
def _tensors(x: nn.Module | Iterable[torch.Tensor]) -> list[torch.Tensor]:
    return list(x.parameters()) if isinstance(x, nn.Module) else list(x)


@torch.no_grad()
def ema_update(
    target: nn.Module | Iterable[torch.Tensor], online: nn.Module | Iterable[torch.Tensor], tau: float
) -> None:
    """The target-network EMA (paper §3.4): target ← (1 − τ)·target + τ·online, in place.

    Args:
      target: the target module (or a sequence of tensors).
      online: the online module of the same architecture (or matching tensors).
      tau: the rate τ in [0, 1] (checked when a Python number; a tensor is not checked).

    Raises:
      ConfigError: a rate outside [0, 1].
      ShapeError: modules of another architecture.
    """
    if isinstance(tau, numbers.Real) and not 0.0 <= float(tau) <= 1.0:
        raise ConfigError(f"tau={tau!r} is invalid: must satisfy 0 <= tau <= 1")
    t, o = _tensors(target), _tensors(online)
    if len(t) != len(o) or any(a.shape != b.shape for a, b in zip(t, o)):
        raise ShapeError(
            "ema_update needs target and online of the same architecture, found parameter shapes "
            f"{[tuple(a.shape) for a in t]} and {[tuple(b.shape) for b in o]}"
        )
    if t:
        torch._foreach_mul_(t, 1.0 - float(tau))
        torch._foreach_add_(t, o, alpha=float(tau))
