"""Frequency tables of the flow-time embedding (paper Appendix A; docs/parity.md, "flow-time embedding"),
shared by both cores' `networks.flow_time_embedding`.

out[2i] = sin(10⁴·k·ω_i), out[2i+1] = cos(10⁴·k·ω_i), ω_i = exp(−2i·ln(10⁴)/size). The phase is reduced
exactly before sin/cos: with G_i = 10⁴·ω_i / 2π turns, k = k_hi + k_lo (k_hi on a 2⁻¹² grid) and
G = G_hi + G_lo (G_hi on 11 significant bits), k_hi·G_hi is exact in float32 for |k| ≤ 2, so the float32
phase is accurate to ~1e-6 rad instead of one ulp of a phase near 10⁴ (5e-4 rad).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["EMBEDDING_K_GRID", "EMBEDDING_FREQ_BITS", "round_to_bits", "embedding_turns"]

EMBEDDING_K_GRID = 4096.0
EMBEDDING_FREQ_BITS = 11


def round_to_bits(x: np.ndarray, bits: int) -> np.ndarray:
    """x rounded to `bits` significant bits (float64; x > 0)."""
    quantum = 2.0 ** (np.floor(np.log2(x)) - (bits - 1))
    return np.round(x / quantum) * quantum


def embedding_turns(size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frequencies in turns per unit flow time, G_i = 10⁴·ω_i / 2π (float64), split G = G_hi + G_lo with
    G_hi on EMBEDDING_FREQ_BITS significant bits: (G, G_hi, G_lo), each (size/2,)."""
    turns = 1e4 * np.exp(-2.0 * np.arange(size // 2) * math.log(1e4) / size) / (2.0 * math.pi)
    hi = round_to_bits(turns, EMBEDDING_FREQ_BITS)
    return turns, hi, turns - hi
