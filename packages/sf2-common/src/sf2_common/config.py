"""`SF2Config`: sizes and loss hyperparameters of SF², validated on construction; both cores re-export this
one class, so their fields, defaults and messages cannot drift. Defaults follow the paper's Table 1
except where the authors' runs differ (docs/core-contract.md lists each); `gamma_su` is γ_su of eq. (3),
`denoising_steps` is T of Algorithm 1's ODE."""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any

from sf2_common.errors import ConfigError

__all__ = ["SF2Config", "INTEGRATORS"]

INTEGRATORS = ("midpoint", "euler")


def _fail(field: str, value: Any, valid: str) -> None:
    raise ConfigError(f"SF2Config.{field} = {value!r} is invalid: {valid}")


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(float(value))


@dataclasses.dataclass(frozen=True)
class SF2Config:
    """Sizes (D = `obs_size`, A = `action_size`, F = `feature_size`, E = `embedding_size`) and
    hyperparameters of SF² (paper §3, Algorithm 1, Appendix D–E); frozen and hashable (a static argument of
    `jax.jit`). Construction validates every field (`ConfigError` naming the field, the value and what is
    valid); lists of sizes are stored as tuples of ints."""

    obs_size: int  # D
    action_size: int  # A
    feature_size: int = 512  # F (Table 1)
    hidden_sizes: tuple[int, ...] = (512, 512, 512)  # psi and policy hidden widths (Table 1)
    q_hidden_size: int = 512  # each Q head's single hidden layer (authors' code: hidden_layer_sizes[0])
    zeta_hidden_sizes: tuple[int, ...] = (512, 512)  # zeta hidden widths (Table 1)
    embedding_size: int = 64  # sinusoidal flow-time embedding size, even (Table 1)
    layer_norm: bool = True  # LayerNorm after each hidden ReLU of psi, zeta, policy (Table 1)
    gamma_su: float = 0.99  # successor discount weighting L_P against L_boot, in [0, 1)
    denoising_steps: int = 1  # T >= 1 steps of the bootstrap ODE
    integrator: str = "midpoint"  # "midpoint" (2 evaluations/step, Algorithm 1) or "euler"
    contract_zeta: bool = True  # fast path (docs/core-contract.md "Networks"); False = plain oracle
    discount: float = 0.99  # MDP gamma
    reward_scaling: float = 1.0
    tau: float = 0.005  # EMA rate of target psi, Q, policy
    tau_zeta: float = 0.05  # EMA rate of target zeta (authors' runs; Table 1 says 0.005)
    learning_rate: float = 1e-3  # Adam lr of psi, zeta, Q, policy (authors' runs; Table 1 says 1e-4)
    alpha_learning_rate: float = 3e-4  # Adam lr of SAC's log alpha (Table 1)
    adam_eps: float = 1e-5  # authors' optimizer
    # ψ keeps one Adam state across its TD and representation steps (authors' code); False: one per loss
    shared_adam: bool = True
    # representation (aux) gradient steps per SGD step, each on the step's minibatch with its own noise draw
    # (paper App. C.2.1, Figure 9 left: "gradient steps dedicated to the feature updater"); 1: the authors'
    aux_steps_per_sgd_step: int = 1
    smoothing_noise: float = 0.2  # TD3 target-policy smoothing sigma (Table 1)
    noise_clip: float = 0.3  # TD3 smoothing clip (Table 1)
    exploration_noise: float = 0.2  # TD3 acting noise (Table 1)
    policy_delay: int = 1  # (Table 1)
    min_std: float = 0.001  # SAC tanh-Gaussian minimum std (Brax)
    target_entropy_scale: float = 0.5  # SAC target entropy = -scale * A (authors' code)
    init_log_alpha: float = 0.0  # SAC
    normalizer_std_min: float = 1e-6  # running-statistics std clip (Brax)
    normalizer_std_max: float = 1e6
    # the SPR baseline's σ of s̃ = s̄ + σξ, its augmentation of state inputs (paper App. B.1, Figure 5's 0.05)
    spr_augmentation_std: float = 0.05

    def __post_init__(self) -> None:
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
        if not _is_int(self.aux_steps_per_sgd_step) or self.aux_steps_per_sgd_step < 1:
            _fail("aux_steps_per_sgd_step", self.aux_steps_per_sgd_step, "must be an int >= 1")
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
        for name in ("layer_norm", "contract_zeta", "shared_adam"):
            if not isinstance(getattr(self, name), bool):
                _fail(name, getattr(self, name), "must be a bool")
        if not _is_real(self.spr_augmentation_std) or self.spr_augmentation_std < 0:
            _fail("spr_augmentation_std", self.spr_augmentation_std, "must be a finite number >= 0")

    @classmethod
    def small(cls, obs_size: int, action_size: int, **overrides: Any) -> SF2Config:
        """The test size: feature 16, hidden (32, 32), q hidden 32, zeta hidden (32, 32), embedding 8."""
        kwargs: dict[str, Any] = dict(feature_size=16, hidden_sizes=(32, 32), q_hidden_size=32,
                                      zeta_hidden_sizes=(32, 32), embedding_size=8)
        kwargs.update(overrides)
        return cls(obs_size=obs_size, action_size=action_size, **kwargs)

    def replace(self, **changes: Any) -> SF2Config:
        """A copy with `changes` applied (validated again)."""
        return dataclasses.replace(self, **changes)
