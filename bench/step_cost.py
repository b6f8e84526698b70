"""The arithmetic of one SGD step: XLA's cost analysis of the JAX trainer's per-seed SGD step, per
representation, and the matrix products' flops per phase.

    python -m bench.step_cost --task AcrobotSwingup --algo td3 --reps none,sf2 [--seeds 16] --out DIR

For each representation this compiles the algorithm's own `sgd_step` (`sf2_jax.agents.algorithms`) for the
`paper` preset's shapes (a batch of `batch_size`, the step's noise; with `--seeds N` > 1 `jax.vmap`ped
over N seeds as the trainer's several-seed program runs it, everything reported per seed), jitted under
the trainer's precisions (`Program._physics_precision`, `learner_precision`), from shapes only: nothing runs.
`step` is the first SGD step, so the step updates the policy (every step at the paper preset's
`policy_delay` = 1). Reported per SGD step:
- `flops`, `bytes accessed`, `transcendentals`: XLA's `cost_analysis()` of the step as compiled for the
  backend JAX runs on (bytes: the inputs and outputs of each top-level instruction, i.e. of each kernel
  on a GPU, so a CPU's count, with its other fusions, is no measure of a GPU's memory traffic; XLA's GPU
  flops leave out most GEMMs, which run as library calls or Triton fusions: use the products' flops);
- the products' flops, 2·M·N·K summed over the optimized HLO's `dot`s (also inside fusions) and library
  GEMMs (a GPU's cuBLAS calls), per phase of the step (`sf2_jax.agents.algorithms.PHASES`, named by
  `jax.named_scope`; `bench.hlo_phases.phase_of`).

At many seeds per device the epoch is the device's work end to end (bench/README.md, issue 12), so these
ratios bound what one representation's SGD step can cost against another's; at one seed the step's ~300
kernel launches set the pace instead. The trainer's epoch scans `grad_updates_per_step` of these steps with
the replay draws and the env step around them.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

from . import hlo_phases

_DIMS = re.compile(r"=\s*\(?[a-z]\w*\[([\d,]*)\]")   # an instruction's result (a tuple's first element)
_LHS = re.compile(r"\s(?:dot|custom-call)\(\s*(?:[a-z]\w*\[([\d,]*)\]\S*\s+)?%?([\w.\-]+)")
_CONTRACT = re.compile(r"lhs_contracting_dims=\{([\d,]*)\}")
_GEMM_CONTRACT = re.compile(r'"lhs_contracting_dimensions":\[([^\]]*)\]')   # a library GEMM's backend config


def _dims(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x]


def dot_flops(text: str, phases: tuple[str, ...]) -> dict:
    """{"dots": dots per call, "flops": their 2·M·N·K, "by_phase": {phase: flops}, "unparsed": library
    GEMMs per call whose contracting dimensions were not found (not counted)} of an optimized HLO
    module's text: every `dot`, fused or not, and every library GEMM (a GPU's cuBLAS custom call, its
    contracting dimensions from its backend config), weighted by the known trip counts of the loops around it
    (`bench.hlo_phases.runs`); a dot's phase is the last of `phases` its op_name names, else "(other)"."""
    comps, entry = hlo_phases.parse(text)
    weight, _, _ = hlo_phases.runs(comps, entry, into_fusions=True)
    dots, flops, by_phase, unparsed = 0.0, 0.0, {}, 0.0
    for comp, w in weight.items():
        shapes = {name: _dims(m.group(1)) for name, _, line in comps[comp] if (m := _DIMS.search(line))}
        for name, op, line in comps[comp]:
            if op == "dot":
                contract = _dims(_CONTRACT.search(line).group(1))
            elif op == "custom-call" and hlo_phases.kernel_kind(op, name, line) == "gemm":
                m = _GEMM_CONTRACT.search(line)
                if m is None:   # a library GEMM whose dimensions its config does not spell out
                    unparsed += w
                    continue
                contract = _dims(m.group(1).replace('"', ""))
            else:
                continue
            inline, lhs_name = _LHS.search(line).groups()
            lhs = _dims(inline) if inline is not None else shapes[lhs_name]
            f = 2.0 * math.prod(shapes[name]) * math.prod(lhs[i] for i in contract)
            dots += w
            flops += w * f
            phase = hlo_phases.phase_of(line, phases)
            by_phase[phase] = by_phase.get(phase, 0.0) + w * f
    return {"dots": dots, "flops": flops, "by_phase": by_phase, "unparsed": unparsed}


def step_cost(cfg, n_seeds: int = 1) -> dict:
    """The cost analysis of `cfg`'s SGD step (module docstring), per seed: at `n_seeds` > 1 the step
    `jax.vmap`ped over seeds as the trainer's several-seed program runs it, divided by `n_seeds`."""
    import jax
    from sf2_jax.agents.algorithms import PHASES
    from sf2_jax.agents.trainer import Program

    program = Program(cfg)
    algo, key = program.algo, jax.random.PRNGKey(0)
    params, opt_state = jax.eval_shape(algo.init, key)
    # a batch as the trainer draws it from its replay buffer (shapes only)
    buffer = program.buffer
    batch = jax.eval_shape(lambda k: buffer.sample(buffer.init(), k, cfg.batch_size), key)
    noise = jax.eval_shape(algo.step_noise, key, batch)
    step = lambda p, o, b, z: algo.sgd_step(p, o, b, z, 0)   # noqa: E731
    args = (params, opt_state, batch, noise)
    if n_seeds > 1:
        step = jax.vmap(step)
        args = jax.tree.map(lambda x: jax.ShapeDtypeStruct((n_seeds, *x.shape), x.dtype), args)
    with program._physics_precision(), program.learner_precision():
        compiled = jax.jit(step).lower(*args).compile()
    analysis = compiled.cost_analysis()
    if isinstance(analysis, list | tuple):   # older JAX: one dict per computation
        analysis = analysis[0]
    text = compiled.as_text()
    dots = dot_flops(text, PHASES)
    kernels = hlo_phases.count(text, PHASES)["by_phase"]
    return {"representation": cfg.representation, "seeds": n_seeds, "flops": analysis["flops"] / n_seeds,
            "bytes": analysis["bytes accessed"] / n_seeds,
            "transcendentals": analysis.get("transcendentals", 0.0) / n_seeds,
            "dot_dots": dots["dots"], "dot_flops": dots["flops"] / n_seeds, "dot_unparsed": dots["unparsed"],
            "dot_by_phase": {k: v / n_seeds for k, v in dots["by_phase"].items()},
            "kernels": sum(sum(kinds.values()) for kinds in kernels.values()),
            "backend": jax.default_backend()}


def markdown(rows: list[dict], phases: tuple[str, ...]) -> str:
    g, mib = (lambda x: f"{x / 1e9:.3f}"), (lambda x: f"{x / 2**20:.1f}")
    out = ["Per seed and SGD step (dots and kernels: per call of the program, all seeds; kernels: "
           "`bench.hlo_phases`' launches, meaningful for a GPU's program):", "",
           "| representation | seeds | GFLOP (XLA) | MiB accessed | M transcendentals | dots | dot GFLOP "
           "| kernels |",
           "|---|---|---|---|---|---|---|---|"]
    out += [f"| {r['representation']} | {r['seeds']} | {g(r['flops'])} | {mib(r['bytes'])} | "
            f"{r['transcendentals'] / 1e6:.2f} | {r['dot_dots']:.0f} | {g(r['dot_flops'])} | "
            f"{r['kernels']:.0f} |" for r in rows]
    skipped = [f"{r['representation']}: {r['dot_unparsed']:.0f}" for r in rows if r["dot_unparsed"]]
    if skipped:
        out += ["", "Library GEMMs whose dimensions were not found, not in the dot flops: "
                + ", ".join(skipped)]
    base = rows[0]
    if len(rows) > 1:
        out += ["", f"Against `{base['representation']}`:", "",
                "| representation | flops | bytes | transcendentals | dots | dot flops |",
                "|---|---|---|---|---|---|"]
        for r in rows[1:]:
            ratio = [f"{r[k] / base[k]:.2f}×" if base[k] else "–"
                     for k in ("flops", "bytes", "transcendentals", "dot_dots", "dot_flops")]
            out.append(f"| {r['representation']} | " + " | ".join(ratio) + " |")
    names = [p for p in (*phases, "(other)") if any(r["dot_by_phase"].get(p) for r in rows)]
    out += ["", "Products' GFLOP per phase:", "",
            "| phase | " + " | ".join(r["representation"] for r in rows) + " |",
            "|---" * (len(rows) + 1) + "|"]
    out += [f"| {p} | " + " | ".join(g(r["dot_by_phase"].get(p, 0.0)) for r in rows) + " |" for p in names]
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.step_cost", description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="AcrobotSwingup")
    p.add_argument("--algo", default="td3")
    p.add_argument("--reps", default="none,sf2", help="comma list; ratios are against the first")
    p.add_argument("--seeds", type=int, default=1, help="seeds vmapped in one program (the trainer's way)")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    p.add_argument("--out", help="folder for step_cost.md / step_cost.json / machine.json")
    args = p.parse_args(argv)
    from sf2_common.errors import ConfigError

    from .agent_throughput import framework_configs, parse_sets
    from .machine import describe

    try:   # every config before anything compiles
        overrides = parse_sets(args.set, ["jax"])
        configs, check = framework_configs("jax", (0,))
        cfgs = [configs.make_config("paper", args.task, args.algo, rep, overrides)
                for rep in args.reps.split(",") if rep]
        for cfg in cfgs:
            check(cfg)
    except (ConfigError, ValueError) as err:
        p.error(str(err))
    if not cfgs:
        p.error("--reps names no representation")
    if args.seeds < 1:
        p.error(f"--seeds must be >= 1, got {args.seeds}")
    from sf2_jax.agents.algorithms import PHASES

    rows = []
    for cfg in cfgs:
        rows.append(step_cost(cfg, args.seeds))
        print(f"  {cfg.representation}: {rows[-1]['flops'] / 1e9:.3f} GFLOP per SGD step", flush=True)
    command = "python -m bench.step_cost " + " ".join(argv if argv is not None else sys.argv[1:])
    cfg = cfgs[0]
    text = (f"Command: `{command}`\n\nOne SGD step of the `paper` preset, {args.task}, {args.algo}, "
            f"{args.seeds} seed(s) (batch {cfg.batch_size}, hidden {list(cfg.hidden_sizes)}, learner "
            f"precision {cfg.learner_precision}); XLA's cost analysis on the {rows[0]['backend']} backend "
            "(bench/step_cost.py).\n\n" + markdown(rows, PHASES))
    print(text)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "step_cost.md").write_text(text + "\n")
        (out / "step_cost.json").write_text(json.dumps(rows, indent=1))
        info = describe(str(Path(__file__).resolve().parents[1]), command)
        (out / "machine.json").write_text(json.dumps(info, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
