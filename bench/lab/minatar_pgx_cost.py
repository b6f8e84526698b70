"""pgx's MinAtar PPO example's update against ours, by XLA's counts: where the 1.47x of the speed table goes.

Both programs are compiled from their own code for the same game and sizes, nothing runs: pgx's
`make_update_fn()` (examples/minatar-ppo/train.py, imported unmodified by
scripts/gpu-host/pgx-example/time_example.py's `load_example`), and our on-policy trainer's epoch program
(`sf2_jax.agents.onpolicy.Program`, one seed, the `paper` preset with the sanity gate's overrides: one update
per epoch). XLA counts a loop's body once, in both: each sum is one rollout step, one GAE step, one SGD step
and what lies outside the loops, so the two are comparable with each other, not with a whole update's work.
Beside XLA's flops and bytes, the optimized module's instructions by opcode (convolutions, dots, fusions,
loops, sorts, gathers, scatters, random bits) say what each program asks the device to do.

    PYTHONPATH=/tmp/pgxlocal:scripts/gpu-host/pgx-example python -m bench.lab.minatar_pgx_cost \
        --example .pgx-example/train.py --game breakout [--set shared_torso=false] [--envs 4096]

(/tmp/pgxlocal: dm-haiku, jmp, tabulate, pydantic for this machine's Python; the stand-ins for wandb,
omegaconf and distrax are in scripts/gpu-host/pgx-example.)
"""

import argparse
import collections
import importlib.util
import json
import sys
from pathlib import Path

GATE = ["critic=v", "discount=0.99", "deterministic_eval=false", "num_eval_envs=100", "shared_torso=true"]
OPCODES = ("convolution", "dot", "fusion", "while", "conditional", "sort", "gather", "scatter",
           "rng-bit-generator", "custom-call", "reduce", "copy", "transpose")


def _time_example():
    """scripts/gpu-host/pgx-example/time_example.py as a module (its `load_example`, `initial_state`)."""
    path = Path(__file__).resolve().parents[2] / "scripts/gpu-host/pgx-example/time_example.py"
    spec = importlib.util.spec_from_file_location("time_example", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def opcode_counts(hlo_text: str) -> dict:
    """Instructions of an optimized HLO module by opcode, over every computation (`bench.hlo.parse`).

    Args:
        hlo_text: `compiled.as_text()`.

    Returns:
        {opcode: count} for `OPCODES`, and "instructions": every instruction.
    """
    from bench import hlo

    comps, _ = hlo.parse(hlo_text)
    found = collections.Counter(op for instructions in comps.values() for _, op, _ in instructions)
    return {"instructions": sum(found.values()), **{name: found.get(name, 0) for name in OPCODES}}


def cost(compiled) -> dict:
    """XLA's flops, bytes accessed and scratch of a compiled program, and its opcode counts."""
    from bench.step_cost import xla_cost

    analysis = xla_cost(compiled)
    memory = compiled.memory_analysis()
    return {"flops": analysis.get("flops", 0.0), "bytes": analysis.get("bytes accessed", 0.0),
            "temp_bytes": getattr(memory, "temp_size_in_bytes", 0) if memory is not None else 0,
            **opcode_counts(compiled.as_text())}


def theirs(example: str, game: str, envs: int) -> dict:
    """The example's compiled update (`jax.jit(make_update_fn())`), lowered on its initial state's shapes."""
    import jax

    te = _time_example()
    m = te.load_example(example, [f"env_name=minatar-{game}", "seed=0", f"num_envs={envs}"])
    state = jax.eval_shape(lambda: te.initial_state(m, 0))
    return cost(jax.jit(m.make_update_fn()).lower(state).compile())


def ours(game: str, envs: int, sets: list[str]) -> dict:
    """Our epoch program at one seed (one update per epoch at the `paper` preset), on its state's shapes."""
    import jax
    from sf2_common.agents import configs
    from sf2_jax.agents.onpolicy import Program
    from sf2_jax.agents.trainer import seed_keys

    overrides = configs.parse_overrides([*GATE, f"num_envs={envs}", *sets])
    cfg = configs.make_config("paper", f"minatar-{game}", "ppo", "none", overrides)
    program = Program(cfg)
    with program.precision():
        state = jax.eval_shape(jax.vmap(program._init_one), seed_keys((0,)))
        epoch = program._program("epoch", 1)
        row = cost(epoch.lower(state).compile())
    return {**row, "updates_per_epoch": configs.schedule(cfg).actor_steps_per_epoch}


def main(argv=None) -> int:
    """Run `python -m bench.lab.minatar_pgx_cost`.

    Args:
        argv: the command line after the module name (default `sys.argv[1:]`).

    Returns:
        The exit status (2 for a bad argument).
    """
    p = argparse.ArgumentParser(prog="python -m bench.lab.minatar_pgx_cost",
                                description=__doc__.split("\n")[0])
    p.add_argument("--example", default=".pgx-example/train.py")
    p.add_argument("--game", default="breakout")
    p.add_argument("--envs", type=int, default=4096)
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="our config, after the gate's")
    args = p.parse_args(argv)
    if not Path(args.example).is_file():
        p.error(f"--example {args.example}: no such file (scripts/gpu-host/pgx-example/README.md)")
    rows = {"pgx example": theirs(args.example, args.game, args.envs),
            "ours": ours(args.game, args.envs, args.set)}
    keys = ["flops", "bytes", "temp_bytes", "instructions", *OPCODES]
    print("| program | " + " | ".join(keys) + " |")
    print("|---|" + "---|" * len(keys))
    for name, row in rows.items():
        print(f"| {name} | " + " | ".join(f"{row[k]:.4g}" if isinstance(row[k], float) else str(row[k])
                                        for k in keys) + " |")
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
