"""JAX and torch agree on every loss term and every parameter gradient (contract: docs/core-contract.md).

One canonical file → both cores; identical batch and explicit noise; float64 to 1e-10 relative, float32
to the tolerance in cross_bridge.TOL. Gradients are taken as the agents take them: JAX `jax.grad` with
respect to the trained groups, torch `loss.backward(inputs=...)` with the trained groups' parameters;
they are compared entry by entry in canonical layout, and every other parameter (targets, networks the
loss reads but does not train) is checked to receive no gradient in torch. The TD3/SAC losses run with the
`critic` keyword (each core's `sf2_critic`, the path the agents train with) and with the default.
"""

from __future__ import annotations

import itertools

import jax
import numpy as np
import pytest
import sf2_jax
import sf2_torch
from cross_bridge import build_pair, canonical_file, check, jbatch, jx, make_batch, np_, tbatch, th
from sf2_jax import params as jparams
from sf2_torch import params as tparams

SIZES = [dict(obs_size=5, action_size=1), dict(obs_size=3, action_size=2), dict(obs_size=8, action_size=4)]
BATCH = 16


def small(obs_size, action_size, **kw):
    base = dict(
        obs_size=obs_size,
        action_size=action_size,
        feature_size=16,
        hidden_sizes=(32, 32),
        q_hidden_size=32,
        zeta_hidden_sizes=(32, 32),
        embedding_size=8,
    )
    base.update(kw)
    return base


def _torch_params(tnets, groups):
    """The parameters of `groups` of torch `Networks` (what `backward(inputs=...)` trains)."""
    return [p for g in groups
            for p in ([tnets.log_alpha] if g == "log_alpha" else getattr(tnets, g).parameters())]


def compare_loss(term, dtype, jax_fn, jparams_all, groups, torch_fn, tnets):
    """Run one loss in both cores; compare value, aux and the gradient of every trained group."""

    def f(sub):
        return jax_fn({**jparams_all, **sub})

    # One jit per case: eager JAX would compile every primitive on its own (~80 ms each on this CPU).
    grad_fn = jax.jit(jax.value_and_grad(f, has_aux=True))
    (jloss, jaux), jgrads = grad_fn({g: jparams_all[g] for g in groups})
    tnets.zero_grad(set_to_none=True)
    tloss, taux = torch_fn()
    tloss.backward(inputs=_torch_params(tnets, groups))
    check(term, np_(jloss), np_(tloss), dtype)
    assert set(jaux) == set(taux), f"{term}: aux keys differ {sorted(jaux)} vs {sorted(taux)}"
    for key in jaux:
        check(f"{term}.{key}", np_(jaux[key]), np_(taux[key]), dtype)
    jflat = jparams.to_canonical(jgrads)
    tflat = tparams.to_canonical(tnets, grads=True)
    assert jflat, f"{term}: no gradient computed"
    for name, g in jflat.items():
        check(f"grad {term}", g, tflat[name], dtype, kind="grad")
    for name, g in tflat.items():
        if name not in jflat:
            assert not np.any(np_(g)), (
                f"{term}: torch put a gradient into {name}, which this loss must not train"
            )
    return float(np_(jloss))


FLOW_GRID = list(itertools.product([1, 2, 4], ["midpoint", "euler"], [0.0, 0.99], [False, True]))


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("steps,integrator,gamma_su,truncation", FLOW_GRID)
def test_flow_loss(tmp_path, dtype, steps, integrator, gamma_su, truncation):
    sizes = SIZES[(steps + int(truncation)) % len(SIZES)]
    kw = small(**sizes, denoising_steps=steps, integrator=integrator, gamma_su=gamma_su)
    path = canonical_file(tmp_path, kw, "td3", seed=steps)
    jn, jp, tn = build_pair(path, kw, "td3", dtype)
    batch, noise = make_batch(kw, BATCH, seed=steps, truncation=truncation)
    jb, tb = jbatch(batch, dtype), tbatch(batch, dtype)
    args_j = [jx(noise[k], dtype) for k in ("next_action", "eps", "flow_time")]
    args_t = [th(noise[k], dtype) for k in ("next_action", "eps", "flow_time")]
    loss = compare_loss(
        "flow_loss",
        dtype,
        lambda p: sf2_jax.losses.flow_loss(jn, p, jb, *args_j),
        jp,
        ("psi", "zeta"),
        lambda: sf2_torch.losses.flow_loss(tn, tb, *args_t),
        tn,
    )
    assert np.isfinite(loss) and loss > 0


@pytest.mark.parametrize("jax_fast,torch_fast", [(True, False), (False, True)])
def test_fast_path_across_frameworks(tmp_path, jax_fast, torch_fast):
    """The contracted ζ algebra in one framework equals the plain oracle in the other (float64)."""
    kw = small(**SIZES[2], denoising_steps=2)
    path = canonical_file(tmp_path, kw, "sac", seed=7)
    jn, jp, _ = build_pair(path, dict(kw, contract_zeta=jax_fast), "sac", "float64")
    _, _, tn = build_pair(path, dict(kw, contract_zeta=torch_fast), "sac", "float64")
    batch, noise = make_batch(kw, BATCH, seed=7, truncation=True)
    keys = ("next_action", "eps", "flow_time")
    compare_loss(
        "flow_loss fast-vs-plain",
        "float64",
        lambda p: sf2_jax.losses.flow_loss(
            jn, p, jbatch(batch, "float64"), *[jx(noise[k], "float64") for k in keys]
        ),
        jp,
        ("psi", "zeta"),
        lambda: sf2_torch.losses.flow_loss(
            tn, tbatch(batch, "float64"), *[th(noise[k], "float64") for k in keys]
        ),
        tn,
    )


CRITIC_CASES = [
    ("td3_critic_loss", "td3", ("q", "psi"), "smoothing"),
    ("td3_actor_loss", "td3", ("policy",), None),
    ("sac_critic_loss", "sac", ("q", "psi"), "noise"),
    ("sac_actor_loss", "sac", ("policy",), "noise"),
    ("sac_alpha_loss", "sac", ("log_alpha",), "noise"),
]


RL_GRID = [(dtype, truncation, sizes, "critic=") for dtype in ("float64", "float32")
           for truncation in (False, True) for sizes in SIZES]
RL_GRID += [("float64", True, SIZES[1], "default")]   # the default critic (None): SF²'s, in both cores


@pytest.mark.parametrize("dtype,truncation,sizes,via", RL_GRID, ids=[
    f"{d}-trunc{int(t)}-D{s['obs_size']}A{s['action_size']}-{v}" for d, t, s, v in RL_GRID])
@pytest.mark.parametrize("name,algo,groups,noise_key", CRITIC_CASES, ids=[c[0] for c in CRITIC_CASES])
def test_rl_losses(tmp_path, dtype, truncation, sizes, via, name, algo, groups, noise_key):
    kw = small(**sizes)
    path = canonical_file(tmp_path, kw, algo, seed=3)
    jn, jp, tn = build_pair(path, kw, algo, dtype)
    batch, noise = make_batch(kw, BATCH, seed=3, truncation=truncation)
    jb, tb = jbatch(batch, dtype), tbatch(batch, dtype)
    extra_j = [] if noise_key is None else [jx(noise[noise_key], dtype)]
    extra_t = [] if noise_key is None else [th(noise[noise_key], dtype)]
    jkw, tkw = {}, {}
    if via == "critic=" and name != "sac_alpha_loss":   # the temperature loss reads no critic
        jkw, tkw = dict(critic=sf2_jax.losses.sf2_critic(jn)), dict(critic=sf2_torch.losses.sf2_critic(tn))
    jfn, tfn = getattr(sf2_jax.losses, name), getattr(sf2_torch.losses, name)
    loss = compare_loss(
        name,
        dtype,
        lambda p: jfn(jn, p, jb, *extra_j, **jkw),
        jp,
        groups,
        lambda: tfn(tn, tb, *extra_t, **tkw),
        tn,
    )
    assert np.isfinite(loss)


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_explicit_mixture_loss(dtype):
    """Appendix A.3 on a shared linear velocity field v(x, k) = x·W + k·b, parameters in both frameworks."""
    rng = np.random.default_rng(5)
    D, B = 3, 32
    W, b = rng.normal(size=(D, D)), rng.normal(size=D)
    data = [rng.normal(size=(B, D)) for _ in range(4)] + [rng.uniform(size=B), rng.uniform(size=B)]
    x1, x2, e1, e2, k1, k2 = data

    def jloss(Wj):
        v = lambda x, k: x @ Wj + k[:, None] * jx(b, dtype)  # noqa: E731
        return sf2_jax.losses.explicit_mixture_loss(v, *[jx(a, dtype) for a in data], 0.3)

    (jval, jaux), jg = jax.jit(jax.value_and_grad(jloss, has_aux=True))(jx(W, dtype))
    Wt = th(W, dtype).requires_grad_(True)
    v = lambda x, k: x @ Wt + k[:, None] * th(b, dtype)  # noqa: E731
    tval, taux = sf2_torch.losses.explicit_mixture_loss(v, *[th(a, dtype) for a in data], 0.3)
    tval.backward()
    check("explicit_mixture_loss", np_(jval), np_(tval), dtype)
    for key in jaux:
        check(f"explicit_mixture_loss.{key}", np_(jaux[key]), np_(taux[key]), dtype)
    check("grad explicit_mixture_loss", np_(jg), np_(Wt.grad), dtype, kind="grad")

    # And it is the weighted sum of the two plain flow-matching terms (A.3's last line).
    def fm(x, e, k):
        xk = k[:, None] * x + (1 - k[:, None]) * e
        return np.mean(np.sum((xk @ W + k[:, None] * b - (x - e)) ** 2, axis=-1))

    expected = 0.3 * fm(x1, e1, k1) + 0.7 * fm(x2, e2, k2)
    assert abs(float(np_(jval)) - expected) <= (1e-12 if dtype == "float64" else 1e-5) * abs(expected)
