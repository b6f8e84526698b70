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
`representation.critic` so that every representation shares them.

Noise: `step_noise(key, batch)` is the thin wrapper that draws every random input of one SGD step, a
dict keyed by `noise_keys()`: TD3 `smoothing_noise` ξ (target-policy smoothing); SAC
`next_action_noise` ξ′ (a′ ~ π(s′) in the TD target), `actor_noise`, `alpha_noise` (a ~ π(s) in the
actor and temperature losses) and, with a representation loss, `flow_action_noise` (ā′ ~ π(s′));
then the representation's `noise_keys` (SF²: `flow_noise` ε, `flow_time` t). The names are the torch
agents' tensordict keys, so tests hand one draw to both frameworks. `sgd_step` is pure given it.

Schedules (`step`, the run's gradient-step index): the actor step is taken when
`step % policy_delay == 0`; a group of `representation.aux_every` ({group: period}) takes its aux Adam
step only when `step % period == 0`. On the other steps that group's parameters and whole Adam state
(moments and step count) are kept by `jnp.where` on the step (no Python branch on a traced value, so
the step stays one program under `jit`, `scan` and the trainer's seed `vmap`): the authors' separate
task-vector optimizer only steps when it is used, so its bias correction counts its own updates.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import optax
from sf2_common.agents.registry import check_aux_every

from sf2_jax import losses, networks
from sf2_jax.config import SF2Config

from .representations import Representation

__all__ = ["Algorithm", "TD3", "SAC", "make_algorithm", "check_aux_every"]

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
    critic_noise_key = ""   # the `step_noise` entry of the TD loss

    def __init__(self, cfg: SF2Config, representation_cls: type[Representation], dtype=jnp.float32):
        self.cfg = cfg
        self.nets = networks.make_networks(cfg, self.name)
        self.rep = representation_cls(cfg, self.nets)
        check_aux_every(self.rep)
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

    def _adam_step(self, params, opt_state, grads, due=None):
        """Adam on every group of `grads`; a group of `due` ({group: bool scalar}) keeps its parameters
        and Adam state (moments and count) where its flag is False."""
        params, opt_state = dict(params), dict(opt_state)
        for group, grad in grads.items():
            updates, state = self._tx(group).update(grad, opt_state[group], params[group])
            new = optax.apply_updates(params[group], updates)
            if due is not None and group in due:
                def keep(n, o, flag=due[group]):
                    return jnp.where(flag, n, o)

                new = jax.tree_util.tree_map(keep, new, params[group])
                state = jax.tree_util.tree_map(keep, state, opt_state[group])
            params[group], opt_state[group] = new, state
        return params, opt_state

    def _loss_step(self, loss_fn, groups, params, opt_state, due=None):
        """One Adam step on `groups` of `loss_fn(params) → (loss, aux)`; other groups are constants.
        `due`: see `_adam_step`."""
        def f(trained):
            return loss_fn({**params, **trained})

        (loss, aux), grads = jax.value_and_grad(f, has_aux=True)({g: params[g] for g in groups})
        params, opt_state = self._adam_step(params, opt_state, grads, due)
        return params, opt_state, loss, aux

    # ------------------------------------------------------------------ acting (overridden)
    def explore(self, params, obs, key):
        raise NotImplementedError

    def act(self, params, obs, key, deterministic: bool):
        raise NotImplementedError

    # ------------------------------------------------------------------ noise (the thin wrapper)
    def _algo_noise(self, k_critic, k_next, k_actor, batch) -> dict[str, jax.Array]:
        raise NotImplementedError

    def _randn(self, key, batch):
        return jax.random.normal(key, batch.action.shape, batch.action.dtype)

    def noise_keys(self) -> tuple[str, ...]:
        raise NotImplementedError

    def step_noise(self, key: jax.Array, batch: losses.Batch) -> dict[str, jax.Array]:
        """Every random input of one SGD step on `batch`, drawn from `key` (module docstring): the keys
        are `noise_keys()`. Split: k_critic, k_aux, k_next, k_actor = split(key, 4); the critic noise
        from k_critic, the representation's `aux_noise(k_aux)`, SAC's ā′ noise from k_next and its
        temperature and actor noise from split(k_actor) = (k_alpha, k_pi)."""
        k_critic, k_aux, k_next, k_actor = jax.random.split(key, 4)
        noise = self._algo_noise(k_critic, k_next, k_actor, batch)
        if self.rep.aux_groups:
            aux = self.rep.aux_noise(k_aux, batch)
            if set(aux) != set(self.rep.noise_keys):
                raise ValueError(f"{type(self.rep).__name__}.aux_noise returned {sorted(aux)}, but its "
                                 f"noise_keys are {self.rep.noise_keys}")
            noise.update(aux)
        return noise

    # ------------------------------------------------------------------ the SGD step
    def critic_loss(self, params, batch, noise):
        raise NotImplementedError

    def aux_next_action(self, params, batch, noise):
        raise NotImplementedError

    def actor_update(self, pre, params, opt_state, batch, noise, step):
        raise NotImplementedError

    def update_q_target(self, params, step) -> Params:
        raise NotImplementedError

    def aux_due(self, step) -> dict[str, Any]:
        """{group: step % period == 0} for the groups of `representation.aux_every`."""
        return {g: step % every == 0 for g, every in self.rep.aux_every.items()}

    def sgd_step(self, params: Params, opt_state: Params, batch: losses.Batch, key: jax.Array, step):
        """One SGD step (module docstring) with the noise `step_noise(key, batch)`; `step` is the
        gradient-step index (policy delay, `aux_every`). Returns (params, opt_state, metrics dict of
        scalars)."""
        noise = self.step_noise(key, batch)
        pre = params
        metrics = {}
        # 1. critic
        critic_noise = noise[self.critic_noise_key]
        params, opt_state, loss, aux = self._loss_step(
            lambda p: self.critic_loss(p, batch, critic_noise), ("q", *self.rep.critic_groups), params,
            opt_state)
        metrics["critic_loss"] = loss
        metrics["q"] = aux["q"]
        # 2. the representation's own loss, on the parameters after step 1
        if self.rep.aux_groups:
            next_action = sg(self.aux_next_action(pre, batch, noise))
            aux_noise = {k: noise[k] for k in self.rep.noise_keys}
            params, opt_state, loss, aux = self._loss_step(
                lambda p: self.rep.aux_loss(p, batch, next_action, aux_noise), self.rep.aux_groups,
                params, opt_state, due=self.aux_due(step))
            metrics[self.rep.aux_loss_name] = loss
            metrics.update(aux)
        # 3. actor (and temperature) from the pre-step critic
        params, opt_state, actor_metrics = self.actor_update(pre, params, opt_state, batch, noise, step)
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
    critic_noise_key = "smoothing_noise"

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

    def noise_keys(self):
        return ("smoothing_noise", *(self.rep.noise_keys if self.rep.aux_groups else ()))

    def _algo_noise(self, k_critic, k_next, k_actor, batch):
        return {"smoothing_noise": self._randn(k_critic, batch)}

    def aux_next_action(self, params, batch, noise):
        """ā′ = π̄(s′) (no smoothing)."""
        return networks.td3_action(self.nets, params, batch.next_obs, target=True)

    def actor_update(self, pre, params, opt_state, batch, noise, step):
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
    critic_noise_key = "next_action_noise"

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

    def noise_keys(self):
        keys = ("next_action_noise", "actor_noise", "alpha_noise")
        return keys + (("flow_action_noise", *self.rep.noise_keys) if self.rep.aux_groups else ())

    def _algo_noise(self, k_critic, k_next, k_actor, batch):
        k_alpha, k_pi = jax.random.split(k_actor)
        out = {"next_action_noise": self._randn(k_critic, batch), "actor_noise": self._randn(k_pi, batch),
               "alpha_noise": self._randn(k_alpha, batch)}
        if self.rep.aux_groups:
            out["flow_action_noise"] = self._randn(k_next, batch)
        return out

    def aux_next_action(self, params, batch, noise):
        """ā′ ~ π(s′) with the explicit noise `flow_action_noise`."""
        return networks.sac_sample(self.nets, params, batch.next_obs, noise["flow_action_noise"])[0]

    def actor_update(self, pre, params, opt_state, batch, noise, step):
        a_noise, p_noise = noise["alpha_noise"], noise["actor_noise"]

        def update(args):
            params, opt_state = args
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
