"""Every network output agrees across frameworks when both load the same canonical file.

Sizes are drawn by hypothesis (observation, action, feature and hidden sizes, batch), so the canonical
naming, the (in, out) kernel layout and ζ's (D, F) reshape are checked on shapes nobody picked by hand.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from _bridge import build_pair, canonical_file, check, jx, np_, th
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sf2_jax import networks as jnet
from sf2_jax import ode as jode
from sf2_torch import networks as tnet
from sf2_torch import ode as tode

size_cases = st.fixed_dictionaries(
    dict(
        obs_size=st.integers(1, 9),
        action_size=st.integers(1, 4),
        feature_size=st.sampled_from([4, 8, 12]),
        hidden_sizes=st.sampled_from([(16,), (16, 8), (8, 8, 8)]),
        q_hidden_size=st.sampled_from([8, 16]),
        zeta_hidden_sizes=st.sampled_from([(8,), (16, 8)]),
        embedding_size=st.sampled_from([4, 8]),
        layer_norm=st.booleans(),
    )
)


def _outputs(kw, algo, dtype, batch_size, seed):
    with tempfile.TemporaryDirectory() as d:
        path = canonical_file(Path(d), kw, algo, seed=seed)
        jn, jp, tn = build_pair(path, kw, algo, dtype)
    rng = np.random.default_rng(seed)
    D, A = kw["obs_size"], kw["action_size"]
    obs, act = rng.normal(size=(batch_size, D)), rng.uniform(-1, 1, (batch_size, A))
    x, k = rng.normal(size=(batch_size, D)), rng.uniform(size=batch_size)
    noise = rng.normal(size=(batch_size, A))
    J = lambda a: jx(a, dtype)  # noqa: E731
    T = lambda a: th(a, dtype)  # noqa: E731
    out = {}
    out["normalize"] = (jnet.normalize(J(obs), jp["obs_norm"]), tnet.normalize(T(obs), tn.obs_norm))
    out["flow_time_embedding"] = (
        jnet.flow_time_embedding(J(k), kw["embedding_size"]), tnet.flow_time_embedding(T(k), kw["embedding_size"])
    )
    fj, ft = jnet.psi(jn, jp, J(obs), J(act)), tnet.psi(tn, T(obs), T(act))
    out["psi"] = (fj, ft)
    for target in (False, True):
        tag = "target_" if target else ""
        out[f"{tag}zeta"] = (jnet.zeta(jn, jp, J(x), J(k), target=target), tnet.zeta(tn, T(x), T(k), target=target))
        out[f"{tag}velocity"] = (
            jnet.velocity(jn, jp, J(x), J(k), fj, target=target),
            tnet.velocity(tn, T(x), T(k), ft, target=target),
        )
        Mj, cj = jnet.contract(jn, jp, fj, target=target)
        Mt, ct = tnet.contract(tn, ft, target=target)
        out[f"{tag}velocity_contracted"] = (
            jnet.velocity_contracted(jn, jp, J(x), J(k), Mj, cj, target=target),
            tnet.velocity_contracted(tn, T(x), T(k), Mt, ct, target=target),
        )
        out[f"{tag}q_values"] = (jnet.q_values(jn, jp, fj, target=target), tnet.q_values(tn, ft, target=target))
    if algo == "td3":
        for target in (False, True):
            out[f"td3_action target={target}"] = (
                jnet.td3_action(jn, jp, J(obs), target=target), tnet.td3_action(tn, T(obs), target=target)
            )
    else:
        (aj, lj), (at, lt) = jnet.sac_sample(jn, jp, J(obs), J(noise)), tnet.sac_sample(tn, T(obs), T(noise))
        out["sac_sample action"], out["sac_sample log_prob"] = (aj, at), (lj, lt)
    for method in ("midpoint", "euler"):
        vj = lambda xx, kk: jnet.velocity(jn, jp, xx, kk, fj)  # noqa: E731
        vt = lambda xx, kk: tnet.velocity(tn, xx, kk, ft)  # noqa: E731
        out[f"ode.integrate {method}"] = (
            jode.integrate(vj, J(x), J(k), 3, method), tode.integrate(vt, T(x), T(k), 3, method)
        )
    return out


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("algo", ["td3", "sac"])
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kw=size_cases, batch_size=st.integers(1, 9), seed=st.integers(0, 10_000))
def test_network_outputs_agree(dtype, algo, kw, batch_size, seed):
    for name, (a, b) in _outputs(kw, algo, dtype, batch_size, seed).items():
        check(name, np_(a), np_(b), dtype)


def test_update_normalizer_agrees():
    """The running observation statistics (Welford, Brax's update) evolve identically."""
    kw = dict(obs_size=4, action_size=2)
    import sf2_jax
    import sf2_torch

    jcfg, tcfg = sf2_jax.SF2Config(**kw), sf2_torch.SF2Config(**kw)
    jstats = jnet.init_params(jnet.make_networks(jcfg, "td3"), __import__("jax").random.key(0))["obs_norm"]
    jstats = {k: jx(v, "float64") for k, v in jstats.items()}
    tn = tnet.make_networks(tcfg, "td3").double()
    rng = np.random.default_rng(0)
    for i in range(4):
        batch = rng.normal(3.0, 2.0, (7 + i, 4))
        jstats = jnet.update_normalizer(jstats, jx(batch, "float64"), jcfg)
        tnet.update_normalizer(tn.obs_norm, th(batch, "float64"), tcfg)
    for key in ("count", "mean", "summed_var", "std"):
        check(f"update_normalizer {key}", np_(jstats[key]), np_(getattr(tn.obs_norm, key)), "float64")
