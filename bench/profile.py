"""Where the device time of one update goes: a `jax.profiler` trace of a few updates, summarized.

For each device (GPU) process of the Perfetto trace: kernels per update, device-busy time per update
(union of kernel intervals), wall time per update, and the kernels that take the most time, grouped
into GEMM (cuBLAS/CUTLASS/Triton matmul), fusion (XLA-generated) and other. On a CPU backend the XLA
worker threads stand in for the device.
"""

from __future__ import annotations

import collections
import glob
import gzip
import json
import os
import tempfile
import time

from .hlo import kernel_name


def _category(name: str) -> str:
    n = name.lower()
    if any(k in n for k in ("gemm", "cutlass", "xmma", "sm90", "cublas", "matmul", "dot", "wgmma")):
        return "gemm"
    if any(k in n for k in ("fusion", "loop_", "input_", "reduce", "triton", "concatenate", "transpose",
                             "copy", "broadcast")):
        return "fusion"
    if "memcpy" in n or "memset" in n:
        return "memcpy/memset"
    return "other"


def _union(intervals) -> float:
    total, end = 0.0, -float("inf")
    for s, e in sorted(intervals):
        if s > end:
            total += e - s
            end = e
        elif e > end:
            total += e - end
            end = e
    return total


def trace(runner, updates: int = 10, label: str = "", kernel_phase: dict[str, str] | None = None) -> dict:
    """Trace a warm runner with `jax.profiler` and summarize the device activity per update.

    Args:
        runner: a calibrated `bench.timing.Runner`.
        updates: calls traced.
        label: the summary's heading.
        kernel_phase: `bench.hlo.kernel_phases` of the traced program: also sum the kernel time per phase.

    Returns:
        {"label", "wall_ms_per_update", "devices": [`summarize_kernels` of each device]}, or
        {"label", "error"}.
    """
    import jax

    runner.step()
    runner.sync()
    d = tempfile.mkdtemp(prefix="sf2prof")
    t0 = time.perf_counter()
    with jax.profiler.trace(d, create_perfetto_trace=True):
        for _ in range(updates):
            runner.step()
        runner.sync()
    wall = (time.perf_counter() - t0) / updates
    updates *= getattr(runner, "per_call", 1)
    wall /= getattr(runner, "per_call", 1)
    files = glob.glob(os.path.join(d, "**", "*perfetto_trace.json.gz"), recursive=True)
    if not files:
        return {"label": label, "error": "no perfetto trace written"}
    with gzip.open(files[0]) as f:
        data = json.load(f)
    events = data["traceEvents"] if isinstance(data, dict) else data
    pname, tname = {}, {}
    for e in events:
        if e.get("ph") == "M" and e.get("name") == "process_name":
            pname[e.get("pid")] = e.get("args", {}).get("name", "")
        if e.get("ph") == "M" and e.get("name") == "thread_name":
            tname[(e.get("pid"), e.get("tid"))] = e.get("args", {}).get("name", "")
    devices = [p for p, n in pname.items() if "gpu" in n.lower() or "device" in n.lower()]
    if not devices:   # CPU backend: the XLA worker threads
        devices = list(pname)
    out = {"label": label, "updates": updates, "wall_ms_per_update": wall * 1e3, "devices": []}
    for pid in devices:
        ks = [e for e in events if e.get("ph") == "X" and e.get("pid") == pid and "dur" in e
              and not tname.get((pid, e.get("tid")), "").lower().startswith(("python", "tf_xlapjrt"))]
        if ks:
            out["devices"].append(summarize_kernels(ks, updates, pname.get(pid, str(pid)), kernel_phase))
    return out


def idle_gaps(ks: list[dict], updates: int, top: int = 8, width: int = 48) -> dict:
    """Find where the device idles between kernels.

    Each interval in which no kernel runs is attributed to the kernel that ended last before it and the
    kernel that starts it.

    Args:
        ks: trace events with `name`, `ts`, `dur` (µs) and, in a torch.profiler trace, `args.stream`.
        updates: updates the events span.
        top: transitions listed.
        width: characters kept of a kernel's name.

    Returns:
        Per update: `idle_ms_per_update`, `gaps_per_update`, `cross_stream_ms_per_update` (idle time where
        the two kernels run on different streams) and `top`, the transitions with the most idle time.
    """
    def label(e):
        return f"{e.get('name', '?')[:width]} (stream {e.get('args', {}).get('stream', '?')})"

    by = collections.defaultdict(lambda: [0, 0.0])
    idle, gaps, cross, last = 0.0, 0, 0.0, None
    for e in sorted(ks, key=lambda e: e["ts"]):
        if last is not None and e["ts"] > last["ts"] + last["dur"]:
            gap = e["ts"] - (last["ts"] + last["dur"])
            idle, gaps = idle + gap, gaps + 1
            if last.get("args", {}).get("stream") != e.get("args", {}).get("stream"):
                cross += gap
            t = by[(label(last), label(e))]
            t[0] += 1
            t[1] += gap
        if last is None or e["ts"] + e["dur"] > last["ts"] + last["dur"]:
            last = e
    rows = sorted(by.items(), key=lambda kv: -kv[1][1])[:top]
    return {"idle_ms_per_update": idle / 1e3 / updates, "gaps_per_update": gaps / updates,
            "cross_stream_ms_per_update": cross / 1e3 / updates,
            "top": [{"after": a, "before": b, "count": v[0] / updates, "ms": v[1] / 1e3 / updates}
                    for (a, b), v in rows]}


def summarize_kernels(ks: list[dict], updates: int, device: str,
                      kernel_phase: dict[str, str] | None = None) -> dict:
    """Summarize one device's kernels per update.

    Args:
        ks: trace events with `name`, `ts`, `dur` (µs), from a JAX or a torch.profiler trace.
        updates: updates the events span.
        device: the device's name.
        kernel_phase: `bench.hlo.kernel_phases` of the traced program, or None.

    Returns:
        Per update: kernels, device-busy time (union of the kernels' intervals), the sum of kernel
        times, the split by category (GEMM, fusion, memcpy/memset, other), the costliest kernels (`top`),
        `idle_gaps` and every kernel by time (`kernels`); with `kernel_phase`, `by_phase` too
        (`phase_times`) and each kernel's phase.
    """
    by_name = collections.defaultdict(lambda: [0, 0.0])
    by_cat = collections.defaultdict(lambda: [0, 0.0])
    phase_of = {}
    for e in ks:
        name = e.get("name", "?")
        hlo = e.get("args", {}).get("hlo_op") or e.get("args", {}).get("long_name") or ""
        key = f"{name} [{hlo[:60]}]" if hlo and hlo != name else name
        by_name[key][0] += 1
        by_name[key][1] += e["dur"]
        if kernel_phase is not None and key not in phase_of:
            phase_of[key] = kernel_phase_of(e, kernel_phase)
        c = by_cat[_category(name)]
        c[0] += 1
        c[1] += e["dur"]
    busy = _union((e["ts"], e["ts"] + e["dur"]) for e in ks) / 1e3 / updates
    ranked = sorted(by_name.items(), key=lambda kv: -kv[1][1])
    top = ranked[:12]
    return {
        "device": device,
        "kernels_per_update": len(ks) / updates,
        "busy_ms_per_update": busy,
        "kernel_ms_per_update": sum(e["dur"] for e in ks) / 1e3 / updates,
        "by_category": {k: {"count": v[0] / updates, "ms": v[1] / 1e3 / updates} for k, v in by_cat.items()},
        "top": [{"name": k, "count": v[0] / updates, "ms": v[1] / 1e3 / updates} for k, v in top],
        "idle": idle_gaps(ks, updates),
        **({"by_phase": phase_times(ks, updates, kernel_phase)} if kernel_phase is not None else {}),
        "kernels": [{"name": k, "count": v[0] / updates, "ms": v[1] / 1e3 / updates,
                     **({"phase": phase_of[k]} if kernel_phase is not None else {})} for k, v in ranked],
    }


def kernel_phase_of(event: dict, kernel_phase: dict[str, str]) -> str:
    """The phase of one traced kernel: that of its instruction (`args.hlo_op`, else the kernel's own name,
    both spelled as `bench.hlo.kernel_name`), or "(unmatched)".

    Args:
        event: a trace event with `name` and, from XLA, `args.hlo_op`.
        kernel_phase: `bench.hlo.kernel_phases` of the traced program.

    Returns:
        The phase's name.
    """
    names = (event.get("args", {}).get("hlo_op"), event.get("name"))
    keys = [kernel_name(n.split()[0]) for n in names if n and n.split()]
    return next((kernel_phase[k] for k in keys if k in kernel_phase), "(unmatched)")


def phase_times(ks: list[dict], updates: int, kernel_phase: dict[str, str]) -> dict:
    """Sum the kernels' count and time per phase of the program that launched them.

    A kernel's phase is that of its instruction (`args.hlo_op`, else the kernel's own name, both spelled
    as `bench.hlo.kernel_name`); a kernel that names no instruction of the program (a library GEMM inside
    one of XLA's command buffers, a CPU thread's bookkeeping) is "(unmatched)".

    Args:
        ks: trace events with `name`, `dur` (µs) and, from XLA, `args.hlo_op`.
        updates: updates the events span.
        kernel_phase: `bench.hlo.kernel_phases` of the traced program.

    Returns:
        {phase: {"count", "ms"}} per update.
    """
    out = collections.defaultdict(lambda: [0, 0.0])
    for e in ks:
        phase = kernel_phase_of(e, kernel_phase)
        out[phase][0] += 1
        out[phase][1] += e["dur"]
    return {p: {"count": c / updates, "ms": t / 1e3 / updates} for p, (c, t) in out.items()}


def markdown(summaries: list[dict]) -> str:
    """Render profile summaries.

    Args:
        summaries: `trace` results (or `bench.agent_profile`'s, with host phases and HLO counts).

    Returns:
        profile.md's text.
    """
    out = ["# Device profile (jax.profiler; the torch trainer's: torch.profiler)", "",
           "Per update: wall time (dispatch to completion, traced), kernels launched, device-busy time "
           "(union of kernel intervals) and its split by kernel category; then the costliest kernels.", ""]
    for s in summaries:
        out.append(f"## {s['label']}")
        if "error" in s:
            out += ["", f"profile failed: {s['error']}", ""]
            continue
        out.append("")
        out.append(f"wall {s['wall_ms_per_update']:.3f} ms per update (under the profiler)")
        # the torch trainer's phases and its evaluation's (bench.agent_profile)
        for key, what, per, rest in (("host", "host, untraced epochs", "update", "the trainer's own Python "
                                      "between them"),
                                     ("evaluation", "evaluation", "env step", "the loop's own Python and "
                                      "tensors")):
            for how, h in s.get(key, {}).items():
                out += ["", f"{what} {how}: wall {h['wall_ms']:.3f} ms per {per}; "
                        + ", ".join(f"{k} {v:.3f} ms" for k, v in h["phases_ms"].items())
                        + f"; the rest ({rest}) {h['rest_ms']:.3f} ms"]
        if s.get("runtime"):
            out += ["", "CUDA runtime/driver calls per update (those that can wait first): "
                    + ", ".join(f"`{r['name']}` {r['count']:.1f} × / {r['ms']:.3f} ms" for r in s["runtime"])]
        for d in s["devices"]:
            cats = ", ".join(f"{k} {v['count']:.0f} kernels / {v['ms']:.3f} ms"
                             for k, v in sorted(d["by_category"].items(), key=lambda kv: -kv[1]["ms"]))
            out += ["", f"- {d['device']}: {d['kernels_per_update']:.0f} kernels, "
                    f"busy {d['busy_ms_per_update']:.3f} ms, "
                    f"sum of kernel times {d['kernel_ms_per_update']:.3f} ms; {cats}", "",
                    "| kernel [HLO op] | per update | ms per update |", "|---|---|---|"]
            out += [f"| `{t['name'][:110]}` | {t['count']:.0f} | {t['ms']:.4f} |" for t in d["top"]]
            if d.get("idle"):
                g = d["idle"]
                out += ["", f"Device idle between kernels: {g['idle_ms_per_update']:.3f} ms per update in "
                        f"{g['gaps_per_update']:.1f} gaps, {g['cross_stream_ms_per_update']:.3f} ms of it "
                        "where the next kernel runs on another stream than the last one; the longest "
                        "transitions:", "",
                        "| after | before | gaps per update | idle ms per update |", "|---|---|---|---|"]
                out += [f"| `{t['after']}` | `{t['before']}` | {t['count']:.2f} | {t['ms']:.4f} |"
                        for t in g["top"]]
            if d.get("by_phase"):
                total = sum(v["ms"] for v in d["by_phase"].values()) or 1.0
                out += ["", "Kernel time per phase (each traced kernel matched by name to its instruction "
                        "in the compiled program, `bench.profile.phase_times`):", "",
                        "| phase | kernels per update | ms per update | share of kernel time |",
                        "|---|---|---|---|"]
                ranked = sorted(d["by_phase"].items(), key=lambda kv: -kv[1]["ms"])
                out += [f"| {p} | {v['count']:.1f} | {v['ms']:.4f} | {v['ms'] / total:.1%} |"
                        for p, v in ranked]
                first = next((p for p, _ in ranked if not p.startswith("(")), None)
                own = [k for k in d.get("kernels", []) if k.get("phase") == first][:10]
                if own:
                    out += ["", f"The costliest kernels of {first}:", "",
                            "| kernel [HLO op] | per update | ms per update |", "|---|---|---|"]
                    out += [f"| `{k['name']}` | {k['count']:g} | {k['ms']:.4f} |" for k in own]
        if s.get("phases"):   # bench.agent_profile --hlo
            from .hlo import markdown as phases_markdown
            from .hlo import phases

            out += ["", phases_markdown(s["phases"], phases(), s["phases"]["sgd_steps"])]
        out.append("")
    return "\n".join(out)
