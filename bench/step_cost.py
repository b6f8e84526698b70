"""The arithmetic of one SGD step: XLA's cost analysis of the JAX trainer's SGD step per representation,
and the matrix products' flops per phase.

    python -m bench.step_cost --task AcrobotSwingup --algo td3 --reps none,sf2 [--seeds 16] --out OUT

Each representation's own `sgd_step` is compiled for the `paper` preset's shapes (with `--seeds N`,
`jax.vmap`ped over N seeds as the trainer runs it; everything per seed) under the trainer's precisions,
from shapes only: nothing runs. Reported per SGD step: XLA's flops, bytes accessed (the inputs and
outputs of each kernel; a GPU's figure, not a CPU's) and transcendentals; the products' flops (2·M·N·K
over every `dot` and library GEMM of the optimized HLO, also per phase: XLA's GPU flops leave most GEMMs
out); the kernels. Bytes over the device's bandwidth plus product flops over its peak bound the step's
time where the device is busy end to end (many seeds); at one seed the kernel launches set the pace.

An on-policy `--algo` (`ppo`, `fpo`: `--task minatar-breakout --algo ppo --reps none,sf2,sf2-ae`) gets
`update_cost`, one update composed of its parts.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

from . import hlo

_DIMS = re.compile(r"=\s*\(?[a-z]\w*\[([\d,]*)\]")   # an instruction's result (a tuple's first element)
_LHS = re.compile(r"\s(?:dot|custom-call)\(\s*(?:[a-z]\w*\[([\d,]*)\]\S*\s+)?%?([\w.\-]+)")
_CONTRACT = re.compile(r"lhs_contracting_dims=\{([\d,]*)\}")
_GEMM_CONTRACT = re.compile(r'"lhs_contracting_dimensions":\[([^\]]*)\]')   # a library GEMM's backend config


def _dims(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x]


def dot_flops(text: str, phases: tuple[str, ...]) -> dict:
    """Count the flops of the matrix products of an optimized HLO module.

    Every `dot`, fused or not, and every library GEMM (a GPU's cuBLAS call, its contracting dimensions
    from its backend config), weighted by the known trip counts of the loops around it (`bench.hlo.runs`).

    Args:
        text: the optimized module's text.
        phases: the phase scopes (`bench.hlo.phase_of`).

    Returns:
        {"dots": products per call, "flops": their 2·M·N·K, "by_phase": {phase: flops}, "unparsed":
        library GEMMs whose contracting dimensions were not found (not counted)}.
    """
    comps, entry = hlo.parse(text)
    weight, _, _ = hlo.runs(comps, entry, into_fusions=True)
    dots, flops, by_phase, unparsed = 0.0, 0.0, {}, 0.0
    for comp, w in weight.items():
        shapes = {name: _dims(m.group(1)) for name, _, line in comps[comp] if (m := _DIMS.search(line))}
        for name, op, line in comps[comp]:
            if op == "dot":
                contract = _dims(_CONTRACT.search(line).group(1))
            elif op == "custom-call" and hlo.kernel_kind(op, name, line) == "gemm":
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
            phase = hlo.phase_of(line, phases)
            by_phase[phase] = by_phase.get(phase, 0.0) + w * f
    return {"dots": dots, "flops": flops, "by_phase": by_phase, "unparsed": unparsed}


def step_cost(cfg, n_seeds: int = 1) -> dict:
    """Compile one SGD step from shapes and read its cost.

    Args:
        cfg: a trainer config (its representation, sizes, precisions); `--algo crl` compiles the
            goal-conditioned trainer's step (actor and temperature, critic, with SF² the flow; phases
            the same scopes `PHASES`), every other off-policy algo the shared trainer's.
        n_seeds: above 1, the step `jax.vmap`ped over that many seeds, as the trainer runs it.

    Returns:
        Per seed: `flops`, `bytes`, `transcendentals` (XLA), `dot_flops` and `dot_by_phase` (the
        products), `dot_dots`, `dot_unparsed`, `kernels`, and the `backend` compiled for.
    """
    import jax
    from sf2_jax.agents.algorithms import PHASES

    key = jax.random.PRNGKey(0)
    if cfg.algo == "crl":
        from sf2_jax.agents import crl

        program = crl.Program(cfg)
        state = jax.eval_shape(program._init_one, key)
        k_sample, noise = jax.eval_shape(program._noise, key)
        batch = jax.eval_shape(lambda b, k: program.buffer.sample(b, k, cfg.batch_size, cfg.discount),
                               state.buffer, k_sample)
        step = program._sgd_step
        args = (state.params, state.opt_state, batch, noise)
    else:
        from sf2_jax.agents.trainer import Program

        program = Program(cfg)
        algo = program.algo
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
    # the trainers' own contexts: every program at fp32 `highest`, the learner's code at its precision
    with jax.default_matmul_precision("highest"), program.learner_precision(), hlo.fresh_compilation():
        compiled = jax.jit(step).lower(*args).compile()
    analysis = xla_cost(compiled)
    text = compiled.as_text()
    dots = dot_flops(text, PHASES)
    kernels = hlo.count(text, PHASES)["by_phase"]
    return {"representation": cfg.representation, "seeds": n_seeds, "flops": analysis["flops"] / n_seeds,
            "bytes": analysis["bytes accessed"] / n_seeds,
            "transcendentals": analysis.get("transcendentals", 0.0) / n_seeds,
            "dot_dots": dots["dots"], "dot_flops": dots["flops"] / n_seeds, "dot_unparsed": dots["unparsed"],
            "dot_by_phase": {k: v / n_seeds for k, v in dots["by_phase"].items()},
            "kernels": sum(sum(kinds.values()) for kinds in kernels.values()),
            "backend": jax.default_backend()}


def xla_cost(compiled) -> dict:
    """XLA's cost analysis of a compiled program ("flops", "bytes accessed", ...) as one dict.

    Args:
        compiled: a `jax.stages.Compiled`.

    Returns:
        Its `cost_analysis()` (older JAX gives a list of one dict per computation: the first).
    """
    analysis = compiled.cost_analysis()
    return analysis[0] if isinstance(analysis, list | tuple) else analysis


def _cost(fn, args, n_seeds: int, contexts) -> dict:
    """XLA's flops and bytes per seed of `fn(*args)` (shapes) compiled under `contexts()`, vmapped over
    `n_seeds` above 1, and its kernel launches per phase (`bench.hlo.count`, all seeds)."""
    import contextlib

    import jax

    if n_seeds > 1:
        fn = jax.vmap(fn)
        args = jax.tree.map(lambda x: jax.ShapeDtypeStruct((n_seeds, *x.shape), x.dtype), args)
    with contextlib.ExitStack() as stack:
        for context in (*contexts(), hlo.fresh_compilation()):
            stack.enter_context(context)
        compiled = jax.jit(fn).lower(*args).compile()
    analysis = xla_cost(compiled)
    memory = compiled.memory_analysis()
    kernels = hlo.count(compiled.as_text(), hlo.phases())["by_phase"]
    return {"flops": analysis["flops"] / n_seeds, "bytes": analysis["bytes accessed"] / n_seeds,
            "temp_bytes": getattr(memory, "temp_size_in_bytes", 0) if memory is not None else 0,
            "kernels_by_phase": {phase: sum(kinds.values()) for phase, kinds in kernels.items()}}


def update_cost(cfg, n_seeds: int = 1) -> dict:
    """Compile the parts of one on-policy update from shapes and read their cost.

    The on-policy trainer's (`sf2_jax.agents.onpolicy.Program`) rollout step and, on one minibatch, each
    loss's clipped Adam step (`_loss_step`: the critic's, the representation's own in `aux_losses`' order,
    the actor's), the targets' EMA and the whole SGD step, each vmapped over `n_seeds` seeds; nothing runs.
    XLA counts a loop's body once, so the update is composed: U = T·rollout step + E·K·SGD step (T =
    `rollout_length`, E = `update_epochs`, K minibatches); the λ-returns, minibatch gathers and FPO's
    per-pass advantage refresh are left out, and a loop inside a part (the env's: pgx's game logic, MJX's
    solver; FPO's Euler sampler) counts once.

    Args:
        cfg: an on-policy trainer config (its task, representation, sizes, precision).
        n_seeds: above 1, each part `jax.vmap`ped over that many seeds, as the trainer runs it.

    Returns:
        Per seed: {"representation", "seeds", "parts": {part: {"flops", "bytes", "temp_bytes",
        "kernels_by_phase", "per_update"}}, "sgd_step" (the whole step, as `parts`' rows), "update_flops",
        "update_bytes" (the composed U; the parts per update sum the SGD step's from its parts), "backend"};
        `temp_bytes` are the program's scratch and `kernels_by_phase` its launches, for all seeds.
    """
    import jax
    import jax.numpy as jnp
    from sf2_jax.agents.onpolicy import Program
    from sf2_jax.agents.representations_onpolicy import OnPolicyBatch

    program, key = Program(cfg), jax.random.PRNGKey(0)
    rep, S, f32 = program.rep, jax.ShapeDtypeStruct, jnp.float32
    with program.precision():
        state = jax.eval_shape(program._init_one, key)
        _, ro = jax.eval_shape(program._act_step, state.params, state.env_state, key)
    B = cfg.minibatch_size
    rows = lambda x: S((B, *x.shape[1:]), x.dtype)   # noqa: E731  (one env's row, B of them)
    obs, one = S((B, *ro.obs.shape[1:]), f32), S((B,), f32)
    mb = OnPolicyBatch(obs=obs, action=rows(ro.action), reward=one, discount=one, truncation=one,
                       next_obs=obs, next_action=rows(ro.action), value=one, advantage=one, target=one,
                       policy_info=jax.tree.map(rows, ro.policy_info))
    steps = cfg.update_epochs * program.num_minibatches

    def critic(p, batch, k):
        loss, aux = rep.critic_loss(p, batch, cfg.clip_eps)
        return cfg.value_coef * loss, aux

    def own(name):
        return lambda p, batch, k: rep.aux_loss(name, p, batch, rep.aux_noise(k, batch))

    losses = {"critic": (critic, rep.critic_groups, None, "critic")}
    losses.update({name: (own(name), groups, program.aux_states, "aux") for name, groups in rep.aux_losses})
    losses["actor"] = (lambda p, batch, k: program.policy.loss(p, batch, cfg), ("actor",), None, "policy")
    learner = lambda: (program.precision(), program.learner_precision())   # noqa: E731
    parts = {"rollout step": {**_cost(program._act_step, (state.params, state.env_state, key), n_seeds,
                                      learner), "per_update": cfg.rollout_length}}
    for part, (loss, groups, states, phase) in losses.items():
        def step(params, opt_state, batch, k, loss=loss, groups=groups, states=states, phase=phase):
            objective = lambda p: loss(p, batch, k)   # noqa: E731
            return program._loss_step(params, opt_state, objective, groups, phase, states)[:2]

        parts[part] = {**_cost(step, (state.params, state.opt_state, mb, key), n_seeds, learner),
                       "per_update": steps}
    if rep.targets():
        def targets(params):   # the trainer's EMA step, returning only what it changes (no copies out)
            return {t: program._targets_step(params)[t] for t in rep.targets()}

        parts["targets"] = {**_cost(targets, (state.params,), n_seeds, learner), "per_update": steps}
    whole = {**_cost(program._sgd_step, (state.params, state.opt_state, mb, key), n_seeds, learner),
             "per_update": steps}
    return {"representation": cfg.representation, "seeds": n_seeds, "parts": parts, "sgd_step": whole,
            "update_flops": sum(r["flops"] * r["per_update"] for r in parts.values()),
            "update_bytes": sum(r["bytes"] * r["per_update"] for r in parts.values()),
            "backend": jax.default_backend()}


def markdown(rows: list[dict], phases: tuple[str, ...]) -> str:
    """Render the step costs, the ratios to the first representation and the product flops per phase.

    Args:
        rows: `step_cost` results, the first the reference.
        phases: the phase scopes, in the table's order.

    Returns:
        step_cost.md's tables.
    """
    g, mib = (lambda x: f"{x / 1e9:.3f}"), (lambda x: f"{x / 2**20:.1f}")
    out = ["Per seed and SGD step (dots and kernels: per call of the program, all seeds; kernels: "
           "`bench.hlo`' launches, meaningful for a GPU's program):", "",
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


def update_markdown(rows: list[dict]) -> str:
    """Render the on-policy update costs, per part and in all, and the ratios to the first representation.

    Args:
        rows: `update_cost` results, the first the reference.

    Returns:
        step_cost.md's tables.
    """
    tf, tb = (lambda x: f"{x / 1e12:.2f}"), (lambda x: f"{x / 1e12:.3f}")
    names = list(dict.fromkeys(part for r in rows for part in r["parts"]))
    out = ["Per seed and update (U = the parts × their count per update; XLA's flops and bytes accessed, "
           "TFLOP / TB):", "",
           "| part | × per update | " + " | ".join(f"{r['representation']} TFLOP | TB" for r in rows) + " |",
           "|---|---" + "|---|---" * len(rows) + "|"]
    for part in names:
        count = next(r["parts"][part]["per_update"] for r in rows if part in r["parts"])
        cells = []
        for r in rows:
            x = r["parts"].get(part)
            cells += ([tf(x["flops"] * x["per_update"]), tb(x["bytes"] * x["per_update"])] if x
                      else ["–", "–"])
        out.append(f"| {part} | {count} | " + " | ".join(cells) + " |")
    out.append("| **update** | | " + " | ".join(f"**{tf(r['update_flops'])}** | **{tb(r['update_bytes'])}**"
                                                 for r in rows) + " |")
    out += ["", "One call of each part, per seed (GFLOP, GB; scratch: the compiled program's temporaries "
            "for all seeds, GiB); the whole SGD step compiled as one program:", "",
            "| representation | part | GFLOP | GB accessed | scratch GiB |", "|---|---|---|---|---|"]
    for r in rows:
        for part, x in [*r["parts"].items(), ("SGD step (whole)", r["sgd_step"])]:
            out.append(f"| {r['representation']} | {part} | {x['flops'] / 1e9:.2f} | "
                       f"{x['bytes'] / 1e9:.3f} | {x['temp_bytes'] / 2**30:.2f} |")
    base = rows[0]
    if len(rows) > 1:
        out += ["", f"Per update against `{base['representation']}`:", "",
                "| representation | flops | bytes |", "|---|---|---|"]
        out += [f"| {r['representation']} | {r['update_flops'] / base['update_flops']:.2f}× | "
                f"{r['update_bytes'] / base['update_bytes']:.2f}× |" for r in rows[1:]]
    return "\n".join(out)


def main(argv=None) -> int:
    """Run `python -m bench.step_cost`.

    Args:
        argv: the command line after the module name (default `sys.argv[1:]`).

    Returns:
        The exit status (2, before anything compiles, for an invalid argument).
    """
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
    command = "python -m bench.step_cost " + " ".join(argv if argv is not None else sys.argv[1:])
    if cfgs[0].algo in configs.ONPOLICY_ALGOS:
        for cfg in cfgs:
            rows.append(update_cost(cfg, args.seeds))
            print(f"  {cfg.representation}: {rows[-1]['update_flops'] / 1e12:.2f} TFLOP per update",
                  flush=True)
        cfg = cfgs[0]
        text = (f"Command: `{command}`\n\nOne update of the `paper` preset, {args.task}, {args.algo}, "
                f"{args.seeds} seed(s) ({cfg.num_envs} envs × {cfg.rollout_length} steps, "
                f"{cfg.update_epochs} passes of minibatches of {cfg.minibatch_size}, learner precision "
                f"{cfg.learner_precision}); XLA's cost analysis on the {rows[0]['backend']} backend "
                "(bench/step_cost.py, `update_cost`)."
                "\n\n" + update_markdown(rows))
        return _write(args.out, text, rows, command)
    for cfg in cfgs:
        rows.append(step_cost(cfg, args.seeds))
        print(f"  {cfg.representation}: {rows[-1]['flops'] / 1e9:.3f} GFLOP per SGD step", flush=True)
    cfg = cfgs[0]
    text = (f"Command: `{command}`\n\nOne SGD step of the `paper` preset, {args.task}, {args.algo}, "
            f"{args.seeds} seed(s) (batch {cfg.batch_size}, hidden {list(cfg.hidden_sizes)}, learner "
            f"precision {cfg.learner_precision}); XLA's cost analysis on the {rows[0]['backend']} backend "
            "(bench/step_cost.py).\n\n" + markdown(rows, PHASES))
    return _write(args.out, text, rows, command)


def _write(out, text: str, rows: list[dict], command: str) -> int:
    """Print `text`; with `out`, write step_cost.md, step_cost.json and machine.json there. Returns 0."""
    from .machine import describe

    print(text)
    if out:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "step_cost.md").write_text(text + "\n")
        (out / "step_cost.json").write_text(json.dumps(rows, indent=1))
        info = describe(str(Path(__file__).resolve().parents[1]), command)
        (out / "machine.json").write_text(json.dumps(info, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
