"""The task table: which MuJoCo Playground DM Control tasks exist and the paper's per-task settings
(Appendix E Table 1; docs/core-contract.md "Agents"): budgets and action repeat. Building the
environments is each core's own `agents.envs` (JAX: Brax wrappers; torch: a TorchRL env over the same
JAX env), which re-exports these.

Playground is imported lazily (for the task list and the budgets of tasks outside the paper).
"""

from __future__ import annotations

import difflib
import functools

from sf2_common.errors import ConfigError

__all__ = [
    "PAPER_TASKS", "PAPER_BUDGETS", "PAPER_ACTION_REPEAT", "valid_tasks", "validate_task",
    "paper_budget", "paper_action_repeat",
]

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
def valid_tasks() -> tuple[str, ...]:
    """Names of Playground's DM Control suite tasks (state observations), e.g. 'CartpoleBalance'."""
    from mujoco_playground import registry

    return tuple(registry.dm_control_suite.ALL_ENVS)


def validate_task(task: str) -> str:
    """Return `task` if Playground knows it, else raise `ConfigError` listing the valid names."""
    tasks = valid_tasks()
    if task in tasks:
        return task
    close = difflib.get_close_matches(str(task), tasks, n=3)
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    raise ConfigError(f"unknown task {task!r}.{hint} Valid tasks (MuJoCo Playground DM Control suite): "
                      f"{', '.join(tasks)}")


def paper_budget(task: str) -> int:
    """Env steps for `task`: Table 1 for the paper's tasks; for the others, Playground's own SAC budget
    (`dm_control_suite_params.brax_sac_config`), which is what the authors' sweep script would use."""
    if task in PAPER_BUDGETS:
        return PAPER_BUDGETS[task]
    from mujoco_playground.config import dm_control_suite_params

    return int(dm_control_suite_params.brax_sac_config(task).num_timesteps)


def paper_action_repeat(task: str) -> int:
    return PAPER_ACTION_REPEAT.get(task, 1)
