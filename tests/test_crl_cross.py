"""JAX and torch agree on CRL's losses (sf2_jax.losses_crl, sf2_torch.losses_crl): one canonical batch of
representations, actor outputs and noise drawn with numpy into both cores; values, aux metrics and the
gradients with respect to every input (InfoNCE forward, backward and symmetric), in float64 (≤ 1e-10
relative) and float32 (cross_bridge.TOL); the goal offsets equal exactly on the same uniform draws.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch
from cross_bridge import check, jx, np_, th
from sf2_jax import losses_crl as jl
from sf2_torch import losses_crl as tl

B, F, A = 16, 8, 4
DTYPES = ["float64", "float32"]


def canonical(seed: int = 0) -> dict[str, np.ndarray]:
    """φ, ψ (B, F) at distances where the softmax is neither flat nor one-hot; the actor's μ, raw log σ,
    ξ (B, A); log α; log π (B,) and q (B,)."""
    rng = np.random.default_rng(seed)
    return {"phi": rng.normal(size=(B, F)), "psi": rng.normal(size=(B, F)) * 0.7,
            "mean": rng.normal(size=(B, A)), "raw_std": rng.normal(size=(B, A)),
            "noise": rng.normal(size=(B, A)),
            "log_alpha": np.array(-0.7), "log_prob": rng.normal(size=B) * 3, "q": rng.normal(size=B) - 2}


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("penalty", [0.0, 0.1])
@pytest.mark.parametrize("direction", ["fwd", "bwd", "sym"])
def test_critic_loss(dtype, penalty, direction):
    x = canonical()
    (jloss, jaux), jgrad = jax.value_and_grad(lambda p, s: jl.crl_critic_loss(p, s, penalty, direction),
                                              argnums=(0, 1), has_aux=True)(jx(x["phi"], dtype),
                                                                            jx(x["psi"], dtype))
    phi, psi = th(x["phi"], dtype).requires_grad_(), th(x["psi"], dtype).requires_grad_()
    tloss, taux = tl.crl_critic_loss(phi, psi, penalty, direction)
    tloss.backward()
    term = f"crl_critic_loss[{direction}]"
    check(term, jloss, np_(tloss), dtype)
    for name in ("accuracy", "logits_pos", "logits_neg", "logsumexp"):
        check(f"{term}.{name}", jaux[name], np_(taux[name]), dtype)
    check(f"grad {term} (φ, ψ)", jgrad[0], np_(phi.grad), dtype, "grad")
    check(f"grad {term} (φ, ψ)", jgrad[1], np_(psi.grad), dtype, "grad")


@pytest.mark.parametrize("dtype", DTYPES)
def test_squashed_sample_and_actor_losses(dtype):
    x = canonical(1)

    def jax_actor(mean, raw, log_alpha):
        action, log_prob = jl.squashed_gaussian_sample(mean, jl.actor_log_std(raw), jx(x["noise"], dtype))
        q = jl.energy(jnp.concatenate([action, action], axis=-1), jx(x["psi"], dtype))
        loss, aux = jl.crl_actor_loss(log_prob, q, log_alpha)
        return loss, (action, log_prob, aux)

    (jloss, (jact, jlogp, jaux)), jgrad = jax.value_and_grad(jax_actor, argnums=(0, 1), has_aux=True)(
        jx(x["mean"], dtype), jx(x["raw_std"], dtype), jx(x["log_alpha"], dtype))
    mean, raw = th(x["mean"], dtype).requires_grad_(), th(x["raw_std"], dtype).requires_grad_()
    action, log_prob = tl.squashed_gaussian_sample(mean, tl.actor_log_std(raw), th(x["noise"], dtype))
    q = tl.energy(torch.cat([action, action], dim=-1), th(x["psi"], dtype))
    tloss, taux = tl.crl_actor_loss(log_prob, q, th(x["log_alpha"], dtype))
    tloss.backward()
    check("squashed_gaussian_sample (a, log π)", jact, np_(action), dtype)
    check("squashed_gaussian_sample (a, log π)", jlogp, np_(log_prob), dtype)
    check("crl_actor_loss", jloss, np_(tloss), dtype)
    check("crl_actor_loss.entropy", jaux["entropy"], np_(taux["entropy"]), dtype)
    check("grad crl_actor_loss (μ, raw log σ)", jgrad[0], np_(mean.grad), dtype, "grad")
    check("grad crl_actor_loss (μ, raw log σ)", jgrad[1], np_(raw.grad), dtype, "grad")


@pytest.mark.parametrize("dtype", DTYPES)
def test_alpha_loss(dtype):
    x = canonical(2)
    log_prob = jx(x["log_prob"], dtype)
    (jloss, jaux), jgrad = jax.value_and_grad(lambda la: jl.crl_alpha_loss(la, log_prob, -2.0),
                                              has_aux=True)(jx(x["log_alpha"], dtype))
    log_alpha = th(x["log_alpha"], dtype).requires_grad_()
    tloss, taux = tl.crl_alpha_loss(log_alpha, th(x["log_prob"], dtype), -2.0)
    tloss.backward()
    check("crl_alpha_loss", jloss, np_(tloss), dtype)
    check("crl_alpha_loss.alpha", jaux["alpha"], np_(taux["alpha"]), dtype)
    check("grad crl_alpha_loss (log α)", jgrad, np_(log_alpha.grad), dtype, "grad")


@pytest.mark.parametrize("dtype", DTYPES)
def test_future_offset(dtype):
    rng = np.random.default_rng(3)
    u = rng.uniform(size=4096)
    n = rng.integers(0, 1000, size=4096)
    jk = np.asarray(jl.future_offset(jx(u, dtype), jnp.asarray(n), 0.99))
    tk = np_(tl.future_offset(th(u, dtype), torch.as_tensor(n), 0.99))
    # equal except where a draw sits within rounding of a step of the CDF (none on these draws)
    np.testing.assert_array_equal(jk, tk)
    check("future_offset", jk, tk, dtype)
