"""Every network output agrees across frameworks when both load the same canonical file.

Sizes are drawn by hypothesis (observation, action, feature and hidden sizes, batch), so the canonical
naming, the (in, out) kernel layout and ζ's (D, F) reshape are checked on shapes nobody picked by hand.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import jax
import numpy as np
import pytest
import torch
from cross_bridge import build_pair, canonical_file, check, jx, np_, th
from hypothesis import HealthCheck, Phase, given, settings
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


def _all_outputs(net, ode, call, inp, kw, algo):
    """Every network output, written once for both frameworks.

    `call(name, *args, **kw)` calls `net.<name>` with the framework's leading arguments ((nets, params) for
    JAX, (nets,) for torch); `inp` holds the framework's input arrays.
    """
    obs, act, x, k, noise, stats = inp["obs"], inp["act"], inp["x"], inp["k"], inp["noise"], inp["stats"]
    out = {
        "normalize": net.normalize(obs, stats),
        "flow_time_embedding": net.flow_time_embedding(k, kw["embedding_size"]),
    }
    features = out["psi"] = call("psi", obs, act)
    for target in (False, True):
        tag = "target_" if target else ""
        out[f"{tag}zeta"] = call("zeta", x, k, target=target)
        out[f"{tag}velocity"] = call("velocity", x, k, features, target=target)
        M, c = call("contract", features, target=target)
        out[f"{tag}velocity_contracted"] = call("velocity_contracted", x, k, M, c, target=target)
        out[f"{tag}q_values"] = call("q_values", features, target=target)
    if algo == "td3":
        for target in (False, True):
            out[f"td3_action target={target}"] = call("td3_action", obs, target=target)
    else:
        out["sac_sample action"], out["sac_sample log_prob"] = call("sac_sample", obs, noise)
    for method in ("midpoint", "euler"):
        v = lambda xx, kk: call("velocity", xx, kk, features)  # noqa: E731
        out[f"ode.integrate {method}"] = ode.integrate(v, x, k, 3, method)
    return out


def _outputs(kw, algo, dtype, batch_size, seed):
    with tempfile.TemporaryDirectory() as d:
        path = canonical_file(Path(d), kw, algo, seed=seed)
        jn, jp, tn = build_pair(path, kw, algo, dtype)
    rng = np.random.default_rng(seed)
    D, A = kw["obs_size"], kw["action_size"]
    raw = dict(
        obs=rng.normal(size=(batch_size, D)),
        act=rng.uniform(-1, 1, (batch_size, A)),
        x=rng.normal(size=(batch_size, D)),
        k=rng.uniform(size=batch_size),
        noise=rng.normal(size=(batch_size, A)),
    )

    def jax_side(params, inp):
        def call(name, *args, **kwargs):
            return getattr(jnet, name)(jn, params, *args, **kwargs)

        return _all_outputs(jnet, jode, call, {**inp, "stats": params["obs_norm"]}, kw, algo)

    jout = jax.jit(jax_side)(jp, {k: jx(v, dtype) for k, v in raw.items()})  # one compile, not one per op
    with torch.no_grad():
        tout = _all_outputs(
            tnet,
            tode,
            lambda name, *a, **k: getattr(tnet, name)(tn, *a, **k),
            {**{k: th(v, dtype) for k, v in raw.items()}, "stats": tn.obs_norm},
            kw,
            algo,
        )
    assert set(jout) == set(tout)
    return {name: (jout[name], tout[name]) for name in jout}


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("algo", ["td3", "sac"])
# No shrinking: every example compiles a fresh program (seconds each); a failing example is shown as drawn.
@settings(
    max_examples=4,
    deadline=None,
    derandomize=True,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(kw=size_cases, batch_size=st.integers(1, 9), seed=st.integers(0, 10_000))
def test_network_outputs_agree(dtype, algo, kw, batch_size, seed):
    for name, (a, b) in _outputs(kw, algo, dtype, batch_size, seed).items():
        check(name, np_(a), np_(b), dtype, kind="ode" if name.startswith("ode.") else "value")


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
