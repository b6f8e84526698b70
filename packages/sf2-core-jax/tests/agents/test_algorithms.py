"""The base algorithms, written against the representation interface, compute exactly the core's losses
when the representation is SF², and one SGD step follows the contract's order ("One SGD step")."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sf2_common.config import SF2Config
from sf2_jax import losses, networks
from sf2_jax.agents import representations
from sf2_jax.agents.algorithms import make_algorithm

D, A, B = 5, 2, 8


def _batch(key):
    ks = jax.random.split(key, 6)
    return losses.Batch(
        obs=jax.random.normal(ks[0], (B, D)), action=jax.random.uniform(ks[1], (B, A), minval=-1, maxval=1),
        reward=jax.random.uniform(ks[2], (B,)), discount=(jax.random.uniform(ks[3], (B,)) > 0.1) * 1.0,
        next_obs=jax.random.normal(ks[4], (B, D)), truncation=(jax.random.uniform(ks[5], (B,)) > 0.8) * 1.0)


def _setup(algo_name, rep="sf2"):
    cfg = SF2Config.small(D, A, gamma_su=0.9)
    algo = make_algorithm(algo_name, cfg, representations.get(rep))
    params, opt = algo.init(jax.random.PRNGKey(0))
    # non-trivial normalizer and targets that differ from the online networks
    params["obs_norm"] = networks.update_normalizer(params["obs_norm"], jax.random.normal(
        jax.random.PRNGKey(9), (64, D)) * 2 + 1, cfg)
    for g in [g for g in params if g.startswith("target_")]:
        params[g] = jax.tree_util.tree_map(lambda x: x * 0.9 + 0.01, params[g])
    return cfg, algo, params, opt


def _close(a, b, tol=1e-5):
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=tol, atol=tol)


def _grads(fn, params, groups):
    return jax.grad(lambda t: fn({**params, **t})[0])({g: params[g] for g in groups})


@pytest.mark.parametrize("algo_name", ["td3", "sac"])
def test_losses_are_the_cores_default_sf2_losses(algo_name):
    """With SF², the agents' losses (the core's on `critic=SF2Representation.critic`, gradient taken over
    the trained groups only) equal the core's losses with the default critic (gradients stopped inside)."""
    _, algo, params, _ = _setup(algo_name)
    batch = _batch(jax.random.PRNGKey(1))
    noise = algo.step_noise(jax.random.PRNGKey(2), batch)
    nets = algo.nets
    policy = algo.policy_losses(params, batch, noise)
    if algo_name == "td3":
        pairs = [
            (lambda p: algo.critic_loss(p, batch, noise),
             lambda p: losses.td3_critic_loss(nets, p, batch, noise["smoothing_noise"]), ("q", "psi")),
            (policy["policy"][1], lambda p: losses.td3_actor_loss(nets, p, batch), ("policy",)),
        ]
    else:
        pairs = [
            (lambda p: algo.critic_loss(p, batch, noise),
             lambda p: losses.sac_critic_loss(nets, p, batch, noise["next_action_noise"]), ("q", "psi")),
            (policy["policy"][1], lambda p: losses.sac_actor_loss(nets, p, batch, noise["actor_noise"]),
             ("policy",)),
            (policy["log_alpha"][1], lambda p: losses.sac_alpha_loss(nets, p, batch, noise["alpha_noise"]),
             ("log_alpha",)),
        ]
    expected = {"policy": "actor_loss", **({"log_alpha": "alpha_loss"} if algo_name == "sac" else {})}
    assert {g: name for g, (name, _) in policy.items()} == expected
    for ours, core, groups in pairs:
        np.testing.assert_allclose(ours(params)[0], core(params)[0], rtol=1e-6)
        _close(_grads(ours, params, groups), _grads(core, params, groups))


def test_td3_sgd_step_order_matches_contract():
    """Critic step on (Q, ψ); flow step on (ψ after the critic step, ζ); actor from the pre-step Q and ψ;
    EMA targets — rebuilt here from the core's losses and optax, compared with `sgd_step`."""
    import optax

    cfg, algo, params, opt = _setup("td3")
    batch = _batch(jax.random.PRNGKey(3))
    key = jax.random.PRNGKey(4)
    new_params, _, metrics = algo.sgd_step(params, opt, batch, algo.step_noise(key, batch), 0)

    nets, adam = algo.nets, optax.adam(cfg.learning_rate, eps=cfg.adam_eps)
    k_critic, k_aux, _, _ = jax.random.split(key, 4)
    smoothing = jax.random.normal(k_critic, (B, A))
    state = {g: adam.init(params[g]) for g in ("q", "psi", "zeta", "policy")}

    def step(p, groups, loss_fn):
        g = _grads(loss_fn, p, groups)
        p = dict(p)
        for name in groups:
            upd, state[name] = adam.update(g[name], state[name], p[name])
            p[name] = optax.apply_updates(p[name], upd)
        return p

    def reference(params):
        p1 = step(params, ("q", "psi"), lambda p: losses.td3_critic_loss(nets, p, batch, smoothing))
        k_eps, k_time = jax.random.split(k_aux)
        eps, flow_time = jax.random.normal(k_eps, (B, D)), jax.random.uniform(k_time, (B,))
        next_action = networks.td3_action(nets, params, batch.next_obs, target=True)
        p2 = step(p1, ("psi", "zeta"),
                  lambda p: losses.flow_loss(nets, p, batch, next_action, eps, flow_time))
        p3 = step(params, ("policy",), lambda p: losses.td3_actor_loss(nets, p, batch))
        return {**p2, "policy": p3["policy"]}

    expected = reference(params)
    for name, tau in (("q", cfg.tau), ("psi", cfg.tau), ("zeta", cfg.tau_zeta), ("policy", cfg.tau)):
        expected[f"target_{name}"] = losses.ema_update(params[f"target_{name}"], expected[name], tau)
    assert set(new_params) == set(expected)
    for name in expected:
        _close(new_params[name], expected[name])
    for name in ("critic_loss", "flow_loss", "loss_p", "loss_boot", "actor_loss"):
        assert np.isfinite(metrics[name])


@pytest.mark.parametrize("algo_name", ["td3", "sac"])
@pytest.mark.parametrize("rep", ["none", "sf2"])
def test_every_combination_steps(algo_name, rep):
    _, algo, params, opt = _setup(algo_name, rep)
    batch = _batch(jax.random.PRNGKey(5))
    noise = algo.step_noise(jax.random.PRNGKey(6), batch)
    new_params, new_opt, metrics = jax.jit(algo.sgd_step)(params, opt, batch, noise, 0)
    assert set(new_params) == set(params) and set(new_opt) == set(opt)
    assert all(np.isfinite(v) for v in metrics.values())
    changed = [g for g in params if not all(np.array_equal(a, b) for a, b in zip(
        jax.tree_util.tree_leaves(params[g]), jax.tree_util.tree_leaves(new_params[g])))]
    assert {"q", "policy", "target_q"} <= set(changed)
    if rep == "sf2":
        assert {"psi", "zeta", "target_psi", "target_zeta"} <= set(changed)
    else:
        assert "psi" not in params
    act = algo.explore(params, batch.obs, jax.random.PRNGKey(7))
    assert act.shape == (B, A) and bool(jnp.all(jnp.abs(act) <= 1))


@pytest.mark.parametrize("algo_name", ["td3", "sac"])
@pytest.mark.parametrize("rep", ["none", "sf2"])
def test_step_noise_is_every_random_input(algo_name, rep):
    """`step_noise` draws exactly `noise_keys()` (the algorithm's, then the representation's `noise_keys`)
    with the batch's leading shape and dtype, as a function of the key (`sgd_step` takes no key: the
    noise is its only random input)."""
    algo = make_algorithm(algo_name, SF2Config.small(D, A, gamma_su=0.9), representations.get(rep))
    batch = _batch(jax.random.PRNGKey(5))
    noise = algo.step_noise(jax.random.PRNGKey(6), batch)
    assert list(noise) == list(algo.noise_keys())
    assert set(algo.rep.noise_keys) <= set(noise) and (rep == "sf2") == bool(algo.rep.noise_keys)
    assert all(v.shape[0] == B and v.dtype == batch.obs.dtype for v in noise.values())
    again = algo.step_noise(jax.random.PRNGKey(6), batch)
    other = algo.step_noise(jax.random.PRNGKey(7), batch)
    for k in noise:
        np.testing.assert_array_equal(noise[k], again[k])
        assert not np.array_equal(noise[k], other[k]), k


class _ZetaEvery3(representations.SF2Representation):
    """SF² whose ζ takes its flow-step Adam update every 3rd gradient step only (a test schedule)."""

    aux_every = {"zeta": 3}


def test_aux_every_keeps_group_and_adam_state_off_period():
    cfg = SF2Config.small(D, A, gamma_su=0.9)
    algo = make_algorithm("td3", cfg, _ZetaEvery3)
    params, opt = algo.init(jax.random.PRNGKey(0))
    step = jax.jit(algo.sgd_step)
    for i in range(5):
        batch = _batch(jax.random.PRNGKey(i))
        noise = algo.step_noise(jax.random.PRNGKey(10 + i), batch)
        new_p, new_o, _ = step(params, opt, batch, noise, jnp.asarray(i, jnp.int32))
        due = i % 3 == 0
        for g in ("zeta",):
            same_p = all(np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(params[g]),
                                                              jax.tree_util.tree_leaves(new_p[g])))
            same_o = all(np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(opt[g]),
                                                              jax.tree_util.tree_leaves(new_o[g])))
            assert same_p == same_o == (not due), (i, same_p, same_o)
        assert int(new_o["zeta"][0].count) == (i // 3) + 1
        assert int(new_o["psi"][0].count) == 2 * (i + 1)  # critic and flow steps, every time
        # ζ̄ is averaged every step (towards the current ζ)
        assert not np.array_equal(np.asarray(jax.tree_util.tree_leaves(new_p["target_zeta"])[0]),
                                  np.asarray(jax.tree_util.tree_leaves(params["target_zeta"])[0]))
        params, opt = new_p, new_o


def _same(a, b) -> bool:
    leaves = jax.tree_util.tree_leaves
    return all(np.array_equal(x, y) for x, y in zip(leaves(a), leaves(b)))


def test_policy_delay_skips_policy_and_its_targets_off_step():
    """TD3 with policy_delay 2 (traced step): odd steps leave π, its Adam state, Q̄ and π̄ as they were and
    report actor_loss 0; even steps move them; ψ̄, ζ̄ move every step."""
    algo = make_algorithm("td3", SF2Config.small(D, A, policy_delay=2), representations.get("sf2"))
    params, opt = algo.init(jax.random.PRNGKey(0))
    step = jax.jit(algo.sgd_step)
    for i in range(3):
        batch = _batch(jax.random.PRNGKey(20 + i))
        new_p, new_o, metrics = step(params, opt, batch, algo.step_noise(jax.random.PRNGKey(i), batch),
                                     jnp.asarray(i, jnp.int32))
        actor = i % 2 == 0
        for g in ("policy", "target_q", "target_policy"):
            assert _same(params[g], new_p[g]) == (not actor), (i, g)
        assert _same(opt["policy"], new_o["policy"]) == (not actor)
        assert (float(metrics["actor_loss"]) != 0.0) == actor
        assert not _same(params["target_psi"], new_p["target_psi"])
        params, opt = new_p, new_o


@pytest.mark.parametrize("every,message", [({"q": 2}, "not one of its aux_groups"),
                                           ({"zeta": 0}, "must be an int >= 1")])
def test_aux_every_is_validated(every, message):
    bad = type("Bad", (representations.SF2Representation,), {"aux_every": every})
    with pytest.raises(ValueError, match=message):
        make_algorithm("td3", SF2Config.small(D, A), bad)


@pytest.mark.parametrize("shared", [True, False])
def test_psi_adam_state_shared_or_one_per_loss(shared):
    """`shared_adam` (the authors' way, True): ψ's TD step and flow step share one Adam state. False: each
    loss has its own, so from fresh states the flow step is Adam's first step, Δψ = −lr·g/(|g| + ε)
    (bias correction is exact at t = 1): every element moves by lr·|g|/(|g| + ε) ≤ lr. ψ after the critic
    step alone (ψ₁) is Adam's first step on the TD gradient, derived here from `critic_loss`."""
    cfg = SF2Config.small(D, A, gamma_su=0.9, shared_adam=shared)
    algo = make_algorithm("td3", cfg, representations.get("sf2"))
    params, opt = algo.init(jax.random.PRNGKey(0))
    assert set(opt) == {"q", "psi", "zeta", "policy"} | (set() if shared else {"psi:aux"})
    batch = _batch(jax.random.PRNGKey(1))
    noise = algo.step_noise(jax.random.PRNGKey(2), batch)
    g_td = jax.grad(lambda psi: algo.critic_loss({**params, "psi": psi}, batch, noise)[0])(params["psi"])
    lr, eps = cfg.learning_rate, cfg.adam_eps
    psi1 = jax.tree_util.tree_map(lambda p, g: p - lr * g / (jnp.abs(g) + eps), params["psi"], g_td)
    new, opt, _ = jax.jit(algo.sgd_step)(params, opt, batch, noise, 0)
    counts = {k: int(v[0].count) for k, v in opt.items()}
    assert counts == ({"q": 1, "psi": 2, "zeta": 1, "policy": 1} if shared
                      else {"q": 1, "psi": 1, "psi:aux": 1, "zeta": 1, "policy": 1})
    steps = np.concatenate([np.abs(np.ravel(a - b)) for a, b in zip(
        jax.tree_util.tree_leaves(new["psi"]), jax.tree_util.tree_leaves(psi1))])
    at_lr = np.mean(np.isclose(steps, lr, rtol=1e-2))
    if shared:
        assert at_lr < 0.5           # the shared moments blend both gradients: most steps are not lr
    else:
        assert steps.max() <= lr * (1 + 1e-3) and at_lr > 0.9   # 1e-3: float32 rounding of ψ − ψ₁


def _sac_step_by_hand(algo, params, opt, batch, noise, draws, step):
    """SAC+SF²'s SGD step composed from the core's flow loss and optax (the critic and policy losses are the
    agent's, tested above): critic Adam step at `params`; one flow step per entry of `draws` (ā′ = π(s′)
    with the draw's flow_action_noise at the pre-step policy, then Adam on ψ with `aux_states`' state and on
    ζ); the policy and temperature steps from the pre-step gradients; Q̄, ψ̄, ζ̄ EMA. Returns (params,
    opt_state, flow losses)."""
    import optax

    cfg, nets = algo.cfg, algo.nets
    adam, alpha_adam = optax.adam(cfg.learning_rate, eps=cfg.adam_eps), optax.adam(cfg.alpha_learning_rate)
    p, s = dict(params), dict(opt)

    def apply(group, grad, state, tx=adam):
        upd, s[state] = tx.update(grad, s[state], p[group])
        p[group] = optax.apply_updates(p[group], upd)

    grads = _grads(lambda q: algo.critic_loss(q, batch, noise), params, ("q", "psi"))
    for g in ("q", "psi"):
        apply(g, grads[g], g)
    flow = []
    for draw in draws:
        next_action = networks.sac_sample(nets, params, batch.next_obs, draw["flow_action_noise"])[0]

        def loss(q, a=next_action, d=draw):
            return losses.flow_loss(nets, q, batch, a, d["flow_noise"], d["flow_time"])

        flow.append(loss(p)[0])
        grads = _grads(loss, p, ("psi", "zeta"))
        for g in ("psi", "zeta"):
            apply(g, grads[g], algo.aux_states[g])
    for g, (_, fn) in algo.policy_losses(params, batch, noise).items():
        apply(g, _grads(fn, params, (g,))[g], g, alpha_adam if g == "log_alpha" else adam)
    for t, (o, tau) in {"target_q": ("q", cfg.tau), "target_psi": ("psi", cfg.tau),
                        "target_zeta": ("zeta", cfg.tau_zeta)}.items():
        p[t] = losses.ema_update(p[t], p[o], tau)
    return p, s, flow


def test_aux_steps_per_sgd_step_repeats_the_flow_step_with_its_own_draws():
    """`aux_steps_per_sgd_step` = k: step 3 (the representation's loss and Adam step) k times on the step's
    minibatch, draw j's noise (ā′'s, the flow's) under "<key>:more"; the first draw is k = 1's. In float64
    from non-fresh Adam states, k = 2 equals two flow steps composed by hand with the two draws and k = 1
    one (the step as it was, same noise keys), to 1e-10; the reported flow loss is the first step's. ψ's
    flow steps have their own Adam state (`shared_adam = False`, the carried state that is not the group's
    name); the shared one is the cross-framework test's k = 2 case."""
    shared = False
    with jax.enable_x64(True):
        cfg = SF2Config.small(D, A, gamma_su=0.9, shared_adam=shared)
        one = make_algorithm("sac", cfg, representations.get("sf2"), dtype=jnp.float64)
        two = make_algorithm("sac", cfg.replace(aux_steps_per_sgd_step=2), representations.get("sf2"),
                             dtype=jnp.float64)
        assert one.noise_keys() == ("next_action_noise", "actor_noise", "alpha_noise", "flow_action_noise",
                                    "flow_noise", "flow_time")
        more = ("flow_action_noise:more", "flow_noise:more", "flow_time:more")
        assert two.noise_keys() == one.noise_keys() + more
        params, opt = one.init(jax.random.PRNGKey(0))
        f64 = jax.tree_util.tree_map(lambda x: x.astype(jnp.float64), _batch(jax.random.PRNGKey(1)))
        step1, step2 = jax.jit(one.sgd_step), jax.jit(two.sgd_step)
        params, opt, _ = step1(params, opt, f64, one.step_noise(jax.random.PRNGKey(2), f64), 0)
        batch = jax.tree_util.tree_map(lambda x: x.astype(jnp.float64), _batch(jax.random.PRNGKey(3)))
        noise1, noise2 = (a.step_noise(jax.random.PRNGKey(4), batch) for a in (one, two))
        assert list(noise2) == list(two.noise_keys())
        for k in one.noise_keys():
            np.testing.assert_array_equal(noise1[k], noise2[k])
        for k in more:
            assert noise2[k].shape == (1, *noise1[k.split(":")[0]].shape) and noise2[k].dtype == jnp.float64
            assert not np.array_equal(noise2[k][0], noise1[k.split(":")[0]])
        draws = [{k: noise1[k] for k in one.aux_noise_keys()},
                 {k: noise2[f"{k}:more"][0] for k in one.aux_noise_keys()}]
        for algo, step, noise, n in ((one, step1, noise1, 1), (two, step2, noise2, 2)):
            got_p, got_s, metrics = step(params, opt, batch, noise, 1)
            want_p, want_s, flow = jax.jit(lambda p, s, d, a=algo, n=noise: _sac_step_by_hand(
                a, p, s, batch, n, d, 1))(params, opt, draws[:n])
            assert set(got_p) == set(want_p) and set(got_s) == set(want_s) == set(opt)
            _close((got_p, got_s), (want_p, want_s), tol=1e-10)
            np.testing.assert_allclose(metrics["flow_loss"], flow[0], rtol=1e-10)
            counts = {k: int(v[0].count) for k, v in got_s.items()}
            assert counts["zeta"] == int(opt["zeta"][0].count) + n
            assert counts["psi"] == int(opt["psi"][0].count) + (1 + n if shared else 1)
        # the second flow step moved ζ beyond the first
        assert not _same(step1(params, opt, batch, noise1, 1)[0]["zeta"],
                         step2(params, opt, batch, noise2, 1)[0]["zeta"])


def test_aux_steps_per_sgd_step_is_one_loop_and_needs_an_aux_loss():
    """k representation steps are one `scan` of k − 1 iterations after the first, so the traced program's
    size does not grow with k; a representation without its own loss (`none`) refuses k > 1."""
    def size_and_scans(k):
        cfg = SF2Config.small(D, A, aux_steps_per_sgd_step=k)
        algo = make_algorithm("td3", cfg, representations.get("sf2"))
        params, opt = jax.eval_shape(algo.init, jax.random.PRNGKey(0))
        batch = _batch(jax.random.PRNGKey(1))
        noise = jax.eval_shape(algo.step_noise, jax.random.PRNGKey(2), batch)
        assert all(noise[f"{key}:more"].shape[:2] == (k - 1, B) for key in algo.aux_noise_keys() if k > 1)
        jaxpr = jax.make_jaxpr(algo.sgd_step)(params, opt, batch, noise, jnp.int32(0)).jaxpr
        scans = [e.params["length"] for e in jaxpr.eqns if e.primitive.name == "scan"]
        return len(jaxpr.eqns), scans

    assert size_and_scans(1)[1] == []
    (n2, scans2), (n8, scans8) = size_and_scans(2), size_and_scans(8)
    assert n2 == n8 and scans2 == [1] and scans8 == [7]
    from sf2_common.errors import ConfigError

    with pytest.raises(ConfigError, match="aux_steps_per_sgd_step = 2 is invalid: must be 1 with "
                       "representation 'none', which has no loss of its own"):
        make_algorithm("sac", SF2Config.small(D, A, aux_steps_per_sgd_step=2), representations.get("none"))
