"""sf2_common: the framework-free code that `sf2_jax` and `sf2_torch` share (SF², ICLR 2026).

Modules: `errors` and `config` (`SF2Config`; both cores name them too), `agents.configs` (`TrainConfig`,
the `paper`/`quick` presets, CLI overrides, validation), `agents.tasks` (the DM Control task table of
Table 1), `agents.registry` (pluggable representations, found by entry points), `agents.runfolder`,
`agents.plotting`, `agents.hostloop` (the framework-free parts of the training loop) and `cli` (the
pieces each core's command line is built from). Only numpy is imported eagerly.
"""

__version__ = "0.2.0"

__all__ = ["__version__"]
