"""Unit tests of sf2_baselines: float64 in both frameworks, small networks."""

from __future__ import annotations

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

try:
    import jax

    jax.config.update("jax_enable_x64", True)
except ImportError:  # torch-only install
    pass

try:
    import torch

    torch.set_num_threads(1)
except ImportError:  # jax-only install
    pass
