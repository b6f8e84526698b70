"""TorchRL loss modules: the SF² flow loss, TD3 and SAC on SF² features, and TorchRL's own TD3/SAC losses
configured as the paper's vanilla baselines.

All follow TorchRL's `LossModule` conventions: tensordict keys are declared in `_AcceptedKeys` and renamed
with `set_keys`; trained networks are registered with `convert_to_functional` (`<name>_params`) and their
targets as `target_<name>_params`, so TorchRL's `SoftUpdate` averages them; `forward(tensordict)` returns a
TensorDict of `loss_*` entries. The transition layout is TorchRL's: `observation`, `action` at the root;
`("next", observation | reward | done | terminated | truncated)`; rewards and flags (B, 1).

The SF² modules compute their numbers with `sf2_torch.losses` (the pure losses of docs/core-contract.md,
proven equal to `sf2_jax` by the cross-framework tests). They are built on an `SF2Networks` and register
*views* of its modules: `<name>_params` share the online parameters and `target_<name>_params` share the
networks' target modules, so a `SoftUpdate` of a loss module moves `nets.target_*` in place and
`sf2_torch.params.to_canonical(nets)` always sees the current state. Every random draw is an input entry
(the "noise keys" below); the losses draw nothing.

Which module owns which target (so that one `SoftUpdate` per module has one rate and one schedule):
- `SF2FlowLoss` owns ψ̄ (rate τ) and ζ̄ (rate τ_ζ): the representation's targets, averaged every SGD step
  by `SF2SoftUpdate(flow_loss, tau, tau_zeta)`.
- `TD3SF2Loss` owns Q̄ and π̄, `SACSF2Loss` owns Q̄: the algorithm's targets (TD3: on actor steps).
  They read ψ and ψ̄ but do not own ψ̄.

Batch semantics follow the JAX trainer (Brax): `discount = 1 − done` and the mask m = 1 − truncated;
truncated samples are left out of the TD loss (counted as zeros in the mean over B).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torch import nn
from torchrl.objectives import LossModule, SACLoss, SoftUpdate, TD3Loss, ValueEstimators

from sf2_torch import losses
from sf2_torch.config import SF2Config
from sf2_torch.networks import MLP, SF2Networks, normalize

__all__ = [
    "SF2FlowLoss", "TD3SF2Loss", "SACSF2Loss", "VanillaTD3Loss", "VanillaSACLoss", "SF2SoftUpdate",
    "VanillaQHead", "TanhGaussian", "batch_from_tensordict", "target_pairs",
]


# ------------------------------------------------------------------------------------------------ helpers
def _flat(x: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """A (B, 1) or (B,) flag/reward as a (B,) tensor of the dtype of `like`, an observation-like (B, D)."""
    if x.ndim == like.ndim:
        x = x.squeeze(-1)
    return x.to(like.dtype)


def batch_from_tensordict(td: TensorDictBase, keys) -> losses.Batch:
    """The core `Batch` of a TorchRL transition tensordict: discount = 1 − done, truncation = truncated."""
    obs = td.get(keys.observation)
    nxt = td.get("next")
    return losses.Batch(
        obs=obs,
        action=td.get(keys.action),
        reward=_flat(nxt.get(keys.reward), obs),
        discount=1.0 - _flat(nxt.get(keys.done), obs),
        next_obs=nxt.get(keys.observation),
        truncation=_flat(nxt.get(keys.truncated), obs),
    )


def _share_target(loss: LossModule, name: str, target: nn.Module) -> None:
    """Make `loss.target_<name>_params` the tensors of `target` (shared, not copied)."""
    params = TensorDict.from_module(target, as_module=True)
    setattr(loss, f"target_{name}_params", TensorDictParams(params, no_convert=True))


def _register(loss: LossModule, name: str, module: nn.Module, target: nn.Module | None) -> None:
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*wasn't part of the annotations.*")
        loss.convert_to_functional(module, name, create_target_params=target is not None)
    if target is not None:
        _share_target(loss, name, target)


class _SF2LossBase(LossModule):
    """Shared construction: `nets` kept as a plain attribute (its tensors are registered via the
    functional params), value-estimator hooks that do nothing (the TD target is computed by the core)."""

    def __init__(self, nets: SF2Networks):
        super().__init__()
        if not isinstance(nets, SF2Networks):
            raise TypeError(f"{type(self).__name__} needs an SF2Networks, found {type(nets).__name__}")
        self.__dict__["nets"] = nets
        self.cfg: SF2Config = nets.cfg

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    def make_value_estimator(self, value_type=None, **hyperparams):
        return self  # the TD target y is part of the core loss

    def batch(self, tensordict: TensorDictBase) -> losses.Batch:
        return batch_from_tensordict(tensordict, self.tensor_keys)

    def _get(self, tensordict: TensorDictBase, key: NestedKey) -> torch.Tensor:
        value = tensordict.get(key, None)
        if value is None:
            raise KeyError(f"{type(self).__name__} needs the entry {key!r} in its input tensordict (an "
                           f"explicit noise input; see the module docstring and set_keys)")
        return value


# ---------------------------------------------------------------------------------------------- flow loss
class SF2FlowLoss(_SF2LossBase):
    """The SF² flow loss on (ψ, ζ) (eq. 3–4, Algorithm 1): `sf2_torch.losses.flow_loss`.

    Noise keys: `flow_noise` ε (B, D), `flow_time` k (B,), `next_action` ā′ (B, A) (TD3: target policy at
    s′; SAC: a policy sample at s′). Output: `loss_flow`, `loss_p`, `loss_boot`.
    Registers `psi_network` with `target_psi_network_params` (= nets.target_psi) and `zeta_network` with
    `target_zeta_network_params` (= nets.target_zeta); average them with `SF2SoftUpdate`.
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys (`set_keys`). `reward`, `done`, `truncated` and `observation` are
        also read under "next"."""

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        reward: NestedKey = "reward"
        done: NestedKey = "done"
        terminated: NestedKey = "terminated"
        truncated: NestedKey = "truncated"
        flow_noise: NestedKey = "flow_noise"
        flow_time: NestedKey = "flow_time"
        next_action: NestedKey = "next_action"

    default_keys = _AcceptedKeys
    out_keys = ["loss_flow", "loss_p", "loss_boot"]

    psi_network: nn.Module
    psi_network_params: TensorDictParams
    target_psi_network_params: TensorDictParams
    zeta_network: nn.Module
    zeta_network_params: TensorDictParams
    target_zeta_network_params: TensorDictParams

    def __init__(self, nets: SF2Networks):
        super().__init__(nets)
        _register(self, "psi_network", nets.psi, nets.target_psi)
        _register(self, "zeta_network", nets.zeta, nets.target_zeta)

    @property
    def in_keys(self):
        k = self.tensor_keys
        return [k.observation, k.action, ("next", k.observation), ("next", k.reward), ("next", k.done),
                ("next", k.truncated), k.flow_noise, k.flow_time, k.next_action]

    def flow_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        k = self.tensor_keys
        return losses.flow_loss(self.nets, self.batch(tensordict), self._get(tensordict, k.next_action),
                                self._get(tensordict, k.flow_noise), self._get(tensordict, k.flow_time))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        loss, aux = self.flow_loss(tensordict)
        return TensorDict({"loss_flow": loss, "loss_p": aux["loss_p"], "loss_boot": aux["loss_boot"]}, [])


class SF2SoftUpdate(SoftUpdate):
    """TorchRL's `SoftUpdate` with a rate per network: `tau` for every target of `loss_module` except
    those named in `taus` (e.g. `{"zeta_network": tau_zeta}`). target ← target + τ (online − target)."""

    def __init__(self, loss_module: LossModule, *, tau: float, taus: dict[str, float] | None = None):
        super().__init__(loss_module, tau=tau)
        self.taus = {f"{name}_params": float(t) for name, t in (taus or {}).items()}

    def step(self) -> None:
        if not self.initialized:
            raise RuntimeError(f"{type(self).__name__} must be initialized before step()")
        for key, param in self._sources.items():
            target = self._targets.get(f"target_{key}")
            target.data.lerp_(param.data, self.taus.get(key, 1.0 - self.eps))

    def weight(self, key: str) -> float:
        return self.taus.get(key, 1.0 - self.eps)


def target_pairs(updater: SoftUpdate) -> list[tuple[float, list[torch.Tensor], list[torch.Tensor]]]:
    """[(τ, targets, sources)] of a `SoftUpdate`: the same in-place lerp as `updater.step()` as flat tensor
    lists, so that a compiled SGD step can run it as one `torch._foreach_lerp_` per rate."""
    out = []
    for key, source in updater._sources.items():
        target = updater._targets.get(f"target_{key}")
        w = updater.weight(key) if isinstance(updater, SF2SoftUpdate) else 1.0 - updater.eps
        s_leaves = [source.get(k) for k in source.keys(True, True)]
        t_leaves = [target.get(k) for k in source.keys(True, True)]
        out.append((w, [t.data for t in t_leaves], [s.data for s in s_leaves]))
    return out


# ------------------------------------------------------------------------------------------------- TD3
class TD3SF2Loss(_SF2LossBase):
    """TD3 on SF² features (Algorithm 2): `sf2_torch.losses.td3_critic_loss` and `td3_actor_loss`.

    Noise key: `smoothing_noise` ξ (B, A) ~ N(0, I) (target-policy smoothing). Output: `loss_qvalue`
    (trains Q and ψ), `loss_actor` (trains the policy; ψ and Q enter detached), `pred_value` (mean Q),
    `target_value` (mean y). Registers `qvalue_network` (+ target = nets.target_q), `actor_network`
    (+ target = nets.target_policy) and `psi_network` (its target belongs to `SF2FlowLoss`).
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys (`set_keys`)."""

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        reward: NestedKey = "reward"
        done: NestedKey = "done"
        terminated: NestedKey = "terminated"
        truncated: NestedKey = "truncated"
        smoothing_noise: NestedKey = "smoothing_noise"

    default_keys = _AcceptedKeys
    out_keys = ["loss_actor", "loss_qvalue", "pred_value", "target_value"]

    actor_network: nn.Module
    actor_network_params: TensorDictParams
    target_actor_network_params: TensorDictParams
    qvalue_network: nn.Module
    qvalue_network_params: TensorDictParams
    target_qvalue_network_params: TensorDictParams
    psi_network: nn.Module
    psi_network_params: TensorDictParams
    target_psi_network_params: TensorDictParams

    def __init__(self, nets: SF2Networks):
        if nets.algo != "td3":
            raise ValueError(f"TD3SF2Loss needs networks built with algo='td3', found {nets.algo!r}")
        super().__init__(nets)
        _register(self, "actor_network", nets.policy, nets.target_policy)
        _register(self, "qvalue_network", nets.q, nets.target_q)
        _register(self, "psi_network", nets.psi, None)

    @property
    def in_keys(self):
        k = self.tensor_keys
        return [k.observation, k.action, ("next", k.observation), ("next", k.reward), ("next", k.done),
                ("next", k.truncated), k.smoothing_noise]

    def value_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return losses.td3_critic_loss(self.nets, self.batch(tensordict),
                                      self._get(tensordict, self.tensor_keys.smoothing_noise))

    def actor_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return losses.td3_actor_loss(self.nets, self.batch(tensordict))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        loss_q, aux_q = self.value_loss(tensordict)
        loss_a, _ = self.actor_loss(tensordict)
        return TensorDict({"loss_qvalue": loss_q, "loss_actor": loss_a, "pred_value": aux_q["q"],
                           "target_value": aux_q["target_q"]}, [])


# ------------------------------------------------------------------------------------------------- SAC
class SACSF2Loss(_SF2LossBase):
    """SAC on SF² features (Algorithm 3): `sf2_torch.losses.sac_critic_loss`, `sac_actor_loss`,
    `sac_alpha_loss` (Brax's temperature loss exp(log α)·sg(−log π − target entropy)).

    Noise keys, each ξ (B, A) ~ N(0, I): `next_action_noise` (a′ ~ π(s′) in the TD target),
    `actor_noise` (a ~ π(s) in the actor loss), `alpha_noise` (a ~ π(s) in the temperature loss).
    Output: `loss_qvalue`, `loss_actor`, `loss_alpha`, `pred_value`, `target_value`, `entropy`, `alpha`.
    `log_alpha` is `nets.log_alpha` (registered here as a parameter, as TorchRL's SACLoss does).
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys (`set_keys`)."""

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        reward: NestedKey = "reward"
        done: NestedKey = "done"
        terminated: NestedKey = "terminated"
        truncated: NestedKey = "truncated"
        next_action_noise: NestedKey = "next_action_noise"
        actor_noise: NestedKey = "actor_noise"
        alpha_noise: NestedKey = "alpha_noise"

    default_keys = _AcceptedKeys
    out_keys = ["loss_actor", "loss_qvalue", "loss_alpha", "pred_value", "target_value", "entropy", "alpha"]

    actor_network: nn.Module
    actor_network_params: TensorDictParams
    target_actor_network_params: TensorDictParams
    qvalue_network: nn.Module
    qvalue_network_params: TensorDictParams
    target_qvalue_network_params: TensorDictParams
    psi_network: nn.Module
    psi_network_params: TensorDictParams
    target_psi_network_params: TensorDictParams

    def __init__(self, nets: SF2Networks):
        if nets.algo != "sac":
            raise ValueError(f"SACSF2Loss needs networks built with algo='sac', found {nets.algo!r}")
        super().__init__(nets)
        _register(self, "actor_network", nets.policy, None)
        _register(self, "qvalue_network", nets.q, nets.target_q)
        _register(self, "psi_network", nets.psi, None)
        self.log_alpha = nets.log_alpha

    @property
    def in_keys(self):
        k = self.tensor_keys
        return [k.observation, k.action, ("next", k.observation), ("next", k.reward), ("next", k.done),
                ("next", k.truncated), k.next_action_noise, k.actor_noise, k.alpha_noise]

    def qvalue_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return losses.sac_critic_loss(self.nets, self.batch(tensordict),
                                      self._get(tensordict, self.tensor_keys.next_action_noise))

    def actor_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return losses.sac_actor_loss(self.nets, self.batch(tensordict),
                                     self._get(tensordict, self.tensor_keys.actor_noise))

    def alpha_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return losses.sac_alpha_loss(self.nets, self.batch(tensordict),
                                     self._get(tensordict, self.tensor_keys.alpha_noise))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        loss_q, aux_q = self.qvalue_loss(tensordict)
        loss_a, aux_a = self.actor_loss(tensordict)
        loss_t, aux_t = self.alpha_loss(tensordict)
        return TensorDict({"loss_qvalue": loss_q, "loss_actor": loss_a, "loss_alpha": loss_t,
                           "pred_value": aux_q["q"], "target_value": aux_q["target_q"],
                           "entropy": aux_a["entropy"], "alpha": aux_t["alpha"]}, [])


# ------------------------------------------------------------------------------------------- vanilla
class VanillaQHead(nn.Module):
    """One vanilla Q head: the core `MLP(hidden_sizes → 1)` (LayerNorm after each hidden ReLU) on
    concat[s̄, a], s̄ the normalized observation (the JAX `VanillaQ` head: Brax's Q network with
    `q_network_layer_norm=True`, as the authors ran vanilla TD3 and SAC)."""

    def __init__(self, cfg: SF2Config, **kw):
        super().__init__()
        self.mlp = MLP(cfg.obs_size + cfg.action_size, cfg.hidden_sizes, 1, cfg.layer_norm, **kw)

    def forward(self, obs_normalized: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.mlp(torch.cat([obs_normalized, action], dim=-1))


class TanhGaussian(torch.distributions.TransformedDistribution):
    """N(loc, scale) squashed by tanh, the core's SAC policy distribution, for TorchRL's `SACLoss`:
    torch's `TanhTransform` with a cache, so log π(a) of a sample comes from its pre-tanh value u
    (log π = Σ[−½ξ² − log σ − ½ log 2π] − Σ 2(log 2 − u − softplus(−2u)), exactly the core's formula; no
    atanh of a saturated action, no clamping), and no argument validation (which would synchronize with
    the host). TorchRL's `TanhNormal` checks its bounds with a host synchronization in eager mode."""

    def __init__(self, loc: torch.Tensor, scale: torch.Tensor):
        base = torch.distributions.Independent(torch.distributions.Normal(loc, scale, validate_args=False), 1,
                                               validate_args=False)
        super().__init__(base, [torch.distributions.TanhTransform(cache_size=1)], validate_args=False)

    @property
    def deterministic_sample(self) -> torch.Tensor:
        return torch.tanh(self.base_dist.base_dist.loc)

    @property
    def mode(self) -> torch.Tensor:
        return self.deterministic_sample


def _prepare(td: TensorDictBase, obs_norm: nn.Module, reward_scaling: float) -> TensorDictBase:
    """A shallow copy of `td` with normalized observations and scaled rewards (TorchRL's TD3Loss and
    SACLoss feed the tensordict's entries to the networks as they are)."""
    out = td.clone(False)
    nxt = td.get("next").clone(False)
    out.set("observation", normalize(td.get("observation"), obs_norm))
    nxt.set("observation", normalize(nxt.get("observation"), obs_norm))
    if reward_scaling != 1.0:
        nxt.set("reward", nxt.get("reward") * reward_scaling)
    out.set("next", nxt)
    return out


class VanillaTD3Loss(TD3Loss):
    """TorchRL's `TD3Loss` at the paper's settings: squared error (`loss_function="l2"`, not TorchRL's
    smooth-L1 default), two Q nets, smoothing σ = `smoothing_noise` clipped at `noise_clip`, actions in
    [−1, 1], target actor and critics, a TD(0) target with γ = `discount`.

    TorchRL reduces the critic loss as Σ_j mean_b (Q_j − y)²; `forward` re-reduces TorchRL's per-sample
    losses (`reduction="none"`) to the JAX trainer's ½ mean_{b,j}(m_b (Q_j − y))², m_b = 1 − truncated
    (= ¼ mean_b m_b Σ_j (Q_j − y)²), and the actor loss to −mean_b Q_0(s, π(s)). Observations in the input
    tensordict must already be normalized and rewards scaled (the algorithm does both). TorchRL draws the
    smoothing noise itself (from torch's global generator) inside `value_loss`.
    """

    def __init__(self, actor: TensorDictModule, qvalue_heads: list[TensorDictModule], cfg: SF2Config,
                 obs_norm: nn.Module):
        super().__init__(actor, qvalue_heads, bounds=(-1.0, 1.0), num_qvalue_nets=2,
                         policy_noise=cfg.smoothing_noise, noise_clip=cfg.noise_clip, loss_function="l2",
                         delay_actor=True, delay_qvalue=True, reduction="none")
        self.make_value_estimator(ValueEstimators.TD0, gamma=cfg.discount)
        self.loss_mask_key = None
        self.__dict__["obs_norm"] = obs_norm
        self.reward_scaling = cfg.reward_scaling

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        tensordict = _prepare(tensordict, self.obs_norm, self.reward_scaling)
        out = super().forward(tensordict)
        q = out.get("pred_value")
        m = 1.0 - _flat(tensordict.get(("next", "truncated")), tensordict.get("observation"))
        return TensorDict({"loss_qvalue": 0.25 * torch.mean(m * out.get("loss_qvalue")),
                           "loss_actor": out.get("loss_actor").mean(), "pred_value": q.mean(),
                           "target_value": out.get("target_value").mean()}, [])


class VanillaSACLoss(SACLoss):
    """TorchRL's `SACLoss` (v2: no value network) at the paper's settings: squared error, two Q nets,
    target critics only, target entropy −`target_entropy_scale`·A, α₀ = exp(`init_log_alpha`), a TD(0)
    target with γ = `discount`. One change of TorchRL's formula: the temperature loss is Brax's and the
    authors', exp(log α)·sg(−log π − target entropy), instead of TorchRL's −log α·(log π + target entropy)
    (the same fixed point; the gradient differs by the factor α).

    `forward` re-reduces TorchRL's per-sample losses (`reduction="none"`) as `VanillaTD3Loss` does: critic
    ½ mean_{b,j}(m_b (Q_j − y))², actor and temperature means over B. TorchRL samples the actions itself.
    """

    def __init__(self, actor, qvalue_heads: list[TensorDictModule], cfg: SF2Config, obs_norm: nn.Module):
        import math

        super().__init__(actor, qvalue_heads, num_qvalue_nets=2, loss_function="l2",
                         alpha_init=math.exp(cfg.init_log_alpha),
                         target_entropy=-cfg.target_entropy_scale * cfg.action_size,
                         delay_actor=False, delay_qvalue=True, reduction="none", scalar_output_mode="exclude")
        self.make_value_estimator(ValueEstimators.TD0, gamma=cfg.discount)
        self.loss_mask_key = None
        self.__dict__["obs_norm"] = obs_norm
        self.reward_scaling = cfg.reward_scaling

    def _alpha_loss(self, log_prob: torch.Tensor) -> torch.Tensor:
        return torch.exp(self.log_alpha) * (-log_prob - self.target_entropy).detach()

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        tensordict = _prepare(tensordict, self.obs_norm, self.reward_scaling)
        loss_q, _ = self.qvalue_v2_loss(tensordict)
        loss_a, meta_a = self.actor_loss(tensordict)
        loss_t = self._alpha_loss(meta_a["log_prob"])
        m = 1.0 - _flat(tensordict.get(("next", "truncated")), tensordict.get("observation"))
        with torch.no_grad():  # mean Q(s, a) of the batch, for the "q" metric
            q = self._vmap_qnetworkN0(tensordict.select(*self.qvalue_network.in_keys, strict=False),
                                      self.qvalue_network_params.detach())
        return TensorDict({"loss_qvalue": 0.25 * torch.mean(m * loss_q), "loss_actor": loss_a.mean(),
                           "loss_alpha": loss_t.mean(), "entropy": -meta_a["log_prob"].mean(),
                           "pred_value": q.get(self.tensor_keys.state_action_value).mean(),
                           "alpha": torch.exp(self.log_alpha.detach())}, [])
