"""Sim (JAX): successor features learned "the simple way" (Chua et al., 2024) for TD3 and SAC (TD3Sim,
SACSim; paper §4.2). Networks, equations and every deviation from the authors' code: README.md "Sim".

Parameter groups (canonical names as docs/params.md): ``phi``/``target_phi``, basis features
φ(s, a, ŵ) = MLP(hidden_sizes → F) on concat[normalize(s), a, ŵ], ŵ = sg(w)/(‖w‖ + 1e-8);
``q``/``target_q``, twin successor-feature heads ψ_j(φ) = Dense(F → q_hidden_size) → ReLU → Dense(→ F);
``task``, the task vector ``task.w`` (F,) ~ N(0, 1), one parameter, never stored in the replay (the
authors' code stores it per insert with the wrong shape, which breaks F = 512).

Q_j(s, a) = wᵀψ_j(φ(s, a, ŵ)), the target critic Q̄_j = wᵀψ̄_j(φ̄(s′, ã′, ŵ)). The TD loss trains ψ_j
and φ; `reward_loss` trains w only, every `REWARD_EVERY[algo]` gradient steps.
"""

from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct
from sf2_common.config import SF2Config
from sf2_jax import networks as core_nw
from sf2_jax.losses import Batch

from . import common

__all__ = [
    "GROUPS",
    "REWARD_EVERY",
    "SFHeads",
    "SimNetworks",
    "make_networks",
    "init_representation",
    "init_params",
    "task_vector",
    "features",
    "successor_features",
    "critic",
    "reward_loss",
]

sg = jax.lax.stop_gradient
Params = dict[str, Any]

# The groups this representation owns (online, task vector, targets).
GROUPS = ("phi", "q", "task", "target_phi", "target_q")
# Gradient steps between two reward-prediction (task-vector) steps, per base algorithm: the authors'
# TD3Sim and SACSim code (Chua et al. also update w on its own, slower schedule).
REWARD_EVERY = {"td3": 10, "sac": 16}


class SFHeads(nn.Module):
    """Twin successor-feature heads `head_0`, `head_1`: the core `MLP((hidden,), F)` without LayerNorm.

    Attributes:
      hidden_size: q_hidden_size.
      feature_size: F.

    `__call__(φ)` → (..., 2, F).
    """

    hidden_size: int
    feature_size: int

    def setup(self):
        self.head_0 = core_nw.MLP((self.hidden_size,), self.feature_size, use_layer_norm=False)
        self.head_1 = core_nw.MLP((self.hidden_size,), self.feature_size, use_layer_norm=False)

    def __call__(self, phi):
        return jnp.stack([self.head_0(phi), self.head_1(phi)], axis=-2)


@struct.dataclass
class SimNetworks:
    """The networks of a Sim agent, without parameters (hashable; `init_params` makes them).

    Attributes:
      cfg: the `SF2Config`.
      algo: "td3" or "sac".
      core: the core `Networks` (the policy and the observation statistics).
      phi: φ, the core `MLP(hidden_sizes → F)` on [normalize(s), a, ŵ].
      q: the `SFHeads`.
    """

    cfg: SF2Config = struct.field(pytree_node=False)
    algo: str = struct.field(pytree_node=False)
    core: core_nw.Networks = struct.field(pytree_node=False)
    phi: core_nw.MLP = struct.field(pytree_node=False)
    q: SFHeads = struct.field(pytree_node=False)


def make_networks(cfg: SF2Config, algo: str) -> SimNetworks:
    """φ: MLP(hidden_sizes → F) on D + A + F inputs; SF heads (q_hidden_size → F); the core's policy."""
    core = core_nw.make_networks(cfg, algo)  # validates cfg and algo
    return SimNetworks(
        cfg=cfg,
        algo=algo,
        core=core,
        phi=core_nw.MLP(cfg.hidden_sizes, cfg.feature_size, use_layer_norm=cfg.layer_norm),
        q=SFHeads(cfg.q_hidden_size, cfg.feature_size),
    )


def _dtype(dtype):
    return jnp.dtype(jnp.result_type(float) if dtype is None else dtype)


def init_representation(nets: SimNetworks, key: jax.Array, dtype=None) -> Params:
    """The Sim groups: `phi`, `q`, `task` ({"w": (F,)} ~ N(0, 1)), and targets copied from the online."""
    cfg = nets.cfg
    dtype = _dtype(dtype)
    D, A, F = cfg.obs_size, cfg.action_size, cfg.feature_size
    k_phi, k_q, k_task = jax.random.split(key, 3)
    f32 = jnp.float32
    online = {
        "phi": nets.phi.init(k_phi, jnp.zeros((1, D + A + F), f32))["params"],
        "q": nets.q.init(k_q, jnp.zeros((1, F), f32))["params"],
        "task": {"w": jax.random.normal(k_task, (F,), f32)},
    }
    online = common.cast_tree(online, dtype)
    return {
        **online,
        "target_phi": common.copy_tree(online["phi"]),
        "target_q": common.copy_tree(online["q"]),
    }


def init_params(nets: SimNetworks, key: jax.Array, dtype=None) -> Params:
    """Every group of a Sim agent: the core's `obs_norm`, `policy`, `target_policy` (TD3) or
    `log_alpha` (SAC), plus `init_representation`'s groups."""
    k_core, k_rep = jax.random.split(key)
    core = core_nw.init_params(nets.core, k_core, dtype=_dtype(dtype))
    params = {n: core[n] for n in ("obs_norm", "policy", "target_policy", "log_alpha") if n in core}
    return {**params, **init_representation(nets, k_rep, dtype)}


# ------------------------------------------------------------------------------------------ networks
def task_vector(params: Params):
    """w (F,)."""
    return params["task"]["w"]


def _task_input(params: Params, batch_shape):
    """ŵ = sg(w) / (‖w‖ + 1e-8), broadcast to (*batch_shape, F): φ's task input. The gradient of every
    loss into w goes through Q = wᵀψ or the reward prediction only (Chua et al.; authors' code)."""
    w_hat = common.l2_normalize(sg(task_vector(params)))
    return jnp.broadcast_to(w_hat, (*batch_shape, w_hat.shape[-1]))


def features(nets: SimNetworks, params: Params, obs, action, target: bool = False):
    """Basis features φ(s, a, ŵ) (B, F) on concat[normalize(s), a, ŵ]; `target` uses φ̄."""
    cfg = nets.cfg
    common.check_last("obs", obs, cfg.obs_size, "obs_size")
    common.check_last("action", action, cfg.action_size, "action_size")
    x = core_nw.normalize(obs, params["obs_norm"])
    x = jnp.concatenate([x, action, _task_input(params, x.shape[:-1]).astype(x.dtype)], axis=-1)
    return nets.phi.apply({"params": params["target_phi" if target else "phi"]}, x)


def successor_features(nets: SimNetworks, params: Params, phi, target: bool = False):
    """ψ_j(φ) (B, 2, F) of the twin heads; `target` uses ψ̄."""
    common.check_last("phi", phi, nets.cfg.feature_size, "feature_size")
    return nets.q.apply({"params": params["target_q" if target else "q"]}, phi)


def critic(nets: SimNetworks, params: Params, obs, action, target: bool = False):
    """Q_j(s, a) = wᵀψ_j(φ(s, a, ŵ)) (B, 2); `target` uses φ̄ and ψ̄ (w is the current task vector)."""
    psi = successor_features(nets, params, features(nets, params, obs, action, target), target)
    return jnp.einsum("...jf,f->...j", psi, task_vector(params))


# ------------------------------------------------------------------------------------------ losses
def reward_loss(nets: SimNetworks, params: Params, batch: Batch, next_action):
    """Sim's reward prediction (Chua et al. 2024; the authors' `task_loss`), trained on w only.

    loss = mean_b m_b (wᵀφ(s′, ā′, ŵ) − rs·r)².

    Args:
      nets: the `SimNetworks`.
      params: the parameters (`init_params`).
      batch: the transitions.
      next_action: ā′ (B, A) from the base algorithm (TD3: the target policy at s′; SAC: a policy sample);
        gets no gradient.

    Returns:
      (loss, {"predicted_reward_rms": √mean_b (wᵀφ′)²}).

    Raises:
      ShapeError: a field of `batch` or `next_action` of another shape.
    """
    cfg = nets.cfg
    b = common.check_batch(cfg, batch)
    common.check_noise("next_action", next_action, b, cfg.action_size, "action_size")
    p = common.trainable(params, ("task",))
    phi_next = features(nets, p, batch.next_obs, sg(next_action))
    pred = phi_next @ task_vector(p)
    err = pred - cfg.reward_scaling * batch.reward
    loss = jnp.mean((1 - batch.truncation) * err**2)
    return loss, {"predicted_reward_rms": jnp.sqrt(jnp.mean(sg(pred) ** 2))}
