"""JAX and torch agree on the MinAtar system's networks, losses and gradients (docs/minatar.md).

One canonical file per method (conv kernels HWIO, dense (in, out), every entry drawn: LayerNorm scales,
biases and targets all non-trivial) is loaded into `sf2_jax.networks_image` and `sf2_torch.networks_image`;
both get the same grids, integer actions and explicit noise; every network output, loss, aux metric and
gradient of the trained groups (JAX `jax.grad` with respect to them, torch `backward(inputs=...)`, compared
in canonical layout) agrees to 1e-10 relative in float64 and to cross_bridge.TOL in float32. The grid is
5×4×3: non-square (the NHWC flatten order) with an odd height (the pooling drops a row).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np
import pytest
import sf2_jax
import sf2_torch
import torch
from cross_bridge import check, jx, np_, th
from sf2_jax import networks_image as jnwi
from sf2_jax import params as jparams
from sf2_torch import networks_image as tnwi
from sf2_torch import params as tparams

SHAPE = (5, 4, 3)
CFG = sf2_jax.SF2Config(obs_size=60, action_size=3, feature_size=6, hidden_sizes=(8, 7), q_hidden_size=5,
                        zeta_hidden_sizes=(6, 5), embedding_size=8, gamma_su=0.9)
B = 6
TRAINED = {"image_flow_loss": ("psi", "zeta"), "latent_flow_loss": ("psi", "zeta"),
           "autoencoder_loss": ("encoder", "decoder"), "ppo_policy_loss": ("actor",),
           "v_critic_loss": ("critic",)}


def canonical_file(tmp_path, cfg, method: str, seed: int):
    """One canonical parameter file of `method`'s networks, every entry drawn with numpy (kernels at the
    LeCun-uniform scale of their fan-in, the product of every axis but the last)."""
    rng = np.random.default_rng(seed)
    flat = {}
    for name, shape in jparams.expected_shapes(jnwi.make_image_networks(cfg, SHAPE, method)).items():
        if name.endswith("kernel"):
            flat[name] = rng.uniform(-1.0, 1.0, shape) * math.sqrt(3.0 / np.prod(shape[:-1]))
        elif name.endswith(".scale"):
            flat[name] = rng.uniform(0.5, 1.5, shape)
        else:
            flat[name] = rng.normal(0.0, 0.1, shape)
    path = tmp_path / f"{method}-{seed}.npz"
    jparams.save(path, flat)
    return path


def build_pair(path, cfg, method: str, dtype: str):
    """(JAX networks, JAX params, torch networks) from one canonical file, at `dtype`."""
    jn = jnwi.make_image_networks(cfg, SHAPE, method)
    jp = jparams.from_canonical(jparams.load(path), jn, dtype=getattr(jax.numpy, dtype))
    tn = tnwi.make_image_networks(cfg, SHAPE, method)   # sf2_torch.SF2Config is sf2_jax.SF2Config
    tparams.from_canonical(tparams.load(path), tn.to(getattr(torch, dtype)))
    return jn, jp, tn


def data(seed: int, latent: bool = False, truncation: bool = True):
    """Identical inputs for both frameworks (numpy): grids in {0, 1}, actions, rewards, noise."""
    rng = np.random.default_rng(100 + seed)
    grid = lambda: (rng.uniform(size=(B, *SHAPE)) < 0.3).astype(np.float64)  # noqa: E731
    return dict(
        obs=grid(), next_obs=grid(), action=rng.integers(0, CFG.action_size, B),
        next_action=rng.integers(0, CFG.action_size, B), reward=rng.normal(size=B),
        discount=(rng.uniform(size=B) > 0.2).astype(np.float64),
        truncation=(rng.uniform(size=B) < 0.4).astype(np.float64) if truncation else np.zeros(B),
        eps=rng.normal(size=(B, jnwi.LATENT_SIZE if latent else CFG.obs_size)), flow_time=rng.uniform(size=B),
        old_log_prob=rng.normal(-1.1, 0.4, B), advantage=rng.normal(size=B), value=rng.normal(size=B),
        features=rng.normal(size=(B, CFG.feature_size)), x=rng.normal(size=(B, CFG.obs_size)),
        z=rng.uniform(-1, 1, (B, jnwi.LATENT_SIZE)),
    )


def arrays(d: dict, dtype: str, framework: str):
    conv = jx if framework == "jax" else th
    return {k: (conv(v, "int64") if k.endswith("action") else conv(v, dtype)) for k, v in d.items()}


def batch(core, a: dict):
    return core.losses.Batch(*[a[k] for k in core.losses.Batch._fields])


def loss_args(name: str, core, a: dict) -> tuple:
    return {
        "image_flow_loss": (batch(core, a), a["next_action"], a["eps"], a["flow_time"]),
        "latent_flow_loss": (batch(core, a), a["next_action"], a["eps"], a["flow_time"]),
        "autoencoder_loss": (a["obs"],),
        "ppo_policy_loss": (a["obs"], a["action"], a["old_log_prob"], a["advantage"], 0.2, 0.01),
        "q_critic_loss": (a["obs"], a["action"], a["reward"] * 3),
        "v_critic_loss": (a["obs"], a["value"], a["value"] + a["advantage"], 0.2),
    }[name]


def compare_loss(name: str, dtype: str, cfg, method: str, path, d: dict, term: str | None = None):
    """One loss in both cores: value, aux and the gradient of every trained group, in canonical layout."""
    jn, jp, tn = build_pair(path, cfg, method, dtype)
    groups = TRAINED.get(name) or (("critic",) if method == "ppo_q" else ("psi", "q"))
    ja, ta = arrays(d, dtype, "jax"), arrays(d, dtype, "torch")
    jfn, tfn = getattr(sf2_jax.losses_onpolicy, name), getattr(sf2_torch.losses_onpolicy, name)

    def f(sub):
        return jfn(jn, {**jp, **sub}, *loss_args(name, sf2_jax, ja))

    (jloss, jaux), jgrads = jax.jit(jax.value_and_grad(f, has_aux=True))({g: jp[g] for g in groups})
    tn.zero_grad(set_to_none=True)
    tloss, taux = tfn(tn, *loss_args(name, sf2_torch, ta))
    tloss.backward(inputs=[p for g in groups for p in getattr(tn, g).parameters()])
    term = term or f"minatar {name}"
    check(term, np_(jloss), np_(tloss), dtype)
    assert set(jaux) == set(taux), (sorted(jaux), sorted(taux))
    for key in jaux:
        check(f"{term}.{key}", np_(jaux[key]), np_(taux[key]), dtype)
    tflat = tparams.to_canonical({g: getattr(tn, g) for g in groups}, grads=True)
    jflat = jparams.to_canonical(jgrads)
    assert set(jflat) == set(tflat)
    for key, g in jflat.items():
        check(f"grad {term}", g, tflat[key], dtype, kind="grad")
    assert all(np.any(g) for g in jflat.values()), f"{term}: a trained leaf got no gradient"
    return float(np_(jloss))


# ------------------------------------------------------------------------------------------ networks
def _outputs(framework: str, jn, jp, tn, a: dict, method: str) -> dict:
    """Every network output of `method`'s networks, written once for both frameworks."""
    core = sf2_jax if framework == "jax" else sf2_torch
    nwi = core.networks_image

    def call(fn, *args, **kw):
        if framework == "jax":
            return getattr(nwi, fn)(jn, jp, *args, **kw)
        return getattr(nwi, fn)(tn, *args, **kw)

    out = {"policy_logits": call("policy_logits", a["obs"])}
    out["categorical_log_prob"] = nwi.categorical_log_prob(out["policy_logits"], a["action"])
    out["categorical_entropy"] = nwi.categorical_entropy(out["policy_logits"])
    if method == "ppo":
        out["state_value"] = call("state_value", a["obs"])
        return out
    out["action_values"] = call("action_values", a["obs"])
    out["expected_value"] = nwi.expected_value(out["policy_logits"], out["action_values"])
    if method == "ppo_q":
        return out
    for target in (False, True):
        tag = " target" if target else ""
        out[f"psi_all{tag}"] = call("psi_all", a["obs"], target=target)
        out[f"psi{tag}"] = call("psi", a["obs"], a["action"], target=target)
    out["q_head"] = call("q_head", a["features"])
    if method == "sf2_ae":
        out["encode"] = call("encode", a["obs"])
        out["decode_logits"] = call("decode_logits", a["z"])
        latent = nwi.latent_networks(jn if framework == "jax" else tn)
        lead = (latent, jp) if framework == "jax" else (latent,)   # the vector core's functions on latents
        z, k, f = a["z"], a["flow_time"], a["features"]
        for target in (False, True):
            tag = " target" if target else ""
            out[f"latent velocity{tag}"] = core.networks.velocity(*lead, z, k, f, target=target)
            M, c = core.networks.contract(*lead, f, target=target)
            out[f"latent velocity_contracted{tag}"] = core.networks.velocity_contracted(*lead, z, k, M, c,
                                                                                        target=target)
        return out
    for target in (False, True):
        tag = " target" if target else ""
        out[f"zeta_hidden{tag}"] = call("zeta_hidden", a["x"], a["flow_time"], target=target)
        out[f"zeta{tag}"] = call("zeta", a["x"], a["flow_time"], target=target)
        out[f"velocity{tag}"] = call("velocity", a["x"], a["flow_time"], a["features"], target=target)
        M, c = call("contract", a["features"], target=target)
        out[f"contract M{tag}"], out[f"contract c{tag}"] = M, c
        out[f"velocity_contracted{tag}"] = call("velocity_contracted", a["x"], a["flow_time"], M, c,
                                                target=target)
    return out


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("method", jnwi.METHODS)
def test_network_outputs_agree(tmp_path, dtype, method):
    path = canonical_file(tmp_path, CFG, method, seed=1)
    jn, jp, tn = build_pair(path, CFG, method, dtype)
    d = data(1, latent=method == "sf2_ae")
    jout = jax.jit(lambda p, a: _outputs("jax", jn, p, None, a, method))(jp, arrays(d, dtype, "jax"))
    with torch.no_grad():
        tout = _outputs("torch", None, None, tn, arrays(d, dtype, "torch"), method)
    assert set(jout) == set(tout)
    for name in jout:
        check(f"minatar {name}", np_(jout[name]), np_(tout[name]), dtype)


# ------------------------------------------------------------------------------------------ flow losses
FLOW = [(1, "midpoint", 0.9, True), (2, "euler", 0.9, False), (1, "midpoint", 0.0, True),
        (3, "midpoint", 0.9, True)]


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("steps,integrator,gamma_su,truncation", FLOW)
def test_image_flow_loss(tmp_path, dtype, steps, integrator, gamma_su, truncation):
    cfg = dataclasses.replace(CFG, denoising_steps=steps, integrator=integrator, gamma_su=gamma_su)
    path = canonical_file(tmp_path, cfg, "sf2", seed=steps)
    loss = compare_loss("image_flow_loss", dtype, cfg, "sf2", path, data(steps, truncation=truncation))
    assert np.isfinite(loss) and loss > 0


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("steps,integrator,gamma_su,truncation", FLOW[:3])
def test_latent_flow_loss(tmp_path, dtype, steps, integrator, gamma_su, truncation):
    cfg = dataclasses.replace(CFG, denoising_steps=steps, integrator=integrator, gamma_su=gamma_su)
    path = canonical_file(tmp_path, cfg, "sf2_ae", seed=10 + steps)
    d = data(10 + steps, latent=True, truncation=truncation)
    assert compare_loss("latent_flow_loss", dtype, cfg, "sf2_ae", path, d) > 0


@pytest.mark.parametrize("jax_fast,torch_fast", [(True, False), (False, True)])
def test_image_fast_path_across_frameworks(tmp_path, jax_fast, torch_fast):
    """The contracted 1×1 layer in one framework equals the materialized ζ in the other (float64)."""
    cfg = dataclasses.replace(CFG, denoising_steps=2)
    path = canonical_file(tmp_path, cfg, "sf2", seed=7)
    jn, jp, _ = build_pair(path, dataclasses.replace(cfg, contract_zeta=jax_fast), "sf2", "float64")
    _, _, tn = build_pair(path, dataclasses.replace(cfg, contract_zeta=torch_fast), "sf2", "float64")
    d = data(7)
    ja, ta = arrays(d, "float64", "jax"), arrays(d, "float64", "torch")
    args = ("next_action", "eps", "flow_time")

    def f(sub):
        jb = batch(sf2_jax, ja)
        return sf2_jax.losses_onpolicy.image_flow_loss(jn, {**jp, **sub}, jb, *[ja[k] for k in args])

    (jloss, jaux), jg = jax.jit(jax.value_and_grad(f, has_aux=True))({g: jp[g] for g in ("psi", "zeta")})
    tloss, taux = sf2_torch.losses_onpolicy.image_flow_loss(tn, batch(sf2_torch, ta), *[ta[k] for k in args])
    tloss.backward(inputs=[*tn.psi.parameters(), *tn.zeta.parameters()])
    check("minatar image_flow_loss fast-vs-plain", np_(jloss), np_(tloss), "float64")
    for key in jaux:
        check(f"minatar image_flow_loss fast-vs-plain.{key}", np_(jaux[key]), np_(taux[key]), "float64")
    tg = tparams.to_canonical({"psi": tn.psi, "zeta": tn.zeta}, grads=True)
    for key, g in jparams.to_canonical(jg).items():
        check("grad minatar image_flow_loss fast-vs-plain", g, tg[key], "float64", kind="grad")


# ------------------------------------------------------------------------------------------ the other losses
@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("name,method", [
    ("autoencoder_loss", "sf2_ae"), ("ppo_policy_loss", "ppo"), ("ppo_policy_loss", "sf2"),
    ("q_critic_loss", "ppo_q"), ("q_critic_loss", "sf2"), ("q_critic_loss", "sf2_ae"),
    ("v_critic_loss", "ppo"),
])
def test_losses(tmp_path, dtype, name, method):
    path = canonical_file(tmp_path, CFG, method, seed=20)
    loss = compare_loss(name, dtype, CFG, method, path, data(20, latent=method == "sf2_ae"),
                        term=f"minatar {name} ({method})" if name == "q_critic_loss" else None)
    assert np.isfinite(loss)


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_returns_agree(dtype):
    """The λ-return and GAE of one random (T, N) rollout with terminations and truncations."""
    rng = np.random.default_rng(30)
    T, N = 16, 5
    d = dict(reward=rng.normal(size=(T, N)), discount=(rng.uniform(size=(T, N)) > 0.1).astype(float),
             truncation=(rng.uniform(size=(T, N)) > 0.9).astype(float), value=rng.normal(size=(T, N)),
             next_value=rng.normal(size=(T, N)))
    out = {}
    for framework, conv, core in (("jax", jx, sf2_jax), ("torch", th, sf2_torch)):
        a = {k: conv(v, dtype) for k, v in d.items()}
        r, disc, tr = a["reward"], a["discount"], a["truncation"]
        G = core.losses_onpolicy.lambda_returns(r, disc, tr, a["next_value"], 0.9, 0.95)
        adv, target = core.losses_onpolicy.gae(r, disc, tr, a["value"], a["next_value"], 0.9, 0.95)
        out[framework] = (G, adv, target)
    for term, j, t in zip(("lambda_returns", "gae advantages", "gae targets"), out["jax"], out["torch"]):
        check(f"minatar {term}", np_(j), np_(t), dtype)
