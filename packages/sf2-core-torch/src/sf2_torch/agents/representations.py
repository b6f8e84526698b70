"""Pluggable representations: what the critic sees, and the representation's own loss step.

The torch mirror of `sf2_jax.agents.representations` (same names, registry, class attributes and
meaning; the methods hold state in modules instead of taking `params`). A representation is the part of
an agent between the raw (s, a) and the twin Q values:

- `critic_loss(algo, obs_norm)` → the TorchRL `LossModule` of the base algorithm on its critic (TD3 or
  SAC: `forward(td)` → `loss_qvalue`, `loss_actor`, [`loss_alpha`], `pred_value`, ...). It owns the Q heads
  and their targets (`target_qvalue_network_params`) and, for TD3, the target policy.
- `groups(critic_loss)` → {group name: parameters} of the groups it trains: always `q` (the Q heads,
  whose input is its features); SF² adds `psi` and `zeta`. The base algorithm adds `policy` and
  `log_alpha`. Each group has one Adam state (ψ keeps one across the critic and the flow steps).
- `critic_groups`: groups besides `q` that the critic (TD) loss trains (SF²: ψ, the authors'
  `back_critic_grad=True`).
- `aux_groups`, `aux_loss` (a `LossModule` whose `forward` returns `loss_<aux_loss_name>`), `aux_noise`:
  its own loss, one Adam step on `aux_groups` right after the critic step of every SGD step (SF²: the
  flow loss on ψ and ζ, `objectives.SF2FlowLoss`). `aux_noise(n, generator)` is the thin wrapper that
  draws the loss's random inputs, a dict keyed by `noise_keys` (SF²: `flow_noise` ε, `flow_time` t;
  the names sf2_jax's `aux_noise` uses too); the loss is pure. The next action ā′ is given by the base
  algorithm (TD3: target policy at s′; SAC: a policy sample) under the loss's `next_action` key.
- `aux_every` ({group: period}, default {}): groups of `aux_groups` that the aux step updates only on
  gradient steps `step % period == 0` (Sim/SimLap's task vector w: every 10 TD3 / 16 SAC steps, the
  authors' `gradient_steps % 10 == 0` cond). On the other steps the base algorithm does not step that
  group's Adam, so its parameters and whole Adam state (moments and step count) stay unchanged, as the
  authors' separate w optimizer, which only steps when it is used (as in sf2_jax).
- `target_updater` → a TorchRL `SoftUpdate` of the targets it owns other than Q̄, applied every SGD step
  (SF²: ψ̄ at τ and ζ̄ at τ_ζ), or None.
- `canonical(critic_loss)` → its groups in the canonical naming of `sf2_torch.params` (for `final/`).

The base algorithms (algorithms.py) are written once against this interface. Baselines plug in by
subclassing `Representation` and calling `register`.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import torch
from sf2_common.agents.registry import Registry
from tensordict.nn import TensorDictModule
from torch import nn

from sf2_torch import params as params_mod
from sf2_torch.config import SF2Config
from sf2_torch.networks import SF2Networks

from . import objectives

__all__ = ["Representation", "NoRepresentation", "SF2Representation", "register", "get", "names", "REGISTRY"]


class Representation:
    """Base class (see the module docstring). Subclasses set the class attributes and override the
    methods; the defaults describe a representation with no loss of its own."""

    name: ClassVar[str] = ""
    label: ClassVar[str] = ""                  # shown in tables and plots, e.g. "SF²"
    supported_algos: ClassVar[tuple[str, ...]] = ("td3", "sac")
    critic_groups: ClassVar[tuple[str, ...]] = ()
    aux_groups: ClassVar[tuple[str, ...]] = ()
    aux_loss_name: ClassVar[str] = "aux_loss"   # the metric's name (as in sf2_jax)
    aux_loss_key: ClassVar[str] = "loss_aux"    # the aux loss module's output entry
    noise_keys: ClassVar[tuple[str, ...]] = ()     # the entries of `aux_noise`
    aux_every: ClassVar[dict[str, int]] = {}       # {aux group: period in gradient steps}

    def __init__(self, cfg: SF2Config, nets: SF2Networks):
        self.cfg = cfg
        self.nets = nets
        self.aux_loss: nn.Module | None = None
        self.target_updater = None

    def critic_loss(self, algo: str):
        raise NotImplementedError

    def groups(self, critic_loss) -> dict[str, list[torch.Tensor]]:
        raise NotImplementedError

    def aux_noise(self, n: tuple[int, ...], generator: torch.Generator) -> dict[str, torch.Tensor]:
        return {}

    def canonical(self, critic_loss) -> dict[str, np.ndarray]:
        raise NotImplementedError


# Selectable by `--repr NAME`: the classes `register`ed in this process (`none`, `sf2`, tests' and the
# bench's variants) and the entry points of "sf2.representations.torch" (sf2-baselines: sim, simlap,
# simlap_authors, spr), imported on first use. `get` of an unknown name: a ConfigError listing the names.
REGISTRY = Registry("torch")
register, names, get = REGISTRY.register, REGISTRY.names, REGISTRY.get


# ------------------------------------------------------------------------------------------- none
class _SACLocScale(nn.Module):
    """The core SAC policy as TorchRL's actor expects it: normalized obs → (loc, scale)."""

    def __init__(self, policy: nn.Module):
        super().__init__()
        self.policy = policy

    def forward(self, obs_normalized):
        return self.policy(obs_normalized)


@register
class NoRepresentation(Representation):
    """`none`: vanilla TD3/SAC with TorchRL's own `TD3Loss`/`SACLoss` (objectives.VanillaTD3Loss,
    VanillaSACLoss: squared error, the JAX trainer's reduction), the critic on (s, a) directly: two
    `VanillaQHead`s (LayerNorm MLPs on concat[s̄, a]); no loss of its own."""

    name = "none"
    label = ""

    def critic_loss(self, algo: str):
        from tensordict.nn import ProbabilisticTensorDictModule, ProbabilisticTensorDictSequential

        cfg, nets = self.cfg, self.nets
        p = next(nets.policy.parameters())
        kw = dict(dtype=p.dtype, device=p.device)
        heads = [TensorDictModule(objectives.VanillaQHead(cfg, **kw), in_keys=["observation", "action"],
                                  out_keys=["state_action_value"]) for _ in range(2)]
        if algo == "td3":
            actor = TensorDictModule(nets.policy, in_keys=["observation"], out_keys=["action"])
            return objectives.VanillaTD3Loss(actor, heads, cfg, nets.obs_norm)
        loc_scale = TensorDictModule(_SACLocScale(nets.policy), in_keys=["observation"],
                                     out_keys=["loc", "scale"])
        actor = ProbabilisticTensorDictSequential(
            loc_scale,
            ProbabilisticTensorDictModule(in_keys=["loc", "scale"], out_keys=["action"],
                                          distribution_class=objectives.TanhGaussian,
                                          return_log_prob=True))
        return objectives.VanillaSACLoss(actor, heads, cfg, nets.obs_norm)

    def groups(self, critic_loss):
        return {"q": list(critic_loss.qvalue_network_params.values(True, True))}

    def canonical(self, critic_loss):
        out = {}
        for prefix, stacked in (("q", critic_loss.qvalue_network_params),
                                ("target_q", critic_loss.target_qvalue_network_params)):
            for j in range(2):
                out.update(_canonical_td(f"{prefix}.head_{j}", stacked[j]))
        flat = params_mod.to_canonical(self.nets)
        out.update({k: v for k, v in flat.items() if k.startswith(("obs_norm.", "policy."))})
        if self.nets.algo == "td3":
            out.update(_canonical_td("target_policy", critic_loss.target_actor_network_params))
        else:
            out["log_alpha"] = critic_loss.log_alpha.detach().cpu().numpy().copy()
        return out


def _canonical_td(prefix: str, params) -> dict[str, np.ndarray]:
    """Canonical names of a TorchRL parameter tensordict of one MLP (keys like ("module", "mlp",
    "dense_0", "weight")): kernels (in, out), LayerNorm `weight` → `scale`."""
    out = {}
    for key, value in params.items(True, True):
        layer, leaf = key[-2], key[-1]
        arr = value.detach().cpu().numpy()
        if leaf == "weight" and layer.startswith("dense"):
            out[f"{prefix}.{layer}.kernel"] = np.ascontiguousarray(arr.T)
        elif leaf == "weight":
            out[f"{prefix}.{layer}.scale"] = arr.copy()
        else:
            out[f"{prefix}.{layer}.{leaf}"] = arr.copy()
    return out


# ------------------------------------------------------------------------------------------- sf2
@register
class SF2Representation(Representation):
    """`sf2`: the critic on ψ(s, a) (twin Q heads of the core), ψ also trained by the TD loss; the flow
    step trains (ψ, ζ) on `objectives.SF2FlowLoss` (eq. 3–4, Algorithm 1); targets ψ̄ (τ) and ζ̄ (τ_ζ)
    averaged every step by `objectives.SF2SoftUpdate`."""

    name = "sf2"
    label = "SF²"
    critic_groups = ("psi",)
    aux_groups = ("psi", "zeta")
    aux_loss_name = "flow_loss"
    aux_loss_key = "loss_flow"
    noise_keys = ("flow_noise", "flow_time")

    def __init__(self, cfg: SF2Config, nets: SF2Networks):
        super().__init__(cfg, nets)
        self.aux_loss = objectives.SF2FlowLoss(nets)
        self.target_updater = objectives.SF2SoftUpdate(self.aux_loss, tau=cfg.tau,
                                                        taus={"zeta_network": cfg.tau_zeta})

    def critic_loss(self, algo: str):
        return objectives.TD3SF2Loss(self.nets) if algo == "td3" else objectives.SACSF2Loss(self.nets)

    def groups(self, critic_loss):
        nets = self.nets
        return {"q": list(nets.q.parameters()), "psi": list(nets.psi.parameters()),
                "zeta": list(nets.zeta.parameters())}

    def aux_noise(self, n, generator):
        p = next(self.nets.psi.parameters())
        kw = dict(dtype=p.dtype, device=p.device, generator=generator)
        return {"flow_noise": torch.randn(*n, self.cfg.obs_size, **kw), "flow_time": torch.rand(*n, **kw)}

    def canonical(self, critic_loss):
        return params_mod.to_canonical(self.nets)
