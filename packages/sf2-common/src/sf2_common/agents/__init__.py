"""The framework-free parts of the SF² agents, shared by `sf2_jax.agents` and `sf2_torch.agents`: configs
and presets, the task table, the representation registry, run folders, the lock, where a run resumes,
checkpoint checks, the host loop, evaluation, plots. `EXPORTS` and `lazy_getattr` give both cores' `agents`
packages the same lazily imported top-level names."""

from __future__ import annotations

import importlib

__all__ = ["EXPORTS", "lazy_getattr"]

# name → module that defines it: a module of the core's agents package (the same module names in both
# cores), or a dotted module path (a name a core takes from sf2_common: "sf2_common.agents.configs")
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
