"""Time one SGD step of TD3/SAC with each representation (JAX), relative to the vanilla algorithm.

    python packages/sf2-baselines/scripts/update_times.py --algo td3 --config quick --obs-size 5 \\
        --action-size 1 --repr none,sf2,sim,simlap,spr

Builds each agent from the `quick` (or `paper`) preset's network sizes and batch size, jits a
`lax.scan` over `--steps` SGD steps on fixed random batches, and times it `--repeats` times,
round-robin over the methods (so that load from other processes hits every method alike); prints the
median milliseconds per SGD step and the ratio to the first method. Needs `sf2-core-jax` with its
agents; the task is not loaded, its sizes are the arguments (CartpoleBalance: 5 and 1).
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np
import sf2_baselines.jax  # noqa: F401  (registers sim, simlap, simlap_authors, spr)
from sf2_jax.agents import configs, representations
from sf2_jax.agents.algorithms import make_algorithm
from sf2_jax.losses import Batch


def build(rep: str, args):
    cfg = configs.make_config(args.config, args.task, algo=args.algo, representation=rep)
    sf2 = cfg.sf2_config(args.obs_size, args.action_size)
    agent = make_algorithm(args.algo, sf2, representations.get(rep))
    params, opt = agent.init(jax.random.PRNGKey(0))
    B, D, A, n = cfg.batch_size, args.obs_size, args.action_size, args.steps
    rng = np.random.default_rng(0)
    batches = Batch(
        obs=jnp.asarray(rng.normal(size=(n, B, D)), jnp.float32),
        action=jnp.asarray(rng.uniform(-1, 1, (n, B, A)), jnp.float32),
        reward=jnp.asarray(rng.uniform(size=(n, B)), jnp.float32),
        discount=jnp.ones((n, B), jnp.float32),
        next_obs=jnp.asarray(rng.normal(size=(n, B, D)), jnp.float32),
        truncation=jnp.zeros((n, B), jnp.float32),
    )

    @jax.jit
    def run(params, opt, key):
        def body(carry, xs):
            params, opt, step = carry
            batch, k = xs
            params, opt, _ = agent.sgd_step(params, opt, batch, k, step)
            return (params, opt, step + 1), None

        (params, opt, _), _ = jax.lax.scan(
            body, (params, opt, jnp.zeros((), jnp.int32)), (batches, jax.random.split(key, n))
        )
        return params, opt

    return run, params, opt, cfg.matmul_precision


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--algo", default="td3")
    p.add_argument("--config", default="quick")
    p.add_argument("--task", default="CartpoleBalance", help="only for the preset's per-task settings")
    p.add_argument("--obs-size", type=int, default=5)
    p.add_argument("--action-size", type=int, default=1)
    p.add_argument("--repr", default="none,sf2,sim,simlap,spr")
    p.add_argument("--steps", type=int, default=50, help="SGD steps per timed call")
    p.add_argument("--repeats", type=int, default=7)
    args = p.parse_args(argv)
    reps = [r.strip() for r in args.repr.split(",") if r.strip()]
    progs = {}
    for rep in reps:
        run, params, opt, precision = build(rep, args)
        with jax.default_matmul_precision(precision):
            jax.block_until_ready(run(params, opt, jax.random.PRNGKey(1)))  # compile + warm up
        progs[rep] = (run, params, opt, precision)
    times = {rep: [] for rep in reps}
    for r in range(args.repeats):
        for rep in reps:
            run, params, opt, precision = progs[rep]
            with jax.default_matmul_precision(precision):
                t0 = time.perf_counter()
                jax.block_until_ready(run(params, opt, jax.random.PRNGKey(2 + r)))
                times[rep].append((time.perf_counter() - t0) / args.steps)
    base = statistics.median(times[reps[0]])
    print(
        f"{args.algo} {args.config} (D={args.obs_size}, A={args.action_size}), {jax.default_backend()}, "
        f"median of {args.repeats} x {args.steps} SGD steps"
    )
    print(f"{'method':16} {'ms/step':>9} {'x ' + reps[0]:>9}")
    for rep in reps:
        m = statistics.median(times[rep])
        print(f"{rep:16} {1e3 * m:9.2f} {m / base:9.2f}")


if __name__ == "__main__":
    main()
