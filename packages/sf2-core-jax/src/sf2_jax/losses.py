"""Losses of SF² with TD3 and SAC: pure functions of parameters, a batch and explicit noise.

Paper: eq. (3)–(4) and Algorithm 1 (flow), Appendix A.3 (explicit mixture), Appendix D Algorithms 2–3
(TD3 and SAC on features); docs/core-contract.md "Losses". Every random draw (ε, flow_time k, smoothing
ξ, SAC noise) is an argument, so the same inputs give the same numbers in JAX and torch. Each loss
returns `(loss, aux)`, `aux` a dict of scalars; batches are 2-D, every field (B, ·) (vmap a loss for more
batch dimensions); batch means divide by B, samples masked by m_b = 1 − truncation_b count as zeros. The
TD3 and SAC losses are written once against a `critic` (default: SF²'s Q(ψ(s, a)), `sf2_critic`; the
agents pass their representation's).

Gradient contract: the caller takes `jax.grad` with respect to the trained groups only; with the default
critic a loss also stops the gradient of every group it does not train. The TD target y and SAC's α are
constants in every case. `check_batch` and `check_noise` are the losses' shape checks, public for the
baselines' losses (the torch core's `sf2_torch.losses` has the same functions).
"""

from __future__ import annotations

import numbers
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from sf2_common.errors import ConfigError, ShapeError

from sf2_jax import networks as nw
from sf2_jax.ode import integrate

__all__ = [
    "Batch", "Critic", "sf2_critic", "flow_loss", "explicit_mixture_loss", "td3_critic_loss",
    "td3_actor_loss", "sac_critic_loss", "sac_actor_loss", "sac_alpha_loss", "ema_update", "check_batch",
    "check_noise", "flow_field_loss", "velocity_fields",
]

sg = jax.lax.stop_gradient
Critic = Callable[..., Any]   # critic(params, obs, action, target=False) -> (B, 2)


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

    obs: Any
    action: Any
    reward: Any
    discount: Any
    next_obs: Any
    truncation: Any


def _trainable(params: nw.Params, groups: tuple[str, ...]) -> nw.Params:
    """Stop the gradient of every group not in `groups` (targets, normalizer, untrained networks)."""
    return {name: (value if name in groups else sg(value)) for name, value in params.items()}


def _with_critic(nets: nw.Networks, params: nw.Params, trained: tuple[str, ...], critic: Critic | None):
    """(params, critic) of a TD3/SAC loss: the default SF² critic with the gradient of every group but
    `trained` stopped, or the caller's critic on the caller's params (module docstring)."""
    if critic is None:
        return _trainable(params, trained), sf2_critic(nets)
    return params, critic


# ------------------------------------------------------------------------------------------------ checks
def check_batch(cfg, batch: Batch) -> tuple[int]:
    """Check a 2-D batch against a config's sizes, on static shapes only (free under `jax.jit`).

    Args:
      cfg: the `SF2Config` (its `obs_size` and `action_size`).
      batch: the transitions; obs and next_obs (B, D), action (B, A), reward, discount, truncation (B,).

    Returns:
      The batch shape (B,).

    Raises:
      ShapeError: a field's shape differs, naming the field, the expected and the found shape.
    """
    nw.check_last("batch.obs", batch.obs, cfg.obs_size, "obs_size")
    if jnp.ndim(batch.obs) != 2:
        raise ShapeError(f"batch.obs: expected shape (B, {cfg.obs_size}) (a 2-D batch; vmap the loss for "
                         f"more batch dimensions), found shape {tuple(jnp.shape(batch.obs))}")
    nw.check_last("batch.next_obs", batch.next_obs, cfg.obs_size, "obs_size")
    nw.check_last("batch.action", batch.action, cfg.action_size, "action_size")
    b = tuple(jnp.shape(batch.obs)[:-1])
    for name in ("next_obs", "action"):
        nw._check_leading(f"batch.{name}", getattr(batch, name), b, "batch.obs")
    for name in ("reward", "discount", "truncation"):
        nw._check_batch_dims(f"batch.{name}", getattr(batch, name), b, "batch.obs")
    return b


def check_noise(name: str, x, batch_shape: tuple, size: int, what: str) -> None:
    """Check an explicit noise (or another per-sample input) of shape (B, size), on static shapes only.

    Args:
      name: the argument's name, for the message.
      x: the array.
      batch_shape: (B,), the batch's (`check_batch`).
      size: its last dimension.
      what: the config field `size` is, for the message ("action_size", "obs_size").

    Raises:
      ShapeError: `x` is not of shape (*batch_shape, size), naming both.
    """
    nw.check_last(name, x, size, what)
    nw._check_leading(name, x, batch_shape, "batch.obs")


def _check_same(name: str, x, shape: tuple, what: str) -> None:
    if tuple(jnp.shape(x)) != tuple(shape):
        raise ShapeError(f"{name} must have shape {tuple(shape)} ({what}), found {tuple(jnp.shape(x))}")


def _require_sac(nets: nw.Networks) -> None:
    if nets.algo != "sac":
        raise ConfigError(f"SAC losses need networks built with algo='sac', found algo={nets.algo!r}")


# ------------------------------------------------------------------------------------------------ flow
def flow_field_loss(cfg, online: Callable, target: Callable | None, x1, eps, flow_time, truncation):
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
        the flow time k = `flow_time`), stacked (len(xs), B, D) or as a sequence (`velocity_fields`).
      target: `target(x, k)` → ū(x, k) = ζ̄(x, k)ψ̄(s′, ā′) (B, D) at any flow time; None when γ_su = 0.
      x1: the flow's data point (B, D): normalize(s′), a flattened grid s′, or a latent z′.
      eps: ε (B, D) ~ N(0, I).
      flow_time: k (B,) ~ U(0, 1).
      truncation: (B,) 1 where the time limit cut the episode.

    Returns:
      (loss, {"loss_p": mean_b m_b ℓ_P, "loss_boot": mean_b m_b ℓ_B}).
    """
    k = flow_time
    x_k = k[:, None] * x1 + (1 - k[:, None]) * eps
    mask = 1 - truncation
    if cfg.gamma_su == 0:
        (u_p,) = online(x_k)
        loss_p = jnp.mean(mask * jnp.sum((u_p - (x1 - eps)) ** 2, axis=-1))
        return loss_p, {"loss_p": loss_p, "loss_boot": jnp.zeros_like(loss_p)}

    x_hat = sg(integrate(target, eps, k, cfg.denoising_steps, cfg.integrator))
    u_p, u_b = online(x_k, x_hat)
    loss_p = jnp.sum((u_p - (x1 - eps)) ** 2, axis=-1)
    loss_b = jnp.sum((u_b - sg(target(x_hat, k))) ** 2, axis=-1)
    loss = jnp.mean(mask * ((1 - cfg.gamma_su) * loss_p + cfg.gamma_su * loss_b))
    return loss, {"loss_p": jnp.mean(mask * loss_p), "loss_boot": jnp.mean(mask * loss_b)}


def velocity_fields(nets: nw.Networks, params: nw.Params, features, next_features, flow_time):
    """The online and target velocity fields of the vector ζ, as `flow_field_loss` takes them.

    With `cfg.contract_zeta` (the fast path, docs/core-contract.md "Networks") ζ's last layer is contracted
    with ψ once (M, c) and with ψ̄′ once (M̄, c̄), reused for every evaluation, and the online evaluations at
    several points go through ζ's hidden layers as one batch; otherwise (the oracle) ζ (B, D, F) is
    materialized at each point.

    Args:
      nets: the `Networks` (its `cfg` and ζ; `sf2_jax.networks_image.latent_networks` for the latent flow).
      params: parameters with the groups `zeta` and `target_zeta`.
      features: ψ(s, a) (B, F).
      next_features: ψ̄(s′, ā′) (B, F), already without gradient; None: no target field.
      flow_time: k (B,), the online field's flow time.

    Returns:
      (online, target): `online(*xs)` → ζ(x, k)ψ at each x, stacked (len(xs), B, D); `target(x, k)` →
      ζ̄(x, k)ψ̄′ (B, D), or None.

    Raises:
      ShapeError: features of another last dimension.
    """
    k = flow_time
    b = tuple(jnp.shape(features)[:-1])
    if nets.cfg.contract_zeta:
        M, c = nw.contract(nets, params, features)

        def online(*xs):   # ζ(x, k)ψ at every x of `xs`: one hidden-layer pass over all of them
            h = nw.zeta_hidden(nets, params, jnp.concatenate(xs), jnp.concatenate([k] * len(xs)))
            return jnp.einsum("nbh,bdh->nbd", h.reshape(len(xs), *b, h.shape[-1]), M) + c
    else:
        def online(*xs):
            return [nw.velocity(nets, params, x, k, features) for x in xs]

    if next_features is None:
        return online, None
    if nets.cfg.contract_zeta:
        M_bar, c_bar = nw.contract(nets, params, next_features, target=True)

        def target(x, kk):
            return nw.velocity_contracted(nets, params, x, kk, M_bar, c_bar, target=True)
    else:
        def target(x, kk):
            return nw.velocity(nets, params, x, kk, next_features, target=True)
    return online, target


def flow_loss(nets: nw.Networks, params: nw.Params, batch: Batch, next_action, eps, flow_time):
    """The flow loss of SF² (eq. 3–4, Algorithm 1), trained on ψ and ζ.

    L_flow = mean_b m_b[(1 − γ_su) ℓ_P + γ_su ℓ_B], with
    ℓ_P = Σ_d (ζ(x_k, k)ψ − (s̄′ − ε))²_d, x_k = k s̄′ + (1 − k) ε, s̄′ = normalize(s′), ψ = ψ(s, a);
    ℓ_B = Σ_d (ζ(x̂, k)ψ − sg(ζ̄(x̂, k)ψ̄′))²_d, ψ̄′ = ψ̄(s′, ā′), x̂ the ODE solution from ε over [0, k] under
    the target field ζ̄ψ̄′ (`denoising_steps` steps of `integrator`): `flow_field_loss` with x1 = s̄′ and
    the fields of `velocity_fields` (the fast path with `cfg.contract_zeta`, else the plain oracle).
    With γ_su = 0 the bootstrap branch is skipped and loss_boot = 0.

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      params: the parameters of every group (`networks.init_params`).
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
    b = check_batch(cfg, batch)
    check_noise("next_action", next_action, b, cfg.action_size, "action_size")
    check_noise("eps", eps, b, cfg.obs_size, "obs_size")
    nw._check_batch_dims("flow_time", flow_time, b, "batch.obs")
    p = _trainable(params, ("psi", "zeta"))
    next_action = sg(next_action)

    next_obs_n = nw.normalize(batch.next_obs, p["obs_norm"])
    features = nw.psi(nets, p, batch.obs, batch.action)
    next_features = None
    if cfg.gamma_su != 0:
        next_features = sg(nw.psi(nets, p, batch.next_obs, next_action, target=True))
    online, target = velocity_fields(nets, p, features, next_features, flow_time)
    return flow_field_loss(cfg, online, target, next_obs_n, eps, flow_time, batch.truncation)


def explicit_mixture_loss(velocity_fn: Callable, x1, x2, eps1, eps2, k1, k2, weight):
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
        _check_same("eps", e, jnp.shape(x), "same as x")
        _check_same("k", k, jnp.shape(x)[:-1], "(B,)")
        x_k = k[..., None] * x + (1 - k[..., None]) * e
        return jnp.mean(jnp.sum((velocity_fn(x_k, k) - (x - e)) ** 2, axis=-1))

    loss_1, loss_2 = term(x1, eps1, k1), term(x2, eps2, k2)
    return weight * loss_1 + (1 - weight) * loss_2, {"loss_1": loss_1, "loss_2": loss_2}


# ------------------------------------------------------------------------------------------------ critic
def sf2_critic(nets: nw.Networks) -> Critic:
    """SF²'s critic Q(ψ(s, a)) (Appendix D): the core's twin Q heads on ψ.

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).

    Returns:
      `critic(params, obs, action, target=False)` → (B, 2); `target=True`: Q̄(ψ̄(s, a)).
    """

    def critic(params: nw.Params, obs, action, target: bool = False):
        return nw.q_values(nets, params, nw.psi(nets, params, obs, action, target=target), target=target)

    return critic


def _td_loss(cfg, batch: Batch, q, next_value):
    """The TD loss of both critics: y = rs·r + discount·γ·next_value (B,), loss = ½ mean_{b,j}(m_b(Q_j −
    sg(y)))² over the twin Q (B, 2). Returns (loss, {"q": mean Q, "target_q": mean y})."""
    y = sg(cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * next_value)
    err = (1 - batch.truncation)[:, None] * (q - y[:, None])
    return 0.5 * jnp.mean(err**2), {"q": jnp.mean(q), "target_q": jnp.mean(y)}


# ------------------------------------------------------------------------------------------------ TD3
def td3_critic_loss(nets: nw.Networks, params: nw.Params, batch: Batch, smoothing, *,
                    critic: Critic | None = None):
    """The TD3 critic loss (Algorithm 2 on features), trained on Q (and, by default, ψ).

    ã′ = clip(π̄(s′) + clip(σ_s ξ, −c, c), −1, 1), y = rs·r + discount·γ·min_j Q̄_j(s′, ã′),
    loss = ½ mean_{b,j}(m_b(Q_j(s, a) − sg(y)))².

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      params: the parameters of every group (`networks.init_params`).
      batch: the transitions.
      smoothing: ξ (B, A) ~ N(0, I), the target policy's smoothing noise.
      critic: `critic(params, obs, action, target=False)` → (B, 2); None: SF²'s Q(ψ) (`sf2_critic`).

    Returns:
      (loss, {"q": mean Q, "target_q": mean y}).

    Raises:
      ShapeError: a field of `batch` or the noise of another shape.
    """
    cfg = nets.cfg
    b = check_batch(cfg, batch)
    check_noise("smoothing", smoothing, b, cfg.action_size, "action_size")
    p, critic = _with_critic(nets, params, ("psi", "q"), critic)
    noise = jnp.clip(cfg.smoothing_noise * smoothing, -cfg.noise_clip, cfg.noise_clip)
    next_action = jnp.clip(nw.td3_action(nets, p, batch.next_obs, target=True) + noise, -1, 1)
    next_q = critic(p, batch.next_obs, next_action, target=True)
    return _td_loss(cfg, batch, critic(p, batch.obs, batch.action), jnp.min(next_q, axis=-1))


def td3_actor_loss(nets: nw.Networks, params: nw.Params, batch: Batch, *, critic: Critic | None = None):
    """The TD3 actor loss (Algorithm 2), trained on the policy only.

    loss = −mean_b Q_0(s, π(s)), the deterministic policy gradient (rlax's `dpg_loss`, which the authors call,
    has the same gradient for A = 1 and 1/A of it otherwise: docs/core-contract.md).

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      params: the parameters of every group (`networks.init_params`).
      batch: the transitions.
      critic: `critic(params, obs, action, target=False)` → (B, 2); None: SF²'s Q(ψ) (`sf2_critic`).

    Returns:
      (loss, {"q": mean Q_0}).

    Raises:
      ShapeError: a field of `batch` of another shape.
    """
    check_batch(nets.cfg, batch)
    p, critic = _with_critic(nets, params, ("policy",), critic)
    action = nw.td3_action(nets, p, batch.obs)
    loss = -jnp.mean(critic(p, batch.obs, action)[:, 0])
    return loss, {"q": -loss}


# ------------------------------------------------------------------------------------------------ SAC
def sac_critic_loss(nets: nw.Networks, params: nw.Params, batch: Batch, noise, *,
                    critic: Critic | None = None):
    """The SAC critic loss (Algorithm 3 on features), trained on Q (and, by default, ψ).

    a′, log π(a′|s′) from the online policy at s′ with ξ′ = `noise`;
    y = rs·r + discount·γ·(min_j Q̄_j(s′, a′) − α log π(a′|s′)), α = exp(log_alpha) constant;
    loss = ½ mean_{b,j}(m_b(Q_j(s, a) − sg(y)))².

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      params: the parameters of every group (`networks.init_params`).
      batch: the transitions.
      noise: ξ′ (B, A) ~ N(0, I), the policy's noise at s′.
      critic: `critic(params, obs, action, target=False)` → (B, 2); None: SF²'s Q(ψ) (`sf2_critic`).

    Returns:
      (loss, {"q": mean Q, "target_q": mean y}).

    Raises:
      ConfigError: networks built for another algorithm than SAC.
      ShapeError: a field of `batch` or the noise of another shape.
    """
    cfg = nets.cfg
    _require_sac(nets)
    b = check_batch(cfg, batch)
    check_noise("noise", noise, b, cfg.action_size, "action_size")
    p, critic = _with_critic(nets, params, ("psi", "q"), critic)
    alpha = sg(jnp.exp(p["log_alpha"]))
    next_action, next_log_prob = nw.sac_sample(nets, p, batch.next_obs, noise)
    next_q = critic(p, batch.next_obs, next_action, target=True)
    next_value = jnp.min(next_q, axis=-1) - alpha * next_log_prob
    return _td_loss(cfg, batch, critic(p, batch.obs, batch.action), next_value)


def sac_actor_loss(nets: nw.Networks, params: nw.Params, batch: Batch, noise, *,
                   critic: Critic | None = None):
    """The SAC actor loss (Algorithm 3), trained on the policy only.

    a ~ π(s) with ξ = `noise`; loss = mean_b(α log π(a|s) − min_j Q_j(s, a)), α constant.

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      params: the parameters of every group (`networks.init_params`).
      batch: the transitions.
      noise: ξ (B, A) ~ N(0, I).
      critic: `critic(params, obs, action, target=False)` → (B, 2); None: SF²'s Q(ψ) (`sf2_critic`).

    Returns:
      (loss, {"entropy": −mean log π}).

    Raises:
      ConfigError: networks built for another algorithm than SAC.
      ShapeError: a field of `batch` or the noise of another shape.
    """
    cfg = nets.cfg
    _require_sac(nets)
    b = check_batch(cfg, batch)
    check_noise("noise", noise, b, cfg.action_size, "action_size")
    p, critic = _with_critic(nets, params, ("policy",), critic)
    alpha = sg(jnp.exp(p["log_alpha"]))
    action, log_prob = nw.sac_sample(nets, p, batch.obs, noise)
    loss = jnp.mean(alpha * log_prob - jnp.min(critic(p, batch.obs, action), axis=-1))
    return loss, {"entropy": -jnp.mean(log_prob)}


def sac_alpha_loss(nets: nw.Networks, params: nw.Params, batch: Batch, noise):
    """The SAC temperature loss, trained on log_alpha only.

    loss = mean_b(exp(log_alpha)·sg(−log π(a|s) − target_entropy)), target_entropy = −target_entropy_scale·A,
    a ~ π(s) with ξ = `noise`.

    Args:
      nets: the `Networks` (its `cfg`: sizes and hyperparameters; its algo: the policy).
      params: the parameters of every group (`networks.init_params`).
      batch: the transitions.
      noise: ξ (B, A) ~ N(0, I).

    Returns:
      (loss, {"alpha": α}).

    Raises:
      ConfigError: networks built for another algorithm than SAC.
      ShapeError: a field of `batch` or the noise of another shape.
    """
    cfg = nets.cfg
    _require_sac(nets)
    b = check_batch(cfg, batch)
    check_noise("noise", noise, b, cfg.action_size, "action_size")
    p = _trainable(params, ("log_alpha",))
    _, log_prob = nw.sac_sample(nets, p, batch.obs, noise)
    target_entropy = -cfg.target_entropy_scale * cfg.action_size
    alpha = jnp.exp(p["log_alpha"])
    loss = jnp.mean(alpha * sg(-log_prob - target_entropy))
    return loss, {"alpha": sg(alpha)}


# ------------------------------------------------------------------------------------------------ EMA
def ema_update(target, online, tau):
    """The target-network EMA (paper §3.4): target ← (1 − τ)·target + τ·online, leaf by leaf.

    Args:
      target: the target parameters (a pytree).
      online: the online parameters, the same tree and shapes.
      tau: the rate τ in [0, 1] (checked when a Python number; a traced value is not checked).

    Returns:
      The new target parameters.

    Raises:
      ConfigError: a rate outside [0, 1].
      ShapeError: trees of another architecture.
    """
    if isinstance(tau, numbers.Real) and not 0.0 <= float(tau) <= 1.0:
        raise ConfigError(f"tau={tau!r} is invalid: must satisfy 0 <= tau <= 1")
    t, o = jax.tree_util.tree_leaves(target), jax.tree_util.tree_leaves(online)
    if (jax.tree_util.tree_structure(target) != jax.tree_util.tree_structure(online)
            or any(jnp.shape(a) != jnp.shape(b) for a, b in zip(t, o))):
        raise ShapeError(
            "ema_update needs target and online of the same architecture, found parameter shapes "
            f"{[tuple(jnp.shape(a)) for a in t]} and {[tuple(jnp.shape(b)) for b in o]}"
        )
    return jax.tree_util.tree_map(lambda t, o: (1 - tau) * t + tau * o, target, online)
