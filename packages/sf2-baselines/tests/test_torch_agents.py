"""The baselines plugged into sf2_torch's agents: registration, shared modules, groups, critics, and SGD
steps that train exactly the right groups on their schedules."""

from __future__ import annotations

import os

import numpy as np
import pytest

torch = pytest.importorskip("torch")
reps = pytest.importorskip("sf2_torch.agents.representations")

import sf2_baselines.torch as bt  # noqa: E402
from baselines_helpers import numpy_batch, small_kwargs  # noqa: E402
from sf2_torch import SF2Config, params  # noqa: E402
from sf2_torch.agents.algorithms import make_algorithm  # noqa: E402
from sf2_torch.losses import Batch  # noqa: E402

CRITIC = {"sim": ("q", "phi"), "simlap": ("q",), "simlap_authors": ("q", "phi"), "spr": ("q", "encoder")}
AUX = {
    "sim": ("task",),
    "simlap": ("phi", "task"),
    "simlap_authors": ("phi", "task"),
    "spr": ("encoder", "projection", "prediction"),
}


MODULES = {"sim": bt.sim, "simlap": bt.simlap, "simlap_authors": bt.simlap, "spr": bt.spr}


def _batch(seed=0, dtype=torch.float64):
    return Batch(**{k: torch.as_tensor(np.asarray(v), dtype=dtype) for k, v in numpy_batch(seed).items()})


def _step(agent, seed, step, batch=None):
    """One SGD step on batch `seed` with the noise `step_noise` draws from a generator seeded `seed`."""
    batch = _batch(seed) if batch is None else batch
    return agent.sgd_step(batch, agent.step_noise(torch.Generator().manual_seed(seed), batch), step)


def test_registered():
    assert bt.REGISTERED == ("sim", "simlap", "simlap_authors", "spr")
    assert set(bt.REGISTERED) <= set(reps.names())


@pytest.mark.parametrize("algo", ["td3", "sac"])
@pytest.mark.parametrize("name", list(CRITIC))
def test_sgd_step_trains_the_right_groups(algo, name):
    torch.manual_seed(0)
    agent = make_algorithm(algo, SF2Config(**small_kwargs()), reps.get(name), dtype=torch.float64)
    nets = agent.rep.baseline_nets
    # the agent's normalizer, policy and log α are the baseline networks' own
    assert nets.obs_norm is agent.nets.obs_norm and nets.policy is agent.nets.policy
    if algo == "sac":
        assert nets.log_alpha is agent.nets.log_alpha
    assert ("q", *agent.rep.critic_groups) == CRITIC[name] and agent.rep.aux_groups == AUX[name]
    module = MODULES[name]
    assert set(agent.groups) == {"obs_norm", "policy", "target_policy" if algo == "td3" else "log_alpha",
                                 *module.GROUPS}
    b = _batch()
    for target in (False, True):  # the critic the base algorithm hands to the core's TD3/SAC losses
        torch.testing.assert_close(agent.rep.critic(b.obs, b.action, target),
                                   module.critic(nets, b.obs, b.action, target), rtol=0, atol=0)
    before = params.to_canonical(agent.groups)
    metrics = _step(agent, 0, 0)
    assert agent.rep.aux_loss_name in metrics
    assert all(np.isfinite(float(v)) for v in metrics.values())
    after = params.to_canonical(agent.groups)
    for group in {*CRITIC[name], *AUX[name], "policy", *(g for g in {n.split(".")[0] for n in before}
                                                          if g.startswith("target_"))}:  # fmt: skip
        assert any(not np.array_equal(before[n], after[n]) for n in before if n.split(".")[0] == group), group
    assert set(after) == set(bt.params.expected_shapes(nets))


@pytest.mark.parametrize("name,critic_steps_phi", [("simlap", False), ("simlap_authors", True)])
def test_simlap_critic_trains_features_only_in_the_authors_variant(name, critic_steps_phi):
    """The paper's SimLap: the TD step does not move φ (its Adam counts the Laplacian steps only); the
    authors' variant steps φ in both (two Adam steps per SGD step, one Adam state, as ψ in SF²)."""
    torch.manual_seed(0)
    agent = make_algorithm("td3", SF2Config(**small_kwargs()), reps.get(name), dtype=torch.float64)
    phi = agent._params(("phi",))[0]
    for i in range(3):
        _step(agent, i, i)
        assert int(agent.optimizers["phi"].state[phi]["step"]) == (i + 1) * (1 + critic_steps_phi)
        assert int(agent.optimizers["q"].state[agent._params(("q",))[0]]["step"]) == i + 1


@pytest.mark.parametrize("algo,every", [("td3", 10), ("sac", 16)])
@pytest.mark.parametrize("name", ["sim", "simlap"])
def test_task_vector_schedule(algo, every, name):
    """w and its Adam state (moments and step count) change only on gradient steps that are multiples of
    `aux_every['task']` (the authors' cond and separate w optimizer); the other trained groups step every
    time. Steps 0 .. every + 1, as the trainer numbers them."""
    torch.manual_seed(0)
    agent = make_algorithm(algo, SF2Config(**small_kwargs()), reps.get(name), dtype=torch.float64)
    assert agent.rep.aux_every == {"task": every}
    w = agent.rep.baseline_nets.task.w
    others = [g for g in agent.trained_groups() if g not in ("task", "log_alpha", "policy")]

    def count(g):
        return int(agent.optimizers[g].state.get(agent._params((g,))[0], {}).get("step", 0))

    for i in range(every + 2):
        w_before = w.detach().clone()
        state = {k: v.clone() for k, v in agent.optimizers["task"].state.get(w, {}).items()}
        counts = {g: count(g) for g in others}
        _step(agent, i, i)
        due = i % every == 0
        assert (not torch.equal(w_before, w)) == due, i
        new_state = agent.optimizers["task"].state[w]
        assert int(new_state["step"]) == i // every + 1
        if not due:
            assert all(torch.equal(state[k], new_state[k]) for k in state), i
        for g in others:
            assert count(g) > counts[g], (i, g)


@pytest.mark.parametrize(
    "device",
    [
        pytest.param("cpu", marks=pytest.mark.skipif(
            not os.environ.get("SF2_TORCH_SLOW"), reason="torch.compile takes minutes on a small CPU; set "
            "SF2_TORCH_SLOW=1")),
        pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")),
    ],
)  # fmt: skip
def test_compiled_schedule_equals_eager(device):
    """TD3Sim with `policy_delay` 2 over steps 0..21 (w due at 0, 10, 20): the compiled step (on CUDA
    also captured as CUDA graphs, one per schedule combination) follows the eager one, and w's Adam
    steps exactly 3 times in both."""
    cfg = SF2Config(**small_kwargs(policy_delay=2))
    agents = []
    for compiled in (False, True):
        torch.manual_seed(0)
        agents.append(make_algorithm("td3", cfg, reps.get("sim"), device=device,
                                     compile_mode="default" if compiled else None,
                                     cudagraphs=compiled and device == "cuda"))  # fmt: skip
    for i in range(22):
        batch = _batch(i, torch.float32)
        noise = agents[0].step_noise(torch.Generator().manual_seed(i), batch)  # drawn on the CPU
        batch = Batch(*(x.to(device) for x in batch))
        noise = {k: v.to(device) for k, v in noise.items()}
        w_before = [a.rep.baseline_nets.task.w.detach().clone() for a in agents]
        for a in agents:
            a.sgd_step(batch, noise, i)
        for a, w in zip(agents, w_before):
            assert (not torch.equal(w, a.rep.baseline_nets.task.w)) == (i % 10 == 0), i
    eager, compiled = (params.to_canonical(a.groups) for a in agents)
    for k in eager:
        np.testing.assert_allclose(compiled[k], eager[k], rtol=1e-3, atol=1e-5, err_msg=k)
    for a in agents:
        assert int(a.optimizers["task"].state[a.rep.baseline_nets.task.w]["step"]) == 3


@pytest.mark.parametrize("sigma", [0.0, 0.05])
def test_spr_augmentation_std_reaches_the_augmentation(sigma):
    """The config field `spr_augmentation_std` (TrainConfig → SF2Config → the SPR representation) is σ of
    the augmentation s̃ = s̄ + σξ (paper App. B.1, Fig. 5): at σ = 0 every draw of ξ gives the clean view
    and the same SPR loss; at σ = 0.05 (the default, the paper's choice) two draws differ."""
    from baselines_helpers import A, D
    from sf2_torch.agents.configs import TrainConfig

    assert TrainConfig().spr_augmentation_std == bt.spr.AUGMENTATION_STD == 0.05
    small = {k: v for k, v in small_kwargs().items() if k not in ("obs_size", "action_size")}
    cfg = TrainConfig(representation="spr", spr_augmentation_std=sigma, **small).sf2_config(D, A)
    torch.manual_seed(0)
    agent = make_algorithm("td3", cfg, reps.get("spr"), dtype=torch.float64)
    nets = agent.rep.baseline_nets
    assert nets.augmentation_std == sigma
    b = _batch()
    draws = [agent.rep.aux_noise(torch.Generator().manual_seed(k), b) for k in (1, 2)]
    with torch.no_grad():
        clean = bt.spr.features(nets, b.obs, b.action)
        views = [bt.spr.features(nets, b.obs, b.action, obs_noise=n["spr_obs_noise"]) for n in draws]
        spr_losses = [float(agent.rep.aux_loss(b, b.action, n)[0]) for n in draws]
    if sigma == 0.0:
        torch.testing.assert_close(views[0], clean, rtol=0, atol=0)
        torch.testing.assert_close(views[1], clean, rtol=0, atol=0)
        assert spr_losses[0] == spr_losses[1]
    else:
        assert not torch.allclose(views[0], views[1]) and spr_losses[0] != spr_losses[1]


def test_aux_steps_per_sgd_step_repeats_a_loss_without_noise():
    """`aux_steps_per_sgd_step` = 3 with TD3+SimLap, whose loss draws no noise (no "<key>:more" entries):
    step index 1 gives φ (an aux group only, due every step) three Adam steps and w (due every 10th step)
    none, its parameters unchanged."""
    torch.manual_seed(0)
    agent = make_algorithm("td3", SF2Config(**small_kwargs(), aux_steps_per_sgd_step=3), reps.get("simlap"),
                           dtype=torch.float64)
    before = params.to_canonical({"task": agent.groups["task"]})
    assert agent.aux_noise_keys() == () and agent.noise_keys() == ("smoothing_noise",)
    _step(agent, 0, 1)
    assert {int(s["step"]) for s in agent.optimizers["phi"].state.values()} == {3}
    assert not agent.optimizers["task"].state
    after = params.to_canonical({"task": agent.groups["task"]})
    assert all(np.array_equal(before[k], after[k]) for k in before)
