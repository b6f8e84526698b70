#!/usr/bin/env bash
# MJX physics latency under XLA's default command buffers against the same with WHILE and CONDITIONAL
# commands (`--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL`: a while loop's predicate is tested on
# the GPU inside a CUDA graph instead of being copied to the host every iteration), on the tasks whose
# constraint solver loops (docs/physics.md "Evaluation latency"). With two GPUs the two settings run at
# the same time, one per GPU; with one, one after the other.
#
#   bash scripts/gpu-host/gpu_physics_flags.sh [TASKS [ENVS]]     # defaults: CheetahRun,FishSwim,HopperHop,PendulumSwingup 640
#
# Writes $OUT/physics-flags.tar.gz (physics.csv/.md, machine.json per setting, the logs) and prints, per
# task, both rates, the ms per env step and whether the final states agree bit for bit. Measured on
# two H200s: the flag gains nothing (0.90-1.00x; git show 0d333e8:bench/results/h200x2/README.md, "18").
set -uo pipefail
tasks=${1:-CheetahRun,FishSwim,HopperHop,PendulumSwingup}; envs=${2:-640}
source scripts/gpu-host/gpu_env.sh || exit 1
export PYTHONPATH=$PYTHONPATH:$PWD PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
flag="--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL"
out=/tmp/physics-flags; rm -rf "$out"; mkdir -p "$out"
P="timeout 240 python3 -m bench.physics --tasks $tasks --envs $envs --steps 200 --repeats 3"
gpus=$(nvidia-smi -L | grep -c '^GPU ')
if [ "$gpus" -ge 2 ]; then
  CUDA_VISIBLE_DEVICES=0 $P --out "$out/default" > "$out/default.log" 2>&1 &
  CUDA_VISIBLE_DEVICES=1 XLA_FLAGS="$flag" $P --out "$out/while" > "$out/while.log" 2>&1 &
  wait
else
  $P --out "$out/default" > "$out/default.log" 2>&1
  XLA_FLAGS="$flag" $P --out "$out/while" > "$out/while.log" 2>&1
fi
python3 - "$out" "$flag" <<'PY' || echo "a setting did not finish: see the logs"
import csv, sys
out, flag = sys.argv[1:]
rows = {s: {r["task"]: r for r in csv.DictReader(open(f"{out}/{s}/physics.csv"))} for s in ("default", "while")}
for task, d in rows["default"].items():
    w = rows["while"].get(task)
    if w is None:
        continue
    speed = float(w["env_steps_per_s"]) / float(d["env_steps_per_s"])
    same = d["state_checksum"] == w["state_checksum"]
    print(f"{task} x{d['num_envs']}: default {float(d['env_steps_per_s']):,.0f}, +WHILE {float(w['env_steps_per_s']):,.0f}"
          f" env steps/s ({speed:.2f}x); ms per env step {1e3 * float(d['median_call_s']) / int(d['steps_per_call']):.3f}"
          f" -> {1e3 * float(w['median_call_s']) / int(w['steps_per_call']):.3f}; same final state: {same}")
PY
mkdir -p "$OUT"; tar czf "$OUT/physics-flags.tar.gz" -C "$out" .
