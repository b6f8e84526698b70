#!/bin/bash
# Issue 12: the arithmetic of one SGD step as XLA compiles it for the GPU (bench/step_cost.py: cost analysis,
# products' flops, kernels), TD3 against TD3+SF2, at one seed and vmapped over the seeds of the targets
# (AcrobotSwingup 16, CheetahRun 8). Code of this commit. Carried: .whl-jax.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
nvidia-smi -L > $R/gpus.txt
S="python3 -m bench.step_cost --reps none,sf2"
timeout 100 $S --seeds 1 --out $R/acro-1 > $R/acro-1.log 2>&1
timeout 100 $S --seeds 16 --out $R/acro-16 > $R/acro-16.log 2>&1
timeout 80 $S --task CheetahRun --seeds 8 --out $R/cheetah-8 > $R/cheetah-8.log 2>&1
cd $OUT && tar czf results.tgz r && rm -rf r
