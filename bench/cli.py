"""`python -m bench`: the wall-clock cost of one SGD update of vanilla TD3/SAC and of TD3/SAC + SF².

Measures milliseconds per full update (critic, flow, actor, targets) over a grid of frameworks (JAX,
torch eager, compiled, CUDA graphs), algorithms, representations, denoising steps T and integrators, and
the paired ratios SF²/vanilla, T=8/T=1 and torch/JAX (bench/README.md says how to read them).

Subcommands:
  run        (default) time full SGD updates; write updates.csv, updates.md, updates.png, machine.json
  flow-step  time the JAX flow-loss step alone (value_and_grad + Adam on ψ, ζ), fast path against oracle
  report     re-render updates.md / updates.png from a results folder's CSV
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import shutil
import sys
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).resolve().parent / "results"


def _ints(s: str) -> tuple[int, ...]:
    return tuple(int(x) for x in s.split(",") if x)


def _names(s: str) -> tuple[str, ...]:
    return tuple(x.strip() for x in s.split(",") if x.strip())


def _tasks(s: str) -> list[str]:
    from .sizes import TASKS, resolve_task, unique_sizes

    if s == "all":
        return list(TASKS)
    if s == "unique":
        return unique_sizes(TASKS)
    return [resolve_task(x) for x in _names(s)]


def _unknown(values, valid, flag: str) -> str | None:
    bad = [v for v in values if v not in valid]
    return (f"{flag}: {', '.join(map(repr, bad))} unknown; valid: {', '.join(valid) or '(none registered)'}"
            if bad else None)


def check(args) -> str | None:
    """Find the first problem in the lists that `run` or `flow-step` were given.

    A bad name would otherwise be skipped silently (a framework or representation) or stop the run with
    a traceback after the machine description (a task).

    Args:
        args: the parsed arguments of `run` or `flow-step`.

    Returns:
        A message naming the flag and the valid choices, or None when every list is valid.
    """
    from .jax_steps import FLOW_VARIANTS, baselines_available
    from .sizes import ALGOS, FRAMEWORKS, INTEGRATORS, VARIANT_REPS

    for flag in ("steps", "compiled_steps", "variant_steps", "flow_steps"):
        text = getattr(args, flag, None)
        if text is None or (flag == "compiled_steps" and text == "all"):
            continue
        values = [x.strip() for x in text.split(",") if x.strip()]
        if not values or not all(v.isdigit() and int(v) >= 1 for v in values):
            return f"--{flag.replace('_', '-')}: {text!r} is not a comma list of denoising steps >= 1"
    for flag in ("tasks", "flow_tasks", "compiled_tasks"):
        if getattr(args, flag, None):
            try:
                _tasks(getattr(args, flag))
            except ValueError as err:
                return f"--{flag.replace('_', '-')}: {err}"
    lists = [("integrators", INTEGRATORS), ("compiled_integrators", INTEGRATORS),
             ("flow_variants", tuple(FLOW_VARIANTS)), ("variants", tuple(FLOW_VARIANTS))]
    if args.cmd == "run":
        lists += [("frameworks", FRAMEWORKS), ("algos", ALGOS), ("compiled_algos", ALGOS),
                  ("variant_algos", ALGOS)]
        if args.reps != "auto":
            lists.append(("reps", ("none", "sf2", *baselines_available("jax"), *sorted(VARIANT_REPS))))
    for flag, valid in lists:
        text = getattr(args, flag, None)
        problem = text is not None and _unknown(_names(text), valid, f"--{flag.replace('_', '-')}")
        if problem:
            return problem
    return None


class Log:
    """A run's log: each line printed with the seconds since the start, and kept for log.txt."""

    def __init__(self):
        self.lines: list[str] = []
        self.t0 = time.perf_counter()

    def __call__(self, msg: str) -> None:
        line = f"[{time.perf_counter() - self.t0:7.1f}s] {msg}"
        self.lines.append(line)
        print(line, flush=True)

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0


def _has_gpu() -> bool:
    try:
        import jax

        return any(d.platform == "gpu" for d in jax.devices())
    except Exception:  # noqa: BLE001
        return False


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--size", choices=("small", "quick", "medium", "paper"), default=None,
                   help="network/batch preset (default: paper on a GPU, small otherwise)")
    p.add_argument("--tasks", default="cartpole,cheetah",
                   help="comma list of tasks or aliases, 'unique' (the six distinct sizes) or 'all'")
    p.add_argument("--repeats", type=int, default=7, help="interleaved timing rounds")
    p.add_argument("--warmup", type=int, default=3, help="updates per case before calibration")
    p.add_argument("--block-s", type=float, default=0.2, help="target seconds per timed block")
    p.add_argument("--precision", default="highest", help="jax_default_matmul_precision")
    p.add_argument("--allow-tf32", action="store_true", help="torch TF32 (never for published numbers)")
    p.add_argument("--threads", type=int, default=None,
                   help="intra-op threads of both frameworks (default 1 on a CPU-only host: "
                   "torch.set_num_threads, XLA --xla_cpu_multi_thread_eigen=false)")
    p.add_argument("--out", default=None, help="results folder (default bench/results/<machine>)")
    p.add_argument("--machine", default=None, help="machine name for the results folder")
    p.add_argument("--budget-s", type=float, default=None,
                   help="wall-clock budget: stop building cases when 3 timing rounds would no longer "
                        "fit, stop rounds (after at least 3) when the next would not")
    p.add_argument("--seed", type=int, default=0)


def parser() -> argparse.ArgumentParser:
    """Build the argument parser of `python -m bench`.

    Returns:
        The parser, with the subcommands `run`, `flow-step` and `report`.
    """
    p = argparse.ArgumentParser(prog="python -m bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd")
    r = sub.add_parser("run", help="time full SGD updates (default)",
                       description="Time full SGD updates (critic, flow, actor, targets) over a grid of "
                       "frameworks, algorithms, representations, denoising steps and integrators: ms per "
                       "update and the paired ratios SF²/vanilla, T=8/T=1, torch/JAX.")
    _common(r)
    r.add_argument("--frameworks", default="jax,torch,torch-compile")
    r.add_argument("--algos", default="td3,sac")
    r.add_argument("--reps", default="auto",
                   help="representations: none (vanilla), sf2, the baselines (sim, simlap, simlap_authors, "
                        "spr: sf2_baselines) and any variant a bench module registered; auto = none,sf2 + "
                        "the baselines when sf2_baselines imports")
    r.add_argument("--steps", default="1,2,4,8", help="denoising steps T")
    r.add_argument("--integrators", default="midpoint,euler")
    r.add_argument("--compiled-steps", default="1,8",
                   help="T values timed for torch-compile ('all' for every T; compiling is slow)")
    r.add_argument("--compiled-algos", default="td3,sac",
                   help="algorithms timed for the compiled torch modes")
    r.add_argument("--compiled-integrators", default="midpoint",
                   help="integrators timed for the compiled torch modes ('midpoint,euler' for both)")
    r.add_argument("--variant-algos", default="td3",
                   help="algorithms timed for the registered variant representations")
    r.add_argument("--variant-steps", default="1,8",
                   help="T values timed for the registered variant representations")
    r.add_argument("--jax-scan", type=int, default=8,
                   help="updates per call of the `jax-scan` framework (lax.scan, as the trainer's "
                        "grad_updates_per_step = 8); `jax` makes one call per update")
    r.add_argument("--device", default="auto", help="torch device: auto, cpu, cuda")
    r.add_argument("--flow-step", action="store_true", help="also run the flow-step table in this run")
    r.add_argument("--flow-steps", default="1,8")
    r.add_argument("--flow-variants", default="", help="registered flow-loss variants for the flow step")
    r.add_argument("--flow-tasks", default=None,
                   help="tasks of the flow-step table (default: last of --tasks)")
    r.add_argument("--flow-accuracy", action="store_true",
                   help="also measure the float32 flow-loss gradient error (fast path and each variant) "
                        "against float64")
    r.add_argument("--compiled-tasks", default=None,
                   help="tasks timed for the compiled torch modes (default all)")
    r.add_argument("--no-peak", action="store_true", help="skip the fp32 matmul ceiling measurement")
    r.add_argument("--dump-hlo", action="store_true",
                   help="write the optimized HLO of the JAX TD3 SF² updates at the largest T (first task)")
    r.add_argument("--profile", action="store_true",
                   help="after timing, trace JAX TD3 updates of the first task (vanilla, SF² T=1 and the "
                        "largest T, variants at T=1) with jax.profiler; write profile.md")
    f = sub.add_parser("flow-step", help="JAX flow-loss step: fast path vs oracle",
                       description="Time the JAX flow-loss step alone (value_and_grad of flow_loss and Adam "
                       "on ψ, ζ) per T: the fast path (ζ never built) against the oracle, in ms per step.")
    _common(f)
    f.set_defaults(tasks="cheetah")
    f.add_argument("--steps", default="1,8")
    f.add_argument("--integrators", default="midpoint")
    f.add_argument("--variants", default="", help="registered flow-loss variants to time as well")
    f.add_argument("--accuracy", action="store_true",
                   help="also measure the float32 flow-loss gradient error (fast path and each variant) "
                        "against float64")
    rep = sub.add_parser("report", help="re-render markdown and plot from a results folder",
                         description="Re-render updates.md and updates.png of a results folder from its "
                         "updates.csv and machine.json.")
    rep.add_argument("folder")
    rep.add_argument("--recount-flops", action="store_true",
                     help="recompute the JAX rows' FLOPs on this machine's CPU backend (results of runs "
                          "whose GPU cost analysis undercounted) before rendering")
    return p


def main(argv=None) -> int:
    """Run `python -m bench`.

    Args:
        argv: the command line after `python -m bench` (default `sys.argv[1:]`); without a subcommand,
            `run`.

    Returns:
        The exit status (2, with nothing written, for an invalid argument).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0].startswith("-") and argv[0] not in ("-h", "--help"):
        argv = ["run", *argv]
    p = parser()
    args = p.parse_args(argv)
    if args.cmd in ("run", "flow-step"):
        problem = check(args)
        if problem:
            p.error(problem)   # exit status 2, before anything is imported, built or written
    if args.cmd == "report":
        from .report import render

        if args.recount_flops:
            _recount_flops(Path(args.folder))
        render(Path(args.folder))
        print(f"re-rendered {args.folder}")
        return 0
    # JAX and torch in one process: no preallocation (JAX would reserve most of the GPU)
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    gpu_host = bool(shutil.which("nvidia-smi")) or os.path.exists("/dev/nvidia0")
    if args.threads is None and not gpu_host:
        args.threads = 1   # a CPU host: one thread per framework (fair, and robust on a shared machine)
    if args.threads == 1 and "jax" not in sys.modules:
        flags = os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false"
        os.environ["XLA_FLAGS"] = flags.strip()
    command = "python -m bench " + " ".join(shlex.quote(a) for a in argv)
    log = Log()
    from . import jax_steps, machine

    jax_steps.configure(args.precision)
    if args.cmd == "run" and any(fw.startswith("torch") for fw in _names(args.frameworks)):
        from . import torch_steps

        torch_steps.configure(args.allow_tf32, args.threads)
    if args.size is None:
        args.size = "paper" if _has_gpu() else "small"
    name = args.machine or machine.default_name()
    out = Path(args.out) if args.out else RESULTS / name
    out.mkdir(parents=True, exist_ok=True)
    info = machine.describe(str(ROOT), command)
    info.update(name=name, repeats=args.repeats, warmup=args.warmup, block_s=args.block_s,
                threads=args.threads or "framework default")
    log(f"machine {name}: cpu {info['cpu']}, gpu {info['gpu']}, load {info['load_average']}; out {out}")
    try:
        if args.cmd == "flow-step":
            flow_step(args, out, info, log)
        else:
            run(args, out, info, log)
    finally:
        (out / "log.txt").write_text("\n".join(log.lines) + "\n")
    return 0


def _recount_flops(folder: Path) -> None:
    from . import jax_steps, report
    from .sizes import Case

    rows = report.read_csv(folder / "updates.csv")
    for r in rows:
        if r["framework"] not in ("jax", "jax-scan"):
            continue
        case = Case("jax", r["algo"], r["rep"], r["task"], r["size"], int(r["steps"]), r["integrator"])
        try:
            r["flops"] = jax_steps.count_flops(case)
            r["flops_source"] = "XLA HLO cost analysis, lowered for CPU (recounted)"
        except Exception as e:  # noqa: BLE001 — e.g. a dot algorithm the CPU backend lacks
            r["flops"] = float("nan")
            r["flops_source"] = f"n/a ({type(e).__name__})"
        r["achieved_tflops"] = r["flops"] / (r["median_ms"] * 1e-3) / 1e12
        print(f"{case.key}: {r['flops'] / 1e9:.3f} GFLOP")
    report.write_csv(rows, folder / "updates.csv")


# ------------------------------------------------------------------------------------------------ run
def _peak(frameworks, device: str, log) -> dict:
    """fp32 matmul ceiling of each framework at the configured precision (one large square product)."""
    peak = {}
    gpu = device == "cuda" or _has_gpu()
    n = 8192 if gpu else 1024
    reps = 10 if gpu else 3
    try:
        import jax
        import jax.numpy as jnp

        a = jax.random.normal(jax.random.key(1), (n, n), jnp.float32)
        b = jax.random.normal(jax.random.key(2), (n, n), jnp.float32)
        f = jax.jit(lambda x, y: x @ y)
        f(a, b).block_until_ready()
        t0 = time.perf_counter()
        for _ in range(reps):
            c = f(a, b)
        c.block_until_ready()
        peak["jax"] = 2 * n**3 * reps / (time.perf_counter() - t0) / 1e12
    except Exception as e:  # noqa: BLE001
        log(f"jax peak failed: {e}")
    if any(fw.startswith("torch") for fw in frameworks):
        try:
            import torch

            dev = torch.device(device)
            a = torch.randn(n, n, device=dev)
            b = torch.randn(n, n, device=dev)
            a @ b
            sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
            sync()
            t0 = time.perf_counter()
            for _ in range(reps):
                a @ b
            sync()
            peak["torch"] = 2 * n**3 * reps / (time.perf_counter() - t0) / 1e12
        except Exception as e:  # noqa: BLE001
            log(f"torch peak failed: {e}")
    log("fp32 matmul ceiling (TFLOP/s): " + ", ".join(f"{k} {v:.2f}" for k, v in peak.items()))
    return peak


def _torch_device(arg: str) -> str:
    if arg != "auto":
        return arg
    try:
        import torch

        return "cuda" if torch.cuda.is_available() else "cpu"
    except Exception:  # noqa: BLE001
        return "cpu"


def run(args, out: Path, info: dict, log) -> None:
    """Time every case of `run`'s grid in interleaved rounds and write the results folder.

    Args:
        args: the parsed arguments of `run`.
        out: results folder: updates.csv, updates.md, updates.png, machine.json (and, as asked,
            flow_step.*, profile.md, hlo-*.txt.gz).
        info: the machine description (`bench.machine.describe`); the measured ceilings are added.
        log: a callable taking one line.
    """
    from . import report, sizes, timing

    frameworks = _names(args.frameworks)
    steps = _ints(args.steps)
    compiled_steps = None if args.compiled_steps == "all" else _ints(args.compiled_steps)
    tasks = _tasks(args.tasks)
    if args.reps == "auto":
        from .jax_steps import baselines_available

        reps = ["none", "sf2", *baselines_available("jax")]
    else:
        reps = list(_names(args.reps))
    if any(fw.startswith("torch") for fw in frameworks):
        info["torch_impl"] = ("sf2_torch.agents sgd_step (torch: eager; torch-graphs: + StepGraph "
                              "(CUDA graph); torch-compile: compile_mode='default'; "
                              "torch-cudagraphs: both)")
    device = _torch_device(args.device)
    cases = sizes.grid(frameworks, _names(args.algos), reps, tasks, args.size, steps,
                       _names(args.integrators), compiled_steps, _ints(args.variant_steps),
                       _names(args.compiled_algos), _names(args.variant_algos),
                       _names(args.compiled_integrators))
    if args.compiled_tasks:
        keep = set(_tasks(args.compiled_tasks))
        cases = [c for c in cases if c.framework not in sizes.COMPILED or c.task in keep]
    log(f"{len(cases)} cases, size {args.size}, torch device {device}")
    if not args.no_peak:
        info["peak"] = _peak(frameworks, device, log)
    budget = args.budget_s or float("inf")
    flow_md = ""
    if args.flow_step:   # first: it is small
        flow_md = flow_step(args, out, info, log, steps=_ints(args.flow_steps),
                            variants=_names(args.flow_variants), write_machine=False)
    runners, meta = [], {}

    def round_s() -> float:   # projected seconds of one timing round
        return sum(r.n * (r.probe_s or args.block_s) for r in runners) * 1.1 + 0.05 * len(runners)

    reserve = 30 + (30 if args.profile else 0)
    for case in cases:
        if log.elapsed() + 3 * round_s() + reserve > budget:
            log(f"budget: skipping {case.key} and later cases")
            break
        try:
            runner, extra = _build(case, device, args)
            timing.calibrate(runner, args.warmup, args.block_s)
            runners.append(runner)
            meta[runner.name] = (case, extra)
            log(f"built {case.key}: compile {runner.compile_s:.1f}s, n={runner.n}, "
                f"flops {extra.get('flops', float('nan')) / 1e9:.3f} G")
        except Exception as e:  # noqa: BLE001 — one broken case must not lose the run
            log(f"FAILED {case.key}: {type(e).__name__}: {e}")
            log(traceback.format_exc(limit=3))
    rounds = 0
    for _ in range(args.repeats):
        if rounds >= 3 and log.elapsed() + round_s() + 20 > budget:
            log("budget: stopping rounds")
            break
        timing.measure(runners, 1, log=lambda s: None)
        rounds += 1
        log(f"round {rounds}/{args.repeats} done")
    info["repeats"] = rounds
    rows = [_row(r, *meta[r.name]) for r in runners]
    report.write_csv(rows, out / "updates.csv")
    (out / "machine.json").write_text(json.dumps(info, indent=1, default=str))
    (out / "updates.md").write_text(report.markdown(rows, info, extra=report._strip_title(flow_md)))
    try:
        report.plot(rows, out / "updates.png", title=f"SF² update time, {info['name']}")
    except Exception as e:  # noqa: BLE001
        log(f"plot failed: {e}")
    log(f"wrote {out}/updates.csv, updates.md, updates.png, machine.json")
    _print_summary(rows, log)
    if args.dump_hlo:
        import gzip

        for r in runners:
            case, extra = meta[r.name]
            if (case.framework == "jax" and case.algo == "td3" and case.task == tasks[0] and case.has_ode
                    and case.steps == max(steps) and case.integrator == "midpoint" and "hlo" in extra):
                name = f"hlo-{case.rep}-T{case.steps}.txt.gz"
                with gzip.open(out / name, "wt") as f:
                    f.write(extra["hlo"]())
                log(f"wrote {name}")
    if args.profile:   # last: the tables are already written if the profiler misbehaves
        _profile(runners, meta, tasks[0], steps, out, log, budget)


def _profile(runners, meta, task, steps, out, log, budget) -> None:
    from . import profile, sizes

    want = []
    fws = {meta[r.name][0].framework for r in runners}
    jfw = "jax-scan" if "jax-scan" in fws else "jax"   # no host dispatch in the scanned program
    for r in runners:
        case = meta[r.name][0]
        if case.framework != jfw or case.algo != "td3" or case.task != task:
            continue
        if case.rep == "none" or (case.rep == "sf2" and case.integrator == "midpoint"
                                  and case.steps in (1, max(steps))) or (
                case.rep in sizes.VARIANT_REPS and case.steps <= 1):
            want.append(r)
    summaries = []
    for r in want:
        if log.elapsed() + 15 > budget:
            log("budget: stopping profiles")
            break
        try:
            summaries.append(profile.trace(r, 10, r.name))
            log(f"profiled {r.name}")
        except Exception as e:  # noqa: BLE001
            log(f"profile of {r.name} failed: {type(e).__name__}: {e}")
    (out / "profile.md").write_text(profile.markdown(summaries))


def _build(case, device, args):
    if case.framework in ("jax", "jax-scan"):
        from . import jax_steps

        scan = args.jax_scan if case.framework == "jax-scan" else 1
        return jax_steps.update_runner(case, seed=args.seed, scan=scan)
    from . import torch_steps

    runner, extra = torch_steps.update_runner(case, device, seed=args.seed)
    try:
        extra["flops"] = torch_steps.count_flops(case, device, seed=args.seed)
        extra["flops_source"] = "torch FlopCounterMode (matmuls)"
    except Exception as e:  # noqa: BLE001
        extra["flops_source"] = f"n/a ({type(e).__name__})"
    return runner, extra


def _row(runner, case, extra) -> dict:
    from .timing import summary

    s = {k: v * 1e3 for k, v in summary(runner.times).items()}
    flops = float(extra.get("flops", float("nan")))
    finite = extra.get("finite")
    try:
        finite = finite() if callable(finite) else finite
    except Exception:  # noqa: BLE001
        finite = "?"
    return dict(
        framework=case.framework, algo=case.algo, rep=case.rep, task=case.task, obs_size=case.obs_size,
        action_size=case.action_size, size=case.size, batch_size=case.batch_size, steps=case.steps,
        integrator=case.integrator, median_ms=s["median"], q25_ms=s["q25"], q75_ms=s["q75"], min_ms=s["min"],
        repeats=len(runner.times), n_per_block=runner.n, compile_s=runner.compile_s, flops=flops,
        flops_source=extra.get("flops_source", "XLA HLO cost_analysis (lowered)"
                               if case.framework == "jax" else ""),
        bytes=float(extra.get("bytes", float("nan"))),
        achieved_tflops=flops / (s["median"] * 1e-3) / 1e12 if s["median"] and not math.isnan(flops) else
        float("nan"),
        finite=finite, impl=extra.get("impl", "sf2_jax.agents sgd_step (jit, donated)"
                                      if case.framework == "jax" else ""),
        times_ms=[t * 1e3 for t in runner.times],
    )


def _print_summary(rows, log) -> None:
    for r in rows:
        log(f"{r['framework']:>13} {r['algo']} {r['rep']:>4} T{r['steps']} {r['integrator']:<8} "
            f"{r['task']:<22} {r['median_ms']:9.3f} ms [{r['q25_ms']:.3f}–{r['q75_ms']:.3f}] "
            f"{r['achieved_tflops']:.3f} TFLOP/s finite={r['finite']}")


# ------------------------------------------------------------------------------------------ flow step
def flow_step(args, out: Path, info: dict, log, steps=None, variants=None, write_machine=True) -> str:
    """Time the JAX flow-loss step at `args.size` for each T: fast path, oracle and the named variants.

    Args:
        args: the parsed arguments of `flow-step` (or of `run --flow-step`).
        out: results folder; flow_step.csv and flow_step.md are written there.
        info: the machine description (`bench.machine.describe`).
        log: a callable taking one line.
        steps: denoising steps T (default `args.steps`).
        variants: names of `jax_steps.FLOW_VARIANTS` to time as well (default `args.variants`).
        write_machine: also write machine.json.

    Returns:
        The markdown table (flow_step.md's text).
    """
    import csv

    from . import jax_steps, sizes, timing

    steps = steps or _ints(args.steps)
    variants = variants if variants is not None else _names(getattr(args, "variants", ""))
    integrators = (_names(getattr(args, "integrators", "midpoint")) if args.cmd == "flow-step"
                   else ("midpoint",))
    if args.cmd == "flow-step":
        tasks = _tasks(args.tasks)
    else:
        tasks = _tasks(args.flow_tasks) if args.flow_tasks else _tasks(args.tasks)[-1:]
    accuracy = getattr(args, "accuracy", False) or getattr(args, "flow_accuracy", False)
    protos = {v: jax_steps.FLOW_VARIANTS[v] for v in variants}
    runners, meta = [], {}
    for task in tasks:
        D, A = sizes.TASKS[task]
        for integ in integrators:
            for T in steps:
                specs = [("fast", True, None), ("oracle", False, None)]
                specs += [(v, True, fn) for v, fn in protos.items()]
                for label, contract, fn in specs:
                    name = f"flow/{task}/{label}/T{T}/{integ}"
                    try:
                        r, extra = jax_steps.flow_step_runner(D, A, args.size, T, integ, contract,
                                                              seed=args.seed, loss_fn=fn, label=name)
                        timing.calibrate(r, args.warmup, args.block_s)
                    except Exception as e:  # noqa: BLE001
                        log(f"FAILED {name}: {type(e).__name__}: {e}")
                        continue
                    runners.append(r)
                    meta[name] = dict(task=task, variant=label, steps=T, integrator=integ, **extra)
                    log(f"built {name}: compile {r.compile_s:.1f}s n={r.n} "
                        f"flops {extra.get('flops', 0) / 1e9:.3f} G")
    timing.measure(runners, args.repeats, log=log)
    rows = []
    for r in runners:
        m = meta[r.name]
        s = timing.summary(r.times)
        rows.append(dict(task=m["task"], variant=m["variant"], steps=m["steps"], integrator=m["integrator"],
                         size=args.size, median_ms=s["median"] * 1e3, q25_ms=s["q25"] * 1e3,
                         q75_ms=s["q75"] * 1e3, min_ms=s["min"] * 1e3, flops=m.get("flops", float("nan")),
                         bytes=m.get("bytes", float("nan")), compile_s=r.compile_s,
                         first_loss=m["first_loss"](),
                         times_ms=";".join(f"{t * 1e3:.6g}" for t in r.times)))
    with open(out / "flow_step.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else ["task"])
        w.writeheader()
        w.writerows(rows)
    md = _flow_md(rows, runners, args, info)
    if accuracy:
        err_rows = []
        for task in tasks:
            D, A = sizes.TASKS[task]
            for T in steps:
                try:
                    err_rows += [dict(task=task, **e) for e in
                                 jax_steps.grad_errors(D, A, args.size, T, protos, seed=args.seed)]
                except Exception as e:  # noqa: BLE001
                    log(f"grad_errors failed: {type(e).__name__}: {e}")
        md += _errors_md(err_rows)
    (out / "flow_step.md").write_text(md)
    if write_machine:
        (out / "machine.json").write_text(json.dumps(info, indent=1, default=str))
    print(md)
    return md


def _flow_md(rows, runners, args, info) -> str:
    from .sizes import SIZES
    from .timing import paired_ratio

    times = {r.name: r.times for r in runners}
    s = SIZES[args.size]
    out = [f"# Flow-loss step (JAX): fast path vs oracle, size `{args.size}`", "",
           f"value_and_grad of `sf2_jax.losses.flow_loss` + Adam on (ψ, ζ), jitted with donated buffers; "
           f"B = {s['batch_size']}, F = {s['feature_size']}, hidden {s['zeta_hidden_sizes']}; "
           f"`jax_default_matmul_precision={info.get('jax_default_matmul_precision', args.precision)}`; "
           f"{args.repeats} interleaved rounds, median ms [quartiles]. `fast` = `contract_zeta=True` "
           "(docs/core-contract.md, fast path), `oracle` = `contract_zeta=False` (ζ materialized).", "",
           "| task | T | integrator | variant | ms | GFLOP (XLA) | first-step loss | oracle / variant |",
           "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        name = f"flow/{row['task']}/{row['variant']}/T{row['steps']}/{row['integrator']}"
        oracle = f"flow/{row['task']}/oracle/T{row['steps']}/{row['integrator']}"
        ratio = "–"
        if oracle in times and row["variant"] != "oracle":
            m, lo, hi = paired_ratio(times[oracle], times[name])
            ratio = f"{m:.2f}× [{lo:.2f}–{hi:.2f}]"
        out.append(f"| {row['task']} | {row['steps']} | {row['integrator']} | {row['variant']} | "
                   f"{row['median_ms']:.3f} [{row['q25_ms']:.3f}–{row['q75_ms']:.3f}] | "
                   f"{row['flops'] / 1e9:.2f} | {row['first_loss']:.7g} | {ratio} |")
    steps = sorted({row["steps"] for row in rows})
    if len(steps) > 1:
        lo_t, hi_t = steps[0], steps[-1]
        out += ["", f"T={hi_t} / T={lo_t} per variant (paired): " + "; ".join(
            f"{row['task']} {row['variant']} "
            f"{paired_ratio(times[_fname(row, hi_t)], times[_fname(row, lo_t)])[0]:.2f}×"
            for row in rows if row["steps"] == lo_t and _fname(row, hi_t) in times)]
    return "\n".join(out) + "\n"


def _errors_md(rows) -> str:
    if not rows:
        return ""
    out = ["", "Gradient accuracy of the flow loss at the initial parameters (one batch; float32 at this "
           "run's precision against the fast path in float64, g₆₄): per group, the worst leaf of "
           "‖g − g₆₄‖∞ / ‖g₆₄‖∞ (and which leaf) and the whole group's ‖g − g₆₄‖₂ / ‖g₆₄‖₂. A ReLU "
           "pre-activation within float32 rounding of 0 switches one sample's contribution to one hidden "
           "unit on or off: such an event shows as ~1e-2 in the worst-leaf column of a ζ leaf before the "
           "last ReLU while the 2-norm column stays ~1e-3 (docs/parity.md, \"float32 ζ gradient\").", "",
           "| task | T | variant | ψ worst leaf | ζ worst leaf | ζ worst leaf name | ψ 2-norm | ζ 2-norm |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            out.append(f"| {r['task']} | {r['steps']} | {r['variant']} | {r['error']} | | | | |")
        else:
            out.append(f"| {r['task']} | {r['steps']} | {r['variant']} | {r['psi_rel_err']:.2e} | "
                       f"{r['zeta_rel_err']:.2e} | {r['zeta_worst_leaf']} | {r['psi_rel_err_2']:.2e} | "
                       f"{r['zeta_rel_err_2']:.2e} |")
    return "\n".join(out) + "\n"


def _fname(row, T):
    return f"flow/{row['task']}/{row['variant']}/T{T}/{row['integrator']}"
