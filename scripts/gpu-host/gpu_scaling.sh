#!/usr/bin/env bash
# Several GPUs of one host against one, through the trainer's own epochs
# (`python -m bench.agent_throughput`), three ways in one command so the ratios share a machine:
#   one-gpu            N seeds vmapped on GPU 0 alone (CUDA_VISIBLE_DEVICES=0)
#   two-gpus-sharded   2N seeds in one process: `Program` spreads them over both GPUs (shard_map on "seed";
#                      SF2_SHARD_SEEDS=1, opt-in, compiled with GSPMD:
#                      see Program.mesh)
#   two-processes      two processes started together, N seeds each, one per GPU (what the study runner
#                      does with whole runs); their aggregate is the sum of the two rates
#
#   bash scripts/gpu-host/gpu_scaling.sh N [bench.agent_throughput options: --tasks --reps --precisions ...]
#
# Takes about 6–7 minutes with `2 --tasks AcrobotSwingup --reps none,sf2 --precisions tensorfloat32` (each
# way compiles for about 32 s per representation; docs/decisions/sharded-seeds.md); pick the
# ways with SCALING_WAYS (default "one-gpu,two-gpus-sharded,two-processes", the order they run in), and
# give each a time limit with SCALING_WAY_LIMIT (seconds, default 240) so a hang or crash of one way does
# not eat the others'.
#
# Results come back even if the device's limit cuts the command: each way's log is written to $OUT as it
# runs (one-gpu.log, two-gpus-sharded.log, two-processes.log; every line stamped with the host's clock, so
# the two processes' timed epochs can be seen to overlap), and $OUT/scaling.tar.gz (each way's
# throughput.csv/.md and machine.json, and the logs) is rewritten after each way. (A command that pipes
# the script's output through `tail` loses everything when it is cut: 2026-11-27, 330 s, nothing came back.)
set -uo pipefail
n=$1; shift
source scripts/gpu-host/gpu_env.sh || exit 1
gpus=$(nvidia-smi -L | grep -c '^GPU ')
[ "$gpus" -ge 2 ] || { echo "gpu_scaling.sh: needs two GPUs, this host has $gpus" >&2; exit 2; }
ways=${SCALING_WAYS:-one-gpu,two-gpus-sharded,two-processes}
limit=${SCALING_WAY_LIMIT:-240}
out=/tmp/scaling; rm -rf "$out"; mkdir -p "$out" "$OUT"
stamp() { while IFS= read -r line; do printf '%s %s\n' "$(date +%s.%N | cut -c1-14)" "$line"; done; }
# each process's exit status is logged: a process killed by a signal (124: the way's time limit) prints
# nothing of its own
bench() {
  timeout --signal=TERM "$limit" python3 -u -m bench.agent_throughput "$@" 2>&1 | stamp
  echo "exit status ${PIPESTATUS[0]}" | stamp
}
pack() { tar czf "$OUT/scaling.tar.gz.part" -C "$out" . && mv "$OUT/scaling.tar.gz.part" "$OUT/scaling.tar.gz"; }
for way in ${ways//,/ }; do
  log=$OUT/$way.log
  echo "== $way ($(date -u +%H:%M:%S) UTC, limit ${limit} s)" | tee "$log"
  case $way in
    one-gpu)
      CUDA_VISIBLE_DEVICES=0 bench --seeds "$n" "$@" --out "$out/one-gpu" | tee -a "$log" ;;
    two-gpus-sharded)
      CUDA_VISIBLE_DEVICES=0,1 SF2_SHARD_SEEDS=1 bench --seeds $((2 * n)) "$@" --out "$out/two-gpus-sharded" \
        | tee -a "$log" ;;
    two-processes)
      CUDA_VISIBLE_DEVICES=0 bench --seeds "$n" "$@" --out "$out/two-processes-gpu0" | sed -u 's/^/gpu0 /' >> "$log" &
      CUDA_VISIBLE_DEVICES=1 bench --seeds "$n" "$@" --out "$out/two-processes-gpu1" | sed -u 's/^/gpu1 /' >> "$log" &
      wait
      tail -n +2 "$log" ;;
    *) echo "gpu_scaling.sh: unknown way '$way' in SCALING_WAYS (valid: one-gpu, two-gpus-sharded, two-processes)" >&2
       exit 2 ;;
  esac
  cp "$log" "$out/"
  pack
done
