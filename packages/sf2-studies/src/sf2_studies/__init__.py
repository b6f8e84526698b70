"""sf2_studies: the paper's evaluation protocol (§4.2, Appendix C) over tasks × methods × seeds, for either
framework. One module per job:

- `spec`: study files (TOML), checked before anything is compiled
- `folder`: the study folder (its study file, state, one run folder per training program)
- `runner`, `progress`: the runs on this host (a core CLI child per GPU or CPU worker), their progress line
- `rayrun`: the runs as Ray tasks on a cluster (extra `ray`)
- `stats`: AUC, normalization, rliable aggregates and bootstrap intervals
- `report`, `figures`: results.csv, summary.md and the paper's figures
- `compare`: several studies' aggregates and claim verdicts side by side (`study compare`)
- `export`: every run of a study folder as one long table, CSV or Parquet (`study export`)
- `merge`: runs of other study folders or their archives joined into one (`study merge`)
- `commands`: the `study` subcommand of `sf2-jax` / `sf2-torch` (entry point group `sf2.commands`)

Study files of the paper's experiments live in the repository's `studies/` folder.
"""

__version__ = "0.2.0"
