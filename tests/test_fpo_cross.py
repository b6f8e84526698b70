"""JAX and torch agree on FPO's losses (losses_onpolicy: cfm_losses, fpo_ratio, fpo_policy_loss,
flow_policy_sample; docs/fpo.md) and their gradients.

One velocity field in both frameworks from the same numpy weights, u(x, τ) = tanh([s, x, τ]W₁ + b₁)W₂ + b₂
at each sample's observation s, B = 6 samples of A = 3 action dimensions, n = 4 (ε, τ) pairs, the same
noise and advantages, with and without the bound on the log-ratio; values, aux metrics and the gradients
of (W₁, b₁, W₂, b₂) agree to 1e-10 relative in float64 and to cross_bridge.TOL in float32
(docs/parity.md).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch
from cross_bridge import check, jx, np_, th
from sf2_jax import losses_onpolicy as jlo
from sf2_torch import losses_onpolicy as tlo

B, A, N, OBS, H = 6, 3, 4, 5, 7
NAMES = ("w1", "b1", "w2", "b2")


def weights(seed=0):
    rng = np.random.default_rng(seed)
    return {"w1": rng.normal(0, 0.5, (OBS + A + 1, H)), "b1": rng.normal(0, 0.1, H),
            "w2": rng.normal(0, 0.5, (H, A)), "b2": rng.normal(0, 0.1, A)}


def data(seed=1):
    rng = np.random.default_rng(seed)
    return {"obs": rng.normal(size=(B, OBS)), "action": rng.normal(size=(B, A)),
            "eps": rng.normal(size=(B, N, A)), "flow_time": rng.uniform(size=(B, N)),
            "advantage": rng.normal(size=B), "noise": rng.normal(size=(B, A))}


def jax_field(w, obs):
    def velocity(x, tau):
        s = jnp.broadcast_to(obs.reshape(obs.shape[:1] + (1,) * (x.ndim - 2) + obs.shape[1:]),
                             x.shape[:-1] + obs.shape[-1:])
        h = jnp.tanh(jnp.concatenate([s, x, tau[..., None]], axis=-1) @ w["w1"] + w["b1"])
        return h @ w["w2"] + w["b2"]
    return velocity


def torch_field(w, obs):
    def velocity(x, tau):
        s = obs.reshape(obs.shape[:1] + (1,) * (x.dim() - 2) + obs.shape[1:]).expand(
            *x.shape[:-1], obs.shape[-1])
        h = torch.tanh(torch.cat([s, x, tau[..., None]], dim=-1) @ w["w1"] + w["b1"])
        return h @ w["w2"] + w["b2"]
    return velocity


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("log_ratio_clip", [None, 0.05])
def test_fpo_losses_agree(dtype, log_ratio_clip):
    d, w_old, w_new = data(), weights(0), weights(1)
    jd = {k: jx(v, dtype) for k, v in d.items()}
    td = {k: th(v, dtype) for k, v in d.items()}
    jw_old = {k: jx(v, dtype) for k, v in w_old.items()}
    tw_old = {k: th(v, dtype) for k, v in w_old.items()}
    jw = {k: jx(v, dtype) for k, v in w_new.items()}
    tw = {k: th(v, dtype).requires_grad_(True) for k, v in w_new.items()}

    j_old = jlo.cfm_losses(jax_field(jw_old, jd["obs"]), jd["action"], jd["eps"], jd["flow_time"])
    t_old = tlo.cfm_losses(torch_field(tw_old, td["obs"]), td["action"], td["eps"], td["flow_time"])
    check("fpo cfm_losses", np_(j_old), np_(t_old), dtype)

    def j_loss(w):
        return jlo.fpo_policy_loss(jax_field(w, jd["obs"]), jd["action"], jd["eps"], jd["flow_time"], j_old,
                                   jd["advantage"], 0.05, log_ratio_clip)

    (jl, jaux), jg = jax.value_and_grad(j_loss, has_aux=True)(jw)
    tl, taux = tlo.fpo_policy_loss(torch_field(tw, td["obs"]), td["action"], td["eps"], td["flow_time"],
                                   t_old, td["advantage"], 0.05, log_ratio_clip)
    tl.backward(inputs=[tw[k] for k in NAMES])
    check("fpo_policy_loss", np_(jl), np_(tl.detach()), dtype)
    for name in ("ratio", "clip_fraction", "cfm_loss"):
        check("fpo_policy_loss", np_(jaux[name]), np_(taux[name]), dtype)
    for k in NAMES:
        check("fpo_policy_loss grad", np_(jg[k]), np_(tw[k].grad), dtype, "grad")
    j_new = jlo.cfm_losses(jax_field(jw, jd["obs"]), jd["action"], jd["eps"], jd["flow_time"])
    with torch.no_grad():
        t_new = tlo.cfm_losses(torch_field(tw, td["obs"]), td["action"], td["eps"], td["flow_time"])
    check("fpo_ratio", np_(jlo.fpo_ratio(j_old, j_new, log_ratio_clip)),
          np_(tlo.fpo_ratio(t_old, t_new, log_ratio_clip)), dtype)
    assert 0 < float(jaux["clip_fraction"]) < 1   # both branches of the clip are exercised


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("steps", [1, 10])
def test_flow_policy_sample_agrees(dtype, steps):
    d, w = data(2), weights(3)
    ja = jlo.flow_policy_sample(jax_field({k: jx(v, dtype) for k, v in w.items()}, jx(d["obs"], dtype)),
                                jx(d["noise"], dtype), steps)
    with torch.no_grad():
        ta = tlo.flow_policy_sample(torch_field({k: th(v, dtype) for k, v in w.items()}, th(d["obs"], dtype)),
                                    th(d["noise"], dtype), steps)
    check("flow_policy_sample", np_(ja), np_(ta), dtype)
