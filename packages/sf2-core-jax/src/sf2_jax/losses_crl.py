"""Losses of contrastive RL (CRL, Eysenbach et al., 2022) as JaxGCRL trains it: pure functions of arrays.

The critic is the energy f(s, a, g) = −‖φ(s, a) − ψ(g)‖ of a state-action encoder φ and a goal encoder ψ,
trained by InfoNCE over a batch (forward: row i's own goal against the other rows' goals; backward: goal j's
own state-action against the other rows'; symmetric: both) with a penalty on the log-sum-exp; the actor is
goal-conditioned SAC on that energy with a learned temperature; goals are future states of the same
trajectory, k steps ahead with P(k) ∝ γ^k. Every random draw is an argument, and the functions take the
encoders' and the actor's outputs, not networks, so the same inputs give the same numbers in JAX and torch
(`sf2_torch.losses_crl`). Losses return `(loss, aux)`. Gradient contract: the temperature is a constant in
the actor loss, the log-probability in the temperature loss; everything else carries its gradient to
whatever produced it. docs/crl.md.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from sf2_common.errors import ConfigError, ShapeError

__all__ = ["ENERGY_EPS", "LOG_STD_MIN", "LOG_STD_MAX", "CONTRASTIVE_LOSSES", "energy", "crl_critic_loss",
           "actor_log_std", "squashed_gaussian_sample", "crl_actor_loss", "crl_alpha_loss", "future_offset"]

sg = jax.lax.stop_gradient
ENERGY_EPS = 1e-6              # inside the square root of the energy (JaxGCRL's "norm")
LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0   # the actor's log σ range
CONTRASTIVE_LOSSES = ("fwd", "bwd", "sym")   # InfoNCE over a row's goals, a column's state-actions, or both


def _check_pair(a_name: str, a, b_name: str, b) -> None:
    if jnp.ndim(a) != 2 or jnp.shape(a) != jnp.shape(b):
        raise ShapeError(f"{a_name} and {b_name} must both have shape (B, F), found {tuple(jnp.shape(a))} "
                         f"and {tuple(jnp.shape(b))}")


def energy(x, y):
    """The CRL energy −sqrt(Σ_f (x − y)²_f + ENERGY_EPS) over the last axis (JaxGCRL's "norm").

    Args:
      x: representations (..., F), e.g. φ(s, a).
      y: representations broadcastable against `x`, e.g. ψ(g).

    Returns:
      The energies, the broadcast shape without the last axis.
    """
    return -jnp.sqrt(jnp.sum((x - y) ** 2, axis=-1) + ENERGY_EPS)


def crl_critic_loss(phi, psi, logsumexp_penalty, direction="fwd"):
    """CRL's critic loss: forward, backward or symmetric InfoNCE over the batch's energies, with a penalty.

    L_ij = energy(φ_i, ψ_j), ℓ_i = log Σ_j exp L_ij (a row: a state-action against the batch's goals),
    m_j = log Σ_i exp L_ij (a column: a goal against the batch's state-actions); P = c · mean_i (ℓ_i + ε)²;
    fwd: loss = −mean_i (L_ii − ℓ_i) + P; bwd: loss = −mean_j (L_jj − m_j) + P; sym, their sum: loss =
    −mean_i (2 L_ii − ℓ_i − m_i) + P. The penalty stays on the rows in all three (JaxGCRL's `fwd_infonce`,
    `bwd_infonce`, `sym_infonce`, its log-sum-exp of L + ε), ε = 1e-6, c = `logsumexp_penalty`.

    Args:
      phi: φ(s_i, a_i) (B, F).
      psi: ψ(g_i) (B, F), g_i the goal sampled for row i.
      logsumexp_penalty: c ≥ 0.
      direction: "fwd", "bwd" or "sym" (`CONTRASTIVE_LOSSES`).

    Returns:
      (loss, {"accuracy": mean_i [argmax_j L_ij = i], "logits_pos": mean_i L_ii, "logits_neg": the mean of
      L_ij over i ≠ j, "logsumexp": mean_i (ℓ_i + ε)}): the rows' metrics in every direction, as JaxGCRL
      logs them.

    Raises:
      ShapeError: φ and ψ not both (B, F).
      ConfigError: `direction` not one of `CONTRASTIVE_LOSSES`.
    """
    _check_pair("phi", phi, "psi", psi)
    if direction not in CONTRASTIVE_LOSSES:
        raise ConfigError(f"direction={direction!r} is invalid: must be one of {CONTRASTIVE_LOSSES}")
    logits = energy(phi[:, None, :], psi[None, :, :])
    diag = jnp.diagonal(logits)
    softmax_axes = {"fwd": (1,), "bwd": (0,), "sym": (1, 0)}[direction]
    contrast = sum(diag - jax.nn.logsumexp(logits, axis=axis) for axis in softmax_axes)
    penalty_lse = jax.nn.logsumexp(logits + ENERGY_EPS, axis=1)
    loss = -jnp.mean(contrast) + logsumexp_penalty * jnp.mean(penalty_lse ** 2)
    b = logits.shape[0]
    eye = jnp.eye(b, dtype=logits.dtype)
    aux = {"accuracy": jnp.mean((jnp.argmax(logits, axis=1) == jnp.arange(b)).astype(logits.dtype)),
           "logits_pos": jnp.mean(diag),
           "logits_neg": jnp.sum(logits * (1 - eye)) / jnp.maximum(b * (b - 1), 1),
           "logsumexp": jnp.mean(penalty_lse)}
    return loss, aux


def actor_log_std(raw):
    """The actor's log σ from its raw head: LOG_STD_MIN + (LOG_STD_MAX − LOG_STD_MIN)(tanh(raw) + 1) / 2.

    Args:
      raw: the head's output (..., A).

    Returns:
      log σ in (LOG_STD_MIN, LOG_STD_MAX), the shape of `raw`.
    """
    return LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (jnp.tanh(raw) + 1.0)


def squashed_gaussian_sample(mean, log_std, noise):
    """A tanh-squashed Gaussian action and its log-probability, as JaxGCRL's CRL computes them.

    x = μ + σξ, a = tanh x; log π(a) = Σ_d [log N(x_d; μ_d, σ_d) − log(1 − a_d² + 1e-6)].

    Args:
      mean: μ (B, A).
      log_std: log σ (B, A).
      noise: ξ (B, A) ~ N(0, I).

    Returns:
      (a (B, A), log π(a) (B,)).

    Raises:
      ShapeError: the three of different shapes.
    """
    if not (jnp.shape(mean) == jnp.shape(log_std) == jnp.shape(noise)):
        shapes = [tuple(jnp.shape(x)) for x in (mean, log_std, noise)]
        raise ShapeError(f"mean, log_std and noise must have one shape (B, A), found {shapes[0]}, "
                         f"{shapes[1]} "
                         f"and {shapes[2]}")
    std = jnp.exp(log_std)
    x = mean + std * noise
    action = jnp.tanh(x)
    log_normal = -0.5 * noise ** 2 - log_std - 0.5 * jnp.log(2.0 * jnp.pi)
    log_prob = jnp.sum(log_normal - jnp.log(1.0 - action ** 2 + 1e-6), axis=-1)
    return action, log_prob


def crl_actor_loss(log_prob, q, log_alpha):
    """The goal-conditioned SAC actor loss on the CRL energy: mean_b (α log π(a_b) − f(s_b, a_b, g_b)).

    Args:
      log_prob: log π(a_b | s_b, g_b) (B,) of actions a_b ~ π (`squashed_gaussian_sample`).
      q: f(s_b, a_b, g_b) = energy(φ(s_b, a_b), ψ(g_b)) (B,).
      log_alpha: log α, a scalar; a constant here.

    Returns:
      (loss, {"entropy": −mean_b log π(a_b)}).

    Raises:
      ShapeError: log_prob and q of different shapes.
    """
    if jnp.shape(log_prob) != jnp.shape(q) or jnp.ndim(q) != 1:
        raise ShapeError(f"log_prob and q must both have shape (B,), found {tuple(jnp.shape(log_prob))} and "
                         f"{tuple(jnp.shape(q))}")
    loss = jnp.mean(jnp.exp(sg(log_alpha)) * log_prob - q)
    return loss, {"entropy": -jnp.mean(sg(log_prob))}


def crl_alpha_loss(log_alpha, log_prob, target_entropy):
    """The temperature loss: α · mean_b sg(−log π(a_b) − H̄), α = exp(log α) (JaxGCRL's form).

    Args:
      log_alpha: log α, a scalar (the trained parameter).
      log_prob: log π(a_b) (B,); a constant here.
      target_entropy: H̄ (JaxGCRL: −A/2).

    Returns:
      (loss, {"alpha": α}).
    """
    alpha = jnp.exp(log_alpha)
    loss = alpha * jnp.mean(sg(-log_prob - target_entropy))
    return loss, {"alpha": sg(alpha)}


def future_offset(u, steps_left, gamma):
    """How far ahead a goal is: k ∈ {1, …, n} with P(k) ∝ γ^k (a geometric law truncated at the trajectory's
    last stored step n = `steps_left`), by inverting its CDF (1 − γ^k) / (1 − γ^n) at u; 0 where n = 0.

    k = clip(⌈log(1 − u(1 − γ^n)) / log γ⌉, 1, n).

    Args:
      u: uniform draws in [0, 1), any shape.
      steps_left: n ≥ 0, integers, the shape of `u`: the trajectory's steps stored after the current one.
      gamma: γ in (0, 1).

    Returns:
      k, int32, the shape of `u`.
    """
    n = jnp.asarray(steps_left)
    u = jnp.asarray(u)
    mass = -jnp.expm1(n.astype(u.dtype) * jnp.log(jnp.asarray(gamma, u.dtype)))    # 1 − γ^n
    k = jnp.ceil(jnp.log1p(-u * mass) / jnp.log(jnp.asarray(gamma, u.dtype)))
    return jnp.clip(k, jnp.minimum(n, 1), n).astype(jnp.int32)
