"""Pluggable representations: what the critic sees, and the representation's own loss.

`Representation` is the interface the base algorithms (algorithms.py) are written against; the trainer
never looks inside one, and every group it returns is saved, restored and trained by name. `none`
(vanilla TD3/SAC, `NoRepresentation`) and `sf2` (`SF2Representation`) are here; the baselines (Sim,
SimLap, SPR) subclass `Representation` in sf2-baselines. `register`, `get`, `names` and `REGISTRY` select
one by name (`--repr NAME`). The vocabulary is the JAX agents' (docs/core-contract.md
"Agents: the plug-in vocabulary"); torch methods act on the modules the representation holds and take a
`torch.Generator` where JAX takes a PRNG key.
"""

from __future__ import annotations

from typing import ClassVar

import torch
from sf2_common.agents.registry import Registry
from sf2_common.config import SF2Config
from torch import nn

from sf2_torch import losses, networks

__all__ = ["Representation", "NoRepresentation", "SF2Representation", "VanillaQ", "register", "get",
           "names", "REGISTRY"]


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

    def init(self, core: networks.Networks) -> dict[str, nn.Module]:
        """Build the groups it owns: always the Q heads `q`, `target_q` (their input is its features).

        Args:
          core: the algorithm's `sf2_torch.networks.Networks` (a representation that reuses core networks
            takes them); new modules are initialised from torch's global generator, which the trainer seeds.

        Returns:
          {group: nn.Module}.
        """
        raise NotImplementedError

    def critic(self, obs: torch.Tensor, action: torch.Tensor, target: bool = False) -> torch.Tensor:
        """Twin Q on its features.

        Args:
          obs: (B, D) raw observations.
          action: (B, A).
          target: the target networks instead of the online ones.

        Returns:
          (B, 2).
        """
        raise NotImplementedError

    def aux_noise(self, generator: torch.Generator, batch: losses.Batch) -> dict[str, torch.Tensor]:
        """Draw the random inputs of its loss.

        Args:
          generator: the seed's `torch.Generator`.
          batch: the SGD step's batch (shapes from `batch.obs.shape[:-1]`, any leading dimensions).

        Returns:
          {noise key: tensor}, keyed by `noise_keys`.
        """
        return {}

    def aux_loss(self, batch: losses.Batch, next_action: torch.Tensor, noise: dict[str, torch.Tensor]):
        """Its own loss, pure given the noise.

        Args:
          batch: the SGD step's batch.
          next_action: ā′ (B, A), from the base algorithm (TD3: the target policy at s′; SAC: a sample).
          noise: `aux_noise`'s draw.

        Returns:
          (loss, {metric: 0-d tensor}).

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
# bench's variants) and the entry points of "sf2.representations.torch" (sf2-baselines: sim, simlap,
# simlap_authors, spr), imported on first use. `get` of an unknown name: a ConfigError listing the names.
REGISTRY = Registry("torch")
register, names, get = REGISTRY.register, REGISTRY.names, REGISTRY.get


def _frozen_copy(module: nn.Module) -> nn.Module:
    import copy

    return copy.deepcopy(module).requires_grad_(False)


# ------------------------------------------------------------------------------------------- none
class VanillaQ(nn.Module):
    """Twin Q(s, a): two heads `head_0`, `head_1`, each the core `MLP(hidden_sizes → 1)` with LayerNorm,
    on concat[normalize(s), a] (Brax's Q network with `q_network_layer_norm=True`, as the authors ran
    vanilla TD3 and SAC); `forward` evaluates both as one program (`networks.twin_heads`)."""

    def __init__(self, cfg: SF2Config, **kw):
        super().__init__()
        n_in = cfg.obs_size + cfg.action_size
        self.head_0 = networks.MLP(n_in, cfg.hidden_sizes, 1, cfg.layer_norm, **kw)
        self.head_1 = networks.MLP(n_in, cfg.hidden_sizes, 1, cfg.layer_norm, **kw)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return networks.twin_heads(self.head_0, self.head_1, x)


@register
class NoRepresentation(Representation):
    """`none`: vanilla TD3/SAC, the critic on (s, a) directly; no loss of its own."""

    name = "none"
    label = ""

    def init(self, core):
        p = core.obs_norm.mean
        self.q = VanillaQ(self.cfg, dtype=p.dtype, device=p.device)
        self.target_q = _frozen_copy(self.q)
        return {"q": self.q, "target_q": self.target_q}

    def critic(self, obs, action, target=False):
        x = torch.cat([networks.normalize(obs, self.nets.obs_norm), action], dim=-1)
        return (self.target_q if target else self.q)(x)


# ------------------------------------------------------------------------------------------- sf2
@register
class SF2Representation(Representation):
    """`sf2`: the critic on ψ(s, a) (twin Q heads of the core), ψ also trained by the TD loss; the flow
    step trains (ψ, ζ) on `sf2_torch.losses.flow_loss` (eq. 3–4, Algorithm 1); targets ψ̄ (τ) and ζ̄ (τ_ζ)."""

    name = "sf2"
    label = "SF²"
    critic_groups = ("psi",)
    aux_groups = ("psi", "zeta")
    aux_loss_name = "flow_loss"
    noise_keys = ("flow_noise", "flow_time")

    def init(self, core):
        # the core already initialised ψ, ζ and the Q heads
        names_ = ("psi", "zeta", "q", "target_psi", "target_zeta", "target_q")
        return {n: getattr(core, n) for n in names_}

    def critic(self, obs, action, target=False):
        return losses.sf2_critic(self.nets)(obs, action, target)

    def aux_noise(self, generator, batch):
        obs = batch.obs
        kw = dict(dtype=obs.dtype, device=obs.device, generator=generator)
        return {"flow_noise": torch.randn(obs.shape, **kw), "flow_time": torch.rand(obs.shape[:-1], **kw)}

    def aux_loss(self, batch, next_action, noise):
        return losses.flow_loss(self.nets, batch, next_action, noise["flow_noise"], noise["flow_time"])

    def targets(self):
        return {"target_psi": ("psi", self.cfg.tau), "target_zeta": ("zeta", self.cfg.tau_zeta)}
