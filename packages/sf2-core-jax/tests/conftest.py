"""Fixtures of the sf2_jax unit tests: float64 everywhere, small networks, non-trivial parameters."""

from __future__ import annotations

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import pytest  # noqa: E402
from jax_helpers import make_batch, perturbed_params, small_cfg  # noqa: E402
from sf2_jax import networks  # noqa: E402


@pytest.fixture(scope="session")
def td3():
    nets = networks.make_networks(small_cfg(), "td3")
    return nets, perturbed_params(nets, 0)


@pytest.fixture(scope="session")
def sac():
    nets = networks.make_networks(small_cfg(), "sac")
    return nets, perturbed_params(nets, 1)


@pytest.fixture(scope="session")
def data():
    return make_batch(0)
