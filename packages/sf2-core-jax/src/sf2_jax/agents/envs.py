"""Tasks and env creation. The task table (which MuJoCo Playground DM Control tasks exist, the paper's
per-task budgets and action repeat: Appendix E Table 1; docs/core-contract.md "Agents") is
`sf2_common.agents.tasks`, re-exported here. Environments always use the pure-JAX MJX backend
(`config_overrides={'impl': 'jax'}`) and are wrapped with Playground's `wrap_for_brax_training`
(Brax's VmapWrapper + EpisodeWrapper(episode_length, action_repeat) + auto-reset to the cached first
state; `state.info['truncation']` is 1 on the step an episode is cut by the time limit). Nothing in
the wrapper stack uses pmap-era JAX APIs, so it works under jax >= 0.10.

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
    valid_tasks,
    validate_task,
)
from sf2_common.errors import ConfigError

__all__ = [
    "PAPER_TASKS", "PAPER_BUDGETS", "PAPER_ACTION_REPEAT", "valid_tasks", "validate_task",
    "paper_budget", "paper_action_repeat", "EnvSpec", "make_envs",
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
def make_envs(task: str, episode_length: int, action_repeat: int) -> EnvSpec:
    """Load `task` with the MJX backend and wrap it for training (auto-reset, truncation flag) and for
    evaluation (same wrapper; the evaluator runs exactly one episode per env and ignores resets)."""
    validate_task(task)
    from mujoco_playground import registry, wrapper

    env = registry.load(task, config_overrides={"impl": "jax"})
    obs_size = env.observation_size
    if not isinstance(obs_size, int):
        raise ConfigError(f"task {task!r} has structured observations {obs_size}; only flat state "
                          f"observations are supported")
    train_env = wrapper.wrap_for_brax_training(env, episode_length=episode_length,
                                               action_repeat=action_repeat)
    eval_env = wrapper.wrap_for_brax_training(env, episode_length=episode_length,
                                              action_repeat=action_repeat)
    return EnvSpec(task=task, train_env=train_env, eval_env=eval_env, obs_size=int(obs_size),
                   action_size=int(env.action_size), episode_length=episode_length,
                   action_repeat=action_repeat)
