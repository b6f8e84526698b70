"""Unit tests of sf2_torch: small sizes, one thread, float64 where numbers are compared. The helpers
(networks, batches, a numpy model of the contract) are the module `torch_reference` beside this file."""

from __future__ import annotations

import pytest
import torch
from torch_reference import make_batch, make_nets

torch.set_num_threads(1)


@pytest.fixture
def td3_nets():
    return make_nets("td3")


@pytest.fixture
def sac_nets():
    return make_nets("sac")


@pytest.fixture
def batch_noise():
    return make_batch()
