"""One CUDA graph per SGD-step (or acting) function, replayed without a host synchronization.

`StepGraph(fn)` runs `fn` (a function of pytrees of CUDA tensors, e.g. the `Batch` and the noise dict,
returning a pytree of tensors, e.g. the metrics) eagerly for `warmup` calls on a side stream (the warm-up
that `torch.compile` and capturable Adam need before capture), captures it as a `torch.cuda.CUDAGraph` at
the next call, and from then on copies each call's inputs into the captured input tensors and replays the
graph, all on the current stream, returning copies of the outputs. Draws from CUDA generators other than
the default one need them named (`generators`, registered): a replay draws what an eager call would have.

Why not tensordict's `CudaGraphModule`: it synchronizes the device before every replay (inputs copied from
the host with `non_blocking=True` could otherwise be read before they land). In the torch trainer every
input of a step is already on the device and written on the current stream, so that wait only stalls the
host, which then cannot queue the next actor step's work (docs/decisions/torch-trainer-step.md). Here the
inputs are copied on the stream the graph replays on, so stream order is the only synchronization needed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch.utils._pytree import tree_flatten, tree_map, tree_unflatten

__all__ = ["StepGraph", "graphs_draw_from_generators"]


def graphs_draw_from_generators() -> bool:
    """Whether this torch can capture draws from generators other than the default one in a CUDA graph."""
    return hasattr(torch.cuda.CUDAGraph, "register_generator_state")


class StepGraph:
    """`fn` captured once as a CUDA graph and replayed (module docstring). Every call must pass tensors of
    the shapes, dtypes and tree structure of the call that was captured; a call that does not raises
    ValueError naming the difference. `generators`: the CUDA generators `fn` draws from, other than the
    default one."""

    def __init__(self, fn: Callable[..., Any], warmup: int = 3, generators=()):
        if warmup < 1:
            raise ValueError(f"warmup = {warmup}: at least one eager call must come before the capture")
        if generators and not graphs_draw_from_generators():
            raise RuntimeError(f"torch {torch.__version__} cannot register a generator with a CUDA graph "
                               "(CUDAGraph.register_generator_state): capture a function without them")
        self.fn, self.warmup = fn, int(warmup)
        self.generators = tuple(generators)
        self.calls = 0
        self.graph: torch.cuda.CUDAGraph | None = None
        self._inputs: list[torch.Tensor] = []
        self._spec = None
        self._out = None

    def __call__(self, *args):
        leaves, spec = tree_flatten(args)
        if self.graph is None:
            if self.calls < self.warmup:
                self.calls += 1
                return self._on_side_stream(lambda: self.fn(*args))
            return self._capture(leaves, spec)
        self._check(leaves, spec)
        torch._foreach_copy_(self._inputs, leaves)
        self.graph.replay()
        return tree_map(torch.clone, self._out)

    @staticmethod
    def _on_side_stream(run):
        """`run()` on a side stream ordered after and before the current one (capture needs its warm-up
        kept off the default stream: torch.cuda.graphs' notes on whole-network capture)."""
        side, current = torch.cuda.Stream(), torch.cuda.current_stream()
        side.wait_stream(current)
        with torch.cuda.stream(side):
            out = run()
        current.wait_stream(side)
        return out

    def _capture(self, leaves, spec):
        bad = [i for i, x in enumerate(leaves) if not isinstance(x, torch.Tensor) or x.device.type != "cuda"]
        if bad:
            raise ValueError(f"StepGraph captures CUDA tensors only; input leaves {bad} are not")
        self._inputs = [x.detach().clone() for x in leaves]
        self._spec = spec
        args = tree_unflatten(self._inputs, spec)
        self.graph = torch.cuda.CUDAGraph()
        for generator in self.generators:
            self.graph.register_generator_state(generator)
        # torch.cuda.graph synchronizes the device once as it begins (the warm-up's work and the input
        # copies have landed) and captures on a stream of its own
        with torch.cuda.graph(self.graph):
            self._out = self.fn(*args)
        self.calls += 1
        # capture records the kernels without running them: this call's step is the first replay
        self.graph.replay()
        return tree_map(torch.clone, self._out)

    def _check(self, leaves, spec):
        if spec != self._spec or len(leaves) != len(self._inputs):
            raise ValueError(f"StepGraph: the inputs' structure {spec} differs from the captured one "
                             f"{self._spec}")
        for i, (x, y) in enumerate(zip(leaves, self._inputs)):
            if x.shape != y.shape or x.dtype != y.dtype or x.device != y.device:
                raise ValueError(f"StepGraph: input leaf {i} is {tuple(x.shape)} {x.dtype} on {x.device}, "
                                 f"the captured one {tuple(y.shape)} {y.dtype} on {y.device}")
