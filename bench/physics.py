"""Physics throughput: env steps per second of MuJoCo Playground's MJX step alone, per task.

    python -m bench.physics --tasks all --envs 128,1024,4096 --out bench/results/h200/10-physics

Each case is one jitted program: `lax.scan` over `--steps` steps of `jax.vmap(env.step)` with uniformly
random actions drawn inside the program (the actions are data, not constants XLA could fold), the pure-JAX
MJX backend (`impl='jax'`) and fp32 `highest` matmuls (physics never runs at a lower precision:
docs/core-contract.md "Precision"). Reported: the median of `--repeats` timed calls.

Warm-up matters. Several Playground tasks return a weakly typed reward (`jnp.where(c, 1.0, 0.0)` in
`reward.tolerance` with margin 0), so the state a step returns differs from the state `reset` returned in
one leaf's weak type. A program called with the reset state and then with its own output is therefore
compiled twice, and a benchmark that warms up with one call times the second compilation: that is what
made five tasks look 30-1000x slower than they are (docs/physics.md has the reproduction). Here every
case is called until its jit cache stops growing, and the number of compilations is reported.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import time
from pathlib import Path

COLUMNS = ["task", "num_envs", "steps_per_call", "compilations", "first_call_s", "median_call_s",
           "env_steps_per_s", "call_s"]


def measure(task: str, num_envs: int, steps: int, repeats: int, log=print) -> dict:
    """Time `repeats` calls of the scan of `steps` vmapped env steps, after warm-up; one row of COLUMNS."""
    import jax
    from mujoco_playground import registry

    env = registry.load(task, config_overrides={"impl": "jax"})

    @jax.jit
    def rollout(state, key):
        def body(s, k):
            a = jax.random.uniform(k, (num_envs, env.action_size), minval=-1.0, maxval=1.0)
            return jax.vmap(env.step)(s, a), None

        return jax.lax.scan(body, state, jax.random.split(key, steps))[0]

    with jax.default_matmul_precision("highest"):
        state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), num_envs))
        t = time.perf_counter()
        state = jax.block_until_ready(rollout(state, jax.random.PRNGKey(1)))
        first = time.perf_counter() - t
        calls, key = 1, 2
        while True:  # until a call compiles nothing new (the output's types equal its input's)
            before = rollout._cache_size()
            state = jax.block_until_ready(rollout(state, jax.random.PRNGKey(key)))
            calls, key = calls + 1, key + 1
            if rollout._cache_size() == before or calls > 5:
                break
        compilations = rollout._cache_size()
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            state = jax.block_until_ready(rollout(state, jax.random.PRNGKey(key)))
            times.append(time.perf_counter() - t)
            key += 1
    med = statistics.median(times)
    row = {"task": task, "num_envs": num_envs, "steps_per_call": steps, "compilations": compilations,
           "first_call_s": round(first, 2), "median_call_s": round(med, 5),
           "env_steps_per_s": round(num_envs * steps / med, 1), "call_s": ";".join(f"{x:.5f}" for x in times)}
    log(f"  {task} x{num_envs}: {row['env_steps_per_s']:,.0f} env steps/s ({compilations} compilation"
        f"{'s' * (compilations > 1)}, first call {first:.1f} s)")
    return row


def markdown(rows: list[dict], info: dict) -> str:
    envs = sorted({r["num_envs"] for r in rows})
    tasks = list(dict.fromkeys(r["task"] for r in rows))
    by = {(r["task"], r["num_envs"]): r for r in rows}
    lines = ["# Physics alone: MJX env steps per second", "",
             "Command:", "", "```", info["command"], "```", "",
             f"- machine: {info.get('cpu')}; GPU: {info.get('gpu')}",
             f"- versions: {json.dumps(info.get('versions'))}; jax backend {info.get('jax_backend')}",
             "- one program per case: `lax.scan` of vmapped `env.step` with random actions drawn inside it, "
             "fp32 `highest`, impl='jax'; median of the timed calls after the jit cache stopped growing",
             "", "| task | " + " | ".join(f"{n} envs" for n in envs) + " | compilations |",
             "|---|" + "---|" * (len(envs) + 1)]
    for t in tasks:
        cells = [f"{by[(t, n)]['env_steps_per_s']:,.0f}" if (t, n) in by else "" for n in envs]
        comp = max(by[(t, n)]["compilations"] for n in envs if (t, n) in by)
        lines.append(f"| {t} | " + " | ".join(cells) + f" | {comp} |")
    lines += ["", "`compilations` = 2: the task's step returns a state whose types differ from the reset "
              "state's (a weakly typed reward); the first two calls compile, later ones do not."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    from sf2_common.agents.tasks import PAPER_TASKS

    p = argparse.ArgumentParser(prog="python -m bench.physics", description=__doc__.split("\n\n")[0])
    p.add_argument("--tasks", default="all", help=f"comma list or 'all' ({', '.join(PAPER_TASKS)})")
    p.add_argument("--envs", default="128,1024,4096", help="numbers of vmapped envs")
    p.add_argument("--steps", type=int, default=50, help="env steps per timed call")
    p.add_argument("--repeats", type=int, default=5, help="timed calls per case")
    p.add_argument("--out", required=True, help="folder for physics.csv / physics.md / machine.json")
    args = p.parse_args(argv)
    tasks = PAPER_TASKS if args.tasks == "all" else tuple(t for t in args.tasks.split(",") if t)
    from .machine import describe

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = "python -m bench.physics " + " ".join(argv if argv is not None else sys.argv[1:])
    info = describe(str(Path(__file__).resolve().parents[1]), command)
    rows = []
    for task in tasks:
        for n in (int(x) for x in args.envs.split(",")):
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
