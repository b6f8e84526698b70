"""pytest-benchmark suite: one full SGD update at the `small` size, per framework, algorithm,
representation, denoising steps and integrator, plus the JAX flow-loss step (fast vs oracle).

    pytest bench/                                   # run and print the table
    pytest bench/ --benchmark-autosave              # store under .benchmarks/
    pytest-benchmark compare 0001 0002 --group-by=group   # regressions between two stored runs
    pytest bench/ --benchmark-disable               # smoke: each update once, no timing
    pytest bench/ --bench-compile                   # include torch.compile'd updates (slow to compile)

Each benchmark calls one update and then synchronizes the device (`block_until_ready` / CUDA sync), so
a round measures device work; compilation and warm-up updates happen before the first round.
"""

from __future__ import annotations

import pytest

from bench import sizes
from bench.sizes import Case

pytest.importorskip("pytest_benchmark")

STEPS = sizes.DEFAULT_STEPS


def _cases():
    out = []
    for fw in sizes.FRAMEWORKS:
        for algo in sizes.ALGOS:
            out.append((fw, algo, "none", 0, ""))
            for integ in sizes.INTEGRATORS:
                for T in STEPS:
                    if fw in sizes.COMPILED and T not in (1, 8):
                        continue
                    if fw == "jax-scan" and (T not in (1, 8) or integ != "midpoint"):
                        continue
                    out.append((fw, algo, "sf2", T, integ))
    return out


def _id(c):
    fw, algo, rep, T, integ = c
    return f"{fw}-{algo}-" + ("vanilla" if rep == "none" else f"sf2-T{T}-{integ}")


@pytest.fixture(scope="session")
def task(pytestconfig):
    return sizes.resolve_task(pytestconfig.getoption("--bench-task"))


def _runner(case):
    if case.framework in sizes.JAX:
        from bench import jax_steps

        jax_steps.configure("highest")
        return jax_steps.update_runner(case, scan=8 if case.framework == "jax-scan" else 1)
    pytest.importorskip("torch")
    from bench import torch_steps

    torch_steps.configure(False, 1)
    device = "cuda" if _cuda() else "cpu"
    return torch_steps.update_runner(case, device)


def _cuda() -> bool:
    try:
        import torch

        return torch.cuda.is_available()
    except ImportError:
        return False


@pytest.mark.parametrize("spec", _cases(), ids=_id)
def test_update(benchmark, spec, task, pytestconfig):
    fw, algo, rep, T, integ = spec
    if fw in sizes.COMPILED and not pytestconfig.getoption("--bench-compile"):
        pytest.skip("torch.compile cases need --bench-compile")
    if fw in sizes.CUDA_ONLY and not _cuda():
        pytest.skip("CUDA graphs need a CUDA device")
    if fw in sizes.JAX:
        pytest.importorskip("jax")
    case = Case(fw, algo, rep, task, "small", T, integ)
    runner, extra = _runner(case)
    for _ in range(2):
        runner.step()
    runner.sync()

    def one():   # one call: 8 updates for jax-scan (see extra_info.updates_per_call)
        runner.step()
        runner.sync()

    benchmark.group = f"update {algo} {task} small"
    benchmark.extra_info.update(case=case.key, flops=extra.get("flops"), compile_s=runner.compile_s,
                                updates_per_call=runner.per_call)
    benchmark.pedantic(one, rounds=20, iterations=1, warmup_rounds=2)
    finite = extra["finite"]()
    assert finite, f"{case.key}: parameters became non-finite"


@pytest.mark.parametrize("contract", [True, False], ids=["fast", "oracle"])
@pytest.mark.parametrize("T", [1, 8])
def test_flow_step(benchmark, T, contract, task):
    pytest.importorskip("jax")
    from bench import jax_steps

    jax_steps.configure("highest")
    D, A = sizes.TASKS[task]
    runner, extra = jax_steps.flow_step_runner(D, A, "small", T, "midpoint", contract)
    runner.step()
    runner.sync()

    def one():
        runner.step()
        runner.sync()

    benchmark.group = f"flow step {task} small"
    benchmark.extra_info.update(flops=extra.get("flops"), first_loss=extra["first_loss"]())
    benchmark.pedantic(one, rounds=20, iterations=1, warmup_rounds=2)
