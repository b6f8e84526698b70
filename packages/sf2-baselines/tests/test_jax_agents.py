"""The baselines plugged into sf2_jax's agents: registration, groups, critics, and SGD steps that train
the right groups on their schedules."""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")
reps = pytest.importorskip("sf2_jax.agents.representations")

import jax.numpy as jnp  # noqa: E402
import sf2_baselines.jax as bj  # noqa: E402
from baselines_helpers import numpy_batch, small_kwargs  # noqa: E402
from sf2_jax import SF2Config  # noqa: E402
from sf2_jax.agents.algorithms import make_algorithm  # noqa: E402
from sf2_jax.losses import Batch  # noqa: E402

MODULES = {"sim": bj.sim, "simlap": bj.simlap, "simlap_authors": bj.simlap, "spr": bj.spr}
CRITIC_GROUPS = {
    "sim": ("q", "phi"),
    "simlap": ("q",),
    "simlap_authors": ("q", "phi"),
    "spr": ("q", "encoder"),
}
AUX = {
    "sim": ("task",),
    "simlap": ("phi", "task"),
    "simlap_authors": ("phi", "task"),
    "spr": ("encoder", "projection", "prediction"),
}


def _batch(seed=0):
    return Batch(**{k: jnp.asarray(v) for k, v in numpy_batch(seed).items()})


def _setup(algo, name):
    cfg = SF2Config(**small_kwargs())
    agent = make_algorithm(algo, cfg, reps.get(name), dtype=jnp.float64)
    params, opt = agent.init(jax.random.PRNGKey(0))
    return cfg, agent, params, opt


def test_registered():
    assert bj.REGISTERED == ("sim", "simlap", "simlap_authors", "spr")
    for name in bj.REGISTERED:
        assert name in reps.names()
        assert reps.get(name).supported_algos == ("td3", "sac")


@pytest.mark.parametrize("algo", ["td3", "sac"])
@pytest.mark.parametrize("name", list(MODULES))
def test_agent_groups_and_critic(algo, name):
    """The representation owns the baseline's groups, trains the documented ones, and its critic is the
    baseline's (the one the base algorithm hands to the core's TD3/SAC losses)."""
    _, agent, params, _ = _setup(algo, name)
    module = MODULES[name]
    core = {"obs_norm", "policy", "target_policy" if algo == "td3" else "log_alpha"}
    assert set(params) == {*core, *module.GROUPS}
    assert ("q", *agent.rep.critic_groups) == CRITIC_GROUPS[name]
    assert agent.rep.aux_groups == AUX[name]
    assert set(agent.trained_groups()) == {*CRITIC_GROUPS[name], *AUX[name], *agent.policy_groups}
    assert {t: o for t, (o, _) in agent.rep.targets().items()} == {
        f"target_{g}": g for g in module.GROUPS if f"target_{g}" in module.GROUPS and g != "q"}
    b = _batch()
    for target in (False, True):
        np.testing.assert_array_equal(
            agent.rep.critic(params, b.obs, b.action, target),
            module.critic(agent.rep.baseline_nets, params, b.obs, b.action, target))


@pytest.mark.parametrize("algo", ["td3", "sac"])
@pytest.mark.parametrize("name", list(MODULES))
def test_sgd_steps_train_the_right_groups(algo, name):
    cfg, agent, params, opt = _setup(algo, name)
    step = jax.jit(agent.sgd_step)
    p, o = params, opt
    for i in range(3):
        b = _batch(i)
        p, o, metrics = step(p, o, b, agent.step_noise(jax.random.PRNGKey(10 + i), b), jnp.asarray(i))
    assert all(np.isfinite(float(v)) for v in metrics.values())
    assert agent.rep.aux_loss_name in metrics

    def changed(g):
        return any(
            not np.array_equal(np.asarray(x), np.asarray(y))
            for x, y in zip(jax.tree_util.tree_leaves(p[g]), jax.tree_util.tree_leaves(params[g]))
        )

    for g in (*CRITIC_GROUPS[name], *AUX[name], "policy"):
        assert changed(g), f"{name}/{algo}: {g} was not trained"
    for g in [g for g in params if g.startswith("target_")]:
        assert changed(g), f"{name}/{algo}: {g} was not averaged"


@pytest.mark.parametrize("algo,every", [("td3", 10), ("sac", 16)])
@pytest.mark.parametrize("name", ["sim", "simlap"])
def test_task_vector_schedule(algo, every, name):
    """w and its Adam state (moments and count) change only on gradient steps that are multiples of
    `aux_every['task']` (the authors' cond and separate w optimizer); every other trained group steps
    every time. Steps 0 .. every + 1 (jitted, the step a traced int32 as in the trainer's scan)."""
    _, agent, params, opt = _setup(algo, name)
    assert agent.rep.aux_every == {"task": every}
    step = jax.jit(agent.sgd_step)
    p, o = params, opt
    due_so_far = 0
    for i in range(every + 2):
        b = _batch(i)
        noise = agent.step_noise(jax.random.PRNGKey(10 + i), b)
        new_p, new_o, _ = step(p, o, b, noise, jnp.asarray(i, jnp.int32))
        due = i % every == 0
        due_so_far += due
        w_moved = not np.array_equal(np.asarray(new_p["task"]["w"]), np.asarray(p["task"]["w"]))
        assert w_moved == due, f"step {i}: w moved={w_moved}, due={due}"
        for old, new in zip(jax.tree_util.tree_leaves(o["task"]), jax.tree_util.tree_leaves(new_o["task"])):
            assert np.array_equal(np.asarray(old), np.asarray(new)) == (not due), f"step {i}: Adam state"
        assert int(new_o["task"][0].count) == due_so_far
        assert int(new_o["q"][0].count) == i + 1
        for g in {*agent.rep.aux_groups, *agent.rep.critic_groups} - {"task"}:
            assert int(new_o[g][0].count) > int(o[g][0].count), f"step {i}: {g} did not step"
        p, o = new_p, new_o


@pytest.mark.parametrize("sigma", [0.0, 0.05])
def test_spr_augmentation_std_reaches_the_augmentation(sigma):
    """The config field `spr_augmentation_std` (TrainConfig → SF2Config → the SPR representation) is σ of
    the augmentation s̃ = s̄ + σξ (paper App. B.1, Fig. 5): at σ = 0 every draw of ξ gives the clean view
    and the same SPR loss; at σ = 0.05 (the default, the paper's choice) two draws differ."""
    from baselines_helpers import A, D
    from sf2_common.agents.configs import TrainConfig

    assert TrainConfig().spr_augmentation_std == bj.spr.AUGMENTATION_STD == 0.05
    small = {k: v for k, v in small_kwargs().items() if k not in ("obs_size", "action_size")}
    cfg = TrainConfig(representation="spr", spr_augmentation_std=sigma, **small).sf2_config(D, A)
    agent = make_algorithm("td3", cfg, reps.get("spr"), dtype=jnp.float64)
    params, _ = agent.init(jax.random.PRNGKey(0))
    nets = agent.rep.baseline_nets
    assert nets.augmentation_std == sigma
    b = _batch()
    clean = np.asarray(bj.spr.features(nets, params, b.obs, b.action))
    draws = [agent.rep.aux_noise(jax.random.PRNGKey(k), b) for k in (1, 2)]
    views = [np.asarray(bj.spr.features(nets, params, b.obs, b.action, obs_noise=n["spr_obs_noise"]))
             for n in draws]
    spr_losses = [float(agent.rep.aux_loss(params, b, b.action, n)[0]) for n in draws]
    if sigma == 0.0:
        np.testing.assert_array_equal(views[0], clean)
        np.testing.assert_array_equal(views[1], clean)
        assert spr_losses[0] == spr_losses[1]
    else:
        assert not np.allclose(views[0], views[1]) and spr_losses[0] != spr_losses[1]


def test_aux_steps_per_sgd_step_repeats_a_loss_without_noise():
    """`aux_steps_per_sgd_step` = 3 with TD3+SimLap, whose loss draws no noise (no "<key>:more" entries):
    from fresh states, step index 1 gives φ (an aux group only, due every step) three Adam steps and w (due
    every 10th step) none, its parameters unchanged."""
    cfg = SF2Config(**small_kwargs(), aux_steps_per_sgd_step=3)
    agent = make_algorithm("td3", cfg, reps.get("simlap"), dtype=jnp.float64)
    params, opt = agent.init(jax.random.PRNGKey(0))
    b = _batch()
    noise = agent.step_noise(jax.random.PRNGKey(1), b)
    assert agent.aux_noise_keys() == () and list(noise) == ["smoothing_noise"]
    p, o, _ = jax.jit(agent.sgd_step)(params, opt, b, noise, jnp.asarray(1))
    assert int(o["phi"][0].count) == 3 and int(o["task"][0].count) == 0
    assert all(np.array_equal(x, y) for x, y in zip(jax.tree_util.tree_leaves(p["task"]),
                                                    jax.tree_util.tree_leaves(params["task"])))
