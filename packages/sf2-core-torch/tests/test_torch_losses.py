from __future__ import annotations

import numpy as np
import pytest
import torch
from sf2_torch import ShapeError, losses, networks, params
from torch_reference import (
    A,
    B,
    D,
    make_batch,
    make_nets,
    np_flow_loss,
    np_mlp,
    np_normalize,
    np_psi,
    np_q,
)

_softplus = lambda x: np.logaddexp(0.0, x)  # noqa: E731


def _grads(nets, prefixes=("psi.", "zeta.")):
    g = params.to_canonical(nets, grads=True)
    return {n: v for n, v in g.items() if n.startswith(prefixes)}


def _zero_grads(nets):
    for p in nets.parameters():
        p.grad = None


def _run_flow(contract_zeta, T, method, gamma):
    nets = make_nets("td3", contract_zeta=contract_zeta, denoising_steps=T, integrator=method, gamma_su=gamma)
    batch, noise = make_batch()
    loss, aux = losses.flow_loss(nets, batch, noise["next_action"], noise["eps"], noise["flow_time"])
    loss.backward()
    return nets, loss, aux, _grads(nets)


@pytest.mark.parametrize("gamma", [0.0, 0.99])
@pytest.mark.parametrize("method", ["midpoint", "euler"])
@pytest.mark.parametrize("T", [1, 2, 4])
def test_fast_path_equals_plain_oracle_and_numpy(T, method, gamma):
    nets, fast, fast_aux, fast_g = _run_flow(True, T, method, gamma)
    _, plain, plain_aux, plain_g = _run_flow(False, T, method, gamma)
    rel = dict(rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(fast, plain, **rel)
    for key in ("loss_p", "loss_boot"):
        torch.testing.assert_close(fast_aux[key], plain_aux[key], **rel)
        assert fast_aux[key].ndim == 0 and not fast_aux[key].requires_grad
    assert fast_g.keys() == plain_g.keys()
    for name in fast_g:
        scale = max(np.abs(plain_g[name]).max(), 1e-30)
        assert np.abs(fast_g[name] - plain_g[name]).max() <= 1e-10 * scale + 1e-14, name
    assert any(np.abs(v).max() > 0 for v in fast_g.values())
    batch, noise = make_batch()
    ref = np_flow_loss(
        params.to_canonical(nets),
        nets.cfg,
        batch,
        *(noise[k].numpy() for k in ("next_action", "eps", "flow_time")),
    )
    np.testing.assert_allclose(fast.item(), ref[0], rtol=1e-11)
    np.testing.assert_allclose(fast_aux["loss_p"].item(), ref[1], rtol=1e-11)
    if gamma:
        np.testing.assert_allclose(fast_aux["loss_boot"].item(), ref[2], rtol=1e-11)


def test_fast_path_never_materializes_zeta(monkeypatch):
    nets = make_nets("td3", denoising_steps=2)

    def boom(*args, **kwargs):
        raise AssertionError("ζ (B, D, F) was materialized")

    monkeypatch.setattr(nets.zeta, "forward", boom)
    monkeypatch.setattr(nets.target_zeta, "forward", boom)
    batch, noise = make_batch()
    losses.flow_loss(nets, batch, noise["next_action"], noise["eps"], noise["flow_time"])[0].backward()


@pytest.mark.parametrize("contract_zeta", [True, False])
def test_gamma_zero_skips_bootstrap(monkeypatch, contract_zeta):
    nets = make_nets("td3", gamma_su=0.0, contract_zeta=contract_zeta)

    def boom(*args, **kwargs):
        raise AssertionError("the bootstrap branch ran")

    for name in ("forward", "hidden"):
        monkeypatch.setattr(nets.target_zeta, name, boom)
    monkeypatch.setattr(nets.target_psi, "forward", boom)
    batch, noise = make_batch()
    loss, aux = losses.flow_loss(nets, batch, noise["next_action"], noise["eps"], noise["flow_time"])
    assert aux["loss_boot"].item() == 0.0
    assert loss.item() == aux["loss_p"].item()


def test_hand_computed_flow_loss_with_constant_fields():
    """Zero every weight except the last biases of ψ, ζ, ψ̄, ζ̄: u = Zp and ū = Z̄p̄ for every sample."""
    gamma = 0.3
    nets = make_nets("td3", gamma_su=gamma)
    rng = np.random.default_rng(5)
    flat = params.to_canonical(nets)
    F = nets.cfg.feature_size
    for name in flat:
        if name.endswith((".kernel", ".bias")):
            flat[name] = np.zeros_like(flat[name])
    Z, Zb = rng.normal(size=(D, F)), rng.normal(size=(D, F))
    p, pb = rng.normal(size=F), rng.normal(size=F)
    flat["zeta.dense_2.bias"], flat["target_zeta.dense_2.bias"] = Z.reshape(-1), Zb.reshape(-1)
    flat["psi.dense_2.bias"], flat["target_psi.dense_2.bias"] = p, pb
    params.from_canonical(flat, nets)
    batch, noise = make_batch()
    loss, aux = losses.flow_loss(nets, batch, noise["next_action"], noise["eps"], noise["flow_time"])
    loss.backward()

    m = 1.0 - batch.truncation.numpy()
    next_n = (batch.next_obs.numpy() - flat["obs_norm.mean"]) / flat["obs_norm.std"]
    target = next_n - noise["eps"].numpy()
    u, u_bar = Z @ p, Zb @ pb
    l_p = ((u - target) ** 2).sum(-1)
    l_b = np.full(B, ((u - u_bar) ** 2).sum())
    np.testing.assert_allclose(aux["loss_p"].item(), (m * l_p).mean(), rtol=1e-12)
    np.testing.assert_allclose(aux["loss_boot"].item(), (m * l_b).mean(), rtol=1e-12)
    np.testing.assert_allclose(loss.item(), (m * ((1 - gamma) * l_p + gamma * l_b)).mean(), rtol=1e-12)
    # d loss / d Z[d, f] = mean_b m_b [2(1−γ)(u − target_b)_d + 2γ(u − ū)_d] p_f
    resid = (m[:, None] * (2 * (1 - gamma) * (u - target) + 2 * gamma * (u - u_bar))).mean(0)
    grad = params.to_canonical(nets, grads=True)["zeta.dense_2.bias"].reshape(D, F)
    np.testing.assert_allclose(grad, np.outer(resid, p), rtol=1e-11, atol=1e-13)


# ------------------------------------------------------------------------------- TD3 / SAC references
def _np_batch(batch):
    return {n: v.numpy() for n, v in batch._asdict().items()}


def _np_sac(flat, cfg, obs, xi):
    out = np_mlp(flat, "policy", np_normalize(flat, obs), len(cfg.hidden_sizes))
    loc, std = out[:, :A], _softplus(out[:, A:]) + cfg.min_std
    u = loc + std * xi
    logp = (-0.5 * xi**2 - np.log(std) - 0.5 * np.log(2 * np.pi)).sum(-1)
    logp -= (2 * (np.log(2) - u - _softplus(-2 * u))).sum(-1)
    return np.tanh(u), logp


def test_td3_losses_match_numpy(td3_nets):
    cfg, flat = td3_nets.cfg, params.to_canonical(td3_nets)
    batch, noise = make_batch()
    b = _np_batch(batch)
    loss, aux = losses.td3_critic_loss(td3_nets, batch, noise["smoothing"])
    pi_bar = np.tanh(np_mlp(flat, "target_policy", np_normalize(flat, b["next_obs"]), 2))
    a_next = np.clip(pi_bar + np.clip(0.2 * noise["smoothing"].numpy(), -0.3, 0.3), -1, 1)
    q_next = np_q(flat, np_psi(flat, cfg, b["next_obs"], a_next, "target_psi"), "target_q").min(-1)
    y = b["reward"] + b["discount"] * 0.99 * q_next
    q = np_q(flat, np_psi(flat, cfg, b["obs"], b["action"]))
    ref = 0.5 * (((1 - b["truncation"])[:, None] * (q - y[:, None])) ** 2).mean()
    np.testing.assert_allclose(loss.item(), ref, rtol=1e-12)
    np.testing.assert_allclose(aux["target_q"].item(), y.mean(), rtol=1e-12)

    loss, _ = losses.td3_actor_loss(td3_nets, batch)
    pi = np.tanh(np_mlp(flat, "policy", np_normalize(flat, b["obs"]), 2))
    ref = -np_q(flat, np_psi(flat, cfg, b["obs"], pi))[:, 0].mean()
    np.testing.assert_allclose(loss.item(), ref, rtol=1e-12)


def test_sac_losses_match_numpy(sac_nets):
    cfg, flat = sac_nets.cfg, params.to_canonical(sac_nets)
    batch, noise = make_batch()
    b, xi = _np_batch(batch), noise["noise"].numpy()
    alpha = np.exp(flat["log_alpha"])
    loss, _ = losses.sac_critic_loss(sac_nets, batch, noise["noise"])
    a_next, logp_next = _np_sac(flat, cfg, b["next_obs"], xi)
    q_next = np_q(flat, np_psi(flat, cfg, b["next_obs"], a_next, "target_psi"), "target_q").min(-1)
    y = b["reward"] + b["discount"] * 0.99 * (q_next - alpha * logp_next)
    q = np_q(flat, np_psi(flat, cfg, b["obs"], b["action"]))
    ref = 0.5 * (((1 - b["truncation"])[:, None] * (q - y[:, None])) ** 2).mean()
    np.testing.assert_allclose(loss.item(), ref, rtol=1e-12)

    a, logp = _np_sac(flat, cfg, b["obs"], xi)
    loss, aux = losses.sac_actor_loss(sac_nets, batch, noise["noise"])
    ref = (alpha * logp - np_q(flat, np_psi(flat, cfg, b["obs"], a)).min(-1)).mean()
    np.testing.assert_allclose(loss.item(), ref, rtol=1e-12)
    np.testing.assert_allclose(aux["entropy"].item(), -logp.mean(), rtol=1e-12)

    loss, _ = losses.sac_alpha_loss(sac_nets, batch, noise["noise"])
    ref = (alpha * (-logp - (-0.5 * A))).mean()
    np.testing.assert_allclose(loss.item(), ref, rtol=1e-12)


# ---------------------------------------------------------------------------------- gradient routing
def _with_grad(nets):
    return {n for n, p in nets.named_parameters() if p.grad is not None and p.grad.abs().sum() > 0}


def _groups(names):
    return {n.split(".")[0] for n in names}


def _loss_calls(nets, batch, noise):
    return {
        "flow": lambda: losses.flow_loss(nets, batch, noise["next_action"], noise["eps"], noise["flow_time"]),
        "td3_critic": lambda: losses.td3_critic_loss(nets, batch, noise["smoothing"]),
        "td3_actor": lambda: losses.td3_actor_loss(nets, batch),
        "sac_critic": lambda: losses.sac_critic_loss(nets, batch, noise["noise"]),
        "sac_actor": lambda: losses.sac_actor_loss(nets, batch, noise["noise"]),
        "sac_alpha": lambda: losses.sac_alpha_loss(nets, batch, noise["noise"]),
    }


@pytest.mark.parametrize(
    "algo, loss_name, trained, reached",
    [
        ("td3", "flow", {"psi", "zeta"}, {"psi", "zeta"}),
        ("td3", "td3_critic", {"psi", "q"}, {"psi", "q"}),
        ("td3", "td3_actor", {"policy"}, {"policy", "psi", "q"}),
        ("sac", "flow", {"psi", "zeta"}, {"psi", "zeta"}),
        ("sac", "sac_critic", {"psi", "q"}, {"psi", "q"}),
        ("sac", "sac_actor", {"policy"}, {"policy", "psi", "q"}),
        ("sac", "sac_alpha", {"log_alpha"}, {"log_alpha"}),
    ],
)
def test_gradient_contract(algo, loss_name, trained, reached):
    """A loss's graph reaches its trained groups and, for the actor losses, the critic it reads, never a
    target, the policy through the TD target, nor log α through α; `backward(inputs=trained)` (the
    module docstring's contract) fills exactly the trained groups."""
    nets = make_nets(algo)
    batch, noise = make_batch()
    call = _loss_calls(nets, batch, noise)[loss_name]
    loss, aux = call()
    assert loss.ndim == 0 and all(v.ndim == 0 and not v.requires_grad for v in aux.values())
    loss.backward(inputs=[p for p in nets.parameters() if p.requires_grad])
    assert _groups(_with_grad(nets)) == reached
    for target in nets.target_modules().values():
        assert all(p.grad is None and not p.requires_grad for p in target.parameters())
    _zero_grads(nets)
    loss, _ = call()
    loss.backward(inputs=[p for n, p in nets.named_parameters() if n.split(".")[0] in trained])
    assert _groups(_with_grad(nets)) == trained
    assert call()[0].item() == loss.item()  # pure: same inputs, same numbers


class _LinearCritic(torch.nn.Module):
    """Q_j(s, a) = [s, a]·W[:, j] (online) or [s, a]·W̄[:, j] (target): a critic that is not SF²'s."""

    def __init__(self):
        super().__init__()
        rng = np.random.default_rng(11)
        self.w = torch.nn.Parameter(torch.as_tensor(rng.normal(size=(D + A, 2))))
        self.register_buffer("w_bar", torch.as_tensor(rng.normal(size=(D + A, 2))))

    def forward(self, obs, action, target=False):
        return torch.cat([obs, action], -1) @ (self.w_bar if target else self.w)


def test_critic_keyword_trains_the_given_critic(td3_nets, sac_nets):
    """The TD3/SAC losses on another critic: the hand-written numpy values, gradients into that critic."""
    batch, noise = make_batch()
    b = _np_batch(batch)
    critic = _LinearCritic()
    w, w_bar = critic.w.detach().numpy(), critic.w_bar.numpy()
    flat = params.to_canonical(td3_nets)
    trunc = (1 - b["truncation"])[:, None]

    loss, aux = losses.td3_critic_loss(td3_nets, batch, noise["smoothing"], critic=critic)
    pi_bar = np.tanh(np_mlp(flat, "target_policy", np_normalize(flat, b["next_obs"]), 2))
    a_next = np.clip(pi_bar + np.clip(0.2 * noise["smoothing"].numpy(), -0.3, 0.3), -1, 1)
    y = b["reward"] + b["discount"] * 0.99 * (np.concatenate([b["next_obs"], a_next], -1) @ w_bar).min(-1)
    q = np.concatenate([b["obs"], b["action"]], -1) @ w
    np.testing.assert_allclose(loss.item(), 0.5 * ((trunc * (q - y[:, None])) ** 2).mean(), rtol=1e-12)
    loss.backward()
    # d/dW of ½ mean_{b,j}(m_b(x_b·W_j − y_b))² = x_bᵀ m_b²(Q − y) / (2B)
    x = np.concatenate([b["obs"], b["action"]], -1)
    np.testing.assert_allclose(critic.w.grad.numpy(), x.T @ (trunc**2 * (q - y[:, None])) / (2 * B),
                               rtol=1e-11)
    assert _with_grad(td3_nets) == set()

    loss, _ = losses.td3_actor_loss(td3_nets, batch, critic=critic)
    pi = np.tanh(np_mlp(flat, "policy", np_normalize(flat, b["obs"]), 2))
    ref = -(np.concatenate([b["obs"], pi], -1) @ w)[:, 0].mean()
    np.testing.assert_allclose(loss.item(), ref, rtol=1e-12)

    flat = params.to_canonical(sac_nets)
    xi = noise["noise"].numpy()
    loss, _ = losses.sac_actor_loss(sac_nets, batch, noise["noise"], critic=critic)
    a, logp = _np_sac(flat, sac_nets.cfg, b["obs"], xi)
    ref = (np.exp(flat["log_alpha"]) * logp - (np.concatenate([b["obs"], a], -1) @ w).min(-1)).mean()
    np.testing.assert_allclose(loss.item(), ref, rtol=1e-12)
    loss, _ = losses.sac_critic_loss(sac_nets, batch, noise["noise"], critic=critic)
    a2, logp2 = _np_sac(flat, sac_nets.cfg, b["next_obs"], xi)
    soft = (np.concatenate([b["next_obs"], a2], -1) @ w_bar).min(-1) - np.exp(flat["log_alpha"]) * logp2
    y = b["reward"] + b["discount"] * 0.99 * soft
    np.testing.assert_allclose(loss.item(), 0.5 * ((trunc * (q - y[:, None])) ** 2).mean(), rtol=1e-12)


def test_default_critic_is_sf2_critic(td3_nets):
    batch, noise = make_batch()
    critic = losses.sf2_critic(td3_nets)
    for fn, args in ((losses.td3_critic_loss, (noise["smoothing"],)), (losses.td3_actor_loss, ())):
        assert fn(td3_nets, batch, *args)[0].item() == fn(td3_nets, batch, *args, critic=critic)[0].item()
    feats = networks.psi(td3_nets, batch.obs, batch.action, target=True)
    torch.testing.assert_close(critic(batch.obs, batch.action, target=True),
                               networks.q_values(td3_nets, feats, target=True), rtol=0, atol=0)


def test_td3_actor_gradient_is_the_dpg_gradient(td3_nets):
    """∇_θ of −mean Q_0(ψ(s, π_θ(s))) equals the chain rule through a detached ∇_a Q_0."""
    batch, _ = make_batch()
    losses.td3_actor_loss(td3_nets, batch)[0].backward(inputs=list(td3_nets.policy.parameters()))
    got = [p.grad.clone() for p in td3_nets.policy.parameters()]
    _zero_grads(td3_nets)
    a = networks.td3_action(td3_nets, batch.obs)
    a_leaf = a.detach().requires_grad_(True)
    q0 = networks.q_values(td3_nets, networks.psi(td3_nets, batch.obs, a_leaf))[:, 0]
    (dqda,) = torch.autograd.grad(q0.sum(), a_leaf)
    (-(a * dqda).sum() / B).backward()
    for g, p in zip(got, td3_nets.policy.parameters()):
        torch.testing.assert_close(g, p.grad, rtol=1e-10, atol=1e-13)


def test_explicit_mixture_loss():
    rng = np.random.default_rng(3)
    x1, x2, e1, e2 = (torch.as_tensor(rng.normal(size=(5, 2))) for _ in range(4))
    k1, k2 = (torch.as_tensor(rng.uniform(size=5)) for _ in range(2))

    def field(x, k):
        return 2.0 * x + k[:, None]

    loss, aux = losses.explicit_mixture_loss(field, x1, x2, e1, e2, k1, k2, 0.25)

    def term(x, e, k):
        x, e, k = x.numpy(), e.numpy(), k.numpy()[:, None]
        xk = k * x + (1 - k) * e
        return (((2.0 * xk + k) - (x - e)) ** 2).sum(-1).mean()

    l1, l2 = term(x1, e1, k1), term(x2, e2, k2)
    np.testing.assert_allclose(loss.item(), 0.25 * l1 + 0.75 * l2, rtol=1e-13)
    np.testing.assert_allclose(aux["loss_1"].item(), l1, rtol=1e-13)


def test_ema_update_formula(td3_nets):
    before = [p.clone() for p in td3_nets.target_psi.parameters()]
    online = list(td3_nets.psi.parameters())
    losses.ema_update(td3_nets.target_psi, td3_nets.psi, 0.05)
    for t0, o, t1 in zip(before, online, td3_nets.target_psi.parameters()):
        torch.testing.assert_close(t1, 0.95 * t0 + 0.05 * o, rtol=1e-14, atol=1e-15)
        assert not t1.requires_grad
    losses.ema_update(td3_nets.target_zeta, td3_nets.zeta, 1.0)
    for t, o in zip(td3_nets.target_zeta.parameters(), td3_nets.zeta.parameters()):
        assert torch.equal(t, o)
    with pytest.raises(ShapeError):
        losses.ema_update(td3_nets.target_psi, td3_nets.zeta, 0.1)


def test_loss_shape_errors(td3_nets):
    batch, noise = make_batch()
    with pytest.raises(ShapeError, match=r"eps must have shape \(6, 3\).*found \(6, 2\)"):
        losses.flow_loss(td3_nets, batch, noise["next_action"], noise["eps"][:, :2], noise["flow_time"])
    with pytest.raises(ShapeError, match=r"batch.obs must have shape \(B, 3\), found \(6, 4\)"):
        bad = batch._replace(obs=torch.zeros(B, 4, dtype=torch.float64))
        losses.td3_critic_loss(td3_nets, bad, noise["smoothing"])
