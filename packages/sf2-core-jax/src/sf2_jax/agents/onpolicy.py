"""The on-policy trainer: PPO on MinAtar (`--algo ppo`, docs/minatar.md) and FPO on Playground (`--algo fpo`,
docs/fpo.md), each with a Q(s, a) or V critic, and SF²; the policy is a plug-in (`policies_onpolicy`).

PureJaxRL's pattern. An update acts `rollout_length` steps in every env (a `lax.scan` over the batched
`minatar` or `playground_onpolicy` env), computes λ-returns (critic "q") or GAE (critic "v") and trains
`update_epochs` passes of minibatches; an epoch, the updates between two evaluations, is one `lax.scan` of
updates: one compiled program over the seeds (vmapped, or with `seed_loop = "map"` one seed after another;
evaluation always vmapped, the policy alone), its state donated, no host sync inside. One SGD step takes the
critic's loss, the representation's own losses (`representations_onpolicy`), the policy's loss, then the
targets' EMA; each loss's gradient is clipped to `max_grad_norm` (global norm over the groups it trains), each
group has its own Adam state (ψ's flow step a second one unless `shared_adam`); with `shared_torso` (pgx's one
network) the critic's and policy's losses are one loss and one step. An evaluation runs the policy for one
episode on `num_eval_envs` fresh envs per seed, at most `episode_length` steps; run folders, resume, the
NaN guard, the rows and the evaluations batched between checkpoints are the off-policy trainer's."""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from sf2_common.agents import configs, hostloop
from sf2_common.agents.configs import TrainConfig
from sf2_common.agents.evaluation import CheckpointEvaluator, CheckpointJob
from sf2_common.agents.registry import aux_states
from sf2_common.agents.tasks import task_kind
from sf2_common.errors import ConfigError

from sf2_jax import losses_onpolicy as lo
from sf2_jax import networks as nw

from . import minatar, playground_onpolicy
from .checkpoint import Checkpointer
from .configs import validate
from .policies_onpolicy import CategoricalPolicy, FlowPolicy
from .representations_onpolicy import REGISTRY, OnPolicyBatch, build
from .trainer import (  # _seed_map: one seed runs unvmapped
    BatchedSeedsSession,
    SingleDeviceProgram,
    TrainingDiverged,
    TrainResult,
    _seed_map,
    eval_keys,
    run_training,
)

__all__ = ["OnPolicyState", "Rollout", "Program", "get_program", "train", "method_label",
           "evaluate_checkpoint", "evaluate_checkpoint_noises", "TrainingDiverged", "TrainResult"]

# Rows per call of the Q critic's advantage refresh: rollout steps go through it in chunks of about this
# many (state, draw) rows (one step at a time is thousands of small sequential programs on a GPU)
VALUE_ROWS = 1 << 19


class OnPolicyState(NamedTuple):
    """One seed's training state (a leading seed axis in a run's state).

    Attributes:
      params: {group: params} (`representations_onpolicy`: actor, critic or ψ/Q/ζ/targets, encoder/decoder).
      opt_state: {group or "psi:aux": Adam state}.
      env_state: the `minatar.EnvState` (`playground_onpolicy.EnvState`) of the `num_envs` training envs.
      key: the training key.
      env_steps: env steps done.
      updates: on-policy updates done.
    """

    params: dict
    opt_state: dict
    env_state: Any
    key: jax.Array
    env_steps: jax.Array
    updates: jax.Array


class Rollout(NamedTuple):
    """One update's rollout, (T, N) leading axes (T = rollout_length steps of N envs); grids as uint8.

    Attributes:
      obs, action, reward, terminal, truncation: s_t, a_t (the env's), r_t and how the step ended its
        episode.
      next_obs: s′ before any reset.
      next_sample: an action drawn from π(·|s′) at rollout time (a′ where none was taken at s′).
      policy_info: what the policy's loss needs (`CategoricalPolicy.act`, `FlowPolicy.act`).
      value, next_value: the critic's value of s_t and of s′, at rollout time.
      episode_return: the completed episode's return where the step ended one, else 0.
      done: 1 where the step ended an episode (terminal or truncation).
      value_input, next_value_input: what the Q critic's values of s_t and s′ were computed from (the
        policy's K draws or its logits: `value_input`), kept for `advantage_refresh = "pass"`; else None.
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    terminal: jax.Array
    truncation: jax.Array
    next_obs: jax.Array
    next_sample: jax.Array
    policy_info: Any
    value: jax.Array
    next_value: jax.Array
    episode_return: jax.Array
    done: jax.Array
    value_input: Any = None
    next_value_input: Any = None


class Program(SingleDeviceProgram):
    """The compiled pieces of one config (module docstring): `init`, `epoch`, `evaluate`, each over the seed
    axis (`trainer._seed_map`). Build with `get_program(cfg)`."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.image = task_kind(cfg.task).observation == "image"
        make = minatar.make if self.image else playground_onpolicy.make
        self.env = make(cfg.task, cfg.episode_length)
        shape, spec = self.env.spec.obs_shape, self.env.spec
        self.sf2 = cfg.sf2_config(math.prod(shape), spec.num_actions or spec.action_size)
        self.rep = build(cfg.representation, self.sf2, shape, cfg.critic, cfg.shared_torso)
        self.policy = (CategoricalPolicy(self.rep) if cfg.algo == "ppo" else
                       FlowPolicy(cfg, math.prod(shape), spec.action_size, cfg.critic))
        self.obs_dtype = jnp.uint8 if self.image else jnp.float32   # grids are exact as uint8
        self.acting = ("actor",) if self.image else ("actor", "obs_norm")   # the groups the policy reads
        self.sched = configs.schedule(cfg)
        self.num_minibatches = cfg.num_envs * cfg.rollout_length // cfg.minibatch_size
        self._adam = optax.adam(cfg.learning_rate, eps=cfg.adam_eps)
        self._clip = optax.clip_by_global_norm(cfg.max_grad_norm)
        self.aux_states = aux_states(cfg, self.rep)   # {aux group: its Adam state's name in opt_state}
        self.trained = tuple(dict.fromkeys(("actor", *self.rep.critic_groups, *self.rep.aux_groups)))
        # the order an SGD step computes its losses in (names the first NaN when several appear at once)
        self.loss_order = ("critic_loss", *(name for name, _ in self.rep.aux_losses), "actor_loss")
        self._programs: dict[tuple, Callable] = {}

    # ------------------------------------------------------------------ host entry points
    def _program(self, name: str, n_seeds: int, *static):
        key = (name, n_seeds == 1, *static)
        if key not in self._programs:
            fn, in_axes = {"init": (self._init_one, (0,)), "epoch": (self._epoch_one, (0,)),
                           "evaluate": (functools.partial(self._eval_one, *static), (0, 0))}[name]
            # evaluation runs the policy alone, whose small batch (num_eval_envs) a map of seeds in turn
            # would leave latency-bound: it vmaps the seeds under either `seed_loop`
            loop = "vmap" if name == "evaluate" else self.cfg.seed_loop
            self._programs[key] = jax.jit(_seed_map(fn, in_axes, n_seeds, loop),
                                          donate_argnums=(0,) if name == "epoch" else ())
        return self._programs[key]

    def epoch(self, state: OnPolicyState, epoch: int) -> tuple[OnPolicyState, dict, dict]:
        """Train epoch `epoch` (`actor_steps_per_epoch` updates). Returns (state, metric means, first
        non-finite index of each loss: update · SGD steps per update + SGD step, or −1)."""
        del epoch   # every update is alike: no prefill
        with self.precision(), warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*donated buffers were not usable.*")
            return self._program("epoch", state.key.shape[0])(state)

    def evaluate(self, params, seeds, epoch: int, n: int | None = None, obs_noise: float = 0.0) -> jax.Array:
        """Episode returns (n_seeds, n) of the policy in `params` (its `acting` groups suffice): one episode
        on each of `n` (default `num_eval_envs`) fresh envs per seed, drawn with the evaluation key of `epoch`
        (`trainer.eval_keys`); `obs_noise` > 0 adds Gaussian noise of that std to what the policy sees."""
        n = self.cfg.num_eval_envs if n is None else int(n)
        with self.precision():
            program = self._program("evaluate", len(seeds), n, float(obs_noise), self.cfg.deterministic_eval)
            return program({g: params[g] for g in self.acting}, eval_keys(seeds, epoch))

    def evaluate_many(self, params, seeds, epochs) -> jax.Array:
        """Episode returns (len(epochs), n_seeds, num_eval_envs): `evaluate` of each epoch's policy (`params`:
        its `acting` groups, leaves stacked (len(epochs), n_seeds, ...)) with that epoch's keys, in one
        program vmapped over the epochs (sf2_common.agents.hostloop.BatchedEvaluation says why)."""
        static = (self.cfg.num_eval_envs, 0.0, self.cfg.deterministic_eval)
        key = ("evaluate_many", *static)
        if key not in self._programs:
            per_seed = jax.vmap(functools.partial(self._eval_one, *static))
            self._programs[key] = jax.jit(jax.vmap(per_seed))
        keys = jnp.stack([eval_keys(seeds, e) for e in epochs])
        with self.precision():
            return self._programs[key]({g: params[g] for g in self.acting}, keys)

    # ------------------------------------------------------------------ per-seed pieces (vmapped)
    def _init_one(self, key) -> OnPolicyState:
        k_params, k_env, k_train = jax.random.split(key, 3)
        params = self.rep.init(k_params)
        if not self.image:   # the flow policy's key: MinAtar's stream stays as it was
            params.update(self.policy.init(jax.random.fold_in(k_params, 1)))
        opt_state = {g: self._adam.init(params[g]) for g in self.trained}
        opt_state.update({state: self._adam.init(params[g]) for g, state in self.aux_states.items()
                          if state != g})
        env_state = self.env.reset(jax.random.split(k_env, self.cfg.num_envs))
        zero = jnp.zeros((), jnp.int32)
        return OnPolicyState(params, opt_state, env_state, k_train, zero, zero)

    def _act_step(self, params, env_state, key):
        """One step of every training env under the current policy, and what the update needs of it."""
        rep, pol = self.rep, self.policy
        k_act, k_next, k_env = jax.random.split(key, 3)
        obs = env_state.obs
        with jax.named_scope("explore"), self.learner_precision():
            value_input = pol.value_input(params, obs, jax.random.fold_in(k_act, 1))
            value = rep.values(params, obs, value_input)
            action, info = pol.act(params, obs, k_act)
        with jax.named_scope("env_step"):
            env_state, tr = self.env.step(env_state, action, k_env)
        with jax.named_scope("observe"), self.learner_precision():
            next_value_input = pol.value_input(params, tr.next_obs, jax.random.fold_in(k_next, 1))
            next_value = rep.values(params, tr.next_obs, next_value_input)
            next_sample = pol.draw(params, tr.next_obs, k_next)
        keep = self.cfg.critic == "q" and self.cfg.advantage_refresh == "pass"
        done = tr.terminal | tr.truncation
        f32 = jnp.float32
        return env_state, Rollout(
            obs=obs.astype(self.obs_dtype), action=action, reward=tr.reward, terminal=tr.terminal.astype(f32),
            truncation=tr.truncation.astype(f32), next_obs=tr.next_obs.astype(self.obs_dtype),
            next_sample=next_sample, policy_info=info, value=value,
            next_value=next_value, episode_return=jnp.where(done, tr.episode_return, 0.0),
            done=done.astype(f32), value_input=value_input if keep else None,
            next_value_input=next_value_input if keep else None)

    def _loss_step(self, params, opt_state, loss_fn, groups, phase, states=None):
        """One Adam step of `groups` on `loss_fn(params)` → (objective, {metric: scalar}), its gradient
        clipped to `max_grad_norm` (global norm over `groups`), under the scopes `{phase}_grad` and
        `{phase}_adam` (`algorithms.PHASES`); `states[group]` names a group's Adam state (default: its own).
        Returns (params, opt_state, metrics)."""
        def objective(trained):
            return loss_fn({**params, **trained})

        with jax.named_scope(f"{phase}_grad"):
            (_, metrics), grads = jax.value_and_grad(objective, has_aux=True)({g: params[g] for g in groups})
            grads, _ = self._clip.update(grads, self._clip.init(grads))
        params, opt_state = dict(params), dict(opt_state)
        with jax.named_scope(f"{phase}_adam"):
            for g in groups:
                name = (states or {}).get(g, g)
                updates, opt_state[name] = self._adam.update(grads[g], opt_state[name], params[g])
                params[g] = optax.apply_updates(params[g], updates)
        return params, opt_state, metrics

    def _sgd_step(self, params, opt_state, mb: OnPolicyBatch, key):
        """The critic's step, the representation's (in `aux_losses`' order), the actor's, the targets' EMA;
        with `rep.joint_step` one step of L = L_actor + value_coef · L_critic (pgx's; metric `total_loss`),
        profiled as the critic's."""
        cfg, rep = self.cfg, self.rep

        def critic(p, *nets):   # nets: `rep.one_pass`'s, in the joint step
            loss, aux = rep.critic_loss(p, mb, cfg.clip_eps, *nets)
            return cfg.value_coef * loss, {"critic_loss": loss, **aux}

        def actor(p, *nets):
            loss, aux = self.policy.loss(p, mb, cfg, *nets)
            return loss, {"actor_loss": loss, **aux}

        if rep.joint_step:
            def joint(p):
                nets = rep.one_pass(p, mb.obs)   # the torso once, under both heads
                (c, m_c), (a, m_a) = critic(p, nets), actor(p, nets)
                return a + c, {"total_loss": a + c, **m_c, **m_a}

            return self._loss_step(params, opt_state, joint, rep.critic_groups, "critic")
        params, opt_state, metrics = self._loss_step(params, opt_state, critic, rep.critic_groups, "critic")
        noise = rep.aux_noise(key, mb)
        for name, groups in rep.aux_losses:
            def own(p, name=name):
                loss, aux = rep.aux_loss(name, p, mb, noise)
                return loss, {name: loss, **aux}

            params, opt_state, m = self._loss_step(params, opt_state, own, groups, "aux", self.aux_states)
            metrics.update(m)
        params, opt_state, m = self._loss_step(params, opt_state, actor, ("actor",), "policy")
        metrics.update(m)
        return self._targets_step(params), opt_state, metrics

    def _targets_step(self, params):
        """Every target group of the representation (`rep.targets()`) one EMA step toward its online group,
        under the scope `targets`. Returns the params."""
        params = dict(params)
        with jax.named_scope("targets"):
            for target, (online, tau) in self.rep.targets().items():
                params[target] = optax.incremental_update(params[online], params[target], tau)
        return params

    def _update(self, state: OnPolicyState, _):
        """One on-policy update: the rollout, its returns and advantages, `update_epochs` × minibatches."""
        cfg = self.cfg
        T, N = cfg.rollout_length, cfg.num_envs
        key, k_roll, k_perm, k_sgd = jax.random.split(state.key, 4)
        env_state, ro = jax.lax.scan(functools.partial(self._act_step, state.params), state.env_state,
                                     jax.random.split(k_roll, T))
        # a′: the action taken at s′; drawn from π(·|s′) where none was (an episode's or the rollout's end)
        last = jnp.zeros((T, N), bool).at[-1].set(True)
        new = ((ro.done > 0) | last).reshape((T, N) + (1,) * (ro.action.ndim - 2))
        next_action = jnp.where(new, ro.next_sample, jnp.roll(ro.action, -1, axis=0))
        reward = ro.reward * cfg.reward_scaling
        discount = 1.0 - ro.terminal

        def returns(value, next_value):
            """(advantage, target) of the rollout from the critic's values at s and s′, each (T, N)."""
            if cfg.critic == "q":
                target = lo.lambda_returns(reward, discount, ro.truncation, next_value, cfg.discount,
                                           cfg.td_lambda)
                return target - value, target
            return lo.gae(reward, discount, ro.truncation, value, next_value, cfg.discount, cfg.td_lambda)

        with jax.named_scope("returns"):
            advantage, target = returns(ro.value, ro.next_value)
        data = OnPolicyBatch(obs=ro.obs, action=ro.action, reward=reward, discount=discount,
                             truncation=ro.truncation, next_obs=ro.next_obs, next_action=next_action,
                             policy_info=ro.policy_info, value=ro.value, advantage=advantage, target=target)
        flat = jax.tree_util.tree_map(lambda x: x.reshape((T * N,) + x.shape[2:]), data)
        params = state.params
        if not self.image and cfg.normalize_observations:   # the rollout's observations, before the SGD
            params = {**params, "obs_norm": nw.update_normalizer(params["obs_norm"], ro.obs, self.sf2)}
        E, K = cfg.update_epochs, self.num_minibatches
        perms = jax.vmap(lambda k: jax.random.permutation(k, T * N))(jax.random.split(k_perm, E))

        def current_values(params, obs, inputs):
            """The current critic's values (T, N) of `obs` (T, N, ...): V over all T·N states at once;
            Q's mean over its rollout-time inputs `inputs` (T, ...) in chunks of steps (`VALUE_ROWS` rows)."""
            if inputs is None:
                flat_obs = obs.reshape((T * N,) + obs.shape[2:]).astype(jnp.float32)
                return self.rep.values(params, flat_obs, None).reshape(T, N)
            rows_per_step = max(x.size // (T * x.shape[-1]) for x in jax.tree_util.tree_leaves(inputs))
            return jax.lax.map(lambda x: self.rep.values(params, x[0].astype(jnp.float32), x[1]),
                               (obs, inputs), batch_size=max(1, min(T, VALUE_ROWS // rows_per_step)))

        def refreshed(params, flat):
            """`flat` with its advantages and targets from the current critic (`advantage_refresh = "pass"`):
            GAE from V, or λ-returns from Q at the rollout's draws (the policy's side stays the rollout's)."""
            with jax.named_scope("returns"), self.learner_precision():
                value = current_values(params, ro.obs, ro.value_input)
                next_value = current_values(params, ro.next_obs, ro.next_value_input)
                advantage, target = returns(value, next_value)
            return flat._replace(advantage=advantage.reshape(-1), target=target.reshape(-1))

        def sgd(flat, carry, xs):
            idx, k = xs
            mb = jax.tree_util.tree_map(lambda x: jnp.take(x, idx, axis=0), flat)
            mb = mb._replace(obs=mb.obs.astype(jnp.float32), next_obs=mb.next_obs.astype(jnp.float32))
            with self.learner_precision():
                params, opt_state, metrics = self._sgd_step(*carry, mb, k)
            return (params, opt_state), metrics

        def one_pass(carry, xs):
            """One pass over the rollout: `K` minibatches of one permutation."""
            perm, keys = xs
            data = refreshed(carry[0], flat) if cfg.advantage_refresh == "pass" else flat
            return jax.lax.scan(functools.partial(sgd, data), carry,
                                (perm.reshape(K, cfg.minibatch_size), keys))

        (params, opt_state), metrics = jax.lax.scan(
            one_pass, (params, state.opt_state), (perms, jax.tree_util.tree_map(
                lambda k: k.reshape((E, K) + k.shape[1:]), jax.random.split(k_sgd, E * K))))
        metrics = jax.tree_util.tree_map(lambda m: m.reshape((E * K,) + m.shape[2:]), metrics)
        state = OnPolicyState(params, opt_state, env_state, key, state.env_steps + T * N, state.updates + 1)
        return state, (metrics, jnp.sum(ro.episode_return), jnp.sum(ro.done))

    def _epoch_one(self, state: OnPolicyState):
        state, (metrics, returns, episodes) = jax.lax.scan(self._update, state, None,
                                                           length=self.sched.actor_steps_per_epoch)
        means = {name: jnp.mean(m) for name, m in metrics.items()}       # m: (updates, SGD steps)
        first_bad = {}
        for name in self.loss_order:
            finite = jnp.isfinite(metrics[name]).reshape(-1)
            first_bad[name] = jnp.where(jnp.all(finite), -1, jnp.argmin(finite))
        count = jnp.sum(episodes)
        means["train_return"] = jnp.sum(returns) / jnp.maximum(count, 1.0)
        means["train_episodes"] = count
        sched = self.sched
        means["sgd_steps"] = jnp.asarray(sched.actor_steps_per_epoch * sched.sgd_steps_per_actor_step)
        return state, means, first_bad

    def _eval_one(self, n: int, obs_noise: float, deterministic: bool, params, key):
        """Returns (n,) of one episode on each of n fresh envs: a `lax.while_loop` until every episode
        ended (a terminal, or the truncation at `episode_length` steps); `params` the `acting` groups."""
        k_reset, k_run = jax.random.split(key)

        def running(carry):
            _, _, alive, t, _ = carry
            return jnp.any(alive) & (t < self.cfg.episode_length)

        def step(carry):
            env_state, ret, alive, t, k = carry
            k, k_act, k_env, k_noise = jax.random.split(k, 4)
            obs = env_state.obs
            if obs_noise:   # its own key: the acting and the games' randomness stay the noise-free run's
                obs = obs + obs_noise * jax.random.normal(k_noise, obs.shape, obs.dtype)
            with self.learner_precision():
                action = self.policy.evaluate(params, obs, k_act, deterministic)
            env_state, tr = self.env.step(env_state, action, k_env)
            ret = ret + jnp.where(alive, tr.reward, 0.0)
            return env_state, ret, alive & ~(tr.terminal | tr.truncation), t + 1, k

        carry = (self.env.reset(jax.random.split(k_reset, n)), jnp.zeros((n,), jnp.float32),
                 jnp.ones((n,), bool), jnp.zeros((), jnp.int32), k_run)
        return jax.lax.while_loop(running, step, carry)[1]


@functools.lru_cache(maxsize=8)
def get_program(cfg: TrainConfig) -> Program:
    """The compiled pieces of one config, cached (the last 8 configs'): runs with equal configs reuse them.

    Args:
      cfg: the run's `TrainConfig` (frozen, hashable), `--algo ppo` on a MinAtar task or `--algo fpo` on a
        Playground task.

    Returns:
      Its `Program`.

    Raises:
      ConfigError: a task of another kind, pgx not installed, or an unknown representation.
    """
    return Program(cfg)


def method_label(cfg: TrainConfig) -> str:
    """'PPO-Q+SF² w AE', 'PPO-Q', 'PPO' (critic "v"), 'PPO (shared torso)', 'FPO+Q(λ)+SF²', 'FPO' (critic
    "v"), ...: the method's label in tables and plots."""
    if cfg.algo == "fpo":
        return ("FPO+Q(λ)" if cfg.critic == "q" else "FPO") + ("+SF²" if cfg.representation == "sf2" else "")
    rep = REGISTRY.label(cfg.representation)
    shared = " (shared torso)" if cfg.shared_torso else ""
    return ("PPO-Q" if cfg.critic == "q" else "PPO") + (f"+{rep}" if rep else "") + shared


def _versions() -> dict:
    return hostloop.versions(("jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "pgx", "sf2-core-jax",
                              "sf2-common"))


def train(cfg: TrainConfig, seeds, out, *, resume: bool = True, fresh: bool = False, progress: bool = True,
          hook: Callable[[str, int], None] | None = None, stop_after_epoch: int | None = None,
          plot: bool = True, log=()) -> TrainResult:
    """Train one `--algo ppo` config for every seed (one vmapped program) into a run folder.

    Args:
      cfg: the run's `TrainConfig`.
      seeds: the seeds, as `parse_seeds` takes them ("0-3", "0,2,5", 7, a sequence of ints).
      out: the run folder (docs/run-folders.md); one writer at a time (a lock file).
      resume: resume from the folder's newest checkpoint that restores completely.
      fresh: delete the folder's previous contents first.
      progress: show the progress bar.
      hook: `hook(event, epoch)`, called at the points of `hostloop.run_epochs` (tests simulate a kill).
      stop_after_epoch: end the run early, after that epoch's checkpoint, as a kill would.
      plot: write the learning-curve PNG.
      log: the sinks every metrics row also goes to (`sf2_common.agents.loggers`): tensorboard, wandb.

    Returns:
      A `TrainResult`: the run folder, its rows, the final `OnPolicyState` of all seeds, the seeds, the
      checkpoint epoch resumed from.

    Raises:
      ConfigError: bad input (also an off-policy algo), before anything is compiled.
      RunFolderError: a run folder that cannot be used (another run's, another core's, in use).
      TrainingDiverged: a NaN or inf loss (nothing of that epoch is written).
    """
    seeds = configs.parse_seeds(seeds)
    validate(cfg, seeds)
    if cfg.algo not in configs.ONPOLICY_ALGOS:
        raise ConfigError(f"algo {cfg.algo!r} is the off-policy trainer's (sf2_jax.agents.trainer.train); "
                          f"the on-policy trainer takes {', '.join(configs.ONPOLICY_ALGOS)}")
    devices = jax.devices()[:1]
    return run_training(cfg, seeds, out, program_of=get_program, session_of=_Session, label=method_label,
                        hardware=hostloop.hardware(d.device_kind for d in devices if d.platform != "cpu"),
                        versions=_versions(), resume=resume, fresh=fresh, progress=progress, hook=hook,
                        stop_after_epoch=stop_after_epoch, plot=plot, log=log)


class _Session(BatchedSeedsSession):
    """The `sf2_common.agents.hostloop.Session` of one run: the vmapped state of all seeds, evaluated in
    batches between checkpoints when `checkpoint_every` > 1."""

    def evaluate(self, epoch: int) -> np.ndarray:
        return np.asarray(self.program.evaluate(self.state.params, self.seeds, epoch))

    def acting(self):
        return {g: self.state.params[g] for g in self.program.acting}

    def evaluate_stacked(self, params, epochs: list[int]) -> jax.Array:
        return self.program.evaluate_many(params, self.seeds, epochs)


def _restore_acting(ckpt: Checkpointer, job: CheckpointJob):
    """(the policy's parameters: its `acting` groups, meta) of checkpoint `job.epoch`; the rest of the state
    is dropped."""
    program = get_program(job.cfg)
    state, meta = ckpt.restore(job.epoch, program.abstract_state(job.seeds))
    return {g: state.params[g] for g in program.acting}, meta


def _act(acting, job: CheckpointJob) -> list[np.ndarray]:
    """Episode returns (seeds, episodes) per noise std of `job`: the run's own evaluation of that epoch
    (its key, `num_eval_envs` envs) when `job.episodes` is None, else `job.episodes` fresh envs."""
    program = get_program(job.eval_cfg)
    epoch, n = (job.epoch, None) if job.episodes is None else (job.key, job.episodes)
    return [np.asarray(program.evaluate(acting, job.seeds, epoch, n, noise))
            for noise in job.noises]


# evaluate_checkpoint(out, epoch, num_eval_envs, deterministic, obs_noise) and evaluate_checkpoint_noises(...,
# noises): the framework-free half is sf2_common.agents.evaluation's (documented there)
_EVALUATOR = CheckpointEvaluator("jax", TrainConfig, Checkpointer, _restore_acting, _act)
evaluate_checkpoint = _EVALUATOR.evaluate_checkpoint
evaluate_checkpoint_noises = _EVALUATOR.evaluate_checkpoint_noises
