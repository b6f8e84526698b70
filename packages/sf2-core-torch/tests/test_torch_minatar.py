"""The MinAtar system's networks and losses (sf2_torch.networks_image, sf2_torch.losses_onpolicy), float64.

The JAX core's test_minatar.py, in torch: hand-derived values on tiny inputs (each derivation is in the
JAX test's docstring, repeated in short here), the fast path against the plain formulation, the flow loss
w AE as the vector `flow_loss` itself, which parameters each loss trains, and the canonical names.
"""

from __future__ import annotations

import dataclasses
import math
import types

import numpy as np
import pytest
import torch
from sf2_torch import SF2Config, losses, params
from sf2_torch import losses_onpolicy as lo
from sf2_torch import networks as nw
from sf2_torch import networks_image as nwi

SHAPE = (5, 4, 3)
CFG = SF2Config(obs_size=60, action_size=3, feature_size=6, hidden_sizes=(8, 8), q_hidden_size=8,
                zeta_hidden_sizes=(6, 5), embedding_size=4, gamma_su=0.9, denoising_steps=2)
TINY = SF2Config(obs_size=4, action_size=2, feature_size=4, hidden_sizes=(4,), q_hidden_size=4,
                 zeta_hidden_sizes=(4,), embedding_size=2)
B = 4


def t(x, dtype=torch.float64):
    return torch.as_tensor(np.array(x), dtype=dtype)


def image_nets(cfg, shape, method, seed=0, set_to=None):
    """float64 networks with every entry drawn (LayerNorm scales ≠ 1, biases ≠ 0, targets ≠ online), then
    the canonical entries of `set_to` {name: value} set to the given values."""
    nets = nwi.make_image_networks(cfg, shape, method, dtype=torch.float64)
    rng = np.random.default_rng(seed)
    flat = {}
    for name, s in params.expected_shapes(nets).items():
        if name.endswith("kernel"):
            flat[name] = rng.uniform(-1.0, 1.0, s) * math.sqrt(3.0 / np.prod(s[:-1]))
        elif name.endswith(".scale"):
            flat[name] = rng.uniform(0.5, 1.5, s)
        else:
            flat[name] = rng.normal(0.0, 0.1, s)
    for name, value in (set_to or {}).items():
        flat[name] = np.broadcast_to(np.asarray(value, np.float64), flat[name].shape)
    return params.from_canonical(flat, nets)


def grids(seed, n=B, shape=SHAPE):
    return t((np.random.default_rng(seed).uniform(size=(n, *shape)) < 0.3).astype(np.float64))


def flow_batch(seed=0, n=B):
    rng = np.random.default_rng(seed)
    batch = losses.Batch(obs=grids(seed, n), action=t(rng.integers(0, CFG.action_size, n), torch.int64),
                         reward=t(rng.normal(size=n)), discount=t(np.ones(n)), next_obs=grids(seed + 1, n),
                         truncation=t(np.eye(n)[1]))
    return batch, t(rng.integers(0, CFG.action_size, n), torch.int64), t(rng.uniform(size=n))


# ------------------------------------------------------------------------------------------ hand-derived
def test_lambda_returns_and_gae_by_hand():
    """T = 3, N = 2, γ = λ = ½; env 0 truncated after t = 1, env 1 terminal at t = 1 (derivation: the JAX
    core's test_minatar.py). G = ((3.5, 0.75), (6, 1), (6, 1)); A = ((2.5, 0.75), (2, −1), (1, −2))."""
    r = t([[1.0, 0.0], [2.0, 1.0], [3.0, -1.0]])
    d = t([[1.0, 1.0], [1.0, 0.0], [1.0, 1.0]])
    tr = t([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
    v_next = t([[4.0, 2.0], [8.0, 10.0], [6.0, 4.0]])
    v = t([[1.0, 0.0], [4.0, 2.0], [5.0, 3.0]])
    G = t([[3.5, 0.75], [6.0, 1.0], [6.0, 1.0]])
    assert torch.equal(lo.lambda_returns(r, d, tr, v_next, 0.5, 0.5), G)
    adv, targets = lo.gae(r, d, tr, v, v_next, 0.5, 0.5)
    assert torch.equal(adv, t([[2.5, 0.75], [2.0, -1.0], [1.0, -2.0]]))
    assert torch.equal(targets, G)


def test_gae_is_the_lambda_return_minus_the_baseline():
    rng = np.random.default_rng(3)
    T, N = 7, 5
    v = rng.normal(size=(T + 1, N))
    r, d = rng.normal(size=(T, N)), (rng.uniform(size=(T, N)) > 0.2).astype(float)
    tr = (rng.uniform(size=(T, N)) > 0.8).astype(float)
    v_next = np.where(tr > 0, rng.normal(size=(T, N)), v[1:])
    adv, _ = lo.gae(t(r), t(d), t(tr), t(v[:-1]), t(v_next), 0.9, 0.95)
    G = lo.lambda_returns(t(r), t(d), t(tr), t(v_next), 0.9, 0.95)
    np.testing.assert_allclose(adv, G - t(v[:-1]), rtol=0, atol=1e-13)


def test_ppo_policy_loss_by_hand():
    """π = (½, ½), Â = ±1/(1 + 1e-8), ρ = (2, 1.1, 0.5, 0.5), ε = 0.2: policy loss 0.05/(1 + 1e-8) (samples 0
    and 3 clipped, 1 inside, 2 below the range with Â > 0), loss − 0.01 ln 2; the logits' bias gradient
    (−0.2, 0.2)/(1 + 1e-8); clip_fraction 3/4."""
    nets = image_nets(TINY, (2, 2, 1), "ppo",
                      set_to={"actor.head.dense_2.kernel": 0.0, "actor.head.dense_2.bias": 0.0})
    ratio = np.array([2.0, 1.1, 0.5, 0.5])
    old = t(-math.log(2) - np.log(ratio))
    loss, aux = lo.ppo_policy_loss(nets, grids(0, 4, (2, 2, 1)), t([0, 1, 0, 1], torch.int64), old,
                                   t([1.0, -1.0, 1.0, -1.0]))
    loss.backward()
    s = 1 / (1 + 1e-8)
    np.testing.assert_allclose(loss.item(), 0.05 * s - 0.01 * math.log(2), rtol=1e-12)
    np.testing.assert_allclose(aux["policy_loss"].item(), 0.05 * s, rtol=1e-12)
    np.testing.assert_allclose(aux["entropy"].item(), math.log(2), rtol=1e-14)
    assert aux["clip_fraction"].item() == 0.75
    np.testing.assert_allclose(aux["approx_kl"].item(), np.mean((ratio - 1) - np.log(ratio)), rtol=1e-12)
    np.testing.assert_allclose(nets.actor.head.dense_2.bias.grad, [-0.2 * s, 0.2 * s], rtol=1e-12)


def test_q_critic_losses_by_hand():
    """PPO-Q: Q(s, ·) = (1, 3), actions (0, 1, 1), G = (2, 1, 3): loss 5/6, bias gradient (−1/3, 2/3).
    SF²: Q_head(ψ) = 1.5: loss 11/24, head-bias gradient −0.5."""
    obs, action, G = grids(1, 3, (2, 2, 1)), t([0, 1, 1], torch.int64), t([2.0, 1.0, 3.0])
    nets = image_nets(TINY, (2, 2, 1), "ppo_q",
                      set_to={"critic.head.dense_2.kernel": 0.0, "critic.head.dense_2.bias": [1.0, 3.0]})
    loss, aux = lo.q_critic_loss(nets, obs, action, G)
    loss.backward()
    np.testing.assert_allclose(loss.item(), 5 / 6, rtol=1e-14)
    np.testing.assert_allclose(aux["q"].item(), 7 / 3, rtol=1e-14)
    np.testing.assert_allclose(nets.critic.head.dense_2.bias.grad, [-1 / 3, 2 / 3], rtol=1e-14)
    for method in ("sf2", "sf2_ae"):
        nets = image_nets(TINY, (2, 2, 1), method, set_to={"q.dense_1.kernel": 0.0, "q.dense_1.bias": 1.5})
        loss, _ = lo.q_critic_loss(nets, obs, action, G)
        loss.backward()
        np.testing.assert_allclose(loss.item(), 11 / 24, rtol=1e-14)
        np.testing.assert_allclose(nets.q.dense_1.bias.grad, [-0.5], rtol=1e-14)


def test_v_critic_loss_by_hand():
    """V = 1, V_old = (0.5, 1.125, 2, 0), G = (0, 2, 1.5, 5), ε = 0.25: loss 3.1015625, bias gradient
    −0.125."""
    nets = image_nets(TINY, (2, 2, 1), "ppo",
                      set_to={"critic.head.dense_2.kernel": 0.0, "critic.head.dense_2.bias": 1.0})
    loss, _ = lo.v_critic_loss(nets, grids(2, 4, (2, 2, 1)), t([0.5, 1.125, 2.0, 0.0]),
                               t([0.0, 2.0, 1.5, 5.0]), 0.25)
    loss.backward()
    assert loss.item() == 3.1015625
    assert nets.critic.head.dense_2.bias.grad.item() == -0.125


def test_autoencoder_loss_by_hand():
    """ℓ = (0, ln 3, ln 3, −ln 3), grids (1, 1, 0, 1) and (0, 1, 1, 0): loss ln(128/9), bias gradient
    (0, −0.25, 0.25, −0.25)."""
    ell = [0.0, math.log(3), math.log(3), -math.log(3)]
    nets = image_nets(TINY, (2, 2, 1), "sf2_ae",
                      set_to={"decoder.dense_0.kernel": 0.0, "decoder.dense_0.bias": ell})
    loss, aux = lo.autoencoder_loss(nets, t([[1.0, 1.0, 0.0, 1.0], [0.0, 1.0, 1.0, 0.0]]).reshape(2, 2, 2, 1))
    loss.backward()
    np.testing.assert_allclose(loss.item(), math.log(128 / 9), rtol=1e-14)
    np.testing.assert_allclose(aux["bce_per_cell"].item(), math.log(128 / 9) / 4, rtol=1e-14)
    np.testing.assert_allclose(nets.decoder.dense_0.bias.grad, [0.0, -0.25, 0.25, -0.25], rtol=0, atol=1e-15)


# ------------------------------------------------------------------------------------------ fast path
@torch.no_grad()
def test_contracted_velocity_equals_the_materialized_zeta():
    nets = image_nets(CFG, SHAPE, "sf2")
    rng = np.random.default_rng(5)
    x, k, f = t(rng.normal(size=(B, 60))), t(rng.uniform(size=B)), t(rng.normal(size=(B, CFG.feature_size)))
    for target in (False, True):
        M, c = nwi.contract(nets, f, target=target)
        fast = nwi.velocity_contracted(nets, x, k, M, c, target=target)
        np.testing.assert_allclose(fast, nwi.velocity(nets, x, k, f, target=target), rtol=1e-12, atol=1e-13)
        h = nwi.zeta_hidden(nets, x, k, target=target).numpy()
        last = (nets.target_zeta if target else nets.zeta).last
        zeta = (np.einsum("bijh,hcf->bijcf", h, last.kernel.numpy()) + last.bias.numpy()).reshape(B, 60, -1)
        np.testing.assert_allclose(nwi.zeta(nets, x, k, target=target), zeta, rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(fast, np.einsum("bdf,bf->bd", zeta, f.numpy()), rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("shape", [SHAPE, (2, 7, 1)])
def test_split_first_convolution_equals_the_broadcast_embedding(shape):
    """h(x, k) with the embedding's part of ζ's first convolution formed per tap (`contract_zeta`) equals
    the convolution over [grid, embedding at every pixel] (the oracle), values and gradients with respect
    to every ζ parameter, on the same draws (as the JAX core's test)."""
    cfg = dataclasses.replace(CFG, obs_size=math.prod(shape))
    rng = np.random.default_rng(7)
    x, k = t(rng.normal(size=(B, cfg.obs_size))), t(rng.uniform(size=B))
    w = t(rng.normal(size=(B, *shape[:2], 5)))
    out = {}
    for fast in (True, False):
        nets = image_nets(dataclasses.replace(cfg, contract_zeta=fast), shape, "sf2", seed=3)
        h = nwi.zeta_hidden(nets, x, k)
        (w * h).sum().backward()
        out[fast] = h.detach().numpy(), params.to_canonical({"zeta": nets.zeta}, grads=True)
    (h_fast, g_fast), (h_plain, g_plain) = out[True], out[False]
    assert h_fast.dtype == np.float64
    assert np.max(np.abs(h_fast - h_plain)) <= 1e-10 * np.max(np.abs(h_plain))
    assert set(g_fast) == set(g_plain)
    for name in g_fast:
        assert np.max(np.abs(g_fast[name] - g_plain[name])) <= 1e-10 * max(np.max(np.abs(g_plain[name])),
                                                                          1e-300), name


@pytest.mark.parametrize("steps,method,gamma_su",
                         [(1, "midpoint", 0.9), (2, "euler", 0.9), (1, "midpoint", 0.0)])
def test_image_flow_loss_fast_path_equals_plain_oracle(steps, method, gamma_su):
    batch, next_action, k = flow_batch(1)
    eps = t(np.random.default_rng(2).normal(size=(B, 60)))
    out = {}
    for fast in (True, False):
        cfg = dataclasses.replace(CFG, denoising_steps=steps, integrator=method, gamma_su=gamma_su,
                                  contract_zeta=fast)
        nets = image_nets(cfg, SHAPE, "sf2", seed=1)
        loss, aux = lo.image_flow_loss(nets, batch, next_action, eps, k)
        loss.backward()
        out[fast] = loss, aux, params.to_canonical({"psi": nets.psi, "zeta": nets.zeta}, grads=True)
    (lf, af, gf), (lp, ap, gp) = out[True], out[False]
    np.testing.assert_allclose(lf.item(), lp.item(), rtol=1e-12)
    for key in af:
        np.testing.assert_allclose(af[key].item(), ap[key].item(), rtol=1e-12)
    for name in gf:
        assert np.max(np.abs(gf[name] - gp[name])) <= 1e-10 * max(np.max(np.abs(gp[name])), 1e-300), name
    assert (af["loss_boot"].item() == 0.0) == (gamma_su == 0)


# ------------------------------------------------------------------------------------------ flow w AE
def test_latent_flow_loss_is_the_vector_flow_loss(monkeypatch):
    """`latent_flow_loss` equals, bit for bit, the vector core's `flow_loss` (called unchanged) on the
    latents when its ψ is the image ψ and its normalizer the identity (as the JAX core's test)."""
    nets = image_nets(CFG, SHAPE, "sf2_ae", seed=2)
    batch, next_action, k = flow_batch(3)
    eps = t(np.random.default_rng(4).normal(size=(B, nwi.LATENT_SIZE)))
    with torch.no_grad():
        z, z_next = nwi.encode(nets, batch.obs), nwi.encode(nets, batch.next_obs)
    one_hot = torch.eye(CFG.action_size, dtype=torch.float64)
    vbatch = losses.Batch(z, one_hot[batch.action], batch.reward, batch.discount, z_next, batch.truncation)
    latent = nwi.latent_networks(nets)
    vector_nets = types.SimpleNamespace(cfg=latent.cfg, zeta=latent.zeta, target_zeta=latent.target_zeta,
                                        obs_norm=nw.ObsNormalizer(nwi.LATENT_SIZE, dtype=torch.float64))

    def image_psi(nets_, obs, action, target=False):   # the vector ψ's signature, the image ψ
        grid = batch.obs if obs is vbatch.obs else batch.next_obs
        return nwi.psi(nets, grid, action.argmax(-1), target=target)

    results = []
    for run in ("latent", "vector"):
        nets.zero_grad(set_to_none=True)
        if run == "latent":
            loss, aux = lo.latent_flow_loss(nets, batch, next_action, eps, k)
        else:
            with monkeypatch.context() as m:
                m.setattr(losses, "psi", image_psi)
                loss, aux = losses.flow_loss(vector_nets, vbatch, one_hot[next_action], eps, k)
        loss.backward()
        grads = params.to_canonical({"psi": nets.psi, "zeta": nets.zeta}, grads=True)
        grads = [torch.as_tensor(g) for g in grads.values()]
        results.append([loss.detach(), aux["loss_p"], aux["loss_boot"], *grads])
    assert all(torch.equal(a, b) for a, b in zip(*results))
    assert results[0][2].item() > 0


# ------------------------------------------------------------------------------------------ contracts
@pytest.mark.parametrize("method,loss,trained", [
    ("sf2", "image_flow_loss", {"psi", "zeta"}), ("sf2_ae", "latent_flow_loss", {"psi", "zeta"}),
    ("sf2_ae", "autoencoder_loss", {"encoder", "decoder"}), ("sf2", "q_critic_loss", {"psi", "q"}),
    ("ppo_q", "q_critic_loss", {"critic"}), ("ppo", "v_critic_loss", {"critic"}),
    ("sf2_ae", "ppo_policy_loss", {"actor"}),
])
def test_each_loss_trains_only_its_groups(method, loss, trained):
    """loss.backward() with every parameter: only the trained groups receive a gradient (targets are
    frozen, ψ̄′, z′ and the targets of the critics carry none)."""
    nets = image_nets(CFG, SHAPE, method, seed=3)
    batch, next_action, k = flow_batch(4)
    size = 60 if method == "sf2" else nwi.LATENT_SIZE
    args = {
        "image_flow_loss": (batch, next_action, torch.ones(B, size, dtype=torch.float64), k),
        "latent_flow_loss": (batch, next_action, torch.ones(B, size, dtype=torch.float64), k),
        "autoencoder_loss": (batch.obs,), "q_critic_loss": (batch.obs, batch.action, batch.reward),
        "v_critic_loss": (batch.obs, batch.reward, batch.reward * 2),
        "ppo_policy_loss": (batch.obs, batch.action, batch.reward - 1.5, batch.reward),
    }[loss]
    getattr(lo, loss)(nets, *args)[0].backward()
    for group, module in nets.named_children():
        got = [p.grad for p in module.parameters() if p.grad is not None]
        assert (len(got) > 0 and any(g.abs().sum() > 0 for g in got)) == (group in trained), group


def test_canonical_names_and_layouts():
    """The same canonical names and shapes as the JAX core's (conv kernels HWIO, dense (in, out), the 1×1
    layer (H_ζ, C, F)); a canonical round trip is exact."""
    for method in nwi.METHODS:
        nets = nwi.make_image_networks(CFG, SHAPE, method)
        shapes = params.expected_shapes(nets)
        assert shapes["actor.torso.conv_0.kernel"] == (2, 2, 3, 32)
        assert shapes["actor.torso.dense_0.kernel"] == (2 * 2 * 32, 64)
        flat = params.to_canonical(nets)
        back = params.to_canonical(params.from_canonical(flat, nwi.make_image_networks(CFG, SHAPE, method)))
        assert all(np.array_equal(back[n], flat[n]) for n in flat)
    s = params.expected_shapes(nwi.make_image_networks(CFG, SHAPE, "sf2"))
    assert s["zeta.conv_0.kernel"] == (3, 3, 3 + 4, 6)
    assert (s["zeta.last.kernel"], s["zeta.last.bias"]) == ((5, 3, 6), (3, 6))
