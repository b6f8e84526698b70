"""sf2_common: the framework-free code both cores' trainers need (SF², ICLR 2026): `config`, `errors`,
`agents` (configs, tasks, run folders, the host loop, evaluation, plots) and `cli`'s pieces."""

__version__ = "0.2.0"

__all__ = ["__version__"]
