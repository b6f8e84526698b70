"""`learner_precision` in the torch trainer: bf16 autocast of the learner's forwards only, fp32 state, and
the physics (MJX, a JAX program) traced at fp32 `highest` with a step whose output types equal its input's.
"""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import pytest
import torch
from sf2_torch.agents import trainer
from sf2_torch.agents.envs import env_spec


def test_physics_is_traced_at_highest_and_keeps_its_types(tiny_cfg):
    """Every dot_general of the env step is HIGHEST although JAX's own default is left as it is (TF32 on a
    GPU), and a step returns the types it was given (no second compilation: docs/physics.md)."""
    cfg = tiny_cfg.replace(task="PendulumSwingup")   # its MJX step returns a weakly typed reward
    spec = env_spec(cfg.task, cfg.episode_length, cfg.action_repeat)
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    state = jax.eval_shape(spec.reset, keys)
    action = jax.ShapeDtypeStruct((2, spec.action_size), jnp.float32)
    dots = re.findall(r"stablehlo\.dot_general.*", spec.step.lower(state, action).as_text())
    assert dots and all("precision = [HIGHEST, HIGHEST]" in d for d in dots), dots[:3]
    after = jax.eval_shape(spec.step, state, action)
    types = [(jax.typeof(x).dtype, jax.typeof(x).weak_type) for x in jax.tree_util.tree_leaves(state)]
    assert [(jax.typeof(x).dtype, jax.typeof(x).weak_type) for x in jax.tree_util.tree_leaves(after)] == types


@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_bfloat16_autocasts_the_forwards_and_keeps_fp32_state(tiny_cfg, algo):
    cfg = tiny_cfg.replace(learner_precision="bfloat16", algo=algo)
    program = trainer.Program(cfg)
    agent = program.make_agent(0)
    algo = agent.algo
    seen = []
    hook = algo.nets.psi.register_forward_hook(lambda m, i, o: seen.append(o.dtype))
    B, D, A = cfg.batch_size, program.spec.obs_size, program.spec.action_size
    g = torch.Generator().manual_seed(0)
    from sf2_torch.losses import Batch

    batch = Batch(obs=torch.randn(B, D, generator=g), action=torch.rand(B, A, generator=g) * 2 - 1,
                  reward=torch.rand(B, generator=g), discount=torch.ones(B),
                  next_obs=torch.randn(B, D, generator=g),
                  truncation=torch.zeros(B))
    before = {n: p.detach().clone() for n, p in algo.nets.psi.named_parameters()}
    with program.learner_precision():
        metrics = algo.sgd_step(batch, algo.step_noise(g, batch), step=0)
    hook.remove()
    assert seen and set(seen) == {torch.bfloat16}, seen           # ψ's matmuls ran in bf16
    for group in algo.trained_groups():                            # parameters and Adam states stay fp32
        for p in algo._params((group,)):
            assert p.dtype == torch.float32
            assert all(v.dtype == torch.float32 for k, v in algo.optimizers[group].state[p].items()
                       if k != "step"), group
    assert any(not torch.equal(before[n], p) for n, p in algo.nets.psi.named_parameters())
    assert all(torch.isfinite(v).all() for v in metrics.values())
    assert all(v.dtype == torch.float32 for k, v in metrics.items()), metrics   # reductions in fp32
