"""A minimal reproduction of the crash of XLA's `shardy-xla` pass on the sharded trainer.

    python -m bench.lab.shardy_repro --case cholesky-shard-map        # one case per process: a crash kills it

On GPUs the trainer's sharded `init` died with SIGSEGV in the `shardy-xla` pass; under GSPMD it compiles
(docs/decisions/sharded-seeds.md). Each case is a few lines of JAX around one suspect, under Shardy unless
named: `cholesky-shard-map` (cuSOLVER's batched Cholesky from MJX's mass-matrix solve, inside a
`shard_map`), `cholesky-shard-map-gspmd` (the same under GSPMD), `cholesky-jit` (no `shard_map`),
`matmul-shard-map` (the control), `reset-shard-map` (Playground's AcrobotSwingup reset, observations out),
`reset-state-shard-map` (the whole env state out, with its zero-size fields), `zero-size-shard-map` (a
`shard_map` with a (seeds, envs, 0) array crossing its boundary). The last two crash: a zero-size array
crossing a `shard_map` boundary is the smallest program found that kills the pass.
Prints the case, the devices and `ok` with the result's checksum; exit status 139 is the crash."""

from __future__ import annotations

import argparse
import sys

CASES = ("cholesky-shard-map", "cholesky-shard-map-gspmd", "cholesky-jit", "matmul-shard-map",
         "reset-shard-map", "reset-state-shard-map", "zero-size-shard-map")


def matrices(seeds: int, envs: int, n: int):
    """The symmetric positive definite inputs (seeds, envs, n, n): A Aᵀ + n I of a seeded normal A."""
    import jax
    import jax.numpy as jnp

    a = jax.random.normal(jax.random.PRNGKey(0), (seeds, envs, n, n), jnp.float32)
    return a @ jnp.swapaxes(a, -1, -2) + n * jnp.eye(n, dtype=jnp.float32)


def run(case: str, per_device: int = 1, envs: int = 256, n: int = 2) -> float:
    import jax
    import jax.numpy as jnp
    import numpy as np
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as P

    if case not in CASES:
        raise SystemExit(f"shardy_repro: unknown case {case!r}; valid: {', '.join(CASES)}")
    jax.config.update("jax_use_shardy_partitioner", not case.endswith("-gspmd"))
    devices = jax.local_devices()
    mesh = Mesh(np.array(devices), ("seed",))
    spd = matrices(per_device * len(devices), envs, n)
    x = jax.device_put(spd, NamedSharding(mesh, P("seed")))
    op = jnp.linalg.cholesky if case.startswith("cholesky") else (lambda m: m @ m)
    if case.startswith("reset"):
        from mujoco_playground import registry, wrapper

        task = registry.load("AcrobotSwingup", config_overrides={"impl": "jax"})
        env = wrapper.wrap_for_brax_training(task, episode_length=1000, action_repeat=1)
        keys = jax.random.split(jax.random.PRNGKey(0), per_device * len(devices) * envs)
        x = jax.device_put(keys.reshape(per_device * len(devices), envs, -1), NamedSharding(mesh, P("seed")))

        def op(k):
            state = env.reset(k)
            return state if case == "reset-state-shard-map" else state.obs
    if case == "zero-size-shard-map":
        empty = jnp.zeros((per_device * len(devices), envs, 0), jnp.float32)
        x = jax.device_put((spd, empty), NamedSharding(mesh, P("seed")))

        def op(pair):
            m, e = pair
            return m * 2.0, e + 1.0
    if case == "cholesky-jit":
        fn = jax.jit(jax.vmap(op))
    else:
        fn = jax.jit(jax.shard_map(jax.vmap(op), mesh=mesh, in_specs=P("seed"), out_specs=P("seed")))
    shapes = [leaf.shape for leaf in jax.tree_util.tree_leaves(x)]
    print(f"{case}: {len(devices)} devices ({', '.join(map(str, devices))}), input {shapes}, partitioner "
          f"{'Shardy' if jax.config.jax_use_shardy_partitioner else 'GSPMD'}", flush=True)
    out = float(sum(jnp.sum(leaf) for leaf in jax.tree_util.tree_leaves(fn(x))))
    print(f"ok {case}: sum {out:.6f}", flush=True)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.lab.shardy_repro", description=__doc__.split("\n\n")[0])
    p.add_argument("--case", required=True, choices=CASES)
    p.add_argument("--per-device", type=int, default=1, help="leading entries (seeds) per device")
    p.add_argument("--envs", type=int, default=256, help="matrices per seed")
    p.add_argument("--n", type=int, default=2, help="matrix size")
    args = p.parse_args(argv)
    run(args.case, args.per_device, args.envs, args.n)
    return 0


if __name__ == "__main__":
    sys.exit(main())
