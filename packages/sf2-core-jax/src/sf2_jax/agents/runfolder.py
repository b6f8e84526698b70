"""A run folder: `config.json`, `metrics.jsonl` (append-safe, one row per evaluation and seed),
`checkpoints/` (Orbax), `learning_curve.png` and `final/params_seed{S}.npz`.

The class is `sf2_common.agents.runfolder.RunFolder`, the same for both cores (see that module for the
append-safe and resume semantics of metrics.jsonl).
"""

from __future__ import annotations

from sf2_common.agents.runfolder import RunFolder, RunFolderMismatch

__all__ = ["RunFolder", "RunFolderMismatch"]
