"""The MinAtar system's networks and losses (sf2_jax.networks_image, sf2_jax.losses_onpolicy), float64.

Hand-derived values on tiny inputs (the λ-return, GAE, PPO's clipped loss, the Q and V critic losses, the
autoencoder's cross-entropy: each derivation is in the test's docstring), the fast path against the plain
formulation it replaces, the flow loss w AE as the vector `flow_loss` itself, the gradient contract and
the canonical names. Networks whose last layer's kernel is zero output its bias, which makes a loss's
value and its gradient with respect to that bias derivable by hand.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sf2_jax import SF2Config, losses, params
from sf2_jax import losses_onpolicy as lo
from sf2_jax import networks as nw
from sf2_jax import networks_image as nwi

SHAPE = (5, 4, 3)    # odd height: the torso's pooling drops the last row
CFG = SF2Config(obs_size=60, action_size=3, feature_size=6, hidden_sizes=(8, 8), q_hidden_size=8,
                zeta_hidden_sizes=(6, 5), embedding_size=4, gamma_su=0.9, denoising_steps=2)
TINY = SF2Config(obs_size=4, action_size=2, feature_size=4, hidden_sizes=(4,), q_hidden_size=4,
                 zeta_hidden_sizes=(4,), embedding_size=2)
B = 4


def image_params(nets, seed=0, set_to=None):
    """Parameters with every entry drawn (LayerNorm scales ≠ 1, biases ≠ 0, targets ≠ their online
    networks), then the canonical entries of `set_to` {name: value} set to the given values."""
    rng = np.random.default_rng(seed)
    flat = {}
    for name, shape in params.expected_shapes(nets).items():
        if name.endswith("kernel"):
            flat[name] = rng.uniform(-1.0, 1.0, shape) * math.sqrt(3.0 / np.prod(shape[:-1]))
        elif name.endswith(".scale"):
            flat[name] = rng.uniform(0.5, 1.5, shape)
        else:
            flat[name] = rng.normal(0.0, 0.1, shape)
    for name, value in (set_to or {}).items():
        flat[name] = np.broadcast_to(np.asarray(value, np.float64), flat[name].shape)
    return params.from_canonical(flat, nets, dtype=jnp.float64)


def grids(seed, n=B, shape=SHAPE):
    return (np.random.default_rng(seed).uniform(size=(n, *shape)) < 0.3).astype(np.float64)


def flow_batch(seed=0, n=B):
    rng = np.random.default_rng(seed)
    batch = losses.Batch(obs=grids(seed, n), action=rng.integers(0, CFG.action_size, n),
                         reward=rng.normal(size=n), discount=np.ones(n), next_obs=grids(seed + 1, n),
                         truncation=np.eye(n)[1])
    return batch, rng.integers(0, CFG.action_size, n), rng.uniform(size=n)


# ------------------------------------------------------------------------------------------ hand-derived
def test_lambda_returns_and_gae_by_hand():
    """T = 3, N = 2, γ = λ = ½. Env 0 is truncated after t = 1, env 1 terminates at t = 1.

    Env 0: r = (1, 2, 3), V̄(s_{t+1}) = (4, 8, 6). G_2 = 3 + ½·6 = 6 (the rollout's end: bootstrap);
    G_1 = 2 + ½·8 = 6 (truncated: bootstrap); G_0 = 1 + ½(½·4 + ½·6) = 3.5.
    Env 1: r = (0, 1, −1), d = (1, 0, 1), V̄ = (2, 10, 4). G_2 = −1 + ½·4 = 1; G_1 = 1 + 0 = 1;
    G_0 = 0 + ½(½·2 + ½·1) = 0.75.
    GAE with V(s_t) = (1, 4, 5) and (0, 2, 3) (V(s_{t+1}) = V̄ but across the truncation and the end):
    env 0: δ = (1 + 2 − 1, 2 + 4 − 4, 3 + 3 − 5) = (2, 2, 1); A_2 = 1, A_1 = 2 (truncated),
    A_0 = 2 + ¼·2 = 2.5;
    env 1: δ = (0 + 1 − 0, 1 + 0 − 2, −1 + 2 − 3) = (1, −1, −2); A_2 = −2, A_1 = −1 (terminal),
    A_0 = 1 + ¼·(−1) = 0.75. The targets A + V are the λ-returns above.
    """
    r = jnp.array([[1.0, 0.0], [2.0, 1.0], [3.0, -1.0]])
    d = jnp.array([[1.0, 1.0], [1.0, 0.0], [1.0, 1.0]])
    tr = jnp.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
    v_next = jnp.array([[4.0, 2.0], [8.0, 10.0], [6.0, 4.0]])
    v = jnp.array([[1.0, 0.0], [4.0, 2.0], [5.0, 3.0]])
    G = jnp.array([[3.5, 0.75], [6.0, 1.0], [6.0, 1.0]])
    assert np.array_equal(lo.lambda_returns(r, d, tr, v_next, 0.5, 0.5), G)
    adv, targets = lo.gae(r, d, tr, v, v_next, 0.5, 0.5)
    assert np.array_equal(adv, [[2.5, 0.75], [2.0, -1.0], [1.0, -2.0]])
    assert np.array_equal(targets, G)


def test_gae_is_the_lambda_return_minus_the_baseline():
    """A_t = G^λ_t − V(s_t) for any rollout whose V(s_{t+1}) is V of the next row where no episode ends."""
    rng = np.random.default_rng(3)
    T, N = 7, 5
    v = rng.normal(size=(T + 1, N))
    r, d = rng.normal(size=(T, N)), (rng.uniform(size=(T, N)) > 0.2).astype(float)
    tr = (rng.uniform(size=(T, N)) > 0.8).astype(float)
    v_next = np.where(tr > 0, rng.normal(size=(T, N)), v[1:])
    adv, _ = lo.gae(r, d, tr, v[:-1], v_next, 0.9, 0.95)
    G = lo.lambda_returns(r, d, tr, v_next, 0.9, 0.95)
    np.testing.assert_allclose(adv, G - v[:-1], rtol=0, atol=1e-13)


def test_ppo_policy_loss_by_hand():
    """Logits (0, 0) for every grid: π = (½, ½), H = ln 2. Advantages (1, −1, 1, −1): mean 0, std 1, so
    Â = ±1/(1 + 1e-8). Ratios ρ = (2, 1.1, 0.5, 0.5), ε = 0.2:
    sample 0: min(2Â, 1.2Â) = 1.2 (clipped above); 1: min(−1.1, −1.1) = −1.1 (inside the range);
    2: min(0.5, 0.8) = 0.5 (below the range, positive Â: not clipped); 3: min(−0.5, −0.8) = −0.8 (clipped).
    policy loss = −(1.2 − 1.1 + 0.5 − 0.8)/4 = 0.05 (times 1/(1 + 1e-8)); loss = 0.05/(1 + 1e-8) − 0.01 ln 2.
    Gradient with respect to the logits' bias b: ∂ log π(a)/∂b = e_a − π; only the unclipped samples 1
    (a = 1) and 2 (a = 0) count: −¼[ρ₁Â₁(e_1 − π) + ρ₂Â₂(e_0 − π)] = −¼[(0.55, −0.55) + (0.25, −0.25)] =
    (−0.2, 0.2)/(1 + 1e-8) (the entropy's gradient is 0 at the uniform policy). clip_fraction = 3/4.
    """
    nets = nwi.make_image_networks(TINY, (2, 2, 1), "ppo")
    p = image_params(nets, set_to={"actor.head.dense_2.kernel": 0.0, "actor.head.dense_2.bias": 0.0})
    ratio = np.array([2.0, 1.1, 0.5, 0.5])
    action = np.array([0, 1, 0, 1])
    old = -math.log(2) - np.log(ratio)
    adv = np.array([1.0, -1.0, 1.0, -1.0])

    def f(actor):
        return lo.ppo_policy_loss(nets, {**p, "actor": actor}, grids(0, 4, (2, 2, 1)), action, old, adv)

    (loss, aux), g = jax.value_and_grad(f, has_aux=True)(p["actor"])
    s = 1 / (1 + 1e-8)
    np.testing.assert_allclose(loss, 0.05 * s - 0.01 * math.log(2), rtol=1e-12)
    np.testing.assert_allclose(aux["policy_loss"], 0.05 * s, rtol=1e-12)
    np.testing.assert_allclose(aux["entropy"], math.log(2), rtol=1e-14)
    assert float(aux["clip_fraction"]) == 0.75
    np.testing.assert_allclose(aux["approx_kl"], np.mean((ratio - 1) - np.log(ratio)), rtol=1e-12)
    np.testing.assert_allclose(g["head"]["dense_2"]["bias"], [-0.2 * s, 0.2 * s], rtol=1e-12)


def test_q_critic_losses_by_hand():
    """PPO-Q: Q(s, ·) = (1, 3) for every grid, actions (0, 1, 1), G = (2, 1, 3): errors (−1, 2, 0), loss =
    ½(1 + 4 + 0)/3 = 5/6, gradient with respect to the bias (−1, 2 + 0)/3. SF²: Q_head(ψ) = 1.5 for every
    feature, G = (2, 1, 3): ½(0.25 + 0.25 + 2.25)/3 = 11/24, gradient with respect to the head's bias
    (−0.5 + 0.5 − 1.5)/3 = −0.5."""
    obs, action, G = grids(1, 3, (2, 2, 1)), np.array([0, 1, 1]), np.array([2.0, 1.0, 3.0])
    nets = nwi.make_image_networks(TINY, (2, 2, 1), "ppo_q")
    p = image_params(nets, set_to={"critic.head.dense_2.kernel": 0.0, "critic.head.dense_2.bias": [1.0, 3.0]})
    (loss, aux), g = jax.value_and_grad(lambda c: lo.q_critic_loss(nets, {**p, "critic": c}, obs, action, G),
                                        has_aux=True)(p["critic"])
    np.testing.assert_allclose(loss, 5 / 6, rtol=1e-14)
    np.testing.assert_allclose(aux["q"], 7 / 3, rtol=1e-14)
    np.testing.assert_allclose(g["head"]["dense_2"]["bias"], [-1 / 3, 2 / 3], rtol=1e-14)
    for method in ("sf2", "sf2_ae"):
        nets = nwi.make_image_networks(TINY, (2, 2, 1), method)
        p = image_params(nets, set_to={"q.dense_1.kernel": 0.0, "q.dense_1.bias": 1.5})
        (loss, _), g = jax.value_and_grad(
            lambda q, nets=nets, p=p: lo.q_critic_loss(nets, {**p, "q": q}, obs, action, G),
            has_aux=True)(p["q"])
        np.testing.assert_allclose(loss, 11 / 24, rtol=1e-14)
        np.testing.assert_allclose(g["dense_1"]["bias"], [-0.5], rtol=1e-14)


def test_v_critic_loss_by_hand():
    """V = 1 for every grid, V_old = (0.5, 1.125, 2, 0), G = (0, 2, 1.5, 5), ε = 0.25:
    V_c = (0.75, 1, 1.75, 0.25); max((V − G)², (V_c − G)²) = (max(1, 0.5625), 1 (a tie), max(0.25, 0.0625),
    max(16, 22.5625)); loss = ½(1 + 1 + 0.25 + 22.5625)/4 = 3.1015625. Gradient with respect to V's bias:
    ½·¼·(2(V − G) for samples 0 and 2, 2(V − G) for the tie, 0 for sample 3, clipped) = ⅛(2 − 2 − 1) = −0.125.
    """
    nets = nwi.make_image_networks(TINY, (2, 2, 1), "ppo")
    p = image_params(nets, set_to={"critic.head.dense_2.kernel": 0.0, "critic.head.dense_2.bias": 1.0})
    old, G = np.array([0.5, 1.125, 2.0, 0.0]), np.array([0.0, 2.0, 1.5, 5.0])
    (loss, _), g = jax.value_and_grad(
        lambda c: lo.v_critic_loss(nets, {**p, "critic": c}, grids(2, 4, (2, 2, 1)), old, G, 0.25),
        has_aux=True)(p["critic"])
    assert float(loss) == 3.1015625
    assert float(g["head"]["dense_2"]["bias"][0]) == -0.125


def test_autoencoder_loss_by_hand():
    """Decoder logits ℓ = (0, ln 3, ln 3, −ln 3) for every latent (its kernel zero). Per cell, s = 1 costs
    ln(1 + e^{−ℓ}), s = 0 costs ln(1 + e^{ℓ}). Grid (1, 1, 0, 1): ln 2 + ln(4/3) + ln 4 + ln 4 = ln(128/3);
    grid (0, 1, 1, 0): ln 2 + ln(4/3) + ln(4/3) + ln(4/3) = ln(128/27); loss = ½ ln(128²/81) = ln(128/9).
    Gradient with respect to ℓ: mean_b (σ(ℓ) − s) = ((0.5 − 1 + 0.5)/2, (0.75 − 1 + 0.75 − 1)/2,
    (0.75 + 0.75 − 1)/2, (0.25 − 1 + 0.25)/2) = (0, −0.25, 0.25, −0.25).
    """
    nets = nwi.make_image_networks(TINY, (2, 2, 1), "sf2_ae")
    ell = [0.0, math.log(3), math.log(3), -math.log(3)]
    p = image_params(nets, set_to={"decoder.dense_0.kernel": 0.0, "decoder.dense_0.bias": ell})
    obs = np.array([[1.0, 1.0, 0.0, 1.0], [0.0, 1.0, 1.0, 0.0]]).reshape(2, 2, 2, 1)
    (loss, aux), g = jax.value_and_grad(lambda d: lo.autoencoder_loss(nets, {**p, "decoder": d}, obs),
                                        has_aux=True)(p["decoder"])
    np.testing.assert_allclose(loss, math.log(128 / 9), rtol=1e-14)
    np.testing.assert_allclose(aux["bce_per_cell"], math.log(128 / 9) / 4, rtol=1e-14)
    np.testing.assert_allclose(g["dense_0"]["bias"], [0.0, -0.25, 0.25, -0.25], rtol=0, atol=1e-15)


# ------------------------------------------------------------------------------------------ fast path
def test_contracted_velocity_equals_the_materialized_zeta():
    """u = h·M + c (M = Wψ) equals u = ζψ with ζ (B, D, F) materialized, and ζ's row (p, c) is
    Σ_h h_{p,h} W_{h,c,f} + b_{c,f} computed here with numpy from h and the canonical W, b."""
    nets = nwi.make_image_networks(CFG, SHAPE, "sf2")
    p = image_params(nets)
    rng = np.random.default_rng(5)
    x, k, f = rng.normal(size=(B, 60)), rng.uniform(size=B), rng.normal(size=(B, CFG.feature_size))
    for target in (False, True):
        M, c = nwi.contract(nets, p, f, target=target)
        fast = nwi.velocity_contracted(nets, p, x, k, M, c, target=target)
        plain = nwi.velocity(nets, p, x, k, f, target=target)
        np.testing.assert_allclose(fast, plain, rtol=1e-12, atol=1e-13)
        h = np.asarray(nwi.zeta_hidden(nets, p, x, k, target=target))
        g = p["target_zeta" if target else "zeta"]["last"]
        zeta = (np.einsum("bijh,hcf->bijcf", h, g["kernel"]) + np.asarray(g["bias"])).reshape(B, 60, -1)
        np.testing.assert_allclose(nwi.zeta(nets, p, x, k, target=target), zeta, rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(fast, np.einsum("bdf,bf->bd", zeta, f), rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("shape", [SHAPE, (2, 7, 1)])
def test_split_first_convolution_equals_the_broadcast_embedding(shape):
    """h(x, k) with the embedding's part of ζ's first convolution formed per tap (`contract_zeta`) equals
    the convolution over [grid, embedding at every pixel] (the oracle), values and gradients with respect
    to every ζ parameter, on the same draws; a grid of two rows has no interior pixel."""
    cfg = dataclasses.replace(CFG, obs_size=math.prod(shape))
    rng = np.random.default_rng(7)
    x, k, w = rng.normal(size=(B, cfg.obs_size)), rng.uniform(size=B), rng.normal(size=(B, *shape[:2], 5))
    out = {}
    for fast in (True, False):
        nets = nwi.make_image_networks(dataclasses.replace(cfg, contract_zeta=fast), shape, "sf2")
        p = image_params(nets, seed=3)

        def h(z, nets=nets, p=p):
            return jnp.sum(w * nwi.zeta_hidden(nets, {**p, "zeta": z}, x, k)), nwi.zeta_hidden(nets, p, x, k)

        out[fast] = jax.value_and_grad(h, has_aux=True)(p["zeta"])
    (_, h_fast), g_fast = out[True]
    (_, h_plain), g_plain = out[False]
    assert h_fast.dtype == jnp.float64
    assert np.max(np.abs(np.asarray(h_fast) - h_plain)) <= 1e-10 * np.max(np.abs(h_plain))
    for a, b in zip(jax.tree_util.tree_leaves(g_fast), jax.tree_util.tree_leaves(g_plain), strict=True):
        assert np.max(np.abs(np.asarray(a) - b)) <= 1e-10 * max(np.max(np.abs(b)), 1e-300)


@pytest.mark.parametrize("steps,method,gamma_su",
                         [(1, "midpoint", 0.9), (2, "euler", 0.9), (1, "midpoint", 0.0)])
def test_image_flow_loss_fast_path_equals_plain_oracle(steps, method, gamma_su):
    out = {}
    batch, next_action, k = flow_batch(1)
    eps = np.random.default_rng(2).normal(size=(B, 60))
    for fast in (True, False):
        cfg = dataclasses.replace(CFG, denoising_steps=steps, integrator=method, gamma_su=gamma_su,
                                  contract_zeta=fast)
        nets = nwi.make_image_networks(cfg, SHAPE, "sf2")
        p = image_params(nets, seed=1)
        def loss(q, nets=nets, p=p):
            return lo.image_flow_loss(nets, {**p, **q}, batch, next_action, eps, k)

        f = jax.jit(jax.value_and_grad(loss, has_aux=True))
        out[fast] = f({g: p[g] for g in ("psi", "zeta")})
    (lf, af), gf = out[True]
    (lp, ap), gp = out[False]
    np.testing.assert_allclose(lf, lp, rtol=1e-12)
    for key in af:
        np.testing.assert_allclose(af[key], ap[key], rtol=1e-12)
    for a, b in zip(jax.tree_util.tree_leaves(gf), jax.tree_util.tree_leaves(gp)):
        assert np.max(np.abs(np.asarray(a) - b)) <= 1e-10 * max(np.max(np.abs(b)), 1e-300)
    assert (float(af["loss_boot"]) == 0.0) == (gamma_su == 0)


# ------------------------------------------------------------------------------------------ flow w AE
def test_latent_flow_loss_is_the_vector_flow_loss(monkeypatch):
    """`latent_flow_loss` equals, bit for bit, the vector core's `flow_loss` (called unchanged) on the
    latents, obs_size 64, when its ψ is the image ψ: the vector ψ is replaced by one that reads the image ψ
    of the batch's grids, the normalizer is the identity (z′ is not normalized), and z′ = E(s′)."""
    nets = nwi.make_image_networks(CFG, SHAPE, "sf2_ae")
    p = image_params(nets, seed=2)
    batch, next_action, k = flow_batch(3)
    eps = np.random.default_rng(4).normal(size=(B, nwi.LATENT_SIZE))
    latent = nwi.latent_networks(nets)
    z, z_next = nwi.encode(nets, p, batch.obs), nwi.encode(nets, p, batch.next_obs)
    one_hot = np.eye(CFG.action_size)
    vbatch = losses.Batch(z, one_hot[batch.action], batch.reward, batch.discount, z_next, batch.truncation)

    def image_psi(nets_, params_, obs, action, target=False):   # the vector ψ's signature, the image ψ
        grid = batch.obs if obs is vbatch.obs else batch.next_obs
        return nwi.psi(nets, params_, grid, jnp.argmax(action, axis=-1), target=target)

    def vector(q):
        with monkeypatch.context() as m:
            m.setattr(nw, "psi", image_psi)
            return losses.flow_loss(latent, {**p, **q, "obs_norm": nw.init_normalizer(64)}, vbatch,
                                    one_hot[next_action], eps, k)

    trained = {g: p[g] for g in ("psi", "zeta")}
    a = jax.value_and_grad(lambda q: lo.latent_flow_loss(nets, {**p, **q}, batch, next_action, eps, k),
                           has_aux=True)(trained)
    b = jax.value_and_grad(vector, has_aux=True)(trained)
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        assert np.array_equal(x, y)
    assert float(a[0][1]["loss_boot"]) > 0


# ------------------------------------------------------------------------------------------ contracts
@pytest.mark.parametrize("method,loss,trained", [
    ("sf2", "image_flow_loss", {"psi", "zeta"}), ("sf2_ae", "latent_flow_loss", {"psi", "zeta"}),
    ("sf2_ae", "autoencoder_loss", {"encoder", "decoder"}), ("sf2", "q_critic_loss", {"psi", "q"}),
    ("ppo_q", "q_critic_loss", {"critic"}), ("ppo", "v_critic_loss", {"critic"}),
    ("sf2_ae", "ppo_policy_loss", {"actor"}),
])
def test_each_loss_stops_the_gradient_of_the_groups_it_does_not_train(method, loss, trained):
    nets = nwi.make_image_networks(CFG, SHAPE, method)
    p = image_params(nets, seed=3)
    batch, next_action, k = flow_batch(4)
    size = 60 if method == "sf2" else nwi.LATENT_SIZE
    args = {
        "image_flow_loss": (batch, next_action, np.ones((B, size)), k),
        "latent_flow_loss": (batch, next_action, np.ones((B, size)), k),
        "autoencoder_loss": (batch.obs,), "q_critic_loss": (batch.obs, batch.action, batch.reward),
        "v_critic_loss": (batch.obs, batch.reward, batch.reward * 2),
        "ppo_policy_loss": (batch.obs, batch.action, batch.reward - 1.5, batch.reward),
    }[loss]
    grads = jax.jit(jax.grad(lambda q: getattr(lo, loss)(nets, q, *args)[0]))(p)
    for group, g in grads.items():
        norm = sum(float(jnp.sum(jnp.abs(v))) for v in jax.tree_util.tree_leaves(g))
        assert (norm > 0) == (group in trained), group


def test_canonical_names_and_layouts():
    """The groups of each method and the layouts: conv kernels HWIO, dense kernels (in, out), ψ's A·F
    outputs, the 1×1 layer (H_ζ, C, F); a canonical round trip is exact."""
    expected = {"ppo": {"actor", "critic"}, "ppo_q": {"actor", "critic"},
                "sf2": {"actor", "psi", "q", "zeta", "target_psi", "target_zeta"},
                "sf2_ae": {"actor", "psi", "q", "zeta", "target_psi", "target_zeta", "encoder", "decoder"}}
    for method, groups in expected.items():
        nets = nwi.make_image_networks(CFG, SHAPE, method)
        shapes = params.expected_shapes(nets)
        assert {n.split(".")[0] for n in shapes} == groups
        assert shapes["actor.torso.conv_0.kernel"] == (2, 2, 3, 32)
        assert shapes["actor.torso.dense_0.kernel"] == (2 * 2 * 32, 64)
        assert shapes["actor.head.dense_2.kernel"] == (64, 3)
        flat = params.to_canonical(image_params(nets))
        back = params.to_canonical(params.from_canonical(flat, nets))
        assert set(flat) == set(shapes) and all(np.array_equal(back[n], flat[n]) for n in flat)
    nets = nwi.make_image_networks(CFG, SHAPE, "sf2")    # one initialisation (compiling one costs seconds)
    p = params.to_canonical(jax.jit(lambda key: nwi.init_image_params(nets, key))(jax.random.key(0)))
    assert {n: v.shape for n, v in p.items()} == params.expected_shapes(nets)
    assert all(np.all(np.isfinite(v)) for v in p.values()) and np.array_equal(p["psi.head.dense_0.kernel"],
                                                                            p["target_psi.head.dense_0.kernel"])
    s = params.expected_shapes(nwi.make_image_networks(CFG, SHAPE, "sf2"))
    assert s["psi.head.dense_2.kernel"] == (8, 3 * 6)
    assert s["zeta.conv_0.kernel"] == (3, 3, 3 + 4, 6)
    assert (s["zeta.last.kernel"], s["zeta.last.bias"]) == ((5, 3, 6), (3, 6))
    s = params.expected_shapes(nwi.make_image_networks(CFG, SHAPE, "sf2_ae"))
    assert s["zeta.dense_2.kernel"] == (5, 6 * 64) and s["decoder.dense_0.kernel"] == (64, 60)
    assert s["encoder.head.dense_0.kernel"] == (64, 64)
