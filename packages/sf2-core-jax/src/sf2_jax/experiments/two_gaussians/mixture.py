"""The target p = γ·p⁽¹⁾ + (1 − γ)·p⁽²⁾ of Appendix A.3 and the exact Wasserstein-1 distance to it.

Components (Table 2, Appendix E.2): p⁽¹⁾ = N(−2.0, 0.3²) carries weight γ, p⁽²⁾ = N(2.0, 0.7²) carries
1 − γ. Why this way round: Appendix A.3 writes p_mix = γ p⁽¹⁾ + (1 − γ) p⁽²⁾ with the table's "first
Gaussian" as p⁽¹⁾, and Table 2's "mixture probability 0.01" is the weight 1 − γ of the second component at
the paper's γ = 0.99 (Appendix A.1, footnote 1). This is the role γ has in SF² (eq. 1 and 3): γ weights
the bootstrapped successor part (here p⁽¹⁾) and 1 − γ the observed transition (here p⁽²⁾), so as γ → 1 a
learner that samples the mixture almost never sees the second component.
`wasserstein1` is exact, in closed form (its docstring derives it). numpy/scipy, float64, on the host."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr
from sf2_common.errors import ConfigError

__all__ = ["MEANS", "STDS", "Mixture", "wasserstein1"]

MEANS = (-2.0, 2.0)   # μ₁, μ₂ (Table 2)
STDS = (0.3, 0.7)     # σ₁, σ₂ (Table 2)
_BISECTION_STEPS = 200


@dataclass(frozen=True)
class Mixture:
    """γ·N(μ₁, σ₁²) + (1 − γ)·N(μ₂, σ₂²); `gamma` ∈ [0, 1] is the weight of the first component (module
    docstring); γ = 1 or 0 is a single Gaussian."""

    gamma: float
    means: tuple[float, float] = MEANS
    stds: tuple[float, float] = STDS

    def __post_init__(self):
        if not 0.0 <= float(self.gamma) <= 1.0:
            raise ConfigError(f"gamma = {self.gamma!r} is invalid: must lie in [0, 1]")

    @property
    def weights(self) -> tuple[float, float]:
        return (float(self.gamma), 1.0 - float(self.gamma))

    def _z(self, x):
        x = np.asarray(x, dtype=np.float64)[..., None]
        return (x - np.asarray(self.means)) / np.asarray(self.stds)

    def pdf(self, x):
        z = self._z(x)
        density = np.exp(-0.5 * z**2) / (np.sqrt(2 * np.pi) * np.asarray(self.stds))
        return np.sum(np.asarray(self.weights) * density, axis=-1)

    def cdf(self, x):
        return np.sum(np.asarray(self.weights) * ndtr(self._z(x)), axis=-1)

    def partial_mean(self, x):
        """M(x) = ∫_{−∞}^x t dF(t); M(−∞) = 0, M(+∞) = the mixture's mean."""
        z = self._z(x)
        phi = np.exp(-0.5 * z**2) / np.sqrt(2 * np.pi)
        parts = np.asarray(self.means) * ndtr(z) - np.asarray(self.stds) * phi
        return np.sum(np.asarray(self.weights) * parts, axis=-1)

    def quantile(self, u):
        """F⁻¹(u) for u in (0, 1), by bisection (F is continuous and strictly increasing)."""
        u = np.asarray(u, dtype=np.float64)
        if np.any((u <= 0) | (u >= 1)):
            raise ConfigError("quantile levels must lie strictly between 0 and 1")
        lo = np.full_like(u, min(self.means) - 40 * max(self.stds))
        hi = np.full_like(u, max(self.means) + 40 * max(self.stds))
        for _ in range(_BISECTION_STEPS):
            mid = 0.5 * (lo + hi)
            below = self.cdf(mid) < u
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        return 0.5 * (lo + hi)

    def mass_above(self, x: float) -> float:
        """P(X > x), e.g. the mass of the second mode, 1 − F(0)."""
        return float(1.0 - self.cdf(x))


def wasserstein1(samples, mixture: Mixture) -> np.ndarray:
    """Exact W1 between the empirical distribution of `samples` (..., n) and `mixture` (below).
    Returns an array of the leading shape (...).

    In one dimension W1(Pₙ, P) = ∫₀¹ |Fₙ⁻¹(u) − F⁻¹(u)| du. Neither a large sample of
    the mixture nor a quantile grid is needed: with the sorted samples x₍₁₎ ≤ … ≤ x₍ₙ₎ and the mixture's
    quantiles qᵢ = F⁻¹(i/n) (q₀ = −∞, qₙ = +∞) it is the finite sum
        W1 = Σᵢ ∫_{qᵢ₋₁}^{qᵢ} |x₍ᵢ₎ − y| dF(y),
    and each term is closed-form through F and the partial mean
    M(y) = ∫_{−∞}^y t dF(t) = Σⱼ wⱼ(μⱼΦ(zⱼ) − σⱼφ(zⱼ)), zⱼ = (y − μⱼ)/σⱼ. So the true-mixture side carries
    no Monte Carlo error at all (a large reference sample of size M would add an error of order M^(−1/2));
    the quantiles come from bisection to float64 resolution.
    Everything here is numpy/scipy (float64) and runs on the host.
    """
    x = np.sort(np.asarray(samples, dtype=np.float64), axis=-1)
    n = x.shape[-1]
    if n < 1:
        raise ConfigError("wasserstein1 needs at least one sample")
    u = np.arange(n + 1) / n
    q = np.concatenate([[-np.inf], mixture.quantile(u[1:-1]), [np.inf]])
    lo, hi = q[:-1], q[1:]
    m = np.clip(x, lo, hi)                         # where y crosses x₍ᵢ₎ inside [qᵢ₋₁, qᵢ]
    f_m = mixture.cdf(m)
    big_m, big_lo, big_hi = mixture.partial_mean(m), mixture.partial_mean(lo), mixture.partial_mean(hi)
    # ∫_{lo}^{m} (x − y) dF + ∫_{m}^{hi} (y − x) dF, with F(lo) = (i − 1)/n and F(hi) = i/n exactly
    terms = x * (f_m - u[:-1]) - (big_m - big_lo) + (big_hi - big_m) - x * (u[1:] - f_m)
    return np.sum(terms, axis=-1)
