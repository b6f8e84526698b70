"""Losses of the MinAtar system (docs/minatar.md): pure functions of the networks, data and explicit noise.

SF²'s flow loss over images (w/o AE) and over an autoencoder's latents (w AE), both `losses.
flow_field_loss` (the vector flow loss's code), the autoencoder's cross-entropy, the expected-SARSA
λ-return and GAE over a (T, N) rollout (reverse scans), and PPO's clipped policy loss, Q critic loss and
clipped V critic loss; FPO's flow-policy losses and Euler sampling (docs/fpo.md), over any velocity field
`velocity(x, τ)`; docs/core-contract.md "On-policy losses". Batches are `losses.Batch` with grids
(B, H, W, C) and integer actions (B,); means divide by B. Each loss returns `(loss, aux)`, `aux` a dict of
detached 0-d tensors; the caller calls `loss.backward(inputs=...)` with the trained groups' parameters
(targets, the λ-return and the latent z′ carry no gradient). The JAX core's `sf2_jax.losses_onpolicy` has
the same functions and messages.
"""

from __future__ import annotations

import numbers

import torch
from sf2_common.errors import ConfigError, ShapeError

from . import networks_image as nwi
from .losses import Batch, check_noise, flow_field_loss, velocity_fields

__all__ = [
    "check_image_batch", "image_flow_loss", "latent_flow_loss", "autoencoder_loss", "lambda_returns", "gae",
    "ppo_policy_loss", "q_critic_loss", "v_critic_loss", "cfm_losses", "fpo_ratio", "fpo_policy_loss",
    "flow_policy_sample",
]

ADVANTAGE_EPS = 1e-8   # PureJaxRL's (A − mean) / (std + 1e-8)


# ------------------------------------------------------------------------------------------------ checks
def _check_per_sample(name: str, x: torch.Tensor, batch_shape: tuple) -> None:
    if tuple(x.shape) != tuple(batch_shape):
        raise ShapeError(f"{name} must have shape {tuple(batch_shape)} (one value per sample), found "
                         f"{tuple(x.shape)}")


def _check_rate(name: str, value, low_open: bool = False) -> None:
    """A Python number in [0, 1] ((0, 1] with `low_open`); a tensor is not checked."""
    if isinstance(value, numbers.Real) and not ((0 < value if low_open else 0 <= value) and value <= 1):
        low = "0 <" if low_open else "0 <="
        raise ConfigError(f"{name}={value!r} is invalid: must satisfy {low} {name} <= 1")


def check_image_batch(nets: nwi.ImageNetworks, batch: Batch) -> tuple[int]:
    """Check a batch of image transitions, on shapes and dtypes (values: `nwi.check_actions`).

    Args:
      nets: the `ImageNetworks`.
      batch: obs and next_obs grids (B, H, W, C) of floats, action indices (B,), reward, discount (1 −
        terminal) and truncation (B,).

    Returns:
      The batch shape (B,).

    Raises:
      ShapeError: a field of another shape or dtype, or an action outside [0, A).
    """
    b = nwi.check_obs(nets, "batch.obs", batch.obs)
    nwi.check_obs(nets, "batch.next_obs", batch.next_obs, b)
    nwi.check_actions(nets, "batch.action", batch.action, b)
    for name in ("reward", "discount", "truncation"):
        _check_per_sample(f"batch.{name}", getattr(batch, name), b)
    return b


def _check_flow_inputs(nets, batch, next_action, eps, flow_time, size: int, what: str) -> tuple[int]:
    b = check_image_batch(nets, batch)
    nwi.check_actions(nets, "next_action", next_action, b)
    check_noise("eps", eps, b, size, what)
    nwi.check_flow_time(flow_time, b)
    return b


# ------------------------------------------------------------------------------------------------ flow
def _image_fields(nets, features, next_features, flow_time):
    """The online and target fields of the image ζ (`losses.velocity_fields`' image counterpart): with
    `cfg.contract_zeta`, M = Wψ and M̄ = W̄ψ̄′ once and the online points as one batch; else the oracle."""
    cfg, k = nets.cfg, flow_time
    B = features.shape[0]
    if cfg.contract_zeta:
        M, c = nwi.contract(nets, features)

        def online(*xs):
            h = nwi.zeta_hidden(nets, torch.cat(xs), torch.cat([k] * len(xs)))
            u = torch.einsum("nbpqh,bhc->nbpqc", h.reshape(len(xs), B, *h.shape[1:]), M) + c[:, None, None, :]
            return tuple(u.reshape(len(xs), B, cfg.obs_size))
    else:
        def online(*xs):
            return tuple(nwi.velocity(nets, x, k, features) for x in xs)

    if next_features is None:
        return online, None
    if cfg.contract_zeta:
        with torch.no_grad():
            M_bar, c_bar = nwi.contract(nets, next_features, target=True)

        def target(x, kk):
            return nwi.velocity_contracted(nets, x, kk, M_bar, c_bar, target=True)
    else:
        def target(x, kk):
            return nwi.velocity(nets, x, kk, next_features, target=True)
    return online, target


def _next_features(nets, batch, next_action):
    if nets.cfg.gamma_su == 0:
        return None
    with torch.no_grad():
        return nwi.psi(nets, batch.next_obs, next_action, target=True)


def image_flow_loss(nets: nwi.ImageNetworks, batch: Batch, next_action: torch.Tensor, eps: torch.Tensor,
                    flow_time: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """SF²'s flow loss w/o AE: the flow in image space, trained on ψ and ζ.

    `losses.flow_field_loss` with x1 = s′ flattened (B, D), D = H·W·C in NHWC order, not normalized;
    u(x, k) = ζ(x, k)ψ(s, a) with the image ζ, u_{p,c} = Σ_h h_{p,h}(x, k) (Wψ)_{h,c} + (bψ)_c (through
    M = Wψ on the fast path, `cfg.contract_zeta`; the materialized ζ otherwise); the bootstrap ODE under
    ū = ζ̄(x, k)ψ̄(s′, a′). L_flow = mean_b m_b[(1 − γ_su) ℓ_P + γ_su ℓ_B], m_b = 1 − truncation_b.

    Args:
      nets: "sf2" `ImageNetworks`.
      batch: image transitions (`check_image_batch`); next_obs is s′ of the transition (at an episode's end,
        its last grid, not the reset one).
      next_action: a′ (B,), the action taken at s′; gets no gradient.
      eps: ε (B, D) ~ N(0, I).
      flow_time: k (B,) ~ U(0, 1).

    Returns:
      (loss, {"loss_p": mean_b m_b ℓ_P, "loss_boot": mean_b m_b ℓ_B}).

    Raises:
      ConfigError: networks of another method.
      ShapeError: a field of `batch`, an action, ε or k of another shape or dtype, an action outside [0, A),
        or a flow time outside [0, 1].
    """
    nwi._require(nets, ("sf2",), "image_flow_loss")
    cfg = nets.cfg
    b = _check_flow_inputs(nets, batch, next_action, eps, flow_time, cfg.obs_size, "obs_size")
    x1 = batch.next_obs.reshape(*b, cfg.obs_size)
    features = nwi.psi(nets, batch.obs, batch.action)
    online, target = _image_fields(nets, features, _next_features(nets, batch, next_action), flow_time)
    return flow_field_loss(cfg, online, target, x1, eps, flow_time, batch.truncation)


def latent_flow_loss(nets: nwi.ImageNetworks, batch: Batch, next_action: torch.Tensor, eps: torch.Tensor,
                     flow_time: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """SF²'s flow loss w AE: the vector flow loss over latents, trained on ψ and ζ (not the encoder).

    `losses.flow_field_loss` with x1 = z′ = sg(E(s′)) ∈ [−1, 1]^64 (no normalization) and the vector ζ's
    fields (`losses.velocity_fields` of `networks_image.latent_networks(nets)`) for ψ(s, a) and ψ̄(s′, a′)
    of the image ψ: the vector `losses.flow_loss`'s computation with these ψ and s̄′ = z′.

    Args:
      nets: "sf2_ae" `ImageNetworks`.
      batch: image transitions (`check_image_batch`).
      next_action: a′ (B,), the action taken at s′; gets no gradient.
      eps: ε (B, 64) ~ N(0, I).
      flow_time: k (B,) ~ U(0, 1).

    Returns:
      (loss, {"loss_p": mean_b m_b ℓ_P, "loss_boot": mean_b m_b ℓ_B}).

    Raises:
      ConfigError: networks of another method.
      ShapeError: as `image_flow_loss`, with ε of shape (B, 64).
    """
    nwi._require(nets, ("sf2_ae",), "latent_flow_loss")
    _check_flow_inputs(nets, batch, next_action, eps, flow_time, nwi.LATENT_SIZE, "the latent size")
    latent = nwi.latent_networks(nets)
    with torch.no_grad():
        x1 = nwi.encode(nets, batch.next_obs)
    features = nwi.psi(nets, batch.obs, batch.action)
    online, target = velocity_fields(latent, features, _next_features(nets, batch, next_action), flow_time)
    return flow_field_loss(latent.cfg, online, target, x1, eps, flow_time, batch.truncation)


def autoencoder_loss(nets: nwi.ImageNetworks, obs: torch.Tensor
                     ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The autoencoder's loss, trained on the encoder and the decoder: binary cross-entropy of the grid's
    cells under the decoder's Bernoulli logits ℓ = D(E(s)), summed over the cells, averaged over the batch.

    loss = mean_b Σ_d [log(1 + e^{ℓ_d}) − ℓ_d s_d] (−log σ(ℓ) for s = 1, −log σ(−ℓ) for s = 0), the softplus
    as logaddexp(0, ℓ): stable, and smooth at ℓ = 0 (its gradient is σ(ℓ) − s everywhere).

    Args:
      nets: "sf2_ae" `ImageNetworks`.
      obs: grids (B, H, W, C) of cells in {0, 1}.

    Returns:
      (loss, {"bce_per_cell": loss / D}).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `obs` of another shape or dtype.
    """
    nwi._require(nets, ("sf2_ae",), "autoencoder_loss")
    b = nwi.check_obs(nets, "obs", obs)
    logits = nwi.decode_logits(nets, nwi.encode(nets, obs))
    bce = torch.logaddexp(torch.zeros_like(logits), logits) - logits * obs
    loss = torch.mean(bce.reshape(*b, -1).sum(-1))
    return loss, {"bce_per_cell": loss.detach() / nets.cfg.obs_size}


# ------------------------------------------------------------------------------------------------ returns
def _check_rollout(reward: torch.Tensor, **others: torch.Tensor) -> tuple[int, int]:
    shape = tuple(reward.shape)
    if len(shape) != 2:
        raise ShapeError(f"reward must have shape (T, N) (T steps of N environments), found {shape}")
    for name, x in others.items():
        if tuple(x.shape) != shape:
            raise ShapeError(f"{name} must have shape {shape} (T, N), that of reward, found {tuple(x.shape)}")
    return shape


def lambda_returns(reward: torch.Tensor, discount: torch.Tensor, truncation: torch.Tensor,
                   next_value: torch.Tensor, gamma, lam) -> torch.Tensor:
    """The expected-SARSA λ-return of a rollout, a reverse scan over its T steps.

    G_t = r_t + γ d_t [(1 − λ) V̄_{t+1} + λ G_{t+1}], d_t = `discount` = 1 − terminal_t; at the rollout's
    last step and at a truncated step the bracket is V̄_{t+1} (a bootstrap: G_{t+1} is another episode's
    or absent). V̄_{t+1} = `next_value`, the critic's value of s_{t+1} at rollout time (PPO-Q: V_Q(s_{t+1}) =
    Σ_a π(a|s_{t+1}) Q(s_{t+1}, a); at a truncated step s_{t+1} is the episode's last grid).

    Args:
      reward: r (T, N).
      discount: d = 1 − terminal (T, N).
      truncation: (T, N), 1 where the time limit cut the episode after that step.
      next_value: V̄(s_{t+1}) (T, N).
      gamma: γ in [0, 1].
      lam: λ in [0, 1].

    Returns:
      G (T, N), without gradient.

    Raises:
      ConfigError: γ or λ outside [0, 1].
      ShapeError: inputs not all of one (T, N) shape.
    """
    T, _ = _check_rollout(reward, discount=discount, truncation=truncation, next_value=next_value)
    _check_rate("gamma", gamma)
    _check_rate("lam", lam)
    with torch.no_grad():
        boot = truncation > 0
        boot[-1] = True
        g = torch.zeros_like(next_value[0])
        out = []
        for t in range(T - 1, -1, -1):
            v = next_value[t]
            g = reward[t] + gamma * discount[t] * torch.where(boot[t], v, (1 - lam) * v + lam * g)
            out.append(g)
        return torch.stack(out[::-1])


def gae(reward: torch.Tensor, discount: torch.Tensor, truncation: torch.Tensor, value: torch.Tensor,
        next_value: torch.Tensor, gamma, lam) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalized advantage estimation of a rollout (PureJaxRL's, with truncation as a bootstrap).

    δ_t = r_t + γ d_t V(s_{t+1}) − V(s_t); A_t = δ_t + γλ d_t (1 − truncation_t) A_{t+1}, A_T = 0; the targets
    A_t + V(s_t) are the λ-returns of V (A_t = `lambda_returns`(…, V(s_{t+1}), …) − V(s_t)).

    Args:
      reward: r (T, N).
      discount: d = 1 − terminal (T, N).
      truncation: (T, N), 1 where the time limit cut the episode after that step.
      value: V(s_t) (T, N).
      next_value: V(s_{t+1}) (T, N) (at a truncated step, of the episode's last grid).
      gamma: γ in [0, 1].
      lam: λ in [0, 1].

    Returns:
      (advantages (T, N), targets A + V (T, N)), without gradient.

    Raises:
      ConfigError: γ or λ outside [0, 1].
      ShapeError: inputs not all of one (T, N) shape.
    """
    T, _ = _check_rollout(reward, discount=discount, truncation=truncation, value=value,
                          next_value=next_value)
    _check_rate("gamma", gamma)
    _check_rate("lam", lam)
    with torch.no_grad():
        a = torch.zeros_like(value[0])
        out = []
        for t in range(T - 1, -1, -1):
            d = discount[t]
            delta = reward[t] + gamma * d * next_value[t] - value[t]
            a = delta + gamma * lam * d * (1 - truncation[t]) * a
            out.append(a)
        advantages = torch.stack(out[::-1])
        return advantages, advantages + value


# ------------------------------------------------------------------------------------------------ PPO
def ppo_policy_loss(nets: nwi.ImageNetworks, obs: torch.Tensor, action: torch.Tensor,
                    old_log_prob: torch.Tensor, advantage: torch.Tensor, clip_eps=0.2, entropy_coef=0.01
                    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """PPO's clipped policy loss with an entropy bonus (PureJaxRL's), trained on the actor only.

    Â = (A − mean_b A) / (std_b A + 1e-8) over the minibatch (std with divisor B), ρ = exp(log π(a|s) −
    log π_old(a|s)), loss = −mean_b min(ρÂ, clip(ρ, 1 − ε, 1 + ε)Â) − entropy_coef · mean_b H(π(·|s)).

    Args:
      nets: the `ImageNetworks`.
      obs: grids (B, H, W, C).
      action: the actions taken (B,).
      old_log_prob: log π_old(a|s) at rollout time (B,).
      advantage: A (B,), before normalization.
      clip_eps: ε in (0, 1].
      entropy_coef: the entropy bonus's weight, >= 0.

    Returns:
      (loss, {"policy_loss": the clipped term, "entropy": mean H, "approx_kl": mean((ρ − 1) − log ρ),
      "clip_fraction": the fraction with |ρ − 1| > ε}).

    Raises:
      ConfigError: ε outside (0, 1] or a negative entropy_coef.
      ShapeError: an input of another shape or dtype, or an action outside [0, A).
    """
    b = nwi.check_obs(nets, "obs", obs)
    nwi.check_actions(nets, "action", action, b)
    _check_per_sample("old_log_prob", old_log_prob, b)
    _check_per_sample("advantage", advantage, b)
    _check_rate("clip_eps", clip_eps, low_open=True)
    if isinstance(entropy_coef, numbers.Real) and not entropy_coef >= 0:
        raise ConfigError(f"entropy_coef={entropy_coef!r} is invalid: must satisfy entropy_coef >= 0")
    logits = nwi.policy_logits(nets, obs)
    log_ratio = nwi.categorical_log_prob(logits, action) - old_log_prob.detach()
    ratio = torch.exp(log_ratio)
    advantage = advantage.detach()
    adv = (advantage - advantage.mean()) / (advantage.std(correction=0) + ADVANTAGE_EPS)
    policy = -torch.mean(torch.minimum(ratio * adv, torch.clamp(ratio, 1 - clip_eps, 1 + clip_eps) * adv))
    entropy = torch.mean(nwi.categorical_entropy(logits))
    with torch.no_grad():
        aux = {"policy_loss": policy.detach(), "entropy": entropy.detach(),
               "approx_kl": torch.mean((ratio - 1) - log_ratio),
               "clip_fraction": torch.mean(((ratio - 1).abs() > clip_eps).to(ratio.dtype))}
    return policy - entropy_coef * entropy, aux


def q_critic_loss(nets: nwi.ImageNetworks, obs: torch.Tensor, action: torch.Tensor,
                  target_return: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The Q critic's TD(λ) loss ½ mean_b (Q(s, a) − sg(G))², trained on "ppo_q"'s critic, or on SF²'s ψ
    and Q head (Q(s, a) = Q_head(ψ(s, a))).

    Args:
      nets: "ppo_q", "sf2" or "sf2_ae" `ImageNetworks`.
      obs: grids (B, H, W, C).
      action: the actions taken (B,).
      target_return: G (B,), the λ-return (`lambda_returns`).

    Returns:
      (loss, {"q": mean Q(s, a)}).

    Raises:
      ConfigError: "ppo" networks.
      ShapeError: an input of another shape or dtype, or an action outside [0, A).
    """
    nwi._require(nets, ("ppo_q", "sf2", "sf2_ae"), "q_critic_loss")
    b = nwi.check_obs(nets, "obs", obs)
    nwi.check_actions(nets, "action", action, b)
    _check_per_sample("target_return", target_return, b)
    if nets.method == "ppo_q":
        q = nwi.action_values(nets, obs).gather(-1, action.long()[:, None])[:, 0]
    else:
        q = nwi.q_head(nets, nwi.psi(nets, obs, action))
    loss = 0.5 * torch.mean((q - target_return.detach()).square())
    return loss, {"q": q.mean().detach()}


def v_critic_loss(nets: nwi.ImageNetworks, obs: torch.Tensor, old_value: torch.Tensor,
                  target_return: torch.Tensor, clip_eps=0.2) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """PPO's clipped value loss (PureJaxRL's, as pgx's example runs it), trained on "ppo"'s critic.

    V_c = V_old + clip(V(s) − V_old, −ε, ε); loss = ½ mean_b max((V(s) − G)², (V_c − G)²).

    Args:
      nets: "ppo" `ImageNetworks`.
      obs: grids (B, H, W, C).
      old_value: V_old(s) at rollout time (B,).
      target_return: G (B,), GAE's targets (`gae`).
      clip_eps: ε in (0, 1].

    Returns:
      (loss, {"v": mean V(s)}).

    Raises:
      ConfigError: networks of another method, or ε outside (0, 1].
      ShapeError: an input of another shape or dtype.
    """
    nwi._require(nets, ("ppo",), "v_critic_loss")
    b = nwi.check_obs(nets, "obs", obs)
    _check_per_sample("old_value", old_value, b)
    _check_per_sample("target_return", target_return, b)
    _check_rate("clip_eps", clip_eps, low_open=True)
    v = nwi.state_value(nets, obs)
    target, old_value = target_return.detach(), old_value.detach()
    v_clipped = old_value + torch.clamp(v - old_value, -clip_eps, clip_eps)
    loss = 0.5 * torch.mean(torch.maximum((v - target).square(), (v_clipped - target).square()))
    return loss, {"v": v.mean().detach()}


# ------------------------------------------------------------------------------------------------ FPO
def _check_fpo_pairs(action: torch.Tensor, eps: torch.Tensor, flow_time: torch.Tensor
                     ) -> tuple[int, int, int]:
    shape = tuple(action.shape)
    if len(shape) != 2:
        raise ShapeError(f"action must have shape (B, A) (B samples of A action dimensions), found {shape}")
    b, a = shape
    if eps.dim() != 3 or tuple(eps.shape)[::2] != (b, a):
        raise ShapeError(f"eps must have shape (B, n, A) = ({b}, n, {a}) (n (ε, τ) pairs per action), found "
                         f"{tuple(eps.shape)}")
    n = eps.shape[1]
    if tuple(flow_time.shape) != (b, n):
        raise ShapeError(f"flow_time must have shape (B, n) = ({b}, {n}), one τ per ε, found "
                         f"{tuple(flow_time.shape)}")
    return b, n, a


def cfm_losses(velocity, action: torch.Tensor, eps: torch.Tensor, flow_time: torch.Tensor) -> torch.Tensor:
    """FPO's per-pair conditional flow-matching losses of a velocity-field policy at stored (ε, τ) pairs.

    The authors' convention (τ = 1 noise, τ = 0 the action) and output mode: x_τ = τ ε + (1 − τ) a,
    u = velocity(x_τ, τ), the predicted noise ε̂ = x_τ + (1 − τ) u, ℓ = mean_d (ε − ε̂)²_d
    = (1 − τ)² mean_d (ε − a − u)²_d.

    Args:
      velocity: u(x, τ) for x (B, n, A) and τ (B, n), returning (B, n, A); the policy at its observations.
      action: a (B, A), the actions taken (before any squashing).
      eps: ε (B, n, A) ~ N(0, I), drawn at rollout time.
      flow_time: τ (B, n) in [0, 1], drawn at rollout time.

    Returns:
      ℓ (B, n).

    Raises:
      ShapeError: inputs of mismatched shapes.
    """
    _check_fpo_pairs(action, eps, flow_time)
    tau = flow_time[..., None]
    x = tau * eps + (1.0 - tau) * action[:, None, :]
    eps_hat = x + (1.0 - tau) * velocity(x, flow_time)
    return torch.mean((eps - eps_hat) ** 2, dim=-1)


def fpo_ratio(old_losses: torch.Tensor, new_losses: torch.Tensor, log_ratio_clip=None) -> torch.Tensor:
    """FPO's likelihood-ratio surrogate ρ = exp(mean_n ℓ_old − mean_n ℓ_new), the losses averaged over the n
    pairs before the exponential (the authors' `average_losses_before_exp`); with `log_ratio_clip` = c the
    exponent is clipped to [−c, c] first (the bound the authors apply in their per-pair mode).

    Args:
      old_losses: ℓ_old (B, n), `cfm_losses` at rollout time.
      new_losses: ℓ (B, n), `cfm_losses` of the current policy at the same pairs.
      log_ratio_clip: c > 0, or None (no clip).

    Returns:
      ρ (B,).

    Raises:
      ShapeError: the two of different shapes, or not (B, n).
    """
    if new_losses.dim() != 2 or tuple(old_losses.shape) != tuple(new_losses.shape):
        raise ShapeError(f"old_losses and new_losses must have one shape (B, n), found "
                         f"{tuple(old_losses.shape)} and {tuple(new_losses.shape)}")
    log_ratio = old_losses.mean(dim=-1) - new_losses.mean(dim=-1)
    if log_ratio_clip is not None:
        log_ratio = torch.clamp(log_ratio, -log_ratio_clip, log_ratio_clip)
    return torch.exp(log_ratio)


def fpo_policy_loss(velocity, action: torch.Tensor, eps: torch.Tensor, flow_time: torch.Tensor,
                    old_losses: torch.Tensor, advantage: torch.Tensor, clip_eps=0.05, log_ratio_clip=None
                    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """FPO's clipped surrogate loss, trained on the policy's velocity field.

    Â = (A − mean_b A) / (std_b A + 1e-8) over the minibatch, ρ = `fpo_ratio`(ℓ_old, `cfm_losses`(…), c),
    loss = −mean_b min(ρÂ, clip(ρ, 1 − ε, 1 + ε)Â) (no entropy term).

    Args:
      velocity: u(x, τ) as in `cfm_losses`, through the trained parameters.
      action: a (B, A).
      eps: ε (B, n, A), stored at rollout time.
      flow_time: τ (B, n), stored at rollout time.
      old_losses: ℓ_old (B, n), stored at rollout time.
      advantage: A (B,), before normalization.
      clip_eps: ε in (0, 1].
      log_ratio_clip: `fpo_ratio`'s bound on the exponent, or None.

    Returns:
      (loss, {"policy_loss": loss, "ratio": mean ρ, "clip_fraction": the fraction with |ρ − 1| > ε,
      "cfm_loss": mean ℓ}).

    Raises:
      ConfigError: ε outside (0, 1].
      ShapeError: inputs of mismatched shapes.
    """
    b, n, _ = _check_fpo_pairs(action, eps, flow_time)
    _check_per_sample("advantage", advantage, (b,))
    if tuple(old_losses.shape) != (b, n):
        raise ShapeError(f"old_losses must have shape (B, n) = ({b}, {n}), found "
                         f"{tuple(old_losses.shape)}")
    _check_rate("clip_eps", clip_eps, low_open=True)
    losses = cfm_losses(velocity, action, eps, flow_time)
    ratio = fpo_ratio(old_losses.detach(), losses, log_ratio_clip)
    advantage = advantage.detach()
    adv = (advantage - advantage.mean()) / (advantage.std(correction=0) + ADVANTAGE_EPS)
    loss = -torch.mean(torch.minimum(ratio * adv, torch.clamp(ratio, 1 - clip_eps, 1 + clip_eps) * adv))
    with torch.no_grad():
        aux = {"policy_loss": loss.detach(), "ratio": ratio.mean(),
               "clip_fraction": torch.mean(((ratio - 1).abs() > clip_eps).to(ratio.dtype)),
               "cfm_loss": losses.mean()}
    return loss, aux


def flow_policy_sample(velocity, noise: torch.Tensor, steps: int = 10) -> torch.Tensor:
    """An action of a velocity-field policy: Euler integration from noise at τ = 1 to τ = 0.

    x_0 = noise; x_{k+1} = x_k − (1/K) u(x_k, τ_k), τ_k = 1 − k/K, k = 0..K−1; the action is x_K.

    Args:
      velocity: u(x, τ) for x (B, A) and τ (B,), returning (B, A); the policy at its observations.
      noise: x_0 (B, A) ~ N(0, I).
      steps: K >= 1.

    Returns:
      The action (B, A) (before any squashing).

    Raises:
      ConfigError: `steps` not an int >= 1.
      ShapeError: `noise` not (B, A).
    """
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ConfigError(f"steps={steps!r} is invalid: must be an int >= 1")
    if noise.dim() != 2:
        raise ShapeError(f"noise must have shape (B, A), found {tuple(noise.shape)}")
    ones = torch.ones(noise.shape[:1], dtype=noise.dtype, device=noise.device)
    x = noise
    for k in range(steps):
        x = x - velocity(x, (1.0 - k / steps) * ones) / steps
    return x
