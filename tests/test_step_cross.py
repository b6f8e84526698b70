"""A full optimizer step (Adam on the flow loss, then EMA targets) leaves both frameworks identical.

optax.adam and torch.optim.Adam implement the same update, m̂/(√v̂ + ε) with bias corrections; with the
authors' ε = 1e-5 and three consecutive steps the parameters, the targets and the Adam moments agree.
"""

from __future__ import annotations

import jax
import optax
import pytest
import sf2_jax
import sf2_torch
import torch
from cross_bridge import build_pair, canonical_file, check, jbatch, jx, make_batch, np_, tbatch, th
from sf2_jax import params as jparams
from sf2_torch import params as tparams


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_adam_and_ema_steps(tmp_path, dtype, algo):
    kw = dict(
        obs_size=5,
        action_size=2,
        feature_size=16,
        hidden_sizes=(32, 32),
        q_hidden_size=32,
        zeta_hidden_sizes=(32, 32),
        embedding_size=8,
        denoising_steps=2,
    )
    path = canonical_file(tmp_path, kw, algo, seed=11)
    jn, jp, tn = build_pair(path, kw, algo, dtype)
    cfg = jn.cfg
    groups = ("psi", "zeta")
    opt = optax.adam(cfg.learning_rate, eps=cfg.adam_eps)
    jopt = opt.init({g: jp[g] for g in groups})
    topt = torch.optim.Adam(
        list(tn.psi.parameters()) + list(tn.zeta.parameters()), lr=cfg.learning_rate, eps=cfg.adam_eps
    )
    keys = ("next_action", "eps", "flow_time")
    for step in range(3):
        batch, noise = make_batch(kw, 16, seed=100 + step, truncation=step == 1)

        def f(sub, batch=batch, noise=noise, jp=jp):
            return sf2_jax.losses.flow_loss(
                jn, {**jp, **sub}, jbatch(batch, dtype), *[jx(noise[k], dtype) for k in keys]
            )

        (_, _), g = jax.jit(jax.value_and_grad(f, has_aux=True))({k: jp[k] for k in groups})
        updates, jopt = opt.update(g, jopt)
        new = optax.apply_updates({k: jp[k] for k in groups}, updates)
        jp = {**jp, **new}
        jp["target_psi"] = sf2_jax.losses.ema_update(jp["target_psi"], jp["psi"], cfg.tau)
        jp["target_zeta"] = sf2_jax.losses.ema_update(jp["target_zeta"], jp["zeta"], cfg.tau_zeta)

        topt.zero_grad(set_to_none=True)
        loss, _ = sf2_torch.losses.flow_loss(tn, tbatch(batch, dtype), *[th(noise[k], dtype) for k in keys])
        loss.backward()
        topt.step()
        sf2_torch.losses.ema_update(tn.target_psi, tn.psi, cfg.tau)
        sf2_torch.losses.ema_update(tn.target_zeta, tn.zeta, cfg.tau_zeta)

    jflat, tflat = jparams.to_canonical(jp), tparams.to_canonical(tn)
    assert set(jflat) == set(tflat)
    moved = 0
    for name in jflat:
        check("params after 3 Adam+EMA steps", jflat[name], tflat[name], dtype, kind="grad")
        moved += name.startswith(("psi.", "zeta.", "target_psi.", "target_zeta."))
    assert moved > 0
    # The Adam moments agree too (canonical layout: torch's (out, in) weights transposed).
    mu = jparams.to_canonical(jopt[0].mu)
    for pname, p in list(tn.psi.named_parameters(prefix="psi")) + list(
        tn.zeta.named_parameters(prefix="zeta")
    ):
        state = topt.state[p]
        m = np_(state["exp_avg"])
        cname = pname.replace(".weight", ".kernel" if m.ndim == 2 else ".scale")
        check("adam first moment", mu[cname], m.T if m.ndim == 2 else m, dtype, kind="grad")
