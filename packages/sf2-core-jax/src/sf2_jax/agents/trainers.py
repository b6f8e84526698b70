"""The JAX trainers by what they train: `trainer_module(task, algo)` names the module of a run (the CLI's
`train` and `eval`, the bench), apart from `configs`, which the trainers themselves import."""

from __future__ import annotations

from sf2_common.agents.configs import ONPOLICY_ALGOS
from sf2_common.agents.tasks import TASKS, task_kind

__all__ = ["trainer_module"]


def trainer_module(task, algo):
    """The JAX trainer that trains `algo` on `task`.

    Args:
      task: a task name (anything else, e.g. a corrupt run folder's, is the off-policy trainer's).
      algo: the algorithm.

    Returns:
      The module `sf2_jax.agents.crl` (`--algo crl`), `.onpolicy` (`--algo ppo` or `fpo`, or a task of the
      on-policy kind: MinAtar's), else the off-policy `.trainer`; each has `get_program`, `train` and
      `evaluate_checkpoint`.
    """
    if algo == "crl":
        from . import crl

        return crl
    if algo in ONPOLICY_ALGOS or (isinstance(task, str) and task in TASKS
                                  and task_kind(task).trainer == "on-policy"):
        from . import onpolicy

        return onpolicy
    from . import trainer

    return trainer
