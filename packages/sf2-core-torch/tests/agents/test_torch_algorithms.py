"""The TorchRL loss modules and the SGD step, without environments: the SF² loss modules compute the
core's losses, follow TorchRL's key and target conventions, the vanilla modules reduce TorchRL's losses
to the JAX trainer's formulas, one SGD step follows the contract's order, makes no host synchronization,
and (slow, opt-in) `torch.compile` of the step gives the eager numbers. The full-step equality with
`sf2_jax` is tests/test_step_agents_cross.py of the repository."""

from __future__ import annotations

import copy
import os

import numpy as np
import pytest
import torch
from sf2_torch import losses, networks
from sf2_torch import params as params_mod
from sf2_torch.agents import algorithms, objectives, representations
from sf2_torch.config import SF2Config
from tensordict import TensorDict

D, A, B = 5, 2, 8


def _td(seed=0, b=B, truncated=True):
    g = torch.Generator().manual_seed(seed)
    trunc = (torch.rand(b, 1, generator=g) < 0.3) if truncated else torch.zeros(b, 1, dtype=torch.bool)
    done = (torch.rand(b, 1, generator=g) < 0.2) | trunc
    return TensorDict({
        "observation": torch.randn(b, D, generator=g) * 2 + 1,
        "action": torch.rand(b, A, generator=g) * 2 - 1,
        "next": {"observation": torch.randn(b, D, generator=g) * 2 + 1,
                 "reward": torch.rand(b, 1, generator=g),
                 "done": done, "terminated": done & ~trunc, "truncated": trunc},
    }, [b])


def _batch(td):
    nxt = td["next"]
    return losses.Batch(td["observation"], td["action"], nxt["reward"][:, 0], 1.0 - nxt["done"][:, 0].float(),
                        nxt["observation"], nxt["truncated"][:, 0].float())


def _algo(name="td3", rep="sf2", **kw):
    torch.manual_seed(0)
    cfg = SF2Config.small(D, A, gamma_su=0.9, **kw)
    algo = algorithms.make_algorithm(name, cfg, representations.get(rep))
    # a non-trivial normalizer and targets that differ from the online networks
    algo.observe(torch.randn(64, D, generator=torch.Generator().manual_seed(9)) * 2 + 1)
    with torch.no_grad():
        for module in algo.nets.target_modules().values():
            for p in module.parameters():
                p.mul_(0.9).add_(0.01)
    return algo


def _noisy_td(algo, seed=0):
    td = _td(seed)
    td.update(algo.draw_noise((B,), torch.Generator().manual_seed(100 + seed)))
    return td


@pytest.mark.parametrize("name", ["td3", "sac"])
def test_sf2_loss_modules_equal_the_core_losses(name):
    algo = _algo(name)
    td = _noisy_td(algo)
    out = algo.loss(td)
    nets, batch = algo.nets, _batch(td)
    if name == "td3":
        crit, aux = losses.td3_critic_loss(nets, batch, td["smoothing_noise"])
        actor, _ = losses.td3_actor_loss(nets, batch)
    else:
        crit, aux = losses.sac_critic_loss(nets, batch, td["next_action_noise"])
        actor, _ = losses.sac_actor_loss(nets, batch, td["actor_noise"])
        alpha, _ = losses.sac_alpha_loss(nets, batch, td["alpha_noise"])
        torch.testing.assert_close(out["loss_alpha"], alpha)
    torch.testing.assert_close(out["loss_qvalue"], crit)
    torch.testing.assert_close(out["loss_actor"], actor)
    torch.testing.assert_close(out["pred_value"], aux["q"])
    next_action = torch.rand(B, A, generator=torch.Generator().manual_seed(3)) * 2 - 1
    flow_td = td.clone(False).set("next_action", next_action)
    flow, faux = losses.flow_loss(nets, batch, next_action, td["flow_noise"], td["flow_time"])
    fout = algo.rep.aux_loss(flow_td)
    torch.testing.assert_close(fout["loss_flow"], flow)
    torch.testing.assert_close(fout["loss_boot"], faux["loss_boot"])


def test_set_keys_renames_every_input():
    algo = _algo("td3")
    td = _noisy_td(algo)
    renamed = TensorDict({"obs": td["observation"], "act": td["action"], "xi": td["smoothing_noise"],
                          "next": {"obs": td["next", "observation"], "r": td["next", "reward"],
                                   "d": td["next", "done"], "t": td["next", "truncated"]}}, [B])
    loss = objectives.TD3SF2Loss(algo.nets)
    with pytest.raises(ValueError, match="not an accepted tensordict key"):
        loss.set_keys(bogus="x")
    loss.set_keys(observation="obs", action="act", smoothing_noise="xi", reward="r", done="d", truncated="t")
    torch.testing.assert_close(loss(renamed)["loss_qvalue"], algo.loss(td)["loss_qvalue"])
    with pytest.raises(KeyError, match="explicit noise"):
        algo.loss(td.exclude("smoothing_noise"))


def test_targets_are_shared_and_soft_updated_at_their_rates():
    algo = _algo("td3", tau=0.1, tau_zeta=0.5)
    nets, flow = algo.nets, algo.rep.aux_loss
    assert flow.target_zeta_network_params["dense_0", "weight"] is nets.target_zeta.dense_0.weight
    target_q = algo.loss.target_qvalue_network_params
    assert target_q["head_0", "dense_0", "weight"] is nets.target_q.head_0.dense_0.weight
    before = params_mod.to_canonical(nets)
    algo.rep.target_updater.step()  # TorchRL's SoftUpdate API, with a rate per network
    after = params_mod.to_canonical(nets)
    for name, tau in (("psi.dense_0.kernel", 0.1), ("zeta.dense_0.kernel", 0.5)):
        expected = before[f"target_{name}"] + tau * (before[name] - before[f"target_{name}"])
        np.testing.assert_allclose(after[f"target_{name}"], expected, rtol=1e-6, atol=1e-7)
    name = "target_q.head_0.dense_0.kernel"
    np.testing.assert_array_equal(after[name], before[name])


@pytest.mark.parametrize("name", ["td3", "sac"])
def test_vanilla_torchrl_losses_reduce_to_the_jax_formulas(name):
    """TorchRL's TD3Loss/SACLoss with squared error, re-reduced: ½ mean_{b,j}(m_b(Q_j − y))²."""
    algo = _algo(name, rep="none", reward_scaling=2.0)
    loss = algo.loss
    assert loss.loss_function == "l2"
    td = _noisy_td(algo)
    torch.manual_seed(5)
    out = loss(td)
    # the same TD target by hand, with the same noise TorchRL draws (seed 5, first draw)
    nets, batch = algo.nets, _batch(td)
    cfg = algo.cfg
    obs_n = networks.normalize(batch.obs, nets.obs_norm)
    next_n = networks.normalize(batch.next_obs, nets.obs_norm)
    qp, tqp = loss.qvalue_network_params, loss.target_qvalue_network_params

    def q(params, o, a):
        heads = []
        for j in range(2):
            mod = copy.deepcopy(loss.qvalue_network)
            params[j].to_module(mod)
            heads.append(mod.module(o, a)[:, 0])
        return torch.stack(heads, -1)

    torch.manual_seed(5)
    with torch.no_grad():
        if name == "td3":
            noise = torch.randn_like(batch.action) * cfg.smoothing_noise
            noise = noise.clamp(-cfg.noise_clip, cfg.noise_clip)
            target_actor = copy.deepcopy(loss.actor_network)
            loss.target_actor_network_params.to_module(target_actor)
            a2 = (target_actor.module(next_n) + noise).clamp(-1, 1)
            v = q(tqp, next_n, a2).min(-1).values
        else:  # TorchRL samples the action; check its distribution is the core's tanh-Gaussian
            dist = loss.actor_network.get_dist(TensorDict({"observation": next_n}, [B]))
            torch.manual_seed(6)
            a2 = dist.rsample()
            log_prob = dist.log_prob(a2)
            torch.manual_seed(6)
            core_a, core_lp = nets.policy.sample(next_n, torch.randn(B, A))
            torch.testing.assert_close(a2, core_a)
            torch.testing.assert_close(log_prob, core_lp)
            return
        not_terminal = 1.0 - td["next", "terminated"][:, 0].float()
        y = cfg.reward_scaling * batch.reward + not_terminal * cfg.discount * v
        err = (1.0 - batch.truncation)[:, None] * (q(qp, obs_n, batch.action) - y[:, None])
        torch.testing.assert_close(out["loss_qvalue"], 0.5 * (err**2).mean())


def _forbid_host_sync(monkeypatch):
    """Every tensor → Python conversion raises, except torch.optim's reads of its step counters, which
    non-capturable Adam keeps on the host by design (on CUDA, `capturable=True` keeps them on the GPU)."""
    import sys

    for name in ("item", "tolist", "numpy", "__bool__", "__float__", "__int__"):
        original = getattr(torch.Tensor, name)

        def refuse(self, *args, _name=name, _original=original, **kwargs):
            caller = sys._getframe(1).f_code.co_filename
            if _name == "item" and f"torch{os.sep}optim{os.sep}" in caller and self.device.type == "cpu":
                return _original(self, *args, **kwargs)
            raise AssertionError(f"host synchronization inside the SGD step: Tensor.{_name} from {caller}")

        monkeypatch.setattr(torch.Tensor, name, refuse)


@pytest.mark.parametrize("rep", ["sf2", "none"])
@pytest.mark.parametrize("name", ["td3", "sac"])
def test_sgd_step_makes_no_host_synchronization(name, rep, monkeypatch):
    algo = _algo(name, rep)
    td = _noisy_td(algo)
    algo.sgd_step(td)  # the first call builds lazy state
    with monkeypatch.context() as m:
        _forbid_host_sync(m)
        metrics = algo.sgd_step(td)
    expected = {"critic_loss", "q", "actor_loss"} | (
        {"flow_loss", "loss_p", "loss_boot"} if rep == "sf2" else set()) | (
        {"alpha_loss", "alpha", "entropy"} if name == "sac" else set())
    assert set(metrics.keys()) == expected


def test_actor_step_uses_the_pre_step_critic():
    """The policy's gradient is the actor loss's gradient at the parameters before the step."""
    algo = _algo("td3")
    td = _noisy_td(algo)
    ref = copy.deepcopy(algo.nets)
    ref.zero_grad()
    losses.td3_actor_loss(ref, _batch(td))[0].backward()
    algo.sgd_step(td, actor_step=True)
    for p, r in zip(algo.nets.policy.parameters(), ref.policy.parameters()):
        torch.testing.assert_close(p.grad, r.grad)
    # a delayed step leaves the policy and its target alone but moves ψ̄ and ζ̄
    before = params_mod.to_canonical(algo.nets)
    algo.sgd_step(_noisy_td(algo, 1), actor_step=False)
    after = params_mod.to_canonical(algo.nets)
    for name in before:
        moved = not np.array_equal(before[name], after[name])
        if name.startswith(("policy.", "target_policy.", "target_q.", "obs_norm.")):
            assert not moved, name
        elif name.startswith(("psi.", "zeta.", "target_psi.", "target_zeta.")) and name.endswith("kernel"):
            assert moved, name


@pytest.mark.parametrize("rep", ["sf2", "none"])
@pytest.mark.parametrize("name", ["td3", "sac"])
def test_noise_keys_are_what_draw_noise_draws(name, rep):
    algo = _algo(name, rep)
    noise = algo.draw_noise((3, B), torch.Generator().manual_seed(0))
    assert list(noise) == list(algo.noise_keys())
    assert all(v.shape[:2] == (3, B) for v in noise.values())
    assert set(algo.rep.noise_keys) <= set(noise)


class _ZetaEvery3(representations.SF2Representation):
    """SF² whose ζ takes its flow-step Adam step every 3rd gradient step only (a test schedule)."""

    aux_every = {"zeta": 3}


def test_aux_every_keeps_group_and_adam_state_off_period(monkeypatch):
    torch.manual_seed(0)
    algo = algorithms.make_algorithm("td3", SF2Config.small(D, A, gamma_su=0.9), _ZetaEvery3)
    zeta, psi = algo.groups["zeta"], algo.groups["psi"]
    for i in range(5):
        td = _noisy_td(algo, i)
        before = [p.detach().clone() for p in zeta]
        state = {k: v.clone() for k, v in algo.optimizers["zeta"].state.get(zeta[0], {}).items()}
        target = algo.nets.target_zeta.dense_0.weight.detach().clone()
        if i == 4:  # the skip is decided on the host: no synchronization either way
            with monkeypatch.context() as m:
                _forbid_host_sync(m)
                algo.sgd_step(td, step=i)
        else:
            algo.sgd_step(td, step=i)
        due = i % 3 == 0
        moved = any(not torch.equal(b, p) for b, p in zip(before, zeta))
        assert moved == due, (i, moved)
        new_state = algo.optimizers["zeta"].state[zeta[0]]
        assert int(new_state["step"]) == i // 3 + 1
        if not due:
            assert all(torch.equal(state[k], new_state[k]) for k in state)
        assert int(algo.optimizers["psi"].state[psi[0]]["step"]) == 2 * (i + 1)  # critic and flow steps
        assert not torch.equal(target, algo.nets.target_zeta.dense_0.weight)  # ζ̄ averaged every step


@pytest.mark.parametrize("every,message", [({"q": 2}, "not one of its aux_groups"),
                                           ({"zeta": 0}, "must be an int >= 1")])
def test_aux_every_is_validated(every, message):
    bad = type("Bad", (representations.SF2Representation,), {"aux_every": every})
    with pytest.raises(ValueError, match=message):
        algorithms.make_algorithm("td3", SF2Config.small(D, A), bad)


@pytest.mark.skipif(not os.environ.get("SF2_TORCH_SLOW"), reason="torch.compile takes minutes on a small "
                    "CPU; set SF2_TORCH_SLOW=1")
@pytest.mark.parametrize("name", ["td3", "sac"])
def test_compiled_step_equals_eager(name):
    eager, compiled = _algo(name), _algo(name)
    compiled.compile_mode = "default"
    for i in range(3):
        td = _noisy_td(eager, i)
        m1, m2 = eager.sgd_step(td), compiled.sgd_step(td.clone())
        for k in m1.keys():
            torch.testing.assert_close(m1[k], m2[k], rtol=1e-4, atol=1e-5)
    a, b = params_mod.to_canonical(eager.nets), params_mod.to_canonical(compiled.nets)
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-4, atol=1e-5)


def test_timing_tool_runs(tmp_path, capsys):
    from sf2_torch.agents import timing

    out = tmp_path / "t.json"
    args = ["--feature-size", "8", "--width", "16", "--embedding-size", "4", "--batch-size", "8",
            "--variants", "torch-eager", "--warmup", "1", "--steps", "3", "--json", str(out)]
    assert timing.main(args) == 0
    import json

    res = json.loads(out.read_text())["results"]["torch-eager"]
    assert res["steps"] == 3 and res["median_ms"] > 0
