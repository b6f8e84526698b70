"""CRL's losses (sf2_torch.losses_crl) against values derived by hand on a batch of three, as the JAX core's
test_losses_crl.py: the energy, forward, backward and symmetric InfoNCE with its log-sum-exp penalty
and the contrastive accuracy (a tie: argmax takes the first), the actor's log σ and its squashed sample,
the actor and temperature losses with their gradient contract, the truncated geometric goal offset and the
shape checks (float64).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from sf2_torch import ConfigError, ShapeError
from sf2_torch import losses_crl as lc

E = 1e-6
F64 = torch.float64


def t(x):
    return torch.tensor(x, dtype=F64)


def e(d):
    """The energy at distance d, by hand."""
    return -math.sqrt(d * d + E)


# φ = [0, 1, 3], ψ = [0, 2, 3] (F = 1); |φ_i − ψ_j| row by row
PHI, PSI = [[0.0], [1.0], [3.0]], [[0.0], [2.0], [3.0]]
DIST = [[0, 2, 3], [1, 1, 2], [3, 1, 0]]
LSE = [math.log(sum(math.exp(e(d)) for d in row)) for row in DIST]
DIAG = [e(0), e(1), e(0)]


def test_energy():
    assert float(lc.energy(t([0.0, 0.0]), t([3.0, 4.0]))) == pytest.approx(-math.sqrt(25 + E))
    np.testing.assert_allclose(lc.energy(t(PHI)[:, None], t(PSI)[None]).numpy(),
                               [[e(d) for d in row] for row in DIST], rtol=1e-12)


@pytest.mark.parametrize("c", [0.0, 0.1])
def test_critic_loss(c):
    loss, aux = lc.crl_critic_loss(t(PHI), t(PSI), c)
    by_hand = -sum(DIAG[i] - LSE[i] for i in range(3)) / 3 + c * sum((LSE[i] + E) ** 2 for i in range(3)) / 3
    assert float(loss.detach()) == pytest.approx(by_hand, rel=1e-12)
    # rows 0 and 2 pick their own goal; row 1 is a tie (distance 1 to goals 0 and 1): argmax takes goal 0
    assert float(aux["accuracy"]) == pytest.approx(2 / 3)
    assert float(aux["logits_pos"]) == pytest.approx(sum(DIAG) / 3, rel=1e-12)
    off = [e(d) for i, row in enumerate(DIST) for j, d in enumerate(row) if i != j]
    assert float(aux["logits_neg"]) == pytest.approx(sum(off) / 6, rel=1e-12)
    assert float(aux["logsumexp"]) == pytest.approx(sum(LSE) / 3 + E, rel=1e-12)


# bwd on φ and ψ' = [0, 2, 4]: rows and columns hold different distances (on ψ they are the same
# multisets, so fwd and bwd would agree); m_j, a goal's column's log-sum-exp
PSI_B = [[0.0], [2.0], [4.0]]
DIST_B = [[0, 2, 4], [1, 1, 3], [3, 1, 1]]
LSE_B = [math.log(sum(math.exp(e(d)) for d in row)) for row in DIST_B]
COL_LSE_B = [math.log(sum(math.exp(e(row[j])) for row in DIST_B)) for j in range(3)]
DIAG_B = [e(0), e(1), e(1)]


@pytest.mark.parametrize("c", [0.0, 0.1])
def test_backward_critic_loss(c):
    """bwd: each goal's column against the batch's state-actions; the penalty and the metrics stay the rows'
    (accuracy 1/3: rows 1 and 2 tie and argmax takes the first; the columns' argmax would score 3/3)."""
    loss, aux = lc.crl_critic_loss(t(PHI), t(PSI_B), c, direction="bwd")
    by_hand = (-sum(DIAG_B[j] - COL_LSE_B[j] for j in range(3)) / 3
               + c * sum((LSE_B[i] + E) ** 2 for i in range(3)) / 3)
    assert float(loss.detach()) == pytest.approx(by_hand, rel=1e-12)
    assert float(aux["accuracy"]) == pytest.approx(1 / 3)
    assert float(aux["logits_pos"]) == pytest.approx(sum(DIAG_B) / 3, rel=1e-12)
    off = [e(d) for i, row in enumerate(DIST_B) for j, d in enumerate(row) if i != j]
    assert float(aux["logits_neg"]) == pytest.approx(sum(off) / 6, rel=1e-12)
    assert float(aux["logsumexp"]) == pytest.approx(sum(LSE_B) / 3 + E, rel=1e-12)
    with pytest.raises(ConfigError,
                       match="direction='binary' is invalid: must be one of .'fwd', 'bwd', 'sym'."):
        lc.crl_critic_loss(t(PHI), t(PSI), c, direction="binary")


@pytest.mark.parametrize("c", [0.0, 0.1])
def test_symmetric_critic_loss(c):
    """sym on φ and ψ': both softmaxes, −mean_i (2 L_ii − ℓ_i − m_i), the rows' penalty and metrics."""
    loss, aux = lc.crl_critic_loss(t(PHI), t(PSI_B), c, direction="sym")
    by_hand = (-sum(2 * DIAG_B[i] - LSE_B[i] - COL_LSE_B[i] for i in range(3)) / 3
               + c * sum((LSE_B[i] + E) ** 2 for i in range(3)) / 3)
    assert float(loss.detach()) == pytest.approx(by_hand, rel=1e-12)
    assert float(aux["accuracy"]) == pytest.approx(1 / 3)
    assert float(aux["logsumexp"]) == pytest.approx(sum(LSE_B) / 3 + E, rel=1e-12)


def test_critic_loss_gradient_pulls_positives_together():
    """d loss / d φ_0 by hand (c = 0): (1/3) Σ_j (p_0j − [j = 0]) dL_0j/dφ_0, dL_0j/dφ_0 =
    −(φ_0 − ψ_j)/sqrt((φ_0 − ψ_j)² + ε)."""
    phi = t(PHI).requires_grad_()
    lc.crl_critic_loss(phi, t(PSI), 0.0)[0].backward()
    p = [math.exp(e(d) - LSE[0]) for d in DIST[0]]
    d_l = [-(PHI[0][0] - PSI[j][0]) / math.sqrt((PHI[0][0] - PSI[j][0]) ** 2 + E) for j in range(3)]
    by_hand = sum((p[j] - (j == 0)) * d_l[j] for j in range(3)) / 3
    assert float(phi.grad[0, 0]) == pytest.approx(by_hand, rel=1e-10)


def test_backward_critic_loss_gradient():
    """bwd on ψ', c = 0: d loss / d φ_0 = (1/3) Σ_j (q_0j − [j = 0]) dL_0j/dφ_0, q_0j = exp(L_0j − m_j)."""
    phi = t(PHI).requires_grad_()
    lc.crl_critic_loss(phi, t(PSI_B), 0.0, "bwd")[0].backward()
    q = [math.exp(e(DIST_B[0][j]) - COL_LSE_B[j]) for j in range(3)]
    d_l = [-(PHI[0][0] - PSI_B[j][0]) / math.sqrt((PHI[0][0] - PSI_B[j][0]) ** 2 + E) for j in range(3)]
    by_hand = sum((q[j] - (j == 0)) * d_l[j] for j in range(3)) / 3
    assert float(phi.grad[0, 0]) == pytest.approx(by_hand, rel=1e-10)


def test_symmetric_critic_loss_gradient():
    """sym on ψ', c = 0: d loss / d φ_0 = (1/3) Σ_j (p_0j + q_0j − 2[j = 0]) dL_0j/dφ_0."""
    phi = t(PHI).requires_grad_()
    lc.crl_critic_loss(phi, t(PSI_B), 0.0, "sym")[0].backward()
    p = [math.exp(e(d) - LSE_B[0]) for d in DIST_B[0]]
    q = [math.exp(e(DIST_B[0][j]) - COL_LSE_B[j]) for j in range(3)]
    d_l = [-(PHI[0][0] - PSI_B[j][0]) / math.sqrt((PHI[0][0] - PSI_B[j][0]) ** 2 + E) for j in range(3)]
    by_hand = sum((p[j] + q[j] - 2 * (j == 0)) * d_l[j] for j in range(3)) / 3
    assert float(phi.grad[0, 0]) == pytest.approx(by_hand, rel=1e-10)


def test_actor_log_std_and_squashed_sample():
    assert float(lc.actor_log_std(t(0.0))) == pytest.approx(-1.5)
    assert float(lc.actor_log_std(t(40.0))) == pytest.approx(2.0)
    a, logp = lc.squashed_gaussian_sample(t([[0.5, 0.0]]), t([[math.log(2.0), 0.0]]), t([[1.0, 0.0]]))
    half_log_2pi = 0.5 * math.log(2 * math.pi)
    by_hand = (-0.5 - math.log(2.0) - half_log_2pi - math.log(1 - math.tanh(2.5) ** 2 + E)
               + (-half_log_2pi - math.log(1 + E)))
    np.testing.assert_allclose(a.numpy(), [[math.tanh(2.5), 0.0]], rtol=1e-12)
    assert float(logp[0]) == pytest.approx(by_hand, rel=1e-12)


def test_actor_and_alpha_losses():
    log_prob, q = t([-1.0, 0.5]).requires_grad_(), t([-2.0, -3.0]).requires_grad_()
    log_alpha = t(math.log(0.5)).requires_grad_()
    loss, aux = lc.crl_actor_loss(log_prob, q, log_alpha)
    assert float(loss.detach()) == pytest.approx((0.5 * -1 + 2 + 0.5 * 0.5 + 3) / 2)   # 2.375
    assert float(aux["entropy"]) == pytest.approx(0.25)
    loss.backward()
    assert log_alpha.grad is None
    np.testing.assert_allclose(log_prob.grad.numpy(), [0.25, 0.25])
    np.testing.assert_allclose(q.grad.numpy(), [-0.5, -0.5])
    # α = 2, −log π − H̄ = [1 + 4, −3 + 4] = [5, 1]: loss 2 · 3, d/dlog α = α · 3
    log_alpha, log_prob = t(math.log(2.0)).requires_grad_(), t([-1.0, 3.0]).requires_grad_()
    loss, aux = lc.crl_alpha_loss(log_alpha, log_prob, -4.0)
    assert float(loss.detach()) == pytest.approx(6.0) and float(aux["alpha"]) == pytest.approx(2.0)
    loss.backward()
    assert float(log_alpha.grad) == pytest.approx(6.0) and log_prob.grad is None


def test_future_offset():
    # γ = 1/2, n = 3: P(k) ∝ 2^-k, k = 1, 2, 3 → 4/7, 2/7, 1/7; the CDF 4/7 ≈ 0.571, 6/7 ≈ 0.857, 1
    u = t([0.0, 0.5, 0.6, 0.85, 0.9, 0.999])
    assert lc.future_offset(u, torch.full((6,), 3), 0.5).tolist() == [1, 1, 2, 2, 3, 3]
    assert lc.future_offset(u, torch.zeros(6, dtype=torch.int32), 0.5).tolist() == [0] * 6
    assert lc.future_offset(u, torch.ones(6, dtype=torch.int32), 0.99).tolist() == [1] * 6
    # γ = 0.99 with room: an even grid of u gives the law's frequencies, P(k = 1) = 0.01 / (1 − 0.99^n)
    grid = (torch.arange(100_000, dtype=F64) + 0.5) / 100_000
    k = lc.future_offset(grid, torch.full(grid.shape, 1000), 0.99)
    assert int(k.min()) == 1 and int(k.max()) <= 1000
    assert float((k == 1).double().mean()) == pytest.approx(0.01 / (1 - 0.99 ** 1000), abs=1e-4)
    first_100 = (1 - 0.99 ** 100) / (1 - 0.99 ** 1000)
    assert float((k <= 100).double().mean()) == pytest.approx(first_100, abs=1e-4)


def test_shapes():
    with pytest.raises(ShapeError, match="phi and psi"):
        lc.crl_critic_loss(torch.zeros((3, 2)), torch.zeros((4, 2)), 0.1)
    with pytest.raises(ShapeError, match="mean, log_std and noise"):
        lc.squashed_gaussian_sample(torch.zeros((3, 2)), torch.zeros((3, 2)), torch.zeros((3, 1)))
    with pytest.raises(ShapeError, match="log_prob and q"):
        lc.crl_actor_loss(torch.zeros(3), torch.zeros(4), 0.0)
