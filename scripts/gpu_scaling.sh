#!/usr/bin/env bash
# Several GPUs of one host against one (issue 12 item 5), through the trainer's own epochs
# (`python -m bench.agent_throughput`), three ways in one command so the ratios share a machine:
#   one-gpu            N seeds vmapped on GPU 0 alone (CUDA_VISIBLE_DEVICES=0)
#   two-gpus-sharded   2N seeds in one process: `Program` spreads them over both GPUs (shard_map on "seed";
#                      SF2_SHARD_SEEDS=1, opt-in, compiled with GSPMD:
#                      see Program.mesh)
#   two-processes      two processes started together, N seeds each, one per GPU (what the study runner
#                      does with whole runs); their aggregate is the sum of the two rates
#
#   bash scripts/gpu_scaling.sh N [bench.agent_throughput options: --tasks --reps --precisions ...]
#
# Results: $OUT/scaling.tar.gz (throughput.csv/.md and machine.json per way, and the logs, each line
# stamped with the host's clock so the two processes' timed epochs can be seen to overlap).
set -uo pipefail
n=$1; shift
source scripts/gpu_env.sh || exit 1
gpus=$(nvidia-smi -L | grep -c '^GPU ')
[ "$gpus" -ge 2 ] || { echo "gpu_scaling.sh: needs two GPUs, this host has $gpus" >&2; exit 2; }
out=/tmp/scaling; rm -rf "$out"; mkdir -p "$out"
stamp() { while IFS= read -r line; do printf '%s %s\n' "$(date +%s.%N | cut -c1-14)" "$line"; done; }
# each process's exit status is logged: a process killed by a signal prints nothing of its own
bench() { python3 -u -m bench.agent_throughput "$@" 2>&1 | stamp; echo "exit status ${PIPESTATUS[0]}"; }
CUDA_VISIBLE_DEVICES=0 bench --seeds "$n" "$@" --out "$out/one-gpu" | tee "$out/one-gpu.log"
SF2_SHARD_SEEDS=1 bench --seeds $((2 * n)) "$@" --out "$out/two-gpus-sharded" | tee "$out/two-gpus-sharded.log"
CUDA_VISIBLE_DEVICES=0 bench --seeds "$n" "$@" --out "$out/two-processes-gpu0" > "$out/two-processes-gpu0.log" &
CUDA_VISIBLE_DEVICES=1 bench --seeds "$n" "$@" --out "$out/two-processes-gpu1" > "$out/two-processes-gpu1.log" &
wait
cat "$out"/two-processes-gpu*.log
mkdir -p "$OUT"
tar czf "$OUT/scaling.tar.gz" -C "$out" .
