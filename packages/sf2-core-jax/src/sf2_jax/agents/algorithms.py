"""Base algorithms TD3 and SAC, written once against the representation interface.

The losses are the core's (`sf2_jax.losses`, with `critic=` the representation's critic); this module
schedules them: one SGD step in the authors' order (docs/core-contract.md "One SGD step"), every random
input drawn up front by `step_noise` (keys `noise_keys()`, the torch agents' too) so `sgd_step` is pure.
The vocabulary is sf2_torch.agents.algorithms' (docs/core-contract.md "Agents: the plug-in vocabulary");
JAX methods are pure, take `params` (and `opt_state` where they update it) first and a PRNG `key` where
torch takes a generator. Each trained group has its own Adam state (`shared_adam = False` gives ψ's aux
step a second one, `opt_state["psi:aux"]`).

Schedules on the traced step index (`aux_every`, `policy_delay`) keep a group's parameters and whole Adam
state by `jnp.where` or skip the policy by `lax.cond`, so the step stays one program under `jit`, `scan`
and the trainer's seed `vmap`. Each part is traced under a `jax.named_scope` (`PHASES`), so `python -m
bench.hlo` counts the compiled step's kernels per part.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from sf2_common.agents.registry import aux_states, check_aux_every, check_aux_steps
from sf2_common.config import SF2Config

from sf2_jax import losses, networks

from .representations import Representation

__all__ = ["Algorithm", "TD3", "SAC", "make_algorithm", "PHASES"]

sg = jax.lax.stop_gradient
Params = dict[str, Any]
# the `jax.named_scope`s of one SGD step, in the step's order (module docstring, "Profiling")
PHASES = ("critic_grad", "critic_adam", "aux_grad", "aux_adam", "policy_grad", "policy_adam", "targets")


def _when(flag, fn: Callable, otherwise: Callable):
    """fn() where `flag`, else otherwise(): a Python bool decides while tracing, a traced one by lax.cond."""
    if isinstance(flag, bool):
        return fn() if flag else otherwise()
    return jax.lax.cond(flag, fn, otherwise)


class Algorithm:
    """The SGD step skeleton (module docstring), parameter and optimizer init, per-group Adam steps."""

    name = ""
    policy_groups: tuple[str, ...] = ()
    critic_noise_key = ""   # the `step_noise` entry of the TD loss
    _aux_action_noise_keys: tuple[str, ...] = ()   # ā′'s `step_noise` entries (SAC: flow_action_noise)

    def __init__(self, cfg: SF2Config, representation_cls: type[Representation], dtype=jnp.float32):
        self.cfg = cfg
        self.nets = networks.make_networks(cfg, self.name)
        self.rep = representation_cls(cfg, self.nets)
        check_aux_every(self.rep)
        check_aux_steps(cfg, self.rep)
        self.dtype = dtype
        self._adam = optax.adam(cfg.learning_rate, eps=cfg.adam_eps)
        self._alpha_adam = optax.adam(cfg.alpha_learning_rate)  # Brax SAC's temperature optimizer
        self.aux_states = aux_states(cfg, self.rep)   # {aux group: its Adam state's name in opt_state}

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
        opt_state.update({state: self._tx(g).init(params[g]) for g, state in self.aux_states.items()
                          if state != g})
        return params, opt_state

    def _value_and_grad(self, loss_fn, groups, params):
        """((loss, aux), {group: gradient}) of `loss_fn(params)` with respect to `groups` only."""
        def f(trained):
            return loss_fn({**params, **trained})

        return jax.value_and_grad(f, has_aux=True)({g: params[g] for g in groups})

    def _adam_step(self, params, opt_state, grads, due=None, states=None):
        """Adam on every group of `grads`, with the state `states[group]` (default: the group's own); a
        group of `due` ({group: bool scalar}) keeps its parameters and Adam state (moments and count) where
        its flag is False."""
        params, opt_state = dict(params), dict(opt_state)
        for group, grad in grads.items():
            key = (states or {}).get(group, group)
            updates, state = self._tx(group).update(grad, opt_state[key], params[group])
            new = optax.apply_updates(params[group], updates)
            if due is not None and group in due:
                def keep(n, o, flag=due[group]):
                    return jnp.where(flag, n, o)

                new = jax.tree_util.tree_map(keep, new, params[group])
                state = jax.tree_util.tree_map(keep, state, opt_state[key])
            params[group], opt_state[key] = new, state
        return params, opt_state

    # ------------------------------------------------------------------ acting (overridden)
    def explore(self, params, obs, key):
        raise NotImplementedError

    def act(self, params, obs, key, deterministic: bool):
        raise NotImplementedError

    # ------------------------------------------------------------------ noise (the thin wrapper)
    def noise_keys(self) -> tuple[str, ...]:
        raise NotImplementedError

    def _algo_noise(self, k_critic, k_next, k_actor, batch) -> dict[str, jax.Array]:
        raise NotImplementedError

    def _randn(self, key, batch):
        return jax.random.normal(key, batch.action.shape, batch.action.dtype)

    def aux_noise_keys(self) -> tuple[str, ...]:
        """The `noise_keys()` of the representation's step (step 3): ā′'s noise (SAC), then the
        representation's `noise_keys`; empty without an aux loss."""
        if not self.rep.aux_groups:
            return ()
        return (*self._aux_action_noise_keys, *self.rep.noise_keys)

    def _more_aux_keys(self) -> tuple[str, ...]:
        """"<key>:more" for each of `aux_noise_keys()` when `aux_steps_per_sgd_step` > 1: the draws of the
        later representation steps, stacked on a leading axis of size k − 1."""
        if self.cfg.aux_steps_per_sgd_step == 1:
            return ()
        return tuple(f"{k}:more" for k in self.aux_noise_keys())

    def _aux_action_noise(self, key, batch) -> dict[str, jax.Array]:
        return {}

    def step_noise(self, key: jax.Array, batch: losses.Batch) -> dict[str, jax.Array]:
        """Every random input of one SGD step on `batch`, drawn from `key` (module docstring): the keys
        are `noise_keys()`. Split: k_critic, k_aux, k_next, k_actor = split(key, 4); the critic noise
        from k_critic, the representation's `aux_noise(k_aux)`, SAC's ā′ noise from k_next and its
        temperature and actor noise from split(k_actor) = (k_alpha, k_pi). With k =
        `aux_steps_per_sgd_step` > 1, representation step j = 2..k draws its own from the (j − 1)th key
        of split(fold_in(k_aux, 1), k − 1), split again into (k_next, k_aux), under "<key>:more"."""
        k_critic, k_aux, k_next, k_actor = jax.random.split(key, 4)
        noise = self._algo_noise(k_critic, k_next, k_actor, batch)
        if self.rep.aux_groups:
            aux = self.rep.aux_noise(k_aux, batch)
            if set(aux) != set(self.rep.noise_keys):
                raise ValueError(f"{type(self.rep).__name__}.aux_noise returned {sorted(aux)}, but its "
                                 f"noise_keys are {self.rep.noise_keys}")
            noise.update(aux)
        if self._more_aux_keys():
            keys = jax.random.split(jax.random.fold_in(k_aux, 1), self.cfg.aux_steps_per_sgd_step - 1)
            more = jax.vmap(lambda k: self._aux_step_noise(k, batch))(keys)
            noise.update({f"{k}:more": more[k] for k in self.aux_noise_keys()})
        return noise

    def _aux_step_noise(self, key, batch) -> dict[str, jax.Array]:
        """The random inputs of one representation step (`aux_noise_keys()`) from `key`: ā′'s from
        k_next and the representation's `aux_noise(k_aux)`, (k_next, k_aux) = split(key)."""
        k_next, k_aux = jax.random.split(key)
        return {**self._aux_action_noise(k_next, batch), **self.rep.aux_noise(k_aux, batch)}

    # ------------------------------------------------------------------ the losses (overridden)
    def critic_loss(self, params, batch, noise):
        """The TD loss of the representation's critic with `noise[critic_noise_key]`: (loss, aux)."""
        raise NotImplementedError

    def policy_losses(self, params, batch, noise) -> dict[str, tuple[str, Callable]]:
        """{policy group: (metric name, loss_fn)}, `loss_fn(params) -> (loss, aux metrics)`."""
        raise NotImplementedError

    def aux_next_action(self, params, batch, noise):
        """ā′, the next action of the representation's loss."""
        raise NotImplementedError

    def updates_q_target(self, step):
        """Whether Q̄ (TD3: and π̄) move this step: a Python bool or a traced bool scalar."""
        raise NotImplementedError

    def _actor_step(self, step):
        return True if self.cfg.policy_delay == 1 else step % self.cfg.policy_delay == 0

    # ------------------------------------------------------------------ the SGD step
    def sgd_step(self, params: Params, opt_state: Params, batch: losses.Batch, noise: dict, step):
        """One SGD step (module docstring) with `noise` (keys `noise_keys()`, from `step_noise`); `step` is
        the gradient-step index (policy delay, `aux_every`). Returns (params, opt_state, metrics dict
        of scalars)."""
        rep, pre = self.rep, params
        # 1. the critic gradient at the pre-step parameters (the policy's: in `policy_step`, also at `pre`)
        with jax.named_scope("critic_grad"):
            (loss, aux), grads = self._value_and_grad(lambda p: self.critic_loss(p, batch, noise),
                                                      ("q", *rep.critic_groups), pre)
        metrics = {"critic_loss": loss, "q": aux["q"]}
        # 2. Adam on the critic groups
        with jax.named_scope("critic_adam"):
            params, opt_state = self._adam_step(params, opt_state, grads)
        # 3. the representation's own loss, on the parameters after step 2 (`aux_steps_per_sgd_step` times)
        if rep.aux_groups:
            params, opt_state, aux_metrics = self._aux_step(pre, params, opt_state, batch, noise, step)
            metrics.update(aux_metrics)
            if self.cfg.aux_steps_per_sgd_step > 1:
                params, opt_state = self._more_aux_steps(pre, params, opt_state, batch, noise, step)

        # 1 and 4: the policy groups' gradients at `pre`, then Adam on them (actor steps only)
        def policy_step():
            grads, out = {}, {}
            with jax.named_scope("policy_grad"):
                for group, (name, loss_fn) in self.policy_losses(pre, batch, noise).items():
                    (out[name], aux), grad = self._value_and_grad(loss_fn, (group,), pre)
                    grads.update(grad)
                    out.update(aux)
            with jax.named_scope("policy_adam"):
                return (*self._adam_step(params, opt_state, grads), out)

        def no_policy_step():
            zeros = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype),
                                           jax.eval_shape(policy_step)[2])
            return params, opt_state, zeros

        params, opt_state, policy_metrics = _when(self._actor_step(step), policy_step, no_policy_step)
        metrics.update(policy_metrics)
        if "log_alpha" in params:
            metrics["alpha"] = jnp.exp(params["log_alpha"])   # SAC's temperature after this step
        # 5. targets
        pairs = {"target_q": ("q", self.cfg.tau)}
        if "target_policy" in params:
            pairs["target_policy"] = ("policy", self.cfg.tau)
        with jax.named_scope("targets"):
            moved = _when(self.updates_q_target(step), lambda: self._ema(params, pairs),
                          lambda: {t: params[t] for t in pairs})
            return {**params, **moved, **self._ema(params, rep.targets())}, opt_state, metrics

    def _aux_step(self, pre: Params, params: Params, opt_state: Params, batch: losses.Batch, noise: dict,
                 step):
        """One representation step (step 3 of `sgd_step`): θ_aux ← Adam(θ_aux, ∇ L_aux(params; ā′, ξ)).

        Args:
          pre: the parameters before the SGD step (ā′ = `aux_next_action(pre, batch, noise)`).
          params: the parameters the loss is taken at; its `aux_groups` are stepped.
          opt_state: the Adam states (`aux_states` names each aux group's).
          batch: the minibatch.
          noise: the draws of this step, keyed by `aux_noise_keys()` (more keys are ignored).
          step: the gradient-step index (`aux_every`).

        Returns:
          (params, opt_state, {aux loss name: loss, its aux metrics}) at the parameters before this step.
        """
        rep = self.rep
        with jax.named_scope("aux_grad"):
            next_action = sg(self.aux_next_action(pre, batch, noise))
            aux_noise = {k: noise[k] for k in rep.noise_keys}
            (loss, aux), grads = self._value_and_grad(
                lambda p: rep.aux_loss(p, batch, next_action, aux_noise), rep.aux_groups, params)
        due = {g: step % every == 0 for g, every in rep.aux_every.items()}
        with jax.named_scope("aux_adam"):
            params, opt_state = self._adam_step(params, opt_state, grads, due, self.aux_states)
        return params, opt_state, {rep.aux_loss_name: loss, **aux}

    def _more_aux_steps(self, pre, params, opt_state, batch, noise, step):
        """Representation steps 2..k (`aux_steps_per_sgd_step` = k) after the first: `_aux_step` by
        `lax.scan` over the draws noise["<key>:more"], carrying the aux groups and their Adam states; their
        metrics are not reported (the step's are the first representation step's)."""
        groups, states = self.rep.aux_groups, tuple(dict.fromkeys(self.aux_states.values()))

        def one(carry, draw):
            p, s, _ = self._aux_step(pre, {**params, **carry[0]}, {**opt_state, **carry[1]}, batch, draw,
                                     step)
            return ({g: p[g] for g in groups}, {n: s[n] for n in states}), None

        draws = {k: noise[f"{k}:more"] for k in self.aux_noise_keys()}   # {} for a loss without noise
        (p, s), _ = jax.lax.scan(one, ({g: params[g] for g in groups}, {n: opt_state[n] for n in states}),
                                 draws, length=self.cfg.aux_steps_per_sgd_step - 1)
        return {**params, **p}, {**opt_state, **s}

    @staticmethod
    def _ema(params, pairs) -> Params:
        """{target: ema_update(target, online, τ)} for `pairs` = {target: (online, τ)}."""
        return {t: losses.ema_update(params[t], params[o], tau) for t, (o, tau) in pairs.items()}


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

    def noise_keys(self):
        return ("smoothing_noise", *self.aux_noise_keys(), *self._more_aux_keys())

    def _algo_noise(self, k_critic, k_next, k_actor, batch):
        return {"smoothing_noise": self._randn(k_critic, batch)}

    def critic_loss(self, params, batch, noise):
        return losses.td3_critic_loss(self.nets, params, batch, noise[self.critic_noise_key],
                                      critic=self.rep.critic)

    def policy_losses(self, params, batch, noise):
        def actor(p):
            return losses.td3_actor_loss(self.nets, p, batch, critic=self.rep.critic)[0], {}

        return {"policy": ("actor_loss", actor)}

    def aux_next_action(self, params, batch, noise):
        """ā′ = π̄(s′) (no smoothing)."""
        return networks.td3_action(self.nets, params, batch.next_obs, target=True)

    def updates_q_target(self, step):
        return self._actor_step(step)


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

    _aux_action_noise_keys = ("flow_action_noise",)

    def noise_keys(self):
        keys = ("next_action_noise", "actor_noise", "alpha_noise")
        return keys + self.aux_noise_keys() + self._more_aux_keys()

    def _aux_action_noise(self, key, batch):
        return {"flow_action_noise": self._randn(key, batch)}

    def _algo_noise(self, k_critic, k_next, k_actor, batch):
        k_alpha, k_pi = jax.random.split(k_actor)
        out = {"next_action_noise": self._randn(k_critic, batch), "actor_noise": self._randn(k_pi, batch),
               "alpha_noise": self._randn(k_alpha, batch)}
        if self.rep.aux_groups:
            out.update(self._aux_action_noise(k_next, batch))
        return out

    def critic_loss(self, params, batch, noise):
        return losses.sac_critic_loss(self.nets, params, batch, noise[self.critic_noise_key],
                                      critic=self.rep.critic)

    def policy_losses(self, params, batch, noise):
        def alpha(p):
            return losses.sac_alpha_loss(self.nets, p, batch, noise["alpha_noise"])[0], {}

        def actor(p):
            return losses.sac_actor_loss(self.nets, p, batch, noise["actor_noise"], critic=self.rep.critic)

        return {"log_alpha": ("alpha_loss", alpha), "policy": ("actor_loss", actor)}

    def aux_next_action(self, params, batch, noise):
        """ā′ ~ π(s′) with the explicit noise `flow_action_noise`."""
        return networks.sac_sample(self.nets, params, batch.next_obs, noise["flow_action_noise"])[0]

    def updates_q_target(self, step):
        return True


_ALGORITHMS = {"td3": TD3, "sac": SAC}


def make_algorithm(algo: str, cfg: SF2Config, representation_cls: type[Representation],
                   dtype=jnp.float32) -> Algorithm:
    return _ALGORITHMS[algo](cfg, representation_cls, dtype)
