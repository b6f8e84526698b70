"""The framework-free parts of both cores' `agents` (configs, tasks, registry, run folders, lock, resume,
checkpoints, host loop, evaluation, plots); `EXPORTS` and `lazy_getattr` give both the same lazy names."""

from __future__ import annotations

import importlib

__all__ = ["EXPORTS", "lazy_getattr"]

# name → the module of the core's agents package that defines it, or a dotted path ("sf2_common.agents.x")
EXPORTS = {
    "TrainConfig": "configs", "make_config": "configs", "parse_seeds": "configs", "validate": "configs",
    "Representation": "representations", "register": "representations",
    "TrainingDiverged": "trainer", "evaluate_checkpoint": "trainer", "get_program": "trainer",
    "train": "trainer",
}


def lazy_getattr(package: str, exports: dict[str, str] = EXPORTS):
    """The module `__getattr__` of the agents package `package` (e.g. "sf2_jax.agents"): the names of
    `exports` are imported on first access, so importing a light module does not pull in the trainer."""

    def __getattr__(name):
        if name in exports:
            module = exports[name] if "." in exports[name] else f"{package}.{exports[name]}"
            return getattr(importlib.import_module(module), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
