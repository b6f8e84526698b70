"""The algorithms and the SGD step, without environments: the agents' losses are the core's on the
representation's critic, vanilla draws nothing of its own, one SGD step follows the contract's order,
targets move at their rates, schedules keep skipped groups whole, no host synchronization, and (slow,
opt-in) `torch.compile` of the step gives the eager numbers. The full-step equality with `sf2_jax` is
tests/test_step_agents_cross.py of the repository."""

from __future__ import annotations

import copy
import os

import numpy as np
import pytest
import torch
from sf2_common.config import SF2Config
from sf2_torch import losses, networks
from sf2_torch import params as params_mod
from sf2_torch.agents import algorithms, representations

D, A, B = 5, 2, 8


def _batch(seed=0, b=B):
    g = torch.Generator().manual_seed(seed)
    trunc = (torch.rand(b, generator=g) < 0.3).float()
    done = torch.maximum((torch.rand(b, generator=g) < 0.2).float(), trunc)
    return losses.Batch(obs=torch.randn(b, D, generator=g) * 2 + 1,
                        action=torch.rand(b, A, generator=g) * 2 - 1,
                        reward=torch.rand(b, generator=g), discount=1.0 - done,
                        next_obs=torch.randn(b, D, generator=g) * 2 + 1, truncation=trunc)


def _algo(name="td3", rep="sf2", cls=None, **kw):
    torch.manual_seed(0)
    cfg = SF2Config.small(D, A, gamma_su=0.9, **kw)
    algo = algorithms.make_algorithm(name, cfg, cls or representations.get(rep))
    # a non-trivial normalizer and targets that differ from the online networks
    obs = torch.randn(64, D, generator=torch.Generator().manual_seed(9)) * 2 + 1
    networks.update_normalizer(algo.nets.obs_norm, obs, cfg)
    with torch.no_grad():
        for group, module in algo.groups.items():
            if group.startswith("target_"):
                for p in module.parameters():
                    p.mul_(0.9).add_(0.01)
    return algo


def _noise(algo, batch, seed=0):
    return algo.step_noise(torch.Generator().manual_seed(100 + seed), batch)


def _flat(algo):
    return params_mod.to_canonical(algo.groups)


@pytest.mark.parametrize("name", ["td3", "sac"])
def test_sf2_agent_losses_are_the_core_losses(name):
    """The SF² agent trains with the core's default (SF²) critic: its critic, policy and flow losses equal
    `sf2_torch.losses` called without `critic=`."""
    algo = _algo(name)
    batch = _batch()
    noise = _noise(algo, batch)
    nets = algo.nets
    crit, aux = algo.critic_loss(batch, noise)
    policy = algo.policy_losses(batch, noise)
    if name == "td3":
        ref = losses.td3_critic_loss(nets, batch, noise["smoothing_noise"])
        refs = {"policy": losses.td3_actor_loss(nets, batch)}
    else:
        ref = losses.sac_critic_loss(nets, batch, noise["next_action_noise"])
        refs = {"policy": losses.sac_actor_loss(nets, batch, noise["actor_noise"]),
                "log_alpha": losses.sac_alpha_loss(nets, batch, noise["alpha_noise"])}
    torch.testing.assert_close(crit, ref[0], rtol=0, atol=0)
    torch.testing.assert_close(aux["q"], ref[1]["q"], rtol=0, atol=0)
    assert set(policy) == set(refs) == set(algo.policy_groups)
    for group, (metric, loss, _) in policy.items():
        torch.testing.assert_close(loss, refs[group][0], rtol=0, atol=0)
        assert metric == {"policy": "actor_loss", "log_alpha": "alpha_loss"}[group]
    next_action = algo.aux_next_action(batch, noise)
    flow = losses.flow_loss(nets, batch, next_action, noise["flow_noise"], noise["flow_time"])
    torch.testing.assert_close(algo.rep.aux_loss(batch, next_action, noise)[0], flow[0], rtol=0, atol=0)


@pytest.mark.parametrize("name", ["td3", "sac"])
def test_vanilla_critic_and_explicit_noise(name):
    """`none` is the same losses on Q(s, a) = VanillaQ(concat[normalize(s), a]) (canonical names as
    sf2_jax's VanillaQ), and its step draws nothing: the same noise gives the same step whatever torch's
    global generator holds."""
    algo = _algo(name, "none")
    assert isinstance(algo.groups["q"], representations.VanillaQ)
    flat = _flat(algo)
    assert flat["q.head_0.dense_0.kernel"].shape == (D + A, 32)
    assert "q.head_1.layer_norm_1.scale" in flat and "target_q.head_1.dense_2.bias" in flat
    assert not any(n.startswith(("psi.", "zeta.")) for n in flat)
    batch = _batch()
    x = torch.cat([networks.normalize(batch.obs, algo.nets.obs_norm), batch.action], -1)
    q = algo.rep.critic(batch.obs, batch.action)
    torch.testing.assert_close(q, torch.cat([algo.groups["q"].head_0(x), algo.groups["q"].head_1(x)], -1))
    noise = _noise(algo, batch)
    twin = copy.deepcopy(algo)
    torch.manual_seed(1)
    m1 = algo.sgd_step(batch, noise, 0)
    torch.manual_seed(2)
    m2 = twin.sgd_step(batch, noise, 0)
    assert m1.keys() == m2.keys()
    for k in m1:
        assert torch.equal(m1[k], m2[k]), k
    a, b = _flat(algo), _flat(twin)
    assert all(np.array_equal(a[n], b[n]) for n in a)


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
    batch = _batch()
    noise = _noise(algo, batch)
    algo.sgd_step(batch, noise, 0)  # the first call builds lazy state
    with monkeypatch.context() as m:
        _forbid_host_sync(m)
        metrics = algo.sgd_step(batch, noise, 1)
    expected = {"critic_loss", "q", "actor_loss"} | (
        {"flow_loss", "loss_p", "loss_boot"} if rep == "sf2" else set()) | (
        {"alpha_loss", "alpha", "entropy"} if name == "sac" else set())
    assert set(metrics) == expected and all(v.ndim == 0 for v in metrics.values())


@pytest.mark.parametrize("name", ["td3", "sac"])
def test_policy_step_uses_the_pre_step_critic(name):
    """The policy groups' gradients are their losses' gradients at the parameters before the step (the
    critic and flow steps change Q and ψ first)."""
    algo = _algo(name)
    batch = _batch()
    noise = _noise(algo, batch)
    ref = copy.deepcopy(algo)
    for group, (_, loss, _) in ref.policy_losses(batch, noise).items():
        loss.backward(inputs=ref._params((group,)))
    algo.sgd_step(batch, noise, 0)
    for group in algo.policy_groups:
        for p, r in zip(algo._params((group,)), ref._params((group,))):
            torch.testing.assert_close(p.grad, r.grad, rtol=1e-6, atol=1e-8)


def test_delayed_step_and_target_rates():
    """policy_delay 2: step 1 leaves the policy, π̄ and Q̄ alone; ψ̄ and ζ̄ move every step, each at its
    rate: target ← target + τ (online after the step − target)."""
    algo = _algo("td3", policy_delay=2, tau=0.1, tau_zeta=0.5)
    assert algo.updates_q_target(0) and not algo.updates_q_target(1)
    algo.sgd_step(_batch(0), _noise(algo, _batch(0)), 0)
    before = _flat(algo)
    metrics = algo.sgd_step(_batch(1), _noise(algo, _batch(1), 1), 1)
    after = _flat(algo)
    assert metrics["actor_loss"].item() == 0.0
    for name in before:
        moved = not np.array_equal(before[name], after[name])
        if name.startswith(("policy.", "target_policy.", "target_q.", "obs_norm.")):
            assert not moved, name
        elif name.startswith(("psi.", "zeta.", "q.", "target_psi.", "target_zeta.")):
            assert moved, name
    for name, tau in (("psi.dense_0.kernel", 0.1), ("zeta.dense_0.kernel", 0.5)):
        expected = before[f"target_{name}"] + tau * (after[name] - before[f"target_{name}"])
        np.testing.assert_allclose(after[f"target_{name}"], expected, rtol=1e-6, atol=1e-7)
    before = after
    algo.sgd_step(_batch(2), _noise(algo, _batch(2), 2), 2)
    after = _flat(algo)
    for name in ("q.head_0.dense_0.kernel", "policy.dense_0.kernel"):
        expected = before[f"target_{name}"] + 0.1 * (after[name] - before[f"target_{name}"])
        np.testing.assert_allclose(after[f"target_{name}"], expected, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("rep", ["sf2", "none"])
@pytest.mark.parametrize("name", ["td3", "sac"])
def test_noise_keys_are_what_step_noise_draws(name, rep):
    algo = _algo(name, rep)
    g = torch.Generator().manual_seed(0)
    batch = losses.Batch(*(torch.zeros(3, *x.shape) for x in _batch()))  # a (G, B) stack of batches
    noise = algo.step_noise(g, batch)
    assert list(noise) == list(algo.noise_keys())
    assert all(v.shape[:2] == (3, B) for v in noise.values())
    assert set(algo.rep.noise_keys) <= set(noise)
    assert noise["flow_noise"].shape == (3, B, D) if rep == "sf2" else True


@pytest.mark.parametrize("name", ["td3", "sac"])
def test_more_aux_steps_draw_after_todays_noise_and_step_without_host_sync(name, monkeypatch):
    """`aux_steps_per_sgd_step` = 3: the draws of flow steps 2 and 3 come after k = 1's from the same
    generator (so k = 1's draws stay as they were), as "<key>:more" of shape (G, 2, B, ...) for a (G, B)
    stack (the trainer's); the step takes one Adam step per flow step on ζ (ψ: the critic's and 3) and
    makes no host synchronization."""
    one, three = _algo(name), _algo(name, aux_steps_per_sgd_step=3)
    stack = losses.Batch(*(torch.stack([x, x + 1]) for x in _batch()))   # G = 2
    a, b = (alg.step_noise(torch.Generator().manual_seed(0), stack) for alg in (one, three))
    assert list(b) == list(three.noise_keys()) == list(one.noise_keys()) + [
        f"{k}:more" for k in three.aux_noise_keys()]
    assert three.aux_noise_keys() == ("flow_action_noise",) * (name == "sac") + ("flow_noise", "flow_time")
    for k in one.noise_keys():
        assert torch.equal(a[k], b[k]), k
    for k in three.aux_noise_keys():
        assert b[f"{k}:more"].shape == (2, 2, *a[k].shape[1:])
        assert not torch.equal(b[f"{k}:more"][:, 0], a[k])
    batch = losses.Batch(*(x[0] for x in stack))
    noise = {k: v[0] for k, v in b.items()}
    three.sgd_step(batch, noise, 0)   # the first call builds lazy state
    with monkeypatch.context() as m:
        _forbid_host_sync(m)
        three.sgd_step(batch, noise, 1)
    steps = {g: int(next(iter(o.state.values()))["step"]) for g, o in three.optimizers.items()}
    assert steps["zeta"] == 6 and steps["psi"] == 8 and steps["q"] == 2


class _ZetaEvery3(representations.SF2Representation):
    """SF² whose ζ takes its flow-step Adam step every 3rd gradient step only (a test schedule)."""

    aux_every = {"zeta": 3}


def test_aux_every_keeps_group_and_adam_state_off_period(monkeypatch):
    algo = _algo("td3", cls=_ZetaEvery3)
    zeta, psi = algo._params(("zeta",)), algo._params(("psi",))
    for i in range(5):
        batch = _batch(i)
        noise = _noise(algo, batch, i)
        before = [p.detach().clone() for p in zeta]
        state = {k: v.clone() for k, v in algo.optimizers["zeta"].state.get(zeta[0], {}).items()}
        target = algo.nets.target_zeta.dense_0.weight.detach().clone()
        if i == 4:  # the skip is decided on the host: no synchronization either way
            with monkeypatch.context() as m:
                _forbid_host_sync(m)
                algo.sgd_step(batch, noise, i)
        else:
            algo.sgd_step(batch, noise, i)
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


@pytest.mark.parametrize("shared_adam", [True, False])
def test_state_dict_round_trip(shared_adam):
    """A checkpoint holds every group and Adam state (ψ's second one, `psi:aux`, when `shared_adam` is
    False): a fresh agent loaded from it takes the same step."""
    algo = _algo("sac", shared_adam=shared_adam)
    algo.sgd_step(_batch(0), _noise(algo, _batch(0)), 0)
    steps = {g: int(next(iter(o.state.values()))["step"]) for g, o in algo.optimizers.items()
             if g in ("psi", "psi:aux")}
    assert steps == ({"psi": 2} if shared_adam else {"psi": 1, "psi:aux": 1})
    fresh = algorithms.make_algorithm("sac", algo.cfg, representations.get("sf2"))
    fresh.load_state_dict(copy.deepcopy(algo.state_dict()))
    batch = _batch(1)
    noise = _noise(algo, batch, 1)
    m1, m2 = algo.sgd_step(batch, noise, 1), fresh.sgd_step(batch, noise, 1)
    assert all(torch.equal(m1[k], m2[k]) for k in m1)
    a, b = _flat(algo), _flat(fresh)
    assert all(np.array_equal(a[n], b[n]) for n in a)


def test_a_checkpoint_keeps_the_loading_agents_adam_flags():
    """`load_state_dict` takes the moments and step counts, but keeps the loading agent's Adam flags and
    learning rate (torch's own `Optimizer.load_state_dict` would take the saved ones: a run with compiled
    updates, foreach and capturable, resuming a checkpoint of the fused Adam would step it fused; a CPU run
    resuming a CUDA-graph run's checkpoint would get a tensor learning rate, which foreach Adam refuses
    without capturable), and puts the step counts where those flags keep them (float32; on the agent's
    device when capturable or fused). Both ways, and the resumed CPU agent takes the same step."""
    plain = _algo("td3")
    plain.sgd_step(_batch(0), _noise(plain, _batch(0)), 0)
    torch.manual_seed(0)
    graphed = algorithms.make_algorithm("td3", plain.cfg, representations.get("sf2"), cudagraphs=True)
    saved = copy.deepcopy(plain.state_dict())
    for o in saved["optimizers"].values():   # as a fused Adam on another run would have written them
        o["param_groups"][0].update(fused=True, foreach=None, capturable=False)
    graphed.load_state_dict(saved)
    for g, o in graphed.optimizers.items():
        group = o.param_groups[0]
        assert (group["capturable"], group["fused"], group["foreach"]) == (True, None, True), g
        assert torch.is_tensor(group["lr"]), g
        for p, s in o.state.items():
            assert s["step"].dtype == torch.float32 and s["step"].device == p.device, g
        for mine, theirs in zip(group["params"], plain.optimizers[g].param_groups[0]["params"]):
            torch.testing.assert_close(o.state[mine]["exp_avg"], plain.optimizers[g].state[theirs]["exp_avg"])
    fresh = _algo("td3")
    fresh.load_state_dict(graphed.state_dict())
    for g, o in fresh.optimizers.items():
        group = o.param_groups[0]
        assert (group["capturable"], group["fused"], group["foreach"]) == (False, None, True), g
        assert not torch.is_tensor(group["lr"]), g
        assert all(s["step"].device.type == "cpu" for s in o.state.values())
    batch = _batch(1)
    noise = _noise(plain, batch, 1)
    m1, m2 = plain.sgd_step(batch, noise, 1), fresh.sgd_step(batch, noise, 1)
    assert all(torch.equal(m1[k], m2[k]) for k in m1)


@pytest.mark.parametrize("name,shared_adam", [("td3", True), ("sac", False)])
def test_compiled_updates_path_equals_optimizer_step(name, shared_adam, monkeypatch):
    """The updates `compile_mode` compiles on CUDA, run uncompiled (torch.compile stubbed to return them):
    Adam through `_adam_steps` on the lists `_adam_inputs` gathers (each optimizer's first step eager, which
    creates its state) and the target lerps through `_move_targets` give, bit for bit, the parameters,
    every Adam state and the metrics of `optimizer.step()` and the plain foreach lerps, over three steps
    (an actor step and a step without, for TD3; SAC's log α has its own learning rate and ε)."""
    plain, fast = _algo(name, shared_adam=shared_adam), _algo(name, shared_adam=shared_adam)
    monkeypatch.setattr(torch, "compile", lambda fn, **kw: fn)
    fast.compile_updates = True   # what `compile_mode` sets on CUDA
    calls = []
    monkeypatch.setattr(algorithms, "_adam_steps",
                        lambda inputs, f=algorithms._adam_steps: (calls.append(len(inputs)), f(inputs)))
    for i in range(3):
        batch = _batch(i)
        noise = _noise(plain, batch, i)
        m1, m2 = plain.sgd_step(batch, noise, i), fast.sgd_step(batch, noise, i)
        assert all(torch.equal(m1[k], m2[k]) for k in m1)
    assert calls, "the functional Adam path never ran"
    a, b = _flat(plain), _flat(fast)
    assert all(np.array_equal(a[n], b[n]) for n in a)
    for g, opt in plain.optimizers.items():
        for p1, p2 in zip(opt.param_groups[0]["params"], fast.optimizers[g].param_groups[0]["params"]):
            s1, s2 = opt.state[p1], fast.optimizers[g].state[p2]
            assert all(torch.equal(s1[k], s2[k]) for k in ("step", "exp_avg", "exp_avg_sq")), g


@pytest.mark.skipif(not os.environ.get("SF2_TORCH_SLOW"), reason="torch.compile takes minutes on a small "
                    "CPU; set SF2_TORCH_SLOW=1")
@pytest.mark.parametrize("name", ["td3", "sac"])
def test_compiled_step_equals_eager(name):
    eager, compiled = _algo(name), _algo(name)
    compiled.compile_mode = "default"
    for i in range(3):
        batch = _batch(i)
        noise = _noise(eager, batch, i)
        m1, m2 = eager.sgd_step(batch, noise, i), compiled.sgd_step(batch, noise, i)
        for k in m1:
            torch.testing.assert_close(m1[k], m2[k], rtol=1e-4, atol=1e-5)
    a, b = _flat(eager), _flat(compiled)
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-4, atol=1e-5)
