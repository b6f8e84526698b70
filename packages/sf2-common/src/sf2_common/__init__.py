"""sf2_common: the framework-free code that `sf2_jax` and `sf2_torch` share (SF², ICLR 2026): `config`
(`SF2Config`), `errors`, `agents` (configs and presets, tasks, run folders and their lock, the host loop,
evaluation, plots) and `cli` (the pieces each core's command line is built from). Only numpy is imported
eagerly."""

__version__ = "0.2.0"

__all__ = ["__version__"]
