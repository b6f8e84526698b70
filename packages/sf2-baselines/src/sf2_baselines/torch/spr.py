"""SPR (PyTorch): self-predictive representations (Schwarzer et al., 2021) adapted to state inputs as in
the SF² paper's Appendix B.1 (K = 1, Gaussian-noise augmentation of std σ: the config field
`spr_augmentation_std`, 0.05 by default, the paper's choice from its Figure 5 sweep). Mirror of
`sf2_baselines.jax.spr`; README.md "SPR".

`SPRNetworks` holds `obs_norm`, `policy`, `target_policy` | `log_alpha` (the core's), `encoder` f
(MLP(hidden_sizes → F) on concat[s̃, a]), `q` (the core's twin Q heads on z = f(s, a)), `projection` g
(Dense F → q_hidden_size), `prediction` h (Dense q_hidden_size → q_hidden_size), and the targets
`target_encoder`, `target_q`, `target_projection`.
"""

from __future__ import annotations

import torch
from sf2_common.config import SF2Config
from sf2_common.errors import ConfigError
from sf2_torch import networks as core_nw
from sf2_torch.losses import Batch
from torch import nn

from . import common

__all__ = [
    "GROUPS",
    "AUGMENTATION_STD",
    "SPRNetworks",
    "make_networks",
    "augment",
    "features",
    "critic",
    "project",
    "predict",
    "spr_loss",
]

GROUPS = ("encoder", "q", "projection", "prediction", "target_encoder", "target_q", "target_projection")
# Appendix B.1 / Figure 5: the default of the config field `spr_augmentation_std` (sf2_common.config)
AUGMENTATION_STD = SF2Config.spr_augmentation_std


class SPRNetworks(nn.Module):
    """All modules of an SPR agent: encoder, projection, prediction, their targets and the core's part.

    Args:
      cfg: the `SF2Config`.
      algo: "td3" or "sac".
      augmentation_std: σ of the Gaussian augmentation s̃ = s̄ + σξ; None for the config's
        `spr_augmentation_std`.
      dtype, device: of every parameter.

    Attributes:
      cfg, algo, augmentation_std: as given.
      encoder, target_encoder: f on [normalize(s), a] and its EMA target.
      projection, target_projection: g, Dense(F → q_hidden_size), and its EMA target.
      prediction: h, Dense(q_hidden_size → q_hidden_size).
      q, target_q: the twin Q heads on z.
      obs_norm, policy, target_policy (TD3) / log_alpha (SAC): the core agent's (`common.init_core`).

    Raises:
      ConfigError: a negative `augmentation_std`, or `cfg`/`algo` as the core's `make_networks`.
    """

    def __init__(
        self,
        cfg: SF2Config,
        algo: str = "td3",
        augmentation_std: float | None = None,
        *,
        dtype=None,
        device=None,
    ) -> None:
        super().__init__()
        if augmentation_std is None:
            augmentation_std = cfg.spr_augmentation_std
        if not (isinstance(augmentation_std, (int, float)) and augmentation_std >= 0):
            raise ConfigError(f"augmentation_std = {augmentation_std!r} is invalid: must be a number >= 0")
        kw = dict(dtype=dtype, device=device)
        common.init_core(self, cfg, algo, **kw)
        self.augmentation_std = float(augmentation_std)
        D, A, F, P = cfg.obs_size, cfg.action_size, cfg.feature_size, cfg.q_hidden_size
        self.encoder = core_nw.MLP(D + A, cfg.hidden_sizes, F, cfg.layer_norm, **kw)
        self.q = core_nw.TwinQ(cfg, **kw)
        self.projection = core_nw.MLP(F, (), P, False, **kw)
        self.prediction = core_nw.MLP(P, (), P, False, **kw)
        self.target_encoder = common.frozen_copy(self.encoder)
        self.target_q = common.frozen_copy(self.q)
        self.target_projection = common.frozen_copy(self.projection)

    def extra_repr(self) -> str:
        return f"algo={self.algo!r}, augmentation_std={self.augmentation_std}"


def make_networks(
    cfg: SF2Config,
    algo: str = "td3",
    augmentation_std: float | None = None,
    *,
    dtype=None,
    device=None,
    core=None,
) -> SPRNetworks:
    """Build and initialise an SPR agent's modules (seed with `torch.manual_seed` first). `core`: an agent's
    `Networks` whose `obs_norm`, `policy`, `target_policy` / `log_alpha` are shared, not copied."""
    return common.share_core(SPRNetworks(cfg, algo, augmentation_std, dtype=dtype, device=device), core)


# ------------------------------------------------------------------------------------------ networks
def augment(nets: SPRNetworks, obs_normalized: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """s̃ = s̄ + σξ: Gaussian-noise augmentation in normalized-observation space (Appendix B.1)."""
    return obs_normalized + nets.augmentation_std * noise


def _input(nets: SPRNetworks, obs, action, obs_noise=None) -> torch.Tensor:
    cfg = nets.cfg
    common.check_last("obs", obs, cfg.obs_size, "obs_size")
    common.check_last("action", action, cfg.action_size, "action_size")
    x = core_nw.normalize(obs, nets.obs_norm)
    if obs_noise is not None:
        common.check_noise("obs_noise", obs_noise, x.shape[:-1], cfg.obs_size, "obs_size")
        x = augment(nets, x, obs_noise)
    return torch.cat([x, action], dim=-1)


def features(nets: SPRNetworks, obs, action, target: bool = False, obs_noise=None) -> torch.Tensor:
    """z = f(s̃, a) (B, F); s̃ = normalize(s) (+ σξ with `obs_noise` ξ); `target` uses f̄."""
    return (nets.target_encoder if target else nets.encoder)(_input(nets, obs, action, obs_noise))


def critic(nets: SPRNetworks, obs, action, target: bool = False) -> torch.Tensor:
    """Twin Q(f(s, a)) (B, 2) on clean observations; `target` uses f̄ and Q̄."""
    return (nets.target_q if target else nets.q)(features(nets, obs, action, target))


def project(nets: SPRNetworks, z: torch.Tensor, target: bool = False) -> torch.Tensor:
    """g(z) (B, q_hidden_size); `target` uses ḡ."""
    common.check_last("z", z, nets.cfg.feature_size, "feature_size")
    return (nets.target_projection if target else nets.projection)(z)


def predict(nets: SPRNetworks, y: torch.Tensor) -> torch.Tensor:
    """h(y) (B, q_hidden_size)."""
    common.check_last("y", y, nets.cfg.q_hidden_size, "q_hidden_size")
    return nets.prediction(y)


# ------------------------------------------------------------------------------------------ losses
def spr_loss(
    nets: SPRNetworks,
    batch: Batch,
    next_action: torch.Tensor,
    obs_noise: torch.Tensor,
    next_obs_noise: torch.Tensor,
):
    """SPR's K = 1 self-prediction loss, trained on the encoder f, the projection g and the prediction h.

    With σ = `augmentation_std`:
        s̃ = normalize(s) + σξ,  s̃′ = normalize(s′) + σξ′,  p = h(g(f(s̃, a))),  t = sg(ḡ(f̄(s̃′, ā′)))
        spr_loss = mean_b m_b ‖p/‖p‖ − t/‖t‖‖²  (= 2 − 2 cos(p, t) per sample)

    Args:
      nets: the `SPRNetworks`.
      batch: the transitions.
      next_action: ā′ (B, A) from the base algorithm (TD3: the target policy at s′; SAC: a policy sample);
        gets no gradient.
      obs_noise: ξ (B, D) ~ N(0, I).
      next_obs_noise: ξ′ (B, D) ~ N(0, I).

    Returns:
      (loss, {"spr_cosine": mean_b m_b cos(p, t)}).

    Raises:
      ShapeError: a field of `batch` or a noise of another shape.
    """
    cfg = nets.cfg
    b = common.check_batch(cfg, batch)
    common.check_noise("next_action", next_action, b, cfg.action_size, "action_size")
    common.check_noise("obs_noise", obs_noise, b, cfg.obs_size, "obs_size")
    common.check_noise("next_obs_noise", next_obs_noise, b, cfg.obs_size, "obs_size")
    z = features(nets, batch.obs, batch.action, obs_noise=obs_noise)
    pred = common.l2_normalize(predict(nets, project(nets, z)))
    with torch.no_grad():
        z_next = features(nets, batch.next_obs, next_action, target=True, obs_noise=next_obs_noise)
        tgt = common.l2_normalize(project(nets, z_next, target=True))
    mask = 1.0 - batch.truncation
    loss = torch.mean(mask * (pred - tgt).square().sum(-1))
    return loss, {"spr_cosine": torch.mean(mask * (pred.detach() * tgt).sum(-1))}
