"""The on-policy trainer's policies (docs/minatar.md, docs/fpo.md): how it acts, what a rollout stores for
the policy's loss, and the loss itself.

`CategoricalPolicy` (`--algo ppo`, MinAtar): the representation's actor logits, PPO's clipped loss on
log π_old. `FlowPolicy` (`--algo fpo`, Playground): FPO's velocity-field policy u(s, x, τ) (the authors'
SiLU MLP of widths (32, 32, 32, 32) on [normalize(s), x, embedding(τ)], its output scaled by 0.25),
actions Euler-integrated from noise and squashed by tanh for the env; a rollout stores the pre-squash
action, the (ε, τ) pairs and their losses ℓ_old; the loss is `losses_onpolicy.fpo_policy_loss`. Both give
the critic what its value needs: the logits (V_Q = Σ_a π(a|s)Q(s, a)) or K sampled actions
(V_Q ≈ mean_k Q(s, a_k)). Methods are pure; every random draw comes from the key given.
"""

from __future__ import annotations

import math

import flax.linen as nn
import jax
import jax.numpy as jnp

from sf2_jax import losses_onpolicy as lo
from sf2_jax import networks as nw
from sf2_jax import networks_image as nwi

__all__ = ["SiluMLP", "time_embedding", "CategoricalPolicy", "FlowPolicy", "FLOW_HIDDEN", "OUTPUT_SCALE",
           "TIME_EMBEDDING"]

FLOW_HIDDEN = (32, 32, 32, 32)   # the authors' flow policy
OUTPUT_SCALE = 0.25              # their `policy_mlp_output_scale`
TIME_EMBEDDING = 8               # their `timestep_embed_dim`


class SiluMLP(nn.Module):
    """Dense → SiLU hidden layers, then a last Dense; LeCun-uniform kernels, zero biases (FPO's MLPs)."""

    hidden_sizes: tuple[int, ...]
    out_size: int

    @nn.compact
    def __call__(self, x):
        for i, n in enumerate(self.hidden_sizes):
            x = nn.silu(nn.Dense(n, kernel_init=nw.LECUN_UNIFORM, name=f"dense_{i}")(x))
        last = nn.Dense(self.out_size, kernel_init=nw.LECUN_UNIFORM, name=f"dense_{len(self.hidden_sizes)}")
        return last(x)


def time_embedding(tau, size: int = TIME_EMBEDDING):
    """FPO's flow-time embedding [cos(2^i τ), sin(2^i τ)], i = 0..size/2 − 1.

    Args:
      tau: τ, any shape (...).
      size: an even embedding size.

    Returns:
      (..., size).
    """
    scaled = tau[..., None] * 2.0 ** jnp.arange(size // 2, dtype=jnp.result_type(tau, jnp.float32))
    return jnp.concatenate([jnp.cos(scaled), jnp.sin(scaled)], axis=-1)


class CategoricalPolicy:
    """PPO's categorical policy over the representation's actor logits (`--algo ppo`).

    Attributes:
      rep: the image representation whose "actor" group gives the logits.
    """

    def __init__(self, rep):
        self.rep = rep

    def init(self, key) -> dict:
        """Its own groups beyond the representation's: none (the actor is in `rep.init`)."""
        return {}

    def act(self, params, obs, key):
        """(a ~ π(·|s), log π(a|s)): the action the env takes and what the loss needs of it."""
        logits = self.rep.logits(params, obs)
        action = jax.random.categorical(key, logits).astype(jnp.int32)
        return action, nwi.categorical_log_prob(logits, action)

    def draw(self, params, obs, key):
        """One action drawn from π(·|s)."""
        return jax.random.categorical(key, self.rep.logits(params, obs)).astype(jnp.int32)

    def value_input(self, params, obs, key):
        """What `rep.values` needs: the logits."""
        return self.rep.logits(params, obs)

    def evaluate(self, params, obs, key, deterministic: bool):
        """The evaluation's action: the argmax of the logits, or a draw."""
        logits = self.rep.logits(params, obs)
        action = jnp.argmax(logits, axis=-1) if deterministic else jax.random.categorical(key, logits)
        return action.astype(jnp.int32)

    def loss(self, params, mb, cfg, nets=None):
        """PPO's clipped loss with the entropy bonus (`losses_onpolicy.ppo_policy_loss`); `nets` (default
        the representation's) as `SharedTorso.one_pass` gives them."""
        nets = self.rep.nets if nets is None else nets
        return lo.ppo_policy_loss(nets, params, mb.obs, mb.action, mb.policy_info, mb.advantage, cfg.clip_eps,
                                  cfg.entropy_coef)


class FlowPolicy:
    """FPO's velocity-field policy (`--algo fpo`; the module docstring).

    Attributes:
      cfg: the run's `TrainConfig` (fpo_samples, fpo_flow_steps, fpo_value_samples, fpo_log_ratio_clip,
        clip_eps, normalize_observations).
      obs_size, action_size: D and A.
      critic: "q" (the critic's value needs K sampled actions) or "v".
      net: the velocity field's `SiluMLP`.
    """

    def __init__(self, cfg, obs_size: int, action_size: int, critic: str):
        self.cfg, self.obs_size, self.action_size, self.critic = cfg, obs_size, action_size, critic
        self.net = SiluMLP(FLOW_HIDDEN, action_size)

    def init(self, key) -> dict:
        """{"actor": the velocity field's parameters} (float32)."""
        x = jnp.zeros((1, self.obs_size + self.action_size + TIME_EMBEDDING), jnp.float32)
        return {"actor": self.net.init(key, x)["params"]}

    def velocity(self, params, obs):
        """u(x, τ) of the policy at observations `obs` (B, D), for x (B, ..., A) and τ (B, ...)."""
        s = nw.normalize(obs, params["obs_norm"]) if self.cfg.normalize_observations else obs

        def u(x, tau):
            s_b = jnp.broadcast_to(s.reshape(s.shape[:1] + (1,) * (x.ndim - 2) + s.shape[1:]),
                                   x.shape[:-1] + s.shape[-1:])
            inputs = jnp.concatenate([s_b, x, time_embedding(tau)], axis=-1)
            return self.net.apply({"params": params["actor"]}, inputs) * OUTPUT_SCALE

        return u

    def _sample(self, params, obs, noise):
        return lo.flow_policy_sample(self.velocity(params, obs), noise, self.cfg.fpo_flow_steps)

    def act(self, params, obs, key):
        """(tanh(a), {raw: a, eps, flow_time, old_losses}): a by Euler integration from x_0 ~ N(0, I); n
        pairs ε ~ N(0, I), τ uniform on the Euler grid {1, 1 − 1/K, …, 1/K} (the authors'
        `discretize_t_for_training`), ℓ_old = `cfm_losses` at them."""
        k_x, k_eps, k_tau = jax.random.split(key, 3)
        b, n, K = obs.shape[0], self.cfg.fpo_samples, self.cfg.fpo_flow_steps
        raw = self._sample(params, obs, jax.random.normal(k_x, (b, self.action_size), jnp.float32))
        eps = jax.random.normal(k_eps, (b, n, self.action_size), jnp.float32)
        tau = 1.0 - jax.random.randint(k_tau, (b, n), 0, K).astype(jnp.float32) / K
        old = lo.cfm_losses(self.velocity(params, obs), raw, eps, tau)
        return jnp.tanh(raw), {"raw": raw, "eps": eps, "flow_time": tau, "old_losses": old}

    def draw(self, params, obs, key):
        """One env action tanh(a), a ~ π(·|s)."""
        noise = jax.random.normal(key, (obs.shape[0], self.action_size), jnp.float32)
        return jnp.tanh(self._sample(params, obs, noise))

    def value_input(self, params, obs, key):
        """K = `fpo_value_samples` env actions per state (K, B, A) for the Q critic; None for "v"."""
        if self.critic == "v":
            return None
        keys = jax.random.split(key, self.cfg.fpo_value_samples)
        return jax.vmap(lambda k: self.draw(params, obs, k))(keys)

    def evaluate(self, params, obs, key, deterministic: bool):
        """The evaluation's action tanh(a): from x_0 = 0 when `deterministic`, else from x_0 ~ N(0, I)."""
        noise = jax.random.normal(key, (obs.shape[0], self.action_size), jnp.float32)
        return jnp.tanh(self._sample(params, obs, jnp.zeros_like(noise) if deterministic else noise))

    def loss(self, params, mb, cfg):
        """FPO's clipped surrogate at the stored pairs (`losses_onpolicy.fpo_policy_loss`)."""
        info = mb.policy_info
        bound = cfg.fpo_log_ratio_clip
        return lo.fpo_policy_loss(self.velocity(params, mb.obs), info["raw"], info["eps"], info["flow_time"],
                                  info["old_losses"], mb.advantage, cfg.clip_eps,
                                  None if math.isinf(bound) else bound)
