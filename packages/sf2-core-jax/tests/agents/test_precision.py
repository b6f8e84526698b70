"""`learner_precision`: the learner's matmuls at the chosen precision, the physics always at fp32 `highest`.

The trainer traces every program under `highest` and the learner's code (SGD steps, acting) under
`configs.LEARNER_PRECISIONS[cfg.learner_precision]`. The test reads the precision of every dot_general in
the lowered epoch program: the dots of the env step (counted by lowering the env step alone) stay
HIGHEST, every other dot takes the learner's precision (bfloat16 here; tensorfloat32 goes through the same
context). The on-policy trainer (FPO on a Playground task) is held to the same. Lowering only traces
(nothing is compiled).
"""

from __future__ import annotations

import collections
import re

import jax
import jax.numpy as jnp
import pytest

pytest.importorskip("mujoco_playground", reason="the trainer needs the [train] extra (playground)")

from sf2_jax.agents.trainer import get_program  # noqa: E402

DOT = re.compile(r"stablehlo\.dot_general.*")


def _precisions(text: str) -> collections.Counter:
    """{"highest" | "tf32" | "bf16" | other: number of dot_generals} of StableHLO `text`."""
    out = collections.Counter()
    for line in DOT.findall(text):
        if "lhs_precision_type = bf16" in line:
            out["bf16"] += 1
        elif "precision = [HIGHEST, HIGHEST]" in line:
            out["highest"] += 1
        elif "precision = [HIGH, HIGH]" in line:
            out["tf32"] += 1
        else:
            out[line[:80]] += 1
    return out


def _epoch_dots(cfg) -> collections.Counter:
    program = get_program(cfg)
    state = program.abstract_state((0,))
    with program._physics_precision():
        return _precisions(program._program("epoch", 1).lower(state, jnp.int32(0)).as_text())


def test_learner_precision_leaves_the_physics_at_highest(tiny_cfg):
    program = get_program(tiny_cfg)
    state = program.abstract_state((0,))
    env_state = jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype), state.env_state)
    action = jax.ShapeDtypeStruct((tiny_cfg.num_envs, program.spec.action_size), jnp.float32)
    with jax.default_matmul_precision("highest"):
        physics = sum(_precisions(jax.jit(program.spec.train_env.step).lower(env_state, action).as_text())
                      .values())
    assert physics > 0, "the env step has no dot_general: the test could not tell physics from learner"

    full = _epoch_dots(tiny_cfg)
    assert tiny_cfg.learner_precision == "highest"
    assert set(full) == {"highest"}, full
    total = full["highest"]
    assert total > physics

    assert _epoch_dots(tiny_cfg.replace(learner_precision="bfloat16")) == {"highest": physics,
                                                                          "bf16": total - physics}


def test_onpolicy_learner_precision_leaves_the_physics_at_highest():
    """The on-policy trainer (FPO on a Playground task) as the off-policy one: the env step's dots stay
    HIGHEST under a learner precision of bfloat16, every other dot (acting, values, SGD) takes it."""
    from sf2_jax.agents import make_config, onpolicy

    cfg = make_config("quick", "CartpoleBalance", algo="fpo", representation="none",
                      overrides={"critic": "v", "num_envs": 4, "rollout_length": 2, "minibatch_size": 8,
                                 "update_epochs": 1, "fpo_flow_steps": 2, "fpo_samples": 2})
    program = onpolicy.get_program(cfg)
    state = program.abstract_state((0,))
    env_state = jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype), state.env_state)
    action = jax.ShapeDtypeStruct((cfg.num_envs, program.env.spec.action_size), jnp.float32)
    key = jax.ShapeDtypeStruct((2,), jnp.uint32)
    with jax.default_matmul_precision("highest"):
        physics = sum(_precisions(jax.jit(program.env.step).lower(env_state, action, key).as_text())
                      .values())
    assert physics > 0, "the env step has no dot_general: the test could not tell physics from learner"

    def dots(c):
        p = onpolicy.get_program(c)
        with p.precision():
            return _precisions(p._program("epoch", 1).lower(p.abstract_state((0,))).as_text())

    full = dots(cfg)
    assert set(full) == {"highest"}, full
    low = dots(cfg.replace(learner_precision="bfloat16"))
    # the rollout steps the env `rollout_length` times in a scan (one traced body), evaluation is apart
    assert low["highest"] == physics and low["bf16"] == full["highest"] - physics, (physics, full, low)
