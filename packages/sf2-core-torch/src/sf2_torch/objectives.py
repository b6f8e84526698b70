"""SF²'s losses as TorchRL loss modules (`torchrl.objectives.LossModule`), keyed by tensordict entries.

`SF2FlowLoss` (eq. 3–4, Algorithm 1: `losses.flow_loss`) and `SF2CriticLoss` (the TD3 or SAC critic on
SF²'s Q(ψ(s, a)): `losses.td3_critic_loss`, `losses.sac_critic_loss`) read a TorchRL replay sample
("observation", "action", ("next", "observation"), ("next", "reward"), ("next", "terminated"), ...;
`set_keys` renames them) and return a TensorDict whose "loss_*" entries a TorchRL trainer sums. They
compute the functional losses on the `Networks` they are given (its target copies ψ̄, ζ̄, Q̄, π̄ included;
`losses.ema_update` moves them), so their values and gradients are those losses'. Noise (ε, flow time,
smoothing or policy noise) is read from the tensordict when present, else drawn here (`generator`): the
thin wrapper of docs/core-contract.md around pure losses. Needs torchrl and tensordict (the `[train]`
extra); `import sf2_torch` does not import this module. Manual: docs/torchrl.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from sf2_common.errors import ConfigError, ShapeError

try:
    from tensordict import TensorDict, TensorDictBase
    from tensordict.utils import NestedKey, unravel_key
    from torchrl.objectives import LossModule
except ImportError as err:   # the message names the extra
    raise ImportError(f"sf2_torch.objectives needs torchrl and tensordict ({err}): pip install "
                      "\"sf2-core-torch[train]\", or pip install torchrl tensordict") from err

from . import losses, networks
from .networks import Networks

__all__ = ["SF2FlowLoss", "SF2CriticLoss", "NEXT_ACTION_SOURCES"]

NEXT_ACTION_SOURCES = ("policy", "tensordict")


def _next(key: NestedKey) -> NestedKey:
    return unravel_key(("next", key))


class _SF2Loss(LossModule):
    """What both modules share: the `Networks`, the noise generator and reading a `losses.Batch`."""

    tensor_keys: object
    nets: Networks

    def __init__(self, nets: Networks, generator: torch.Generator | None = None) -> None:
        if not isinstance(nets, Networks):
            raise ConfigError(f"{type(self).__name__} takes sf2_torch's Networks (make_networks), found "
                              f"{type(nets).__name__}")
        super().__init__()
        self.nets = nets
        self.generator = generator
        self._in_keys = None

    @property
    def in_keys(self) -> list:
        if self._in_keys is None:
            self._set_in_keys()
        return self._in_keys

    @in_keys.setter
    def in_keys(self, values) -> None:
        self._in_keys = values

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        self._set_in_keys()   # no value estimator: the keys only

    def _column(self, td: TensorDictBase, key: NestedKey, b: int, dtype) -> torch.Tensor:
        """A (B,) column of `td` stored (B,) or (B, 1), TorchRL's layout of rewards and done flags."""
        x = td.get(key)
        if x.shape == (b, 1):
            x = x.squeeze(-1)
        if x.shape != (b,):
            raise ShapeError(f"tensordict entry {key!r} must have shape ({b},) or ({b}, 1), found "
                             f"{tuple(x.shape)}")
        return x.to(dtype)

    def _truncation(self, td: TensorDictBase, b: int, dtype) -> torch.Tensor:
        """("next", truncated), else ("next", done) and not ("next", terminated): 1 where the time limit
        cut the episode (the sample's losses are masked)."""
        keys = self.tensor_keys
        if td.get(_next(keys.truncated), None) is not None:
            return self._column(td, _next(keys.truncated), b, dtype)
        if td.get(_next(keys.done), None) is None or td.get(_next(keys.terminated), None) is None:
            raise KeyError(f"{type(self).__name__} needs {_next(keys.truncated)!r}, or {_next(keys.done)!r} "
                           f"and {_next(keys.terminated)!r}, in the tensordict (set_keys renames them)")
        done = self._column(td, _next(keys.done), b, torch.bool)
        terminated = self._column(td, _next(keys.terminated), b, torch.bool)
        return (done & ~terminated).to(dtype)

    def _noise(self, td: TensorDictBase, key: NestedKey, shape: tuple, like: torch.Tensor, uniform=False):
        """The tensordict's entry `key` if present, else a draw of N(0, I) (U(0, 1) if `uniform`)."""
        x = td.get(key, None)
        if x is not None:
            return x
        draw = torch.rand if uniform else torch.randn
        return draw(shape, dtype=like.dtype, device=like.device, generator=self.generator)

    def batch(self, tensordict: TensorDictBase) -> losses.Batch:
        """The transitions of `tensordict` as the functional losses take them (2-D: a tensordict of several
        batch dimensions is flattened; reward 0 and discount 1 where the module reads no reward).

        Args:
          tensordict: a TorchRL sample with this module's `in_keys`.

        Returns:
          The `losses.Batch`: obs, action, next_obs (B, ·); reward; discount = 1 − ("next", terminated);
          truncation (`SF2CriticLoss` reads reward and terminated, `SF2FlowLoss` neither).
        """
        td = tensordict.reshape(-1) if tensordict.batch_dims != 1 else tensordict
        keys = self.tensor_keys
        obs = td.get(keys.observation)
        b, dtype = obs.shape[0], obs.dtype
        if getattr(keys, "reward", None) is not None:
            reward = self._column(td, _next(keys.reward), b, dtype)
            discount = 1.0 - self._column(td, _next(keys.terminated), b, dtype)
        else:
            reward, discount = obs.new_zeros(b), obs.new_ones(b)
        return losses.Batch(obs=obs, action=td.get(keys.action).to(dtype), reward=reward, discount=discount,
                            next_obs=td.get(_next(keys.observation)),
                            truncation=self._truncation(td, b, dtype))


class SF2FlowLoss(_SF2Loss):
    """SF²'s flow loss (eq. 3–4, Algorithm 1) as a TorchRL loss module, trained on ψ and ζ.

    L_flow = mean_b m_b[(1 − γ_su) ℓ_P + γ_su ℓ_B], `losses.flow_loss` on the module's `Networks`: the
    velocity ζ(x, k)ψ(s, a) is regressed onto s̄′ − ε (the transition term) and onto the target field
    ζ̄ψ̄(s′, ā′) at the point x̂ its ODE reaches (the bootstrap term); m_b = 1 − truncation_b.

    Args:
      nets: the `Networks` of `sf2_torch.make_networks` (its cfg: γ_su, T, the integrator; its algo: the
        policy of ā′).
      next_action: where ā′ comes from: "policy" (default, as the trainers: TD3's target policy π̄(s′);
        SAC a sample of π(s′) with the noise `flow_action_noise`) or "tensordict" (the entry
        ("next", action)).
      generator: the `torch.Generator` of the noise the tensordict does not hold (None: torch's default).

    Keys (`set_keys`): observation, action, done, terminated, truncated, flow_noise (ε (B, D)), flow_time
    (k (B,)), flow_action_noise (SAC's ξ (B, A)); the next-step ones are read under "next".

    Returns (forward):
      TensorDict of "loss_flow" (L_flow), "flow_loss_p" and "flow_loss_boot" (its two terms, detached).
    """

    @dataclass
    class _AcceptedKeys:
        """The tensordict keys `set_keys` renames and their defaults (TorchRL's names)."""

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        done: NestedKey = "done"
        terminated: NestedKey = "terminated"
        truncated: NestedKey = "truncated"
        flow_noise: NestedKey = "flow_noise"
        flow_time: NestedKey = "flow_time"
        flow_action_noise: NestedKey = "flow_action_noise"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    out_keys = ["loss_flow", "flow_loss_p", "flow_loss_boot"]

    def __init__(self, nets: Networks, *, next_action: str = "policy",
                 generator: torch.Generator | None = None) -> None:
        if next_action not in NEXT_ACTION_SOURCES:
            raise ConfigError(f"next_action={next_action!r} is invalid: one of "
                              f"{', '.join(NEXT_ACTION_SOURCES)}")
        super().__init__(nets, generator)
        self.next_action = next_action

    def _set_in_keys(self) -> None:
        k = self.tensor_keys
        keys = [k.observation, k.action, _next(k.observation), _next(k.truncated), k.flow_noise, k.flow_time]
        if self.next_action == "tensordict":
            keys.append(_next(k.action))
        elif self.nets.algo == "sac":
            keys.append(k.flow_action_noise)
        self._in_keys = keys

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """The flow loss of a TorchRL sample (the class docstring)."""
        td = tensordict.reshape(-1) if tensordict.batch_dims != 1 else tensordict
        batch = self.batch(td)
        cfg, keys = self.nets.cfg, self.tensor_keys
        b = batch.obs.shape[0]
        eps = self._noise(td, keys.flow_noise, (b, cfg.obs_size), batch.obs)
        flow_time = self._noise(td, keys.flow_time, (b,), batch.obs, uniform=True)
        if self.next_action == "tensordict":
            next_action = td.get(_next(keys.action)).to(batch.obs.dtype)
        else:
            with torch.no_grad():
                if self.nets.algo == "td3":
                    next_action = networks.td3_action(self.nets, batch.next_obs, target=True)
                else:
                    xi = self._noise(td, keys.flow_action_noise, (b, cfg.action_size), batch.obs)
                    next_action = networks.sac_sample(self.nets, batch.next_obs, xi)[0]
        loss, aux = losses.flow_loss(self.nets, batch, next_action, eps, flow_time)
        out = {"loss_flow": loss, "flow_loss_p": aux["loss_p"], "flow_loss_boot": aux["loss_boot"]}
        return TensorDict(out, batch_size=[])


class SF2CriticLoss(_SF2Loss):
    """The critic of TD3+SF² or SAC+SF² (Appendix D, Algorithms 2–3) as a TorchRL loss module, trained on
    Q and ψ: the TD loss of Q(ψ(s, a)), `losses.td3_critic_loss` or `losses.sac_critic_loss` by the
    networks' algo.

    TD3: y = rs·r + (1 − terminated)·γ·min_j Q̄_j(ψ̄(s′, ã′)), ã′ = clip(π̄(s′) + clip(σ_s ξ, −c, c), −1, 1);
    SAC: y = rs·r + (1 − terminated)·γ·(min_j Q̄_j(ψ̄(s′, a′)) − α log π(a′|s′)), a′ ~ π(s′) with ξ′;
    loss = ½ mean_{b,j}(m_b(Q_j(ψ(s, a)) − sg(y)))², m_b = 1 − truncation_b.

    Args:
      nets: the `Networks` of `sf2_torch.make_networks` (its cfg: γ, reward scaling, smoothing; its algo).
      critic: `critic(obs, action, target=False)` → (B, 2); None: SF²'s Q(ψ) (`losses.sf2_critic`).
      generator: the `torch.Generator` of the noise the tensordict does not hold (None: torch's default).

    Keys (`set_keys`): observation, action, reward, done, terminated, truncated, smoothing_noise (TD3's ξ
    (B, A)), next_action_noise (SAC's ξ′ (B, A)); the next-step ones are read under "next".

    Returns (forward):
      TensorDict of "loss_qvalue" (the TD loss), "pred_value" (mean Q) and "target_value" (mean y), as
      TorchRL's TD3Loss names them.
    """

    @dataclass
    class _AcceptedKeys:
        """The tensordict keys `set_keys` renames and their defaults (TorchRL's names)."""

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        reward: NestedKey = "reward"
        done: NestedKey = "done"
        terminated: NestedKey = "terminated"
        truncated: NestedKey = "truncated"
        smoothing_noise: NestedKey = "smoothing_noise"
        next_action_noise: NestedKey = "next_action_noise"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    out_keys = ["loss_qvalue", "pred_value", "target_value"]

    def __init__(self, nets: Networks, *, critic: losses.Critic | None = None,
                 generator: torch.Generator | None = None) -> None:
        super().__init__(nets, generator)
        self.critic = critic

    def _set_in_keys(self) -> None:
        k = self.tensor_keys
        noise = k.smoothing_noise if self.nets.algo == "td3" else k.next_action_noise
        self._in_keys = [k.observation, k.action, _next(k.observation), _next(k.reward), _next(k.terminated),
                         _next(k.truncated), noise]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """The critic loss of a TorchRL sample (the class docstring)."""
        td = tensordict.reshape(-1) if tensordict.batch_dims != 1 else tensordict
        batch = self.batch(td)
        b, a = batch.obs.shape[0], self.nets.cfg.action_size
        if self.nets.algo == "td3":
            xi = self._noise(td, self.tensor_keys.smoothing_noise, (b, a), batch.obs)
            loss, aux = losses.td3_critic_loss(self.nets, batch, xi, critic=self.critic)
        else:
            xi = self._noise(td, self.tensor_keys.next_action_noise, (b, a), batch.obs)
            loss, aux = losses.sac_critic_loss(self.nets, batch, xi, critic=self.critic)
        return TensorDict({"loss_qvalue": loss, "pred_value": aux["q"], "target_value": aux["target_q"]},
                          batch_size=[])
