"""A minimal reproduction of the crash of XLA's `shardy-xla` pass on the sharded trainer.

    python -m bench.lab.shardy_repro --case cholesky-shard-map        # one case per process: a crash kills it

On GPUs the trainer's sharded `init` (SF2_SHARD_SEEDS=1, `Program.mesh`) died with SIGSEGV in the
`shardy-xla` pass (docs/decisions/sharded-seeds.md); under GSPMD it compiles. The module that pass was
handed (the `shardy/…/00.input_module.mlir` of XLA's dump, `scripts/gpu-host/gpu_shard_probe.sh programs`)
holds one custom call with a Shardy sharding rule: cuSOLVER's batched Cholesky factorization
(`cusolver_potrf_ffi`, from MJX's mass-matrix solve in the env reset), inside the `shard_map` body. On CPUs
the same factorization is a LAPACK custom call, and the CPU compiles the trainer under Shardy. Each case
here is a few lines of JAX around that one operation, so the one that crashes is the report:

- `cholesky-shard-map`: `shard_map(vmap(jnp.linalg.cholesky))` over a one-axis mesh of the local devices
  (the trainer's layout: seeds × envs × 2 × 2 mass matrices), under Shardy (JAX's default);
- `cholesky-shard-map-gspmd`: the same under GSPMD (`jax_use_shardy_partitioner=False`, what
  `Program._program` switches to);
- `cholesky-jit`: `jit(vmap(cholesky))` of an array sharded over the mesh, no `shard_map`, under Shardy;
- `matmul-shard-map`: `shard_map` of a batched matmul, no custom call, under Shardy (the control);
- `reset-shard-map`: `shard_map(vmap(reset))` of MuJoCo Playground's AcrobotSwingup (MJX, the trainer's
  env: Playground's task, Brax's wrappers), `--envs` envs per seed, its observations out, under Shardy;
- `reset-state-shard-map`: the same with the whole env state out of the `shard_map`, as the trainer's
  `init` returns it. The dumped module passes zero-size arrays across the `shard_map` boundary hundreds of
  times (MJX's state has empty fields for what AcrobotSwingup lacks, e.g. (seeds, envs, 0) contacts);
- `zero-size-shard-map`: the smallest form of that: a `shard_map` whose input and output include a
  (seeds, envs, 0) array beside a non-empty one.

On two H100s the first five cases ran under Shardy without a crash; the last two **crash** (SIGSEGV;
docs/decisions/sharded-seeds.md has the evidence): a `shard_map` with a zero-size array crossing its
boundary is the smallest program found that kills the pass. Keeping the
trainer's zero-size arrays out of its `shard_map` did not stop its crash (the programs make more inside).

Prints the case, the devices and `ok` with the result's checksum; exit status 139 is the crash.
"""

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
