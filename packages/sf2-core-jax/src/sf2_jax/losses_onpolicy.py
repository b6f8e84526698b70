"""Losses of the MinAtar system (docs/minatar.md): pure functions of parameters, data and explicit noise.

SF²'s flow loss over images (w/o AE) and over an autoencoder's latents (w AE), both `losses.
flow_field_loss` (the vector flow loss's code), the autoencoder's cross-entropy, the expected-SARSA
λ-return and GAE over a (T, N) rollout (reverse scans), and PPO's clipped policy loss, Q critic loss and
clipped V critic loss; FPO's flow-policy losses and Euler sampling (docs/fpo.md), over any velocity field
`velocity(x, τ)`; docs/core-contract.md "On-policy losses". Batches are `losses.Batch` with grids
(B, H, W, C) and integer actions (B,); means divide by B. Each loss returns `(loss, aux)`, `aux` a dict of
scalars, and stops the gradient of every group it does not train (the caller takes `jax.grad` with respect
to the trained groups). The torch core's `sf2_torch.losses_onpolicy` has the same functions and messages.
"""

from __future__ import annotations

import numbers

import jax
import jax.numpy as jnp
from sf2_common.errors import ConfigError, ShapeError

from sf2_jax import networks_image as nwi
from sf2_jax.losses import Batch, _trainable, check_noise, flow_field_loss, velocity_fields

__all__ = [
    "check_image_batch", "image_flow_loss", "latent_flow_loss", "autoencoder_loss", "lambda_returns", "gae",
    "ppo_policy_loss", "q_critic_loss", "v_critic_loss", "cfm_losses", "fpo_ratio", "fpo_policy_loss",
    "flow_policy_sample",
]

sg = jax.lax.stop_gradient
ADVANTAGE_EPS = 1e-8   # PureJaxRL's (A − mean) / (std + 1e-8)


# ------------------------------------------------------------------------------------------------ checks
def _check_per_sample(name: str, x, batch_shape: tuple) -> None:
    if tuple(jnp.shape(x)) != tuple(batch_shape):
        raise ShapeError(f"{name} must have shape {tuple(batch_shape)} (one value per sample), found "
                         f"{tuple(jnp.shape(x))}")


def _check_rate(name: str, value, low_open: bool = False) -> None:
    """A Python number in [0, 1] ((0, 1] with `low_open`); a traced value is not checked."""
    if isinstance(value, numbers.Real) and not ((0 < value if low_open else 0 <= value) and value <= 1):
        low = "0 <" if low_open else "0 <="
        raise ConfigError(f"{name}={value!r} is invalid: must satisfy {low} {name} <= 1")


def check_image_batch(nets: nwi.ImageNetworks, batch: Batch) -> tuple[int]:
    """Check a batch of image transitions, on static shapes and dtypes (values: `nwi.check_actions`).

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
def _image_fields(nets, p, features, next_features, flow_time):
    """The online and target fields of the image ζ (`losses.velocity_fields`' image counterpart): with
    `cfg.contract_zeta`, M = Wψ and M̄ = W̄ψ̄′ once and the online points as one batch; else the oracle."""
    cfg, k = nets.cfg, flow_time
    B = jnp.shape(features)[0]
    if cfg.contract_zeta:
        M, c = nwi.contract(nets, p, features)

        def online(*xs):
            h = nwi.zeta_hidden(nets, p, jnp.concatenate(xs), jnp.concatenate([k] * len(xs)))
            u = jnp.einsum("nbpqh,bhc->nbpqc", h.reshape(len(xs), B, *h.shape[1:]), M) + c[:, None, None, :]
            return u.reshape(len(xs), B, cfg.obs_size)
    else:
        def online(*xs):
            return [nwi.velocity(nets, p, x, k, features) for x in xs]

    if next_features is None:
        return online, None
    if cfg.contract_zeta:
        M_bar, c_bar = nwi.contract(nets, p, next_features, target=True)

        def target(x, kk):
            return nwi.velocity_contracted(nets, p, x, kk, M_bar, c_bar, target=True)
    else:
        def target(x, kk):
            return nwi.velocity(nets, p, x, kk, next_features, target=True)
    return online, target


def _next_features(nets, p, batch, next_action):
    if nets.cfg.gamma_su == 0:
        return None
    return sg(nwi.psi(nets, p, batch.next_obs, next_action, target=True))


def image_flow_loss(nets: nwi.ImageNetworks, params: nwi.Params, batch: Batch, next_action, eps, flow_time):
    """SF²'s flow loss w/o AE: the flow in image space, trained on ψ and ζ.

    `losses.flow_field_loss` with x1 = s′ flattened (B, D), D = H·W·C in NHWC order, not normalized;
    u(x, k) = ζ(x, k)ψ(s, a) with the image ζ, u_{p,c} = Σ_h h_{p,h}(x, k) (Wψ)_{h,c} + (bψ)_c (through
    M = Wψ on the fast path, `cfg.contract_zeta`; the materialized ζ otherwise); the bootstrap ODE under
    ū = ζ̄(x, k)ψ̄(s′, a′). L_flow = mean_b m_b[(1 − γ_su) ℓ_P + γ_su ℓ_B], m_b = 1 − truncation_b.

    Args:
      nets: "sf2" `ImageNetworks`.
      params: the parameters of every group (`networks_image.init_image_params`).
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
    p = _trainable(params, ("psi", "zeta"))
    x1 = jnp.reshape(batch.next_obs, (*b, cfg.obs_size))
    features = nwi.psi(nets, p, batch.obs, batch.action)
    online, target = _image_fields(nets, p, features, _next_features(nets, p, batch, next_action), flow_time)
    return flow_field_loss(cfg, online, target, x1, eps, flow_time, batch.truncation)


def latent_flow_loss(nets: nwi.ImageNetworks, params: nwi.Params, batch: Batch, next_action, eps, flow_time):
    """SF²'s flow loss w AE: the vector flow loss over latents, trained on ψ and ζ (not the encoder).

    `losses.flow_field_loss` with x1 = z′ = sg(E(s′)) ∈ [−1, 1]^64 (no normalization) and the vector ζ's
    fields (`losses.velocity_fields` of `networks_image.latent_networks(nets)`) for ψ(s, a) and ψ̄(s′, a′)
    of the image ψ: the vector `losses.flow_loss`'s computation with these ψ and s̄′ = z′.

    Args:
      nets: "sf2_ae" `ImageNetworks`.
      params: the parameters of every group (`networks_image.init_image_params`).
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
    p = _trainable(params, ("psi", "zeta"))
    latent = nwi.latent_networks(nets)
    x1 = sg(nwi.encode(nets, p, batch.next_obs))
    features = nwi.psi(nets, p, batch.obs, batch.action)
    next_features = _next_features(nets, p, batch, next_action)
    online, target = velocity_fields(latent, p, features, next_features, flow_time)
    return flow_field_loss(latent.cfg, online, target, x1, eps, flow_time, batch.truncation)


def autoencoder_loss(nets: nwi.ImageNetworks, params: nwi.Params, obs):
    """The autoencoder's loss, trained on the encoder and the decoder: binary cross-entropy of the grid's
    cells under the decoder's Bernoulli logits ℓ = D(E(s)), summed over the cells, averaged over the batch.

    loss = mean_b Σ_d [log(1 + e^{ℓ_d}) − ℓ_d s_d] (−log σ(ℓ) for s = 1, −log σ(−ℓ) for s = 0), the softplus
    as logaddexp(0, ℓ): stable, and smooth at ℓ = 0 (its gradient is σ(ℓ) − s everywhere).

    Args:
      nets: "sf2_ae" `ImageNetworks`.
      params: the parameters of every group (`networks_image.init_image_params`).
      obs: grids (B, H, W, C) of cells in {0, 1}.

    Returns:
      (loss, {"bce_per_cell": loss / D}).

    Raises:
      ConfigError: networks of another method.
      ShapeError: `obs` of another shape or dtype.
    """
    nwi._require(nets, ("sf2_ae",), "autoencoder_loss")
    b = nwi.check_obs(nets, "obs", obs)
    p = _trainable(params, ("encoder", "decoder"))
    logits = nwi.decode_logits(nets, p, nwi.encode(nets, p, obs))
    bce = jnp.logaddexp(0.0, logits) - logits * obs
    loss = jnp.mean(jnp.sum(bce.reshape(*b, -1), axis=-1))
    return loss, {"bce_per_cell": loss / nets.cfg.obs_size}


# ------------------------------------------------------------------------------------------------ returns
def _check_rollout(reward, **others) -> tuple[int, int]:
    shape = tuple(jnp.shape(reward))
    if len(shape) != 2:
        raise ShapeError(f"reward must have shape (T, N) (T steps of N environments), found {shape}")
    for name, x in others.items():
        if tuple(jnp.shape(x)) != shape:
            raise ShapeError(f"{name} must have shape {shape} (T, N), that of reward, found "
                             f"{tuple(jnp.shape(x))}")
    return shape


def lambda_returns(reward, discount, truncation, next_value, gamma, lam):
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
    _check_rollout(reward, discount=discount, truncation=truncation, next_value=next_value)
    _check_rate("gamma", gamma)
    _check_rate("lam", lam)
    boot = (jnp.asarray(truncation) > 0).at[-1].set(True)

    def step(g_next, xs):
        r, d, b, v = xs
        g = r + gamma * d * jnp.where(b, v, (1 - lam) * v + lam * g_next)
        return g, g

    _, returns = jax.lax.scan(step, jnp.zeros_like(next_value[0]), (reward, discount, boot, next_value),
                              reverse=True)
    return sg(returns)


def gae(reward, discount, truncation, value, next_value, gamma, lam):
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
    _check_rollout(reward, discount=discount, truncation=truncation, value=value, next_value=next_value)
    _check_rate("gamma", gamma)
    _check_rate("lam", lam)

    def step(a_next, xs):
        r, d, tr, v, v_next = xs
        delta = r + gamma * d * v_next - v
        a = delta + gamma * lam * d * (1 - tr) * a_next
        return a, a

    _, advantages = jax.lax.scan(step, jnp.zeros_like(value[0]),
                                 (reward, discount, truncation, value, next_value), reverse=True)
    return sg(advantages), sg(advantages + value)


# ------------------------------------------------------------------------------------------------ PPO
def ppo_policy_loss(nets: nwi.ImageNetworks, params: nwi.Params, obs, action, old_log_prob, advantage,
                    clip_eps=0.2, entropy_coef=0.01):
    """PPO's clipped policy loss with an entropy bonus (PureJaxRL's), trained on the actor only.

    Â = (A − mean_b A) / (std_b A + 1e-8) over the minibatch (std with divisor B), ρ = exp(log π(a|s) −
    log π_old(a|s)), loss = −mean_b min(ρÂ, clip(ρ, 1 − ε, 1 + ε)Â) − entropy_coef · mean_b H(π(·|s)).

    Args:
      nets: the `ImageNetworks`.
      params: the parameters of every group (`networks_image.init_image_params`).
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
    p = _trainable(params, ("actor",))
    logits = nwi.policy_logits(nets, p, obs)
    log_ratio = nwi.categorical_log_prob(logits, action) - old_log_prob
    ratio = jnp.exp(log_ratio)
    adv = (advantage - jnp.mean(advantage)) / (jnp.std(advantage) + ADVANTAGE_EPS)
    policy = -jnp.mean(jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - clip_eps, 1 + clip_eps) * adv))
    entropy = jnp.mean(nwi.categorical_entropy(logits))
    aux = {"policy_loss": policy, "entropy": entropy, "approx_kl": jnp.mean((ratio - 1) - log_ratio),
           "clip_fraction": jnp.mean((jnp.abs(ratio - 1) > clip_eps).astype(ratio.dtype))}
    return policy - entropy_coef * entropy, jax.tree_util.tree_map(sg, aux)


def q_critic_loss(nets: nwi.ImageNetworks, params: nwi.Params, obs, action, target_return):
    """The Q critic's TD(λ) loss ½ mean_b (Q(s, a) − sg(G))², trained on "ppo_q"'s critic, or on SF²'s ψ
    and Q head (Q(s, a) = Q_head(ψ(s, a))).

    Args:
      nets: "ppo_q", "sf2" or "sf2_ae" `ImageNetworks`.
      params: the parameters of every group (`networks_image.init_image_params`).
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
        p = _trainable(params, ("critic",))
        q = jnp.take_along_axis(nwi.action_values(nets, p, obs), jnp.asarray(action)[:, None], axis=-1)[:, 0]
    else:
        p = _trainable(params, ("psi", "q"))
        q = nwi.q_head(nets, p, nwi.psi(nets, p, obs, action))
    loss = 0.5 * jnp.mean((q - sg(target_return)) ** 2)
    return loss, {"q": sg(jnp.mean(q))}


def v_critic_loss(nets: nwi.ImageNetworks, params: nwi.Params, obs, old_value, target_return, clip_eps=0.2):
    """PPO's clipped value loss (PureJaxRL's, as pgx's example runs it), trained on "ppo"'s critic.

    V_c = V_old + clip(V(s) − V_old, −ε, ε); loss = ½ mean_b max((V(s) − G)², (V_c − G)²).

    Args:
      nets: "ppo" `ImageNetworks`.
      params: the parameters of every group (`networks_image.init_image_params`).
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
    p = _trainable(params, ("critic",))
    v = nwi.state_value(nets, p, obs)
    target = sg(target_return)
    v_clipped = old_value + jnp.clip(v - old_value, -clip_eps, clip_eps)
    loss = 0.5 * jnp.mean(jnp.maximum((v - target) ** 2, (v_clipped - target) ** 2))
    return loss, {"v": sg(jnp.mean(v))}


# ------------------------------------------------------------------------------------------------ FPO
def _check_fpo_pairs(action, eps, flow_time) -> tuple[int, int, int]:
    shape = tuple(jnp.shape(action))
    if len(shape) != 2:
        raise ShapeError(f"action must have shape (B, A) (B samples of A action dimensions), found {shape}")
    b, a = shape
    if len(jnp.shape(eps)) != 3 or tuple(jnp.shape(eps))[::2] != (b, a):
        raise ShapeError(f"eps must have shape (B, n, A) = ({b}, n, {a}) (n (ε, τ) pairs per action), found "
                         f"{tuple(jnp.shape(eps))}")
    n = jnp.shape(eps)[1]
    if tuple(jnp.shape(flow_time)) != (b, n):
        raise ShapeError(f"flow_time must have shape (B, n) = ({b}, {n}), one τ per ε, found "
                         f"{tuple(jnp.shape(flow_time))}")
    return b, n, a


def cfm_losses(velocity, action, eps, flow_time):
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
    return jnp.mean((eps - eps_hat) ** 2, axis=-1)


def fpo_ratio(old_losses, new_losses, log_ratio_clip=None):
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
    if len(jnp.shape(new_losses)) != 2 or tuple(jnp.shape(old_losses)) != tuple(jnp.shape(new_losses)):
        raise ShapeError(f"old_losses and new_losses must have one shape (B, n), found "
                         f"{tuple(jnp.shape(old_losses))} and {tuple(jnp.shape(new_losses))}")
    log_ratio = jnp.mean(old_losses, axis=-1) - jnp.mean(new_losses, axis=-1)
    if log_ratio_clip is not None:
        log_ratio = jnp.clip(log_ratio, -log_ratio_clip, log_ratio_clip)
    return jnp.exp(log_ratio)


def fpo_policy_loss(velocity, action, eps, flow_time, old_losses, advantage, clip_eps=0.05,
                    log_ratio_clip=None):
    """FPO's clipped surrogate loss, trained on the policy's velocity field.

    Â = (A − mean_b A) / (std_b A + 1e-8) over the minibatch, ρ = `fpo_ratio`(ℓ_old, `cfm_losses`(…), c),
    loss = −mean_b min(ρÂ, clip(ρ, 1 − ε, 1 + ε)Â) (no entropy term).

    Args:
      velocity: u(x, τ) as in `cfm_losses`, closing over the trained parameters.
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
    if tuple(jnp.shape(old_losses)) != (b, n):
        raise ShapeError(f"old_losses must have shape (B, n) = ({b}, {n}), found "
                         f"{tuple(jnp.shape(old_losses))}")
    _check_rate("clip_eps", clip_eps, low_open=True)
    losses = cfm_losses(velocity, action, eps, flow_time)
    ratio = fpo_ratio(sg(old_losses), losses, log_ratio_clip)
    adv = sg((advantage - jnp.mean(advantage)) / (jnp.std(advantage) + ADVANTAGE_EPS))
    loss = -jnp.mean(jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - clip_eps, 1 + clip_eps) * adv))
    aux = {"policy_loss": loss, "ratio": jnp.mean(ratio),
           "clip_fraction": jnp.mean((jnp.abs(ratio - 1) > clip_eps).astype(ratio.dtype)),
           "cfm_loss": jnp.mean(losses)}
    return loss, jax.tree_util.tree_map(sg, aux)


def flow_policy_sample(velocity, noise, steps: int = 10):
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
    if len(jnp.shape(noise)) != 2:
        raise ShapeError(f"noise must have shape (B, A), found {tuple(jnp.shape(noise))}")
    ones = jnp.ones(jnp.shape(noise)[:1], noise.dtype)

    def step(x, k):
        tau = 1.0 - k / steps
        return x - velocity(x, tau * ones) / steps, None

    return jax.lax.scan(step, noise, jnp.arange(steps, dtype=noise.dtype))[0]
