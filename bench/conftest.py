"""pytest configuration of the bench suite (`pytest bench/`).

The benchmarks (test_updates.py) run at the `small` size; torch-compile cases compile for minutes on a
CPU, so they run only with `--bench-compile`. `--benchmark-disable` turns every benchmark into a single
smoke run (what CI would use); `--benchmark-autosave` / `pytest-benchmark compare` track regressions.
"""

from __future__ import annotations

import os

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")


def pytest_addoption(parser):
    parser.addoption("--bench-compile", action="store_true", default=False,
                     help="also benchmark torch.compile'd updates (slow to compile)")
    parser.addoption("--bench-task", default="CheetahRun", help="task whose (D, A) the suite uses")
