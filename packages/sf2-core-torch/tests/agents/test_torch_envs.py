"""The torch trainer's env keeps the JAX state packed (sf2_torch/agents/envs.py, module docstring): stepping
it gives, bit for bit, what stepping the plain JAX state with the same jitted step gives, across episode
ends (auto-reset, truncation); `step_actions` (the trainer's loops' step) gives what TorchRL's `step` nests
under "next", key for key; its state leaves are the plain state's, copies that later steps do not
change, and restore into another env exactly; a leaf that does not fit is refused with its shapes, and so
is an action of another shape or device, the state left as it was."""

from __future__ import annotations

import re

import jax
import numpy as np
import pytest
import torch
from sf2_torch.agents import envs
from tensordict import TensorDict

TASK, EPISODE, N = "CartpoleBalance", 7, 4   # 7-step episodes: three episode ends in 20 steps


def _actions(steps):
    g = torch.Generator().manual_seed(0)
    return [torch.rand(N, 1, generator=g) * 2 - 1 for _ in range(steps)]


def _keys():
    return jax.random.split(jax.random.PRNGKey(3), N)


def _step(env, obs, action):
    return env.step(TensorDict({"observation": obs, "action": action}, batch_size=[N],
                               device=obs.device)).get("next")


def _np(t):
    return t.cpu().numpy()


_CUDA = pytest.mark.skipif(not torch.cuda.is_available(),
                           reason="needs a CUDA device for torch (and for JAX: on the GPU host run it with "
                                  "JAX_PLATFORMS=cuda,cpu)")


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=_CUDA)])
def test_the_packed_state_steps_as_the_plain_state(device, request):
    if device == "cuda":
        request.getfixturevalue("jax_on_gpu")   # skips, with its reason, where JAX has no GPU
    env = envs.make_env(TASK, EPISODE, 1, N, device)
    spec = envs.env_spec(TASK, EPISODE, 1)
    jax_device = jax.devices("gpu" if device == "cuda" else "cpu")[0]
    obs = env.reset_from_keys(_keys()).get("observation")
    state = spec.reset(jax.device_put(_keys(), jax_device))
    np.testing.assert_array_equal(_np(obs), np.asarray(state.obs, np.float32))
    ends = 0
    for action in _actions(20):
        nxt = _step(env, obs, action.to(device))
        state = spec.step(state, jax.device_put(action.numpy(), jax_device))
        obs = nxt.get("observation")
        np.testing.assert_array_equal(_np(obs), np.asarray(state.obs, np.float32))
        np.testing.assert_array_equal(_np(nxt.get("reward"))[:, 0], np.asarray(state.reward, np.float32))
        done, trunc = np.asarray(state.done) > 0.5, np.asarray(state.info["truncation"]) > 0.5
        np.testing.assert_array_equal(_np(nxt.get("done"))[:, 0], done)
        np.testing.assert_array_equal(_np(nxt.get("truncated"))[:, 0], trunc)
        np.testing.assert_array_equal(_np(nxt.get("terminated"))[:, 0], done & ~trunc)
        ends += int(trunc.any())
    assert ends == 2   # episodes ended at steps 7 and 14 (truncated: the time limit)
    leaves = env.get_state_leaves()
    plain = jax.tree_util.tree_leaves(state)
    assert len(leaves) == len(plain)
    for a, b in zip(leaves, plain):
        assert a.shape == b.shape and a.dtype == b.dtype
        np.testing.assert_array_equal(a, np.asarray(b))


def test_state_leaves_are_copies_and_restore_exactly():
    env, other = envs.make_env(TASK, EPISODE, 1, N), envs.make_env(TASK, EPISODE, 1, N)
    obs = env.reset_from_keys(_keys()).get("observation")
    other.reset_from_keys(jax.random.split(jax.random.PRNGKey(9), N))
    actions = _actions(10)
    for action in actions[:5]:
        obs = _step(env, obs, action).get("observation")
    leaves = env.get_state_leaves()
    kept = [x.copy() for x in leaves]
    other.set_state_leaves(leaves)
    obs_other = obs.clone()
    for action in actions[5:]:
        a, b = _step(env, obs, action), _step(other, obs_other, action)
        obs, obs_other = a.get("observation"), b.get("observation")
        for key in ("observation", "reward", "done", "truncated"):
            assert torch.equal(a.get(key), b.get(key)), key
    assert all(np.array_equal(x, y) for x, y in zip(leaves, kept))   # not moved by the later steps
    bad = list(leaves)
    bad[1] = np.zeros((3, *bad[1].shape), bad[1].dtype)
    with pytest.raises(ValueError, match="does not fit"):
        other.set_state_leaves(bad)
    with pytest.raises(ValueError, match=f"has {len(leaves)} arrays, got {len(leaves) - 1}"):
        other.set_state_leaves(leaves[:-1])


def test_step_actions_gives_what_torchrls_step_gives():
    env, lean = envs.make_env(TASK, EPISODE, 1, N), envs.make_env(TASK, EPISODE, 1, N)
    with pytest.raises(RuntimeError, match="reset the env once before stepping it"):
        lean.step_actions(_actions(1)[0])
    obs = env.reset_from_keys(_keys()).get("observation")
    lean.reset_from_keys(_keys())
    ends = 0
    for action in _actions(16):
        nxt, mine = _step(env, obs, action), lean.step_actions(action)
        assert set(mine.keys()) == set(nxt.keys()) == {"observation", "reward", "done", "terminated",
                                                       "truncated"}
        for key in nxt.keys():
            assert mine.get(key).dtype == nxt.get(key).dtype and torch.equal(mine.get(key), nxt.get(key)), key
        obs = nxt.get("observation")
        ends += int(mine.get("truncated").any())
    assert ends == 2   # at steps 7 and 14


def test_an_action_of_another_shape_or_device_is_refused_and_the_state_kept():
    env = envs.make_env(TASK, EPISODE, 1, N)
    env.reset_from_keys(_keys())
    before = env.get_state_leaves()
    bad = {"(4, 2)": torch.zeros(N, 2), "(4,)": torch.zeros(N), "(3, 1)": torch.zeros(N - 1, 1),
           "meta": torch.zeros(N, 1, device="meta")}
    for shown, action in bad.items():
        with pytest.raises(ValueError, match=re.escape(shown)) as err:
            env.step_actions(action)
        assert "CartpoleBalance" in str(err.value) and "= (4, 1) on cpu" in str(err.value)
    assert all(np.array_equal(x, y) for x, y in zip(env.get_state_leaves(), before))
    env.step_actions(torch.zeros(N, 1))   # a right action still steps
    assert not all(np.array_equal(x, y) for x, y in zip(env.get_state_leaves(), before))
