"""Tasks and env creation. The task table (Playground's tasks and users' environments, the paper's
per-task budgets and action repeat: Appendix E Table 1; docs/core-contract.md "Agents") is
`sf2_common.agents.tasks`, re-exported here; envs are built by its `training_env`: Playground's tasks with
the pure-JAX MJX backend (`config_overrides={'impl': 'jax'}`), wrapped with Playground's
`wrap_for_brax_training` (Brax's VmapWrapper + EpisodeWrapper(episode_length, action_repeat) + auto-reset
to the cached first state; `state.info['truncation']` is 1 on the step an episode is cut by the time
limit). Nothing in the wrapper stack uses pmap-era JAX APIs, so it works under jax >= 0.10.

Playground is imported lazily, so `import sf2_jax.agents` stays cheap.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

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

__all__ = [
    "PAPER_TASKS", "PAPER_BUDGETS", "PAPER_ACTION_REPEAT", "valid_tasks", "validate_task",
    "paper_budget", "paper_action_repeat", "EnvSpec", "env_spec", "StrongTypes", "strong_types",
]


@dataclass(frozen=True)
class EnvSpec:
    """The wrapped training and evaluation envs of one task and their sizes."""

    task: str
    train_env: Any
    eval_env: Any
    obs_size: int
    action_size: int
    episode_length: int
    action_repeat: int


@functools.lru_cache(maxsize=16)
def env_spec(task: str, episode_length: int, action_repeat: int) -> EnvSpec:
    """Load a task with the MJX backend, wrapped for training and for evaluation.

    Both use Playground's `wrap_for_brax_training` (auto-reset, truncation flag); the evaluator runs exactly
    one episode per env and ignores the resets.

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
    train_env, sizes = training_env(task, episode_length, action_repeat)
    eval_env, _ = training_env(task, episode_length, action_repeat)
    return EnvSpec(task=task, train_env=StrongTypes(train_env), eval_env=StrongTypes(eval_env),
                   obs_size=sizes.obs_size, action_size=sizes.action_size, episode_length=episode_length,
                   action_repeat=action_repeat)


class StrongTypes:
    """An env whose `reset` and `step` return every state leaf strongly typed (`x.astype(x.dtype)`).

    Playground tasks return some leaves weakly typed, at reset or at step (CheetahRun's `data.time` after
    reset, the Cartpole sparse tasks' and HopperHop's reward metrics after a step; docs/physics.md). The
    training epoch's `lax.scan` hands back its carry strongly typed, so a program called first with a
    reset state and then with its own output would compile twice. Values are unchanged. The torch
    trainer's env does the same (`sf2_torch.agents.envs._physics`)."""

    def __init__(self, env):
        self.env = env

    def reset(self, rng):
        return strong_types(self.env.reset(rng))

    def step(self, state, action):
        return strong_types(self.env.step(state, action))

    def __getattr__(self, name):          # observation_size, action_size, unwrapped, ...
        return getattr(self.env, name)


def strong_types(tree):
    """The same pytree with every leaf strongly typed, values unchanged.

    A weak leaf's program input type differs from the same leaf after `lax.scan` or `jit`, which would
    compile the program again.

    Args:
      tree: a pytree of JAX arrays (an env state).

    Returns:
      The tree, each leaf `x.astype(x.dtype)`.
    """
    import jax

    return jax.tree_util.tree_map(lambda x: x.astype(x.dtype), tree)
