from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from sf2_torch import ConfigError, ShapeError, networks, params
from torch import nn
from torch_reference import A, B, D, make_batch, make_cfg, np_embedding, np_mlp, np_psi, np_q, np_zeta


def test_shapes_td3(td3_nets):
    cfg = td3_nets.cfg
    batch, noise = make_batch()
    f = networks.psi(td3_nets, batch.obs, batch.action)
    assert f.shape == (B, cfg.feature_size)
    assert networks.psi(td3_nets, batch.obs, batch.action, target=True).shape == (B, cfg.feature_size)
    assert networks.zeta(td3_nets, noise["eps"], noise["flow_time"]).shape == (B, D, cfg.feature_size)
    assert networks.zeta_hidden(td3_nets, noise["eps"], noise["flow_time"]).shape == (B, 32)
    assert networks.velocity(td3_nets, noise["eps"], noise["flow_time"], f).shape == (B, D)
    m, c = networks.contract(td3_nets, f, target=True)
    assert m.shape == (B, D, 32) and c.shape == (B, D)
    assert networks.q_values(td3_nets, f).shape == (B, 2)
    a = networks.td3_action(td3_nets, batch.obs, target=True)
    assert a.shape == (B, A) and a.abs().max() <= 1
    assert networks.flow_time_embedding(noise["flow_time"], 8).shape == (B, 8)


def test_shapes_sac(sac_nets):
    batch, noise = make_batch()
    a, logp = networks.sac_sample(sac_nets, batch.obs, noise["noise"])
    assert a.shape == (B, A) and logp.shape == (B,)
    assert networks.sac_mode(sac_nets, batch.obs).shape == (B, A)
    assert sac_nets.log_alpha.shape == () and not hasattr(sac_nets, "target_policy")
    with pytest.raises(ConfigError, match="algo='td3'"):
        networks.td3_action(sac_nets, batch.obs)


def test_structure_names_and_init():
    torch.manual_seed(0)
    nets = networks.make_networks(make_cfg(), "td3")
    names = dict(nets.psi.named_children())
    assert list(names) == ["dense_0", "layer_norm_0", "dense_1", "layer_norm_1", "dense_2"]
    assert all(isinstance(m, nn.LayerNorm) and m.eps == 1e-6 for n, m in names.items() if "norm" in n)
    assert list(dict(nets.q.head_0.named_children())) == ["dense_0", "dense_1"]
    for name, mod in nets.named_modules():
        if isinstance(mod, nn.Linear):
            bound = math.sqrt(3.0 / mod.in_features)
            assert mod.weight.abs().max() <= bound and torch.all(mod.bias == 0), name
            assert mod.weight.std() > 0.3 * bound, name
    for name, target in nets.target_modules().items():
        online = getattr(nets, name.removeprefix("target_"))
        for p, q in zip(target.parameters(), online.parameters()):
            assert not p.requires_grad and torch.equal(p, q) and p.data_ptr() != q.data_ptr()
    assert torch.equal(nets.obs_norm.std, torch.ones(D)) and nets.obs_norm.count == 0
    with pytest.raises(ConfigError, match="'td3', 'sac'"):
        networks.make_networks(make_cfg(), "ppo")


def test_numpy_reference_forward(td3_nets):
    """ψ, ζ (with its d·F + f reshape) and Q match a numpy re-implementation from canonical params."""
    cfg, flat = td3_nets.cfg, params.to_canonical(td3_nets)
    batch, noise = make_batch()
    obs, act, eps, k = (
        batch.obs.numpy(),
        batch.action.numpy(),
        noise["eps"].numpy(),
        noise["flow_time"].numpy(),
    )
    f = networks.psi(td3_nets, batch.obs, batch.action)
    np.testing.assert_allclose(f.detach().numpy(), np_psi(flat, cfg, obs, act), rtol=1e-12, atol=1e-12)
    z = networks.zeta(td3_nets, noise["eps"], noise["flow_time"]).detach().numpy()
    # The reference forms the phase 10⁴·k·ω_i directly, rounded to ~1e4·2⁻⁵³ ≈ 1e-12 rad; the core reduces
    # it exactly (flow_time_embedding), so ζ agrees to a few 1e-12, not to the last bits.
    np.testing.assert_allclose(z, np_zeta(flat, cfg, eps, k), rtol=1e-12, atol=1e-11)
    np.testing.assert_allclose(
        networks.q_values(td3_nets, f).detach().numpy(),
        np_q(flat, f.detach().numpy()),
        rtol=1e-12,
        atol=1e-12,
    )
    pol = np.tanh(np_mlp(flat, "policy", (obs - flat["obs_norm.mean"]) / flat["obs_norm.std"], 2))
    np.testing.assert_allclose(networks.td3_action(td3_nets, batch.obs).detach().numpy(), pol, rtol=1e-12)


def test_twin_q_one_product_equals_two_heads(td3_nets):
    """TwinQ's one product (both hidden layers as one GEMM, both output layers as one row sum) against the
    plain `cat([head_0(f), head_1(f)])`: values and the gradients of every head parameter and of the
    features, float64."""
    f = torch.randn(B, td3_nets.cfg.feature_size, dtype=torch.float64, requires_grad=True)
    weight = torch.randn(B, 2, dtype=torch.float64)
    q = td3_nets.q
    fast = q(f)
    plain = torch.cat([q.head_0(f), q.head_1(f)], dim=-1)
    torch.testing.assert_close(fast, plain, rtol=1e-12, atol=1e-12)
    inputs = [f, *q.parameters()]
    g_fast = torch.autograd.grad((fast * weight).sum(), inputs)
    g_plain = torch.autograd.grad((plain * weight).sum(), inputs)
    for name, a, b in zip(["features", *dict(q.named_parameters())], g_fast, g_plain):
        assert a.shape == b.shape, name
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12, msg=name)
    with pytest.raises(ShapeError, match="feature_size"):
        q(f[:, :-1])


@pytest.mark.parametrize("layer_norm", [True, False])
def test_twin_heads_one_program_equals_two_mlps(layer_norm):
    """`twin_heads` (the vanilla critic's VanillaQ: two 3-hidden-layer MLPs on one input) against the plain
    `cat([head_0(x), head_1(x)])`: values and the gradients of the input and of every parameter, float64,
    with LayerNorm (its own weight and bias per head, set away from 1 and 0 so a swap would show) and
    without, for an input with two leading dimensions."""
    torch.manual_seed(0)
    kw = dict(dtype=torch.float64)
    heads = [networks.MLP(D + A, (16, 12, 12), 1, layer_norm, **kw) for _ in range(2)]
    with torch.no_grad():
        for p in (p for h in heads for p in h.parameters()):
            p.add_(0.1 * torch.randn_like(p))
    x = torch.randn(3, B, D + A, dtype=torch.float64, requires_grad=True)
    fast = networks.twin_heads(*heads, x)
    plain = torch.cat([heads[0](x), heads[1](x)], dim=-1)
    assert fast.shape == (3, B, 2)
    torch.testing.assert_close(fast, plain, rtol=1e-12, atol=1e-12)
    weight = torch.randn(3, B, 2, dtype=torch.float64)
    inputs = [x, *heads[0].parameters(), *heads[1].parameters()]
    g_fast = torch.autograd.grad((fast * weight).sum(), inputs)
    g_plain = torch.autograd.grad((plain * weight).sum(), inputs)
    for a, b in zip(g_fast, g_plain):
        assert a.shape == b.shape
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)


def test_flow_time_embedding_formula():
    k = torch.tensor([0.0, 0.25, 0.7, 1.0], dtype=torch.float64)
    out = networks.flow_time_embedding(k, 6).numpy()
    # np_embedding forms the float64 phase 10⁴·k·ω_i directly (rounding up to ~1e4·2⁻⁵³ ≈ 1e-12 rad).
    np.testing.assert_allclose(out, np_embedding(k.numpy(), 6), rtol=0, atol=5e-12)
    assert out[0].tolist() == [0.0, 1.0] * 3
    with pytest.raises(ConfigError):
        networks.flow_time_embedding(k, 5)


def test_flow_time_embedding_float32_phase_is_reduced_exactly():
    """float32 embedding vs the float64 formula at float32 flow times in [0, 1]: the exact phase reduction
    leaves ~1e-7 turn of phase error (2π·1e-7 ≈ 6e-7 rad) plus sin/cos rounding; forming 10⁴·k·ω_i
    directly in float32 would be off by up to half an ulp of 10⁴ (4.9e-4 rad)."""
    k = torch.from_numpy(np.random.default_rng(0).uniform(size=4096).astype(np.float32))
    out = networks.flow_time_embedding(k, 64)
    assert out.dtype == torch.float32
    ref = np_embedding(k.double().numpy(), 64)
    assert np.max(np.abs(out.double().numpy() - ref)) < 2e-6


def test_contracted_velocity_equals_plain(td3_nets):
    batch, noise = make_batch()
    f = networks.psi(td3_nets, batch.obs, batch.action)
    for target in (False, True):
        m, c = networks.contract(td3_nets, f, target=target)
        fast = networks.velocity_contracted(td3_nets, noise["eps"], noise["flow_time"], m, c, target=target)
        plain = networks.velocity(td3_nets, noise["eps"], noise["flow_time"], f, target=target)
        torch.testing.assert_close(fast, plain, rtol=1e-12, atol=1e-12)


def test_sac_log_prob_matches_change_of_variables(sac_nets):
    batch, noise = make_batch()
    a, logp = networks.sac_sample(sac_nets, batch.obs, noise["noise"])
    loc, std = sac_nets.policy(networks.normalize(batch.obs, sac_nets.obs_norm))
    u = loc + std * noise["noise"]
    ref = torch.distributions.Normal(loc, std).log_prob(u).sum(-1) - torch.log1p(-(torch.tanh(u) ** 2)).sum(
        -1
    )
    torch.testing.assert_close(logp, ref, rtol=1e-10, atol=1e-10)
    torch.testing.assert_close(a, torch.tanh(u))
    assert torch.all(std >= sac_nets.cfg.min_std)


def test_normalizer_update_matches_batch_statistics():
    cfg = make_cfg()
    norm = networks.ObsNormalizer(D, dtype=torch.float64)
    rng = np.random.default_rng(0)
    x1, x2 = rng.normal(2.0, 3.0, (7, D)), rng.normal(-1.0, 0.5, (2, 5, D))
    networks.update_normalizer(norm, torch.as_tensor(x1), cfg)
    networks.update_normalizer(norm, torch.as_tensor(x2), cfg)
    allx = np.concatenate([x1, x2.reshape(-1, D)])
    assert float(norm.count) == 17
    np.testing.assert_allclose(norm.mean.numpy(), allx.mean(0), rtol=1e-12)
    np.testing.assert_allclose(norm.summed_var.numpy(), ((allx - allx.mean(0)) ** 2).sum(0), rtol=1e-12)
    np.testing.assert_allclose(norm.std.numpy(), allx.std(0), rtol=1e-12)
    obs = torch.as_tensor(rng.normal(size=(3, D)))
    np.testing.assert_allclose(
        networks.normalize(obs, norm).numpy(), (obs.numpy() - allx.mean(0)) / allx.std(0)
    )
    # functional form on a dict leaves the input alone; std is clipped at std_min for constant data
    stats = {
        "count": torch.zeros(()),
        "mean": torch.zeros(D),
        "summed_var": torch.zeros(D),
        "std": torch.ones(D),
    }
    new = networks.update_normalizer(stats, torch.ones(4, D), cfg)
    assert float(stats["count"]) == 0 and torch.all(new["std"] == cfg.normalizer_std_min)


def test_shape_errors_name_expected_and_found(td3_nets):
    batch, noise = make_batch()
    with pytest.raises(ShapeError, match=r"obs_size = 3, found 4"):
        networks.psi(td3_nets, torch.zeros(B, 4, dtype=torch.float64), batch.action)
    with pytest.raises(ShapeError, match=r"action_size = 2, found 5"):
        networks.psi(td3_nets, batch.obs, torch.zeros(B, 5, dtype=torch.float64))
    with pytest.raises(ShapeError, match=r"obs_size = 3, found 7"):
        networks.td3_action(td3_nets, torch.zeros(B, 7, dtype=torch.float64))
    with pytest.raises(ShapeError, match=r"obs_size = 3, found 2"):
        networks.zeta(td3_nets, torch.zeros(B, 2, dtype=torch.float64), noise["flow_time"])
    with pytest.raises(ShapeError, match=r"flow_time must have shape \(6,\)"):
        networks.zeta(td3_nets, noise["eps"], torch.zeros(5, dtype=torch.float64))
    with pytest.raises(ShapeError, match=r"feature_size = 16, found 3"):
        networks.q_values(td3_nets, torch.zeros(B, 3, dtype=torch.float64))
    with pytest.raises(ShapeError, match="batch shape"):
        networks.psi(td3_nets, batch.obs, batch.action[:2])
