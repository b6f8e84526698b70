"""Unit tests of sf2_torch: small sizes, one thread, float64 where numbers are compared."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

torch.set_num_threads(1)
sys.path.insert(0, str(Path(__file__).parent))

from _torch_reference import make_batch, make_nets  # noqa: E402


@pytest.fixture
def td3_nets():
    return make_nets("td3")


@pytest.fixture
def sac_nets():
    return make_nets("sac")


@pytest.fixture
def batch_noise():
    return make_batch()
