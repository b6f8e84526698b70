"""FPO's losses and the Q(λ) return (sf2_jax.losses_onpolicy; docs/fpo.md), float64, derived by hand.

The tiny policy is one-dimensional and linear, u_θ(x, τ) = θx, so every conditional flow-matching loss,
the ratio, the clipped objective and its gradient in θ follow from a few products (each test's docstring).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sf2_common.errors import ConfigError, ShapeError
from sf2_jax import losses_onpolicy as lo

# two samples (B = 2), one action dimension (A = 1), two (ε, τ) pairs each (n = 2)
ACTION = jnp.array([[1.0], [-1.0]])
EPS = jnp.array([[[1.0], [-1.0]], [[1.0], [0.0]]])
TAU = jnp.array([[0.5, 0.0], [0.0, 0.5]])
OLD = jnp.array([[0.0, 4.0], [4.0, 0.25]])          # ℓ at θ = 0 (below)
NEW = jnp.array([[0.0625, 6.25], [6.25, 0.390625]])  # ℓ at θ = ½


def linear(theta):
    return lambda x, tau: theta * x


def test_cfm_losses_by_hand():
    """ℓ = mean_d (ε − x_τ − (1 − τ)u)², x_τ = τε + (1 − τ)a. At θ = 0 (u = 0): ℓ = (1 − τ)²(ε − a)²:
    sample 0 (a = 1): (ε, τ) = (1, ½) → ¼·0 = 0; (−1, 0) → (−2)² = 4. Sample 1 (a = −1): (1, 0) → 2² = 4;
    (0, ½) → ¼·1² = ¼. At θ = ½ (u = x_τ/2, ε̂ = x_τ(1 + (1 − τ)/2)): sample 0: x = 1, ε̂ = 1.25, ℓ = 0.0625;
    x = 1, ε̂ = 1.5, ℓ = 6.25. Sample 1: x = −1, ε̂ = −1.5, ℓ = 2.5² = 6.25; x = −½, ε̂ = −0.625,
    ℓ = 0.390625."""
    assert np.array_equal(lo.cfm_losses(linear(0.0), ACTION, EPS, TAU), OLD)
    assert np.array_equal(lo.cfm_losses(linear(0.5), ACTION, EPS, TAU), NEW)


def test_fpo_ratio_averages_the_losses_before_the_exponential():
    """ρ_b = exp(mean_n ℓ_old − mean_n ℓ_new): exp(2 − 3.15625) = exp(−1.15625) and exp(2.125 − 3.3203125)
    = exp(−1.1953125); not the mean of the per-pair ratios."""
    rho = lo.fpo_ratio(OLD, NEW)
    np.testing.assert_allclose(rho, [math.exp(-1.15625), math.exp(-1.1953125)], rtol=1e-15)
    per_pair = jnp.mean(jnp.exp(OLD - NEW), axis=-1)
    assert not np.allclose(rho, per_pair)


def test_fpo_policy_loss_and_its_gradient_by_hand():
    """A = (1, −1) normalizes to Â = ±1/(1 + 1e-8). ρ = (e^−1.15625, e^−1.1953125) ≈ (0.315, 0.303), both
    below 1 − 0.05. Sample 0 (Â > 0): min(ρÂ, 0.95Â) = ρ_0Â; sample 1 (Â < 0): min(−ρ_1, −0.95)/(1 + 1e-8)
    = −0.95/(1 + 1e-8), the clipped term. loss = −½(ρ_0 − 0.95)/(1 + 1e-8); clip fraction 1.
    Gradient: only ρ_0 depends on θ; dℓ/dθ = −2(ε − ε̂)(1 − τ)x_τ per pair: −2(−0.25)(½)(1) = 0.25 and
    −2(−2.5)(1)(1) = 5, mean 2.625; dρ_0/dθ = −2.625ρ_0, so dloss/dθ = 1.3125ρ_0/(1 + 1e-8)."""
    adv = jnp.array([1.0, -1.0])
    scale = 1.0 / (1.0 + 1e-8)
    rho0 = math.exp(-1.15625)

    def loss_of(theta):
        return lo.fpo_policy_loss(linear(theta), ACTION, EPS, TAU, OLD, adv, 0.05)

    (loss, aux), grad = jax.value_and_grad(loss_of, has_aux=True)(0.5)
    np.testing.assert_allclose(loss, -0.5 * (rho0 - 0.95) * scale, rtol=1e-14)
    np.testing.assert_allclose(grad, 1.3125 * rho0 * scale, rtol=1e-14)
    assert aux["clip_fraction"] == 1.0
    np.testing.assert_allclose(aux["ratio"], (rho0 + math.exp(-1.1953125)) / 2, rtol=1e-15)
    np.testing.assert_allclose(aux["cfm_loss"], float(jnp.mean(NEW)), rtol=1e-15)
    # at the rollout's parameters ρ = 1: the loss is −mean Â = 0 and nothing is clipped
    loss0, aux0 = lo.fpo_policy_loss(linear(0.0), ACTION, EPS, TAU, OLD, adv, 0.05)
    assert abs(float(loss0)) < 1e-15 and aux0["clip_fraction"] == 0.0 and aux0["ratio"] == 1.0


def test_log_ratio_clip_bounds_the_exponent_and_stops_its_gradient():
    """With c = 1 the exponents (−1.15625, −1.1953125) become −1: ρ = (e^−1, e^−1), both still below
    1 − 0.05, so sample 1 stays clipped and sample 0's term is e^−1·Â_0, now constant in θ: loss =
    −½(e^−1 − 0.95)/(1 + 1e-8), gradient 0. A bound above both exponents (c = 2) changes nothing."""
    adv = jnp.array([1.0, -1.0])
    np.testing.assert_allclose(lo.fpo_ratio(OLD, NEW, 1.0), [math.exp(-1.0)] * 2, rtol=1e-15)
    np.testing.assert_allclose(lo.fpo_ratio(OLD, NEW, 2.0), lo.fpo_ratio(OLD, NEW), rtol=0, atol=0)

    def loss_of(theta):
        return lo.fpo_policy_loss(linear(theta), ACTION, EPS, TAU, OLD, adv, 0.05, 1.0)[0]

    loss, grad = jax.value_and_grad(loss_of)(0.5)
    np.testing.assert_allclose(loss, -0.5 * (math.exp(-1.0) - 0.95) / (1.0 + 1e-8), rtol=1e-14)
    assert grad == 0.0


def test_flow_policy_sample_by_hand():
    """K = 2 Euler steps of u(x, τ) = τx + 1 from x_0 = 2 at τ = 1: x_1 = 2 − ½·3 = ½; at τ = ½:
    x_2 = ½ − ½(¼ + 1) = −0.125. From x_0 = 0: x_1 = −½, x_2 = −½ − ½(−¼ + 1) = −0.875."""
    out = lo.flow_policy_sample(lambda x, tau: tau[:, None] * x + 1.0, jnp.array([[2.0], [0.0]]), 2)
    np.testing.assert_allclose(out, [[-0.125], [-0.875]], rtol=0, atol=1e-15)


def test_q_lambda_return_by_hand():
    """Q(λ)'s target (Peng & Williams; purejaxql's recursion with the next action's Q), `lambda_returns`
    with V̄_{t+1} = Q(s_{t+1}, a_{t+1}): γ = λ = ½, T = 4, one env, truncated after t = 1, terminal at t = 3.
    r = (1, 2, 0, 4), Q(s_{t+1}, a_{t+1}) = (2, 6, 4, 100). G_3 = 4 (terminal: the 100 is ignored);
    G_2 = 0 + ½(½·4 + ½·4) = 2; G_1 = 2 + ½·6 = 5 (truncation: bootstrap only); G_0 = 1 + ½(½·2 + ½·5)
    = 2.75."""
    r = jnp.array([[1.0], [2.0], [0.0], [4.0]])
    d = jnp.array([[1.0], [1.0], [1.0], [0.0]])
    tr = jnp.array([[0.0], [1.0], [0.0], [0.0]])
    q_next = jnp.array([[2.0], [6.0], [4.0], [100.0]])
    G = lo.lambda_returns(r, d, tr, q_next, 0.5, 0.5)
    assert np.array_equal(G, [[2.75], [5.0], [2.0], [4.0]])


@pytest.mark.parametrize("call,error,text", [
    (lambda: lo.cfm_losses(linear(0.0), ACTION[0], EPS, TAU), ShapeError, "action must have shape (B, A)"),
    (lambda: lo.cfm_losses(linear(0.0), ACTION, EPS[:, :, 0], TAU), ShapeError, "eps must have shape"),
    (lambda: lo.cfm_losses(linear(0.0), ACTION, EPS, TAU[:, :1]), ShapeError, "flow_time must have shape"),
    (lambda: lo.fpo_ratio(OLD, NEW[:1]), ShapeError, "one shape (B, n)"),
    (lambda: lo.fpo_policy_loss(linear(0.0), ACTION, EPS, TAU, OLD, jnp.zeros(3)), ShapeError, "advantage"),
    (lambda: lo.fpo_policy_loss(linear(0.0), ACTION, EPS, TAU, OLD, jnp.zeros(2), 0.0), ConfigError,
     "clip_eps=0.0"),
    (lambda: lo.flow_policy_sample(linear(0.0), jnp.zeros((2, 1)), 0), ConfigError, "steps=0"),
    (lambda: lo.flow_policy_sample(linear(0.0), jnp.zeros(2), 2), ShapeError, "noise must have shape"),
])
def test_bad_input(call, error, text):
    with pytest.raises(error, match=None) as err:
        call()
    assert text in str(err.value)
