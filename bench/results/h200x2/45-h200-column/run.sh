#!/bin/bash
# Issue 12: the H200 column at today's code (a332a3a: branch-free actor step, torch buffer without .item()).
# Two H200s of one host; GPU 0 the JAX trainer at fp32 `highest` (1 and 8 seeds), GPU 1 JAX against torch at
# one seed (fp32 and TF32, same process) and CheetahRun at 8 seeds (TF32). The TF32 rows at 1 and 8 seeds
# are 44-fusion-flags' default runs (same host kind, same code).
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
nvidia-smi -L > $R/gpus.txt
T="python3 -m bench.agent_throughput --algos td3"
(export CUDA_VISIBLE_DEVICES=0
 timeout 400 $T --tasks AcrobotSwingup --reps sf2,none --seeds 1,8 --precisions highest --env-steps 24000 --epochs 4 \
   --out $R/acro-highest > $R/acro-highest.log 2>&1) &
(export CUDA_VISIBLE_DEVICES=1
 timeout 250 $T --tasks AcrobotSwingup --reps sf2 --seeds 1 --precisions highest,tensorfloat32 --frameworks jax,torch \
   --env-steps 24000 --epochs 4 --out $R/acro-torch > $R/acro-torch.log 2>&1
 timeout 170 $T --tasks CheetahRun --reps sf2 --seeds 8 --precisions tensorfloat32 --env-steps 48000 --epochs 3 \
   --out $R/cheetah8 > $R/cheetah8.log 2>&1) &
wait
cd $OUT && tar czf results.tgz r && rm -rf r
