"""Pluggable representations: what the critic sees, and the representation's own loss.

A representation is the part of an agent between the raw (s, a) and the twin Q values. The vocabulary
is the same in sf2_torch.agents.representations (table: docs/core-contract.md "Agents: the plug-in
vocabulary"); JAX methods are pure and take `params` (and a PRNG `key` where torch takes a generator).

Class attributes:
- `name`, `label` (tables and plots, e.g. "SF²"), `supported_algos`;
- `critic_groups`: groups besides `q` that the critic (TD) loss trains (SF²: ψ, the authors'
  `back_critic_grad=True`);
- `aux_groups`, `aux_loss_name`: the groups its own loss trains, one Adam step right after the critic
  step of every SGD step (SF²: the flow loss `flow_loss` on ψ and ζ);
- `noise_keys`: the entries of `aux_noise` (SF²: `flow_noise` ε and `flow_time` k, eq. 3); the names are
  the torch agents' too, so one draw feeds both frameworks;
- `aux_every` ({group: period}, default {}): groups of `aux_groups` that the aux step updates only on
  gradient steps `step % period == 0` (Sim/SimLap's task vector w: every 10 TD3 / 16 SAC steps, the
  authors' `gradient_steps % 10 == 0` cond). On the other steps the base algorithm leaves that group's
  parameters *and* its whole Adam state (moments and step count) unchanged, as the authors' separate w
  optimizer, which only steps when it is used: Adam's bias correction counts w's own updates.

Methods:
- `__init__(cfg, nets)`: `nets` are the core `Networks` of the algorithm (policy, SF² networks);
- `init(key, core_params)` → {group: params}: the groups it owns. It always owns the Q heads
  `q`/`target_q` (their input is its features); SF² adds ψ, ζ and their targets. `core_params` are the
  groups `sf2_jax.networks.init_params` made, so a representation that reuses core networks takes them;
- `critic(params, obs, action, target=False)` → (B, 2): twin Q on its features (online or target);
- `aux_noise(key, batch)` → {noise key: array}: the random inputs of its loss, shapes from
  `batch.obs.shape[:-1]` (any leading dims); the loss is pure;
- `aux_loss(params, batch, next_action, noise)` → (loss, aux dict): its own loss; `next_action` ā′ is
  given by the base algorithm (TD3: target policy at s′; SAC: a policy sample);
- `targets()` → {target group: (online group, τ)}: the EMA targets it owns besides `target_q`; the base
  algorithm applies them every step (`losses.ema_update`) and moves `target_q` on its own schedule.

The base algorithms (algorithms.py) are written once against this interface; the trainer never looks
inside a representation. Baselines (Sim, SimLap, SPR) plug in by subclassing `Representation` and
calling `register`. Every group a representation returns is saved, restored and trained by name.
"""

from __future__ import annotations

from typing import Any, ClassVar

import flax.linen as nn
import jax
import jax.numpy as jnp
from sf2_common.agents.registry import Registry
from sf2_common.config import SF2Config

from sf2_jax import losses, networks

__all__ = ["Representation", "NoRepresentation", "SF2Representation", "VanillaQ", "register", "get",
           "names", "REGISTRY"]

Params = dict[str, Any]


class Representation:
    """Base class (see the module docstring). Subclasses set the class attributes and override the
    methods; the defaults describe a representation with no loss of its own."""

    name: ClassVar[str] = ""
    label: ClassVar[str] = ""                  # shown in tables and plots, e.g. "SF²"
    supported_algos: ClassVar[tuple[str, ...]] = ("td3", "sac")
    critic_groups: ClassVar[tuple[str, ...]] = ()
    aux_groups: ClassVar[tuple[str, ...]] = ()
    aux_loss_name: ClassVar[str] = "aux_loss"
    noise_keys: ClassVar[tuple[str, ...]] = ()     # the entries of `aux_noise`
    aux_every: ClassVar[dict[str, int]] = {}       # {aux group: period in gradient steps}

    def __init__(self, cfg: SF2Config, nets: networks.Networks):
        self.cfg = cfg
        self.nets = nets

    def init(self, key: jax.Array, core_params: Params) -> Params:
        raise NotImplementedError

    def critic(self, params: Params, obs, action, target: bool = False):
        raise NotImplementedError

    def aux_noise(self, key: jax.Array, batch: losses.Batch) -> dict[str, jax.Array]:
        return {}

    def aux_loss(self, params: Params, batch: losses.Batch, next_action, noise):
        raise NotImplementedError(f"representation {self.name!r} has no loss of its own")

    def targets(self) -> dict[str, tuple[str, float]]:
        return {}


# Selectable by `--repr NAME`: the classes `register`ed in this process (`none`, `sf2`, tests' and the
# bench's variants) and the entry points of "sf2.representations.jax" (sf2-baselines: sim, simlap,
# simlap_authors, spr), imported on first use. `get` of an unknown name: a ConfigError listing the names.
REGISTRY = Registry("jax")
register, names, get = REGISTRY.register, REGISTRY.names, REGISTRY.get


# ------------------------------------------------------------------------------------------- none
class VanillaQ(nn.Module):
    """Twin Q(s, a): two heads `head_0`, `head_1`, each the core `MLP(hidden_sizes → 1)` with LayerNorm,
    on concat[normalize(s), a] (Brax's Q network with `q_network_layer_norm=True`, as the authors ran
    vanilla TD3 and SAC)."""

    hidden_sizes: tuple[int, ...]
    layer_norm: bool = True

    def setup(self):
        self.head_0 = networks.MLP(self.hidden_sizes, 1, use_layer_norm=self.layer_norm)
        self.head_1 = networks.MLP(self.hidden_sizes, 1, use_layer_norm=self.layer_norm)

    def __call__(self, x):
        return jnp.concatenate([self.head_0(x), self.head_1(x)], axis=-1)


@register
class NoRepresentation(Representation):
    """`none`: vanilla TD3/SAC, the critic on (s, a) directly; no loss of its own."""

    name = "none"
    label = ""

    def __init__(self, cfg: SF2Config, nets: networks.Networks):
        super().__init__(cfg, nets)
        self.q_net = VanillaQ(cfg.hidden_sizes, cfg.layer_norm)

    def init(self, key, core_params):
        dtype = core_params["obs_norm"]["mean"].dtype
        x = jnp.zeros((1, self.cfg.obs_size + self.cfg.action_size), jnp.float32)
        q = jax.tree_util.tree_map(lambda v: v.astype(dtype), self.q_net.init(key, x)["params"])
        return {"q": q, "target_q": jax.tree_util.tree_map(jnp.copy, q)}

    def critic(self, params, obs, action, target=False):
        x = jnp.concatenate([networks.normalize(obs, params["obs_norm"]), action], axis=-1)
        return self.q_net.apply({"params": params["target_q" if target else "q"]}, x)


# ------------------------------------------------------------------------------------------- sf2
@register
class SF2Representation(Representation):
    """`sf2`: the critic on ψ(s, a) (twin Q heads of the core), ψ also trained by the TD loss; the flow
    step trains (ψ, ζ) on `sf2_jax.losses.flow_loss` (eq. 3–4, Algorithm 1); targets ψ̄ (τ) and ζ̄ (τ_ζ)."""

    name = "sf2"
    label = "SF²"
    critic_groups = ("psi",)
    aux_groups = ("psi", "zeta")
    aux_loss_name = "flow_loss"
    noise_keys = ("flow_noise", "flow_time")

    def init(self, key, core_params):
        del key  # the core already initialised ψ, ζ and the Q heads
        names_ = ("psi", "zeta", "q", "target_psi", "target_zeta", "target_q")
        return {n: core_params[n] for n in names_}

    def critic(self, params, obs, action, target=False):
        return losses.sf2_critic(self.nets)(params, obs, action, target)

    def aux_noise(self, key, batch):
        k_eps, k_time = jax.random.split(key)
        obs = batch.obs
        eps = jax.random.normal(k_eps, obs.shape, obs.dtype)
        flow_time = jax.random.uniform(k_time, obs.shape[:-1], obs.dtype)
        return {"flow_noise": eps, "flow_time": flow_time}

    def aux_loss(self, params, batch, next_action, noise):
        return losses.flow_loss(self.nets, params, batch, next_action, noise["flow_noise"],
                                noise["flow_time"])

    def targets(self):
        return {"target_psi": ("psi", self.cfg.tau), "target_zeta": ("zeta", self.cfg.tau_zeta)}
