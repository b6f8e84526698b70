"""The on-policy trainer's representations (`--algo ppo` on MinAtar, docs/minatar.md; `--algo fpo` on
Playground, docs/fpo.md): what the critic sees and the representation's own losses.

`none` (PPO-Q with `critic = "q"`, PPO with `critic = "v"`), `sf2` (SF² w/o AE: the flow over the image)
and `sf2-ae` (SF² w AE: the flow over the autoencoder's latent) are registered in `REGISTRY`, the on-policy
trainer's `sf2_common.agents.registry.Registry` (entry-point group `sf2.representations.jax.onpolicy`);
over images they use `networks_image`, over vector observations (`build`) their `vector` classes the
off-policy core's ψ, twin Q heads and `losses.flow_loss`. The
vocabulary is the off-policy representations': `supported_algos`, `critic_groups`, `aux_groups`,
`noise_keys`, `targets`; `critics` names the critic kinds one works with, `aux_losses` its own losses in
the order an SGD step takes them, each with the groups it trains, and `joint_step` one step of the critic's
and actor's losses summed (`SharedTorso`, pgx's). Methods are pure: `params` first.
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
from sf2_common.agents.registry import Registry
from sf2_common.config import SF2Config
from sf2_common.errors import ConfigError

from sf2_jax import losses_onpolicy as lo
from sf2_jax import networks as nw
from sf2_jax import networks_image as nwi
from sf2_jax.losses import Batch, _trainable, flow_loss

from .policies_onpolicy import SiluMLP

__all__ = ["OnPolicyBatch", "OnPolicyRepresentation", "NoRepresentation", "SF2Representation",
           "SF2AERepresentation", "ActorCritic", "SharedTorso", "VectorRepresentation", "VectorNone",
           "VectorSF2", "REGISTRY", "GROUP", "register", "get", "names", "build", "VALUE_HIDDEN",
           "q_lambda_loss"]

Params = dict[str, Any]
GROUP = "sf2.representations.jax.onpolicy"


class OnPolicyBatch(NamedTuple):
    """A minibatch of rollout transitions, as the losses read it (leading axis: the sample).

    Attributes:
      obs: s, float32 grids (B, H, W, C) or vectors (B, D).
      action: a, int32 (B,), or the env's action (B, A) in [−1, 1] (FPO: tanh of the flow's).
      reward: r (B,), scaled by `reward_scaling`.
      discount: 1 − terminal (B,).
      truncation: 1 where the episode limit cut the episode after this step (B,).
      next_obs: s′ before any reset, float32 grids (B, H, W, C).
      next_action: a′ (B,) or (B, A): the action taken at s′, or one drawn from π(·|s′) at rollout time where
        none was (the episode ended, or the rollout did).
      policy_info: what the policy's loss needs of the rollout (`policies_onpolicy`): log π_old(a|s) (B,)
        (PPO), or the pre-squash action, the (ε, τ) pairs and ℓ_old (FPO).
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
    policy_info: Any
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
      joint_step: the critic's loss (× `value_coef`) and the actor's as one loss in one clipped Adam step of
        `critic_groups`, which then hold the actor too (pgx's one network), instead of a step each.
    """

    name: ClassVar[str] = ""
    label: ClassVar[str] = ""
    supported_algos: ClassVar[tuple[str, ...]] = ("ppo",)
    vector: ClassVar[type | None] = None   # its class over vector observations (`build`), if any
    shared: ClassVar[type | None] = None   # its class with `shared_torso` (`build`), if any
    critics: ClassVar[tuple[str, ...]] = ("q",)
    critic_groups: ClassVar[tuple[str, ...]] = ()
    aux_losses: ClassVar[tuple[tuple[str, tuple[str, ...]], ...]] = ()
    noise_keys: ClassVar[tuple[str, ...]] = ()
    joint_step: ClassVar[bool] = False

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

    def critic_loss(self, params: Params, mb: OnPolicyBatch, clip_eps: float, nets=None):
        """The critic's loss, (loss, {metric: scalar}): ½(Q(s, a) − G)², or PPO's clipped V loss; `nets`
        (default `self.nets`) as `SharedTorso.one_pass` gives them."""
        nets = self.nets if nets is None else nets
        if self.critic == "v":
            return lo.v_critic_loss(nets, params, mb.obs, mb.value, mb.target, clip_eps)
        return lo.q_critic_loss(nets, params, mb.obs, mb.action, mb.target)

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
    supported_algos = ("ppo", "fpo")
    critics = ("q", "v")
    critic_groups = ("critic",)

    def method(self, critic):
        return "ppo_q" if critic == "q" else "ppo"


class ActorCritic(nn.Module):
    """pgx's MinAtar PPO network: `torso` (`networks_image.Torso`) under two heads (`networks_image.Head`,
    Dense 64 tanh ×2), `policy` → A logits and `value` → 1; the initialization of `networks_image`."""

    num_actions: int

    def setup(self):
        self.torso = nwi.Torso()
        self.policy = nwi.Head(nwi.HEAD_SIZES, self.num_actions)
        self.value = nwi.Head(nwi.HEAD_SIZES, 1)

    def __call__(self, obs):
        h = self.torso(obs)
        return self.policy(h), self.value(h)


class _Logits(ActorCritic):
    """`ActorCritic`'s parameters applied as the actor: the logits (B, A)."""

    def __call__(self, obs):
        return self.policy(self.torso(obs))


class _Value(ActorCritic):
    """`ActorCritic`'s parameters applied as the V critic: V(s) (B, 1)."""

    def __call__(self, obs):
        return self.value(self.torso(obs))


class _Given:
    """A stand-in for a network inside one traced loss: `apply` returns an output computed before it (the
    shared torso's one pass), whatever the parameters and grids it is given."""

    def __init__(self, output):
        self.output = output

    def apply(self, variables, obs):
        del variables, obs
        return self.output


class SharedTorso(NoRepresentation):
    """`none` with `shared_torso` (PPO, critic "v"): pgx's one `ActorCritic` in the group "actor" (the policy
    reads it whole), V(s) its value head; `joint_step`: one loss, one clipped gradient, one Adam state, the
    torso run once for both heads (`one_pass`)."""

    supported_algos = ("ppo",)
    critics = ("v",)
    critic_groups = ("actor",)
    joint_step = True

    def __init__(self, cfg: SF2Config, obs_shape: tuple[int, int, int], critic: str):
        super().__init__(cfg, obs_shape, critic)
        self.net = ActorCritic(cfg.action_size)
        self.nets = self.nets.replace(actor=_Logits(cfg.action_size), critic=_Value(cfg.action_size))

    def init(self, key):
        """{"actor": the `ActorCritic`'s parameters} (float32)."""
        return {"actor": self.net.init(key, jnp.zeros((1, *self.nets.obs_shape), jnp.float32))["params"]}

    @staticmethod
    def _as_critic(params: Params) -> Params:
        """`params` with the network also as "critic", the group the V critic's functions read."""
        return {**params, "critic": params["actor"]}

    def values(self, params, obs, logits):
        return super().values(self._as_critic(params), obs, logits)

    def critic_loss(self, params, mb, clip_eps, nets=None):
        return super().critic_loss(self._as_critic(params), mb, clip_eps, nets)

    def one_pass(self, params: Params, obs):
        """The networks for one joint loss at `obs`: the torso and both heads applied once (pgx's forward),
        the actor's and the V critic's `apply` returning those outputs. Within the traced loss the gradient
        reaches the parameters through that one pass, so the torso's backward runs once for both heads
        (applied apart, as `nets` are, it would run once per head: the same gradient, twice the work).

        Args:
          params: the parameters ({"actor": the `ActorCritic`'s}).
          obs: the minibatch's grids (B, H, W, C), as the losses are given them.

        Returns:
          `nets` with `actor` and `critic` replaced, for `critic_loss` and the policy's `loss`.
        """
        logits, value = self.net.apply({"params": params["actor"]}, obs)
        return self.nets.replace(actor=_Given(logits), critic=_Given(value))


NoRepresentation.shared = SharedTorso


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
    supported_algos = ("ppo", "fpo")
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


# ------------------------------------------------------------------------------------------------ vectors
VALUE_HIDDEN = (256, 256, 256, 256, 256)   # FPO's V network (SiLU), the critic of `critic = "v"`


def q_lambda_loss(nets: nw.Networks, params: Params, obs, action, target_return):
    """Q(λ)'s regression of the twin Q heads on ψ(s, a) to the λ-return, trained on ψ and the heads.

    loss = ½ mean_b mean_i (Q_i(s, a) − sg(G))², Q_i = head i of Q(ψ(s, a)); the critic's value is the
    heads' mean.

    Args:
      nets: the off-policy core's `Networks` (ψ, twin Q).
      params: the parameters (obs_norm, psi, q, ...).
      obs: s (B, D).
      action: a (B, A).
      target_return: G (B,).

    Returns:
      (loss, {"q": mean Q(s, a)}).
    """
    p = _trainable(params, ("psi", "q"))
    q = nw.q_values(nets, p, nw.psi(nets, p, obs, action))
    loss = 0.5 * jnp.mean((q - jax.lax.stop_gradient(target_return)[:, None]) ** 2)
    return loss, {"q": jax.lax.stop_gradient(jnp.mean(q))}


class VectorRepresentation(OnPolicyRepresentation):
    """A representation over vector observations with continuous actions (`--algo fpo`): the off-policy
    core's ψ(s, a) on [normalize(s), a] and twin Q heads (critic "q": Q(λ)), or FPO's V network (critic
    "v"); the groups include `obs_norm`, the running observation statistics the policy reads too."""

    supported_algos = ("fpo",)

    def __init__(self, cfg: SF2Config, obs_shape: tuple[int], critic: str):
        if critic not in self.critics:
            raise ValueError(f"{type(self).__name__} takes critic {' or '.join(self.critics)}, not "
                             f"{critic!r}")
        self.cfg, self.critic = cfg, critic
        self.nets = nw.make_networks(cfg, "td3")
        self.value_net = SiluMLP(VALUE_HIDDEN, 1)

    @property
    def groups(self) -> tuple[str, ...]:
        """Its parameter groups."""
        if self.critic == "v":
            return ("obs_norm", "critic")
        return ("obs_norm", "psi", "q", *self.aux_groups, *self.targets())

    def init(self, key):
        k_nets, k_v = jax.random.split(key)
        params = nw.init_params(self.nets, k_nets, jnp.float32)
        params["critic"] = self.value_net.init(k_v, jnp.zeros((1, self.cfg.obs_size), jnp.float32))["params"]
        return {g: params[g] for g in self.groups}

    def state_value(self, params, obs):
        """V(s) (B,) of critic "v"."""
        return self.value_net.apply({"params": params["critic"]}, nw.normalize(obs, params["obs_norm"]))[:, 0]

    def q_value(self, params, obs, action):
        """Q(s, a) (...,): the mean of the twin heads on ψ(s, a); `obs` and `action` (..., D), (..., A)."""
        lead = action.shape[:-1]
        obs = jnp.broadcast_to(obs, lead + obs.shape[-1:]).reshape(-1, obs.shape[-1])
        features = nw.psi(self.nets, params, obs, action.reshape(-1, action.shape[-1]))
        q = nw.q_values(self.nets, params, features)
        return jnp.mean(q, axis=-1).reshape(lead)

    def values(self, params, obs, draws):
        """V(s), or V_Q(s) ≈ mean_k Q(s, a_k) over the K actions `draws` (K, B, A) drawn from π(·|s)."""
        if self.critic == "v":
            return self.state_value(params, obs)
        return jnp.mean(self.q_value(params, obs[None], draws), axis=0)

    def critic_loss(self, params, mb: OnPolicyBatch, clip_eps: float):
        """Q(λ)'s `q_lambda_loss`, or FPO's value loss ½(V(s) − G)² (unclipped, as the authors')."""
        if self.critic == "v":
            p = _trainable(params, ("critic",))
            v = self.state_value(p, mb.obs)
            loss = 0.5 * jnp.mean((v - jax.lax.stop_gradient(mb.target)) ** 2)
            return loss, {"v": jax.lax.stop_gradient(jnp.mean(v))}
        return q_lambda_loss(self.nets, params, mb.obs, mb.action, mb.target)


class VectorNone(VectorRepresentation):
    """`none` over vectors: Q(λ) on ψ(s, a) trained by the TD(λ) loss alone (FPO + Q(λ)), or V (FPO)."""

    name = "none"
    label = ""
    critics = ("q", "v")

    @property
    def critic_groups(self):
        return ("critic",) if self.critic == "v" else ("psi", "q")


class VectorSF2(VectorRepresentation):
    """`sf2` over vectors: Q(λ) on ψ(s, a), ψ trained by the TD(λ) loss and SF²'s `losses.flow_loss` on the
    rollout's (s, a, s′, a′) (FPO + Q(λ) + SF²); targets ψ̄ (τ) and ζ̄ (τ_ζ)."""

    name = "sf2"
    label = "SF²"
    critics = ("q",)
    critic_groups = ("psi", "q")
    aux_losses = (("flow_loss", ("psi", "zeta")),)
    noise_keys = ("flow_noise", "flow_time")

    def aux_noise(self, key, mb):
        k_eps, k_time = jax.random.split(key)
        b = mb.obs.shape[0]
        return {"flow_noise": jax.random.normal(k_eps, (b, self.cfg.obs_size), jnp.float32),
                "flow_time": jax.random.uniform(k_time, (b,), jnp.float32)}

    def aux_loss(self, name, params, mb, noise):
        return flow_loss(self.nets, params, mb.transitions(), mb.next_action, noise["flow_noise"],
                         noise["flow_time"])

    def targets(self):
        return {"target_psi": ("psi", self.cfg.tau), "target_zeta": ("zeta", self.cfg.tau_zeta)}


NoRepresentation.vector = VectorNone
SF2Representation.vector = VectorSF2


def build(name: str, cfg: SF2Config, obs_shape: tuple[int, ...], critic: str,
          shared_torso: bool = False) -> OnPolicyRepresentation:
    """The representation `name` for observations of `obs_shape`: the registered class over images (H, W, C),
    its `vector` class over vectors (D,), its `shared` class with `shared_torso`.

    Args:
      name: a registered name (`--repr`).
      cfg: the `SF2Config` (obs_size, action_size: the number of actions, or A).
      obs_shape: (H, W, C) or (D,).
      critic: "q" or "v".
      shared_torso: pgx's one network and joint step (`none` with critic "v" over images only).

    Returns:
      The representation.

    Raises:
      ConfigError: an unknown name, one without a vector class for vector observations, or `shared_torso`
        for another representation, critic or observation kind.
    """
    cls = REGISTRY.get(name)
    if shared_torso:
        if cls.shared is None or len(obs_shape) != 3 or critic not in cls.shared.critics:
            raise ConfigError(f"shared_torso = True (pgx's one network) exists for representation 'none' "
                              f"with critic 'v' over images only, found representation {name!r}, critic "
                              f"{critic!r}, observations of shape {tuple(obs_shape)}")
        return cls.shared(cfg, obs_shape, critic)
    if len(obs_shape) == 1:
        if cls.vector is None:
            raise ConfigError(f"representation {name!r} takes image observations; over vector observations "
                              f"the on-policy trainer takes {', '.join(n for n in names() if get(n).vector)}")
        return cls.vector(cfg, obs_shape, critic)
    return cls(cfg, obs_shape, critic)
