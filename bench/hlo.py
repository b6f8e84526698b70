"""Kernels per part of the JAX trainer's epoch, counted in its compiled (optimized) HLO.

    python -m bench.hlo DUMP_DIR_OR_FILE [--sgd-steps N] [--json OUT]
    python -m bench.agent_profile ... --hlo        (dumps the epoch and appends this table)

The trainer traces each part of an actor step and of an SGD step under a `jax.named_scope`
(`sf2_jax.agents.trainer.ACTOR_PHASES`, `sf2_jax.agents.algorithms.PHASES`), which reaches every compiled
instruction's `op_name`. This reads the epoch module's `*after_optimizations.txt` (XLA's `--xla_dump_to`
with `--xla_dump_hlo_as_text`) and counts, per phase, the instructions that launch a kernel on a GPU
(fusions, library calls, copies; not parameters, tuples, bitcasts, constants or control flow), each
weighted by the known trip counts of the loops around it; a conditional's branches and a loop without a
known trip count count once. Divided by `--sgd-steps`, the counts compare with `bench.agent_profile`'s
traced kernels per SGD step, which cannot tell the parts apart inside XLA's command buffers.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import re
import sys
from pathlib import Path

# opcodes that launch nothing on the device (or only control the launches of others)
FREE = frozenset({
    "parameter", "constant", "get-tuple-element", "tuple", "bitcast", "while", "conditional", "call",
    "after-all", "add-dependency", "opt-barrier", "partition-id", "replica-id", "domain",
    "get-dimension-size", "copy-done", "all-reduce-done", "all-gather-done", "collective-permute-done",
    "send-done", "recv-done", "async-done", "async-update"})

_COMP = re.compile(r"^(ENTRY\s+)?%?([\w.\-]+)\s.*\{\s*$")
_INSTR = re.compile(r"^\s+(ROOT\s+)?%?([\w.\-]+)\s*=\s*.*?\s([a-z][\w\-]*)\(")
_OP_NAME = re.compile(r'op_name="([^"]*)"')
_TRIP = re.compile(r'"known_trip_count":\{"n":"(\d+)"\}')
_CALLS = re.compile(r"(calls|body|condition|to_apply|branch_computations|called_computations|"
                    r"true_computation|false_computation)=(\{[^}]*\}|%?[\w.\-]+)")


def phases() -> tuple[str, ...]:
    """List the JAX trainer's phases.

    Returns:
        The scopes of an actor step, then those of an SGD step.
    """
    from sf2_jax.agents.algorithms import PHASES
    from sf2_jax.agents.trainer import ACTOR_PHASES

    return ACTOR_PHASES + PHASES


@contextlib.contextmanager
def fresh_compilation():
    """Compile without JAX's persistent compilation cache (`jax_enable_compilation_cache`), then restore it.

    The cache's key leaves out the `op_name` metadata (`jax_compilation_cache_include_metadata_in_key`), so a
    program taken from it carries the scopes of whatever code compiled it first (a `sf2-jax train` in the
    same process turns the cache on), and a cache hit writes no `--xla_dump_to` dump.
    """
    import jax

    before = jax.config.jax_enable_compilation_cache
    jax.config.update("jax_enable_compilation_cache", False)
    try:
        yield
    finally:
        jax.config.update("jax_enable_compilation_cache", before)


def parse(text: str) -> tuple[dict[str, list[tuple[str, str, str]]], str]:
    """Split an HLO module's text into its computations.

    Args:
        text: the module's text (XLA's `--xla_dump_hlo_as_text`).

    Returns:
        ({computation: [(instruction, opcode, line)]}, the entry computation's name).
    """
    comps: dict[str, list] = {}
    entry, current = "", None
    for line in text.splitlines():
        if current is None:
            m = _COMP.match(line)
            if m and not line.startswith("HloModule"):
                current = m.group(2)
                comps[current] = []
                if m.group(1):
                    entry = current
            continue
        if line.startswith("}"):
            current = None
            continue
        m = _INSTR.match(line)
        if m:
            comps[current].append((m.group(2), m.group(3), line))
    if not entry:
        raise ValueError("no ENTRY computation in the HLO text: not an HLO module dump")
    return comps, entry


def _callees(opcode: str, line: str) -> list[tuple[str, str]]:
    out = []
    for key, val in _CALLS.findall(line):
        for name in val.strip("{}").split(","):
            name = name.strip().lstrip("%")
            if name:
                out.append((key, name))
    return out


def runs(comps: dict, entry: str, into_fusions: bool = False) -> tuple[dict[str, float], int, int]:
    """Weight each computation by how often it runs in one call of the module.

    A computation's weight is the product of the known trip counts of the loops around it; each branch
    of a conditional counts as if it ran.

    Args:
        comps: `parse`'s computations.
        entry: the entry computation.
        into_fusions: also weigh the computations fused into a fusion (the instructions a kernel
            computes, for counting their arithmetic; not their scalar reducers); otherwise a fusion is a
            leaf (one kernel).

    Returns:
        ({computation: runs per call}, while loops without a known trip count, conditional branches).
    """
    fused = set() if into_fusions else {
        name for instrs in comps.values() for _, op, line in instrs
        for key, name in _callees(op, line) if op == "fusion" and key == "calls"}
    weight: dict[str, float] = collections.defaultdict(float)
    unknown_loops, branches = 0, 0
    stack = [(entry, 1.0)]
    while stack:   # XLA's call graph is a DAG
        comp, w = stack.pop()
        weight[comp] += w
        for _, op, line in comps.get(comp, ()):
            if op == "fusion" and not into_fusions:
                continue
            for key, callee in _callees(op, line):
                if callee not in comps or callee in fused or (into_fusions and key == "to_apply"):
                    continue
                m = w
                if op == "while" and key == "body":
                    trip = _TRIP.search(line)
                    if trip:
                        m = w * int(trip.group(1))
                    else:
                        unknown_loops += 1
                elif op == "conditional":
                    branches += 1
                stack.append((callee, m))
    return weight, unknown_loops, branches


_WRAPPED = re.compile(r"^[\w.\-]+\((.*)\)$")


def phase_of(line: str, phases: tuple[str, ...], default: str = "(other)") -> str:
    """Find the phase an instruction belongs to.

    A transformation wraps the scopes traced under it (`vmap(critic_grad)`, `jvp(...)`,
    `transpose(...)`): each element of the `op_name` path is unwrapped to its innermost name.

    Args:
        line: the instruction's line.
        phases: the phase scopes.
        default: the phase of an instruction that names none.

    Returns:
        The last scope of `phases` that the instruction's `op_name` names, else `default`.
    """
    m = _OP_NAME.search(line)
    path = []
    for part in m.group(1).split("/") if m else ():
        while (w := _WRAPPED.match(part)) is not None:
            part = w.group(1)
        path.append(part)
    return next((p for p in reversed(path) if p in phases), default)


def count(text: str, phases: tuple[str, ...]) -> dict:
    """Count kernel launches per phase in one call of the module.

    Args:
        text: the optimized module's text.
        phases: the phase scopes.

    Returns:
        {"by_phase": {phase: {kind: launches}}, "unknown_trip_count_loops", "conditional_branches"};
        kinds as `kernel_kind`.
    """
    comps, entry = parse(text)
    weight, unknown_loops, branches = runs(comps, entry)
    by_phase: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for comp, w in weight.items():
        for name, op, line in comps[comp]:
            if op in FREE:
                continue
            by_phase[phase_of(line, phases)][kernel_kind(op, name, line)] += w
    return {"by_phase": {p: dict(c) for p, c in by_phase.items()},
            "unknown_trip_count_loops": unknown_loops, "conditional_branches": branches}


def kernel_phases(text: str, phases: tuple[str, ...]) -> dict[str, str]:
    """Map each kernel a module launches to its phase, by the name a profiler trace gives the kernel.

    XLA names a fusion's kernel after the instruction, its dots and dashes as underscores on a GPU
    (`loop_add_fusion.11` launches `loop_add_fusion_11`), and a trace event also carries the instruction
    (`hlo_op`) outside command buffers; both spellings map to the instruction's phase (`phase_of`).

    Args:
        text: the optimized module's text.
        phases: the phase scopes.

    Returns:
        {kernel or instruction name, as `kernel_name` spells it: phase} for every launching instruction.
    """
    comps, _ = parse(text)
    return {kernel_name(name): phase_of(line, phases)
            for instructions in comps.values() for name, op, line in instructions if op not in FREE}


def kernel_name(name: str) -> str:
    """Spell an instruction's or a kernel's name one way (dots and dashes as underscores)."""
    return re.sub(r"[.\-]", "_", name)


def kernel_kind(op: str, name: str, line: str) -> str:
    """Classify the kernel an instruction launches, from its own name, target and backend config.

    Args:
        op: the opcode.
        name: the instruction's name.
        line: its line.

    Returns:
        "gemm" (a cuBLAS/cuBLASLt call or a Triton or cuDNN GEMM fusion), "fusion" (the other fusions),
        "copy", "library" (other custom calls, e.g. cuSOLVER) or "other".
    """
    if op == "custom-call":
        target = re.search(r'custom_call_target="([^"]*)"', line)
        target = target.group(1) if target else ""
        return "gemm" if ("gemm" in target or "matmul" in target) else "library"
    if op == "fusion":
        kind = re.search(r'"fusion_backend_config":\{.*?"kind":"([^"]*)"', line)
        kind = kind.group(1) if kind else ""
        return "gemm" if ("gemm" in name or "gemm" in kind or "cudnn" in kind) else "fusion"
    if op in ("copy", "copy-start"):
        return "copy"
    return "other"


def find_module(path: Path, module: str = "epoch_one") -> Path:
    """Find a module's optimized HLO in an XLA dump.

    Args:
        path: a dump folder, or one `*after_optimizations.txt` file (returned as is).
        module: the module's name.

    Returns:
        The most recently written `*<module>*after_optimizations.txt`; FileNotFoundError if none.
    """
    if path.is_file():
        return path
    files = [f for f in path.glob(f"*{module}*after_optimizations.txt")
             if "-" not in f.name.split("after_optimizations")[-1]]   # not the buffer-assignment reports
    if not files:
        raise FileNotFoundError(f"no '*{module}*after_optimizations.txt' in {path} (dump with XLA_FLAGS="
                                "--xla_dump_to=DIR --xla_dump_hlo_as_text)")
    return max(files, key=lambda f: f.stat().st_mtime_ns)   # the newest: the last compiled


def markdown(result: dict, phases: tuple[str, ...], sgd_steps: int = 1) -> str:
    """Render `count`'s result as a table of kernels per phase and kind.

    Args:
        result: `count`'s result.
        phases: the phase scopes, in the table's order.
        sgd_steps: divide every count by this (the epoch's SGD steps).

    Returns:
        The markdown table with a line on conditional branches and unknown trip counts.
    """
    kinds = ("gemm", "fusion", "copy", "library", "other")
    rows = ["| phase | kernels | " + " | ".join(kinds) + " |", "|---" * (len(kinds) + 2) + "|"]
    order = [p for p in phases if p in result["by_phase"]] + [
        p for p in result["by_phase"] if p not in phases]
    total = collections.Counter()
    for p in order:
        c = result["by_phase"][p]
        total.update(c)
        rows.append(f"| {p} | {sum(c.values()) / sgd_steps:.1f} | "
                    + " | ".join(f"{c.get(k, 0) / sgd_steps:.1f}" for k in kinds) + " |")
    rows.append(f"| **all** | **{sum(total.values()) / sgd_steps:.1f}** | "
                + " | ".join(f"{total.get(k, 0) / sgd_steps:.1f}" for k in kinds) + " |")
    per = "per SGD step" if sgd_steps > 1 else "per call of the module"
    return "\n".join([
        f"Kernel launches {per}, by phase (compiled HLO; `python -m bench.hlo`). Conditional branches "
        f"counted as if each ran: {result['conditional_branches']}; while loops without a known trip count "
        f"counted once: {result['unknown_trip_count_loops']}.", "", *rows])


def main(argv=None) -> int:
    """Run `python -m bench.hlo`.

    Args:
        argv: the command line after the module name (default `sys.argv[1:]`).

    Returns:
        The exit status.
    """
    p = argparse.ArgumentParser(prog="python -m bench.hlo", description=__doc__.split("\n\n")[0])
    p.add_argument("path", help="an XLA dump folder or one *after_optimizations.txt file")
    p.add_argument("--module", default="epoch_one", help="module name to look for in a dump folder")
    p.add_argument("--sgd-steps", type=int, default=1, help="divide by this (the epoch's SGD steps)")
    p.add_argument("--json", help="also write the counts here")
    args = p.parse_args(argv)
    if args.sgd_steps < 1:
        p.error(f"--sgd-steps must be >= 1, got {args.sgd_steps}")
    try:
        f = find_module(Path(args.path), args.module)
        result = count(f.read_text(), phases())
    except (FileNotFoundError, ValueError) as err:
        p.error(str(err))
    print(f"{f}\n\n" + markdown(result, phases(), args.sgd_steps))
    if args.json:
        Path(args.json).write_text(json.dumps({**result, "file": str(f), "sgd_steps": args.sgd_steps},
                                              indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
