"""`sf2_torch.agents.graphs.StepGraph`, the CUDA graph of the torch agents' SGD step: a replay computes what
the function computes (a toy step with state, then the agents' TD3+SF² and SAC+SF² steps against the same
algorithm without graphs), each call's inputs are the ones used, outputs are copies, a call of another
shape is refused, a replay normalizes with the statistics as updated before it, and no replay synchronizes
the device (the reason it replaced tensordict's `CudaGraphModule`: graphs.py); a replay draws from a
registered generator what an eager call would, so the trainer's evaluation, its seeds' policies one graph,
acts as without it. CUDA graphs need a CUDA device: on a CPU-only host these tests report themselves
skipped, with that reason, except the argument checks; on a leased GPU host (scripts/gpu-host/) they run
with `source scripts/gpu-host/gpu_env.sh && JAX_PLATFORMS=cuda,cpu python3 -m pytest
packages/sf2-core-torch/tests/agents/test_torch_graphs.py` (the evaluation's envs are JAX's, on the GPU)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from sf2_common.config import SF2Config
from sf2_torch import losses, networks
from sf2_torch import params as params_mod
from sf2_torch.agents import algorithms, graphs, representations
from sf2_torch.agents.graphs import StepGraph

cuda = pytest.mark.skipif(not torch.cuda.is_available(),
                          reason="CUDA graphs need a CUDA device (the GPU host runs these: docstring)")


def test_a_capture_needs_a_warm_up_call():
    with pytest.raises(ValueError, match="warmup = 0"):
        StepGraph(lambda x: x, warmup=0)


def _toy():
    """A step with state: w moves by the batch's mean, the output reads the state and the noise."""
    w = torch.zeros(3, device="cuda")

    def step(batch, noise):
        w.add_(batch["x"].mean(0))
        return {"w2": w * 2 + noise["y"], "s": batch["x"].sum()}
    return w, step


@cuda
def test_replays_compute_the_function_with_each_calls_inputs():
    w_graph, graphed = _toy()
    w_eager, eager = _toy()
    graphed = StepGraph(graphed, warmup=2)
    g = torch.Generator(device="cuda").manual_seed(0)
    outs = []
    for i in range(7):   # 2 warm-up calls, the capture, 4 replays
        batch = {"x": torch.randn(5, 3, device="cuda", generator=g)}
        noise = {"y": torch.full((3,), float(i), device="cuda")}
        got, want = graphed(batch, noise), eager(batch, noise)
        outs.append(got)
        torch.testing.assert_close(got, want, rtol=0, atol=0)
    torch.testing.assert_close(w_graph, w_eager, rtol=0, atol=0)
    assert graphed.graph is not None and graphed.calls == 3
    # the outputs are copies: a later replay did not overwrite an earlier call's
    assert len({float(o["s"]) for o in outs}) == len(outs)


@cuda
def test_a_call_of_another_shape_is_refused():
    _, step = _toy()
    graphed = StepGraph(step, warmup=1)
    for _ in range(2):
        graphed({"x": torch.ones(5, 3, device="cuda")}, {"y": torch.zeros(3, device="cuda")})
    with pytest.raises(ValueError, match=r"input leaf 0 is \(4, 3\)"):
        graphed({"x": torch.ones(4, 3, device="cuda")}, {"y": torch.zeros(3, device="cuda")})


D, A, B = 5, 2, 16


def _algorithm(name, cudagraphs, rep="sf2"):
    """The algorithm as the trainer builds it with graphs (capturable Adam, its learning rate a device
    tensor); `cudagraphs` False then runs the same optimizers without capture, so only the graph differs."""
    torch.manual_seed(0)
    cfg = SF2Config.small(D, A, gamma_su=0.9)
    algo = algorithms.make_algorithm(name, cfg, representations.get(rep), device="cuda", cudagraphs=True)
    algo.cudagraphs = cudagraphs
    return algo


def _batches(n):
    g = torch.Generator(device="cuda").manual_seed(1)
    out = []
    for _ in range(n):
        trunc = (torch.rand(B, device="cuda", generator=g) < 0.3).float()
        out.append(losses.Batch(obs=torch.randn(B, D, device="cuda", generator=g),
                                action=torch.rand(B, A, device="cuda", generator=g) * 2 - 1,
                                reward=torch.rand(B, device="cuda", generator=g), discount=1.0 - trunc,
                                next_obs=torch.randn(B, D, device="cuda", generator=g), truncation=trunc))
    return out


@cuda
@pytest.mark.parametrize("name", ["td3", "sac"])
def test_the_agents_graphed_step_is_their_step(name, monkeypatch):
    """12 SGD steps (TD3: both schedule combinations of the policy delay, each captured after its own 3
    warm-up calls) with and without CUDA graphs, same batches and noise: the same parameters and metrics,
    and, once every graph is captured, no `torch.cuda.synchronize` on the way. The tolerance (1e-6) only
    allows for cuBLAS picking another kernel under capture; replays of the same kernels agree exactly."""
    plain, graphed = _algorithm(name, False), _algorithm(name, True)
    steps = 12
    batches = _batches(steps)
    syncs, real = [], torch.cuda.synchronize

    def counted(*args, **kwargs):
        syncs.append(1)
        return real(*args, **kwargs)

    for i, batch in enumerate(batches):
        noise = plain.step_noise(torch.Generator(device="cuda").manual_seed(100 + i), batch)
        if i == steps - 2:   # every schedule combination has been captured by now
            monkeypatch.setattr(torch.cuda, "synchronize", counted)
        want = plain.sgd_step(batch, noise, step=i)
        got = graphed.sgd_step(batch, noise, step=i)
        torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-6)
    assert syncs == []
    a, b = params_mod.to_canonical(plain.groups), params_mod.to_canonical(graphed.groups)
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(b[k], a[k], rtol=1e-6, atol=1e-6, msg=lambda m, k=k: f"{k}: {m}")


@cuda
@pytest.mark.parametrize("rep", ["none", "sf2"])
def test_a_replay_reads_the_normalizer_as_updated_before_it(rep):
    """The trainer updates the observation normalizer in place before each actor step's SGD steps
    (`networks.update_normalizer`): TD3 steps with and without CUDA graphs, each after the same update
    (every step's observations shifted and scaled, so the statistics move), give the same metrics and
    parameters, so a replay normalizes with the statistics of its own step, not those of its capture."""
    plain, graphed = _algorithm("td3", False, rep), _algorithm("td3", True, rep)
    for i, batch in enumerate(_batches(12)):
        for algo in (plain, graphed):
            networks.update_normalizer(algo.nets.obs_norm, batch.obs * (i + 1) + i, algo.cfg)
        noise = plain.step_noise(torch.Generator(device="cuda").manual_seed(100 + i), batch)
        want = plain.sgd_step(batch, noise, step=i)
        torch.testing.assert_close(graphed.sgd_step(batch, noise, step=i), want, rtol=1e-6, atol=1e-6)
    assert float(graphed.nets.obs_norm.mean.abs().max()) > 1.0   # the statistics did move
    a, b = params_mod.to_canonical(plain.groups), params_mod.to_canonical(graphed.groups)
    for k in a:
        torch.testing.assert_close(b[k], a[k], rtol=1e-6, atol=1e-6, msg=lambda m, k=k: f"{k}: {m}")


@cuda
@pytest.mark.parametrize("name", ["td3", "sac"])
def test_compiled_updates_are_the_fused_adam_step(name):
    """The updates compiled on CUDA (`compile_updates`: torch's functional foreach Adam, capturable, and
    the target lerps through `torch.compile`, inside the step's CUDA graph) against the eager fused Adam,
    the losses eager in both: 12 SGD steps, the same parameters and metrics up to the rounding of two
    Adam formulations (1e-5)."""
    torch.manual_seed(0)
    cfg = SF2Config.small(D, A, gamma_su=0.9)
    plain = algorithms.make_algorithm(name, cfg, representations.get("sf2"), device="cuda")
    torch.manual_seed(0)
    fast = algorithms.make_algorithm(name, cfg, representations.get("sf2"), device="cuda",
                                     compile_mode="default", cudagraphs=True)
    fast.compile_mode = None   # the losses eager: only the updates differ
    assert fast.compile_updates and plain.optimizers["q"].param_groups[0]["fused"]
    for i, batch in enumerate(_batches(12)):
        noise = plain.step_noise(torch.Generator(device="cuda").manual_seed(100 + i), batch)
        torch.testing.assert_close(fast.sgd_step(batch, noise, step=i), plain.sgd_step(batch, noise, step=i),
                                   rtol=1e-5, atol=1e-5)
    assert {"_adam_steps", "_move_targets"} <= set(fast._compiled)
    a, b = params_mod.to_canonical(plain.groups), params_mod.to_canonical(fast.groups)
    for k in a:
        torch.testing.assert_close(b[k], a[k], rtol=1e-5, atol=1e-5, msg=lambda m, k=k: f"{k}: {m}")


def _draws_from_generators():
    if not graphs.graphs_draw_from_generators():
        pytest.skip(f"torch {torch.__version__} cannot register a generator with a CUDA graph (the "
                    "trainer's evaluation then acts without one)")


@cuda
def test_a_replay_draws_from_a_registered_generator_what_an_eager_call_would():
    """A function drawing from a generator of its own, graphed with the generator registered, against the
    same function on a generator seeded alike: the same draws at every call (1 warm-up, the capture, 4
    replays), so the graph advances the generator as eager calls do."""
    _draws_from_generators()

    def fn(generator):
        return lambda x: x + torch.randn(x.shape, device="cuda", generator=generator)

    g_graph, g_eager = (torch.Generator(device="cuda").manual_seed(7) for _ in range(2))
    graphed, eager = StepGraph(fn(g_graph), warmup=1, generators=[g_graph]), fn(g_eager)
    for i in range(6):
        x = torch.full((4, 3), float(i), device="cuda")
        torch.testing.assert_close(graphed(x), eager(x), rtol=0, atol=0)
    assert graphed.graph is not None


@cuda
@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_the_evaluation_acts_as_without_its_graph(algo, jax_on_gpu):
    """The trainer's evaluation policy (`Program.eval_policy`: every seed's exploring `act` as one CUDA
    graph) against the seeds acting one by one, same agents and generator seeds: the same actions at every
    step of a sequence of observations, and the same evaluation returns. The tolerance (1e-6) only allows
    for cuBLAS picking another kernel under capture, as in the SGD step's test."""
    _draws_from_generators()
    from sf2_torch.agents import configs, trainer

    cfg = configs.make_config("quick", "CartpoleBalance", algo, "sf2", {
        "device": "cuda", "num_eval_envs": 8, "episode_length": 100, "deterministic_eval": False})
    program = trainer.get_program(cfg)
    state = program.init((0, 1))
    assert program.cudagraphs

    def gens():
        return [torch.Generator(device="cuda").manual_seed(10 + i) for i in range(2)]

    graphed = program.eval_policy(state.agents, gens())
    assert isinstance(graphed, StepGraph)
    program.cudagraphs = False
    eager = program.eval_policy(state.agents, gens())
    g = torch.Generator(device="cuda").manual_seed(3)
    for _ in range(6):
        obs = torch.randn(2, 8, program.spec.obs_size, device="cuda", generator=g)
        torch.testing.assert_close(graphed(obs), eager(obs), rtol=1e-6, atol=1e-6)
    plain = program.evaluate(state.agents, state.eval_keys, state.seeds, 1)
    program.cudagraphs = True
    got = program.evaluate(state.agents, state.eval_keys, state.seeds, 1)
    np.testing.assert_allclose(got, plain, rtol=1e-5, atol=1e-5)


def test_a_torch_that_cannot_register_a_generator_refuses_one():
    """Where torch has no `CUDAGraph.register_generator_state`, a graph of a function drawing from a
    generator of its own would not advance it: StepGraph refuses the generator, naming the version."""
    g = torch.Generator()
    if graphs.graphs_draw_from_generators():
        assert StepGraph(lambda x: x, generators=[g]).generators == (g,)
    else:
        with pytest.raises(RuntimeError, match=re.escape(f"torch {torch.__version__} cannot register")):
            StepGraph(lambda x: x, generators=[g])
