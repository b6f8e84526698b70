"""Tasks and env creation, for the torch trainer. The task table (Playground's tasks and users' environments,
the paper's budgets and action repeat) is `sf2_common.agents.tasks`, re-exported here as in the JAX agents.

`PlaygroundEnv` is a TorchRL env (a subclass of TorchRL's `MujocoPlaygroundWrapper`) around the *same* JAX
env the JAX trainer steps: Playground's task with the pure-JAX MJX backend, wrapped by
`wrap_for_brax_training` (episode length, action repeat, auto-reset inside the step), so both frameworks
see identical dynamics, truncation flags and resets; arrays cross by DLPack. TorchRL's own
`MujocoPlaygroundEnv` steps the bare task (no time limit, no per-env auto-reset, no action repeat), so the
subclass keeps TorchRL's specs and `reset`/`step`/`rollout` API and replaces `_init_env`/`_reset`/`_step`:
one jitted vectorised reset and step per task, episode length and action repeat; TorchRL's done
convention (`done = terminated | truncated`); `reset_from_keys` from the JAX trainer's keys;
`step_actions`, the step without TorchRL's `step` around it (the trainer's loops); the state
kept packed into one buffer per dtype between steps (`StateLayout`, exact; fewer arrays cross per call:
docs/decisions/torch-trainer-step.md); `get_state_leaves`/`set_state_leaves` for checkpoints. Playground
and JAX are imported when an env is built.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from sf2_common.agents.tasks import (
    PAPER_ACTION_REPEAT,
    PAPER_BUDGETS,
    PAPER_TASKS,
    paper_action_repeat,
    paper_budget,
    training_env,
    valid_tasks,
    validate_task,
)
from tensordict import TensorDict
from torchrl.data.tensor_specs import Bounded, Composite, Unbounded
from torchrl.envs import MujocoPlaygroundWrapper

__all__ = [
    "PAPER_TASKS", "PAPER_BUDGETS", "PAPER_ACTION_REPEAT", "valid_tasks", "validate_task",
    "paper_budget", "paper_action_repeat", "EnvSpec", "env_spec", "make_env", "PlaygroundEnv",
]


@dataclass(frozen=True)
class EnvSpec:
    """The wrapped JAX env of one task, its jitted vectorised reset/step, and its sizes."""

    task: str
    jax_env: Any          # wrap_for_brax_training(...) of the MJX task
    reset: Any            # jax.jit(jax_env.reset): keys (n, 2) -> state
    step: Any             # jax.jit(jax_env.step): (state, action (n, A)) -> state
    obs_size: int
    action_size: int
    episode_length: int
    action_repeat: int


@dataclass(frozen=True)
class StateLayout:
    """How a JAX env state (a pytree) is packed: its leaves grouped by dtype, each group raveled into one
    flat buffer, in leaf order. `pack`/`unpack` work on JAX arrays (`xp=jax.numpy`, inside jit) and on numpy
    arrays (`xp=numpy`, checkpoints) alike."""

    treedef: Any
    shapes: tuple[tuple[int, ...], ...]
    dtypes: tuple[str, ...]

    @classmethod
    def of(cls, state) -> StateLayout:
        import jax

        leaves, treedef = jax.tree_util.tree_flatten(state)
        return cls(treedef, tuple(tuple(x.shape) for x in leaves), tuple(str(x.dtype) for x in leaves))

    @property
    def groups(self) -> tuple[str, ...]:
        return tuple(sorted(set(self.dtypes)))

    def pack(self, leaves, xp) -> tuple:
        return tuple(xp.concatenate([xp.ravel(x) for x, d in zip(leaves, self.dtypes) if d == g])
                     for g in self.groups)

    def unpack(self, buffers, xp) -> list:
        offsets = dict.fromkeys(self.groups, 0)
        by_group = dict(zip(self.groups, buffers))
        leaves = []
        for shape, d in zip(self.shapes, self.dtypes):
            size = int(np.prod(shape, dtype=np.int64))
            start = offsets[d]
            leaves.append(xp.reshape(by_group[d][start:start + size], shape))
            offsets[d] = start + size
        return leaves


def _transition(state):
    """[observation | reward | done | truncation] (n, D + 3) float32, one array for one DLPack crossing."""
    import jax.numpy as jnp

    n = state.obs.shape[0]
    cols = [state.obs, state.reward, state.done, state.info["truncation"]]
    return jnp.concatenate([c.reshape(n, -1).astype(jnp.float32) for c in cols], axis=-1)


@functools.lru_cache(maxsize=32)
def _packed_fns(spec: EnvSpec, layout: StateLayout):
    """(pack, step) of `spec` on states of `layout`, jitted once per task and batch size: `pack(state)` →
    (buffers, transition); `step(buffers, action)` → (buffers′, transition), the buffers donated."""
    import jax
    import jax.numpy as jnp

    def unflatten(buffers):
        return jax.tree_util.tree_unflatten(layout.treedef, layout.unpack(buffers, jnp))

    def pack(state):
        return layout.pack(jax.tree_util.tree_leaves(state), jnp), _transition(state)

    def step(buffers, action):
        action = action.astype(jax.dtypes.canonicalize_dtype(np.float64))
        return pack(spec.step(unflatten(buffers), action))

    return jax.jit(pack), jax.jit(step, donate_argnums=0)


@functools.lru_cache(maxsize=16)
def env_spec(task: str, episode_length: int, action_repeat: int) -> EnvSpec:
    """Load a task with the MJX backend, wrapped as the JAX trainer wraps it, its reset and step jitted.

    Args:
      task: a Playground task or a user's environment (`validate_task`).
      episode_length: env steps per episode (the time limit; `truncation` is set where it cuts).
      action_repeat: physics steps per env step.

    Returns:
      Its `EnvSpec`, cached per (task, episode_length, action_repeat).

    Raises:
      ConfigError: an unknown task, or one whose observations or actions the agents cannot take
        (`sf2_common.agents.tasks.env_sizes`).
    """
    validate_task(task)
    import jax

    wrapped, sizes = training_env(task, episode_length, action_repeat)
    return EnvSpec(task=task, jax_env=wrapped, reset=jax.jit(_physics(wrapped.reset)),
                   step=jax.jit(_physics(wrapped.step)), obs_size=sizes.obs_size,
                   action_size=sizes.action_size, episode_length=episode_length,
                   action_repeat=action_repeat)


def _physics(fn):
    """`fn` (a JAX env's reset or step) traced at fp32 `highest` (TF32 inside MJX breaks training, and
    JAX's default on a GPU is TF32; docs/core-contract.md "Precision"), its output state strongly typed:
    several tasks' steps return weakly typed leaves (docs/physics.md), which would make the jitted step
    compile a second time when it is called with its own output."""
    import jax

    def traced(*args):
        with jax.default_matmul_precision("highest"):
            out = fn(*args)
        return jax.tree_util.tree_map(lambda x: x.astype(x.dtype), out)

    return traced


def make_env(task: str, episode_length: int, action_repeat: int, num_envs: int,
             device: torch.device | str = "cpu") -> PlaygroundEnv:
    """A TorchRL env of parallel copies of a task.

    Args:
      task, episode_length, action_repeat: as `env_spec`'s.
      num_envs: the batch of envs.
      device: where its tensors live.

    Returns:
      The `PlaygroundEnv`; call `reset` (or `reset_from_keys`) once, never on done.

    Raises:
      ConfigError: as `env_spec`.
    """
    return PlaygroundEnv(env_spec(task, episode_length, action_repeat), num_envs=num_envs, device=device)


class PlaygroundEnv(MujocoPlaygroundWrapper):
    """TorchRL env over a Brax-wrapped Playground task (see the module docstring):
    `PlaygroundEnv(spec, num_envs, device)`, `spec = env_spec(task, episode_length, action_repeat)`."""

    def __init__(self, spec: EnvSpec, num_envs: int, device="cpu"):
        self._spec = spec
        super().__init__(env=spec.jax_env, batch_size=torch.Size([int(num_envs)]), device=device)

    # ---------------------------------------------------------------- TorchRL hooks
    def _make_specs(self, env) -> None:
        n, a, d = self.batch_size, self._spec.action_size, self._spec.obs_size
        self.action_spec = Bounded(low=-1, high=1, shape=(*n, a), device=self.device)
        self.reward_spec = Unbounded(shape=(*n, 1), device=self.device)
        self.observation_spec = Composite(observation=Unbounded(shape=(*n, d), device=self.device),
                                          shape=n)
        bool_spec = Composite(
            done=Unbounded(shape=(*n, 1), dtype=torch.bool, device=self.device),
            terminated=Unbounded(shape=(*n, 1), dtype=torch.bool, device=self.device),
            truncated=Unbounded(shape=(*n, 1), dtype=torch.bool, device=self.device),
            shape=n)
        self.done_spec = bool_spec

    def _init_env(self):
        import jax

        self._key = None
        self._keep(_packed=None,     # the packed JAX state (module docstring)
                   _step_fn=None)    # its jitted step (`_packed_fns`), set at each reset
        self._layout: StateLayout | None = None
        self._jax_device = jax.devices("gpu" if self.device.type == "cuda" else "cpu")[0]

    def _set_seed(self, seed):
        import jax

        self._key = jax.random.PRNGKey(0 if seed is None else int(seed))

    def _reset(self, tensordict=None, **kwargs):
        import jax

        if self._key is None:
            self._key = jax.random.PRNGKey(0)
        self._key, sub = jax.random.split(self._key)
        return self._reset_from(jax.random.split(sub, self.batch_size.numel()))

    def _step(self, tensordict):
        return self.step_actions(tensordict.get("action"))

    # ---------------------------------------------------------------- helpers
    def step_actions(self, action: torch.Tensor) -> TensorDict:
        """Step every env with `action`, without TorchRL's `step` around it (the trainer's loops).

        Args:
          action: (num_envs, A).

        Returns:
          What `step(td)["next"]` holds: `observation`, `reward`, `done`, `terminated`, `truncated`.

        Raises:
          RuntimeError: the env was never reset.
          ValueError: `action` of another shape, or on another kind of device than the env's (the state is
            left as it was).
        """
        if self._step_fn is None:
            raise RuntimeError("reset the env once before stepping it")
        want = (*self.batch_size, self._spec.action_size)
        if tuple(action.shape) != want or action.device.type != self.device.type:
            raise ValueError(f"{self._spec.task}: an action of shape {tuple(action.shape)} on "
                             f"{action.device}; this env steps (num_envs, action_size) = {want} on "
                             f"{self.device}")
        packed, transition = self._step_fn(self._packed, self._to_jax(action.to(torch.float32)))
        self._keep(_packed=packed)
        return self._outputs(transition, with_reward=True)

    def _keep(self, **values) -> None:
        """Set plain attributes straight in the instance's dict, skipping TorchRL's and `nn.Module`'s
        `__setattr__` (spec and submodule bookkeeping, none of which a JAX state needs) on every step."""
        self.__dict__.update(values)

    def reset_from_keys(self, keys) -> TensorDict:
        """Reset every env from explicit JAX PRNG keys, as the JAX trainer resets from the same keys.

        Args:
          keys: JAX PRNG keys (num_envs, 2) (`trainer.env_reset_keys`, `fresh_eval_start_keys`).

        Returns:
          The reset TensorDict (`observation`, `done`, `terminated`, `truncated`).
        """
        return self._reset_from(keys)

    def _reset_from(self, keys):
        import jax

        keys = jax.device_put(keys, self._jax_device)  # committed, like every later input
        state = self._spec.reset(keys)
        self._layout = StateLayout.of(state)
        pack, step = _packed_fns(self._spec, self._layout)
        packed, transition = pack(state)
        self._keep(_packed=packed, _step_fn=step)
        return self._outputs(transition, with_reward=False)

    def _to_jax(self, t: torch.Tensor):
        """`t` as a JAX array (the jitted step casts it to JAX's default float width: MJX builds its
        state in float64 when `jax_enable_x64` is on, and a float32 action would then break its `lax.scan`
        carry)."""
        import jax

        if t.device.type == "cuda":
            return jax.dlpack.from_dlpack(t.contiguous())
        return jax.device_put(t.detach().contiguous().numpy(), self._jax_device)

    def _outputs(self, transition, with_reward: bool):
        """The TensorDict of one `_transition` array (copied out of JAX's buffer)."""
        n, d = (*self.batch_size, 1), self._spec.obs_size
        t = torch.from_dlpack(transition).to(self.device)
        done, trunc = t[:, d + 1:d + 2] > 0.5, t[:, d + 2:d + 3] > 0.5
        out = {"observation": t[:, :d].clone(), "done": done.view(n), "terminated": (done & ~trunc).view(n),
               "truncated": trunc.view(n)}
        if with_reward:
            out["reward"] = t[:, d:d + 1].clone().view(n)
        return TensorDict._new_unsafe(source=out, batch_size=self.batch_size, device=self.device)

    def get_state_leaves(self) -> list[np.ndarray]:
        """The JAX env state as numpy arrays in tree order, copies (for a checkpoint).

        Returns:
          The state's leaves.

        Raises:
          RuntimeError: the env was never reset.
        """
        if self._layout is None:
            raise RuntimeError("reset the env once before reading its state")
        # copies: the next step donates the buffers, and a checkpoint is written while the next epochs train
        return [np.array(x) for x in self._layout.unpack([np.asarray(b) for b in self._packed], np)]

    def set_state_leaves(self, leaves) -> None:
        """Restore the JAX env state from `get_state_leaves`'s arrays.

        Args:
          leaves: the arrays, in tree order.

        Raises:
          RuntimeError: the env was never reset (its layout is unknown).
          ValueError: the arrays do not fit the state (count, shape or dtype).
        """
        import jax

        if self._layout is None:
            raise RuntimeError("reset the env once before restoring its state")
        layout = self._layout
        if len(layout.shapes) != len(leaves):
            raise ValueError(f"env state has {len(layout.shapes)} arrays, got {len(leaves)}")
        arrays = []
        for shape, dtype, x in zip(layout.shapes, layout.dtypes, leaves):
            x = np.asarray(x)
            if x.shape != shape or str(x.dtype) != dtype:
                raise ValueError(f"env state array {x.shape} {x.dtype} does not fit {shape} {dtype}")
            arrays.append(x)
        self._keep(_packed=tuple(jax.device_put(b, self._jax_device) for b in layout.pack(arrays, np)))

    def __repr__(self) -> str:
        return (f"PlaygroundEnv(task={self._spec.task!r}, num_envs={self.batch_size.numel()}, "
                f"episode_length={self._spec.episode_length}, action_repeat={self._spec.action_repeat}, "
                f"device={self.device})")
