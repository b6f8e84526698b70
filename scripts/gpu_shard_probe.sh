#!/usr/bin/env bash
# Why does one process with a run's seeds sharded over two GPUs die (SF2_SHARD_SEEDS=1, Program.mesh)?
# bench/results/h200x2/README.md "15-two-gpus": the process ended before its first epoch without a message.
# Each probe below is a fresh process (timeout 75 s): first a minimal two-device jit (is any multi-GPU
# compile broken?), then the trainer's sharded program under XLA flags that switch off one suspect each.
#   bash scripts/gpu_shard_probe.sh      (on a host with two GPUs; prints each probe's exit status)
set -uo pipefail
source scripts/gpu_env.sh || exit 1
export XLA_PYTHON_CLIENT_PREALLOCATE=false
echo "== minimal: a jitted sum of an array sharded over both GPUs"
timeout 75 python3 -X faulthandler -c '
import jax, jax.numpy as jnp, numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
mesh = Mesh(np.array(jax.local_devices()), ("seed",))
x = jax.device_put(jnp.arange(8.0).reshape(4, 2), NamedSharding(mesh, P("seed")))
print(jax.devices(), jax.jit(lambda a: (a * 2).sum(axis=1))(x))' 2>&1 | tail -3
echo "exit ${PIPESTATUS[0]}"
probe() {
  echo "== trainer, 4 seeds sharded over 2 GPUs, $*"
  env "$@" SF2_SHARD_SEEDS=1 timeout 75 python3 -X faulthandler -u -m bench.agent_throughput \
    --tasks AcrobotSwingup --reps none --seeds 4 --precisions tensorfloat32 --env-steps 8000 --epochs 2 \
    --out /tmp/shard-probe 2>&1 | grep -v "^WARNING\|warp\|^  File\|^Extension modules" | tail -4
  echo "exit ${PIPESTATUS[0]}"
}
probe XLA_FLAGS=
probe JAX_ENABLE_COMPILATION_CACHE=false
probe XLA_FLAGS=--xla_gpu_autotune_level=0
probe XLA_FLAGS=--xla_gpu_enable_command_buffer=
probe XLA_FLAGS=--xla_gpu_enable_triton_gemm=false
