"""`shared_torso` (docs/minatar.md, the sanity gate): pgx's MinAtar PPO network, one torso under the policy
and value heads, trained by one joint step. The joint step against pgx's loss written out by hand from one
forward pass of the network, and against optax's Adam on the hand-clipped total gradient; the parameter
tree shares its torso; every other combination is refused. No training: one tiny SGD step on a CPU."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from sf2_common.errors import ConfigError

pytest.importorskip("pgx", reason="the [minatar] extra: pip install \"packages/sf2-core-jax[minatar]\"")

from sf2_jax.agents import make_config, onpolicy  # noqa: E402
from sf2_jax.agents import representations_onpolicy as ro  # noqa: E402
from sf2_jax.agents.configs import validate  # noqa: E402

TASK = "minatar-breakout"
B = 16


def _cfg(**overrides):
    return make_config("quick", TASK, algo="ppo", representation="none", overrides=dict(
        critic="v", shared_torso=True, num_envs=4, rollout_length=8, minibatch_size=B, **overrides))


@pytest.fixture(scope="module")
def program():
    """The program of a tiny config whose gradient clip is small enough to act (`test_joint_step_...`)."""
    return onpolicy.Program(_cfg(max_grad_norm=0.05))


@pytest.fixture(scope="module")
def batch(program):
    """A minibatch of B random grids and actions; log π_old and V_old the current network's moved by noise of
    std 0.3 (so both the ratio clip and the value clip act on some samples); A and G standard normal."""
    k_obs, k_act, k_params, k_lp, k_v, k_adv, k_tgt = jax.random.split(jax.random.PRNGKey(7), 7)
    rep = program.rep
    obs = jax.random.bernoulli(k_obs, 0.2, (B, *rep.nets.obs_shape)).astype(jnp.float32)
    action = jax.random.randint(k_act, (B,), 0, rep.cfg.action_size)
    params = rep.init(k_params)
    logits, value = rep.net.apply({"params": params["actor"]}, obs)
    log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[:, None], axis=1)[:, 0]
    zero = jnp.zeros((B,), jnp.float32)
    mb = ro.OnPolicyBatch(
        obs=obs, action=action, reward=zero, discount=zero + 1, truncation=zero, next_obs=obs,
        next_action=action,
        policy_info=log_prob + 0.3 * jax.random.normal(k_lp, (B,)),
        value=value[:, 0] + 0.3 * jax.random.normal(k_v, (B,)),
        advantage=jax.random.normal(k_adv, (B,)), target=jax.random.normal(k_tgt, (B,)))
    return params, mb


def _pgx_loss(program, net_params, mb):
    """pgx's example's loss written out from ONE forward pass: L_π + c·L_V − e·H (its `_loss_fn`)."""
    cfg, eps = program.cfg, program.cfg.clip_eps
    logits, value = program.rep.net.apply({"params": net_params}, mb.obs)
    value = value[:, 0]
    v_clipped = mb.value + jnp.clip(value - mb.value, -eps, eps)
    value_loss = 0.5 * jnp.mean(jnp.maximum((value - mb.target) ** 2, (v_clipped - mb.target) ** 2))
    log_p = jax.nn.log_softmax(logits)
    ratio = jnp.exp(jnp.take_along_axis(log_p, mb.action[:, None], axis=1)[:, 0] - mb.policy_info)
    adv = (mb.advantage - mb.advantage.mean()) / (mb.advantage.std() + 1e-8)
    policy_loss = -jnp.mean(jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - eps, 1 + eps) * adv))
    entropy = jnp.mean(-jnp.sum(jnp.exp(log_p) * log_p, axis=-1))
    return policy_loss + cfg.value_coef * value_loss - cfg.entropy_coef * entropy, (ratio, value, v_clipped)


def _f64(tree):
    return jax.tree_util.tree_map(lambda x: x.astype(jnp.float64) if jnp.issubdtype(x.dtype, jnp.floating)
                                  else x, tree)


def test_joint_step_is_pgx_loss_and_one_adam_step_on_the_clipped_total_gradient(program, batch):
    """The joint step's `total_loss` is pgx's loss of the same outputs, and its parameters and its one Adam
    state are optax's Adam (lr, ε of the config) applied to the total gradient clipped by hand to global norm
    `max_grad_norm`: g·c/max(‖g‖, c). In float64 (parameters and batch cast), equal to 1e-10."""
    with jax.enable_x64(True):
        _joint_step_against_pgx(program, *_f64(batch))


def _joint_step_against_pgx(program, params, mb):
    cfg = program.cfg
    opt_state = {g: program._adam.init(params[g]) for g in program.trained}
    assert program.trained == ("actor",) and set(opt_state) == {"actor"}   # one group, one Adam state
    new_params, new_state, metrics = program._sgd_step(params, opt_state, mb, jax.random.PRNGKey(0))

    (loss, (ratio, value, v_clipped)), grads = jax.value_and_grad(
        lambda p: _pgx_loss(program, p, mb), has_aux=True)(params["actor"])
    # the batch exercises both clips
    assert np.any(np.abs(np.asarray(ratio) - 1) > cfg.clip_eps) and np.any(np.asarray(v_clipped != value))
    assert metrics["total_loss"].dtype == jnp.float64
    np.testing.assert_allclose(metrics["total_loss"], loss, rtol=1e-10)
    np.testing.assert_allclose(metrics["actor_loss"] + cfg.value_coef * metrics["critic_loss"], loss,
                               rtol=1e-10)
    norm = jnp.sqrt(sum(jnp.sum(g ** 2) for g in jax.tree_util.tree_leaves(grads)))
    assert norm > cfg.max_grad_norm   # the clip acts
    clipped = jax.tree_util.tree_map(lambda g: g * cfg.max_grad_norm / norm, grads)
    adam = optax.adam(cfg.learning_rate, eps=cfg.adam_eps)
    updates, expected_state = adam.update(clipped, adam.init(params["actor"]), params["actor"])
    expected = optax.apply_updates(params["actor"], updates)
    assert set(new_params) == {"actor"} and set(new_state) == {"actor"}
    for got, want in ((new_params["actor"], expected), (new_state["actor"], expected_state)):
        assert jax.tree_util.tree_structure(got) == jax.tree_util.tree_structure(want)
        for x, y in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(want)):
            np.testing.assert_allclose(x, y, rtol=1e-10, atol=1e-15)


def test_joint_loss_runs_the_torso_once_and_equals_the_heads_applied_apart(program, batch):
    """`SharedTorso.one_pass` (the joint step's fast path) gives the joint loss and gradient of the plain
    formulation, the actor and V critic each applying the network (float64, 1e-10), and its compiled
    gradient holds two convolutions, the torso's forward and its kernel's gradient (the grids take none),
    where the plain one holds one kernel gradient per head."""
    cfg, rep = program.cfg, program.rep

    def joint(p, mb, fast):
        nets = (rep.one_pass(p, mb.obs),) if fast else ()
        critic, _ = rep.critic_loss(p, mb, cfg.clip_eps, *nets)
        actor, _ = program.policy.loss(p, mb, cfg, *nets)
        return actor + cfg.value_coef * critic

    with jax.enable_x64(True):
        params, mb = _f64(batch)
        plain, fast = (jax.value_and_grad(lambda p, f=f: joint(p, mb, f))(params) for f in (False, True))
        for x, y in zip(jax.tree_util.tree_leaves(fast), jax.tree_util.tree_leaves(plain)):
            np.testing.assert_allclose(x, y, rtol=1e-10, atol=1e-15)
    params, mb = batch
    convolutions = {f: jax.jit(jax.grad(lambda p, f=f: joint(p, mb, f))).lower(params).compile().as_text()
                    .count(" convolution(") for f in (False, True)}
    assert convolutions[True] == 2 and convolutions[False] > convolutions[True], convolutions


def _perturbed(params, part):
    """`params` with every weight of `part` of the network ("torso", "policy" or "value") plus 0.1."""
    net = dict(params["actor"])
    net[part] = jax.tree_util.tree_map(lambda w: w + 0.1, net[part])
    return {"actor": net}


def test_one_torso_under_both_heads(program, batch):
    """The parameters are one network in the group "actor" (torso, policy head, value head): moving the
    torso's weights alone moves both the logits and V(s); a head's weights move only its own output; the
    critic's loss alone has a gradient on the torso (through the view `SharedTorso` gives the V critic)."""
    params, mb = batch
    rep = program.rep
    assert set(params) == {"actor"} and set(params["actor"]) == {"torso", "policy", "value"}

    def outputs(p):
        return np.asarray(rep.logits(p, mb.obs)), np.asarray(rep.values(p, mb.obs, None))

    logits, value = outputs(params)
    for part, moves_logits, moves_value in (("torso", True, True), ("policy", True, False),
                                            ("value", False, True)):
        new_logits, new_value = outputs(_perturbed(params, part))
        assert np.any(new_logits != logits) == moves_logits, part
        assert np.any(new_value != value) == moves_value, part
    grads = jax.grad(lambda p: rep.critic_loss(p, mb, program.cfg.clip_eps)[0])(params)
    assert all(np.any(np.asarray(g) != 0) for g in jax.tree_util.tree_leaves(grads["actor"]["torso"]))
    assert all(np.all(np.asarray(g) == 0) for g in jax.tree_util.tree_leaves(grads["actor"]["policy"]))


@pytest.mark.parametrize("overrides,found", [
    (dict(critic="q"), "critic 'q', representation 'none'"),
    (dict(representation="sf2", critic="q"), "critic 'q', representation 'sf2'"),
    (dict(representation="sf2-ae", critic="v"), "critic 'v', representation 'sf2-ae'"),
])
def test_shared_torso_refused_outside_ppo_with_v_and_no_representation(overrides, found):
    """`validate` refuses `shared_torso` with critic q or an SF² representation, naming what it found and
    the valid combination; `build` refuses it too (a program built without validation); the CLI's string
    "true" parses to True; a non-bool is refused."""
    rep = overrides.pop("representation", "none")
    cfg = make_config("quick", TASK, algo="ppo", representation=rep,
                      overrides=dict(shared_torso="true", **overrides))
    assert cfg.shared_torso is True
    with pytest.raises(ConfigError, match="shared_torso = True is invalid: pgx's shared torso exists for "
                       "algo 'ppo' with critic 'v' and representation 'none' only, found algo 'ppo', "
                       f"{found}"):
        validate(cfg)
    sf2 = cfg.sf2_config(400, 3)
    with pytest.raises(ConfigError, match="representation 'none' with critic 'v' over images only"):
        ro.build(rep, sf2, (10, 10, 4), cfg.critic, shared_torso=True)
    with pytest.raises(ConfigError, match="shared_torso = 'yes' is invalid: must be a bool"):
        validate(_cfg().replace(shared_torso="yes"))
    assert validate(_cfg()).shared_torso is True and make_config("quick", TASK, algo="ppo",
                                                                 representation="none").shared_torso is False
