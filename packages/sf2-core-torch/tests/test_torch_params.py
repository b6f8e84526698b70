from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import torch
from sf2_torch import ParamsError, losses, networks, params
from torch_reference import make_batch, make_cfg, make_nets

SUFFIXES = (".npz", ".safetensors") if importlib.util.find_spec("safetensors") else (".npz",)


@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_round_trip_into_fresh_networks(algo, tmp_path):
    src = make_nets(algo, seed=0)
    flat = params.to_canonical(src)
    assert flat["psi.dense_0.kernel"].shape == (5, 32) and flat["zeta.dense_2.kernel"].shape == (32, 48)
    np.testing.assert_array_equal(flat["psi.dense_0.kernel"], src.psi.dense_0.weight.detach().numpy().T)
    np.testing.assert_array_equal(
        flat["psi.layer_norm_1.scale"], src.psi.layer_norm_1.weight.detach().numpy()
    )
    assert ("target_policy.dense_0.kernel" in flat) == (algo == "td3") and ("log_alpha" in flat) == (
        algo == "sac"
    )
    for suffix in SUFFIXES:
        path = params.save(tmp_path / f"p{suffix}", flat)
        loaded = params.load(path)
        assert loaded.keys() == flat.keys()
        dst = networks.make_networks(make_cfg(), algo).double()
        params.from_canonical(loaded, dst)
        again = params.to_canonical(dst)
        for name in flat:
            np.testing.assert_array_equal(again[name], flat[name], err_msg=name)
        batch, noise = make_batch()
        l1 = losses.flow_loss(src, batch, noise["next_action"], noise["eps"], noise["flow_time"])[0]
        l2 = losses.flow_loss(dst, batch, noise["next_action"], noise["eps"], noise["flow_time"])[0]
        assert l1.item() == l2.item()


def test_from_canonical_keeps_dtype_and_copies():
    flat = params.to_canonical(make_nets("td3"))
    nets = networks.make_networks(make_cfg(), "td3")  # float32
    params.from_canonical(flat, nets)
    assert nets.psi.dense_0.weight.dtype == torch.float32 and nets.obs_norm.count.dtype == torch.float32
    assert not nets.target_psi.dense_0.weight.requires_grad and nets.psi.dense_0.weight.requires_grad
    np.testing.assert_allclose(
        nets.zeta.dense_2.weight.detach().numpy().T, flat["zeta.dense_2.kernel"], rtol=1e-6
    )
    out = params.to_canonical(nets)
    out["psi.dense_0.bias"][:] = 123.0  # a copy, not a view
    assert not torch.any(nets.psi.dense_0.bias == 123.0)
    out["q.head_0.dense_1.kernel"][:] = 123.0  # (H, 1): its transpose is contiguous, still a copy
    assert not torch.any(nets.q.head_0.dense_1.weight == 123.0)


def test_grads_in_canonical_layout(td3_nets):
    batch, noise = make_batch()
    losses.flow_loss(td3_nets, batch, noise["next_action"], noise["eps"], noise["flow_time"])[0].backward()
    g = params.to_canonical(td3_nets, grads=True)
    assert "obs_norm.count" not in g
    np.testing.assert_array_equal(g["zeta.dense_1.kernel"], td3_nets.zeta.dense_1.weight.grad.numpy().T)
    assert not np.any(g["target_zeta.dense_1.kernel"]) and not np.any(g["q.head_0.dense_0.kernel"])
    shapes = {n: s for n, s in params.expected_shapes(td3_nets).items() if not n.startswith("obs_norm.")}
    assert {n: v.shape for n, v in g.items()} == shapes


def test_validate_names_every_problem(td3_nets):
    flat = params.to_canonical(td3_nets)
    params.validate(flat, td3_nets)
    params.validate(flat, make_cfg(), "td3")
    del flat["psi.dense_0.kernel"], flat["target_policy.dense_2.bias"]
    flat["log_alpha"] = np.zeros(())
    flat["zeta.dense_2.kernel"] = np.zeros((48, 32))
    flat["obs_norm.count"] = np.zeros((1,))
    with pytest.raises(ParamsError) as info:
        params.validate(flat, td3_nets)
    msg = str(info.value)
    assert "2 missing, 1 unexpected, 2 misshaped" in msg
    assert "missing    psi.dense_0.kernel: expected shape (5, 32)" in msg
    assert "missing    target_policy.dense_2.bias: expected shape (2,)" in msg
    assert "unexpected log_alpha: found shape ()" in msg
    assert "misshaped  zeta.dense_2.kernel: expected shape (32, 48), found (48, 32)" in msg
    assert "misshaped  obs_norm.count: expected shape (), found (1,)" in msg
    with pytest.raises(ParamsError, match="missing    log_alpha"):
        params.validate(params.to_canonical(td3_nets), make_cfg(), "sac")
    before = params.to_canonical(td3_nets)
    with pytest.raises(ParamsError):
        params.from_canonical(flat, td3_nets)
    after = params.to_canonical(td3_nets)
    assert all(np.array_equal(before[n], after[n]) for n in before)  # nothing was half-copied


def test_load_errors(tmp_path):
    with pytest.raises(ParamsError, match="not found"):
        params.load(tmp_path / "absent.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"PK\x03\x04 this is not a zip archive")
    with pytest.raises(ParamsError, match="cannot read parameter file"):
        params.load(bad)
    with pytest.raises(ParamsError, match="suffix '.pt'"):
        params.save(tmp_path / "x.pt", {"a": np.zeros(2)})
    with pytest.raises(ParamsError, match="suffix '.pkl'"):
        params.load(tmp_path / "x.pkl")
    path = params.save(tmp_path / "sub" / "dtype.npz", {"a": np.zeros(2, np.float32), "b": np.asarray(1.0)})
    loaded = params.load(path)
    assert loaded["a"].dtype == np.float32 and loaded["b"].shape == ()
    with pytest.raises(ParamsError, match="numeric"):
        params.save(tmp_path / "x.npz", {"a": np.array(["text"])})


def test_load_errors_safetensors(tmp_path):
    pytest.importorskip("safetensors", reason="the optional extra sf2-core-torch[safetensors] is absent")
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"\x00\x01garbage")
    with pytest.raises(ParamsError, match="cannot read parameter file"):
        params.load(junk)
