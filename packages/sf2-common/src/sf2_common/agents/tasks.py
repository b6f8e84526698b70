"""The task table: which tasks exist, of which kind (MuJoCo Playground DM Control; MinAtar, docs/minatar.md)
and what the trainers need to know of each (observation and action kinds, the trainer that takes it, the
episode limit, the paper's per-task settings: Appendix E Table 1; docs/core-contract.md "Agents"). Building
the environments is each core's own `agents.envs` (JAX: Brax wrappers; torch: a TorchRL env over the same
JAX env) and `sf2_jax.agents.minatar`.

Data-driven: `KINDS` describes each kind, `TASKS` lists the tasks known without an import (MinAtar's);
every other valid name is Playground's, imported lazily (for the task list and the budgets of tasks
outside the paper). Neither Playground nor pgx is imported to validate a MinAtar task.
"""

from __future__ import annotations

import difflib
import functools
import importlib.util
from dataclasses import dataclass

from sf2_common.errors import ConfigError

__all__ = [
    "PAPER_TASKS", "PAPER_BUDGETS", "PAPER_ACTION_REPEAT", "valid_tasks", "validate_task",
    "paper_budget", "paper_action_repeat", "TaskKind", "Task", "KINDS", "TASKS", "MINATAR_TASKS",
    "playground_tasks", "task_kind", "check_algo", "check_installed",
]


@dataclass(frozen=True)
class TaskKind:
    """One family of tasks and what a trainer needs to know of it.

    Attributes:
      name: the kind's key in `KINDS`.
      label: its name in messages and in `tasks` listings.
      observation: "vector" (flat state) or "image" (an H×W×C grid).
      action: "continuous" (a box) or "discrete" (an action index).
      trainer: the trainer family that takes it, "off-policy" or "on-policy".
      algos: the `--algo` values of that trainer; any other known algo is refused (`check_algo`).
      episode_length: the episode limit in agent steps; reaching it is a truncation, not a termination.
      requires: the module its environments import, checked by `check_installed`; None where the task
        list itself imports it.
      install: the command that installs what it needs.
      budget: env steps of the `paper` preset for every task of the kind; None: per task (`paper_budget`).
    """

    name: str
    label: str
    observation: str
    action: str
    trainer: str
    algos: tuple[str, ...]
    episode_length: int
    requires: str | None
    install: str
    budget: int | None = None


@dataclass(frozen=True)
class Task:
    """A task known without importing its environment package: its kind and sizes.

    Attributes:
      kind: a key of `KINDS`.
      obs_shape: the observation's shape.
      num_actions: the number of discrete actions (0 for continuous actions).
    """

    kind: str
    obs_shape: tuple[int, ...]
    num_actions: int


# `ppo` is the on-policy trainer's algo; ALGOS (sf2_common.agents.configs) holds the algos that exist.
KINDS = {
    "playground": TaskKind(
        "playground", "Playground DM Control", observation="vector", action="continuous",
        trainer="off-policy", algos=("td3", "sac"), episode_length=1000, requires=None,
        install='pip install "packages/sf2-core-jax[train]"'),
    "minatar": TaskKind(
        "minatar", "MinAtar", observation="image", action="discrete", trainer="on-policy", algos=("ppo",),
        episode_length=10_000, requires="pgx", install='pip install "packages/sf2-core-jax[minatar]"',
        budget=20_000_000),
}
# pgx's MinAtar games with its defaults (minimal action sets, sticky actions 0.1): bool 10×10×C grids
MINATAR_TASKS = {
    "minatar-asterix": Task("minatar", (10, 10, 4), 5),
    "minatar-breakout": Task("minatar", (10, 10, 4), 3),
    "minatar-freeway": Task("minatar", (10, 10, 7), 3),
    "minatar-seaquest": Task("minatar", (10, 10, 10), 6),
    "minatar-space_invaders": Task("minatar", (10, 10, 6), 4),
}
# The tasks known without an import; every other valid task is Playground's (`valid_tasks`).
TASKS = {**MINATAR_TASKS}

# The seven tasks of the paper's DM Control experiments (§4.2, Appendix E Table 1).
PAPER_TASKS = (
    "AcrobotSwingup", "CartpoleBalanceSparse", "CartpoleSwingupSparse", "CheetahRun", "FishSwim",
    "HopperHop", "PendulumSwingup",
)
# Table 1 "Number of Timesteps" (env steps, counted after action repeat as Brax does).
PAPER_BUDGETS = {
    "CartpoleBalanceSparse": 5_000_000, "CartpoleSwingupSparse": 5_000_000, "FishSwim": 5_000_000,
    "AcrobotSwingup": 10_000_000, "HopperHop": 10_000_000, "CheetahRun": 10_000_000,
    "PendulumSwingup": 10_000_000,
}
# Table 1 "Action Repeat: 1 (4 for PendulumSwingUp)". The authors' runs took action repeat from
# Playground's SAC config, which spells the task "PendulumSwingUp", so their PendulumSwingup runs used
# action repeat 1 and 5M steps; the `paper` preset follows the table (docs/core-contract.md, "The
# authors' code").
PAPER_ACTION_REPEAT = {"PendulumSwingup": 4}


@functools.lru_cache(maxsize=1)
def playground_tasks() -> tuple[str, ...]:
    """Names of Playground's DM Control suite tasks (state observations), e.g. 'CartpoleBalance'."""
    from mujoco_playground import registry

    return tuple(registry.dm_control_suite.ALL_ENVS)


def valid_tasks() -> tuple[str, ...]:
    """Every valid task name: Playground's DM Control suite (imported), then `TASKS` (MinAtar's)."""
    return playground_tasks() + tuple(TASKS)


def validate_task(task: str) -> str:
    """Return `task` if it is valid, else raise `ConfigError` listing the valid names by kind.

    Args:
      task: a task name; one of `TASKS` is valid without importing Playground.

    Returns:
      `task`.

    Raises:
      ConfigError: an unknown name.
    """
    if task in TASKS:
        return task
    tasks = tuple(dict.fromkeys(valid_tasks() + tuple(TASKS)))
    if task in tasks:
        return task
    close = difflib.get_close_matches(str(task), tasks, n=3)
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    by_kind = {k.label: [t for t in tasks if task_kind(t) is k] for k in KINDS.values()}
    listing = "; ".join(f"{label}: {', '.join(names)}" for label, names in by_kind.items() if names)
    raise ConfigError(f"unknown task {task!r}.{hint} Valid tasks ({listing})")


def task_kind(task: str) -> TaskKind:
    """The `TaskKind` of a valid task name: its `TASKS` row's, else Playground's."""
    return KINDS[TASKS[task].kind] if task in TASKS else KINDS["playground"]


def check_algo(task: str, algo: str) -> None:
    """Refuse a task that `algo`'s trainer does not take, before anything is compiled.

    The hook between tasks and trainers: every trainer's config validation calls it. An algo that no
    kind lists is left to the trainer's own check of its algos.

    Args:
      task: a valid task name.
      algo: the `--algo` value.

    Raises:
      ConfigError: the algo trains another kind of task; the message names the algos that take `task`.
    """
    kind = task_kind(task)
    takers = [k for k in KINDS.values() if algo in k.algos]
    if algo in kind.algos or not takers:
        return
    names = " or ".join(f"--algo {a}" for a in kind.algos)
    other = ", ".join(f"{k.label} tasks' {k.trainer} trainer" for k in takers)
    raise ConfigError(f"task {task!r} is a {kind.label} task: {kind.label} tasks take the {kind.trainer} "
                      f"trainer ({names}); --algo {algo} is the {other}")


def check_installed(task: str) -> None:
    """Refuse a task whose environment package is not installed (found without importing it).

    Args:
      task: a valid task name.

    Raises:
      ConfigError: its kind's `requires` module is missing; the message says how to install it.
    """
    kind = task_kind(task)
    if kind.requires is None:
        return
    try:
        found = importlib.util.find_spec(kind.requires) is not None
    except (ImportError, ValueError):   # a module set to None in sys.modules, or one without a spec
        found = False
    if not found:
        raise ConfigError(f"task {task!r} is a {kind.label} task and needs {kind.requires!r}, which is not "
                          f"installed: {kind.install}")


def paper_budget(task: str) -> int:
    """Env steps for `task`: Table 1 for the paper's tasks; its kind's `budget` where it has one (MinAtar:
    docs/minatar.md); for the other Playground tasks, Playground's own SAC budget
    (`dm_control_suite_params.brax_sac_config`), which is what the authors' sweep script would use."""
    if task in PAPER_BUDGETS:
        return PAPER_BUDGETS[task]
    if task_kind(task).budget is not None:
        return task_kind(task).budget
    from mujoco_playground.config import dm_control_suite_params

    return int(dm_control_suite_params.brax_sac_config(task).num_timesteps)


def paper_action_repeat(task: str) -> int:
    return PAPER_ACTION_REPEAT.get(task, 1)
