"""Learning curves: one run folder (per-seed lines, mean and 95% CI band) and several run folders (one line
and band per method and task); the final-return table. All of it is `sf2_common.agents.plotting`, the same
for both cores; `method_label` here names methods with the torch agents' representation labels.
"""

from __future__ import annotations

from sf2_common.agents import plotting as _plotting
from sf2_common.agents.plotting import curves, final_table, mean_ci, plot_learning_curve, plot_runs

__all__ = ["method_label", "mean_ci", "curves", "plot_learning_curve", "plot_runs", "final_table"]


def method_label(algo: str, representation: str) -> str:
    """'TD3+SF²', 'SAC', ... (vanilla has no suffix), with the representation's registered label."""
    from . import representations

    return _plotting.method_label(algo, representation, representations.REGISTRY)
