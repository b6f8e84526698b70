"""The baselines as pluggable representations of `sf2_torch.agents` (TD3 and SAC, `--repr NAME`).

The torch mirror of `sf2_baselines.jax.representations` on the torch agents' interface
(`sf2_torch.agents.representations.Representation`): the critic loss and the representation's own loss
are TorchRL `LossModule`s whose numbers come from the baselines' pure losses (`sim`, `simlap`, `spr`,
proven equal to JAX by tests/test_baselines_cross.py). Each representation builds its networks with
`make_networks(..., core=agent_nets)`, so the normalizer, the policy, its target and log α are the
agent's own modules.

==================  ==============  ==================  ==========================  =================
name                critic trains   aux step trains     aux loss (output key)       targets (τ), owner
==================  ==============  ==================  ==========================  =================
``sim``             q, phi          task                reward (`loss_reward`)      φ̄: aux loss
``simlap``          q               phi, task           SimLap (`loss_simlap`)      φ̄: aux loss
``simlap_authors``  q, phi          phi, task           SimLap (`loss_simlap`)      φ̄: aux loss
``spr``             q, encoder      encoder, proj, pred SPR (`loss_spr`)            f̄, ḡ: aux loss
==================  ==============  ==================  ==========================  =================

The critic loss modules own Q̄ (and π̄ for TD3), which the base algorithm averages on its schedule; the
aux loss modules own the representation's targets, averaged every SGD step by `target_updater`.
`aux_every` (w every 10 TD3 / 16 SAC gradient steps): the base algorithm steps w's Adam only on gradient
steps that are multiples of the period (`Representation.aux_every`), as the authors' code.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch
from sf2_torch import losses as core_losses
from sf2_torch import params as params_mod
from sf2_torch.agents import representations as reps
from sf2_torch.agents.objectives import batch_from_tensordict
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.utils import NestedKey
from torch import nn
from torchrl.objectives import LossModule, SoftUpdate

from . import sim, simlap, spr

__all__ = [
    "BaselineTD3Loss", "BaselineSACLoss", "RewardLoss", "SimLapLoss", "SPRLoss", "SimRepresentation",
    "SimLapRepresentation", "SimLapAuthorsRepresentation", "SPRRepresentation", "register_all", "NAMES",
]  # fmt: skip

NAMES = ("sim", "simlap", "simlap_authors", "spr")


# ------------------------------------------------------------------------------------------- loss modules
def _register(loss: LossModule, name: str, module: nn.Module, target: nn.Module | None) -> None:
    """`loss.<name>_params` views `module`'s parameters; `loss.target_<name>_params` views `target`'s."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*wasn't part of the annotations.*")
        loss.convert_to_functional(module, name, create_target_params=target is not None)
    if target is not None:
        params = TensorDict.from_module(target, as_module=True)
        setattr(loss, f"target_{name}_params", TensorDictParams(params, no_convert=True))


@dataclass
class _Keys:
    """Configurable tensordict keys (`set_keys`); `reward`, `done`, `truncated`, `observation` are also
    read under "next"."""

    observation: NestedKey = "observation"
    action: NestedKey = "action"
    reward: NestedKey = "reward"
    done: NestedKey = "done"
    terminated: NestedKey = "terminated"
    truncated: NestedKey = "truncated"
    smoothing_noise: NestedKey = "smoothing_noise"
    next_action_noise: NestedKey = "next_action_noise"
    actor_noise: NestedKey = "actor_noise"
    alpha_noise: NestedKey = "alpha_noise"
    next_action: NestedKey = "next_action"
    spr_obs_noise: NestedKey = "spr_obs_noise"
    spr_next_obs_noise: NestedKey = "spr_next_obs_noise"


class _BaselineLoss(LossModule):
    """`nets` kept as a plain attribute (its tensors are registered through the functional params); the
    TD target is computed by the pure losses, so the value-estimator hooks do nothing."""

    _AcceptedKeys = _Keys
    default_keys = _Keys

    def __init__(self, nets: nn.Module):
        super().__init__()
        self.__dict__["nets"] = nets
        self.cfg = nets.cfg

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    def make_value_estimator(self, value_type=None, **hyperparams):
        return self

    def batch(self, td: TensorDictBase) -> core_losses.Batch:
        return batch_from_tensordict(td, self.tensor_keys)

    def _get(self, td: TensorDictBase, key: NestedKey) -> torch.Tensor:
        value = td.get(key, None)
        if value is None:
            raise KeyError(f"{type(self).__name__} needs the entry {key!r} in its input tensordict")
        return value


def _features_module(nets):
    return ("phi_network", nets.phi) if hasattr(nets, "phi") else ("encoder_network", nets.encoder)


class BaselineTD3Loss(_BaselineLoss):
    """TD3 on a baseline's critic: `<module>.td3_critic_loss` and `td3_actor_loss`. Noise key
    `smoothing_noise`. Output: `loss_qvalue`, `loss_actor`, `pred_value`, `target_value`. Owns Q̄ and π̄."""

    out_keys = ["loss_actor", "loss_qvalue", "pred_value", "target_value"]

    def __init__(self, nets: nn.Module, module, **critic_kwargs):
        super().__init__(nets)
        self.__dict__["module"] = module
        self.critic_kwargs = dict(critic_kwargs)
        _register(self, "actor_network", nets.policy, nets.target_policy)
        _register(self, "qvalue_network", nets.q, nets.target_q)
        _register(self, *_features_module(nets), None)

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        b = self.batch(td)
        loss_q, aux_q = self.module.td3_critic_loss(
            self.nets, b, self._get(td, self.tensor_keys.smoothing_noise), **self.critic_kwargs
        )
        loss_a, _ = self.module.td3_actor_loss(self.nets, b)
        return TensorDict({"loss_qvalue": loss_q, "loss_actor": loss_a, "pred_value": aux_q["q"],
                           "target_value": aux_q["target_q"]}, [])  # fmt: skip


class BaselineSACLoss(_BaselineLoss):
    """SAC on a baseline's critic: `<module>.sac_critic_loss`, `sac_actor_loss` and the core's
    `sac_alpha_loss`. Noise keys `next_action_noise`, `actor_noise`, `alpha_noise`. Owns Q̄."""

    out_keys = ["loss_actor", "loss_qvalue", "loss_alpha", "pred_value", "target_value", "entropy", "alpha"]

    def __init__(self, nets: nn.Module, module, **critic_kwargs):
        super().__init__(nets)
        self.__dict__["module"] = module
        self.critic_kwargs = dict(critic_kwargs)
        _register(self, "actor_network", nets.policy, None)
        _register(self, "qvalue_network", nets.q, nets.target_q)
        _register(self, *_features_module(nets), None)
        self.log_alpha = nets.log_alpha

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        k, b = self.tensor_keys, self.batch(td)
        loss_q, aux_q = self.module.sac_critic_loss(self.nets, b, self._get(td, k.next_action_noise),
                                                    **self.critic_kwargs)  # fmt: skip
        loss_a, aux_a = self.module.sac_actor_loss(self.nets, b, self._get(td, k.actor_noise))
        loss_t, aux_t = core_losses.sac_alpha_loss(self.nets, b, self._get(td, k.alpha_noise))
        return TensorDict({"loss_qvalue": loss_q, "loss_actor": loss_a, "loss_alpha": loss_t,
                           "pred_value": aux_q["q"], "target_value": aux_q["target_q"],
                           "entropy": aux_a["entropy"], "alpha": aux_t["alpha"]}, [])  # fmt: skip


class RewardLoss(_BaselineLoss):
    """Sim's representation step: `sim.reward_loss` (trains w). Input `next_action` ā′. Output
    `loss_reward`, `predicted_reward_rms`. Owns φ̄ (averaged every SGD step)."""

    def __init__(self, nets: nn.Module):
        super().__init__(nets)
        _register(self, "phi_network", nets.phi, nets.target_phi)

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        loss, aux = sim.reward_loss(self.nets, self.batch(td), self._get(td, self.tensor_keys.next_action))
        return TensorDict({"loss_reward": loss, **aux}, [])


class SimLapLoss(_BaselineLoss):
    """SimLap's representation step: `simlap.simlap_loss` (Laplacian on φ + reward on w). Input
    `next_action`. Output `loss_simlap` and the terms. Owns φ̄."""

    def __init__(self, nets: nn.Module):
        super().__init__(nets)
        _register(self, "phi_network", nets.phi, nets.target_phi)

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        loss, aux = simlap.simlap_loss(self.nets, self.batch(td), self._get(td, self.tensor_keys.next_action))
        return TensorDict({"loss_simlap": loss, **aux}, [])


class SPRLoss(_BaselineLoss):
    """SPR's representation step: `spr.spr_loss`. Inputs `next_action`, `spr_obs_noise`,
    `spr_next_obs_noise` (B, D). Output `loss_spr`, `spr_cosine`. Owns f̄ and ḡ."""

    def __init__(self, nets: nn.Module):
        super().__init__(nets)
        _register(self, "encoder_network", nets.encoder, nets.target_encoder)
        _register(self, "projection_network", nets.projection, nets.target_projection)

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        k = self.tensor_keys
        noise = self._get(td, k.spr_obs_noise), self._get(td, k.spr_next_obs_noise)
        loss, aux = spr.spr_loss(self.nets, self.batch(td), self._get(td, k.next_action), *noise)
        return TensorDict({"loss_spr": loss, **aux}, [])


# ------------------------------------------------------------------------------------------- representations
def _kw(nets) -> dict:
    p = next(nets.policy.parameters())
    return dict(dtype=p.dtype, device=p.device, core=nets)


class _SimBase(reps.Representation):
    aux_loss_name = "reward_loss"
    aux_loss_key = "loss_reward"
    train_features = True
    _aux_cls = RewardLoss

    def __init__(self, cfg, nets):
        super().__init__(cfg, nets)
        self.baseline_nets = sim.make_networks(cfg, nets.algo, **_kw(nets))
        self.aux_every = {"task": sim.REWARD_EVERY[nets.algo]}
        self.aux_loss = self._aux_cls(self.baseline_nets)
        self.target_updater = SoftUpdate(self.aux_loss, tau=cfg.tau)

    def critic_loss(self, algo):
        cls = BaselineTD3Loss if algo == "td3" else BaselineSACLoss
        return cls(self.baseline_nets, sim, train_features=self.train_features)

    def groups(self, critic_loss):
        n = self.baseline_nets
        return {"q": list(n.q.parameters()), "phi": list(n.phi.parameters()), "task": [n.task.w]}

    def canonical(self, critic_loss):
        return params_mod.to_canonical(self.baseline_nets)


@reps.register
class SimRepresentation(_SimBase):
    """`sim`: TD3Sim / SACSim (SF² paper §4.2). TD loss → SF heads and φ; reward prediction → w."""

    name = "sim"
    label = "Sim"
    critic_groups = ("phi",)
    aux_groups = ("task",)


@reps.register
class SimLapRepresentation(_SimBase):
    """`simlap`: the paper's SimLap: TD loss → SF heads only; Laplacian → φ; reward prediction → w."""

    name = "simlap"
    label = "SimLap"
    critic_groups = ()
    aux_groups = ("phi", "task")
    aux_loss_name = "simlap_loss"
    aux_loss_key = "loss_simlap"
    train_features = False
    _aux_cls = SimLapLoss


@reps.register
class SimLapAuthorsRepresentation(SimLapRepresentation):
    """`simlap_authors`: SimLap as the authors' code runs it (the TD loss also trains φ)."""

    name = "simlap_authors"
    label = "SimLap(code)"
    critic_groups = ("phi",)
    train_features = True


@reps.register
class SPRRepresentation(reps.Representation):
    """`spr`: TD3+SPR / SAC+SPR (Appendix B.1). TD loss → Q heads and encoder; SPR → encoder, g, h."""

    name = "spr"
    label = "SPR"
    critic_groups = ("encoder",)
    aux_groups = ("encoder", "projection", "prediction")
    aux_loss_name = "spr_loss"
    aux_loss_key = "loss_spr"
    noise_keys = ("spr_obs_noise", "spr_next_obs_noise")

    def __init__(self, cfg, nets):
        super().__init__(cfg, nets)
        self.baseline_nets = spr.make_networks(cfg, nets.algo, **_kw(nets))
        self.aux_loss = SPRLoss(self.baseline_nets)
        self.target_updater = SoftUpdate(self.aux_loss, tau=cfg.tau)

    def critic_loss(self, algo):
        cls = BaselineTD3Loss if algo == "td3" else BaselineSACLoss
        return cls(self.baseline_nets, spr)

    def groups(self, critic_loss):
        n = self.baseline_nets
        return {g: list(getattr(n, g).parameters()) for g in ("q", "encoder", "projection", "prediction")}

    def aux_noise(self, n, generator):
        p = next(self.baseline_nets.encoder.parameters())
        kw = dict(dtype=p.dtype, device=p.device, generator=generator)
        D = self.cfg.obs_size
        return {"spr_obs_noise": torch.randn(*n, D, **kw), "spr_next_obs_noise": torch.randn(*n, D, **kw)}

    def canonical(self, critic_loss):
        return params_mod.to_canonical(self.baseline_nets)


def register_all() -> tuple[str, ...]:
    """(Re-)register every baseline with `sf2_torch.agents.representations`; returns their names."""
    for cls in (SimRepresentation, SimLapRepresentation, SimLapAuthorsRepresentation, SPRRepresentation):
        reps.register(cls)
    return NAMES
