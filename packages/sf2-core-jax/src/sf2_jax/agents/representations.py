"""Pluggable representations: what the critic sees, and the representation's own loss.

`Representation` is the interface the base algorithms (algorithms.py) are written against; the trainer
never looks inside one, and every group it returns is saved, restored and trained by name. `none`
(vanilla TD3/SAC, `NoRepresentation`) and `sf2` (`SF2Representation`) are here; the baselines (Sim,
SimLap, SPR) subclass `Representation` in sf2-baselines. `register`, `get`, `names` and `REGISTRY` select
one by name (`--repr NAME`). The vocabulary is sf2_torch.agents.representations' (docs/core-contract.md
"Agents: the plug-in vocabulary"); JAX methods are pure and take `params` first and a PRNG `key` where
torch takes a generator.
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
    """The part of an agent between the raw (s, a) and the twin Q values, and its own loss.

    Subclasses set the class attributes and override the methods; the defaults describe a representation
    with no loss of its own.

    Attributes:
      name: selects it (`--repr NAME`, `register`).
      label: shown in tables and plots, e.g. "SF²".
      supported_algos: the algorithms it works with.
      critic_groups: groups besides `q` that the critic (TD) loss trains (SF²: ψ, the authors'
        `back_critic_grad=True`).
      aux_groups: the groups its own loss trains, one Adam step right after the critic step of every SGD
        step (SF²: ψ and ζ).
      aux_loss_name: its loss's metric name (SF²: "flow_loss").
      noise_keys: the entries of `aux_noise` (SF²: `flow_noise` ε and `flow_time` k, eq. 3); one draw
        feeds both frameworks.
      aux_every: {aux group: period}: groups the aux step updates only on gradient steps `step % period
        == 0` (Sim's task vector w, as the authors' separate optimizer); on the other steps the group's
        parameters and whole Adam state (moments and step count) stay unchanged.
    """

    name: ClassVar[str] = ""
    label: ClassVar[str] = ""                  # shown in tables and plots, e.g. "SF²"
    supported_algos: ClassVar[tuple[str, ...]] = ("td3", "sac")
    critic_groups: ClassVar[tuple[str, ...]] = ()
    aux_groups: ClassVar[tuple[str, ...]] = ()
    aux_loss_name: ClassVar[str] = "aux_loss"
    noise_keys: ClassVar[tuple[str, ...]] = ()     # the entries of `aux_noise`
    aux_every: ClassVar[dict[str, int]] = {}       # {aux group: period in gradient steps}

    def __init__(self, cfg: SF2Config, nets: networks.Networks):
        """Keep the config and the algorithm's networks.

        Args:
          cfg: the algorithm's `SF2Config`.
          nets: the core `Networks` of the algorithm (the policy; SF²'s networks).
        """
        self.cfg = cfg
        self.nets = nets

    def init(self, key: jax.Array, core_params: Params) -> Params:
        """Initialise the groups it owns: always the Q heads `q`, `target_q` (their input is its features).

        Args:
          key: a PRNG key.
          core_params: the groups `sf2_jax.networks.init_params` made (a representation that reuses core
            networks takes them).

        Returns:
          {group: params}.
        """
        raise NotImplementedError

    def critic(self, params: Params, obs, action, target: bool = False):
        """Twin Q on its features.

        Args:
          params: the agent's parameters.
          obs: (B, D) raw observations.
          action: (B, A).
          target: the target networks instead of the online ones.

        Returns:
          (B, 2).
        """
        raise NotImplementedError

    def aux_noise(self, key: jax.Array, batch: losses.Batch) -> dict[str, jax.Array]:
        """Draw the random inputs of its loss.

        Args:
          key: a PRNG key.
          batch: the SGD step's batch (shapes from `batch.obs.shape[:-1]`, any leading dimensions).

        Returns:
          {noise key: array}, keyed by `noise_keys`.
        """
        return {}

    def aux_loss(self, params: Params, batch: losses.Batch, next_action, noise):
        """Its own loss, pure given the noise.

        Args:
          params: the agent's parameters.
          batch: the SGD step's batch.
          next_action: ā′ (B, A), from the base algorithm (TD3: the target policy at s′; SAC: a sample).
          noise: `aux_noise`'s draw.

        Returns:
          (loss, {metric: scalar}).

        Raises:
          NotImplementedError: it has no loss of its own.
        """
        raise NotImplementedError(f"representation {self.name!r} has no loss of its own")

    def targets(self) -> dict[str, tuple[str, float]]:
        """The EMA targets it owns besides `target_q`, which the base algorithm moves every step.

        Returns:
          {target group: (online group, τ)}.
        """
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
