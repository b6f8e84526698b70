"""sf2_torch.objectives, SF²'s TorchRL loss modules: from one canonical parameter file loaded into two
networks, a module and the functional loss it wraps give the same value, terms and gradients in float64
(the noise passed explicitly); `set_keys` renames every entry; noise the tensordict lacks is drawn from
the module's generator; docs/torchrl.md's example runs beside TorchRL's TD3Loss."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("torchrl", reason="sf2_torch.objectives: the [train] extra")

from sf2_torch import ConfigError, losses, networks, params  # noqa: E402
from sf2_torch.objectives import SF2CriticLoss, SF2FlowLoss  # noqa: E402
from tensordict import TensorDict  # noqa: E402
from torch_reference import make_batch, make_cfg, make_nets  # noqa: E402

DOC = Path(__file__).resolve().parents[4] / "docs" / "torchrl.md"
REL = 1e-12


def _pair(tmp_path, algo, **overrides):
    """Two float64 `Networks` loaded from one canonical file of non-trivial values (torch_reference)."""
    path = params.save(tmp_path / f"{algo}.npz", params.to_canonical(make_nets(algo, **overrides)))
    flat = params.load(path)
    out = []
    for _ in range(2):
        nets = networks.make_networks(make_cfg(**overrides), algo).double()
        params.from_canonical(flat, nets)
        out.append(nets)
    return out


def _sample(batch, noise, keys=None):
    """The batch and noise as a TorchRL replay sample: rewards and flags (B, 1), flags bool, done =
    terminated or truncated; `keys` renames the entries (default: the modules' default keys)."""
    k = {"observation": "observation", "action": "action", "reward": "reward", "done": "done",
         "terminated": "terminated", "truncated": "truncated", "flow_noise": "flow_noise",
         "flow_time": "flow_time", "flow_action_noise": "flow_action_noise",
         "smoothing_noise": "smoothing_noise", "next_action_noise": "next_action_noise", **(keys or {})}
    term = (batch.discount == 0)[:, None]
    trunc = batch.truncation.bool()[:, None]
    td = TensorDict({}, batch_size=[batch.obs.shape[0]])
    nxt = {"observation": batch.next_obs, "action": noise["next_action"], "reward": batch.reward[:, None],
           "terminated": term, "truncated": trunc, "done": term | trunc}
    for name, value in nxt.items():
        td.set(("next", k[name]) if isinstance(k[name], str) else ("next", *k[name]), value)
    for name, value in (("observation", batch.obs), ("action", batch.action), ("flow_noise", noise["eps"]),
                        ("flow_time", noise["flow_time"]), ("flow_action_noise", noise["noise"]),
                        ("smoothing_noise", noise["smoothing"]), ("next_action_noise", noise["noise"])):
        td.set(k[name], value)
    return td


def _rel(a, b) -> float:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return float(np.max(np.abs(a - b))) / max(float(np.max(np.abs(b))), 1e-30) if a.size else 0.0


def _same(module_out: dict, functional: dict, nets_m, nets_f):
    """Values and every parameter's gradient within REL relative (they are in fact equal, bit for bit)."""
    for name, value in functional.items():
        assert _rel(module_out[name].detach(), value.detach()) <= REL, name
        assert torch.equal(module_out[name].detach(), value.detach()), name
    gm, gf = params.to_canonical(nets_m, grads=True), params.to_canonical(nets_f, grads=True)
    assert gm.keys() == gf.keys()
    for name in gf:
        assert _rel(gm[name], gf[name]) <= REL, name
        assert np.array_equal(gm[name], gf[name]), name
    assert any(np.abs(g).max() > 0 for g in gf.values())


@pytest.mark.parametrize("contract_zeta", [True, False])
@pytest.mark.parametrize("gamma_su", [0.99, 0.0])
@pytest.mark.parametrize("source", ["policy", "tensordict"])
@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_flow_loss_module_is_the_functional_flow_loss(tmp_path, algo, source, gamma_su, contract_zeta):
    nets_m, nets_f = _pair(tmp_path, algo, gamma_su=gamma_su, contract_zeta=contract_zeta, denoising_steps=2)
    batch, noise = make_batch()
    out = SF2FlowLoss(nets_m, next_action=source)(_sample(batch, noise))
    out["loss_flow"].backward()
    if source == "tensordict":
        next_action = noise["next_action"]
    elif algo == "td3":   # the trainers' ā′: TD3's target policy; SAC a sample of the policy at s′
        next_action = networks.td3_action(nets_f, batch.next_obs, target=True)
    else:
        next_action = networks.sac_sample(nets_f, batch.next_obs, noise["noise"])[0]
    loss, aux = losses.flow_loss(nets_f, batch, next_action.detach(), noise["eps"], noise["flow_time"])
    loss.backward()
    assert set(out.keys()) == {"loss_flow", "flow_loss_p", "flow_loss_boot"}
    _same(out, {"loss_flow": loss, "flow_loss_p": aux["loss_p"], "flow_loss_boot": aux["loss_boot"]},
          nets_m, nets_f)
    assert not out["flow_loss_p"].requires_grad


@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_critic_module_is_the_functional_critic_loss(tmp_path, algo):
    nets_m, nets_f = _pair(tmp_path, algo)
    batch, noise = make_batch()
    out = SF2CriticLoss(nets_m)(_sample(batch, noise))
    out["loss_qvalue"].backward()
    fn = losses.td3_critic_loss if algo == "td3" else losses.sac_critic_loss
    loss, aux = fn(nets_f, batch, noise["smoothing" if algo == "td3" else "noise"])
    loss.backward()
    _same(out, {"loss_qvalue": loss, "pred_value": aux["q"], "target_value": aux["target_q"]}, nets_m, nets_f)
    grads = params.to_canonical(nets_m, grads=True)   # Q and ψ: the critic's groups, nothing else
    trained = {n.split(".")[0] for n, g in grads.items() if np.abs(g).max() > 0}
    assert trained == {"q", "psi"}


def test_keys_are_renamed_with_set_keys(tmp_path):
    """Every entry under another name (the observation nested) gives the same numbers; `in_keys` follow;
    an unknown name is refused by TorchRL's `set_keys`."""
    names = {"observation": ("agent", "obs"), "action": "act", "reward": "rew", "done": "stop",
             "terminated": "term", "truncated": "trunc", "flow_noise": "eps", "flow_time": "k",
             "flow_action_noise": "xi_flow", "smoothing_noise": "xi", "next_action_noise": "xi_next"}
    batch, noise = make_batch()
    default, renamed = _sample(batch, noise), _sample(batch, noise, names)
    assert "observation" not in renamed.keys() and ("next", "agent", "obs") in renamed.keys(True)
    for cls, algo, kw in ((SF2FlowLoss, "sac", {}), (SF2FlowLoss, "td3", {"next_action": "tensordict"}),
                          (SF2CriticLoss, "td3", {}), (SF2CriticLoss, "sac", {})):
        nets = make_nets(algo)
        module = cls(nets, **kw)
        module.set_keys(**{k: v for k, v in names.items() if k in module.tensor_keys.__dataclass_fields__})
        assert ("agent", "obs") in module.in_keys and ("next", "agent", "obs") in module.in_keys
        a, b = module(renamed), cls(nets, **kw)(default)
        for key in a.keys():
            assert torch.equal(a[key], b[key]), (cls.__name__, algo, key)
    with pytest.raises(ValueError, match="not an accepted tensordict key"):
        SF2FlowLoss(make_nets("td3")).set_keys(reward="r")   # the flow loss reads no reward


def test_noise_the_tensordict_lacks_is_drawn_from_the_generator(tmp_path):
    """Without noise entries a module draws ε, then k, from its generator: equal generators give equal
    losses, equal to the functional loss fed those draws; another seed another loss."""
    nets_m, nets_f = _pair(tmp_path, "td3")
    batch, noise = make_batch()
    td = _sample(batch, noise).exclude("flow_noise", "flow_time")
    out = SF2FlowLoss(nets_m, generator=torch.Generator().manual_seed(3))(td)
    g = torch.Generator().manual_seed(3)
    eps = torch.randn(batch.obs.shape, dtype=torch.float64, generator=g)
    k = torch.rand(batch.obs.shape[:1], dtype=torch.float64, generator=g)
    with torch.no_grad():
        next_action = networks.td3_action(nets_f, batch.next_obs, target=True)
    assert torch.equal(out["loss_flow"], losses.flow_loss(nets_f, batch, next_action, eps, k)[0])
    other = SF2FlowLoss(nets_m, generator=torch.Generator().manual_seed(4))(td)
    assert not torch.equal(out["loss_flow"], other["loss_flow"])


def test_batch_shapes_flags_and_bad_input(tmp_path):
    """A sample of two batch dimensions is flattened; without a truncated entry, truncation is done and not
    terminated; a sample without the flags, or of a wrong shape, is refused naming the entry."""
    nets = make_nets("td3")
    batch, noise = make_batch()
    td = _sample(batch, noise)
    module = SF2CriticLoss(nets)
    flat = module(td)
    assert torch.equal(module(td.reshape(2, 3))["loss_qvalue"], flat["loss_qvalue"])
    assert torch.equal(module(td.exclude(("next", "truncated")))["loss_qvalue"], flat["loss_qvalue"])
    assert torch.equal(module.batch(td).truncation, batch.truncation)
    with pytest.raises(KeyError, match="truncated"):
        module(td.exclude(("next", "truncated"), ("next", "done")))
    bad = td.clone()
    bad.set(("next", "reward"), torch.zeros(6, 2, dtype=torch.float64))
    with pytest.raises(Exception, match=r"\('next', 'reward'\) must have shape \(6,\) or \(6, 1\)"):
        module(bad)
    with pytest.raises(ConfigError, match="next_action='target' is invalid"):
        SF2FlowLoss(nets, next_action="target")
    with pytest.raises(ConfigError, match="takes sf2_torch's Networks"):
        SF2CriticLoss(torch.nn.Linear(2, 2))


def test_import_sf2_torch_does_not_import_torchrl():
    code = ("import sys, sf2_torch; assert 'torchrl' not in sys.modules; "
            "assert sf2_torch.objectives.SF2FlowLoss and 'torchrl' in sys.modules")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]


def test_the_manuals_example_runs(tmp_path):
    """docs/torchrl.md's Python block, as a user pastes it, in a fresh interpreter."""
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
    assert len(blocks) == 1
    done = subprocess.run([sys.executable, "-c", blocks[0]], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
