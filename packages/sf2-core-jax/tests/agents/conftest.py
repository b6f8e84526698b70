"""Agent tests need the [train] extra (brax, playground, orbax-checkpoint); without it only the
algorithm tests run.

They run on the CPU in float32, the trainer's dtype (x64, which the unit tests turn on, is off here).
Training tests share a few tiny configs, so compiled programs are reused (`get_program` caches them).
"""

from __future__ import annotations

import importlib.util
import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

_MISSING = [m for m in ("brax", "mujoco_playground", "orbax.checkpoint", "matplotlib", "tqdm")
            if importlib.util.find_spec(m.split(".")[0]) is None]
if _MISSING:  # test_algorithms.py needs only jax, flax and optax
    collect_ignore_glob = ["test_inputs.py", "test_contract.py", "test_training.py", "test_learning.py"]

import pytest  # noqa: E402


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a real learning run (about a minute of training on a CPU); "
                            "deselect with -m 'not slow'")


@pytest.fixture(scope="session", autouse=True)
def compile_cache(request):
    """JAX's persistent compilation cache in pytest's cache folder, the one the CLI children of the tests
    get (`--compile-cache`): a child (test_faults.py's `kill -9` of `sf2-jax train`) loads the programs
    this process compiled for the same config instead of compiling them again (~1 min on 2 cores). Keys
    hold the program and the compile options; PYTHONHASHSEED=0 (tox) keeps them equal across processes."""
    import jax

    cache = getattr(request.config, "cache", None)
    if cache is not None:
        jax.config.update("jax_compilation_cache_dir", str(cache.mkdir("sf2-jax-compile-cache")))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


@pytest.fixture(scope="module", autouse=True)
def float32_jax():
    """The unit tests' conftest turns on x64 for the whole session; the trainer runs in float32."""
    import jax

    with jax.enable_x64(False):
        yield


@pytest.fixture(scope="session")
def agent_core():
    """The JAX agents, for the contract tests of `sf2_testing.contract` (test_contract.py)."""
    from sf2_jax.agents import configs, envs, representations, trainer
    from sf2_testing.contract import AgentCore

    return AgentCore("jax", configs, trainer, envs, representations)


@pytest.fixture(scope="session")
def tiny_cfg():
    """Seconds per run: 4 envs, 60-step episodes, 16-wide networks; 3 epochs of 12 actor steps, the
    first 8 of them the prefill; 2 SGD steps per actor step (8, 24, 24 SGD steps per epoch)."""
    from sf2_jax.agents import make_config

    return make_config("quick", "CartpoleBalance", algo="td3", representation="sf2", overrides=dict(
        num_timesteps=4 * 36, num_evals=4, num_envs=4, num_eval_envs=2, episode_length=60,
        batch_size=16, grad_updates_per_step=2, min_replay_size=32, max_replay_size=512,
        feature_size=8, hidden_sizes=(16,), q_hidden_size=16, zeta_hidden_sizes=(16,), embedding_size=4))


@pytest.fixture
def poison_epoch(monkeypatch):
    """`poison_epoch(cfg, epoch)`: the cached program of `cfg` trains epoch `epoch` from Q heads set to NaN
    (as if an update had diverged there), so every loss of that epoch's first SGD step is non-finite. It
    wraps the program's `epoch`, so no new program is compiled; undone after the test."""
    import jax
    import jax.numpy as jnp
    from sf2_jax.agents.trainer import get_program

    def poison(cfg, bad_epoch: int) -> None:
        program = get_program(cfg)
        real_epoch = program.epoch

        def poisoned_epoch(state, epoch):
            if epoch == bad_epoch:
                q = jax.tree_util.tree_map(lambda x: x * jnp.nan, state.params["q"])
                state = state._replace(params={**state.params, "q": q})
            return real_epoch(state, epoch)

        monkeypatch.setattr(program, "epoch", poisoned_epoch)

    return poison
