"""Properties over sizes nobody picked by hand (hypothesis): fast path = oracle, canonical round trip."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from sf2_torch import SF2Config, losses, networks, params

sizes = st.fixed_dictionaries(
    dict(
        obs_size=st.integers(1, 6),
        action_size=st.integers(1, 3),
        feature_size=st.integers(1, 7),
        hidden_sizes=st.sampled_from([(), (5,), (4, 3)]),
        q_hidden_size=st.integers(1, 5),
        zeta_hidden_sizes=st.sampled_from([(), (6,), (3, 5)]),
        embedding_size=st.sampled_from([2, 6]),
        layer_norm=st.booleans(),
        denoising_steps=st.integers(1, 3),
        integrator=st.sampled_from(["midpoint", "euler"]),
        gamma_su=st.sampled_from([0.0, 0.5]),
    )
)


@settings(max_examples=15, deadline=None)
@given(kw=sizes, batch=st.integers(1, 4), seed=st.integers(0, 2**16), algo=st.sampled_from(["td3", "sac"]))
def test_fast_path_and_round_trip(kw, batch, seed, algo):
    torch.manual_seed(seed)
    cfg = SF2Config(**kw)
    nets = networks.make_networks(cfg, algo, dtype=torch.float64)
    g = torch.Generator().manual_seed(seed)

    def r(*shape):
        return torch.randn(shape, generator=g, dtype=torch.float64)

    with torch.no_grad():  # non-trivial LayerNorm and biases
        for p in nets.parameters():
            p.add_(0.3 * r(*tuple(p.shape)))
    D, A = cfg.obs_size, cfg.action_size
    b = losses.Batch(
        r(batch, D),
        torch.tanh(r(batch, A)),
        r(batch),
        torch.ones(batch, dtype=torch.float64),
        r(batch, D),
        torch.zeros(batch, dtype=torch.float64),
    )
    args = (torch.tanh(r(batch, A)), r(batch, D), torch.rand(batch, generator=g, dtype=torch.float64))
    plain = networks.make_networks(cfg.replace(contract_zeta=False), algo, dtype=torch.float64)
    params.from_canonical(params.to_canonical(nets), plain)
    fast_loss, _ = losses.flow_loss(nets, b, *args)
    plain_loss, _ = losses.flow_loss(plain, b, *args)
    fast_loss.backward()
    plain_loss.backward()
    torch.testing.assert_close(fast_loss, plain_loss, rtol=1e-10, atol=1e-12)
    fg, pg = params.to_canonical(nets, grads=True), params.to_canonical(plain, grads=True)
    for name in fg:
        np.testing.assert_allclose(fg[name], pg[name], rtol=1e-9, atol=1e-11, err_msg=name)
