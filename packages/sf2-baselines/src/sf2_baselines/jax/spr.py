"""SPR (JAX): self-predictive representations (Schwarzer et al., 2021) for state inputs, as the SF² paper's
Appendix B.1 adds them to TD3 and SAC (TD3+SPR, SAC+SPR): K = 1 prediction step, Gaussian-noise
augmentation of std σ (the config field `spr_augmentation_std`, 0.05 by default, the paper's choice from
its Figure 5 sweep). README.md "SPR".

Parameter groups: ``encoder``/``target_encoder``, z = f(s̃, a) = MLP(hidden_sizes → F) on concat[s̃, a]
(SPR's encoder and its one-step transition model in one state-action network, the shape of SF²'s ψ);
``q``/``target_q``, the core's twin Q heads on z (the TD loss trains q and f); ``projection``/
``target_projection``, g = Dense(F → q_hidden_size); ``prediction``, h = Dense(q_hidden_size →
q_hidden_size), linear. f̄ and ḡ are EMAs (rate τ); f̄ is also the critic's target encoder.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct
from sf2_common.config import SF2Config
from sf2_common.errors import ConfigError
from sf2_jax import networks as core_nw
from sf2_jax.losses import Batch

from . import common

__all__ = [
    "GROUPS",
    "AUGMENTATION_STD",
    "SPRNetworks",
    "make_networks",
    "init_representation",
    "init_params",
    "augment",
    "features",
    "critic",
    "project",
    "predict",
    "spr_loss",
]

sg = jax.lax.stop_gradient
Params = dict[str, Any]

GROUPS = ("encoder", "q", "projection", "prediction", "target_encoder", "target_q", "target_projection")
# Appendix B.1 / Figure 5: the Gaussian augmentation std chosen on AcrobotSwingup and used everywhere; the
# default of the config field `spr_augmentation_std` (sf2_common.config.SF2Config), which sets it per run.
AUGMENTATION_STD = SF2Config.spr_augmentation_std


@struct.dataclass
class SPRNetworks:
    """The networks of an SPR agent, without parameters (hashable; `init_params` makes them).

    Attributes:
      cfg: the `SF2Config`.
      algo: "td3" or "sac".
      augmentation_std: σ of the Gaussian augmentation s̃ = s̄ + σξ.
      core: the core `Networks` (the policy, the twin Q heads, the observation statistics).
      encoder: f, the core `MLP(hidden_sizes → F)` on [normalize(s), a].
      projection: g, Dense(F → q_hidden_size).
      prediction: h, Dense(q_hidden_size → q_hidden_size).
    """

    cfg: SF2Config = struct.field(pytree_node=False)
    algo: str = struct.field(pytree_node=False)
    core: core_nw.Networks = struct.field(pytree_node=False)
    encoder: core_nw.MLP = struct.field(pytree_node=False)
    projection: core_nw.MLP = struct.field(pytree_node=False)
    prediction: core_nw.MLP = struct.field(pytree_node=False)
    augmentation_std: float = struct.field(pytree_node=False, default=AUGMENTATION_STD)


def make_networks(cfg: SF2Config, algo: str, augmentation_std: float | None = None) -> SPRNetworks:
    """f: MLP(hidden_sizes → F) on D + A inputs; g: Dense(F → q_hidden_size); h: Dense(q_hidden_size →
    q_hidden_size); the core's policy and twin Q heads. σ = `augmentation_std`, by default the config's
    `spr_augmentation_std`."""
    core = core_nw.make_networks(cfg, algo)
    if augmentation_std is None:
        augmentation_std = cfg.spr_augmentation_std
    if not (isinstance(augmentation_std, (int, float)) and augmentation_std >= 0):
        raise ConfigError(f"augmentation_std = {augmentation_std!r} is invalid: must be a number >= 0")
    P = cfg.q_hidden_size
    return SPRNetworks(
        cfg=cfg,
        algo=algo,
        core=core,
        encoder=core_nw.MLP(cfg.hidden_sizes, cfg.feature_size, use_layer_norm=cfg.layer_norm),
        projection=core_nw.MLP((), P, use_layer_norm=False),
        prediction=core_nw.MLP((), P, use_layer_norm=False),
        augmentation_std=float(augmentation_std),
    )


def _dtype(dtype):
    return jnp.dtype(jnp.result_type(float) if dtype is None else dtype)


def init_representation(nets: SPRNetworks, key: jax.Array, dtype=None, q=None) -> Params:
    """The SPR groups; targets are copies of the online networks. `q`: reuse these Q-head parameters
    (the core's, when the agent already initialised them)."""
    cfg = nets.cfg
    dtype = _dtype(dtype)
    D, A, F, P = cfg.obs_size, cfg.action_size, cfg.feature_size, cfg.q_hidden_size
    k_enc, k_q, k_proj, k_pred = jax.random.split(key, 4)
    f32 = jnp.float32
    online = {
        "encoder": nets.encoder.init(k_enc, jnp.zeros((1, D + A), f32))["params"],
        "q": nets.core.q.init(k_q, jnp.zeros((1, F), f32))["params"] if q is None else q,
        "projection": nets.projection.init(k_proj, jnp.zeros((1, F), f32))["params"],
        "prediction": nets.prediction.init(k_pred, jnp.zeros((1, P), f32))["params"],
    }
    online = common.cast_tree(online, dtype)
    return {**online, **{f"target_{n}": common.copy_tree(online[n]) for n in ("encoder", "q", "projection")}}


def init_params(nets: SPRNetworks, key: jax.Array, dtype=None) -> Params:
    """Every group of an SPR agent: the core's `obs_norm`, `policy`, `target_policy` | `log_alpha`, and
    `init_representation`'s groups."""
    k_core, k_rep = jax.random.split(key)
    core = core_nw.init_params(nets.core, k_core, dtype=_dtype(dtype))
    params = {n: core[n] for n in ("obs_norm", "policy", "target_policy", "log_alpha") if n in core}
    return {**params, **init_representation(nets, k_rep, dtype)}


# ------------------------------------------------------------------------------------------ networks
def augment(nets: SPRNetworks, obs_normalized, noise):
    """s̃ = s̄ + σξ: Gaussian-noise augmentation in normalized-observation space (Appendix B.1)."""
    return obs_normalized + nets.augmentation_std * noise


def features(nets: SPRNetworks, params: Params, obs, action, target: bool = False, obs_noise=None):
    """z = f(s̃, a) (B, F); s̃ = normalize(s), plus σξ when `obs_noise` ξ (B, D) is given; `target`: f̄."""
    cfg = nets.cfg
    common.check_last("obs", obs, cfg.obs_size, "obs_size")
    common.check_last("action", action, cfg.action_size, "action_size")
    x = core_nw.normalize(obs, params["obs_norm"])
    if obs_noise is not None:
        common.check_noise("obs_noise", obs_noise, x.shape[:-1], cfg.obs_size, "obs_size")
        x = augment(nets, x, obs_noise)
    x = jnp.concatenate([x, action], axis=-1)
    return nets.encoder.apply({"params": params["target_encoder" if target else "encoder"]}, x)


def critic(nets: SPRNetworks, params: Params, obs, action, target: bool = False):
    """Twin Q(f(s, a)) (B, 2) on clean (unaugmented) observations; `target` uses f̄ and Q̄."""
    return core_nw.q_values(nets.core, params, features(nets, params, obs, action, target), target)


def project(nets: SPRNetworks, params: Params, z, target: bool = False):
    """g(z) (B, q_hidden_size); `target` uses ḡ."""
    common.check_last("z", z, nets.cfg.feature_size, "feature_size")
    return nets.projection.apply({"params": params["target_projection" if target else "projection"]}, z)


def predict(nets: SPRNetworks, params: Params, y):
    """h(y) (B, q_hidden_size)."""
    common.check_last("y", y, nets.cfg.q_hidden_size, "q_hidden_size")
    return nets.prediction.apply({"params": params["prediction"]}, y)


# ------------------------------------------------------------------------------------------ losses
def spr_loss(nets: SPRNetworks, params: Params, batch: Batch, next_action, obs_noise, next_obs_noise):
    """SPR's K = 1 self-prediction loss, trained on the encoder f, the projection g and the prediction h.

    With σ = `augmentation_std`:
        s̃ = normalize(s) + σξ,  s̃′ = normalize(s′) + σξ′,  p = h(g(f(s̃, a))),  t = sg(ḡ(f̄(s̃′, ā′)))
        spr_loss = mean_b m_b ‖p/‖p‖ − t/‖t‖‖²  (= 2 − 2 cos(p, t) per sample)

    Args:
      nets: the `SPRNetworks`.
      params: the parameters (`init_params`).
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
    p = common.trainable(params, ("encoder", "projection", "prediction"))
    z = features(nets, p, batch.obs, batch.action, obs_noise=obs_noise)
    pred = common.l2_normalize(predict(nets, p, project(nets, p, z)))
    z_next = features(nets, p, batch.next_obs, sg(next_action), target=True, obs_noise=next_obs_noise)
    tgt = sg(common.l2_normalize(project(nets, p, z_next, target=True)))
    mask = 1 - batch.truncation
    loss = jnp.mean(mask * jnp.sum((pred - tgt) ** 2, axis=-1))
    return loss, {"spr_cosine": jnp.mean(mask * jnp.sum(sg(pred) * tgt, axis=-1))}
