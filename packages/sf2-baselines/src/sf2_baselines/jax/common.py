"""Pieces every baseline shares (JAX): shape checks, L2 normalization, TD3/SAC losses on any critic.

The TD3 and SAC losses below are the core's (docs/core-contract.md "TD3 on features", "SAC on
features"; paper Appendix D, Algorithms 2–3) written against a `critic(params, obs, action, target)`
function instead of ψ and the core's Q heads, so each baseline gets the same critic and actor losses
that `sf2_jax.agents.algorithms` computes with its representation. They are pure: the TD3 smoothing
noise ξ and the SAC action noise ξ are arguments. Batch means divide by B; samples with
truncation_b = 1 count as zeros (m_b = 1 − truncation_b).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from sf2_jax import networks as core_nw
from sf2_jax.errors import ShapeError
from sf2_jax.losses import Batch

__all__ = [
    "NORM_EPS",
    "l2_normalize",
    "trainable",
    "check_last",
    "check_batch",
    "check_noise",
    "td_loss",
    "td3_critic_loss",
    "td3_actor_loss",
    "sac_critic_loss",
    "sac_actor_loss",
    "cast_tree",
    "copy_tree",
]

sg = jax.lax.stop_gradient
Params = dict[str, Any]
Critic = Callable[..., Any]  # critic(params, obs, action, target=False) -> (B, 2)

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


# ------------------------------------------------------------------------------------------ checks
def check_last(name: str, x, expected: int, what: str) -> None:
    shape = tuple(jnp.shape(x))
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
    b = tuple(jnp.shape(batch.obs)[:-1])
    for name in ("next_obs", "action"):
        found = tuple(jnp.shape(getattr(batch, name))[:-1])
        if found != b:
            raise ShapeError(f"batch.{name}: expected batch shape {b} (that of batch.obs), found {found}")
    for name in ("reward", "discount", "truncation"):
        found = tuple(jnp.shape(getattr(batch, name)))
        if found != b:
            raise ShapeError(
                f"batch.{name}: expected shape {b} (the batch shape of batch.obs), found {found}"
            )
    return b


def check_noise(name: str, x, batch_shape, size: int, what: str) -> None:
    check_last(name, x, size, what)
    found = tuple(jnp.shape(x)[:-1])
    if found != tuple(batch_shape):
        raise ShapeError(
            f"{name}: expected batch shape {tuple(batch_shape)} (that of batch.obs), found {found}"
        )


# ------------------------------------------------------------------------------------------ TD3 / SAC
def td_loss(q, y, truncation):
    """½ mean_{b,j}(m_b(Q_j − sg(y)))², m_b = 1 − truncation_b."""
    err = (1 - truncation)[..., None] * (q - sg(y)[..., None])
    return 0.5 * jnp.mean(err**2)


def td3_critic_loss(
    critic: Critic, core: core_nw.Networks, params: Params, batch: Batch, smoothing, trained: tuple[str, ...]
):
    """TD3 critic (Algorithm 2) on `critic`: ã′ = clip(π̄(s′) + clip(σ_s ξ, −c, c), −1, 1),
    y = rs·r + discount·γ·min_j Q̄_j(s′, ã′), loss = ½ mean_{b,j}(m_b(Q_j(s, a) − sg(y)))².
    Trains the groups `trained`. aux: q (mean Q), target_q (mean y)."""
    cfg = core.cfg
    b = check_batch(cfg, batch)
    check_noise("smoothing", smoothing, b, cfg.action_size, "action_size")
    p = trainable(params, trained)
    noise = jnp.clip(cfg.smoothing_noise * smoothing, -cfg.noise_clip, cfg.noise_clip)
    next_action = jnp.clip(core_nw.td3_action(core, p, batch.next_obs, target=True) + noise, -1, 1)
    next_q = critic(p, batch.next_obs, next_action, target=True)
    y = cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * jnp.min(next_q, axis=-1)
    q = critic(p, batch.obs, batch.action)
    return td_loss(q, y, batch.truncation), {"q": jnp.mean(q), "target_q": jnp.mean(sg(y))}


def td3_actor_loss(critic: Critic, core: core_nw.Networks, params: Params, batch: Batch):
    """TD3 actor: −mean_b Q_0(s, π(s)). Trains the policy only. aux: q (mean Q_0)."""
    check_batch(core.cfg, batch)
    p = trainable(params, ("policy",))
    action = core_nw.td3_action(core, p, batch.obs)
    loss = -jnp.mean(critic(p, batch.obs, action)[..., 0])
    return loss, {"q": -loss}


def sac_critic_loss(
    critic: Critic, core: core_nw.Networks, params: Params, batch: Batch, noise, trained: tuple[str, ...]
):
    """SAC critic (Algorithm 3) on `critic`: a′, log π(a′|s′) from the online policy with ξ′ = `noise`;
    y = rs·r + discount·γ·(min_j Q̄_j(s′, a′) − α log π(a′|s′)), α = exp(log_alpha) constant;
    loss = ½ mean_{b,j}(m_b(Q_j(s, a) − sg(y)))². Trains `trained`. aux: q, target_q."""
    cfg = core.cfg
    b = check_batch(cfg, batch)
    check_noise("noise", noise, b, cfg.action_size, "action_size")
    p = trainable(params, trained)
    alpha = jnp.exp(p["log_alpha"])
    next_action, next_log_prob = core_nw.sac_sample(core, p, batch.next_obs, noise)
    next_q = critic(p, batch.next_obs, next_action, target=True)
    y = cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * (
        jnp.min(next_q, axis=-1) - alpha * next_log_prob
    )
    q = critic(p, batch.obs, batch.action)
    return td_loss(q, y, batch.truncation), {"q": jnp.mean(q), "target_q": jnp.mean(sg(y))}


def sac_actor_loss(critic: Critic, core: core_nw.Networks, params: Params, batch: Batch, noise):
    """SAC actor: a ~ π(s) with ξ = `noise`; loss = mean_b(α log π(a|s) − min_j Q_j(s, a)), α constant.
    Trains the policy only. aux: entropy (−mean log π)."""
    cfg = core.cfg
    b = check_batch(cfg, batch)
    check_noise("noise", noise, b, cfg.action_size, "action_size")
    p = trainable(params, ("policy",))
    alpha = jnp.exp(p["log_alpha"])
    action, log_prob = core_nw.sac_sample(core, p, batch.obs, noise)
    q = critic(p, batch.obs, action)
    return jnp.mean(alpha * log_prob - jnp.min(q, axis=-1)), {"entropy": -jnp.mean(log_prob)}
