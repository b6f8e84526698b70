"""Tasks and env creation. The task table (which MuJoCo Playground DM Control tasks exist, the paper's
per-task budgets and action repeat) is `sf2_common.agents.tasks`, re-exported here (as in the JAX
agents).

Environments: `PlaygroundEnv` is a TorchRL env (a subclass of TorchRL's `MujocoPlaygroundWrapper`) around
the *same* JAX env the JAX trainer steps: Playground's task with the pure-JAX MJX backend
(`config_overrides={'impl': 'jax'}`), wrapped by `wrap_for_brax_training` (Brax's VmapWrapper +
EpisodeWrapper(episode_length, action_repeat) + auto-reset to the cached first state). So both frameworks
see identical dynamics, truncation flags and resets; arrays cross between JAX and torch by DLPack.

Why not TorchRL's `MujocoPlaygroundEnv` as it is: it steps the bare task (no time limit, so no truncation
signal: its `terminated` equals `done`), resets the whole batch at once (no per-env auto-reset), has no
action repeat of its own (a FrameSkipTransform sums rewards but does not count env steps the Brax way),
and runs `vmap(jit(step))`, which re-traces the vmap on every call. The subclass keeps TorchRL's specs,
`reset`/`step`/`rollout` API and TensorDict layout, and replaces `_init_env`/`_reset`/`_step`:

- one `jax.jit` of the whole vectorised reset and step (shared by every env of the same task, episode
  length and action repeat in the process, so training and evaluation envs compile once per batch size);
- outputs `observation`, `reward` (…, 1), `done`, `terminated` and `truncated` (…, 1), TorchRL's done
  convention: `done = terminated | truncated`, with Brax's `done` and `info['truncation']`;
- auto-reset happens inside the JAX step (Brax semantics): on the step an episode ends, `next.observation`
  is already the first observation of the next episode, exactly what the JAX trainer stores as s′
  (its critic masks truncated transitions and does not bootstrap terminal ones, so s′ only matters for
  the flow loss on terminal steps, which DM Control tasks do not have). Call `reset` once; never on done.
- `reset_from_keys(keys)`: reset from explicit JAX PRNG keys (n, 2), so the torch trainer starts its envs and
  evaluation episodes from the same states as the JAX trainer with the same seed.
- `get_state_leaves()` / `set_state_leaves(leaves)`: the JAX env state as numpy arrays, for checkpoints.

Playground and JAX are imported when an env is built.
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
    valid_tasks,
    validate_task,
)
from sf2_common.errors import ConfigError
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


@functools.lru_cache(maxsize=16)
def env_spec(task: str, episode_length: int, action_repeat: int) -> EnvSpec:
    """Load `task` with the MJX backend, wrap it as the JAX trainer does, jit reset and step (cached)."""
    validate_task(task)
    import jax
    from mujoco_playground import registry, wrapper

    env = registry.load(task, config_overrides={"impl": "jax"})
    obs_size = env.observation_size
    if not isinstance(obs_size, int):
        raise ConfigError(f"task {task!r} has structured observations {obs_size}; only flat state "
                          f"observations are supported")
    wrapped = wrapper.wrap_for_brax_training(env, episode_length=episode_length, action_repeat=action_repeat)
    return EnvSpec(task=task, jax_env=wrapped, reset=jax.jit(_physics(wrapped.reset)),
                   step=jax.jit(_physics(wrapped.step)), obs_size=int(obs_size),
                   action_size=int(env.action_size), episode_length=episode_length,
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
    """A `PlaygroundEnv` of `num_envs` parallel copies of `task` on `device`."""
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
        self._current_state = None
        self._treedef = None
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
        action = tensordict.get("action")
        state = self._spec.step(self._current_state, self._to_jax(action.to(torch.float32)))
        self._current_state = state
        return self._outputs(state, with_reward=True)

    # ---------------------------------------------------------------- helpers
    def reset_from_keys(self, keys) -> TensorDict:
        """Reset every env from explicit JAX PRNG keys (num_envs, 2); returns the reset TensorDict."""
        self._reset_from(keys)
        return self._outputs(self._current_state, with_reward=False)

    def _reset_from(self, keys):
        import jax

        keys = jax.device_put(keys, self._jax_device)  # committed, like every later input
        state = self._spec.reset(keys)
        self._current_state = state
        self._treedef = jax.tree_util.tree_structure(state)
        return self._outputs(state, with_reward=False)

    def _to_jax(self, t: torch.Tensor):
        """`t` as a JAX array of JAX's default float width: MJX builds its state in float64 when
        `jax_enable_x64` is on (a float32 action would then break its `lax.scan` carry)."""
        import jax

        if t.device.type == "cuda":
            x = jax.dlpack.from_dlpack(t.contiguous())
        else:
            x = jax.device_put(t.detach().contiguous().numpy(), self._jax_device)
        return x.astype(jax.dtypes.canonicalize_dtype(np.float64))

    def _to_torch(self, x) -> torch.Tensor:
        return torch.from_dlpack(x).to(self.device)

    def _outputs(self, state, with_reward: bool):
        n = (*self.batch_size, 1)
        done = self._to_torch(state.done).view(n) > 0.5
        trunc = self._to_torch(state.info["truncation"]).view(n) > 0.5
        out = {"observation": self._to_torch(state.obs).to(torch.float32).clone(),
               "done": done, "terminated": done & ~trunc, "truncated": trunc}
        if with_reward:
            out["reward"] = self._to_torch(state.reward).to(torch.float32).view(n).clone()
        return TensorDict._new_unsafe(source=out, batch_size=self.batch_size, device=self.device)

    def get_state_leaves(self) -> list[np.ndarray]:
        import jax

        return [np.asarray(x) for x in jax.tree_util.tree_leaves(self._current_state)]

    def set_state_leaves(self, leaves) -> None:
        import jax

        if self._treedef is None:
            raise RuntimeError("reset the env once before restoring its state")
        template = jax.tree_util.tree_leaves(self._current_state)
        if len(template) != len(leaves):
            raise ValueError(f"env state has {len(template)} arrays, got {len(leaves)}")
        arrays = []
        for t, x in zip(template, leaves):
            x = np.asarray(x)
            if x.shape != t.shape or x.dtype != t.dtype:
                raise ValueError(f"env state array {x.shape} {x.dtype} does not fit {t.shape} {t.dtype}")
            arrays.append(jax.device_put(x, self._jax_device))
        self._current_state = jax.tree_util.tree_unflatten(self._treedef, arrays)

    def __repr__(self) -> str:
        return (f"PlaygroundEnv(task={self._spec.task!r}, num_envs={self.batch_size.numel()}, "
                f"episode_length={self._spec.episode_length}, action_repeat={self._spec.action_repeat}, "
                f"device={self.device})")
