#!/bin/bash
# Issue 12 item 6: one flat vector per parameter group (agents/flat.py, with flat-groups.patch applied to a332a3a)
# against the previous commit (old/, `git archive HEAD packages/sf2-core-jax/src`). Four GPUs, one job each;
# every throughput pair on one GPU, one after the other.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
OLD=$PWD/old/packages/sf2-core-jax/src
T="python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2,none --env-steps 24000 --epochs 4"
nvidia-smi -L > $R/gpus.txt
# GPU 0: kernels per phase, new code
(CUDA_VISIBLE_DEVICES=0 timeout 420 python3 -m bench.agent_profile --task AcrobotSwingup --reps sf2,none --seeds 1 \
   --epochs 2 --hlo --out $R/profile-new > $R/profile-new.log 2>&1) &
# GPU 1: one seed TF32, old then new
(export CUDA_VISIBLE_DEVICES=1
 PYTHONPATH=$OLD:$PYTHONPATH timeout 200 $T --seeds 1 --precisions tensorfloat32 --out $R/old-1-tf32-a > $R/old-1-tf32-a.log 2>&1
 timeout 200 $T --seeds 1 --precisions tensorfloat32 --out $R/new-1-tf32-a > $R/new-1-tf32-a.log 2>&1) &
# GPU 2: one seed TF32, new then old; then fp32
(export CUDA_VISIBLE_DEVICES=2
 timeout 200 $T --seeds 1 --precisions tensorfloat32 --out $R/new-1-tf32-b > $R/new-1-tf32-b.log 2>&1
 PYTHONPATH=$OLD:$PYTHONPATH timeout 200 $T --seeds 1 --precisions tensorfloat32 --out $R/old-1-tf32-b > $R/old-1-tf32-b.log 2>&1) &
# GPU 3: 8 seeds TF32, new then old
(export CUDA_VISIBLE_DEVICES=3
 timeout 200 $T --seeds 8 --precisions tensorfloat32 --out $R/new-8-tf32 > $R/new-8-tf32.log 2>&1
 PYTHONPATH=$OLD:$PYTHONPATH timeout 200 $T --seeds 8 --precisions tensorfloat32 --out $R/old-8-tf32 > $R/old-8-tf32.log 2>&1) &
wait
cd $OUT && tar czf results.tgz r && rm -rf r
