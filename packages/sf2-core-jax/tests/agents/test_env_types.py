"""The trainer's envs keep their state's types: `reset` and `step` return every leaf strongly typed with
the dtypes `step` was given, so the epoch program (a `lax.scan` whose carry comes back strongly typed)
compiles once, not once for the reset state and again for its own output (sf2_jax.agents.envs.StrongTypes,
docs/physics.md). Task: CartpoleSwingupSparse, whose raw Playground env changes a leaf's weak type at each
step (CheetahRun's does at reset: the same wrapper, but four times the tracing time). Shapes only
(`jax.eval_shape`): nothing is compiled."""

import jax
import jax.numpy as jnp
from sf2_jax.agents.envs import env_spec


def _types(state):
    return {jax.tree_util.keystr(k): (v.shape, v.dtype, v.weak_type)
            for k, v in jax.tree_util.tree_flatten_with_path(state)[0]}


def test_reset_and_step_keep_strong_types():
    spec = env_spec("CartpoleSwingupSparse", 1000, 1)
    raw = spec.train_env.env
    keys = jax.ShapeDtypeStruct((3, 2), jnp.uint32)
    action = jax.ShapeDtypeStruct((3, spec.action_size), jnp.float32)
    raw_reset = _types(jax.eval_shape(raw.reset, keys))
    raw_step = _types(jax.eval_shape(raw.step, jax.eval_shape(raw.reset, keys), action))
    assert raw_reset != raw_step, "the raw env no longer changes a leaf's type: pick a task that does"
    reset = jax.eval_shape(spec.train_env.reset, keys)
    stepped = jax.eval_shape(spec.train_env.step, reset, action)
    assert _types(stepped) == _types(reset)
    assert not any(weak for _, _, weak in _types(reset).values())
    assert type(spec.eval_env) is type(spec.train_env)
