#!/usr/bin/env bash
# The trainer rows of bench/README.md's tables for one GPU kind, in one command on one host: physics, the
# JAX and torch trainers at one and 16 seeds, CheetahRun at 8 seeds, two GPUs against one. Needs four GPUs
# of one host (`nvidia-h100-x4`, `nvidia-h200-x4`); 340 s on four H100s (bench/results/h100x4/59-column).
# Four lanes at once, each one after the other:
#   GPU 0  physics of the seven paper tasks at 1024 envs; the JAX trainer at one seed, TD3+SF² and TD3, fp32
#          and TF32 (one process: the one-seed target and SF²/TD3 at one seed)
#   GPU 1  the JAX and torch trainers at one seed, TD3+SF², fp32 and TF32 (one process: torch / JAX); then
#          TD3 (`none`, the twin critic heads as one program) in both at one seed, TF32
#   GPU 2  the JAX trainer at 16 seeds, TD3+SF² and TD3, TF32 (all seeds on one GPU, SF²/TD3 at 16 seeds, the
#          one-GPU reference of the two-GPU row)
#   GPU 3  CheetahRun TD3+SF² at 8 seeds, TF32
# then, once GPUs 2 and 3 are done: one process on each, 16 seeds each (two-gpus-2, two-gpus-3; the study
# runner's way). Each part has its own time limit (on H200s the torch and CheetahRun rows need more:
# bench/results/h200x2/56-h200-column-rest).
#
#   bash scripts/gpu-host/gpu_column.sh            (carry .whl-jax and .whl-torch)
#
# Results: $OUT/column.tgz (one folder per part: throughput.md/.csv or physics.md/.csv, machine.json; every
# log; times.txt), rewritten after each lane ends, so a cut command still returns what finished.
set -uo pipefail
source scripts/gpu-host/gpu_env.sh || exit 1
gpus=$(nvidia-smi -L | grep -c '^GPU ')
[ "$gpus" -ge 4 ] || { echo "gpu_column.sh: needs four GPUs of one host (nvidia-h100-x4, nvidia-h200-x4), this host has $gpus" >&2; exit 2; }
R=/tmp/column; rm -rf "$R"; mkdir -p "$R" "$OUT"
nvidia-smi -L > "$R/gpus.txt"
T="python3 -m bench.agent_throughput --algos td3 --epochs 3"
A="--tasks AcrobotSwingup --env-steps 24000"
stamp() { echo "$(date +%s) $*" >> "$R/times.txt"; }
pack() { tar czf "$OUT/column.tgz.$BASHPID" -C /tmp column && mv "$OUT/column.tgz.$BASHPID" "$OUT/column.tgz"; }
part() {   # part GPU LIMIT NAME ARGS...: one measurement on one GPU, its log and stamp
  local gpu=$1 limit=$2 name=$3; shift 3
  CUDA_VISIBLE_DEVICES=$gpu timeout "$limit" "$@" --out "$R/$name" > "$R/$name.log" 2>&1
  stamp "$name exit $?"
}
(sleep 560; stamp watchdog; pkill -f bench.agent_; pkill -f bench.physics) & W=$!
(part 0 200 physics python3 -m bench.physics --tasks all --envs 1024 --repeats 3
 part 0 260 jax-1 $T $A --reps sf2,none --seeds 1 --precisions highest,tensorfloat32; pack) & L0=$!
(part 1 320 torch-1 $T $A --reps sf2 --seeds 1 --precisions highest,tensorfloat32 --frameworks jax,torch
 part 1 180 torch-td3 $T $A --reps none --seeds 1 --precisions tensorfloat32 --frameworks jax,torch; pack) & L1=$!
(part 2 200 jax-16 $T $A --reps sf2,none --seeds 16 --precisions tensorfloat32; pack) & L2=$!
(part 3 220 cheetah-8 $T --tasks CheetahRun --reps sf2 --seeds 8 --precisions tensorfloat32 --env-steps 48000
 pack) & L3=$!
wait $L2 $L3
stamp two-gpus-start
two() { part "$1" 160 "two-gpus-$1" $T $A --reps sf2 --seeds 16 --precisions tensorfloat32; }
two 2 & Q2=$!; two 3 & Q3=$!
wait $Q2 $Q3 $L0 $L1
kill $W 2>/dev/null
pack
for f in "$R"/*/physics.md "$R"/*/throughput.md; do [ -f "$f" ] && { echo "== $f"; cat "$f"; }; done
