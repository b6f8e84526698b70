"""The one off-policy training loop (Brax style, on TorchRL), for every algorithm × representation: the
torch mirror of the JAX agents' trainer (same schedule, order of operations, run folder, rows, NaN guard,
checkpoint/resume semantics and progress output).

A `Program` is what one `TrainConfig` needs in a process. Every seed has its own agent (networks, Adam
states, target updaters; `torch.manual_seed(seed)` before they are built), TorchRL replay buffer and
`torch.Generator`, and the seeds take their SGD steps one after the other; all seeds' envs step together
in one Playground batch, reset from the JAX trainer's keys (`env_reset_keys`), so both frameworks start
from the same states. `epoch` runs `actor_steps_per_epoch` actor steps (the prefill acts uniformly at
random and trains nothing; every later one explores, observes, inserts and runs `grad_updates_per_step`
SGD steps on noise drawn in one go) and returns each metric's mean and first non-finite index, indexed as
the JAX trainer's. The host loop between epochs is `sf2_common.agents.hostloop.run_epochs`, shared with
the JAX core: train → NaN guard → evaluate → append rows → checkpoint (docs/run-folders.md).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from sf2_common.agents import configs as common_configs
from sf2_common.agents import hostloop, loggers
from sf2_common.agents.evaluation import CheckpointEvaluator, CheckpointJob
from sf2_common.agents.hostloop import WALL_FIELDS, TrainingDiverged
from sf2_common.agents.lock import FolderLock
from sf2_common.agents.plotting import method_label
from sf2_common.agents.resume import resume_run
from sf2_common.agents.runfolder import RunFolder
from sf2_common.errors import ConfigError
from tensordict import TensorDict

from sf2_torch import losses, networks, params

from . import configs, envs, graphs, representations
from .algorithms import Algorithm, make_algorithm
from .checkpoint import Checkpointer, CheckpointMismatch
from .configs import TrainConfig
from .replay import ReplayBuffer, to_batch

__all__ = ["Program", "SeedState", "TrainState", "get_program", "TrainingDiverged", "TrainResult", "train",
           "evaluate_checkpoint", "evaluate_checkpoint_noises", "seed_keys", "eval_keys", "env_reset_keys",
           "fresh_eval_start_keys", "EVAL_STREAM", "WALL_FIELDS"]

EVAL_STREAM = 0x5EED  # eval keys: fold_in(fold_in(PRNGKey(seed), EVAL_STREAM), epoch), as in the JAX core
OBS_NOISE_STREAM = 0x0B5  # the observation noise of `evaluate(..., obs_noise)`: its own generator per seed
# WALL_FIELDS, TrainingDiverged and the host loop's framework-free helpers (rows, the NaN guard's
# message, progress bar, curve) are sf2_common.agents.hostloop, shared with the JAX core's trainer.


# The envs are Playground's JAX envs (envs.PlaygroundEnv): they reset from JAX PRNG keys, derived here as the
# JAX trainer derives them, so both frameworks start from the same states. JAX is imported only here.
def seed_keys(seeds):
    """The root key PRNGKey(s) of every seed, stacked (n_seeds, 2): the JAX trainer's `seed_keys`."""
    import jax
    import jax.numpy as jnp

    return jnp.stack([jax.random.PRNGKey(s) for s in seeds])


def env_reset_keys(seeds, num_envs: int, num_eval_envs: int):
    """(training keys (n_seeds · num_envs, 2), evaluation start keys (n_seeds · num_eval_envs, 2)): per seed,
    split(split(PRNGKey(seed), 3)[1], num_envs + num_eval_envs) as the JAX trainer's init, seeds in order."""
    import jax
    import jax.numpy as jnp

    keys = [jax.random.split(jax.random.split(k, 3)[1], num_envs + num_eval_envs) for k in seed_keys(seeds)]
    return jnp.concatenate([k[:num_envs] for k in keys]), jnp.concatenate([k[num_envs:] for k in keys])


def eval_keys(seeds, epoch: int):
    """fold_in(fold_in(PRNGKey(seed), EVAL_STREAM), epoch) of every seed, stacked: the JAX trainer's
    `eval_keys`."""
    import jax
    import jax.numpy as jnp

    return jnp.stack([jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(s), EVAL_STREAM), epoch)
                      for s in seeds])


def fresh_eval_start_keys(seeds, epoch: int, n: int):
    """Reset keys (n_seeds · n, 2) of `n` new evaluation start states per seed (`sf2-torch eval --episodes
    n`): split(fold_in(eval key, 1), n) per seed, as the JAX trainer's `Program.fresh_eval_starts`."""
    import jax
    import jax.numpy as jnp

    return jnp.concatenate([jax.random.split(jax.random.fold_in(k, 1), n) for k in eval_keys(seeds, epoch)])


@dataclasses.dataclass
class SeedState:
    seed: int
    algo: Algorithm
    replay: ReplayBuffer
    generator: torch.Generator


@dataclasses.dataclass
class TrainState:
    seeds: tuple[int, ...]
    agents: list[SeedState]
    env: Any                      # PlaygroundEnv of len(seeds) · num_envs envs
    obs: torch.Tensor             # (seeds, num_envs, D): the observations to act on
    eval_keys: Any = None         # JAX reset keys (seeds · num_eval_envs, 2) of the evaluation start states
    env_steps: int = 0
    grad_steps: int = 0


class Program:
    """What one config needs (module docstring). Build with `get_program(cfg)`."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.device = configs.resolve_device(cfg)
        self.compile_mode = configs.resolve_compile(cfg, self.device)
        self.cudagraphs = configs.resolve_cudagraphs(cfg, self.device)
        self.spec = envs.env_spec(cfg.task, cfg.episode_length, cfg.action_repeat)
        self.sf2 = cfg.sf2_config(self.spec.obs_size, self.spec.action_size)
        self.rep_cls = representations.get(cfg.representation)
        self.sched = common_configs.schedule(cfg)
        # the order an SGD step computes its losses in (names the first NaN when several appear at once)
        self.loss_order = ("critic_loss", self.rep_cls.aux_loss_name, "alpha_loss", "actor_loss")

    # ------------------------------------------------------------------ setup
    def learner_precision(self):
        """`cfg.learner_precision` (common_configs.LEARNER_PRECISIONS): TF32 matmuls when
        "tensorfloat32" (torch's global flags; the physics is MJX, traced at fp32 `highest` by
        `envs.env_spec`, whatever torch's flags say). Returns the context the learner's forwards run in:
        bf16 autocast when "bfloat16" (bf16 matmul inputs; parameters, Adam states, gradients and the
        losses' reductions stay fp32), else nothing."""
        torch.backends.cuda.matmul.allow_tf32 = self.cfg.learner_precision == "tensorfloat32"
        torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32
        if self.cfg.learner_precision == "bfloat16":
            return torch.autocast(self.device.type, dtype=torch.bfloat16)
        return contextlib.nullcontext()

    def make_agent(self, seed: int) -> SeedState:
        torch.manual_seed(seed)
        algo = make_algorithm(self.cfg.algo, self.sf2, self.rep_cls, device=self.device,
                              compile_mode=self.compile_mode, cudagraphs=self.cudagraphs)
        generator = torch.Generator(device=self.device).manual_seed(seed)
        replay = ReplayBuffer(self.cfg.max_replay_size, self.device, generator)
        return SeedState(seed, algo, replay, generator)

    def init(self, seeds) -> TrainState:
        self.learner_precision()
        agents = [self.make_agent(s) for s in seeds]
        env = envs.make_env(self.cfg.task, self.cfg.episode_length, self.cfg.action_repeat,
                            len(seeds) * self.cfg.num_envs, self.device)
        train_keys, eval_start_keys = env_reset_keys(seeds, self.cfg.num_envs, self.cfg.num_eval_envs)
        obs = env.reset_from_keys(train_keys).get("observation")
        return TrainState(tuple(seeds), agents, env, obs.view(len(seeds), self.cfg.num_envs, -1),
                          eval_keys=eval_start_keys)

    # ------------------------------------------------------------------ acting
    def _env_step(self, state: TrainState, actions: torch.Tensor) -> TensorDict:
        """Step every env with `actions` (seeds, num_envs, A); returns the transitions (seeds, num_envs)."""
        s, n = len(state.seeds), self.cfg.num_envs
        obs, actions = state.obs.reshape(s * n, -1), actions.reshape(s * n, -1)
        nxt = state.env.step_actions(actions)
        trans = TensorDict({"observation": obs, "action": actions,
                            "next": nxt.select("observation", "reward", "done", "terminated", "truncated")},
                           [s * n], device=self.device)
        state.obs = nxt.get("observation").view(s, n, -1)
        state.env_steps += self.sched.env_steps_per_actor_step
        return trans.view(s, n)

    def _observe(self, state: TrainState, trans: TensorDict) -> None:
        for i, agent in enumerate(state.agents):
            t = trans[i]
            if self.cfg.normalize_observations:
                # Brax's running statistics, updated with the observations acted on
                networks.update_normalizer(agent.algo.nets.obs_norm, t.get("observation"), self.sf2)
            agent.replay.insert(t)

    def _actor_step(self, state: TrainState, actor_step: int, metrics, sgd_index) -> None:
        """Global actor step `actor_step` (0-based): prefill (uniform random actions, no SGD) or act,
        observe and take `grad_updates_per_step` SGD steps."""
        cfg = self.cfg
        if actor_step < self.sched.prefill_actor_steps:
            actions = torch.stack([
                torch.rand(cfg.num_envs, self.spec.action_size, device=self.device, generator=ag.generator)
                * 2.0 - 1.0 for ag in state.agents])
            self._observe(state, self._env_step(state, actions))
            return
        with self.learner_precision():
            actions = torch.stack([ag.algo.explore(state.obs[i], ag.generator)
                                   for i, ag in enumerate(state.agents)]).float()
        self._observe(state, self._env_step(state, actions))
        G, B = cfg.grad_updates_per_step, cfg.batch_size
        local = actor_step % self.sched.actor_steps_per_epoch
        for i, ag in enumerate(state.agents):
            batches = to_batch(ag.replay.sample(G * B).reshape(G, B))
            noise = ag.algo.step_noise(ag.generator, batches)
            for g in range(G):  # the step index drives the policy delay and `aux_every` schedules
                batch = losses.Batch(*(x[g] for x in batches))
                with self.learner_precision():
                    metrics[i].append(ag.algo.sgd_step(batch, {k: v[g] for k, v in noise.items()},
                                                       step=state.grad_steps + g))
        sgd_index.extend(local * G + g for g in range(G))
        state.grad_steps += G

    def epoch(self, state: TrainState, epoch: int) -> tuple[TrainState, dict, dict]:
        """Run epoch `epoch` (1-based). Returns (state, {metric: (seeds,) means over the epoch's SGD
        steps, "sgd_steps": (seeds,) counts}, {metric: (seeds,) first non-finite index | −1})."""
        metrics: list[list[dict]] = [[] for _ in state.agents]
        sgd_index: list[int] = []
        first = (epoch - 1) * self.sched.actor_steps_per_epoch
        for actor_step in range(first, first + self.sched.actor_steps_per_epoch):
            self._actor_step(state, actor_step, metrics, sgd_index)
        n = len(state.agents)
        means = {"sgd_steps": np.full(n, len(sgd_index))}
        first_bad: dict[str, np.ndarray] = {}
        if sgd_index:
            names = sorted(metrics[0][0])
            # (seeds, steps, metrics): the epoch's one host transfer
            stacked = torch.stack([torch.stack([torch.stack([m[k] for k in names]) for m in ms])
                                   for ms in metrics]).to("cpu").double().numpy()
            for j, name in enumerate(names):
                per_seed = [s[:, j] for s in stacked]
                means[name] = np.array([v.mean() for v in per_seed])
                first_bad[name] = np.array([
                    -1 if np.isfinite(v).all() else sgd_index[int(np.argmin(np.isfinite(v)))]
                    for v in per_seed])
        return state, means, first_bad

    def eval_policy(self, agents, generators) -> Callable[[torch.Tensor], torch.Tensor]:
        """The evaluation's acting: observations (seeds, n, D) → every seed's `act` (seeds, n, A), float32,
        with `cfg.deterministic_eval`, seed i's noise drawn from `generators[i]`. On CUDA with `cudagraphs`,
        a learner precision other than bfloat16 (whose autocast caches casts) and a torch that can register
        generators with a graph, the seeds' policies are one CUDA graph, replayed once per step after one
        eager call (`graphs.StepGraph`); else the seeds act one after another."""
        det = self.cfg.deterministic_eval

        @torch.no_grad()
        def act(obs):
            with self.learner_precision():
                return torch.stack([ag.algo.act(obs[i], generators[i], det)
                                    for i, ag in enumerate(agents)]).float()

        if (self.cudagraphs and self.cfg.learner_precision != "bfloat16"
                and graphs.graphs_draw_from_generators()):
            return graphs.StepGraph(act, warmup=1, generators=generators)
        return act

    @torch.no_grad()
    def evaluate(self, agents, start_keys, seeds, epoch: int, env=None, obs_noise: float = 0.0) -> np.ndarray:
        """Episode returns (n_seeds, n) of one episode from each start state, the envs reset from the JAX
        keys `start_keys` (n_seeds · n, 2); the acting noise depends on (seed, epoch). `obs_noise` > 0 adds
        Gaussian noise of that std to every observation the policy sees (paper App. C.2.2), drawn from its
        own generator per seed, so the acting noise is that of the noise-free evaluation."""
        cfg = self.cfg
        s = len(seeds)
        n = start_keys.shape[0] // s
        env = env or envs.make_env(cfg.task, cfg.episode_length, cfg.action_repeat, s * n, self.device)
        obs = env.reset_from_keys(start_keys).get("observation").view(s, n, -1)
        gens = [torch.Generator(device=self.device).manual_seed(
            (int(seed) * 1_000_003 + EVAL_STREAM * 7919 + int(epoch)) % (2**63)) for seed in seeds]
        noise_gens = [torch.Generator(device=self.device).manual_seed(
            (int(seed) * 1_000_003 + OBS_NOISE_STREAM * 7919 + int(epoch)) % (2**63)) for seed in seeds]
        policy = self.eval_policy(agents, gens)
        ret = torch.zeros(s, n, device=self.device)
        alive = torch.ones(s, n, device=self.device)
        for _ in range(self.sched.eval_actor_steps):
            seen = obs
            if obs_noise:
                seen = obs + obs_noise * torch.stack([torch.randn(obs[i].shape, generator=noise_gens[i],
                                                                  device=self.device, dtype=obs.dtype)
                                                      for i in range(s)])
            actions = policy(seen)
            nxt = env.step_actions(actions.reshape(s * n, -1))
            ret += nxt.get("reward").view(s, n) * alive
            alive *= 1.0 - nxt.get("done").view(s, n).to(alive.dtype)
            obs = nxt.get("observation").view(s, n, -1)
        return ret.cpu().numpy()

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self, state: TrainState) -> dict:
        out = {"seeds": list(state.seeds), "env_steps": state.env_steps, "grad_steps": state.grad_steps,
               "obs": state.obs.cpu(), "agents": []}
        for ag in state.agents:
            out["agents"].append({"seed": ag.seed, "algo": ag.algo.state_dict(),
                                  "replay": ag.replay.state_dict(), "generator": ag.generator.get_state()})
        return out

    def load_state_dict(self, state: TrainState, saved: dict, env_leaves) -> TrainState:
        if list(saved["seeds"]) != list(state.seeds):
            raise CheckpointMismatch(f"checkpoint seeds {saved['seeds']} differ from {list(state.seeds)}")
        try:
            for ag, s in zip(state.agents, saved["agents"]):
                ag.algo.load_state_dict(s["algo"])
                ag.replay.load_state_dict(s["replay"])
                # a generator takes its state as a CPU byte tensor, wherever the checkpoint was loaded
                ag.generator.set_state(s["generator"].cpu())
            state.env.set_state_leaves(env_leaves)
        except (RuntimeError, ValueError, KeyError) as err:
            raise CheckpointMismatch(f"checkpoint does not fit this program: {err}") from err
        state.obs = saved["obs"].to(self.device)
        state.env_steps, state.grad_steps = int(saved["env_steps"]), int(saved["grad_steps"])
        return state


_PROGRAMS: dict[TrainConfig, Program] = {}


def get_program(cfg: TrainConfig) -> Program:
    """What one config needs in this process, cached (the env functions are cached per task as well).

    Args:
      cfg: the run's `TrainConfig` (frozen, hashable: the cache key).

    Returns:
      Its `Program` (the last 8 configs' are kept).

    Raises:
      ConfigError: the task is unknown or has structured observations, or the representation is unknown.
    """
    if cfg not in _PROGRAMS:
        if len(_PROGRAMS) >= 8:
            _PROGRAMS.pop(next(iter(_PROGRAMS)))
        _PROGRAMS[cfg] = Program(cfg)
    return _PROGRAMS[cfg]


# ------------------------------------------------------------------------------------------- host loop
@dataclasses.dataclass
class TrainResult:
    run: RunFolder
    rows: list[dict]
    state: TrainState
    seeds: tuple[int, ...]
    resumed_from: int | None    # checkpoint epoch resumed from, if any


def _save(ckpt: Checkpointer, program: Program, state: TrainState, epoch: int, env_steps: int, seeds) -> None:
    # written in the background while the next epochs train; the checkpointer completes it before the
    # next save and on close (checkpoint.py)
    ckpt.save(epoch, program.state_dict(state), state.env.get_state_leaves(),
              {"env_steps": env_steps, "seeds": list(seeds), "framework": "torch"}, wait=False)


def train(cfg: TrainConfig, seeds, out, *, resume: bool = True, fresh: bool = False,
          progress: bool = True, hook: Callable[[str, int], None] | None = None,
          stop_after_epoch: int | None = None, plot: bool = True, log=()) -> TrainResult:
    """Train one config for every seed (one agent per seed, their envs in one batch) into a run folder.

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
      ConfigError: bad input, before anything is built.
      RunFolderError: a run folder that cannot be used (another run's, another core's, in use).
      TrainingDiverged: a NaN or inf loss (nothing of that epoch is written).
    """
    seeds = common_configs.parse_seeds(seeds)
    configs.validate(cfg, seeds)
    if stop_after_epoch is not None and (not isinstance(stop_after_epoch, int) or stop_after_epoch < 0):
        raise ConfigError(f"stop_after_epoch = {stop_after_epoch!r} is invalid: must be an int >= 0")
    log = loggers.parse_log(log)
    run = RunFolder(out)
    run.check_usable()
    lock = FolderLock(run.path, "sf2-torch train").acquire(say=run.say)   # one writer per run folder
    try:
        if fresh:
            run.clear()
        run.check_framework("torch")
        cfg = run.keep_trained_values(cfg)
        existing = run.check_compatible(cfg.to_dict(), seeds)
        sched = common_configs.schedule(cfg)
        program = get_program(cfg)
        hardware = _hardware(program.device)
        env = hostloop.numerics_environment()
        if not existing:
            run.write_config({"config": cfg.to_dict(), "seeds": list(seeds),
                              "schedule": dataclasses.asdict(sched), "label": _label(cfg),
                              "versions": _versions(), "framework": "torch",
                              "device": str(program.device), "hardware": hardware, "environment": env,
                              "compile_mode": program.compile_mode, "cudagraphs": program.cudagraphs})
        run.log(f"hardware: {hardware}")
        run.log(hostloop.environment_line(env))
        ckpt = Checkpointer(run.checkpoint_dir, keep=cfg.keep_checkpoints)
        title = hostloop.run_title(_label(cfg), cfg.task, seeds)
        state = program.init(seeds)

        def restore(epoch: int) -> dict:
            saved, leaves, meta = ckpt.restore(epoch, map_location=program.device)
            program.load_state_dict(state, saved, leaves)
            return meta

        try:
            res = resume_run(run, ckpt, restore, seeds=seeds, sched=sched, existing=existing, resume=resume)
            rows = hostloop.run_epochs(_Session(program, ckpt, run, state), cfg=cfg, sched=sched, seeds=seeds,
                                       run=run, title=title, rows=res.rows, start=res.start, last=res.epoch,
                                       walltime=res.walltime, progress=progress, hook=hook,
                                       stop_after_epoch=stop_after_epoch, plot=plot, log=log)
        finally:
            ckpt.close()
        return TrainResult(run=run, rows=rows, state=state, seeds=seeds, resumed_from=res.epoch)
    finally:
        lock.release()


class _Session:
    """The `sf2_common.agents.hostloop.Session` of one run: every seed's agent, the envs, the evaluation
    envs (built at the first evaluation, then reused)."""

    def __init__(self, program: Program, ckpt: Checkpointer, run: RunFolder, state: TrainState):
        self.program, self.ckpt, self.run, self.state = program, ckpt, run, state
        self.eval_env = None

    def start(self) -> None:
        pass  # `Program.init` built the state before the checkpoint (if any) was restored into it

    def train_epoch(self, epoch: int):
        self.state, means, first_bad = self.program.epoch(self.state, epoch)
        return means, first_bad

    def evaluate(self, epoch: int) -> np.ndarray:
        seeds = self.state.seeds
        self.eval_env = self.eval_env or _eval_env(self.program, seeds)
        return self.program.evaluate(self.state.agents, self.state.eval_keys, seeds, epoch, self.eval_env)

    def save(self, epoch: int, env_steps: int) -> None:
        _save(self.ckpt, self.program, self.state, epoch, env_steps, self.state.seeds)

    def write_seconds(self) -> float | None:
        return self.ckpt.write_seconds

    def loss_order(self) -> tuple[str, ...]:
        return self.program.loss_order

    def finish(self) -> None:
        _write_final(self.run, self.state)


def _eval_env(program: Program, seeds):
    cfg = program.cfg
    return envs.make_env(cfg.task, cfg.episode_length, cfg.action_repeat, len(seeds) * cfg.num_eval_envs,
                         program.device)


def _label(cfg: TrainConfig) -> str:
    return method_label(cfg.algo, cfg.representation, representations.REGISTRY)


def _write_final(run: RunFolder, state: TrainState) -> None:
    run.final_dir.mkdir(parents=True, exist_ok=True)
    for ag in state.agents:
        np.savez(run.final_dir / f"params_seed{ag.seed}.npz", **params.to_canonical(ag.algo.groups))


def _hardware(device: torch.device) -> str:
    """The device this run's program uses (`hostloop.hardware`)."""
    return hostloop.hardware([torch.cuda.get_device_name(device)] if device.type == "cuda" else [])


def _versions() -> dict:
    return hostloop.versions(("torch", "torchrl", "tensordict", "jax", "jaxlib", "playground", "mujoco",
                              "mujoco-mjx", "sf2-core-torch", "sf2-common"))


def _restore_acting(ckpt: Checkpointer, job: CheckpointJob):
    """(every seed's agent, loaded from checkpoint `job.epoch`, the checkpoint's meta); the replay buffers it
    also holds are dropped here."""
    program = get_program(job.eval_cfg)
    program.learner_precision()
    agents = [program.make_agent(s) for s in job.seeds]
    saved, _, meta = ckpt.restore(job.epoch, map_location=program.device)
    try:
        for ag, s in zip(agents, saved["agents"]):
            ag.algo.load_state_dict(s["algo"])
    except (RuntimeError, KeyError) as err:
        raise CheckpointMismatch(f"checkpoint {job.epoch} does not fit this program: {err}") from err
    return agents, meta


def _act(agents, job: CheckpointJob) -> list[np.ndarray]:
    """Episode returns (seeds, episodes) per noise std of `job`, from the run's evaluation start states or
    `job.episodes` fresh ones."""
    if job.episodes is None:
        starts = env_reset_keys(job.seeds, job.cfg.num_envs, job.cfg.num_eval_envs)[1]
    else:
        starts = fresh_eval_start_keys(job.seeds, job.key, job.episodes)
    program = get_program(job.eval_cfg)
    return [program.evaluate(agents, starts, job.seeds, job.key, obs_noise=noise) for noise in job.noises]


# evaluate_checkpoint(out, epoch, num_eval_envs, deterministic, obs_noise) and evaluate_checkpoint_noises(...,
# noises): the framework-free half is sf2_common.agents.evaluation's (documented there)
_EVALUATOR = CheckpointEvaluator("torch", TrainConfig, Checkpointer, _restore_acting, _act)
evaluate_checkpoint = _EVALUATOR.evaluate_checkpoint
evaluate_checkpoint_noises = _EVALUATOR.evaluate_checkpoint_noises
