"""sf2_baselines.jax: networks, pure losses, canonical parameters and the agents' plug-ins."""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")
pytest.importorskip("sf2_jax")

import functools  # noqa: E402

import jax.numpy as jnp  # noqa: E402
import optax  # noqa: E402
from baselines_helpers import A, B, D, laplacian_reference, numpy_batch, numpy_noise, small_kwargs  # noqa: E402
from sf2_baselines.jax import params as bparams  # noqa: E402
from sf2_baselines.jax import sim, simlap, spr  # noqa: E402
from sf2_common.errors import ConfigError, ParamsError, ShapeError  # noqa: E402
from sf2_jax import SF2Config, losses  # noqa: E402
from sf2_jax.losses import Batch  # noqa: E402


def _batch(seed=0, truncation=True, batch_size=B):
    return Batch(**{k: jnp.asarray(v) for k, v in numpy_batch(seed, batch_size, truncation).items()})


def _noise(seed=0, batch_size=B):
    return {k: jnp.asarray(v) for k, v in numpy_noise(seed, batch_size).items()}


def _setup(module, algo="td3", seed=0, **kw):
    nets = module.make_networks(SF2Config(**small_kwargs(**kw)), algo)
    params = module.init_params(nets, jax.random.key(seed))
    # non-trivial normalizer and targets that differ from the online networks
    params["obs_norm"] = {**params["obs_norm"], "mean": jnp.full((D,), 0.3), "std": jnp.full((D,), 1.7)}
    for g in [g for g in params if g.startswith("target_")]:
        params[g] = jax.tree_util.tree_map(lambda x: x * 0.9 + 0.01, params[g])
    return nets, params


def _nonzero_groups(fn, params):
    """Groups of `params` that receive a nonzero gradient from fn(params)[0]."""
    grads = jax.grad(lambda p: fn(p)[0])(params)
    return {
        g for g, v in grads.items() if any(np.any(np.asarray(x) != 0) for x in jax.tree_util.tree_leaves(v))
    }


# ------------------------------------------------------------------------------------------- Sim
def test_sim_groups_and_shapes():
    nets, params = _setup(sim)
    assert set(params) == {"obs_norm", "policy", "target_policy", *sim.GROUPS}
    shapes = bparams.expected_shapes(nets)
    F, H = 16, 24
    assert shapes["task.w"] == (F,)
    assert shapes["phi.dense_0.kernel"] == (D + A + F, 32)
    assert shapes["q.head_0.dense_1.kernel"] == (H, F)
    b, n = _batch(), _noise()
    assert sim.features(nets, params, b.obs, b.action).shape == (B, F)
    assert sim.successor_features(nets, params, sim.features(nets, params, b.obs, b.action)).shape == (
        B,
        2,
        F,
    )
    assert sim.critic(nets, params, b.obs, b.action, target=True).shape == (B, 2)
    assert np.isfinite(float(sim.reward_loss(nets, params, b, n["next_action"])[0]))


def test_sim_feature_size_512():
    """README.md "Sim": the authors' Sim stores the task vector with a shape that breaks F = 512."""
    nets, params = _setup(sim, feature_size=512, q_hidden_size=16)
    assert params["task"]["w"].shape == (512,)
    b, n = _batch(), _noise()
    assert sim.critic(nets, params, b.obs, b.action).shape == (B, 2)
    critic = functools.partial(sim.critic, nets)
    for fn in (
        lambda p: sim.reward_loss(nets, p, b, n["next_action"]),
        lambda p: simlap.simlap_loss(nets, p, b, n["next_action"]),
        lambda p: losses.td3_critic_loss(nets.core, p, b, n["smoothing"], critic=critic),
    ):
        assert np.isfinite(float(fn(params)[0]))


def test_sim_critic_is_task_times_successor_features():
    nets, params = _setup(sim)
    b = _batch()
    phi = sim.features(nets, params, b.obs, b.action)
    psi = np.asarray(sim.successor_features(nets, params, phi))
    w = np.asarray(params["task"]["w"])
    np.testing.assert_allclose(np.asarray(sim.critic(nets, params, b.obs, b.action)), psi @ w, rtol=1e-12)


def test_sim_features_see_the_normalized_task_without_gradient():
    nets, params = _setup(sim)
    b = _batch()
    # scaling w leaves φ unchanged (ŵ = w/‖w‖) ...
    scaled = {**params, "task": {"w": params["task"]["w"] * 3.0}}
    np.testing.assert_allclose(
        np.asarray(sim.features(nets, scaled, b.obs, b.action)),
        np.asarray(sim.features(nets, params, b.obs, b.action)),
        rtol=1e-6,
        atol=1e-9,
    )
    # ... and no gradient reaches w through φ's input
    g = jax.grad(lambda p: jnp.sum(sim.features(nets, p, b.obs, b.action) ** 2))(params)
    assert not np.any(np.asarray(g["task"]["w"]))


@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_each_loss_trains_exactly_its_groups(algo):
    """The baselines' own losses stop the gradient of every group they do not train (their TD3/SAC losses
    are the core's, differentiated by the agents over the representation's critic groups)."""
    nets, params = _setup(sim, algo)
    b, n = _batch(), _noise()
    cases = [
        (lambda p: sim.reward_loss(nets, p, b, n["next_action"]), {"task"}),
        (lambda p: simlap.laplacian_loss(nets, p, b, n["next_action"]), {"phi"}),
        (lambda p: simlap.simlap_loss(nets, p, b, n["next_action"]), {"phi", "task"}),
    ]
    for fn, groups in cases:
        assert _nonzero_groups(fn, params) == groups
    snets, sparams = _setup(spr, algo)
    spr_loss = lambda p: spr.spr_loss(snets, p, b, n["next_action"], n["obs_noise"], n["next_obs_noise"])  # noqa: E731
    assert _nonzero_groups(spr_loss, sparams) == {"encoder", "projection", "prediction"}


def test_reward_loss_formula():
    nets, params = _setup(sim)
    b, n = _batch(), _noise()
    phi = np.asarray(sim.features(nets, params, b.next_obs, n["next_action"]))
    pred = phi @ np.asarray(params["task"]["w"])
    want = np.mean((1 - np.asarray(b.truncation)) * (pred - np.asarray(b.reward)) ** 2)
    np.testing.assert_allclose(float(sim.reward_loss(nets, params, b, n["next_action"])[0]), want, rtol=1e-12)


# ------------------------------------------------------------------------------------------- SimLap
def test_laplacian_loss_matches_reference():
    nets, params = _setup(simlap)
    b, n = _batch(), _noise()
    phi = sim.features(nets, params, b.obs, b.action)
    phi_next = sim.features(nets, params, b.next_obs, n["next_action"])
    loss, aux = simlap.laplacian_loss(nets, params, b, n["next_action"])
    want = laplacian_reference(phi, phi_next, 1 - np.asarray(b.truncation))
    np.testing.assert_allclose(float(loss), want, rtol=1e-10)
    np.testing.assert_allclose(
        float(loss), float(aux["lap_term"] + aux["orth_diag"] + aux["orth_offdiag"]), rtol=1e-12
    )


def test_laplacian_needs_two_samples():
    nets, params = _setup(simlap)
    b, n = _batch(batch_size=1), _noise(batch_size=1)
    with pytest.raises(ShapeError, match="B >= 2"):
        simlap.laplacian_loss(nets, params, b, n["next_action"])


# ------------------------------------------------------------------------------------------- SPR
def test_spr_loss_is_two_minus_two_cosine():
    nets, params = _setup(spr)
    b, n = _batch(truncation=False), _noise()
    loss, aux = spr.spr_loss(nets, params, b, n["next_action"], n["obs_noise"], n["next_obs_noise"])
    np.testing.assert_allclose(float(loss), 2 - 2 * float(aux["spr_cosine"]), rtol=1e-6)
    z = spr.features(nets, params, b.obs, b.action, obs_noise=n["obs_noise"])
    p = np.asarray(spr.predict(nets, params, spr.project(nets, params, z)))
    zt = spr.features(nets, params, b.next_obs, n["next_action"], target=True, obs_noise=n["next_obs_noise"])
    t = np.asarray(spr.project(nets, params, zt, target=True))
    cos = np.sum(p * t, -1) / (np.linalg.norm(p, axis=-1) * np.linalg.norm(t, axis=-1))
    np.testing.assert_allclose(float(aux["spr_cosine"]), cos.mean(), rtol=1e-6)


def test_spr_augmentation():
    nets, params = _setup(spr)
    b, n = _batch(), _noise()
    clean = np.asarray(spr.features(nets, params, b.obs, b.action))
    aug = np.asarray(spr.features(nets, params, b.obs, b.action, obs_noise=n["obs_noise"]))
    assert not np.allclose(clean, aug)
    # the noise is added in normalized space with std σ = 0.05
    x = (np.asarray(b.obs) - 0.3) / 1.7 + 0.05 * np.asarray(n["obs_noise"])
    np.testing.assert_allclose(
        np.asarray(spr.augment(nets, (b.obs - 0.3) / 1.7, n["obs_noise"])), x, rtol=1e-12
    )
    off = spr.make_networks(nets.cfg, "td3", augmentation_std=0.0)
    np.testing.assert_allclose(
        np.asarray(spr.features(off, params, b.obs, b.action, obs_noise=n["obs_noise"])), clean, rtol=1e-12
    )
    with pytest.raises(ConfigError, match="augmentation_std"):
        spr.make_networks(nets.cfg, "td3", augmentation_std=-1.0)


# ------------------------------------------------------------------------------------------- checks, params
def test_shape_errors_name_the_sizes():
    nets, params = _setup(sim)
    b, n = _batch(), _noise()
    with pytest.raises(ShapeError, match="obs_size"):
        sim.critic(nets, params, jnp.zeros((B, D + 1)), b.action)
    with pytest.raises(ShapeError, match="next_action"):
        sim.reward_loss(nets, params, b, jnp.zeros((B, A + 1)))
    snets, sparams = _setup(spr)
    with pytest.raises(ShapeError, match="obs_noise"):
        spr.spr_loss(snets, sparams, b, n["next_action"], jnp.zeros((B, D - 1)), n["next_obs_noise"])
    with pytest.raises(ConfigError, match="algo"):
        sim.make_networks(nets.cfg, "ppo")
    stacked = Batch(*(jnp.stack([v, v]) for v in b))
    with pytest.raises(ShapeError, match="a 2-D batch"):
        sim.reward_loss(nets, params, stacked, jnp.stack([n["next_action"]] * 2))


@pytest.mark.parametrize("module", [sim, spr])
@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_canonical_roundtrip(tmp_path, module, algo):
    nets, params = _setup(module, algo)
    flat = bparams.to_canonical(params)
    assert set(flat) == set(bparams.expected_shapes(nets))
    path = bparams.save(tmp_path / "p.npz", flat)
    back = bparams.from_canonical(bparams.load(path), nets)
    b = _batch()
    np.testing.assert_array_equal(
        np.asarray(module.critic(nets, back, b.obs, b.action)),
        np.asarray(module.critic(nets, params, b.obs, b.action)),
    )
    bad = dict(flat)
    del bad[next(iter(sorted(bad)))]
    bad["extra.kernel"] = np.zeros(3)
    key = "task.w" if module is sim else "projection.dense_0.kernel"
    bad[key] = np.zeros((7,))
    with pytest.raises(ParamsError) as err:
        bparams.from_canonical(bad, nets)
    msg = str(err.value)
    assert "missing" in msg and "extra.kernel" in msg and key in msg and "(7,)" in msg


# ------------------------------------------------------------------------------------------- learning
def _descend(loss_fn, params, groups, steps=150, lr=1e-2):
    opt = optax.adam(lr)
    state = opt.init({g: params[g] for g in groups})

    @jax.jit
    def step(params, state):
        (loss, _), g = jax.value_and_grad(lambda t: loss_fn({**params, **t}), has_aux=True)(
            {k: params[k] for k in groups}
        )
        updates, state = opt.update(g, state)
        return {**params, **optax.apply_updates({k: params[k] for k in groups}, updates)}, state, loss

    losses = []
    for _ in range(steps):
        params, state, loss = step(params, state)
        losses.append(float(loss))
    return losses


def test_losses_can_be_minimized():
    """Each representation loss, minimized alone on a fixed batch, goes down; the reward regression, linear
    in w, reaches its least-squares optimum."""
    b, n = _batch(truncation=False, batch_size=32), _noise(batch_size=32)
    nets, params = _setup(sim)
    rew = _descend(lambda p: sim.reward_loss(nets, p, b, n["next_action"]), params, ("task",), steps=600)
    phi = np.asarray(sim.features(nets, params, b.next_obs, n["next_action"]))
    w_opt = np.linalg.lstsq(phi, np.asarray(b.reward), rcond=None)[0]
    optimum = np.mean((phi @ w_opt - np.asarray(b.reward)) ** 2)
    assert rew[-1] < optimum + 0.02 * (rew[0] - optimum)
    lap = _descend(lambda p: simlap.laplacian_loss(nets, p, b, n["next_action"]), params, ("phi",))
    assert lap[-1] < lap[0] - 0.5
    snets, sparams = _setup(spr)
    sl = _descend(
        lambda p: spr.spr_loss(snets, p, b, n["next_action"], n["obs_noise"], n["next_obs_noise"]),
        sparams,
        ("encoder", "projection", "prediction"),
    )
    assert sl[-1] < 0.2 * sl[0]
