"""Time pgx's MinAtar PPO example's update (examples/minatar-ppo/train.py, unmodified).

The example is imported as a module with its command line set (`env_name`, `seed`, any `key=value`), so
its config, env, network, optimizer and `make_update_fn` are its own and its `__main__` block (the
training loop, whose printed `sec` never waits for the GPU) does not run. The parameters, optimizer state
and envs are initialised as its `train` does, with the same key splits; then each update (its `_update_step`
under `jax.jit`) is timed from dispatch to `jax.block_until_ready`, the first with the compilation; no
evaluation. Prints one JSON line: env steps per update, each update's seconds, the median after the first
and the rate. The stand-ins in this folder (wandb, omegaconf, distrax) and pgx's wheels go on PYTHONPATH
first, as run.sh puts them.

    python3 time_example.py --example .pgx-example/train.py --game breakout --iters 8 [--out rate.json]
"""

import argparse
import importlib.util
import json
import statistics
import sys
import time
from pathlib import Path

GAMES = ("breakout", "asterix", "freeway", "seaquest", "space_invaders")


def load_example(path: str, cli: list[str]):
    """Import the example's train.py as a module with its command line set.

    Args:
        path: the example's train.py.
        cli: its `key=value` arguments (read by its `OmegaConf.from_cli()` at import).

    Returns:
        The module (its `__name__` is not `__main__`, so nothing trains).
    """
    spec = importlib.util.spec_from_file_location("pgx_minatar_ppo", path)
    module = importlib.util.module_from_spec(spec)
    argv, sys.argv = sys.argv, [path, *cli]
    sys.modules[spec.name] = module
    try:
        spec.loader.exec_module(module)
    finally:
        sys.argv = argv
    return module


def initial_state(m, seed: int):
    """The runner state the example's `train` builds before its warm-up update.

    Args:
        m: the example's module.
        seed: its `seed` (train's key is `jax.random.PRNGKey(seed)`).

    Returns:
        (params, opt_state, env_state, observation, key), drawn with train's splits in its order.
    """
    import jax
    import jax.numpy as jnp

    rng = jax.random.PRNGKey(seed)
    rng, key = jax.random.split(rng)
    params = m.forward.init(key, jnp.zeros((1,) + m.env.observation_shape))
    opt_state = m.optimizer.init(params=params)
    rng, key = jax.random.split(rng)
    env_state = jax.jit(jax.vmap(m.env.init))(jax.random.split(key, m.args.num_envs))
    rng, key = jax.random.split(rng)
    return params, opt_state, env_state, env_state.observation, key


def main() -> int:
    """Run `python3 time_example.py`.

    Returns:
        The exit status (2 for a bad argument or a config the example refuses).
    """
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--example", default=".pgx-example/train.py", help="the example's unmodified train.py")
    p.add_argument("--game", default="breakout", help=f"one of {', '.join(GAMES)}")
    p.add_argument("--iters", type=int, default=8, help="timed updates, the first with compilation")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="also write the JSON line to this file")
    p.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                   help="the example's own config fields (its defaults otherwise: 4096 envs x 128 steps)")
    args = p.parse_args()
    if args.game not in GAMES:
        p.error(f"--game {args.game!r} unknown; valid: {', '.join(GAMES)}")
    if args.iters < 2:
        p.error(f"--iters {args.iters}: a rate needs >= 2 (the first holds the compilation)")
    if not Path(args.example).is_file():
        p.error(f"--example {args.example}: no such file (README.md here says how to fetch it)")
    bad = [o for o in args.overrides if "=" not in o or o.split("=", 1)[0] in ("env_name", "seed")]
    if bad:
        p.error(f"{' '.join(bad)}: overrides are KEY=VALUE of the example's config other than env_name "
                "and seed (--game, --seed)")
    import jax
    import pydantic

    try:
        cli = [f"env_name=minatar-{args.game}", f"seed={args.seed}", *args.overrides]
        m = load_example(args.example, cli)
    except pydantic.ValidationError as err:
        p.error(f"the example refuses its config: {err}")
    update = jax.jit(m.make_update_fn())
    state = initial_state(m, args.seed)
    jax.block_until_ready(state)
    seconds = []
    for _ in range(args.iters):
        start = time.perf_counter()
        state, loss = update(state)
        jax.block_until_ready((state, loss))
        seconds.append(time.perf_counter() - start)
    c = m.args
    steps = c.num_envs * c.num_steps
    median = statistics.median(seconds[1:])
    row = {"code": "pgx examples/minatar-ppo/train.py (unmodified)", "game": args.game, "seed": args.seed,
           "envs": c.num_envs, "steps_per_env": c.num_steps, "env_steps_per_update": steps,
           "sgd_steps_per_update": c.update_epochs * m.num_minibatches,
           "overrides": args.overrides, "update_s": [round(s, 4) for s in seconds],
           "median_s_after_first": round(median, 4), "env_steps_per_s": round(steps / median, 1),
           "compilations": update._cache_size(),
           "matmul_precision": str(jax.config.jax_default_matmul_precision),
           "device": str(jax.devices()[0].device_kind)}
    print(json.dumps(row))
    if args.out:
        Path(args.out).write_text(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
