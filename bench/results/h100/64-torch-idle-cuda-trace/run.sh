#!/usr/bin/env bash
# bench/results/h100/64-torch-idle-cuda-trace: ../62-torch-idle again, the trace now recording CUDA activity
# only (issue 12: "the torch epoch's idle 13%"). One GPU; .whl-jax and .whl-torch carried.
set -uo pipefail
source scripts/gpu_env.sh || exit 1
nvidia-smi -L > /tmp/gpus.txt
timeout 400 python3 -m bench.agent_profile --framework torch --task AcrobotSwingup --reps sf2,none --seeds 1 \
  --epochs 2 --out /tmp/p > /tmp/p.log 2>&1; echo "exit $?"
cp /tmp/gpus.txt /tmp/p.log /tmp/p/ 2>/dev/null
tar czf $OUT/profile.tgz -C /tmp p
grep -A 14 "Device idle" /tmp/p/agent_profile.md; grep "^wall\|^host\|^- GPU\|CUDA runtime" /tmp/p/agent_profile.md | cut -c1-400
