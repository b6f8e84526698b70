"""Pieces every baseline shares (PyTorch): the core's shape checks, L2 normalization, target copies, the
modules shared with the core agent.

The baselines' TD3 and SAC losses are the core's (`sf2_torch.losses.td3_critic_loss`, ..., paper
Appendix D, Algorithms 2–3) with `critic=` the baseline's critic (`sim.critic`, `spr.critic`, or a
representation's `critic`); the agents pass it. Their own losses (reward prediction, Laplacian, SPR)
take 2-D batches (B, ·), as the core's do. Mirror of `sf2_baselines.jax.common`.
"""

from __future__ import annotations

import torch
from sf2_common.config import SF2Config
from sf2_common.errors import ConfigError
from sf2_torch import networks as core_nw
from sf2_torch.losses import check_batch, check_noise
from sf2_torch.networks import check_last
from torch import nn

__all__ = ["NORM_EPS", "l2_normalize", "frozen_copy", "init_core", "share_core", "check_last", "check_batch",
           "check_noise"]

# check_last, check_batch, check_noise: the core's public shape checks (`sf2_torch.networks`,
# `sf2_torch.losses`), the same the core's losses run, re-exported for the baselines' modules
NORM_EPS = 1e-8


def l2_normalize(x: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """x / (‖x‖₂ + 1e-8) along `dim`."""
    return x / (torch.linalg.vector_norm(x, dim=dim, keepdim=True) + NORM_EPS)


def frozen_copy(module: nn.Module) -> nn.Module:
    """A deep copy with `requires_grad=False` (a target network)."""
    import copy

    return copy.deepcopy(module).requires_grad_(False)


def init_core(nets: nn.Module, cfg: SF2Config, algo: str, **kw) -> None:
    """Give a baseline's networks `nets` the core agent's part: `cfg`, `algo` (both checked), `obs_norm`,
    `policy` and `target_policy` (TD3) or the `log_alpha` parameter (SAC), built as the core's `Networks`
    builds them (`kw`: dtype, device); `share_core` replaces them with an agent's own."""
    if not isinstance(cfg, SF2Config):
        raise ConfigError(f"cfg must be an SF2Config, found {type(cfg).__name__}")
    if algo not in core_nw.ALGOS:
        raise ConfigError(f"algo={algo!r} is invalid: must be one of {', '.join(map(repr, core_nw.ALGOS))}")
    nets.cfg, nets.algo = cfg, algo
    nets.obs_norm = core_nw.ObsNormalizer(cfg.obs_size, cfg.normalizer_std_min, cfg.normalizer_std_max, **kw)
    nets.policy = core_nw.TD3Policy(cfg, **kw) if algo == "td3" else core_nw.SACPolicy(cfg, **kw)
    if algo == "td3":
        nets.target_policy = frozen_copy(nets.policy)
    else:
        dtype, device = kw.get("dtype") or torch.get_default_dtype(), kw.get("device")
        nets.log_alpha = nn.Parameter(torch.full((), cfg.init_log_alpha, dtype=dtype, device=device))


def share_core(nets: nn.Module, core: nn.Module | None) -> nn.Module:
    """Make `nets` use the core agent's `obs_norm`, `policy` and `target_policy` (TD3) or `log_alpha` (SAC)
    modules and parameter (the same objects), so an agent's normalizer and policy are one. Returns `nets`."""
    if core is None:
        return nets
    if core.algo != nets.algo or core.cfg != nets.cfg:
        raise ConfigError(
            f"cannot share modules of networks built for algo={core.algo!r} with networks built for "
            f"algo={nets.algo!r} (or with another config)"
        )
    nets.obs_norm = core.obs_norm
    nets.policy = core.policy
    if nets.algo == "td3":
        nets.target_policy = core.target_policy
    else:
        nets.log_alpha = core.log_alpha
    return nets
