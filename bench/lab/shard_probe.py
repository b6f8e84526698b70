"""Which of the JAX trainer's programs fails when a run's seeds are sharded over the local devices?

    SF2_SHARD_SEEDS=1 python -m bench.lab.shard_probe --programs init
    SF2_SHARD_SEEDS=1 python -m bench.lab.shard_probe --programs epoch,evaluate

Builds the `--config` preset's `Program` for one task, algorithm and representation and `--seeds` seeds,
and runs the listed programs with the seeds spread over the "seed" mesh (`Program.mesh`), printing
`ok <program>` after each; a crash of XLA kills the process, so give each suspect its own process
(scripts/gpu-host/gpu_shard_probe.sh). Sharded programs compile with GSPMD; `--shardy` switches back to
Shardy, whose pass crashed on two GPUs (docs/decisions/sharded-seeds.md)."""

from __future__ import annotations

import argparse
import os
import sys
import time

PROGRAMS = ("init", "epoch", "evaluate")


def probe(task: str, algo: str, rep: str, preset: str, n_seeds: int, programs: tuple[str, ...],
          overrides: dict, shardy: bool = False, log=print) -> None:
    import jax
    from sf2_common.agents import configs
    from sf2_jax.agents import representations
    from sf2_jax.agents.trainer import SHARD_SEEDS, get_program

    seeds = tuple(range(n_seeds))
    cfg = configs.make_config(preset, task, algo, rep, overrides)
    configs.validate(cfg, seeds, representations.REGISTRY)
    program = get_program(cfg)
    mesh = program.mesh(n_seeds)
    if mesh is None:
        raise SystemExit(f"shard_probe: no seed mesh: needs {SHARD_SEEDS}=1 and several local devices that "
                         f"divide --seeds {n_seeds} (devices: {jax.local_devices()})")
    if shardy:   # jit reads the partitioner when it compiles: build the programs (GSPMD), then switch back
        for name in programs:
            program._program(name, n_seeds)
        jax.config.update("jax_use_shardy_partitioner", True)
    log(f"mesh: {n_seeds} seeds over {mesh.devices.size} devices ({', '.join(map(str, mesh.devices.flat))}), "
        f"partitioner {'Shardy (--shardy)' if shardy else 'GSPMD (Program._program switches to it)'}")

    def timed(name, fn):
        t = time.perf_counter()
        out = fn()
        jax.block_until_ready(out)
        log(f"ok {name} ({time.perf_counter() - t:.1f} s)")
        return out

    if "init" in programs:
        state = timed("init (sharded)", lambda: program.init(seeds))
    else:
        os.environ[SHARD_SEEDS] = "0"   # `Program.mesh` reads it at each call: this init stays on one device
        state = timed("init (one device)", lambda: program.init(seeds))
        os.environ[SHARD_SEEDS] = "1"
        state = timed("place (spread over the mesh)", lambda: program.place(state))
    if "epoch" in programs:
        state = timed("epoch (sharded)", lambda: program.epoch(state, 1)[0])
    if "evaluate" in programs:
        timed("evaluate (sharded)", lambda: program.evaluate(state.params, state.eval_start, seeds, 1))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.lab.shard_probe", description=__doc__.split("\n\n")[0])
    p.add_argument("--programs", default="init", help=f"comma list of {', '.join(PROGRAMS)}")
    p.add_argument("--task", default="AcrobotSwingup")
    p.add_argument("--algo", default="td3")
    p.add_argument("--rep", default="none")
    p.add_argument("--config", default="paper", help="preset (sf2_common.agents.configs)")
    p.add_argument("--seeds", type=int, default=4, help="number of seeds (a multiple of the devices)")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    p.add_argument("--shardy", action="store_true",
                   help="compile with JAX's default Shardy partitioner, not Program._program's GSPMD")
    args = p.parse_args(argv)
    programs = tuple(x for x in args.programs.split(",") if x)
    bad = [x for x in programs if x not in PROGRAMS]
    if bad or not programs:
        p.error(f"--programs: {', '.join(map(repr, bad)) or 'none given'}; valid: {', '.join(PROGRAMS)}")
    if args.seeds < 2:
        p.error(f"--seeds {args.seeds}: needs at least 2 to spread over devices")
    from sf2_common.agents import configs

    try:
        overrides = configs.parse_overrides(args.set) if args.set else {}
        probe(args.task, args.algo, args.rep, args.config, args.seeds, programs, overrides, args.shardy)
    except configs.ConfigError as err:
        p.error(str(err))
    return 0


if __name__ == "__main__":
    sys.exit(main())
