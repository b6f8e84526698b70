#!/usr/bin/env bash
# Why does one process with a run's seeds sharded over two GPUs die (SF2_SHARD_SEEDS=1, Program.mesh)?
# docs/decisions/sharded-seeds.md. Each probe is a fresh process (a crash of XLA kills it)
# with a time limit; each prints its exit status (139 = SIGSEGV).
#
#   bash scripts/gpu-host/gpu_shard_probe.sh flags      a minimal two-device jit, then the trainer's sharded program
#                                              under XLA flags that each switch one suspect off (measured
#                                              2026-11-25, under Shardy, before `Program.mesh` picked GSPMD:
#                                              every one segfaults in the compile of `init`)
#   bash scripts/gpu-host/gpu_shard_probe.sh programs   each program sharded (`python -m bench.lab.shard_probe`) under the
#                                              GSPMD partitioner that `Program._program` picks: init; epoch and
#                                              evaluate after a one-device init; then init under JAX's
#                                              default Shardy partitioner (`--shardy`: the crash), again with XLA's
#                                              per-pass HLO dump, whose last pass names where the compiler
#                                              died ($OUT/xla-dump.tar.gz)
#   bash scripts/gpu-host/gpu_shard_probe.sh minimal [CASE...]
#                                              `python -m bench.lab.shardy_repro`'s cases, one process each: the
#                                              operation that the dump's Shardy input holds one custom call
#                                              for (cuSOLVER's Cholesky, from MJX's env reset) alone under
#                                              Shardy, inside and outside `shard_map`, its GSPMD and matmul
#                                              controls, and the env reset itself
set -uo pipefail
mode=${1:?usage: bash scripts/gpu-host/gpu_shard_probe.sh flags|programs|minimal}
source scripts/gpu-host/gpu_env.sh || exit 1
export XLA_PYTHON_CLIENT_PREALLOCATE=false
quiet() { grep -v "^WARNING\|warp\|^  File\|^Extension modules" | tail -6; }
trainer() {   # trainer ENV... : the throughput bench's 4-seed TD3 program, sharded
  echo "== trainer, 4 seeds sharded over 2 GPUs, $*"
  env "$@" SF2_SHARD_SEEDS=1 timeout 75 python3 -X faulthandler -u -m bench.agent_throughput \
    --tasks AcrobotSwingup --reps none --seeds 4 --precisions tensorfloat32 --env-steps 8000 --epochs 2 \
    --out /tmp/shard-probe 2>&1 | quiet
  echo "exit ${PIPESTATUS[0]}"
}
programs() {   # programs "LIST [--shardy]" [ENV...]
  local list=$1; shift
  echo "== bench.lab.shard_probe --programs $list $*"
  # shellcheck disable=SC2086   # $list is the program list and, for the crash, --shardy
  env "$@" SF2_SHARD_SEEDS=1 timeout 120 python3 -X faulthandler -u -m bench.lab.shard_probe --programs $list \
    --seeds 4 2>&1 | quiet
  echo "exit ${PIPESTATUS[0]}"
}
case $mode in
  minimal)
    cases=("${@:2}")   # the cases named after `minimal`, else all of them
    [ ${#cases[@]} -gt 0 ] || cases=(cholesky-shard-map cholesky-shard-map-gspmd cholesky-jit \
      matmul-shard-map reset-shard-map reset-state-shard-map zero-size-shard-map)
    for c in "${cases[@]}"; do
      echo "== bench.lab.shardy_repro --case $c"
      timeout 90 python3 -X faulthandler -u -m bench.lab.shardy_repro --case "$c" 2>&1 | quiet
      echo "exit ${PIPESTATUS[0]}"
    done ;;
  flags)
    echo "== minimal: a jitted sum of an array sharded over both GPUs"
    timeout 75 python3 -X faulthandler -c '
import jax, jax.numpy as jnp, numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
mesh = Mesh(np.array(jax.local_devices()), ("seed",))
x = jax.device_put(jnp.arange(8.0).reshape(4, 2), NamedSharding(mesh, P("seed")))
print(jax.devices(), jax.jit(lambda a: (a * 2).sum(axis=1))(x))' 2>&1 | tail -3
    echo "exit ${PIPESTATUS[0]}"
    trainer XLA_FLAGS=
    trainer JAX_ENABLE_COMPILATION_CACHE=false
    trainer XLA_FLAGS=--xla_gpu_autotune_level=0
    trainer XLA_FLAGS=--xla_gpu_enable_command_buffer=
    trainer XLA_FLAGS=--xla_gpu_enable_triton_gemm=false ;;
  programs)
    programs init
    programs epoch
    programs evaluate
    programs "init --shardy"
    dump=/tmp/xla-dump; rm -rf "$dump"
    programs "init --shardy" XLA_FLAGS="--xla_dump_to=$dump --xla_dump_hlo_module_re=.*_init_one.* --xla_dump_hlo_pass_re=.* --xla_dump_hlo_as_text"
    echo "== the last HLO passes dumped before the crash (newest last)"
    ls -tr "$dump" 2>/dev/null | tail -8
    mkdir -p "$OUT"
    # the module before optimization and the last 20 passes' dumps: enough to bisect, small enough to carry
    (cd "$dump" 2>/dev/null && tar czf "$OUT/xla-dump.tar.gz" $(ls *before_optimizations* 2>/dev/null) \
      $(ls -tr | tail -20)) ;;
  *) echo "gpu_shard_probe.sh: unknown mode '$mode'; valid: flags, programs, minimal" >&2; exit 2 ;;
esac
