import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax_helpers import A, B, D
from sf2_jax import ConfigError, ShapeError
from sf2_jax import networks as nw


def test_output_shapes(td3, sac, data):
    batch, noise = data
    for nets, params in (td3, sac):
        cfg = nets.cfg
        F, H = cfg.feature_size, cfg.zeta_hidden_sizes[-1]
        feats = nw.psi(nets, params, batch.obs, batch.action)
        assert feats.shape == (B, F)
        assert nw.psi(nets, params, batch.obs, batch.action, target=True).shape == (B, F)
        x, k = noise["eps"], noise["flow_time"]
        assert nw.zeta(nets, params, x, k).shape == (B, D, F)
        assert nw.zeta(nets, params, x, k, target=True).shape == (B, D, F)
        assert nw.zeta_hidden(nets, params, x, k).shape == (B, H)
        W, b = nw.zeta_last_layer(nets, params)
        assert W.shape == (H, F * D) and b.shape == (F * D,)
        assert nw.velocity(nets, params, x, k, feats).shape == (B, D)
        M, c = nw.contract(nets, params, feats)
        assert M.shape == (B, D, H) and c.shape == (B, D)
        assert nw.velocity_contracted(nets, params, x, k, M, c).shape == (B, D)
        assert nw.q_values(nets, params, feats).shape == (B, 2)
        assert nw.q_values(nets, params, feats, target=True).shape == (B, 2)
        assert nw.flow_time_embedding(k, cfg.embedding_size).shape == (B, cfg.embedding_size)
        assert nw.normalize(batch.obs, params["obs_norm"]).shape == (B, D)
    nets, params = td3
    a = nw.td3_action(nets, params, batch.obs)
    assert a.shape == (B, A) and np.all(np.abs(a) <= 1)
    assert nw.td3_action(nets, params, batch.obs, target=True).shape == (B, A)
    nets, params = sac
    a, logp = nw.sac_sample(nets, params, batch.obs, noise["noise"])
    assert a.shape == (B, A) and logp.shape == (B,)
    assert nw.sac_mode(nets, params, batch.obs).shape == (B, A)
    loc, std = nw.sac_distribution(nets, params, batch.obs)
    assert loc.shape == std.shape == (B, A) and np.all(std >= nets.cfg.min_std)


def test_init_params_groups_and_defaults(td3, sac):
    t = nw.init_params(td3[0], jax.random.key(0))
    s = nw.init_params(sac[0], jax.random.key(0))
    common = {"obs_norm", "psi", "zeta", "q", "policy", "target_psi", "target_zeta", "target_q"}
    assert set(t) == common | {"target_policy"} and set(s) == common | {"log_alpha"}
    assert s["log_alpha"].shape == () and float(s["log_alpha"]) == sac[0].cfg.init_log_alpha
    norm = t["obs_norm"]
    assert float(norm["count"]) == 0 and np.all(norm["mean"] == 0) and np.all(norm["summed_var"] == 0)
    assert np.all(norm["std"] == 1)
    for name in ("psi", "zeta", "q", "policy"):
        jax.tree_util.tree_map(np.testing.assert_array_equal, t[name], t[f"target_{name}"])
    k = t["psi"]["dense_0"]["kernel"]
    assert k.dtype == jnp.float64 and np.all(np.abs(k) <= math.sqrt(3 / k.shape[0]))
    assert np.all(t["psi"]["dense_0"]["bias"] == 0) and np.all(t["psi"]["layer_norm_0"]["scale"] == 1)


def test_zeta_reshape_is_row_major(td3, data):
    nets, params = td3
    x, k = data[1]["eps"], data[1]["flow_time"]
    F = nets.cfg.feature_size
    W, b = nw.zeta_last_layer(nets, params)
    raw = nw.zeta_hidden(nets, params, x, k) @ W + b
    z = nw.zeta(nets, params, x, k)
    for d in range(D):
        for f in (0, F - 1):
            np.testing.assert_allclose(z[:, d, f], raw[:, d * F + f], rtol=1e-13)


def test_layer_norm_formula(td3, data):
    """First hidden layer of ψ equals ReLU(xW + b), then (y − mean)/√(var + 1e-6)·scale + bias."""
    nets, params = td3
    batch = data[0]
    p = params["psi"]
    norm = params["obs_norm"]
    x = np.concatenate([(batch.obs - norm["mean"]) / norm["std"], batch.action], -1)
    y = np.maximum(x @ p["dense_0"]["kernel"] + p["dense_0"]["bias"], 0)
    mu = y.mean(-1, keepdims=True)
    var = ((y - mu) ** 2).mean(-1, keepdims=True)
    expected = (y - mu) / np.sqrt(var + 1e-6) * p["layer_norm_0"]["scale"] + p["layer_norm_0"]["bias"]
    one_layer = nw.MLP((nets.cfg.hidden_sizes[0],), 1)
    sub = {"dense_0": p["dense_0"], "layer_norm_0": p["layer_norm_0"]}
    got = one_layer.apply({"params": sub}, x, method=nw.MLP.hidden)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)


def test_velocity_fast_equals_plain(td3, data):
    nets, params = td3
    batch, noise = data
    feats = nw.psi(nets, params, batch.obs, batch.action)
    x, k = noise["eps"], noise["flow_time"]
    for target in (False, True):
        M, c = nw.contract(nets, params, feats, target=target)
        np.testing.assert_allclose(nw.velocity_contracted(nets, params, x, k, M, c, target=target),
                                   nw.velocity(nets, params, x, k, feats, target=target), rtol=1e-12)


def test_flow_time_embedding_formula():
    k = np.array([0.0, 0.3, 1.0])
    E = 6
    out = np.asarray(nw.flow_time_embedding(k, E))
    for i in range(E // 2):
        w = math.exp(-2 * i * math.log(1e4) / E)
        np.testing.assert_allclose(out[:, 2 * i], np.sin(1e4 * k * w), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out[:, 2 * i + 1], np.cos(1e4 * k * w), rtol=1e-12, atol=1e-12)
    with pytest.raises(ConfigError):
        nw.flow_time_embedding(k, 5)


def test_flow_time_embedding_float32_phase_is_reduced_exactly():
    """float32 embedding vs the float64 formula at float32 flow times in [0, 1]: the exact phase reduction
    leaves ~1e-7 turn of phase error (2π·1e-7 ≈ 6e-7 rad) plus sin/cos rounding; forming 10⁴·k·ω_i
    directly in float32 would be off by up to half an ulp of 10⁴ (4.9e-4 rad)."""
    E = 64
    k = np.random.default_rng(0).uniform(size=4096).astype(np.float32)
    out = np.asarray(jax.jit(lambda k: nw.flow_time_embedding(k, E))(jnp.asarray(k, jnp.float32)))
    assert out.dtype == np.float32
    ref = np.asarray(nw.flow_time_embedding(jnp.asarray(k, jnp.float64), E))
    assert np.max(np.abs(out - ref)) < 2e-6


def test_normalizer_update_matches_numpy(td3):
    cfg = td3[0].cfg
    rng = np.random.default_rng(3)
    b1, b2 = rng.normal(1.0, 3.0, (7, D)), rng.normal(-1.0, 0.5, (4, 2, D))
    stats = nw.init_normalizer(D)
    stats = nw.update_normalizer(stats, b1, cfg)
    stats = nw.update_normalizer(stats, b2, cfg)
    allobs = np.concatenate([b1, b2.reshape(-1, D)])
    assert float(stats["count"]) == 15
    np.testing.assert_allclose(stats["mean"], allobs.mean(0), rtol=1e-12)
    np.testing.assert_allclose(stats["summed_var"], ((allobs - allobs.mean(0)) ** 2).sum(0), rtol=1e-12)
    np.testing.assert_allclose(stats["std"], allobs.std(0), rtol=1e-12)
    expected = (allobs - allobs.mean(0)) / allobs.std(0)
    np.testing.assert_allclose(nw.normalize(allobs, stats), expected, rtol=1e-10)
    const = nw.update_normalizer(nw.init_normalizer(D), np.ones((3, D)), cfg)
    np.testing.assert_array_equal(const["std"], np.full(D, cfg.normalizer_std_min))


def test_sac_log_prob_is_tanh_gaussian_density(sac, data):
    """The contract's log-prob formula equals log N(u; loc, σ) − Σ log(1 − tanh(u)²)."""
    nets, params = sac
    obs, xi = data[0].obs, data[1]["noise"]
    a, logp = nw.sac_sample(nets, params, obs, xi)
    loc, std = (np.asarray(v) for v in nw.sac_distribution(nets, params, obs))
    u = loc + std * xi
    gauss = (-0.5 * ((u - loc) / std) ** 2 - np.log(std) - 0.5 * np.log(2 * np.pi)).sum(-1)
    np.testing.assert_allclose(a, np.tanh(u), rtol=1e-12)
    np.testing.assert_allclose(logp, gauss - np.log(1 - np.tanh(u) ** 2).sum(-1), rtol=1e-9)
    np.testing.assert_allclose(nw.sac_mode(nets, params, obs), np.tanh(loc), rtol=1e-12)


def test_shape_errors_name_both_sizes(td3, sac, data):
    batch, noise = data
    nets, params = td3
    with pytest.raises(ShapeError, match=r"expected last dimension 3 \(obs_size\), found 4"):
        nw.psi(nets, params, np.zeros((B, 4)), batch.action)
    with pytest.raises(ShapeError, match=r"expected last dimension 2 \(action_size\), found 1"):
        nw.psi(nets, params, batch.obs, np.zeros((B, 1)))
    with pytest.raises(ShapeError, match=r"expected last dimension 3 \(obs_size\), found 5"):
        nw.td3_action(nets, params, np.zeros((B, 5)))
    with pytest.raises(ShapeError, match=r"expected last dimension 3 \(obs_size\), found 2"):
        nw.zeta(nets, params, np.zeros((B, 2)), noise["flow_time"])
    with pytest.raises(ShapeError, match="flow_time"):
        nw.zeta(nets, params, noise["eps"], np.zeros(B + 1))
    with pytest.raises(ShapeError, match=r"expected last dimension 16 \(feature_size\), found 15"):
        nw.q_values(nets, params, np.zeros((B, 15)))
    with pytest.raises(ShapeError, match=r"expected last dimension 2 \(action_size\), found 3"):
        nw.sac_sample(sac[0], sac[1], batch.obs, np.zeros((B, 3)))
    with pytest.raises(ConfigError, match="algo='sac'"):
        nw.sac_sample(nets, params, batch.obs, noise["noise"])


def test_networks_are_jit_friendly(td3, data):
    nets, params = td3
    batch = data[0]
    f = jax.jit(nw.psi)
    np.testing.assert_allclose(f(nets, params, batch.obs, batch.action),
                               nw.psi(nets, params, batch.obs, batch.action), rtol=1e-12)
