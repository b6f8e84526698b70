#!/bin/bash
# Issue 12: a profile of the sharded epoch (TD3+SF², AcrobotSwingup, TF32) on GPUs 0 and 1 against the
# one-GPU epoch at half the seeds, and XLA's deterministic ops at 10 seeds on a physics-heavy task
# (CheetahRun) on GPUs 2 and 3, two processes at once.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
nvidia-smi -L > $R/gpus.txt
P="python3 -m bench.agent_profile --task AcrobotSwingup --reps sf2 --epochs 2"
(export CUDA_VISIBLE_DEVICES=0,1
 SF2_SHARD_SEEDS=1 timeout 200 $P --seeds 16 --out $R/sharded-16 > $R/sharded-16.log 2>&1
 CUDA_VISIBLE_DEVICES=0 timeout 150 $P --seeds 8 --out $R/one-8 > $R/one-8.log 2>&1
 SF2_SHARD_SEEDS=1 timeout 200 $P --seeds 16 --hlo --out $R/sharded-16-hlo > $R/sharded-16-hlo.log 2>&1) &
(export CUDA_VISIBLE_DEVICES=2,3
 timeout 540 bash scripts/gpu_determinism.sh deterministic -- --task CheetahRun --algo td3 --repr sf2 \
   --config paper --seeds 0-9 --set num_timesteps=100000 --set num_evals=20 > $R/determinism.log 2>&1) &
wait
cd $OUT && tar czf results.tgz r && rm -rf r
