import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax_helpers import A, B, D, make_batch, small_cfg
from sf2_jax import ShapeError, losses
from sf2_jax import networks as nw

TRAINED = {
    "flow": {"psi", "zeta"}, "td3_critic": {"psi", "q"}, "td3_actor": {"policy"},
    "sac_critic": {"psi", "q"}, "sac_actor": {"policy"}, "sac_alpha": {"log_alpha"},
}


def flow_value_and_grad(nets, params, batch, noise):
    def f(p):
        return losses.flow_loss(nets, p, batch, noise["next_action"], noise["eps"], noise["flow_time"])

    return jax.value_and_grad(f, has_aux=True)(params)


def assert_trees_close(a, b, rtol):
    for (path, x), y in zip(jax.tree_util.tree_leaves_with_path(a), jax.tree_util.tree_leaves(b)):
        x, y = np.asarray(x), np.asarray(y)
        scale = max(np.max(np.abs(y)), 1e-300)
        assert np.max(np.abs(x - y)) <= rtol * scale, jax.tree_util.keystr(path)


@pytest.mark.parametrize("steps, method, gamma_su", list(itertools.product(
    (1, 2, 4), ("midpoint", "euler"), (0.0, 0.99))))
def test_fast_path_equals_plain_oracle(td3, data, steps, method, gamma_su):
    _, params = td3
    batch, noise = data
    out = {}
    for contract in (True, False):
        cfg = small_cfg(denoising_steps=steps, integrator=method, gamma_su=gamma_su, contract_zeta=contract)
        out[contract] = flow_value_and_grad(nw.make_networks(cfg, "td3"), params, batch, noise)
    (loss_f, aux_f), grad_f = out[True]
    (loss_p, aux_p), grad_p = out[False]
    np.testing.assert_allclose(loss_f, loss_p, rtol=1e-12)
    for key in ("loss_p", "loss_boot"):
        np.testing.assert_allclose(aux_f[key], aux_p[key], rtol=1e-12)
    assert_trees_close(grad_f, grad_p, rtol=1e-10)
    assert float(jnp.max(jnp.abs(grad_f["zeta"]["dense_0"]["kernel"]))) > 0
    if gamma_su == 0:
        assert float(aux_f["loss_boot"]) == 0.0
        assert float(loss_f) == float((1 - 0.0) * aux_f["loss_p"])
    else:
        assert float(aux_f["loss_boot"]) > 0


def constant_field_params(nets, seed=0):
    """All parameters zero except the normalizer and the last biases of ψ, ζ, ψ̄, ζ̄: then ψ and ζ are
    constant (LayerNorm of a zero vector is its zero bias)."""
    rng = np.random.default_rng(seed)
    params = jax.tree_util.tree_map(jnp.zeros_like, nw.init_params(nets, jax.random.key(0)))
    cfg = nets.cfg
    F, n_psi, n_zeta = cfg.feature_size, len(cfg.hidden_sizes), len(cfg.zeta_hidden_sizes)
    consts = {}
    for group, n, size in (("psi", n_psi, F), ("zeta", n_zeta, F * D),
                           ("target_psi", n_psi, F), ("target_zeta", n_zeta, F * D)):
        consts[group] = rng.normal(size=size)
        params[group][f"dense_{n}"]["bias"] = jnp.asarray(consts[group])
    mean, std = rng.normal(size=D), rng.uniform(0.5, 2.0, D)
    params["obs_norm"] = dict(params["obs_norm"], mean=jnp.asarray(mean), std=jnp.asarray(std))
    return params, consts, mean, std


@pytest.mark.parametrize("gamma_su", [0.0, 0.7])
def test_flow_loss_by_hand(gamma_su):
    nets = nw.make_networks(small_cfg(gamma_su=gamma_su, denoising_steps=3), "td3")
    params, consts, mean, std = constant_field_params(nets)
    batch, noise = make_batch(2)
    F = nets.cfg.feature_size
    eps, k = noise["eps"], noise["flow_time"]
    u = consts["zeta"].reshape(D, F) @ consts["psi"]          # ζψ, the same for every (x, k)
    u_bar = consts["target_zeta"].reshape(D, F) @ consts["target_psi"]
    s_next = (batch.next_obs - mean) / std
    mask = 1 - batch.truncation
    l_p = ((u - (s_next - eps)) ** 2).sum(-1)                 # (B,)
    l_b = np.full(B, ((u - u_bar) ** 2).sum())                # x̂ does not matter for a constant field
    expected = np.mean(mask * ((1 - gamma_su) * l_p + gamma_su * l_b))
    loss, aux = losses.flow_loss(nets, params, batch, noise["next_action"], eps, k)
    np.testing.assert_allclose(loss, expected, rtol=1e-12)
    np.testing.assert_allclose(aux["loss_p"], np.mean(mask * l_p), rtol=1e-12)
    np.testing.assert_allclose(aux["loss_boot"], np.mean(mask * l_b) if gamma_su else 0.0, rtol=1e-12)


def test_gamma_zero_skips_bootstrap(td3, data):
    nets, params = td3
    batch, noise = data
    nets0 = nw.make_networks(small_cfg(gamma_su=0.0), "td3")
    # The bootstrap branch is never traced: a broken target group cannot matter.
    broken = dict(params, target_psi=None, target_zeta=None)
    loss, aux = losses.flow_loss(nets0, broken, batch, noise["next_action"], noise["eps"], noise["flow_time"])
    assert float(aux["loss_boot"]) == 0.0
    assert float(loss) == float(aux["loss_p"])
    args = (noise["next_action"], noise["eps"], noise["flow_time"])
    loss_99, aux_99 = losses.flow_loss(nets, params, batch, *args)
    np.testing.assert_allclose(aux_99["loss_p"], aux["loss_p"], rtol=1e-13)
    np.testing.assert_allclose(loss_99, 0.01 * aux_99["loss_p"] + 0.99 * aux_99["loss_boot"], rtol=1e-12)


def test_truncated_samples_count_as_zero(td3):
    nets, params = td3
    batch, noise = make_batch(3, truncation=True)
    args = (noise["next_action"], noise["eps"], noise["flow_time"])
    full, _ = losses.flow_loss(nets, params, batch, *args)
    keep = np.flatnonzero(batch.truncation == 0)
    sub = losses.Batch(*(np.asarray(v)[keep] for v in batch))
    part, _ = losses.flow_loss(nets, params, sub, *(np.asarray(a)[keep] for a in args))
    np.testing.assert_allclose(full, part * len(keep) / B, rtol=1e-12)


def all_losses(td3, sac, batch, noise):
    return {
        "flow": (td3, lambda n, p: losses.flow_loss(n, p, batch, noise["next_action"], noise["eps"],
                                                    noise["flow_time"])),
        "td3_critic": (td3, lambda n, p: losses.td3_critic_loss(n, p, batch, noise["smoothing"])),
        "td3_actor": (td3, lambda n, p: losses.td3_actor_loss(n, p, batch)),
        "sac_critic": (sac, lambda n, p: losses.sac_critic_loss(n, p, batch, noise["noise"])),
        "sac_actor": (sac, lambda n, p: losses.sac_actor_loss(n, p, batch, noise["noise"])),
        "sac_alpha": (sac, lambda n, p: losses.sac_alpha_loss(n, p, batch, noise["noise"])),
    }


def test_gradients_reach_only_trained_groups(td3, sac, data):
    batch, noise = data
    for name, ((nets, params), fn) in all_losses(td3, sac, batch, noise).items():
        (loss, aux), grads = jax.value_and_grad(lambda p, n=nets, f=fn: f(n, p), has_aux=True)(params)
        assert np.isfinite(float(loss)) and all(np.ndim(v) == 0 for v in aux.values()), name
        for group, g in grads.items():
            norm = sum(float(jnp.sum(jnp.abs(leaf))) for leaf in jax.tree_util.tree_leaves(g))
            assert (norm > 0) == (group in TRAINED[name]), (name, group, norm)


def test_td3_critic_by_formula(td3, data):
    nets, params = td3
    batch, noise = data
    cfg = nets.cfg
    smooth = np.clip(cfg.smoothing_noise * noise["smoothing"], -cfg.noise_clip, cfg.noise_clip)
    a_next = np.clip(np.asarray(nw.td3_action(nets, params, batch.next_obs, target=True)) + smooth, -1, 1)
    q_next = nw.q_values(nets, params, nw.psi(nets, params, batch.next_obs, a_next, target=True), target=True)
    y = cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * np.min(q_next, -1)
    q = np.asarray(nw.q_values(nets, params, nw.psi(nets, params, batch.obs, batch.action)))
    expected = 0.5 * np.mean(((1 - batch.truncation)[:, None] * (q - y[:, None])) ** 2)
    np.testing.assert_allclose(losses.td3_critic_loss(nets, params, batch, noise["smoothing"])[0], expected,
                               rtol=1e-12)
    pi = nw.td3_action(nets, params, batch.obs)
    q0 = nw.q_values(nets, params, nw.psi(nets, params, batch.obs, pi))[:, 0]
    np.testing.assert_allclose(losses.td3_actor_loss(nets, params, batch)[0], -np.mean(q0), rtol=1e-12)


def test_sac_losses_by_formula(sac, data):
    nets, params = sac
    batch, noise = data
    cfg = nets.cfg
    alpha = float(np.exp(params["log_alpha"]))
    a2, lp2 = nw.sac_sample(nets, params, batch.next_obs, noise["noise"])
    q_next = nw.q_values(nets, params, nw.psi(nets, params, batch.next_obs, a2, target=True), target=True)
    y = cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * (np.min(q_next, -1) - alpha * lp2)
    q = np.asarray(nw.q_values(nets, params, nw.psi(nets, params, batch.obs, batch.action)))
    expected = 0.5 * np.mean(((1 - batch.truncation)[:, None] * (q - np.asarray(y)[:, None])) ** 2)
    np.testing.assert_allclose(losses.sac_critic_loss(nets, params, batch, noise["noise"])[0], expected,
                               rtol=1e-12)
    a, lp = nw.sac_sample(nets, params, batch.obs, noise["noise"])
    qa = nw.q_values(nets, params, nw.psi(nets, params, batch.obs, a))
    np.testing.assert_allclose(losses.sac_actor_loss(nets, params, batch, noise["noise"])[0],
                               np.mean(alpha * lp - np.min(qa, -1)), rtol=1e-12)
    target_entropy = -cfg.target_entropy_scale * A
    alpha_loss = lambda p: losses.sac_alpha_loss(nets, p, batch, noise["noise"])[0]  # noqa: E731
    loss, grads = jax.value_and_grad(alpha_loss)(params)
    np.testing.assert_allclose(loss, np.mean(alpha * (-lp - target_entropy)), rtol=1e-12)
    np.testing.assert_allclose(grads["log_alpha"], loss, rtol=1e-12)   # d/dlogα of α·c is α·c


def _linear_critic(weights):
    """A critic other than SF²'s: Q_j(s, a) = w_j·[s, a] (target: 2·w_j), so the TD losses are checkable by
    hand and its gradient lands in the group `lin` only."""

    def critic(p, obs, action, target=False):
        x = jnp.concatenate([obs, action], axis=-1)
        return x @ (p["lin"].T * (2.0 if target else 1.0))

    return critic


def test_td3_and_sac_losses_on_a_given_critic(td3, sac, data):
    """`critic=` replaces Q(ψ) in every TD3/SAC loss (value by formula); the losses leave the caller's params
    untouched, so the gradient of the critic's own group is the formula's too."""
    batch, noise = data
    w = np.random.default_rng(7).normal(size=(2, D + A))
    critic = _linear_critic(w)
    m = 1 - batch.truncation

    def q(obs, act, target=False):
        return np.concatenate([obs, act], -1) @ w.T * (2.0 if target else 1.0)

    def td(cfg, next_v):
        y = cfg.reward_scaling * batch.reward + batch.discount * cfg.discount * next_v
        err = m[:, None] * (q(batch.obs, batch.action) - y[:, None])
        return 0.5 * np.mean(err**2), err, y

    nets, params = td3
    p = {**params, "lin": jnp.asarray(w)}
    cfg = nets.cfg
    smooth = np.clip(cfg.smoothing_noise * noise["smoothing"], -cfg.noise_clip, cfg.noise_clip)
    a_next = np.clip(np.asarray(nw.td3_action(nets, params, batch.next_obs, target=True)) + smooth, -1, 1)
    expected, err, y = td(cfg, np.min(q(batch.next_obs, a_next, True), -1))
    f = lambda p: losses.td3_critic_loss(nets, p, batch, noise["smoothing"], critic=critic)  # noqa: E731
    (loss, aux), grads = jax.value_and_grad(f, has_aux=True)(p)
    np.testing.assert_allclose(loss, expected, rtol=1e-12)
    np.testing.assert_allclose(aux["target_q"], np.mean(y), rtol=1e-12)
    x = np.concatenate([batch.obs, batch.action], -1)
    np.testing.assert_allclose(grads["lin"], (m[:, None] * err).T @ x / err.size, rtol=1e-10)   # y constant
    pi = np.asarray(nw.td3_action(nets, params, batch.obs))
    np.testing.assert_allclose(losses.td3_actor_loss(nets, p, batch, critic=critic)[0],
                               -np.mean(q(batch.obs, pi)[:, 0]), rtol=1e-12)

    nets, params = sac
    p = {**params, "lin": jnp.asarray(w)}
    cfg, alpha = nets.cfg, float(np.exp(params["log_alpha"]))
    a2, lp2 = nw.sac_sample(nets, params, batch.next_obs, noise["noise"])
    expected, _, _ = td(cfg, np.min(q(batch.next_obs, np.asarray(a2), True), -1) - alpha * np.asarray(lp2))
    np.testing.assert_allclose(losses.sac_critic_loss(nets, p, batch, noise["noise"], critic=critic)[0],
                               expected, rtol=1e-12)
    a, lp = nw.sac_sample(nets, params, batch.obs, noise["noise"])
    f = lambda p: losses.sac_actor_loss(nets, p, batch, noise["noise"], critic=critic)  # noqa: E731
    (loss, _), grads = jax.value_and_grad(f, has_aux=True)(p)
    expected = np.mean(alpha * np.asarray(lp) - np.min(q(batch.obs, np.asarray(a)), -1))
    np.testing.assert_allclose(loss, expected, rtol=1e-12)
    assert float(grads["log_alpha"]) == 0.0   # α is a constant of the actor loss


def test_sf2_critic_is_the_default(td3, data):
    nets, params = td3
    batch, noise = data
    critic = losses.sf2_critic(nets)
    q = nw.q_values(nets, params, nw.psi(nets, params, batch.obs, batch.action))
    np.testing.assert_array_equal(critic(params, batch.obs, batch.action), q)
    for fn in (lambda p, **kw: losses.td3_critic_loss(nets, p, batch, noise["smoothing"], **kw),
               lambda p, **kw: losses.td3_actor_loss(nets, p, batch, **kw)):
        np.testing.assert_array_equal(fn(params)[0], fn(params, critic=critic)[0])


def test_losses_take_2d_batches_only(td3, data):
    nets, params = td3
    batch, noise = data
    stacked = losses.Batch(*(np.stack([v, v]) for v in batch))
    with pytest.raises(ShapeError, match=r"batch.obs: expected shape \(B, 3\) \(a 2-D batch; vmap"):
        losses.td3_critic_loss(nets, params, stacked, np.stack([noise["smoothing"]] * 2))
    vmapped = jax.vmap(lambda b, s: losses.td3_critic_loss(nets, params, b, s)[0])(
        stacked, np.stack([noise["smoothing"]] * 2))
    one = losses.td3_critic_loss(nets, params, batch, noise["smoothing"])[0]
    np.testing.assert_allclose(vmapped, [one, one], rtol=1e-12)


def test_explicit_mixture_loss():
    rng = np.random.default_rng(5)
    x1, x2, e1, e2 = (rng.normal(size=(4, D)) for _ in range(4))
    k1, k2 = rng.uniform(size=4), rng.uniform(size=4)
    scale = np.array([0.5, -1.0, 2.0])

    def v(x, k):
        return scale * x + k[:, None]

    def term(x, e, k):
        xk = k[:, None] * x + (1 - k[:, None]) * e
        return np.mean(((v(xk, k) - (x - e)) ** 2).sum(-1))

    loss, aux = losses.explicit_mixture_loss(v, x1, x2, e1, e2, k1, k2, 0.3)
    np.testing.assert_allclose(loss, 0.3 * term(x1, e1, k1) + 0.7 * term(x2, e2, k2), rtol=1e-12)
    np.testing.assert_allclose(aux["loss_1"], term(x1, e1, k1), rtol=1e-12)


def test_ema_update():
    target = {"a": jnp.array([1.0, 2.0]), "b": {"c": jnp.array(4.0)}}
    online = {"a": jnp.array([3.0, 0.0]), "b": {"c": jnp.array(0.0)}}
    out = losses.ema_update(target, online, 0.25)
    np.testing.assert_allclose(out["a"], [1.5, 1.5])
    np.testing.assert_allclose(out["b"]["c"], 3.0)


def test_loss_shape_errors(td3, data):
    nets, params = td3
    batch, noise = data
    bad = batch._replace(obs=np.zeros((B, D + 1)))
    with pytest.raises(ShapeError, match=r"batch.obs: expected last dimension 3 \(obs_size\), found 4"):
        losses.flow_loss(nets, params, bad, noise["next_action"], noise["eps"], noise["flow_time"])
    with pytest.raises(ShapeError, match=r"next_action: expected last dimension 2 \(action_size\), found 3"):
        losses.flow_loss(nets, params, batch, np.zeros((B, 3)), noise["eps"], noise["flow_time"])
    with pytest.raises(ShapeError, match="eps"):
        losses.flow_loss(nets, params, batch, noise["next_action"], np.zeros((B + 1, D)), noise["flow_time"])
    with pytest.raises(ShapeError, match="batch.reward"):
        losses.td3_critic_loss(nets, params, batch._replace(reward=np.zeros(B + 1)), noise["smoothing"])


def test_flow_loss_jits(td3, data):
    nets, params = td3
    batch, noise = data
    args = (noise["next_action"], noise["eps"], noise["flow_time"])
    eager, _ = losses.flow_loss(nets, params, batch, *args)
    jitted, _ = jax.jit(losses.flow_loss)(nets, params, batch, *args)
    np.testing.assert_allclose(jitted, eager, rtol=1e-12)
