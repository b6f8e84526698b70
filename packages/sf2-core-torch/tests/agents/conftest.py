"""Agent tests need the `[train]` extra (torchrl, tensordict, playground, mujoco-mjx, jax, matplotlib,
tqdm); without it they are skipped.

They run on the CPU in float32 (the trainer's dtype) with one torch thread. The Playground envs are JAX
programs: their compilation (tens of seconds per batch size on a small CPU) is cached on disk in pytest's
cache folder (JAX's persistent compilation cache) and in the process (one jitted reset/step per task),
and the training tests share a few tiny configs with equal train/eval batch sizes so that one compiled
env step serves all of them.
"""

from __future__ import annotations

import importlib.util
import os
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

_MISSING = [m for m in ("torchrl", "tensordict", "mujoco_playground", "jax", "matplotlib", "tqdm")
            if importlib.util.find_spec(m) is None]
if _MISSING:
    collect_ignore_glob = ["test_*.py"]

import pytest  # noqa: E402


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a real learning run (about a minute of training on a CPU); "
                            "deselect with -m 'not slow'")


@pytest.fixture(scope="session", autouse=True)
def _agents_setup(request):
    import torch

    torch.set_num_threads(1)
    if _MISSING:
        return
    import jax

    cache = getattr(request.config, "cache", None)
    folder = str(cache.mkdir("jax-compile-cache")) if cache is not None else tempfile.mkdtemp()
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


@pytest.fixture(scope="module", autouse=True)
def float32_jax():
    """The torch trainer's envs are JAX programs in float32. The JAX core's and the cross-framework tests'
    conftests turn x64 on for the whole session, so run in one pytest process with them (not tox's
    separate envs) the env state would be float64 here and a checkpoint written by a fresh `sf2-torch`
    child (float32) would not restore. As in the JAX core's agent tests: x64 off inside these modules."""
    if _MISSING:
        yield
        return
    import jax

    with jax.enable_x64(False):
        yield


@pytest.fixture
def jax_on_gpu():
    """Skips a test that needs JAX on the GPU when it has none: this conftest defaults JAX to the CPU, so on
    the GPU host run such a test with JAX_PLATFORMS=cuda,cpu."""
    import jax

    try:
        gpus = jax.devices("gpu")
    except RuntimeError:
        gpus = []
    if not gpus:
        pytest.skip("needs JAX on a GPU (this conftest defaults JAX to the CPU: on the GPU host run it with "
                    "JAX_PLATFORMS=cuda,cpu)")


TINY = dict(
    num_envs=4, num_eval_envs=4, episode_length=60, num_evals=4, num_timesteps=4 * 36,
    batch_size=16, grad_updates_per_step=2, min_replay_size=32, max_replay_size=512,
    feature_size=8, hidden_sizes=(16,), q_hidden_size=16, zeta_hidden_sizes=(16,), embedding_size=4,
    compile="off", device="cpu",   # CPU tests on any host; the CUDA paths: test_torch_graphs.py, @cuda
)


@pytest.fixture(scope="session")
def agent_core():
    """The torch agents, for the contract tests of `sf2_testing.contract` (test_torch_contract.py)."""
    from sf2_testing.contract import AgentCore
    from sf2_torch.agents import configs, envs, representations, trainer

    return AgentCore("torch", configs, trainer, envs, representations, own_fields=configs.TORCH_FIELDS)


@pytest.fixture(scope="session")
def tiny_cfg():
    """Seconds per run: 4 envs, 60-step episodes, 16-wide networks; 3 epochs of 12 actor steps, the
    first 8 of them the prefill; 2 SGD steps per actor step (8, 24, 24 SGD steps per epoch). The same
    schedule as sf2_jax's agent tests (which use 2 evaluation envs; 4 here share the training envs'
    compiled JAX step)."""
    from sf2_torch.agents import make_config

    return make_config("quick", "CartpoleBalance", algo="td3", representation="sf2", overrides=TINY)
