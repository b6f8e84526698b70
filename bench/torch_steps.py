"""torch updates to time: one full SGD step (critic, representation, policy, targets) of `sf2_torch.agents`
(`Algorithm.sgd_step`, the step the torch trainer runs; tests/test_step_agents_cross.py proves it equal
to the JAX agents' step for TD3/SAC × vanilla/SF²).

Frameworks: `torch` = eager; `torch-graphs` = eager + the agents' CUDA graph
(`sf2_torch.agents.graphs.StepGraph`; CUDA only); `torch-compile` = `compile_mode="default"` (the loss +
gradient parts compiled); `torch-cudagraphs` = compiled + CUDA graphs (the torch trainer's default on
CUDA). The noise is drawn every update with `Algorithm.step_noise` (the thin wrapper the trainer uses), as
the JAX step draws inside its jitted function. Synchronization: `torch.cuda.synchronize()` on CUDA.
"""

from __future__ import annotations

import time

from .data import FIELDS, make_batches
from .sizes import Case
from .timing import Runner

# framework → (compile_mode, CUDA graphs)
MODES = {"torch": (None, False), "torch-graphs": (None, True), "torch-compile": ("default", False),
         "torch-cudagraphs": ("default", True)}


def configure(allow_tf32: bool = False, threads: int | None = None) -> None:
    """Set torch's matmul precision and threads for every update built afterwards.

    Args:
        allow_tf32: TF32 matmuls and convolutions; False (full fp32) for published numbers.
        threads: intra-op threads (`torch.set_num_threads`); None leaves torch's default.
    """
    import torch

    torch.backends.cuda.matmul.allow_tf32 = allow_tf32
    torch.backends.cudnn.allow_tf32 = allow_tf32
    torch.set_float32_matmul_precision("medium" if allow_tf32 else "highest")
    if threads:
        torch.set_num_threads(threads)


class AgentsUpdate:
    """One SGD step of `sf2_torch.agents` on `device`: `step_noise` then `sgd_step`, with a growing step
    counter (the policy delay and the baselines' every-k-steps schedules average out)."""

    def __init__(self, case: Case, device: str, seed: int = 0, dtype=None):
        import torch
        from sf2_common.config import SF2Config
        from sf2_torch.agents import algorithms, representations
        from sf2_torch.losses import Batch

        self.torch = torch
        self.device = torch.device(device)
        dtype = dtype or torch.float32
        cfg = SF2Config(obs_size=case.obs_size, action_size=case.action_size, **case.sf2_overrides())
        compile_mode, cudagraphs = MODES[case.framework]
        if cudagraphs and self.device.type != "cuda":
            raise RuntimeError(f"{case.framework} needs a CUDA device")
        torch.manual_seed(seed)
        if case.rep not in representations.names():
            import importlib

            importlib.import_module("sf2_baselines.torch")   # registers Sim, SimLap, SPR
        self.alg = algorithms.make_algorithm(case.algo, cfg, representations.get(case.rep), dtype=dtype,
                                             device=self.device, compile_mode=compile_mode,
                                             cudagraphs=cudagraphs)
        self.generator = torch.Generator(self.device)
        self.generator.manual_seed(seed + 1)
        self.batches = [Batch(*(torch.as_tensor(b[f], dtype=dtype, device=self.device) for f in FIELDS))
                        for b in make_batches(case.obs_size, case.action_size, case.batch_size, 4, seed)]
        self.i = 0

    def step(self) -> None:
        """Dispatch one update (noise drawn, then `sgd_step`)."""
        batch = self.batches[self.i % len(self.batches)]
        self.alg.sgd_step(batch, self.alg.step_noise(self.generator, batch), self.i)
        self.i += 1

    def sync(self) -> None:
        """Wait until the device has finished every dispatched update."""
        if self.device.type == "cuda":
            self.torch.cuda.synchronize(self.device)

    def finite(self) -> bool:
        """Whether every trained parameter is finite."""
        return all(bool(self.torch.isfinite(p).all()) for p in self.alg._params(self.alg.groups))


def update_runner(case: Case, device: str, seed: int = 0, warm_compile: int = 3) -> tuple[Runner, dict]:
    """Build a timed torch update: `step_noise` then `sgd_step` of `sf2_torch.agents`.

    Args:
        case: what to time (a torch case: eager, compiled, with CUDA graphs).
        device: "cpu" or "cuda".
        seed: seed of the parameters, batches and noise.
        warm_compile: steps run here for the compiled or graphed frameworks, their time reported as the
            compile time.

    Returns:
        The `Runner` and a dict with `finite` (a callable) and `impl`.
    """
    upd = AgentsUpdate(case, device, seed=seed)
    prepared = MODES[case.framework] != (None, False)
    t0 = time.perf_counter()
    for _ in range(warm_compile if prepared else 1):
        upd.step()
    upd.sync()
    compile_s = time.perf_counter() - t0
    runner = Runner(case.key, upd.step, upd.sync, compile_s=compile_s)
    return runner, {"finite": upd.finite, "impl": "sf2_torch.agents sgd_step"}


def count_flops(case: Case, device: str = "cpu", seed: int = 0) -> float:
    """Count the FLOPs of one eager update with torch's FlopCounterMode.

    Args:
        case: the update (its framework is replaced by eager `torch`).
        device: where to run it.
        seed: seed of the parameters and batch.

    Returns:
        FLOPs of the matmuls only (a lower count than XLA's, which counts every operation).
    """
    from torch.utils.flop_counter import FlopCounterMode

    upd = AgentsUpdate(case.__class__(**{**case.__dict__, "framework": "torch"}), device, seed=seed)
    upd.step()
    with FlopCounterMode(display=False) as counter:
        upd.step()
    return float(counter.get_total_flops())
