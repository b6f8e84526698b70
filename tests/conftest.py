"""Cross-framework fixtures: one canonical parameter file, loaded into both cores.

float64 runs with `jax_enable_x64`; float32 runs cast the same canonical arrays down. Every comparison is
recorded by term, and the largest relative difference per (dtype, term) is printed at the end of the run
(the figures quoted in docs/parity.md come from that table).
"""

from __future__ import annotations

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_default_matmul_precision", "highest")

import torch  # noqa: E402

torch.backends.cuda.matmul.allow_tf32 = False
torch.set_num_threads(1)

import pytest  # noqa: E402
from cross_bridge import RECORD  # noqa: E402


def pytest_sessionfinish(session):
    """Under pytest-xdist (`-n 2` in tox), each worker hands its records to the controller."""
    if hasattr(session.config, "workeroutput"):
        session.config.workeroutput["parity_record"] = [[*key, *value] for key, value in RECORD.items()]


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    """The controller merges a worker's records: the largest difference and the count of checks."""
    for dtype, term, worst, tol, n in getattr(node, "workeroutput", {}).get("parity_record", []):
        old_worst, _, old_n = RECORD.get((dtype, term), (0.0, tol, 0))
        RECORD[(dtype, term)] = [max(old_worst, worst), tol, old_n + n]


def pytest_terminal_summary(terminalreporter):
    if not RECORD:
        return
    tr = terminalreporter
    tr.section("largest JAX-vs-torch relative difference per term")
    tr.write_line(f"{'dtype':8} {'term':34} {'max rel diff':>14} {'tolerance':>10} {'checks':>7}")
    for (dtype, term), (worst, tol, n) in sorted(RECORD.items()):
        tr.write_line(f"{dtype:8} {term:34} {worst:14.3e} {tol:10.0e} {n:7d}")
