"""sf2_baselines.torch: modules, pure losses (gradients land only where they should), canonical parameters."""

from __future__ import annotations

import functools

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("sf2_torch")

from baselines_helpers import A, B, D, laplacian_reference, numpy_batch, numpy_noise, small_kwargs  # noqa: E402
from sf2_baselines.torch import params as bparams  # noqa: E402
from sf2_baselines.torch import sim, simlap, spr  # noqa: E402
from sf2_common.errors import ConfigError, ParamsError, ShapeError  # noqa: E402
from sf2_torch import SF2Config, losses  # noqa: E402
from sf2_torch.losses import Batch  # noqa: E402

f64 = torch.float64


def _batch(seed=0, truncation=True, batch_size=B):
    return Batch(
        **{k: torch.as_tensor(v, dtype=f64) for k, v in numpy_batch(seed, batch_size, truncation).items()}
    )


def _noise(seed=0, batch_size=B):
    return {k: torch.as_tensor(v, dtype=f64) for k, v in numpy_noise(seed, batch_size).items()}


def _nets(module, algo="td3", seed=0, **kw):
    torch.manual_seed(seed)
    nets = module.make_networks(SF2Config(**small_kwargs(**kw)), algo, dtype=f64)
    with torch.no_grad():
        nets.obs_norm.mean.fill_(0.3)
        nets.obs_norm.std.fill_(1.7)
        for name, module_ in nets.named_children():
            if name.startswith("target_"):
                for p in module_.parameters():
                    p.mul_(0.9).add_(0.01)
    return nets


def _trained(nets, loss):
    """Top-level groups whose parameters got a nonzero .grad from `loss`."""
    nets.zero_grad(set_to_none=True)
    loss.backward()
    out = set()
    for name, p in nets.named_parameters():
        if p.grad is not None and torch.any(p.grad != 0):
            out.add(name.split(".")[0])
    return out


def test_sim_modules_and_shapes():
    nets = _nets(sim)
    shapes = bparams.expected_shapes(nets)
    F, H = 16, 24
    assert shapes["task.w"] == (F,)
    assert shapes["phi.dense_0.kernel"] == (D + A + F, 32)
    assert shapes["q.head_1.dense_1.kernel"] == (H, F)
    assert {k.split(".")[0] for k in shapes} == {"obs_norm", "policy", "target_policy", *sim.GROUPS}
    b = _batch()
    phi = sim.features(nets, b.obs, b.action)
    assert phi.shape == (B, F) and sim.successor_features(nets, phi).shape == (B, 2, F)
    psi = sim.successor_features(nets, phi)
    torch.testing.assert_close(sim.critic(nets, b.obs, b.action), psi @ nets.task.w)
    assert not any(p.requires_grad for n, p in nets.named_parameters() if n.startswith("target_"))


def test_sim_feature_size_512():
    """README.md "Sim": the authors' Sim breaks at F = 512; here w is one (F,) parameter."""
    nets = _nets(sim, feature_size=512, q_hidden_size=16)
    assert tuple(nets.task.w.shape) == (512,)
    b, n = _batch(), _noise()
    assert torch.isfinite(simlap.simlap_loss(nets, b, n["next_action"])[0])
    critic = functools.partial(sim.critic, nets)
    assert torch.isfinite(losses.td3_critic_loss(nets, b, n["smoothing"], critic=critic)[0])


@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_each_loss_trains_exactly_its_groups(algo):
    """The baselines' own losses reach only the groups they train; their TD3/SAC losses are the core's on
    the baseline's critic, whose graph reaches every online group the critic reads (the agents choose the
    trained ones with `backward(inputs=...)`: the representation's critic groups)."""
    b, n = _batch(), _noise()
    xi = n["smoothing"] if algo == "td3" else n["noise"]
    nets = _nets(sim, algo)
    cases = [
        (lambda: sim.reward_loss(nets, b, n["next_action"]), {"task"}),
        (lambda: simlap.laplacian_loss(nets, b, n["next_action"]), {"phi"}),
        (lambda: simlap.simlap_loss(nets, b, n["next_action"]), {"phi", "task"}),
    ]
    for fn, groups in cases:
        assert _trained(nets, fn()[0]) == groups
    crit = getattr(losses, f"{algo}_critic_loss")
    assert _trained(nets, crit(nets, b, xi, critic=functools.partial(sim.critic, nets))[0]) == {
        "q", "phi", "task"}
    snets = _nets(spr, algo)
    spr_loss = spr.spr_loss(snets, b, n["next_action"], n["obs_noise"], n["next_obs_noise"])[0]
    assert _trained(snets, spr_loss) == {"encoder", "projection", "prediction"}
    assert _trained(snets, crit(snets, b, xi, critic=functools.partial(spr.critic, snets))[0]) == {
        "q", "encoder"}


def test_task_input_is_normalized_and_detached():
    nets = _nets(sim)
    b = _batch()
    before = sim.features(nets, b.obs, b.action).detach()
    with torch.no_grad():
        nets.task.w.mul_(3.0)
    torch.testing.assert_close(sim.features(nets, b.obs, b.action).detach(), before)
    assert "task" not in _trained(nets, sim.features(nets, b.obs, b.action).square().sum())


def test_laplacian_loss_matches_reference():
    nets = _nets(simlap)
    b, n = _batch(), _noise()
    with torch.no_grad():
        phi = sim.features(nets, b.obs, b.action)
        phi_next = sim.features(nets, b.next_obs, n["next_action"])
        loss, aux = simlap.laplacian_loss(nets, b, n["next_action"])
    want = laplacian_reference(phi.numpy(), phi_next.numpy(), 1 - b.truncation.numpy())
    np.testing.assert_allclose(float(loss), want, rtol=1e-10)
    np.testing.assert_allclose(float(loss), float(aux["lap_term"] + aux["orth_diag"] + aux["orth_offdiag"]))
    with pytest.raises(ShapeError, match="B >= 2"):
        simlap.laplacian_loss(nets, _batch(batch_size=1), _noise(batch_size=1)["next_action"])


def test_spr_loss_is_two_minus_two_cosine_and_augments():
    nets = _nets(spr)
    b, n = _batch(truncation=False), _noise()
    loss, aux = spr.spr_loss(nets, b, n["next_action"], n["obs_noise"], n["next_obs_noise"])
    np.testing.assert_allclose(float(loss.detach()), 2 - 2 * float(aux["spr_cosine"]), rtol=1e-6)
    with torch.no_grad():
        clean = spr.features(nets, b.obs, b.action)
        assert not torch.allclose(clean, spr.features(nets, b.obs, b.action, obs_noise=n["obs_noise"]))
        nets.augmentation_std = 0.0
        torch.testing.assert_close(spr.features(nets, b.obs, b.action, obs_noise=n["obs_noise"]), clean)
    with pytest.raises(ConfigError, match="augmentation_std"):
        spr.make_networks(nets.cfg, "td3", augmentation_std=-0.1)


def test_shape_errors():
    nets = _nets(sim)
    b, n = _batch(), _noise()
    with pytest.raises(ShapeError, match="obs_size"):
        sim.critic(nets, torch.zeros(B, D + 1, dtype=f64), b.action)
    with pytest.raises(ShapeError, match="next_action"):
        sim.reward_loss(nets, b, torch.zeros(B, A + 1, dtype=f64))
    with pytest.raises(ConfigError, match="algo"):
        sim.make_networks(nets.cfg, "ppo")
    stacked = Batch(*(torch.stack([v, v]) for v in b))
    with pytest.raises(ShapeError, match="a 2-D batch"):
        sim.reward_loss(nets, stacked, torch.stack([n["next_action"]] * 2))


@pytest.mark.parametrize("module", [sim, spr])
@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_canonical_roundtrip(tmp_path, module, algo):
    nets = _nets(module, algo, seed=1)
    flat = bparams.to_canonical(nets)
    path = bparams.save(tmp_path / "p.npz", flat)
    other = _nets(module, algo, seed=2)
    bparams.from_canonical(bparams.load(path), other)
    b = _batch()
    with torch.no_grad():
        torch.testing.assert_close(
            module.critic(other, b.obs, b.action), module.critic(nets, b.obs, b.action)
        )
    bad = dict(flat)
    key = "task.w" if module is sim else "projection.dense_0.kernel"
    bad[key] = np.zeros((7,))
    with pytest.raises(ParamsError, match=key.replace(".", r"\.")):
        bparams.from_canonical(bad, other)


def _minimize(loss_fn, params, steps=150):
    opt = torch.optim.Adam(list(params), lr=1e-2)
    first = float(loss_fn().detach())
    for _ in range(steps):
        opt.zero_grad()
        loss_fn().backward()
        opt.step()
    return first, float(loss_fn().detach())


def test_losses_can_be_minimized():
    b, n = _batch(truncation=False, batch_size=32), _noise(batch_size=32)
    nets, snets = _nets(sim), _nets(spr)
    first, last = _minimize(
        lambda: simlap.laplacian_loss(nets, b, n["next_action"])[0], nets.phi.parameters()
    )
    assert last < first - 0.3
    first, last = _minimize(
        lambda: spr.spr_loss(snets, b, n["next_action"], n["obs_noise"], n["next_obs_noise"])[0],
        [*snets.encoder.parameters(), *snets.projection.parameters(), *snets.prediction.parameters()],
    )
    assert last < 0.2 * first
