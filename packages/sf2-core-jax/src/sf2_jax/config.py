"""`SF2Config`: sizes and loss hyperparameters of SF², validated on construction.

Defaults follow the paper's Appendix E Table 1, except where the authors' published runs differ
(`tau_zeta` = 0.05 and `learning_rate` = 1e-3; docs/core-contract.md lists every such place).
Names follow DESIGN.md §3: `gamma_su` is γ_su of eq. (3), `denoising_steps` is T of Algorithm 1's ODE.
"""

from __future__ import annotations

import dataclasses
import math
from numbers import Integral, Real

from sf2_jax.errors import ConfigError

__all__ = ["SF2Config", "INTEGRATORS"]

INTEGRATORS = ("midpoint", "euler")


def _fail(field: str, value, valid: str):
    raise ConfigError(f"SF2Config.{field} = {value!r} is invalid: {valid}")


def _is_int(value) -> bool:
    return isinstance(value, Integral) and not isinstance(value, bool)


def _is_real(value) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(float(value))


@dataclasses.dataclass(frozen=True)
class SF2Config:
    """Sizes (D = `obs_size`, A = `action_size`, F = `feature_size`, E = `embedding_size`) and
    hyperparameters of SF² (paper §3, Algorithm 1, Appendix D–E). Frozen and hashable, so it can be a
    static argument of `jax.jit`. Raises `ConfigError` naming the field, the value and what is valid."""

    obs_size: int
    action_size: int
    feature_size: int = 512
    hidden_sizes: tuple[int, ...] = (512, 512, 512)
    q_hidden_size: int = 512
    zeta_hidden_sizes: tuple[int, ...] = (512, 512)
    embedding_size: int = 64
    layer_norm: bool = True
    gamma_su: float = 0.99
    denoising_steps: int = 1
    integrator: str = "midpoint"
    contract_zeta: bool = True
    discount: float = 0.99
    reward_scaling: float = 1.0
    tau: float = 0.005
    tau_zeta: float = 0.05
    learning_rate: float = 1e-3
    alpha_learning_rate: float = 3e-4
    adam_eps: float = 1e-5
    smoothing_noise: float = 0.2
    noise_clip: float = 0.3
    exploration_noise: float = 0.2
    policy_delay: int = 1
    min_std: float = 0.001
    target_entropy_scale: float = 0.5
    init_log_alpha: float = 0.0
    normalizer_std_min: float = 1e-6
    normalizer_std_max: float = 1e6

    def __post_init__(self):
        for name in ("obs_size", "action_size", "feature_size", "q_hidden_size", "embedding_size"):
            value = getattr(self, name)
            if not _is_int(value) or value < 1:
                _fail(name, value, "must be an int >= 1")
        for name in ("hidden_sizes", "zeta_hidden_sizes"):
            value = getattr(self, name)
            try:
                sizes = tuple(value)
            except TypeError:
                _fail(name, value, "must be a sequence of ints >= 1")
            if not all(_is_int(n) and n >= 1 for n in sizes):
                _fail(name, value, "must be a sequence of ints >= 1")
            object.__setattr__(self, name, tuple(int(n) for n in sizes))
        if self.embedding_size % 2:
            _fail("embedding_size", self.embedding_size, "must be even (sin/cos pairs)")
        if not _is_int(self.denoising_steps) or self.denoising_steps < 1:
            _fail("denoising_steps", self.denoising_steps, "must be an int >= 1")
        if not _is_int(self.policy_delay) or self.policy_delay < 1:
            _fail("policy_delay", self.policy_delay, "must be an int >= 1")
        if not _is_real(self.gamma_su) or not 0.0 <= self.gamma_su < 1.0:
            _fail("gamma_su", self.gamma_su, "must satisfy 0 <= gamma_su < 1")
        if self.integrator not in INTEGRATORS:
            _fail("integrator", self.integrator, f"must be one of {INTEGRATORS}")
        for name in ("tau", "tau_zeta"):
            value = getattr(self, name)
            if not _is_real(value) or not 0.0 < value <= 1.0:
                _fail(name, value, "must satisfy 0 < value <= 1")
        for name in ("learning_rate", "alpha_learning_rate"):
            value = getattr(self, name)
            if not _is_real(value) or value <= 0.0:
                _fail(name, value, "must be > 0")
        if not _is_real(self.discount) or not 0.0 < self.discount <= 1.0:
            _fail("discount", self.discount, "must satisfy 0 < discount <= 1")
        for name in ("layer_norm", "contract_zeta"):
            if not isinstance(getattr(self, name), bool):
                _fail(name, getattr(self, name), "must be a bool")

    @classmethod
    def small(cls, obs_size: int, action_size: int, **overrides) -> SF2Config:
        """The test size: feature 16, hidden (32, 32), Q hidden 32, ζ hidden (32, 32), embedding 8."""
        sizes = dict(feature_size=16, hidden_sizes=(32, 32), q_hidden_size=32,
                     zeta_hidden_sizes=(32, 32), embedding_size=8)
        sizes.update(overrides)
        return cls(obs_size=obs_size, action_size=action_size, **sizes)

    def replace(self, **changes) -> SF2Config:
        """A copy with `changes` applied (validated again)."""
        return dataclasses.replace(self, **changes)
