"""How far a last-bit difference in the policy moves an evaluation's returns.

    python -m bench.lab.eval_sensitivity --task FishSwim --algo sac --repr sim --seeds 0-4 --out OUT

The trainer's own evaluation program of the initial policy, three times: as initialized, again (every
difference must be 0), and with every acting parameter one float32 ulp up (`nextafter`), which stands in
for two GPU processes whose autotuned GEMMs round the actor's products differently
(docs/decisions/gpu-determinism.md). The episodes are closed loop, where a last-bit difference can grow;
for contrast the same episodes open loop (uniform random actions, then the same actions one ulp up).
`--set FIELD=VALUE` overrides a preset field (defaults here: `num_eval_envs=16`, `max_replay_size=16384`).
Writes sensitivity.csv (one row per seed and episode), sensitivity.md and machine.json to `--out`."""

from __future__ import annotations

import argparse
import csv
import functools
import json
import sys
from pathlib import Path

COLUMNS = ["task", "algo", "representation", "seed", "episode", "return", "return_repeated",
           "return_one_ulp", "open_loop_return", "open_loop_return_one_ulp"]
DEFAULTS = {"num_eval_envs": "16", "max_replay_size": "16384"}


def measure(cfg, seeds: tuple[int, ...]) -> list[dict]:
    """Rows of `COLUMNS`: the epoch-0 evaluation's return of every seed and episode, three ways (`cfg`: a
    validated config)."""
    import jax
    import jax.numpy as jnp
    import numpy as np
    from sf2_jax.agents.trainer import Program, episode_returns

    program = Program(cfg)
    state = program.init(seeds)
    one_ulp = jax.tree_util.tree_map(lambda x: jnp.nextafter(x, jnp.inf) if jnp.issubdtype(
        x.dtype, jnp.floating) else x, state.params)
    runs = [np.asarray(program.evaluate(p, state.eval_start, seeds, 0))
            for p in (state.params, state.params, one_ulp)]
    n_steps = program.sched.eval_actor_steps
    n_envs, n_actions = state.eval_start.obs.shape[1], program.spec.action_size

    def open_loop(start, one_ulp_up: bool):   # one seed's episodes under uniform random actions
        def act(obs, k):
            a = jax.random.uniform(k, (n_envs, n_actions), minval=-1.0, maxval=1.0)
            return jnp.nextafter(a, jnp.inf) if one_ulp_up else a
        return episode_returns(program.spec.eval_env, start, act, jax.random.PRNGKey(0), n_steps)

    with jax.default_matmul_precision("highest"):
        runs += [np.asarray(jax.jit(jax.vmap(functools.partial(open_loop, one_ulp_up=up)))(state.eval_start))
                 for up in (False, True)]
    return [{"task": cfg.task, "algo": cfg.algo, "representation": cfg.representation, "seed": seed,
             "episode": e,
             "return": float(runs[0][i, e]), "return_repeated": float(runs[1][i, e]),
             "return_one_ulp": float(runs[2][i, e]), "open_loop_return": float(runs[3][i, e]),
             "open_loop_return_one_ulp": float(runs[4][i, e])}
            for i, seed in enumerate(seeds) for e in range(runs[0].shape[1])]


def markdown(rows: list[dict], command: str, info: dict) -> str:
    import numpy as np

    lines = ["# Evaluation sensitivity to a last-bit difference in the policy", "", "Command:", "", "```",
             command, "```", "", f"- machine: {info.get('cpu')}; GPU: {info.get('gpu')}; "
             f"versions: {json.dumps(info.get('versions'))}", "",
             "Per seed: the mean return over its episodes (epoch-0 evaluation), repeated, and with every "
             "acting parameter one float32 ulp up; |Δ| per episode against the first. Open loop: the "
             "same start states under random actions, and under the same actions one ulp up.", "",
             "| task | method | seed | episodes | mean return | repeated: max abs Δ | one ulp: mean return "
             "| one ulp: mean abs Δ | one ulp: max abs Δ | open loop: mean return | open loop, one ulp: "
             "max abs Δ |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for seed in sorted({r["seed"] for r in rows}):
        rs = [r for r in rows if r["seed"] == seed]
        base, rep, ulp, ol, ol_ulp = (np.array([r[k] for r in rs]) for k in (
            "return", "return_repeated", "return_one_ulp", "open_loop_return", "open_loop_return_one_ulp"))
        r0 = rs[0]
        lines.append(f"| {r0['task']} | {r0['algo']}+{r0['representation']} | {seed} | {len(rs)} | "
                     f"{base.mean():.2f} | {np.abs(rep - base).max():.3g} | {ulp.mean():.2f} | "
                     f"{np.abs(ulp - base).mean():.3g} | {np.abs(ulp - base).max():.3g} | {ol.mean():.2f} | "
                     f"{np.abs(ol_ulp - ol).max():.3g} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    from sf2_common.agents import configs
    from sf2_common.errors import ConfigError

    p = argparse.ArgumentParser(prog="python -m bench.lab.eval_sensitivity",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="FishSwim")
    p.add_argument("--algo", default="sac")
    p.add_argument("--repr", default="sim", help="representation (none, sf2, sim, simlap, spr)")
    p.add_argument("--seeds", default="0-4", help="seeds, e.g. 0-4 or 0,3")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help=f"override a config field of the paper preset (defaults: "
                        f"{', '.join(f'{k}={v}' for k, v in DEFAULTS.items())})")
    p.add_argument("--out", required=True, help="folder for sensitivity.csv / .md / machine.json")
    args = p.parse_args(argv)
    try:
        seeds = configs.parse_seeds(args.seeds)
        overrides = configs.parse_overrides([f"{k}={v}" for k, v in DEFAULTS.items()] + args.set)
        cfg = configs.make_config("paper", args.task, args.algo, args.repr, overrides)
        from sf2_jax.agents import representations
        configs.validate(cfg, seeds, representations.REGISTRY)
    except ConfigError as err:
        p.error(str(err))
    rows = measure(cfg, seeds)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "sensitivity.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    from bench.machine import describe

    command = "python -m bench.lab.eval_sensitivity " + " ".join(sys.argv[1:] if argv is None else argv)
    info = describe(str(Path(__file__).resolve().parents[1]), command)
    (out / "machine.json").write_text(json.dumps(info, indent=2) + "\n")
    text = markdown(rows, command, info)
    (out / "sensitivity.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
