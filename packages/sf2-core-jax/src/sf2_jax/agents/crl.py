"""The goal-conditioned trainer (`--algo crl`, `ant-goal`; docs/crl.md): CRL as JaxGCRL trains it; CRL+SF².

CRL's critic is the energy −‖φ(s, a) − ψ(g)‖ of a state-action encoder φ and a goal encoder ψ (swish
MLPs), trained by InfoNCE on hindsight goals from the same episode's future (`goal_replay`); its actor is
goal-conditioned SAC on that energy (`sf2_jax.losses_crl`). With representation "sf2", φ(s, a) is also SF²'s
feature ψ(s, a): after the critic's step, SF²'s flow loss (`sf2_jax.losses.velocity_fields` and
`flow_field_loss`, unchanged) trains φ (one Adam state with `shared_adam`) and ζ on the logged
(s, a, s′, a′), and the targets φ̄, ζ̄ move by EMA. An actor step steps every env once (the policy acts,
also in the prefill), then, after the prefill, runs `grad_updates_per_step` SGD steps (actor and
temperature, critic, flow); an epoch is one compiled `lax.scan` of actor steps, vmapped over seeds, its state
donated. Evaluation: the deterministic policy tanh(μ), one episode from fixed start states. Run folders,
resume, the NaN guard and the rows: `trainer.run_training` and `sf2_common.agents.hostloop`.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from sf2_common.agents import configs, hostloop
from sf2_common.agents.configs import TrainConfig
from sf2_common.agents.evaluation import CheckpointEvaluator, CheckpointJob
from sf2_common.agents.registry import Registry
from sf2_common.errors import ConfigError

from sf2_jax import losses
from sf2_jax import losses_crl as lc
from sf2_jax import networks as nw

from . import antgoal
from .checkpoint import Checkpointer
from .goal_replay import TrajectoryBuffer
from .trainer import (  # _seed_map: one seed runs unvmapped
    SeedsSession,
    SingleDeviceProgram,
    TrainingDiverged,
    TrainResult,
    _seed_map,
    episode_returns,
    eval_keys,
    run_training,
)

__all__ = ["CRLState", "FLOW_FEATURE_NORMS", "flow_features", "Encoder", "Actor", "REGISTRY", "Program",
           "get_program", "train", "method_label",
           "validate", "evaluate_checkpoint", "evaluate_checkpoint_noises", "TrainingDiverged", "TrainResult"]

_LECUN = nn.initializers.variance_scaling(1 / 3, "fan_in", "uniform")   # JaxGCRL's kernels; biases zero
FLOW_FEATURE_NORMS = ("none", "l2")   # φ as SF²'s flow takes it (`flow_features`)
_L2_EPS = 1e-12


def flow_features(phi, norm: str):
    """φ(s, a) as SF²'s flow takes it (the config's `flow_feature_norm`; InfoNCE always takes φ itself).

    "none": φ; "l2": φ / √(‖φ‖² + 1e-12), each row on the unit sphere, so the flow sees φ's direction
    only: its gradient in φ is orthogonal to φ (the flow cannot change φ's scale, which InfoNCE sets) and
    its velocity ζ(x, k)φ/‖φ‖ does not grow with φ.

    Args:
      phi: φ (..., F).
      norm: one of `FLOW_FEATURE_NORMS`.

    Returns:
      The features (..., F).
    """
    if norm == "none":
        return phi
    return phi / jnp.sqrt(jnp.sum(phi * phi, axis=-1, keepdims=True) + _L2_EPS)


class Encoder(nn.Module):
    """An MLP: Dense → swish per hidden width, then Dense to `out` (JaxGCRL's encoder, no LayerNorm)."""

    hidden: tuple[int, ...]
    out: int

    @nn.compact
    def __call__(self, x):
        for width in self.hidden:
            x = nn.swish(nn.Dense(width, kernel_init=_LECUN)(x))
        return nn.Dense(self.out, kernel_init=_LECUN)(x)


class Actor(nn.Module):
    """JaxGCRL's actor: the encoder's torso, a mean head, a raw log σ head (`losses_crl.actor_log_std`)."""

    hidden: tuple[int, ...]
    action_size: int

    @nn.compact
    def __call__(self, x):
        for width in self.hidden:
            x = nn.swish(nn.Dense(width, kernel_init=_LECUN)(x))
        mean = nn.Dense(self.action_size, kernel_init=_LECUN)(x)
        return mean, lc.actor_log_std(nn.Dense(self.action_size, kernel_init=_LECUN)(x))


class _Representation:
    """What `--repr` selects for `--algo crl` (the registry's vocabulary)."""

    name = ""
    label = ""
    supported_algos = ("crl",)


REGISTRY = Registry("jax", group="sf2.representations.crl", baselines=())


@REGISTRY.register
class _Plain(_Representation):
    name, label = "none", ""


@REGISTRY.register
class _SF2(_Representation):
    name, label = "sf2", "SF²"


class CRLState(NamedTuple):
    """One seed's training state (a leading seed axis in a run's state).

    Attributes:
      params: {"sa_encoder", "g_encoder", "actor", "log_alpha"}; with SF² also "zeta", "target_zeta",
        "target_sa_encoder" and "obs_norm" (the statistics that normalize the flow's s′).
      opt_state: {"sa_encoder", "g_encoder", "actor", "log_alpha"}, with SF² "zeta" (and "sa_encoder:aux"
        unless `shared_adam`: φ's own Adam state in the flow step).
      env_state: the `ant-goal` envs' Brax state.
      buffer: the `TrajectoryBuffer`'s state.
      episode: (num_envs,) int32, each env's episode counter.
      key: the training key.
      env_steps, grad_steps: counters.
      eval_start: the evaluation episodes' start states.
    """

    params: dict
    opt_state: dict
    env_state: Any
    buffer: dict
    episode: jax.Array
    key: jax.Array
    env_steps: jax.Array
    grad_steps: jax.Array
    eval_start: Any


class Program(SingleDeviceProgram):
    """The compiled pieces of one config (module docstring): `init`, `epoch`, `evaluate`, each over the seed
    axis (`trainer._seed_map`). Build with `get_program(cfg)`."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.spec = antgoal.make(cfg.episode_length, cfg.physics)   # Brax's spring pipeline or MJX
        S, A, F = self.spec.state_size, self.spec.action_size, cfg.feature_size
        self.goal_indices = jnp.array(self.spec.goal_indices)
        self.sf2_on = cfg.representation == "sf2"
        self.sf2 = cfg.sf2_config(S, A)      # ζ's sizes and the flow's settings (its ψ network is unused)
        self.nets = nw.make_networks(self.sf2, "sac")
        self.sa_encoder = Encoder(tuple(cfg.hidden_sizes), F)
        self.g_encoder = Encoder(tuple(cfg.hidden_sizes), F)
        self.actor = Actor(tuple(cfg.hidden_sizes), A)
        self.buffer = TrajectoryBuffer(cfg.max_replay_size // cfg.num_envs, cfg.num_envs, S, A)
        self.sched = configs.schedule(cfg)
        self.target_entropy = -cfg.target_entropy_scale * A
        self._adam = optax.adam(cfg.learning_rate, eps=cfg.adam_eps)
        self._alpha_adam = optax.adam(cfg.alpha_learning_rate)
        # φ's Adam state in the flow step: its InfoNCE step's (`shared_adam`, SF²'s authors') or its own
        self.flow_state = "sa_encoder" if cfg.shared_adam else "sa_encoder:aux"
        flow = ("flow_loss",) if self.sf2_on else ()
        self.loss_order = ("actor_loss", "alpha_loss", "critic_loss", *flow)
        self._programs: dict[tuple, Callable] = {}

    # ------------------------------------------------------------------ host entry points
    def _program(self, name: str, n_seeds: int):
        key = (name, n_seeds == 1)
        if key not in self._programs:
            fn, in_axes = {"init": (self._init_one, (0,)), "epoch": (self._epoch_one, (0, None)),
                           "evaluate": (self._eval_one, (0, 0, 0))}[name]
            self._programs[key] = jax.jit(_seed_map(fn, in_axes, n_seeds),
                                          donate_argnums=(0,) if name == "epoch" else ())
        return self._programs[key]

    def epoch(self, state: CRLState, epoch: int) -> tuple[CRLState, dict, dict]:
        """Train epoch `epoch` (1-based). Returns (state, metric means, first non-finite index per loss)."""
        first = jnp.asarray((epoch - 1) * self.sched.actor_steps_per_epoch, jnp.int32)
        with self.precision(), warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*donated buffers were not usable.*")
            return self._program("epoch", state.key.shape[0])(state, first)

    def evaluate(self, actor, eval_start, seeds, epoch: int) -> jax.Array:
        """Episode returns (n_seeds, num_eval_envs) of the deterministic policy `actor` (its parameters)
        from `eval_start`: the steps within 0.5 of the goal, per episode."""
        with self.precision():
            return self._program("evaluate", len(seeds))(actor, eval_start, eval_keys(seeds, epoch))

    # ------------------------------------------------------------------ per-seed pieces (vmapped)
    def _init_one(self, key) -> CRLState:
        cfg, S, A = self.cfg, self.spec.state_size, self.spec.action_size
        k_sa, k_g, k_actor, k_sf2, k_env, k_train = jax.random.split(key, 6)
        G = len(self.spec.goal_indices)
        params = {"sa_encoder": self.sa_encoder.init(k_sa, jnp.zeros((1, S + A)))["params"],
                  "g_encoder": self.g_encoder.init(k_g, jnp.zeros((1, G)))["params"],
                  "actor": self.actor.init(k_actor, jnp.zeros((1, self.spec.obs_size)))["params"],
                  "log_alpha": jnp.asarray(cfg.init_log_alpha, jnp.float32)}
        opt_state = {"sa_encoder": self._adam.init(params["sa_encoder"]),
                     "g_encoder": self._adam.init(params["g_encoder"]),
                     "actor": self._adam.init(params["actor"]),
                     "log_alpha": self._alpha_adam.init(params["log_alpha"])}
        if self.sf2_on:
            core = nw.init_params(self.nets, k_sf2, dtype=jnp.float32)
            params.update(zeta=core["zeta"], target_zeta=core["target_zeta"], obs_norm=core["obs_norm"],
                          target_sa_encoder=jax.tree_util.tree_map(jnp.copy, params["sa_encoder"]))
            opt_state["zeta"] = self._adam.init(params["zeta"])
            if self.flow_state != "sa_encoder":
                opt_state[self.flow_state] = self._adam.init(params["sa_encoder"])
        n, m = cfg.num_envs, cfg.num_eval_envs
        both = self.spec.env.reset(jax.random.split(k_env, n + m))
        env_state = jax.tree_util.tree_map(lambda x: x[:n], both)
        eval_start = jax.tree_util.tree_map(lambda x: x[n:], both)
        zero = jnp.zeros((), jnp.int32)
        return CRLState(params, opt_state, env_state, self.buffer.init(), jnp.zeros((n,), jnp.int32), k_train,
                        zero, zero, eval_start)

    def _policy(self, actor, obs, noise):
        """(tanh(μ + σξ), log π) at observations [state, goal]."""
        mean, log_std = self.actor.apply({"params": actor}, obs)
        return lc.squashed_gaussian_sample(mean, log_std, noise)

    def _energy(self, params, state, action, goal):
        phi = self.sa_encoder.apply({"params": params["sa_encoder"]}, jnp.concatenate([state, action], -1))
        return phi, self.g_encoder.apply({"params": params["g_encoder"]}, goal)

    def _adam_step(self, tx, grads, opt, params):
        updates, opt = tx.update(grads, opt, params)
        return optax.apply_updates(params, updates), opt

    def _sgd_step(self, params, opt_state, sample, noise):
        """Actor and temperature (at the pre-step critic, JaxGCRL's order), critic, then SF²'s flow and the
        targets' EMA, each part under the off-policy trainer's `jax.named_scope`s (`algorithms.PHASES`: the
        flow is the "aux" loss), for `bench.step_cost`. Returns (params, opt_state, metrics)."""
        cfg = self.cfg
        params, opt_state = dict(params), dict(opt_state)
        goal = sample.goal_state[:, self.goal_indices]
        obs = jnp.concatenate([sample.state, goal], axis=-1)
        critic = jax.lax.stop_gradient({g: params[g] for g in ("sa_encoder", "g_encoder")})

        def actor_loss(actor):
            action, log_prob = self._policy(actor, obs, noise["actor"])
            q = lc.energy(*self._energy(critic, sample.state, action, goal))
            loss, aux = lc.crl_actor_loss(log_prob, q, params["log_alpha"])
            return loss, (log_prob, aux)

        with jax.named_scope("policy_grad"):
            (a_loss, (log_prob, a_aux)), grad = jax.value_and_grad(actor_loss, has_aux=True)(params["actor"])
            (al_loss, al_aux), al_grad = jax.value_and_grad(
                lambda la: lc.crl_alpha_loss(la, log_prob, self.target_entropy), has_aux=True
            )(params["log_alpha"])
        with jax.named_scope("policy_adam"):
            params["actor"], opt_state["actor"] = self._adam_step(self._adam, grad, opt_state["actor"],
                                                                  params["actor"])
            params["log_alpha"], opt_state["log_alpha"] = self._adam_step(
                self._alpha_adam, al_grad, opt_state["log_alpha"], params["log_alpha"])

        def critic_loss(enc):
            phi, psi = self._energy(enc, sample.state, sample.action, goal)
            return lc.crl_critic_loss(phi, psi, cfg.logsumexp_penalty, cfg.contrastive_loss)

        with jax.named_scope("critic_grad"):
            (c_loss, c_aux), grad = jax.value_and_grad(critic_loss, has_aux=True)(critic)
        with jax.named_scope("critic_adam"):
            for g in critic:
                params[g], opt_state[g] = self._adam_step(self._adam, grad[g], opt_state[g], critic[g])
        metrics = {"actor_loss": a_loss, "alpha_loss": al_loss, "critic_loss": c_loss, **a_aux, **al_aux,
                   **c_aux}
        if self.sf2_on:
            params, opt_state, flow = self._flow_step(params, opt_state, sample, noise)
            metrics.update(flow)
        return params, opt_state, metrics

    def _flow_step(self, params, opt_state, sample, noise):
        """SF²'s flow loss on φ (Adam state `flow_state`) and ζ, fed `flow_features` of φ and of φ̄′, then φ̄
        and ζ̄ by EMA."""
        cfg = self.cfg
        with jax.named_scope("aux_grad"):
            next_sa = jnp.concatenate([sample.next_state, sample.next_action], -1)
            target_phi = self.sa_encoder.apply({"params": params["target_sa_encoder"]}, next_sa)
            next_features = jax.lax.stop_gradient(flow_features(target_phi, cfg.flow_feature_norm))
            x1 = nw.normalize(sample.next_state, params["obs_norm"])

        def flow_loss(trained):
            p = {**params, **trained}
            features = flow_features(self.sa_encoder.apply(
                {"params": p["sa_encoder"]}, jnp.concatenate([sample.state, sample.action], -1)),
                cfg.flow_feature_norm)
            bootstrap = None if cfg.gamma_su == 0 else next_features
            online, target = losses.velocity_fields(self.nets, p, features, bootstrap, noise["flow_time"])
            return losses.flow_field_loss(self.sf2, online, target, x1, noise["eps"], noise["flow_time"],
                                          sample.last)

        trained = {g: params[g] for g in ("sa_encoder", "zeta")}
        with jax.named_scope("aux_grad"):
            (loss, aux), grad = jax.value_and_grad(flow_loss, has_aux=True)(trained)
        with jax.named_scope("aux_adam"):
            params["sa_encoder"], opt_state[self.flow_state] = self._adam_step(
                self._adam, grad["sa_encoder"], opt_state[self.flow_state], params["sa_encoder"])
            params["zeta"], opt_state["zeta"] = self._adam_step(self._adam, grad["zeta"], opt_state["zeta"],
                                                                params["zeta"])
        with jax.named_scope("targets"):
            params["target_sa_encoder"] = losses.ema_update(params["target_sa_encoder"], params["sa_encoder"],
                                                            cfg.tau)
            params["target_zeta"] = losses.ema_update(params["target_zeta"], params["zeta"], cfg.tau_zeta)
        return params, opt_state, {"flow_loss": loss, **aux}

    def _noise(self, key):
        """Every random input of one SGD step: the goal sample's key, ξ of the actor, ε and k of the flow."""
        B, S, A = self.cfg.batch_size, self.spec.state_size, self.spec.action_size
        k_sample, k_actor, k_eps, k_time = jax.random.split(key, 4)
        return k_sample, {"actor": jax.random.normal(k_actor, (B, A)),
                          "eps": jax.random.normal(k_eps, (B, S)),
                          "flow_time": jax.random.uniform(k_time, (B,))}

    def _actor_step(self, state: CRLState, actor_step):
        """Act in every env with the policy, store the step, then `grad_updates_per_step` SGD steps unless
        in the prefill (computed and discarded there by `jnp.where`: one program, no `lax.cond`); its parts
        under the off-policy trainer's scopes (`trainer.ACTOR_PHASES`)."""
        cfg, S = self.cfg, self.spec.state_size
        train = actor_step >= self.sched.prefill_actor_steps
        key, k_act, k_sgd = jax.random.split(state.key, 3)
        obs = state.env_state.obs
        with jax.named_scope("explore"), self.learner_precision():
            action, _ = self._policy(state.params["actor"], obs,
                                     jax.random.normal(k_act, (cfg.num_envs, self.spec.action_size)))
        with jax.named_scope("env_step"):
            env_state = self.spec.env.step(state.env_state, action)
        params = dict(state.params)
        with jax.named_scope("observe"):
            buffer = self.buffer.insert(state.buffer, obs[:, :S], action, state.episode)
            if self.sf2_on:
                params["obs_norm"] = nw.update_normalizer(params["obs_norm"], obs[:, :S], self.sf2)

        def sgd(carry, k):
            params, opt_state, steps = carry
            with jax.named_scope("step_noise"):
                k_sample, noise = self._noise(k)
            with jax.named_scope("sample"):
                sample = self.buffer.sample(buffer, k_sample, cfg.batch_size, cfg.discount)
            with self.learner_precision():
                new_params, new_opt, metrics = self._sgd_step(params, opt_state, sample, noise)
            keep = lambda n, o: jnp.where(train, n, o)   # noqa: E731
            params = jax.tree_util.tree_map(keep, new_params, params)
            opt_state = jax.tree_util.tree_map(keep, new_opt, opt_state)
            return (params, opt_state, steps + train.astype(steps.dtype)), metrics

        (params, opt_state, grad_steps), metrics = jax.lax.scan(
            sgd, (params, state.opt_state, state.grad_steps),
            jax.random.split(k_sgd, cfg.grad_updates_per_step))
        env_steps = state.env_steps + self.sched.env_steps_per_actor_step
        state = CRLState(params, opt_state, env_state, buffer, state.episode + (env_state.done > 0), key,
                         env_steps, grad_steps, state.eval_start)
        return state, (metrics, train, jnp.sum(env_state.done > 0))

    def _epoch_one(self, state: CRLState, first_actor_step):
        steps = first_actor_step + jnp.arange(self.sched.actor_steps_per_epoch, dtype=jnp.int32)
        state, (metrics, trained, ended) = jax.lax.scan(self._actor_step, state, steps)
        mask = trained.astype(jnp.float32)[:, None]              # (actor steps, 1)
        count = jnp.maximum(jnp.sum(trained) * self.cfg.grad_updates_per_step, 1)
        means, first_bad = {}, {}
        for name, m in metrics.items():                          # m: (actor steps, grad updates)
            means[name] = jnp.sum(jnp.where(mask > 0, m, 0.0)) / count
            if name in self.loss_order:
                flat = (jnp.isfinite(m) | (mask == 0)).reshape(-1)
                first_bad[name] = jnp.where(jnp.all(flat), -1, jnp.argmin(flat))
        means["sgd_steps"] = jnp.sum(trained) * self.cfg.grad_updates_per_step
        # episodes the training envs ended, and their mean length were the epoch a steady state (env steps
        # over episodes): a short one says the Ant falls (JaxGCRL logs its evaluation's episode length)
        episodes = jnp.sum(ended)
        means["train_episodes"] = episodes
        means["train_episode_length"] = self.cfg.num_envs * steps.shape[0] / jnp.maximum(episodes, 1)
        return state, means, first_bad

    def _eval_one(self, actor, eval_start, key):
        def act(obs, _):
            with self.learner_precision():
                return jnp.tanh(self.actor.apply({"params": actor}, obs)[0])

        return episode_returns(self.spec.env, eval_start, act, key, self.sched.eval_actor_steps)


@functools.lru_cache(maxsize=8)
def get_program(cfg: TrainConfig) -> Program:
    """The compiled pieces of one config, cached (the last 8 configs').

    Args:
      cfg: the run's `TrainConfig` (frozen, hashable), `--algo crl` on `ant-goal`.

    Returns:
      Its `Program`.
    """
    return Program(cfg)


def method_label(cfg: TrainConfig) -> str:
    """'CRL' or 'CRL+SF²': the method's label in tables and plots."""
    rep = REGISTRY.label(cfg.representation)
    return "CRL" + (f"+{rep}" if rep else "")


def validate(cfg: TrainConfig, seeds=(0,)) -> TrainConfig:
    """Check a `--algo crl` config before anything is compiled (`configs.validate` with this trainer's
    registry, then CRL's own fields).

    Args:
      cfg: the config.
      seeds: the seeds.

    Returns:
      `cfg`.

    Raises:
      ConfigError: naming the field, its value and what is valid.
    """
    configs.validate(cfg, seeds, REGISTRY)
    if cfg.algo != "crl":
        raise ConfigError(f"algo {cfg.algo!r} is not this trainer's: the goal-conditioned trainer takes crl")
    if cfg.batch_size < 2:
        configs.bad_field("batch_size", cfg.batch_size, "must be >= 2 (InfoNCE's negatives are the batch's)")
    if cfg.max_replay_size // cfg.num_envs < 2:
        configs.bad_field("max_replay_size", cfg.max_replay_size, f"must hold at least 2 steps of every env "
                          f"(>= 2 × num_envs = {2 * cfg.num_envs})")
    p = cfg.logsumexp_penalty
    if not isinstance(p, (int, float)) or isinstance(p, bool) or not np.isfinite(p) or p < 0:
        configs.bad_field("logsumexp_penalty", p, "must be a finite number >= 0")
    if cfg.contrastive_loss not in lc.CONTRASTIVE_LOSSES:
        configs.bad_field("contrastive_loss", cfg.contrastive_loss, f"must be one of {lc.CONTRASTIVE_LOSSES} "
                          "(InfoNCE over a row's goals, over a goal's state-actions, or both)")
    if cfg.flow_feature_norm not in FLOW_FEATURE_NORMS:
        configs.bad_field("flow_feature_norm", cfg.flow_feature_norm, f"must be one of {FLOW_FEATURE_NORMS} "
                          "(φ itself, or φ/‖φ‖, as SF²'s flow takes it)")
    if cfg.flow_feature_norm != "none" and cfg.representation != "sf2":
        configs.bad_field("flow_feature_norm", cfg.flow_feature_norm, "only --repr sf2 has a flow; "
                          f"--repr {cfg.representation} takes 'none'")
    return cfg


def _versions() -> dict:
    return hostloop.versions(("jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "brax", "mujoco",
                              "mujoco-mjx", "sf2-core-jax", "sf2-common"))


def train(cfg: TrainConfig, seeds, out, *, resume: bool = True, fresh: bool = False, progress: bool = True,
          hook: Callable[[str, int], None] | None = None, stop_after_epoch: int | None = None,
          plot: bool = True, log=()) -> TrainResult:
    """Train one `--algo crl` config for every seed (one vmapped program) into a run folder.

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
      A `TrainResult`: the run folder, its rows, the final `CRLState` of all seeds, the seeds, the
      checkpoint epoch resumed from.

    Raises:
      ConfigError: bad input, before anything is compiled.
      RunFolderError: a run folder that cannot be used.
      TrainingDiverged: a NaN or inf loss (nothing of that epoch is written).
    """
    seeds = configs.parse_seeds(seeds)
    validate(cfg, seeds)
    devices = jax.devices()[:1]
    return run_training(cfg, seeds, out, program_of=get_program, session_of=_Session, label=method_label,
                        hardware=hostloop.hardware(d.device_kind for d in devices if d.platform != "cpu"),
                        versions=_versions(), resume=resume, fresh=fresh, progress=progress, hook=hook,
                        stop_after_epoch=stop_after_epoch, plot=plot, log=log)


class _Session(SeedsSession):
    """The `sf2_common.agents.hostloop.Session` of one run: the vmapped state of all seeds."""

    def evaluate(self, epoch: int) -> np.ndarray:
        return np.asarray(self.program.evaluate(self.state.params["actor"], self.state.eval_start, self.seeds,
                                                epoch))

    @staticmethod
    def eval_metrics(returns: np.ndarray) -> dict:
        """JaxGCRL's `episode_success_any`: the share of episodes that reached the goal at least once (a
        return > 0: the return counts the steps within reach of the goal)."""
        return {"eval_success_any": float(np.mean(returns > 0))}


def _restore_acting(ckpt: Checkpointer, job: CheckpointJob):
    """((the actor's parameters, the evaluation start states), meta) of checkpoint `job.epoch`."""
    state, meta = ckpt.restore(job.epoch, get_program(job.cfg).abstract_state(job.seeds))
    return (state.params["actor"], state.eval_start), meta


def _act(restored, job: CheckpointJob) -> list[np.ndarray]:
    """Episode returns (seeds, episodes) of the run's own evaluation of that epoch: the deterministic policy
    from the run's start states (fresh start states, a stochastic policy and observation noise are not
    offered for `--algo crl`)."""
    actor, starts = restored
    if job.episodes is not None or any(job.noises) or not job.eval_cfg.deterministic_eval:
        raise ConfigError("eval of an --algo crl run replays its own deterministic evaluation: it takes "
                          "neither --episodes, --stochastic nor --obs-noise")
    return [np.asarray(get_program(job.eval_cfg).evaluate(actor, starts, job.seeds, job.epoch))]


# evaluate_checkpoint(out, epoch, ...) and evaluate_checkpoint_noises: sf2_common.agents.evaluation's
_EVALUATOR = CheckpointEvaluator("jax", TrainConfig, Checkpointer, _restore_acting, _act)
evaluate_checkpoint = _EVALUATOR.evaluate_checkpoint
evaluate_checkpoint_noises = _EVALUATOR.evaluate_checkpoint_noises
