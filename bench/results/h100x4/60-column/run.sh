#!/usr/bin/env bash
# bench/results/h100x4/60-column: one command on a four-GPU host (asked nvidia-h200-x4, ran on four H100s) (2026-11-27, thirty-third session).
#   1. issue 12's target column: scripts/gpu_column.sh ($OUT/column.tgz)
#   2. then, at once:
#      GPUs 0, 1  the deterministic pair of scripts/gpu_determinism.sh (XLA's deterministic ops; AcrobotSwingup
#                 TD3+SF², 5 seeds, 100k env steps), to compare with the same pair on another host
#                 ($OUT/determinism.tar.gz)
#      GPU 2      torch TD3 with the plain critic heads (sf2_torch of d3e564a^, carried as probe/plain-heads)
#      GPU 3      torch TD3 with networks.twin_heads (this commit's sf2_torch)
#                 each beside the JAX trainer in its own process (torch / JAX), one seed, TF32 ($OUT/heads.tgz)
# Carry: .whl-jax, .whl-torch, probe/plain-heads.
set -uo pipefail
{ hostname; nvidia-smi -L; } > /tmp/host.txt
bash scripts/gpu_column.sh > /tmp/column.out 2>&1; echo "gpu_column.sh exit $?"; tail -12 /tmp/column.out
source scripts/gpu_env.sh || exit 1
H=/tmp/heads; mkdir -p $H; cp /tmp/host.txt $H/
for p in "$PWD/probe/plain-heads:" ""; do PYTHONPATH=$p$PYTHONPATH python3 -c "import sf2_torch.networks as n; print(n.__file__, 'twin_heads' in dir(n))"; done > $H/which.txt 2>&1
T="python3 -m bench.agent_throughput --algos td3 --epochs 3 --tasks AcrobotSwingup --env-steps 24000 --reps none --seeds 1 --precisions tensorfloat32 --frameworks jax,torch"
(CUDA_VISIBLE_DEVICES=2 PYTHONPATH=$PWD/probe/plain-heads:$PYTHONPATH timeout 200 $T --out $H/plain > $H/plain.log 2>&1; echo "plain exit $?" >> $H/times.txt) &
(CUDA_VISIBLE_DEVICES=3 timeout 200 $T --out $H/twin > $H/twin.log 2>&1; echo "twin exit $?" >> $H/times.txt) &
CUDA_VISIBLE_DEVICES=0,1 timeout 220 bash scripts/gpu_determinism.sh deterministic > /tmp/det.out 2>&1; echo "determinism exit $?"
wait
grep -h "sf2_torch\|torch / JAX\|^| torch\|^| jax" $H/*.log $H/*/throughput.md | head -20
cat /tmp/det.out | tail -5
tar czf $OUT/heads.tgz -C /tmp heads
