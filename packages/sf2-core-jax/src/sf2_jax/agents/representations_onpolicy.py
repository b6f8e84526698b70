"""The on-policy trainer's representations (`--algo ppo` on MinAtar; docs/minatar.md): what the critic sees
and the representation's own losses, over the core's `networks_image` and `losses_onpolicy`.

`none` (PPO-Q with `critic = "q"`, PPO with `critic = "v"`), `sf2` (SF² w/o AE: the flow over the image)
and `sf2-ae` (SF² w AE: the flow over the autoencoder's latent) are registered in `REGISTRY`, the on-policy
trainer's `sf2_common.agents.registry.Registry` (entry-point group `sf2.representations.jax.onpolicy`). The
vocabulary is the off-policy representations': `supported_algos`, `critic_groups`, `aux_groups`,
`noise_keys`, `targets`; `critics` names the critic kinds one works with, and `aux_losses` its own losses in
the order an SGD step takes them, each with the groups it trains. Methods are pure: `params` first.
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
from sf2_common.agents.registry import Registry
from sf2_common.config import SF2Config

from sf2_jax import losses_onpolicy as lo
from sf2_jax import networks_image as nwi
from sf2_jax.losses import Batch

__all__ = ["OnPolicyBatch", "OnPolicyRepresentation", "NoRepresentation", "SF2Representation",
           "SF2AERepresentation", "REGISTRY", "GROUP", "register", "get", "names"]

Params = dict[str, Any]
GROUP = "sf2.representations.jax.onpolicy"


class OnPolicyBatch(NamedTuple):
    """A minibatch of rollout transitions, as the losses read it (leading axis: the sample).

    Attributes:
      obs: s, float32 grids (B, H, W, C).
      action: a, int32 (B,).
      reward: r (B,), scaled by `reward_scaling`.
      discount: 1 − terminal (B,).
      truncation: 1 where the episode limit cut the episode after this step (B,).
      next_obs: s′ before any reset, float32 grids (B, H, W, C).
      next_action: a′ (B,): the action taken at s′, or one drawn from π(·|s′) at rollout time where none was
        (the episode ended, or the rollout did).
      log_prob: log π_old(a|s) at rollout time (B,).
      value: the critic's value of s at rollout time (B,): V(s), or V_Q(s) = Σ_a π(a|s) Q(s, a).
      advantage: A (B,), before normalization.
      target: the critic's regression target G (B,): the λ-return (Q), or GAE's A + V (V).
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    discount: jax.Array
    truncation: jax.Array
    next_obs: jax.Array
    next_action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    advantage: jax.Array
    target: jax.Array

    def transitions(self) -> Batch:
        """The `losses.Batch` of (s, a, r, d, s′, truncation) the flow losses take."""
        return Batch(obs=self.obs, action=self.action, reward=self.reward, discount=self.discount,
                     next_obs=self.next_obs, truncation=self.truncation)


class OnPolicyRepresentation:
    """The part of a PPO agent between the grid and the critic's values, and its own losses.

    Attributes:
      name: selects it (`--repr NAME`).
      label: shown in tables and plots, e.g. "SF² w AE".
      supported_algos: the algorithms it works with.
      critics: the critic kinds it works with (`TrainConfig.critic`).
      critic_groups: the groups the critic loss trains.
      aux_losses: ((metric name, groups it trains), ...), its own losses in the order an SGD step takes
        them, right after the critic's.
      noise_keys: the entries of `aux_noise`.
    """

    name: ClassVar[str] = ""
    label: ClassVar[str] = ""
    supported_algos: ClassVar[tuple[str, ...]] = ("ppo",)
    critics: ClassVar[tuple[str, ...]] = ("q",)
    critic_groups: ClassVar[tuple[str, ...]] = ()
    aux_losses: ClassVar[tuple[tuple[str, tuple[str, ...]], ...]] = ()
    noise_keys: ClassVar[tuple[str, ...]] = ()

    def __init__(self, cfg: SF2Config, obs_shape: tuple[int, int, int], critic: str):
        """Build the networks of `method(critic)`.

        Args:
          cfg: the `SF2Config` (obs_size = H·W·C, action_size = the number of actions).
          obs_shape: (H, W, C).
          critic: "q" or "v", one of `critics`.
        """
        if critic not in self.critics:
            raise ValueError(f"{type(self).__name__} takes critic {' or '.join(self.critics)}, not "
                             f"{critic!r}")
        self.cfg = cfg
        self.critic = critic
        self.nets = nwi.make_image_networks(cfg, obs_shape, self.method(critic))

    @property
    def aux_groups(self) -> tuple[str, ...]:
        """Every group its own losses train."""
        return tuple(dict.fromkeys(g for _, groups in self.aux_losses for g in groups))

    def method(self, critic: str) -> str:
        """The `networks_image` method of its networks."""
        raise NotImplementedError

    def init(self, key: jax.Array) -> Params:
        """{group: params} of every network and target (float32)."""
        return nwi.init_image_params(self.nets, key, jnp.float32)

    def logits(self, params: Params, obs) -> jax.Array:
        """The actor's logits (B, A)."""
        return nwi.policy_logits(self.nets, params, obs)

    def values(self, params: Params, obs, logits) -> jax.Array:
        """The critic's value of s (B,): V(s), or V_Q(s) = Σ_a π(a|s) Q(s, a) with π from `logits`."""
        if self.critic == "v":
            return nwi.state_value(self.nets, params, obs)
        return nwi.expected_value(logits, nwi.action_values(self.nets, params, obs))

    def critic_loss(self, params: Params, mb: OnPolicyBatch, clip_eps: float):
        """The critic's loss, (loss, {metric: scalar}): ½(Q(s, a) − G)², or PPO's clipped V loss."""
        if self.critic == "v":
            return lo.v_critic_loss(self.nets, params, mb.obs, mb.value, mb.target, clip_eps)
        return lo.q_critic_loss(self.nets, params, mb.obs, mb.action, mb.target)

    def aux_noise(self, key: jax.Array, mb: OnPolicyBatch) -> dict[str, jax.Array]:
        """The random inputs of its losses, keyed by `noise_keys`."""
        return {}

    def aux_loss(self, name: str, params: Params, mb: OnPolicyBatch, noise: dict):
        """Its loss `name` (one of `aux_losses`), pure given the noise: (loss, {metric: scalar})."""
        raise NotImplementedError(f"representation {self.name!r} has no loss {name!r}")

    def targets(self) -> dict[str, tuple[str, float]]:
        """{target group: (online group, τ)}, moved by EMA after every SGD step."""
        return {}


REGISTRY = Registry("jax", group=GROUP, baselines=())
register, names, get = REGISTRY.register, REGISTRY.names, REGISTRY.get


@register
class NoRepresentation(OnPolicyRepresentation):
    """`none`: the critic on the grid, its own torso: Q(s, ·) (PPO-Q) or V(s) (PPO); no loss of its own."""

    name = "none"
    label = ""
    critics = ("q", "v")
    critic_groups = ("critic",)

    def method(self, critic):
        return "ppo_q" if critic == "q" else "ppo"


class _Flow(OnPolicyRepresentation):
    """SF²'s critic Q(s, a) = Q_head(ψ(s, a)), ψ trained by the critic's loss and the flow loss; targets ψ̄
    (τ) and ζ̄ (τ_ζ)."""

    critic_groups = ("psi", "q")
    noise_keys = ("flow_noise", "flow_time")
    flow_size: ClassVar[int | None] = None   # ε's size: None for the grid's H·W·C

    def aux_noise(self, key, mb):
        k_eps, k_time = jax.random.split(key)
        b = mb.action.shape[0]
        size = self.flow_size or self.cfg.obs_size
        return {"flow_noise": jax.random.normal(k_eps, (b, size), jnp.float32),
                "flow_time": jax.random.uniform(k_time, (b,), jnp.float32)}

    def targets(self):
        return {"target_psi": ("psi", self.cfg.tau), "target_zeta": ("zeta", self.cfg.tau_zeta)}


@register
class SF2Representation(_Flow):
    """`sf2` (SF² w/o AE): the flow over the grid, `losses_onpolicy.image_flow_loss` on (ψ, ζ)."""

    name = "sf2"
    label = "SF² w/o AE"
    aux_losses = (("flow_loss", ("psi", "zeta")),)

    def method(self, critic):
        return "sf2"

    def aux_loss(self, name, params, mb, noise):
        return lo.image_flow_loss(self.nets, params, mb.transitions(), mb.next_action, noise["flow_noise"],
                                  noise["flow_time"])


@register
class SF2AERepresentation(_Flow):
    """`sf2-ae` (SF² w AE): the flow over the latent z′ = sg(E(s′)), `losses_onpolicy.latent_flow_loss` on
    (ψ, ζ), then the autoencoder's `autoencoder_loss` on (encoder, decoder) over s."""

    name = "sf2-ae"
    label = "SF² w AE"
    aux_losses = (("flow_loss", ("psi", "zeta")), ("ae_loss", ("encoder", "decoder")))
    flow_size = nwi.LATENT_SIZE

    def method(self, critic):
        return "sf2_ae"

    def aux_loss(self, name, params, mb, noise):
        if name == "ae_loss":
            return lo.autoencoder_loss(self.nets, params, mb.obs)
        return lo.latent_flow_loss(self.nets, params, mb.transitions(), mb.next_action, noise["flow_noise"],
                                   noise["flow_time"])
