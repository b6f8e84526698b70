"""Base algorithms TD3 and SAC, written once against the representation interface.

One SGD step follows docs/core-contract.md "One SGD step" (the authors' order):
1. critic step: Adam on `q` + `representation.critic_groups` from the TD loss;
2. representation step: Adam on `representation.aux_groups` (after step 1) from its own loss;
3. actor step (every `policy_delay`): Adam on the policy from Q (and features) as they were *before*
   step 1; SAC first takes its temperature step from the pre-step policy;
4. targets: TD3 averages Q̄ and π̄ into the targets on actor steps (the authors blended the new policy
   into the old *online* policy; we do not); SAC averages Q̄ every step; the representation's targets
   are updated every step.

Each group has its own Adam state, so ψ, trained in steps 1 and 2, keeps one state across both (as in
the authors' code). The TD and actor losses here equal `sf2_jax.losses.td3_critic_loss`, ... when the
representation is SF² (tests/agents/test_algorithms.py proves it); they are written against
`representation.critic` so that every representation shares them. Random draws are made here and
passed to the losses as explicit noise.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import optax

from sf2_jax import losses, networks
from sf2_jax.config import SF2Config

from .representations import Representation

__all__ = ["Algorithm", "TD3", "SAC", "make_algorithm"]

sg = jax.lax.stop_gradient
Params = dict[str, Any]


def _td_loss(q, y, truncation):
    """½ mean_{b,j}(m_b(Q_j − sg(y)))², m_b = 1 − truncation_b."""
    err = (1 - truncation)[..., None] * (q - sg(y)[..., None])
    return 0.5 * jnp.mean(err**2)


class Algorithm:
    """Shared machinery: parameter/optimizer init, per-group Adam steps, the SGD step skeleton."""

    name = ""
    policy_groups: tuple[str, ...] = ()

    def __init__(self, cfg: SF2Config, representation_cls: type[Representation], dtype=jnp.float32):
        self.cfg = cfg
        self.nets = networks.make_networks(cfg, self.name)
        self.rep = representation_cls(cfg, self.nets)
        self.dtype = dtype
        self._adam = optax.adam(cfg.learning_rate, eps=cfg.adam_eps)
        self._alpha_adam = optax.adam(cfg.alpha_learning_rate)  # Brax SAC's temperature optimizer

    # ------------------------------------------------------------------ parameters and optimizers
    def _tx(self, group: str):
        return self._alpha_adam if group == "log_alpha" else self._adam

    def trained_groups(self) -> tuple[str, ...]:
        groups = ["q", *self.rep.critic_groups, *self.rep.aux_groups, *self.policy_groups]
        return tuple(dict.fromkeys(groups))

    def init(self, key: jax.Array) -> tuple[Params, Params]:
        """(params, opt_state): the algorithm's groups (obs_norm, policy, target_policy | log_alpha)
        plus the representation's, and one Adam state per trained group."""
        k_core, k_rep = jax.random.split(key)
        core = networks.init_params(self.nets, k_core, dtype=self.dtype)
        params = {n: core[n] for n in ("obs_norm", "policy", "target_policy", "log_alpha") if n in core}
        params.update(self.rep.init(k_rep, core))
        opt_state = {g: self._tx(g).init(params[g]) for g in self.trained_groups()}
        return params, opt_state

    def _adam_step(self, params, opt_state, grads):
        params, opt_state = dict(params), dict(opt_state)
        for group, grad in grads.items():
            updates, opt_state[group] = self._tx(group).update(grad, opt_state[group], params[group])
            params[group] = optax.apply_updates(params[group], updates)
        return params, opt_state

    def _loss_step(self, loss_fn, groups, params, opt_state):
        """One Adam step on `groups` of `loss_fn(params) → (loss, aux)`; other groups are constants."""
        def f(trained):
            return loss_fn({**params, **trained})

        (loss, aux), grads = jax.value_and_grad(f, has_aux=True)({g: params[g] for g in groups})
        params, opt_state = self._adam_step(params, opt_state, grads)
        return params, opt_state, loss, aux

    # ------------------------------------------------------------------ acting (overridden)
    def explore(self, params, obs, key):
        raise NotImplementedError

    def act(self, params, obs, key, deterministic: bool):
        raise NotImplementedError

    # ------------------------------------------------------------------ the SGD step
    def critic_noise(self, key, batch):
        return jax.random.normal(key, batch.action.shape, batch.action.dtype)

    def critic_loss(self, params, batch, noise):
        raise NotImplementedError

    def aux_next_action(self, params, batch, key):
        raise NotImplementedError

    def actor_update(self, pre, params, opt_state, batch, key, step):
        raise NotImplementedError

    def update_q_target(self, params, step) -> Params:
        raise NotImplementedError

    def sgd_step(self, params: Params, opt_state: Params, batch: losses.Batch, key: jax.Array, step):
        """One SGD step (module docstring). Returns (params, opt_state, metrics dict of scalars)."""
        k_critic, k_aux, k_next, k_actor = jax.random.split(key, 4)
        pre = params
        metrics = {}
        # 1. critic
        noise = self.critic_noise(k_critic, batch)
        params, opt_state, loss, aux = self._loss_step(
            lambda p: self.critic_loss(p, batch, noise), ("q", *self.rep.critic_groups), params, opt_state)
        metrics["critic_loss"] = loss
        metrics["q"] = aux["q"]
        # 2. the representation's own loss, on the parameters after step 1
        if self.rep.aux_groups:
            next_action = sg(self.aux_next_action(pre, batch, k_next))
            aux_noise = self.rep.aux_noise(k_aux, batch)
            params, opt_state, loss, aux = self._loss_step(
                lambda p: self.rep.aux_loss(p, batch, next_action, aux_noise), self.rep.aux_groups,
                params, opt_state)
            metrics[self.rep.aux_loss_name] = loss
            metrics.update(aux)
        # 3. actor (and temperature) from the pre-step critic
        params, opt_state, actor_metrics = self.actor_update(pre, params, opt_state, batch, k_actor, step)
        metrics.update(actor_metrics)
        # 4. targets
        params = {**params, **self.update_q_target(params, step), **self.rep.update_targets(params)}
        return params, opt_state, metrics

    def _policy_step_due(self, step):
        return step % self.cfg.policy_delay == 0


class TD3(Algorithm):
    """TD3 (Fujimoto et al., 2018) on the representation's critic (Algorithm 2 for SF²)."""

    name = "td3"
    policy_groups = ("policy",)

    def explore(self, params, obs, key):
        """Authors' acting: π(s) + clip(σ_e ξ, −c, c), clipped to [−1, 1]."""
        cfg = self.cfg
        action = networks.td3_action(self.nets, params, obs)
        noise = jax.random.normal(key, action.shape, action.dtype) * cfg.exploration_noise
        return jnp.clip(action + jnp.clip(noise, -cfg.noise_clip, cfg.noise_clip), -1.0, 1.0)

    def act(self, params, obs, key, deterministic):
        if deterministic:
            return networks.td3_action(self.nets, params, obs)
        return self.explore(params, obs, key)

    def critic_loss(self, params, batch, noise):
        """y = rs·r + discount·γ·min_j Q̄_j(s′, ã′), ã′ = clip(π̄(s′) + clip(σ_s ξ, −c, c), −1, 1)."""
        cfg = self.cfg
        smoothing = jnp.clip(cfg.smoothing_noise * noise, -cfg.noise_clip, cfg.noise_clip)
        next_action = jnp.clip(networks.td3_action(self.nets, params, batch.next_obs, target=True)
                               + smoothing, -1.0, 1.0)
        next_q = self.rep.critic(params, batch.next_obs, next_action, target=True)
        y = cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * jnp.min(next_q, axis=-1)
        q = self.rep.critic(params, batch.obs, batch.action)
        return _td_loss(q, y, batch.truncation), {"q": jnp.mean(q)}

    def actor_loss(self, params, batch):
        """−mean_b Q_0(s, π(s))."""
        action = networks.td3_action(self.nets, params, batch.obs)
        return -jnp.mean(self.rep.critic(params, batch.obs, action)[..., 0]), {}

    def aux_next_action(self, params, batch, key):
        return networks.td3_action(self.nets, params, batch.next_obs, target=True)

    def actor_update(self, pre, params, opt_state, batch, key, step):
        def update(args):
            params, opt_state = args
            # differentiate the policy only; Q and features stay at their pre-step values
            new_pre, new_opt, loss, _ = self._loss_step(lambda p: self.actor_loss(p, batch), ("policy",),
                                                        pre, opt_state)
            return {**params, "policy": new_pre["policy"]}, new_opt, loss

        if self.cfg.policy_delay == 1:
            params, opt_state, loss = update((params, opt_state))
        else:
            params, opt_state, loss = jax.lax.cond(
                self._policy_step_due(step), update,
                lambda args: (args[0], args[1], jnp.zeros((), self.dtype)), (params, opt_state))
        return params, opt_state, {"actor_loss": loss}

    def update_q_target(self, params, step):
        tau = self.cfg.tau

        def new_targets():
            return {"target_q": losses.ema_update(params["target_q"], params["q"], tau),
                    "target_policy": losses.ema_update(params["target_policy"], params["policy"], tau)}

        if self.cfg.policy_delay == 1:
            return new_targets()
        keep = {"target_q": params["target_q"], "target_policy": params["target_policy"]}
        return jax.lax.cond(self._policy_step_due(step), new_targets, lambda: keep)


class SAC(Algorithm):
    """SAC (Haarnoja et al., 2018) with a learned temperature, on the representation's critic
    (Algorithm 3 for SF²)."""

    name = "sac"
    policy_groups = ("policy", "log_alpha")

    def explore(self, params, obs, key):
        noise = jax.random.normal(key, obs.shape[:-1] + (self.cfg.action_size,), obs.dtype)
        return networks.sac_sample(self.nets, params, obs, noise)[0]

    def act(self, params, obs, key, deterministic):
        return networks.sac_mode(self.nets, params, obs) if deterministic else self.explore(params, obs, key)

    def critic_loss(self, params, batch, noise):
        """y = rs·r + discount·γ·(min_j Q̄_j(s′, a′) − α log π(a′|s′)), a′ ~ π(s′) with ξ′ = noise."""
        cfg = self.cfg
        alpha = sg(jnp.exp(params["log_alpha"]))
        next_action, next_log_prob = networks.sac_sample(self.nets, params, batch.next_obs, noise)
        next_q = self.rep.critic(params, batch.next_obs, next_action, target=True)
        y = cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * (
            jnp.min(next_q, axis=-1) - alpha * next_log_prob)
        q = self.rep.critic(params, batch.obs, batch.action)
        return _td_loss(q, y, batch.truncation), {"q": jnp.mean(q)}

    def actor_loss(self, params, batch, noise):
        """mean_b(α log π(a|s) − min_j Q_j(s, a)), a ~ π(s) with ξ = noise; α constant."""
        alpha = sg(jnp.exp(params["log_alpha"]))
        action, log_prob = networks.sac_sample(self.nets, params, batch.obs, noise)
        q = self.rep.critic(params, batch.obs, action)
        return jnp.mean(alpha * log_prob - jnp.min(q, axis=-1)), {"entropy": -jnp.mean(log_prob)}

    def alpha_loss(self, params, batch, noise):
        """mean_b(exp(log_alpha)·sg(−log π(a|s) − target_entropy)), target = −scale·A."""
        _, log_prob = networks.sac_sample(self.nets, params, batch.obs, noise)
        target_entropy = -self.cfg.target_entropy_scale * self.cfg.action_size
        alpha = jnp.exp(params["log_alpha"])
        return jnp.mean(alpha * sg(-log_prob - target_entropy)), {}

    def aux_next_action(self, params, batch, key):
        noise = jax.random.normal(key, batch.action.shape, batch.action.dtype)
        return networks.sac_sample(self.nets, params, batch.next_obs, noise)[0]

    def actor_update(self, pre, params, opt_state, batch, key, step):
        k_alpha, k_actor = jax.random.split(key)

        def update(args):
            params, opt_state = args
            a_noise = jax.random.normal(k_alpha, batch.action.shape, batch.action.dtype)
            p_noise = jax.random.normal(k_actor, batch.action.shape, batch.action.dtype)
            new, opt_state, alpha_loss, _ = self._loss_step(
                lambda p: self.alpha_loss(p, batch, a_noise), ("log_alpha",), pre, opt_state)
            new2, opt_state, actor_loss, aux = self._loss_step(
                lambda p: self.actor_loss(p, batch, p_noise), ("policy",), pre, opt_state)
            params = {**params, "log_alpha": new["log_alpha"], "policy": new2["policy"]}
            return params, opt_state, (actor_loss, alpha_loss, aux["entropy"])

        if self.cfg.policy_delay == 1:
            params, opt_state, out = update((params, opt_state))
        else:
            zero = jnp.zeros((), self.dtype)
            params, opt_state, out = jax.lax.cond(
                self._policy_step_due(step), update, lambda args: (args[0], args[1], (zero, zero, zero)),
                (params, opt_state))
        actor_loss, alpha_loss, entropy = out
        return params, opt_state, {"actor_loss": actor_loss, "alpha_loss": alpha_loss,
                                   "alpha": jnp.exp(params["log_alpha"]), "entropy": entropy}

    def update_q_target(self, params, step):
        return {"target_q": losses.ema_update(params["target_q"], params["q"], self.cfg.tau)}


_ALGORITHMS = {"td3": TD3, "sac": SAC}


def make_algorithm(algo: str, cfg: SF2Config, representation_cls: type[Representation],
                   dtype=jnp.float32) -> Algorithm:
    return _ALGORITHMS[algo](cfg, representation_cls, dtype)
