#!/bin/bash
# Issue 12, fourth device call of 2026-11-27 (code 7f02dcb): why the torch trainer is now 0.57-0.63x the JAX
# trainer at one seed (h200x2/46): both trainers' SGD steps profiled at the paper preset (TF32 learner), one
# GPU each, at the same time.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
P="python3 -m bench.agent_profile --task AcrobotSwingup --reps sf2 --seeds 1 --epochs 2"
nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
(export CUDA_VISIBLE_DEVICES=0; stamp start0
 timeout 420 $P --framework torch --out $R/profile-torch > $R/profile-torch.log 2>&1; stamp profile-torch) &
(export CUDA_VISIBLE_DEVICES=1; stamp start1
 timeout 420 $P --framework jax --out $R/profile-jax > $R/profile-jax.log 2>&1; stamp profile-jax) &
wait
cd $OUT && tar czf results.tgz r && rm -rf r
