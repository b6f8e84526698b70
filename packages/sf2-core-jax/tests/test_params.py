import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax_helpers import A, D, small_cfg
from sf2_jax import ParamsError
from sf2_jax import networks as nw
from sf2_jax import params as pm


def outputs(nets, params, data):
    batch, noise = data
    feats = nw.psi(nets, params, batch.obs, batch.action)
    x, k = noise["eps"], noise["flow_time"]
    out = [feats, nw.zeta(nets, params, x, k, target=True), nw.q_values(nets, params, feats, target=True),
           nw.normalize(batch.obs, params["obs_norm"])]
    if nets.algo == "td3":
        out.append(nw.td3_action(nets, params, batch.obs, target=True))
    else:
        out += list(nw.sac_sample(nets, params, batch.obs, noise["noise"]))
    return [np.asarray(o) for o in out]


@pytest.mark.parametrize("suffix", [".npz", ".safetensors"])
def test_round_trip_gives_identical_outputs(td3, sac, data, tmp_path, suffix):
    if suffix == ".safetensors":
        pytest.importorskip("safetensors")
    for nets, params in (td3, sac):
        flat = pm.to_canonical(params)
        assert all(isinstance(v, np.ndarray) for v in flat.values())
        assert flat["psi.dense_0.kernel"].shape == (D + A, nets.cfg.hidden_sizes[0])
        path = pm.save(tmp_path / f"{nets.algo}{suffix}", flat)
        loaded = pm.load(path)
        assert set(loaded) == set(flat)
        for name in flat:
            np.testing.assert_array_equal(loaded[name], flat[name])
            assert (loaded[name].shape, loaded[name].dtype) == (flat[name].shape, flat[name].dtype)
        back = pm.from_canonical(loaded, nets)
        jax.tree_util.tree_map(np.testing.assert_array_equal, back, params)
        for a, b in zip(outputs(nets, back, data), outputs(nets, params, data)):
            np.testing.assert_array_equal(a, b)


def test_from_canonical_dtype(td3):
    nets, params = td3
    back = pm.from_canonical(pm.to_canonical(params), nets, dtype=jnp.float32)
    assert all(leaf.dtype == jnp.float32 for leaf in jax.tree_util.tree_leaves(back))


def test_validate_names_every_bad_entry(td3):
    nets, params = td3
    flat = pm.to_canonical(params)
    pm.validate(flat, nets)
    pm.validate(flat, nets.cfg, "td3")
    del flat["zeta.dense_2.bias"], flat["target_policy.layer_norm_1.scale"]
    flat["log_alpha"] = np.zeros(())
    flat["psi.extra"] = np.zeros((2, 2))
    flat["q.head_1.dense_0.kernel"] = np.zeros((16, 31))
    with pytest.raises(ParamsError) as err:
        pm.from_canonical(flat, nets)
    msg = str(err.value)
    F, H = nets.cfg.feature_size, nets.cfg.zeta_hidden_sizes[-1]
    assert "missing (2)" in msg and f"zeta.dense_2.bias (expected shape ({F * D},))" in msg
    assert f"target_policy.layer_norm_1.scale (expected shape ({H},))" in msg
    assert "unexpected (2)" in msg and "log_alpha (shape ())" in msg and "psi.extra (shape (2, 2))" in msg
    assert "misshaped (1)" in msg
    assert "q.head_1.dense_0.kernel: expected shape (16, 32), found (16, 31)" in msg


def test_validate_against_other_config(td3):
    flat = pm.to_canonical(td3[1])
    with pytest.raises(ParamsError, match=r"psi.dense_0.kernel: expected shape \(8, 32\), found \(5, 32\)"):
        pm.validate(flat, small_cfg().replace(obs_size=6), "td3")
    with pytest.raises(ParamsError, match="target_policy"):
        pm.validate(flat, small_cfg(), "sac")


def test_expected_shapes_without_layer_norm():
    shapes = pm.expected_shapes(small_cfg(layer_norm=False), "sac")
    assert not any("layer_norm" in name for name in shapes)
    assert shapes["policy.dense_2.kernel"] == (32, 2 * A) and shapes["log_alpha"] == ()


def test_load_errors(tmp_path):
    with pytest.raises(ParamsError, match="no parameter file"):
        pm.load(tmp_path / "absent.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip file at all")
    with pytest.raises(ParamsError, match="corrupt"):
        pm.load(bad)
    with pytest.raises(ParamsError, match=r"\.npz"):
        pm.save(tmp_path / "x.pt", {"a": np.zeros(2)})
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"\x00\x01garbage")
    with pytest.raises(ParamsError, match="corrupt|safetensors"):
        pm.load(bad)
