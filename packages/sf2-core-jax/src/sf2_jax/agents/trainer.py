"""The one off-policy training loop (Brax style, current JAX), for every algorithm × representation.

A `Program` is everything compiled for one `TrainConfig`, `vmap`ped over seeds: `--seeds 0-3` trains four
independent agents in one jitted program (one seed runs the per-seed functions without the vmap). Per
seed the `TrainState` holds the parameters (the observation statistics are the `obs_norm` group), Adam
states, the vectorized env state, the replay buffer, a PRNG key, counters and the evaluation start states.
`epoch` scans `actor_steps_per_epoch` actor steps (the run's first `prefill_actor_steps` act uniformly at
random and train nothing, in the same program, so the env step compiles once; every later one explores,
observes, inserts and runs `grad_updates_per_step` SGD steps) and returns each metric's mean and first
non-finite index; `evaluate` runs one episode from each evaluation start state, `evaluate_many` several
epochs' parameters in one program. The actor step's parts are `jax.named_scope`s (`ACTOR_PHASES`).

The host loop between epochs (NaN guard, evaluation rows, checkpoints, progress, the curve) is
`sf2_common.agents.hostloop.run_epochs`, shared with sf2_torch: train → NaN guard → evaluate → append
rows → checkpoint; a run killed at any moment resumes from its last checkpoint (docs/run-folders.md).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from sf2_common.agents import configs, hostloop, loggers, plotting
from sf2_common.agents.configs import TrainConfig
from sf2_common.agents.evaluation import CheckpointEvaluator, CheckpointJob
from sf2_common.agents.hostloop import WALL_FIELDS, TrainingDiverged
from sf2_common.agents.lock import FolderLock
from sf2_common.agents.resume import resume_run
from sf2_common.agents.runfolder import RunFolder
from sf2_common.errors import ConfigError

from sf2_jax import networks
from sf2_jax.losses import Batch

from . import envs, representations
from .algorithms import make_algorithm
from .checkpoint import Checkpointer
from .replay import ReplayBuffer

# the `jax.named_scope`s of one actor step (module docstring), in its order; the on-policy trainer's
# rollout step uses the first three and its returns and advantages are "returns"
ACTOR_PHASES = ("explore", "env_step", "observe", "sample", "step_noise", "returns")

__all__ = ["TrainState", "Program", "get_program", "episode_returns", "TrainingDiverged", "TrainResult",
           "train", "evaluate_checkpoint", "evaluate_checkpoint_noises", "seed_keys", "eval_keys",
           "acting_params", "flatten_params", "device_note", "EVAL_STREAM", "WALL_FIELDS", "run_training",
           "SingleDeviceProgram", "SeedsSession", "BatchedSeedsSession"]

EVAL_STREAM = 0x5EED  # eval keys: fold_in(fold_in(PRNGKey(seed), EVAL_STREAM), epoch)
# WALL_FIELDS, TrainingDiverged and the host loop's framework-free helpers (rows, the NaN guard's
# message, progress bar, curve) are sf2_common.agents.hostloop, shared with sf2_torch's trainer.


class TrainState(NamedTuple):
    params: dict
    opt_state: dict
    env_state: Any
    replay: dict
    key: jax.Array
    env_steps: jax.Array
    grad_steps: jax.Array
    eval_start: Any


def seed_keys(seeds) -> jax.Array:
    """The root key PRNGKey(s) of every seed, stacked (n_seeds, 2); `init` splits each in three (parameters,
    env resets, training)."""
    return jnp.stack([jax.random.PRNGKey(s) for s in seeds])


def eval_keys(seeds, epoch: int) -> jax.Array:
    """fold_in(fold_in(PRNGKey(seed), EVAL_STREAM), epoch) of every seed, stacked (n_seeds, 2): the
    evaluation of `epoch`'s acting noise (and, split, its fresh start states)."""
    return jnp.stack([jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(s), EVAL_STREAM), epoch)
                      for s in seeds])


def acting_params(params: dict) -> dict:
    """The parameter groups `Algorithm.act` reads (TD3's and SAC's: the policy and the observation
    statistics; a group it lacks fails as the program traces): all that the evaluation programs take and
    an epoch's snapshot keeps (paper preset, TD3+SF²: 1/14 of the parameters on AcrobotSwingup, 1/25 on
    CheetahRun)."""
    return {name: params[name] for name in ("policy", "obs_norm")}


SHARD_SEEDS = "SF2_SHARD_SEEDS"   # "1": spread a run's seeds over the local devices (Program.mesh)


class Program:
    """The compiled pieces of one config (see the module docstring). Build with `get_program(cfg)`."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.spec = envs.env_spec(cfg.task, cfg.episode_length, cfg.action_repeat)
        self.sf2 = cfg.sf2_config(self.spec.obs_size, self.spec.action_size)
        self.algo = make_algorithm(cfg.algo, self.sf2, representations.get(cfg.representation))
        self.buffer = ReplayBuffer(cfg.max_replay_size, self.spec.obs_size, self.spec.action_size)
        self.sched = configs.schedule(cfg)
        # the order an SGD step computes its losses in (names the first NaN when several appear at once)
        self.loss_order = ("critic_loss", self.algo.rep.aux_loss_name, "alpha_loss", "actor_loss")
        self._programs: dict[tuple, Callable] = {}   # (name, obs noise, seeds spread) -> jitted program
        self._eval_starts = jax.jit(jax.vmap(self._eval_starts_one, in_axes=(0, None)), static_argnums=1)

    # ------------------------------------------------------------------ host entry points
    def _physics_precision(self):
        """Every program is traced at fp32 `highest` (the physics always runs at it); the learner's code
        inside them (SGD steps, acting) is traced under `learner_precision()`."""
        return jax.default_matmul_precision("highest")

    def learner_precision(self):
        """The context the learner's code (SGD steps, acting) is traced in: `cfg.learner_precision` as a
        trace-time matmul precision (`configs.LEARNER_PRECISIONS`); torch's `Program.learner_precision`."""
        return jax.default_matmul_precision(configs.LEARNER_PRECISIONS[self.cfg.learner_precision])

    def init(self, seeds) -> TrainState:
        with self._physics_precision():
            return self._program("init", len(seeds))(seed_keys(seeds))

    def abstract_state(self, seeds) -> TrainState:
        with self._physics_precision():
            return jax.eval_shape(jax.vmap(self._init_one), seed_keys(seeds))

    @staticmethod
    def mesh(n_seeds: int) -> jax.sharding.Mesh | None:
        """The local devices as one "seed" mesh, when one run's seeds are to be spread over them.

        Opt-in (docs/decisions/sharded-seeds.md): several GPUs are used by whole runs, one per GPU (`study
        run`); a sharded program is compiled with the GSPMD partitioner, under which its numbers differ from
        one device's in the last bits. Tested on two CPU devices (tests/agents/test_devices.py).

        Args:
          n_seeds: the run's number of seeds.

        Returns:
          The mesh when `SF2_SHARD_SEEDS=1` is set, there are several local devices and they divide
          `n_seeds` evenly; else None (everything on the default device).
        """
        devices = jax.local_devices()
        if os.environ.get(SHARD_SEEDS) != "1" or len(devices) < 2 or n_seeds % len(devices):
            return None
        return jax.sharding.Mesh(np.array(devices), ("seed",))

    def place(self, state):
        """Put a state (e.g. a restored checkpoint) where the programs keep it: its seeds spread over the
        local devices (`mesh`), or unchanged on one device."""
        mesh = self.mesh(jax.tree_util.tree_leaves(state)[0].shape[0])
        if mesh is None:
            return state
        return jax.device_put(state, jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("seed")))

    def _program(self, name: str, n_seeds: int, obs_noise: float = 0.0):
        """The jitted program `name` ("init", "epoch", "evaluate") over the seed axis (`_seed_map`). With
        several local devices that divide the seeds evenly it is a `shard_map` over the "seed" axis: every
        device runs that program on its own seeds, so nothing crosses devices inside an epoch (docs/core-
        contract.md "Agents"; the seeds' numbers are those of one device up to float rounding)."""
        mesh = self.mesh(n_seeds)
        per_device = n_seeds // (mesh.devices.size if mesh is not None else 1)
        key = (name, obs_noise, mesh is not None, per_device == 1)
        if key not in self._programs:
            fn, in_axes = {"init": (self._init_one, (0,)), "epoch": (self._epoch_one, (0, None)),
                           "evaluate": (functools.partial(self._eval_one, obs_noise=obs_noise), (0, 0, 0))
                           }[name]
            fn = _seed_map(fn, in_axes, per_device)
            if mesh is not None:
                # XLA's Shardy pass segfaults on these programs on GPUs (`mesh`): this process compiles
                # with GSPMD from here on (jit reads the flag when it compiles; JAX warns it is deprecated)
                jax.config.update("jax_use_shardy_partitioner", False)
                seed, whole = jax.sharding.PartitionSpec("seed"), jax.sharding.PartitionSpec()
                fn = jax.shard_map(fn, mesh=mesh, in_specs=tuple(seed if a == 0 else whole for a in in_axes),
                                   out_specs=seed, check_vma=False)
            self._programs[key] = jax.jit(fn, donate_argnums=(0,) if name == "epoch" else ())
        return self._programs[key]

    def epoch(self, state: TrainState, epoch: int) -> tuple[TrainState, dict, dict]:
        """Run epoch `epoch` (1-based). Returns (state, metric means, first non-finite index)."""
        first = jnp.asarray((epoch - 1) * self.sched.actor_steps_per_epoch, jnp.int32)
        n_seeds = state.key.shape[0]
        with self._physics_precision(), warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*donated buffers were not usable.*")
            return self._program("epoch", n_seeds)(state, first)

    def evaluate(self, params, eval_start, seeds, epoch: int, obs_noise: float = 0.0) -> jax.Array:
        """Episode returns (n_seeds, n_eval_envs) from the start states `eval_start`. `obs_noise` > 0 adds
        Gaussian noise of that std to every observation the policy sees (paper App. C.2.2; one compiled
        program per std; 0 is the training's own evaluation program)."""
        with self._physics_precision():
            program = self._program("evaluate", len(seeds), float(obs_noise))
            return program(acting_params(params), eval_start, eval_keys(seeds, epoch))

    def evaluate_many(self, params, eval_start, seeds, epochs, obs_noise: float = 0.0) -> jax.Array:
        """Episode returns (len(epochs), n_seeds, n_eval_envs): `evaluate` of each epoch's parameters
        (`params`: leaves stacked (len(epochs), n_seeds, ...)) from the same start states, in one program
        vmapped over the epochs (sf2_common.agents.hostloop.BatchedEvaluation says why). With the seeds
        spread over several devices (`mesh`) it is one `evaluate` per epoch."""
        if self.mesh(len(seeds)) is not None:
            return jnp.stack([self.evaluate(jax.tree_util.tree_map(lambda x, k=k: x[k], params), eval_start,
                                            seeds, e, obs_noise) for k, e in enumerate(epochs)])
        key = ("evaluate_many", float(obs_noise), False)
        if key not in self._programs:
            per_seed = jax.vmap(functools.partial(self._eval_one, obs_noise=float(obs_noise)))
            self._programs[key] = jax.jit(jax.vmap(per_seed, in_axes=(0, None, 0)))
        keys = jnp.stack([eval_keys(seeds, e) for e in epochs])
        with self._physics_precision():
            return self._programs[key](acting_params(params), eval_start, keys)

    def fresh_eval_starts(self, seeds, n: int, epoch: int):
        """`n` new evaluation start states per seed (for `sf2-jax eval --episodes`)."""
        with self._physics_precision():
            return self._eval_starts(eval_keys(seeds, epoch), n)

    # ------------------------------------------------------------------ per-seed pieces (vmapped)
    def _init_one(self, key) -> TrainState:
        k_params, k_env, k_train = jax.random.split(key, 3)
        params, opt_state = self.algo.init(k_params)
        n, m = self.cfg.num_envs, self.cfg.num_eval_envs
        both = self.spec.train_env.reset(jax.random.split(k_env, n + m))  # one reset compiled, not two
        for leaf in jax.tree_util.tree_leaves(both):
            assert leaf.shape[:1] == (n + m,), f"env state leaf without the env axis: {leaf.shape}"
        env_state = jax.tree_util.tree_map(lambda x: x[:n], both)
        eval_start = jax.tree_util.tree_map(lambda x: x[n:], both)
        zero = jnp.zeros((), jnp.int32)
        return TrainState(params, opt_state, env_state, self.buffer.init(), k_train, zero, zero, eval_start)

    def _eval_starts_one(self, key, n):
        return self.spec.eval_env.reset(jax.random.split(jax.random.fold_in(key, 1), n))

    def _env_step(self, env_state, action):
        nstate = self.spec.train_env.step(env_state, action)
        batch = Batch(obs=env_state.obs, action=action, reward=nstate.reward,
                      discount=1.0 - nstate.done, next_obs=nstate.obs,
                      truncation=nstate.info["truncation"])
        return nstate, jax.tree_util.tree_map(lambda x: x.astype(jnp.float32), batch)

    def _sgd_steps(self, state: TrainState, key, train=True):
        """`grad_updates_per_step` SGD steps on fresh batches from the buffer; where `train` (a bool scalar)
        is False each step keeps the parameters, Adam states and SGD count and reports zero metrics (the
        prefill, `_actor_step`). The selection is inside the scan's body, where XLA fuses most of it into
        the Adam and target updates; after the scan it would cost a copy of every array into the loop and a
        select kernel for each (docs/decisions/jax-trainer-step.md)."""
        G, B = self.cfg.grad_updates_per_step, self.cfg.batch_size
        k_sample, k_sgd = jax.random.split(key)
        with jax.named_scope("sample"):
            batches = jax.tree_util.tree_map(lambda x: x.reshape((G, B) + x.shape[1:]),
                                             self.buffer.sample(state.replay, k_sample, G * B))

        def sgd(carry, xs):
            params, opt_state, step = carry
            batch, k = xs
            with jax.named_scope("step_noise"):
                noise = self.algo.step_noise(k, batch)
            with self.learner_precision():
                new = self.algo.sgd_step(params, opt_state, batch, noise, step)
            params, opt_state, metrics = jax.tree_util.tree_map(
                lambda n, o: jnp.where(train, n, o), new, (params, opt_state, jax.tree_util.tree_map(
                    jnp.zeros_like, new[2])))
            return (params, opt_state, step + jnp.asarray(train, step.dtype)), metrics

        (params, opt_state, grad_steps), metrics = jax.lax.scan(
            sgd, (state.params, state.opt_state, state.grad_steps), (batches, jax.random.split(k_sgd, G)))
        return state._replace(params=params, opt_state=opt_state, grad_steps=grad_steps), metrics

    def _actor_step(self, state: TrainState, actor_step):
        """One actor step. A prefill step (`actor_step`, the run's global index, below
        `prefill_actor_steps`) acts uniformly at random and leaves the parameters, Adam states and SGD
        count as they were; a training step acts with `explore` and runs `grad_updates_per_step` SGD steps.
        Both are computed and the step's kind selects (`jnp.where` on the unbatched flag; the SGD steps'
        inside their scan, `_sgd_steps`), with no `lax.cond`: on a GPU a conditional copies its predicate
        to the host and every array that passes through it to new buffers
        (docs/decisions/jax-trainer-step.md), while the prefill's discarded SGD steps cost only the run's
        first prefill actor steps."""
        cfg, A = self.cfg, self.spec.action_size
        prefill = actor_step < self.sched.prefill_actor_steps
        key, k_act, k_sgd = jax.random.split(state.key, 3)
        obs = state.env_state.obs
        with jax.named_scope("explore"):
            with self.learner_precision():
                policy_action = self.algo.explore(state.params, obs, k_act).astype(jnp.float32)
            action = jnp.where(prefill, jax.random.uniform(k_act, (cfg.num_envs, A), jnp.float32, -1.0, 1.0),
                               policy_action)
        with jax.named_scope("env_step"):
            env_state, batch = self._env_step(state.env_state, action)
        params = state.params
        with jax.named_scope("observe"):
            if cfg.normalize_observations:
                params = {**params, "obs_norm": networks.update_normalizer(params["obs_norm"], batch.obs,
                                                                           self.sf2)}
            replay = self.buffer.insert(state.replay, batch)
        state = state._replace(params=params, env_state=env_state, key=key, replay=replay,
                               env_steps=state.env_steps + self.sched.env_steps_per_actor_step)
        state, metrics = self._sgd_steps(state, k_sgd, ~prefill)
        return state, (metrics, ~prefill)

    def _epoch_one(self, state: TrainState, first_actor_step):
        steps = first_actor_step + jnp.arange(self.sched.actor_steps_per_epoch, dtype=jnp.int32)
        state, (metrics, trained) = jax.lax.scan(self._actor_step, state, steps)
        mask = trained.astype(jnp.float32)[:, None]              # (actor steps, 1)
        count = jnp.maximum(jnp.sum(trained) * self.cfg.grad_updates_per_step, 1)
        means, first_bad = {}, {}
        for name, m in metrics.items():                          # m: (actor steps, grad updates)
            finite = jnp.isfinite(m) | (mask == 0)
            means[name] = jnp.sum(jnp.where(mask > 0, m, 0.0)) / count
            flat = finite.reshape(-1)
            first_bad[name] = jnp.where(jnp.all(flat), -1, jnp.argmin(flat))
        means["sgd_steps"] = jnp.sum(trained) * self.cfg.grad_updates_per_step
        return state, means, first_bad

    def _eval_one(self, params, eval_start, key, obs_noise: float = 0.0):
        cfg = self.cfg

        def act(obs, k):
            if obs_noise:   # its own key: the acting noise stays that of the noise-free evaluation
                obs = obs + obs_noise * jax.random.normal(jax.random.fold_in(k, 1), obs.shape, obs.dtype)
            with self.learner_precision():
                return self.algo.act(params, obs, k, cfg.deterministic_eval)

        return episode_returns(self.spec.eval_env, eval_start, act, key, self.sched.eval_actor_steps)


def episode_returns(env, eval_start, act, key, n_steps: int) -> jax.Array:
    """Returns (n_envs,) of one episode per env from the start states `eval_start`: `n_steps` steps of
    `env.step(state, act(obs, k))`, `k` one of `key`'s `n_steps` splits; an env's rewards count until its
    episode is done. The evaluation of `Program` (`act`: the policy), and of bench/lab/eval_sensitivity.py."""
    n_envs = jax.tree_util.tree_leaves(eval_start)[0].shape[0]

    def step(carry, k):
        env_state, ret, alive = carry
        env_state = env.step(env_state, act(env_state.obs, k))
        ret = ret + env_state.reward.astype(jnp.float32) * alive
        alive = alive * (1.0 - env_state.done.astype(jnp.float32))
        return (env_state, ret, alive), None

    zeros = jnp.zeros((n_envs,), jnp.float32)
    (_, ret, _), _ = jax.lax.scan(step, (eval_start, zeros, zeros + 1.0), jax.random.split(key, n_steps))
    return ret


def _seed_map(fn, in_axes, n_seeds: int, loop: str = "vmap"):
    """`fn` over the seed axis (axis 0 of the arguments whose `in_axes` entry is 0, and of every output).

    "vmap" batches the seeds into one program, except at one seed, where `fn` runs on the seed's slice and
    the axis is added back outside: the same operations, but under a vmap of one seed XLA lays the GEMMs'
    outputs out column-major on a GPU, so that every LayerNorm is a chain of column reductions instead of
    one or two Triton kernels (docs/decisions/jax-trainer-step.md). "map" runs the seeds one after another
    in the program (`jax.lax.map`), each on `fn`'s unbatched shapes: under a vmap a convolution becomes a
    grouped one (`feature_group_count` = seeds), which cuDNN may run slower than the seeds in turn.

    Args:
      fn: the per-seed function.
      in_axes: per argument, 0 (sliced along the seed axis) or None (the same for every seed).
      n_seeds: the length of the seed axis.
      loop: "vmap" or "map" (`configs.SEED_LOOPS`, the config's `seed_loop`).

    Returns:
      `fn` over the seed axis, its outputs stacked on axis 0 (as `jax.vmap`'s), with `fn`'s name.
    """
    if loop == "map":
        def mapped(*args):
            seeded = [a for a, axis in zip(args, in_axes, strict=True) if axis == 0]

            def one(sliced):
                it = iter(sliced)
                return fn(*(next(it) if axis == 0 else a for a, axis in zip(args, in_axes, strict=True)))

            return jax.lax.map(one, seeded)

        return functools.wraps(fn)(mapped)   # the compiled module keeps fn's name (bench.hlo finds it by it)
    if loop != "vmap":
        raise ValueError(f"seed loop {loop!r} is invalid: must be one of {', '.join(configs.SEED_LOOPS)}")
    if n_seeds != 1:
        return jax.vmap(fn, in_axes=in_axes)

    def one(*args):
        args = [jax.tree_util.tree_map(lambda x: x[0], a) if axis == 0 else a
                for a, axis in zip(args, in_axes, strict=True)]
        return jax.tree_util.tree_map(lambda x: x[None], fn(*args))

    return functools.wraps(fn)(one)   # the compiled module keeps fn's name (bench.hlo finds it by it)


@functools.lru_cache(maxsize=8)
def get_program(cfg: TrainConfig) -> Program:
    """The compiled pieces of one config, cached: runs with equal configs reuse the compiled functions.

    Args:
      cfg: the run's `TrainConfig` (frozen, hashable: the cache key).

    Returns:
      Its `Program` (the last 8 configs' are kept).

    Raises:
      ConfigError: the task is unknown or has structured observations, or the representation is unknown.
    """
    return Program(cfg)


# ------------------------------------------------------------------------------------------- host loop
@dataclasses.dataclass
class TrainResult:
    run: RunFolder
    rows: list[dict]
    state: TrainState           # final state of all seeds (leading axis = seed)
    seeds: tuple[int, ...]
    resumed_from: int | None    # checkpoint epoch resumed from, if any


def flatten_params(params: dict, seed_index: int | None = None) -> dict[str, np.ndarray]:
    """Dot-joined names → numpy arrays (the canonical naming of `sf2_jax.params`)."""
    out = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(params)[0]:
        name = ".".join(str(getattr(p, "key", getattr(p, "idx", p))) for p in path)
        arr = np.asarray(leaf)
        out[name] = arr if seed_index is None else arr[seed_index]
    return out


def device_note(n_seeds: int) -> str | None:
    """What `train` tells the user when the host has several devices and the run uses one of them
    (`Program.mesh` is None: `SF2_SHARD_SEEDS` unset, or the devices do not divide the seeds)."""
    devices = jax.local_devices()
    if len(devices) < 2 or Program.mesh(n_seeds) is not None:
        return None
    return (f"note: this host has {len(devices)} {devices[0].platform.upper()} devices and this run uses "
            f"one; run one run per device with `study run` (README, Studies), or set {SHARD_SEEDS}=1 to "
            f"spread the seeds over them (experimental: Program.mesh)")


def train(cfg: TrainConfig, seeds, out, *, resume: bool = True, fresh: bool = False,
          progress: bool = True, hook: Callable[[str, int], None] | None = None,
          stop_after_epoch: int | None = None, plot: bool = True, log=()) -> TrainResult:
    """Train one config for every seed (one vmapped program) into a run folder.

    Args:
      cfg: the run's `TrainConfig`.
      seeds: the seeds, as `parse_seeds` takes them ("0-3", "0,2,5", 7, a sequence of ints).
      out: the run folder (docs/run-folders.md); one writer at a time (a lock file).
      resume: resume from the folder's newest checkpoint that restores completely when it holds the same
        run (`sf2_common.agents.resume` sets damaged ones aside).
      fresh: delete the folder's previous contents first.
      progress: show the progress bar.
      hook: `hook(event, epoch)`, called at the points of `hostloop.run_epochs` (tests simulate a kill).
      stop_after_epoch: end the run early, after that epoch's checkpoint, as a kill would.
      plot: write the learning-curve PNG.
      log: the sinks every metrics row also goes to: "tensorboard", "wandb", both comma-separated, or a
        sequence of them (`sf2_common.agents.loggers`).

    Returns:
      A `TrainResult`: the run folder, its rows, the final state of all seeds, the seeds, the checkpoint
      epoch resumed from.

    Raises:
      ConfigError: bad input, before anything is compiled.
      RunFolderError: a run folder that cannot be used (another run's, another core's, in use).
      TrainingDiverged: a NaN or inf loss (nothing of that epoch is written).
    """
    seeds = configs.parse_seeds(seeds)
    if cfg.algo in configs.ONPOLICY_ALGOS:
        raise ConfigError(f"algo {cfg.algo!r} is the on-policy trainer's (sf2_jax.agents.onpolicy.train); "
                          f"this off-policy trainer takes td3 and sac")
    configs.validate(cfg, seeds, representations.REGISTRY)
    return run_training(cfg, seeds, out, program_of=get_program, session_of=_Session, label=_label,
                        hardware=_hardware(len(seeds)), versions=_versions(), note=device_note(len(seeds)),
                        resume=resume, fresh=fresh, progress=progress, hook=hook,
                        stop_after_epoch=stop_after_epoch, plot=plot, log=log)


def run_training(cfg: TrainConfig, seeds: tuple[int, ...], out, *, program_of: Callable, session_of: Callable,
                 label: Callable[[TrainConfig], str], hardware: str, versions: dict, note: str | None = None,
                 resume: bool = True, fresh: bool = False, progress: bool = True,
                 hook: Callable[[str, int], None] | None = None, stop_after_epoch: int | None = None,
                 plot: bool = True, log=()) -> TrainResult:
    """The run-folder half of a JAX trainer's `train` (this module's and `onpolicy`'s), for a config and
    seeds already validated: the lock, the folder's checks and config.json, the resume from the newest
    checkpoint that restores completely, then `hostloop.run_epochs`.

    Args:
      cfg: the run's `TrainConfig`, validated.
      seeds: the seeds, parsed.
      out: the run folder.
      program_of: `program_of(cfg)` → the trainer's program, with `abstract_state(seeds)` (the state's
        shapes, a checkpoint's template) and `place(state)` (a restored state where the programs keep it).
      session_of: `session_of(program, checkpointer, run, seeds, state)` → its `hostloop.Session` (`state`
        None: it starts one).
      label: `label(cfg)` → the method's label, e.g. "TD3+SF²".
      hardware: what the run trains on (`hostloop.hardware`).
      versions: the libraries' versions, for config.json.
      note: a line said once the program is built, or None.
      resume, fresh, progress, hook, stop_after_epoch, plot, log: as `train`'s.

    Returns:
      The `TrainResult`.

    Raises:
      RunFolderError: a run folder that cannot be used.
      TrainingDiverged: a NaN or inf loss.
    """
    log = loggers.parse_log(log)
    run = RunFolder(out)
    run.check_usable()
    lock = FolderLock(run.path, "sf2-jax train").acquire(say=run.say)   # one writer per run folder
    try:
        if fresh:
            run.clear()
        run.check_framework("jax")
        cfg = run.keep_trained_values(cfg)
        existing = run.check_compatible(cfg.to_dict(), seeds)
        if existing:
            run.say_execution_changes(cfg.to_dict())
        sched = configs.schedule(cfg)
        env = hostloop.numerics_environment()
        if not existing:
            run.write_config({"config": cfg.to_dict(), "seeds": list(seeds),
                              "schedule": dataclasses.asdict(sched), "label": label(cfg),
                              "versions": versions, "hardware": hardware, "environment": env})
        run.log(f"hardware: {hardware}")
        run.log(hostloop.environment_line(env))
        program = program_of(cfg)
        if note:
            run.say(note)
        ckpt = Checkpointer(run.checkpoint_dir, keep=cfg.keep_checkpoints)
        title = hostloop.run_title(label(cfg), cfg.task, seeds)
        try:
            res = resume_run(run, ckpt, lambda e: ckpt.restore(e, program.abstract_state(seeds)), seeds=seeds,
                             sched=sched, existing=existing, resume=resume)
            state = None if res.restored is None else program.place(res.restored[0])
            session = session_of(program, ckpt, run, seeds, state)
            rows = hostloop.run_epochs(session, cfg=cfg, sched=sched, seeds=seeds, run=run, title=title,
                                       rows=res.rows, start=res.start, last=res.epoch, walltime=res.walltime,
                                       progress=progress, hook=hook, stop_after_epoch=stop_after_epoch,
                                       plot=plot, log=log)
        finally:
            ckpt.close()
        return TrainResult(run=run, rows=rows, state=session.state, seeds=seeds, resumed_from=res.epoch)
    finally:
        lock.release()


class SeedsSession:
    """The `sf2_common.agents.hostloop.Session` of one run of a JAX trainer: the vmapped state of all seeds,
    saved in the background. A subclass defines `evaluate(epoch)` (and may offer batched evaluation)."""

    def __init__(self, program, ckpt: Checkpointer, run: RunFolder, seeds, state):
        self.program, self.ckpt, self.run, self.seeds, self.state = program, ckpt, run, seeds, state

    def start(self) -> None:
        self.state = self.program.init(self.seeds)

    def train_epoch(self, epoch: int):
        self.state, means, first_bad = self.program.epoch(self.state, epoch)
        return jax.device_get(means), first_bad

    def save(self, epoch: int, env_steps: int) -> None:
        # written in the background while the next epoch trains (checkpoint.py)
        self.ckpt.save(epoch, self.state, {"env_steps": env_steps, "seeds": list(self.seeds)}, wait=False)

    def write_seconds(self) -> float | None:
        return self.ckpt.write_seconds

    def loss_order(self) -> tuple[str, ...]:
        return self.program.loss_order

    def finish(self) -> None:
        _write_final(self.run, self.state, self.seeds)


class BatchedSeedsSession(SeedsSession):
    """`SeedsSession` with the host loop's batched evaluation (`hostloop.BatchedEvaluation`). A subclass
    defines `acting()` (the policy's parameters in the state now) and `evaluate_stacked(params, epochs)` (its
    program's `evaluate_many`)."""

    def __init__(self, program, ckpt: Checkpointer, run: RunFolder, seeds, state):
        super().__init__(program, ckpt, run, seeds, state)
        self.snapshots: dict[int, dict] = {}   # epoch -> a copy of its acting params (`snapshot`)

    def snapshot(self, epoch: int) -> None:
        # a copy: the next epoch's program donates (overwrites) the state's buffers
        self.snapshots[epoch] = jax.tree_util.tree_map(jnp.copy, self.acting())

    def evaluate_many(self, epochs: list[int]) -> np.ndarray:
        # One batch shape per run: a shorter batch (the schedule's last, a stop) is padded with its last
        # epoch, whose extra returns are dropped, so the program compiles once (a second shape compiles
        # the whole evaluation again: docs/decisions/batched-evaluation.md).
        pad = max(self.program.cfg.checkpoint_every - len(epochs), 0)
        snaps = [self.snapshots.pop(e) for e in epochs]
        params = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *snaps, *[snaps[-1]] * pad)
        padded = epochs + [epochs[-1]] * pad
        return np.asarray(self.evaluate_stacked(params, padded))[: len(epochs)]


class _Session(BatchedSeedsSession):
    """The off-policy trainer's session: `SeedsSession` with its batched evaluation."""

    def evaluate(self, epoch: int) -> np.ndarray:
        return np.asarray(self.program.evaluate(self.state.params, self.state.eval_start, self.seeds, epoch))

    def acting(self):
        return acting_params(self.state.params)

    def evaluate_stacked(self, params, epochs: list[int]) -> jax.Array:
        return self.program.evaluate_many(params, self.state.eval_start, self.seeds, epochs)


class SingleDeviceProgram:
    """What the on-policy and goal-conditioned trainers' `Program`s share: their state is vmapped over seeds
    on one device. A subclass defines `cfg`, `_program(name, n_seeds)` and `_init_one(key)`."""

    def precision(self):
        """The matmul precision every program is traced at: the physics' fp32 `highest` (Playground's MJX;
        MinAtar's games have none); the learner's code inside is traced under `learner_precision()`."""
        return jax.default_matmul_precision("highest")

    def learner_precision(self):
        """The context the learner's code (acting, values, SGD steps) is traced in: `cfg.learner_precision`
        (`configs.LEARNER_PRECISIONS`)."""
        return jax.default_matmul_precision(configs.LEARNER_PRECISIONS[self.cfg.learner_precision])

    def init(self, seeds):
        """The initial state of every seed (leading axis: the seed)."""
        with self.precision():
            return self._program("init", len(seeds))(seed_keys(seeds))

    def abstract_state(self, seeds):
        """The shapes and dtypes of `init(seeds)` (a checkpoint's template)."""
        with self.precision():
            return jax.eval_shape(jax.vmap(self._init_one), seed_keys(seeds))

    def place(self, state):
        """A restored state where the programs keep it: the default device, as it is."""
        return state


def _label(cfg: TrainConfig) -> str:
    return plotting.method_label(cfg.algo, cfg.representation, representations.REGISTRY)


def _write_final(run: RunFolder, state: TrainState, seeds) -> None:
    run.final_dir.mkdir(parents=True, exist_ok=True)
    params = jax.device_get(state.params)
    for i, s in enumerate(seeds):
        np.savez(run.final_dir / f"params_seed{s}.npz", **flatten_params(params, i))


def _hardware(n_seeds: int) -> str:
    """The devices this run's program uses (`hostloop.hardware`): the default device, or those of
    `Program.mesh` when the seeds are sharded."""
    mesh = Program.mesh(n_seeds)
    devices = list(mesh.devices.flat) if mesh is not None else jax.devices()[:1]
    return hostloop.hardware(d.device_kind for d in devices if d.platform != "cpu")


def _versions() -> dict:
    return hostloop.versions(("jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "brax", "playground",
                              "mujoco", "mujoco-mjx", "sf2-core-jax", "sf2-common"))


def _restore_acting(ckpt: Checkpointer, job: CheckpointJob):
    """((acting parameters, evaluation start states), meta) of checkpoint `job.epoch`; the replay buffers
    and optimizer states it also holds are dropped here."""
    state, meta = ckpt.restore(job.epoch, get_program(job.cfg).abstract_state(job.seeds))
    return (acting_params(state.params), state.eval_start), meta


def _act(restored, job: CheckpointJob) -> list[np.ndarray]:
    """Episode returns (seeds, episodes) per noise std of `job`, from the run's evaluation start states or
    `job.episodes` fresh ones."""
    params, starts = restored
    program = get_program(job.eval_cfg)
    if job.episodes is not None:
        starts = program.fresh_eval_starts(job.seeds, job.episodes, job.key)
    return [np.asarray(program.evaluate(params, starts, job.seeds, job.key, noise)) for noise in job.noises]


# evaluate_checkpoint(out, epoch, num_eval_envs, deterministic, obs_noise) and evaluate_checkpoint_noises(...,
# noises): the framework-free half is sf2_common.agents.evaluation's (documented there)
_EVALUATOR = CheckpointEvaluator("jax", TrainConfig, Checkpointer, _restore_acting, _act)
evaluate_checkpoint = _EVALUATOR.evaluate_checkpoint
evaluate_checkpoint_noises = _EVALUATOR.evaluate_checkpoint_noises
