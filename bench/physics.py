"""Physics throughput: env steps per second of MuJoCo Playground's MJX step alone, per task.

    python -m bench.physics --tasks all --envs 128,1024,4096 --out OUT

Each case is one jitted program: `lax.scan` over `--steps` steps of `jax.vmap(env.step)` with random
actions drawn inside the program (data, not constants XLA could fold), the pure-JAX MJX backend
(`impl='jax'`) and fp32 `highest` matmuls (physics never runs at a lower precision). Reported: the median
of `--repeats` timed calls. Some tasks' `env.step` returns a leaf whose weak type differs from the reset
state's, so a program fed its own output compiles twice (docs/physics.md); here the scan carry is kept
strongly typed, `type_changes` lists such leaves and `compilations` (the jit cache size after the timed
calls) shows that the timed calls compiled nothing.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import sys
import time
from pathlib import Path

COLUMNS = ["task", "num_envs", "steps_per_call", "compilations", "type_changes", "first_call_s",
           "median_call_s", "env_steps_per_s", "call_s", "state_checksum"]


def type_changes(env, state) -> list[str]:
    """Find the leaves whose dtype or weak type `env.step` changes.

    Args:
        env: a Playground environment.
        state: a vmapped reset state.

    Returns:
        One "path: type -> type" line per changed leaf.
    """
    import jax
    import jax.numpy as jnp

    n = jax.tree_util.tree_leaves(state)[0].shape[0]
    action = jax.ShapeDtypeStruct((n, env.action_size), jnp.float32)
    after = jax.eval_shape(jax.vmap(env.step), state, action)
    out = []
    for (path, a), b in zip(jax.tree_util.tree_flatten_with_path(state)[0], jax.tree_util.tree_leaves(after)):
        ta, tb = jax.typeof(a), jax.typeof(b)
        if (ta.dtype, ta.weak_type) != (tb.dtype, tb.weak_type):
            weak = {True: "weak ", False: ""}
            out.append(f"{jax.tree_util.keystr(path)}: {weak[ta.weak_type]}{ta.dtype} -> "
                       f"{weak[tb.weak_type]}{tb.dtype}")
    return out


def checksum_of(state) -> str:
    """Fingerprint a physics state, so two runs of one case can be checked to compute one trajectory.

    Args:
        state: the final state (every case runs the same actions from the same start).

    Returns:
        The float64 sums of qpos and qvel, exactly (`float.hex`).
    """
    import numpy as np

    return ";".join(float(np.asarray(x, np.float64).sum()).hex() for x in (state.data.qpos, state.data.qvel))


def measure(task: str, num_envs: int, steps: int, repeats: int, log=print) -> dict:
    """Time the physics of one task.

    Args:
        task: a Playground task.
        num_envs: vmapped envs.
        steps: env steps per timed call (one `lax.scan`).
        repeats: timed calls, after the warm-up.
        log: a callable taking one line.

    Returns:
        One row of `COLUMNS` (env steps/s, compilations, type changes, checksum).
    """
    import jax
    from mujoco_playground import registry
    from sf2_jax.agents.envs import strong_types as strong  # the carry's types cannot change

    env = registry.load(task, config_overrides={"impl": "jax"})

    @jax.jit
    def rollout(state, key):
        def body(s, k):
            a = jax.random.uniform(k, (num_envs, env.action_size), minval=-1.0, maxval=1.0)
            return strong(jax.vmap(env.step)(s, a)), None

        return jax.lax.scan(body, state, jax.random.split(key, steps))[0]

    with jax.default_matmul_precision("highest"):
        state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), num_envs))
        changes = type_changes(env, state)
        state = strong(state)
        t = time.perf_counter()
        state = jax.block_until_ready(rollout(state, jax.random.PRNGKey(1)))
        first = time.perf_counter() - t
        times = []
        for key in range(2, 3 + repeats):  # one untimed call, then `repeats` timed ones
            t = time.perf_counter()
            state = jax.block_until_ready(rollout(state, jax.random.PRNGKey(key)))
            times.append(time.perf_counter() - t)
        times = times[1:]
        compilations = rollout._cache_size()
        checksum = checksum_of(state)
    med = statistics.median(times)
    row = {"task": task, "num_envs": num_envs, "steps_per_call": steps, "compilations": compilations,
           "type_changes": "; ".join(changes) or "none",
           "first_call_s": round(first, 2), "median_call_s": round(med, 5),
           "env_steps_per_s": round(num_envs * steps / med, 1), "call_s": ";".join(f"{x:.5f}" for x in times),
           "state_checksum": checksum}
    log(f"  {task} x{num_envs}: {row['env_steps_per_s']:,.0f} env steps/s ({compilations} compilation"
        f"{'s' * (compilations > 1)}, first call {first:.1f} s; type changes: {row['type_changes']})")
    return row


def markdown(rows: list[dict], info: dict) -> str:
    """Render the rows as a table of tasks by env counts.

    Args:
        rows: `measure` rows.
        info: the machine description.

    Returns:
        physics.md's text.
    """
    envs = sorted({r["num_envs"] for r in rows})
    tasks = list(dict.fromkeys(r["task"] for r in rows))
    by = {(r["task"], r["num_envs"]): r for r in rows}
    lines = ["# Physics alone: MJX env steps per second", "",
             "Command:", "", "```", info["command"], "```", "",
             f"- machine: {info.get('cpu')}; GPU: {info.get('gpu')}",
             f"- XLA_FLAGS: `{info.get('xla_flags') or '(unset)'}`",
             f"- versions: {json.dumps(info.get('versions'))}; jax backend {info.get('jax_backend')}",
             "- one program per case: `lax.scan` of vmapped `env.step` with random actions drawn inside it, "
             "fp32 `highest`, impl='jax', the carry strongly typed; median of the timed calls",
             "", "| task | " + " | ".join(f"{n} envs" for n in envs) + " | compilations | leaves `env.step` "
             "retypes |", "|---|" + "---|" * (len(envs) + 2)]
    for t in tasks:
        cells = [f"{by[(t, n)]['env_steps_per_s']:,.0f}" if (t, n) in by else "" for n in envs]
        comp = max(by[(t, n)]["compilations"] for n in envs if (t, n) in by)
        change = next(by[(t, n)]["type_changes"] for n in envs if (t, n) in by)
        lines.append(f"| {t} | " + " | ".join(cells) + f" | {comp} | {change} |")
    lines += ["", "The carry is kept strongly typed, so every case compiles once (`compilations` = 1) even "
              "where `env.step` retypes a leaf; without that, those tasks compile twice (docs/physics.md)."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    """Run `python -m bench.physics`.

    Args:
        argv: the command line after the module name (default `sys.argv[1:]`).

    Returns:
        The exit status (2, before anything is compiled or written, for an invalid argument).
    """
    from sf2_common.agents.tasks import PAPER_TASKS, validate_task
    from sf2_common.errors import ConfigError

    p = argparse.ArgumentParser(prog="python -m bench.physics", description=__doc__.split("\n\n")[0])
    p.add_argument("--tasks", default="all", help=f"comma list or 'all' ({', '.join(PAPER_TASKS)})")
    p.add_argument("--envs", default="128,1024,4096", help="numbers of vmapped envs")
    p.add_argument("--steps", type=int, default=50, help="env steps per timed call")
    p.add_argument("--repeats", type=int, default=5, help="timed calls per case")
    p.add_argument("--out", required=True, help="folder for physics.csv / physics.md / machine.json")
    args = p.parse_args(argv)
    names = [x.strip() for x in args.tasks.split(",") if x.strip()]
    tasks = PAPER_TASKS if args.tasks == "all" else tuple(names)
    try:   # checked before anything is compiled or written (exit status 2 naming the problem)
        for t in tasks:
            validate_task(t)
    except ConfigError as err:
        p.error(f"--tasks: {err}")
    try:
        envs = [int(x) for x in args.envs.split(",") if x.strip()]
    except ValueError:
        envs = []
    if not envs or min(envs) < 1 or args.steps < 1 or args.repeats < 1:
        p.error(f"--envs {args.envs!r}, --steps {args.steps}, --repeats {args.repeats}: each must be >= 1 "
                f"(--envs a comma list)")
    from .machine import describe

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = "python -m bench.physics " + " ".join(argv if argv is not None else sys.argv[1:])
    info = describe(str(Path(__file__).resolve().parents[1]), command)
    info["xla_flags"] = os.environ.get("XLA_FLAGS", "")
    rows = []
    for task in tasks:
        for n in envs:
            rows.append(measure(task, n, args.steps, args.repeats))
            with open(out / "physics.csv", "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=COLUMNS)
                w.writeheader()
                w.writerows(rows)
    (out / "machine.json").write_text(json.dumps(info, indent=2))
    text = markdown(rows, info)
    (out / "physics.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
