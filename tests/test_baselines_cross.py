"""JAX and torch baselines (sf2_baselines: Sim, SimLap, SPR) compute the same numbers.

Same method as the core's suite: one canonical parameter file per (method, config, algo), built from the
JAX initializer with every entry redrawn so that nothing sits at a default, loaded into both
frameworks; identical batch and explicit noise; float64 to 1e-10 relative, float32 to cross_bridge.TOL. Each
loss's value, aux and the gradient of every trained group are compared in canonical layout (JAX:
`jax.grad` with respect to the trained groups; torch: `backward(inputs=...)` with their parameters), and
every other parameter is checked to get no gradient in torch. The TD3/SAC losses are the cores' on the
baseline's critic (`critic=`), as the agents train them; the agents' full SGD steps are compared too.
"""

from __future__ import annotations

import functools

import jax
import numpy as np
import optax
import pytest
import torch
from cross_bridge import canonical_values, check, jbatch, jx, make_batch, np_, tbatch, th

pytest.importorskip("sf2_baselines")
import sf2_baselines.jax as bj  # noqa: E402
import sf2_baselines.torch as bt  # noqa: E402
import sf2_jax  # noqa: E402
import sf2_torch  # noqa: E402

SIZES = [dict(obs_size=5, action_size=1), dict(obs_size=3, action_size=2), dict(obs_size=8, action_size=4)]
BATCH = 16


def small(obs_size, action_size, **kw):
    base = dict(
        obs_size=obs_size,
        action_size=action_size,
        feature_size=16,
        hidden_sizes=(32, 32),
        q_hidden_size=24,
        zeta_hidden_sizes=(32, 32),
        embedding_size=8,
    )
    base.update(kw)
    return base


METHOD = {"sim": (bj.sim, bt.sim), "simlap": (bj.simlap, bt.simlap), "spr": (bj.spr, bt.spr)}


def canonical_file(tmp_path, method, cfg_kwargs, algo, seed=0):
    """A canonical file of `method`'s networks (names and shapes from `expected_shapes`) with every entry
    non-trivial (`cross_bridge.canonical_values`)."""
    jmod = METHOD[method][0]
    shapes = bj.params.expected_shapes(jmod.make_networks(sf2_jax.SF2Config(**cfg_kwargs), algo))
    out = canonical_values(shapes, seed)
    path = tmp_path / f"{method}-{algo}-{seed}.npz"
    bj.params.save(path, out)
    return path


def build_pair(path, method, cfg_kwargs, algo, dtype):
    jmod, tmod = METHOD[method]
    jn = jmod.make_networks(sf2_jax.SF2Config(**cfg_kwargs), algo)
    jp = bj.params.from_canonical(bj.params.load(path), jn, dtype=getattr(jax.numpy, dtype))
    tn = tmod.make_networks(sf2_torch.SF2Config(**cfg_kwargs), algo).to(getattr(torch, dtype))
    bt.params.from_canonical(bt.params.load(path), tn)
    return jn, jp, tn


def compare_loss(term, dtype, jax_fn, jparams_all, groups, torch_fn, tnets):
    """One loss in both frameworks: value, aux, gradient of every trained group; zero gradient elsewhere."""

    def f(sub):
        return jax_fn({**jparams_all, **sub})

    # one jit per case: eager JAX compiles every primitive on its own
    (jloss, jaux), jgrads = jax.jit(jax.value_and_grad(f, has_aux=True))({g: jparams_all[g] for g in groups})
    tnets.zero_grad(set_to_none=True)
    tloss, taux = torch_fn()
    tloss.backward(inputs=[p for g in groups for p in (
        [tnets.log_alpha] if g == "log_alpha" else getattr(tnets, g).parameters())])
    check(term, np_(jloss), np_(tloss), dtype)
    assert set(jaux) == set(taux), f"{term}: aux keys differ {sorted(jaux)} vs {sorted(taux)}"
    for key in jaux:
        # aux metrics are batch means of signed terms (mean Q, mean cosine) that can cancel: in float32
        # they get the gradient tolerance; float64 stays at 1e-10.
        check(f"{term}.{key}", np_(jaux[key]), np_(taux[key]), dtype, kind="grad")
    jflat = bj.params.to_canonical(jgrads)
    tflat = bt.params.to_canonical(tnets, grads=True)
    assert jflat, f"{term}: no gradient computed"
    for name, g in jflat.items():
        check(f"grad {term}", g, tflat[name], dtype, kind="grad")
    assert any(np.any(g != 0) for g in jflat.values()), f"{term}: every gradient is zero"
    for name, g in tflat.items():
        if name not in jflat:
            assert not np.any(np_(g)), (
                f"{term}: torch put a gradient into {name}, which this loss must not train"
            )
    return float(np_(jloss))


def _setup(tmp_path, method, algo, dtype, seed, truncation, **kw):
    cfg_kwargs = small(**SIZES[seed % len(SIZES)], **kw)
    path = canonical_file(tmp_path, method, cfg_kwargs, algo, seed=seed)
    jn, jp, tn = build_pair(path, method, cfg_kwargs, algo, dtype)
    batch, noise = make_batch(cfg_kwargs, BATCH, seed=seed, truncation=truncation)
    noise["next_eps"] = np.random.default_rng(7000 + seed).normal(size=batch["obs"].shape)
    return jn, jp, tn, batch, noise


DTYPES = ["float64", "float32"]
ALGOS = ["td3", "sac"]


# ------------------------------------------------------------------------------------------- networks
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("algo", ALGOS)
@pytest.mark.parametrize("method", ["sim", "spr"])
def test_critic_and_features(tmp_path, dtype, algo, method):
    jn, jp, tn, batch, noise = _setup(tmp_path, method, algo, dtype, seed=1, truncation=False)
    jmod, tmod = METHOD[method]
    obs, act = batch["obs"], batch["action"]
    with torch.no_grad():
        for target in (False, True):
            check(
                f"{method} features",
                np_(jmod.features(jn, jp, jx(obs, dtype), jx(act, dtype), target)),
                np_(tmod.features(tn, th(obs, dtype), th(act, dtype), target)),
                dtype,
            )
            check(
                f"{method} critic",
                np_(jmod.critic(jn, jp, jx(obs, dtype), jx(act, dtype), target)),
                np_(tmod.critic(tn, th(obs, dtype), th(act, dtype), target)),
                dtype,
            )
        if method == "sim":
            phi = jmod.features(jn, jp, jx(obs, dtype), jx(act, dtype))
            tphi = tmod.features(tn, th(obs, dtype), th(act, dtype))
            check(
                "sim successor_features",
                np_(jmod.successor_features(jn, jp, phi)),
                np_(tmod.successor_features(tn, tphi)),
                dtype,
            )
        else:
            z = jmod.features(jn, jp, jx(obs, dtype), jx(act, dtype), obs_noise=jx(noise["eps"], dtype))
            tz = tmod.features(tn, th(obs, dtype), th(act, dtype), obs_noise=th(noise["eps"], dtype))
            check("spr augmented features", np_(z), np_(tz), dtype)
            check(
                "spr projection+prediction",
                np_(jmod.predict(jn, jp, jmod.project(jn, jp, z))),
                np_(tmod.predict(tn, tmod.project(tn, tz))),
                dtype,
            )


# ------------------------------------------------------------------------------------------- Sim / SimLap
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("algo", ALGOS)
@pytest.mark.parametrize("truncation", [False, True])
def test_reward_loss(tmp_path, dtype, algo, truncation):
    jn, jp, tn, batch, noise = _setup(
        tmp_path, "sim", algo, dtype, seed=2 + truncation, truncation=truncation
    )
    na = noise["next_action"]
    loss = compare_loss(
        "sim.reward_loss",
        dtype,
        lambda p: bj.sim.reward_loss(jn, p, jbatch(batch, dtype), jx(na, dtype)),
        jp,
        ("task",),
        lambda: bt.sim.reward_loss(tn, tbatch(batch, dtype), th(na, dtype)),
        tn,
    )
    assert loss > 0


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("algo", ALGOS)
@pytest.mark.parametrize("truncation", [False, True])
def test_laplacian_and_simlap_loss(tmp_path, dtype, algo, truncation):
    jn, jp, tn, batch, noise = _setup(
        tmp_path, "simlap", algo, dtype, seed=4 + truncation, truncation=truncation
    )
    na = noise["next_action"]
    compare_loss(
        "simlap.laplacian_loss",
        dtype,
        lambda p: bj.simlap.laplacian_loss(jn, p, jbatch(batch, dtype), jx(na, dtype)),
        jp,
        ("phi",),
        lambda: bt.simlap.laplacian_loss(tn, tbatch(batch, dtype), th(na, dtype)),
        tn,
    )
    compare_loss(
        "simlap.simlap_loss",
        dtype,
        lambda p: bj.simlap.simlap_loss(jn, p, jbatch(batch, dtype), jx(na, dtype)),
        jp,
        ("phi", "task"),
        lambda: bt.simlap.simlap_loss(tn, tbatch(batch, dtype), th(na, dtype)),
        tn,
    )


def _rl_losses(name, jmod, tmod, jn, jp, tn, batch, noise, algo, dtype, critic_groups):
    """The cores' TD3/SAC critic and actor losses on the baseline's critic (`critic=`), in both
    frameworks: value, aux and the gradients of `critic_groups` (critic) and the policy (actor)."""
    jb, tb = jbatch(batch, dtype), tbatch(batch, dtype)
    xi = noise["smoothing"] if algo == "td3" else noise["noise"]
    jcritic, tcritic = functools.partial(jmod.critic, jn), functools.partial(tmod.critic, tn)
    jl, tl = sf2_jax.losses, sf2_torch.losses
    compare_loss(
        f"{name}: {algo}_critic_loss",
        dtype,
        lambda p: getattr(jl, f"{algo}_critic_loss")(jn.core, p, jb, jx(xi, dtype), critic=jcritic),
        jp,
        critic_groups,
        lambda: getattr(tl, f"{algo}_critic_loss")(tn, tb, th(xi, dtype), critic=tcritic),
        tn,
    )
    extra_j, extra_t = ([], []) if algo == "td3" else ([jx(xi, dtype)], [th(xi, dtype)])
    compare_loss(
        f"{name}: {algo}_actor_loss",
        dtype,
        lambda p: getattr(jl, f"{algo}_actor_loss")(jn.core, p, jb, *extra_j, critic=jcritic),
        jp,
        ("policy",),
        lambda: getattr(tl, f"{algo}_actor_loss")(tn, tb, *extra_t, critic=tcritic),
        tn,
    )


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("algo", ALGOS)
@pytest.mark.parametrize("critic_groups", [("q", "phi"), ("q",)], ids=["sim", "simlap"])
def test_sim_critic_and_actor_losses(tmp_path, dtype, algo, critic_groups):
    """Sim's critic trained as `sim` and `simlap_authors` (Q heads and φ) and as `simlap` (Q heads)."""
    jn, jp, tn, batch, noise = _setup(tmp_path, "sim", algo, dtype, seed=6 + len(critic_groups),
                                      truncation=True)
    _rl_losses("sim", bj.sim, bt.sim, jn, jp, tn, batch, noise, algo, dtype, critic_groups)


# ------------------------------------------------------------------------------------------- SPR
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("algo", ALGOS)
@pytest.mark.parametrize("truncation", [False, True])
def test_spr_loss(tmp_path, dtype, algo, truncation):
    jn, jp, tn, batch, noise = _setup(
        tmp_path, "spr", algo, dtype, seed=8 + truncation, truncation=truncation
    )
    keys = ("next_action", "eps", "next_eps")
    loss = compare_loss(
        "spr.spr_loss",
        dtype,
        lambda p: bj.spr.spr_loss(jn, p, jbatch(batch, dtype), *[jx(noise[k], dtype) for k in keys]),
        jp,
        ("encoder", "projection", "prediction"),
        lambda: bt.spr.spr_loss(tn, tbatch(batch, dtype), *[th(noise[k], dtype) for k in keys]),
        tn,
    )
    assert 0 < loss < 4


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("algo", ALGOS)
def test_spr_critic_and_actor_losses(tmp_path, dtype, algo):
    jn, jp, tn, batch, noise = _setup(tmp_path, "spr", algo, dtype, seed=10, truncation=True)
    _rl_losses("spr", bj.spr, bt.spr, jn, jp, tn, batch, noise, algo, dtype, ("q", "encoder"))


# ------------------------------------------------------------------------------------------- optimizer steps
STEP_CASES = {
    # method: (aux loss name, trained groups, targets {target group: online group})
    "simlap": ("simlap_loss", ("phi", "task"), {"target_phi": "phi"}),
    "spr": (
        "spr_loss",
        ("encoder", "projection", "prediction"),
        {"target_encoder": "encoder", "target_projection": "projection"},
    ),
}


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("method", list(STEP_CASES))
def test_aux_adam_and_ema_steps(tmp_path, dtype, method):
    """Three Adam steps on the representation's loss (one Adam state per group, as the agents keep them)
    and EMA targets leave both frameworks with the same parameters."""
    loss_name, groups, targets = STEP_CASES[method]
    jn, jp, tn, _, _ = _setup(tmp_path, method, "td3", dtype, seed=12, truncation=False)
    jmod, tmod = METHOD[method]
    cfg = jn.cfg
    opt = optax.adam(cfg.learning_rate, eps=cfg.adam_eps)
    jopt = {g: opt.init(jp[g]) for g in groups}
    topt = {
        g: torch.optim.Adam(getattr(tn, g).parameters(), lr=cfg.learning_rate, eps=cfg.adam_eps)
        for g in groups
    }
    kw = small(**SIZES[12 % len(SIZES)])
    for step in range(3):
        batch, noise = make_batch(kw, BATCH, seed=200 + step, truncation=step == 1)
        noise["next_eps"] = np.random.default_rng(300 + step).normal(size=batch["obs"].shape)
        keys = ("next_action", "eps", "next_eps") if method == "spr" else ("next_action",)

        def f(sub, batch=batch, noise=noise, keys=keys, jp=jp):
            return getattr(jmod, loss_name)(
                jn, {**jp, **sub}, jbatch(batch, dtype), *[jx(noise[k], dtype) for k in keys]
            )

        _, grads = jax.value_and_grad(f, has_aux=True)({g: jp[g] for g in groups})
        for g in groups:
            updates, jopt[g] = opt.update(grads[g], jopt[g])
            jp = {**jp, g: optax.apply_updates(jp[g], updates)}
        for t, o in targets.items():
            jp[t] = sf2_jax.losses.ema_update(jp[t], jp[o], cfg.tau)

        for o in topt.values():
            o.zero_grad(set_to_none=True)
        loss, _ = getattr(tmod, loss_name)(tn, tbatch(batch, dtype), *[th(noise[k], dtype) for k in keys])
        loss.backward()
        for o in topt.values():
            o.step()
        for t, o in targets.items():
            sf2_torch.losses.ema_update(getattr(tn, t), getattr(tn, o), cfg.tau)

    jflat, tflat = bj.params.to_canonical(jp), bt.params.to_canonical(tn)
    assert set(jflat) == set(tflat)
    moved = 0
    for name in jflat:
        check(f"{method} params after 3 Adam+EMA steps", jflat[name], tflat[name], dtype, kind="grad")
        moved += name.split(".")[0] in (*groups, *targets)
    assert moved > 0


def test_canonical_names_agree():
    """Both frameworks name and shape every entry identically, for every method and algo."""
    for method, (jmod, tmod) in METHOD.items():
        for algo in ALGOS:
            kw = small(**SIZES[0])
            jshapes = bj.params.expected_shapes(jmod.make_networks(sf2_jax.SF2Config(**kw), algo))
            tshapes = bt.params.expected_shapes(tmod.make_networks(sf2_torch.SF2Config(**kw), algo))
            assert jshapes == tshapes, f"{method}/{algo}: {set(jshapes) ^ set(tshapes)}"


# ------------------------------------------------------------------------------------------- agents
AGENT_CASES = [(name, algo) for name in ("sim", "simlap", "simlap_authors", "spr") for algo in ALGOS]


def _check_task_adam(name, jopt, talg, dtype, updates: int) -> None:
    """w's Adam state has taken `updates` steps in both frameworks, with equal moments."""
    adam = jopt["task"][0]
    st = talg.optimizers["task"].state.get(talg._params(("task",))[0], {})
    assert int(adam.count) == updates
    if updates == 0:  # torch creates the state on the first step
        assert not st and not np.any(np.asarray(adam.mu["w"])) and not np.any(np.asarray(adam.nu["w"]))
        return
    assert int(st["step"]) == updates
    for k, tk in (("mu", "exp_avg"), ("nu", "exp_avg_sq")):
        jv = np.asarray(getattr(adam, k)["w"])
        check(f"agent step {name}: w adam {k}", jv, st[tk].numpy(), dtype, kind="grad")


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("name,algo", AGENT_CASES)
def test_agent_sgd_steps(tmp_path, dtype, name, algo):
    """Three SGD steps of the agents (sf2_jax's jitted `sgd_step`, sf2_torch's `sgd_step`) with each
    baseline, from one canonical file, fresh Adam states, the same batches and the noise of sf2_jax's
    `step_noise`, leave every parameter and target identical. The step indices P − 1, P, P + 1 (P = 10
    TD3, 16 SAC) span a period of the task-vector schedule (`aux_every`): w and its Adam state (moments,
    step count) move at P only, in both frameworks."""
    jalgs = pytest.importorskip("sf2_jax.agents.algorithms")
    talgs = pytest.importorskip("sf2_torch.agents.algorithms")
    from sf2_jax.agents import representations as jreps
    from sf2_torch import params as tparams
    from sf2_torch.agents import representations as treps

    jdt, tdt = getattr(jax.numpy, dtype), getattr(torch, dtype)
    kw = small(obs_size=5, action_size=2)
    method = "spr" if name == "spr" else "sim"
    path = canonical_file(tmp_path, method, kw, algo, seed=31)

    jalg = jalgs.make_algorithm(algo, sf2_jax.SF2Config(**kw), jreps.get(name), dtype=jdt)
    jp = bj.params.from_canonical(bj.params.load(path), jalg.rep.baseline_nets, dtype=jdt)
    cfg = jalg.cfg
    adam = optax.adam(cfg.learning_rate, eps=cfg.adam_eps)
    jopt = {g: (optax.adam(cfg.alpha_learning_rate) if g == "log_alpha" else adam).init(jp[g])
            for g in jalg.trained_groups()}  # fmt: skip
    jstep = jax.jit(jalg.sgd_step)

    talg = talgs.make_algorithm(algo, sf2_torch.SF2Config(**kw), treps.get(name), dtype=tdt)
    tparams.from_canonical(bt.params.load(path), talg.groups)  # the agent's groups: the same names
    assert set(talg.groups) == set(jp) and talg.trained_groups() == jalg.trained_groups()
    assert jalg.rep.aux_every == talg.rep.aux_every
    assert jalg.noise_keys() == talg.noise_keys()

    period = {"td3": 10, "sac": 16}[algo]
    first = tparams.to_canonical(talg.groups)
    for i, step in enumerate((period - 1, period, period + 1)):
        raw, _ = make_batch(kw, BATCH, seed=400 + i, truncation=i == 1)
        jb = sf2_jax.losses.Batch(**{k: jax.numpy.asarray(v, dtype=jdt) for k, v in raw.items()})
        noise = jalg.step_noise(jax.random.PRNGKey(50 + i), jb)
        assert list(noise) == list(talg.noise_keys())
        w_before = tparams.to_canonical(talg.groups).get("task.w")
        jp, jopt, jm = jstep(jp, jopt, jb, noise, step)
        tb = sf2_torch.losses.Batch(**{k: torch.as_tensor(np.asarray(v), dtype=tdt) for k, v in raw.items()})
        tm = talg.sgd_step(tb, {k: torch.as_tensor(np.array(v)) for k, v in noise.items()}, step)
        jflat, tflat = bj.params.to_canonical(jp), tparams.to_canonical(talg.groups)
        assert set(jflat) == set(tflat)
        for pname in sorted(jflat):
            check(f"agent step {name}: {pname.split('.')[0]}", jflat[pname], tflat[pname], dtype, kind="grad")
        assert set(jm) == set(tm), (sorted(jm), sorted(tm))
        for m in jm:
            check(f"agent step {name}: metric", np.asarray(jm[m]), tm[m].numpy(), dtype, kind="grad")
        if "task" in talg.rep.aux_every:
            assert (not np.array_equal(w_before, tflat["task.w"])) == (step == period), step
            _check_task_adam(name, jopt, talg, dtype, updates=int(step >= period))
    last = tparams.to_canonical(talg.groups)
    for group in set(jalg.trained_groups()) | {g for g in jp if g.startswith("target_")}:
        assert any(not np.array_equal(first[n], last[n]) for n in first if n.split(".")[0] == group), group
