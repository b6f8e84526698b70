#!/bin/bash
# Issue 12: two cheaper torch SGD steps at one seed (TD3+SF², AcrobotSwingup, TF32; h200x2/48 found the torch
# step's device work at 1.49x the JAX step's: GEMMs 0.728 against 0.465 ms, the fused Adam 0.183 ms).
# GPU 0, one after the other: HEAD (the working tree: `--set` takes the torch fields since this commit),
#   a probe with foreach Adam instead of the fused one (probe/: `git archive HEAD packages/sf2-core-torch/src`
#   with `fused = False` in Algorithm._make_adam), HEAD again;
# GPU 1: `torch.compile(mode="max-autotune-no-cudagraphs")` (Triton GEMM templates autotuned against cuBLAS;
#   the trainer's StepGraph makes the CUDA graphs).
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
PROBE=$PWD/probe/packages/sf2-core-torch/src
T="python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2 --seeds 1 --precisions tensorfloat32 --frameworks torch --env-steps 24000 --epochs 4"
nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
(export CUDA_VISIBLE_DEVICES=0; stamp start0
 timeout 110 $T --out $R/head-a > $R/head-a.log 2>&1; stamp head-a
 PYTHONPATH=$PROBE:$PYTHONPATH timeout 110 $T --out $R/foreach-adam > $R/foreach-adam.log 2>&1; stamp foreach-adam
 timeout 110 $T --out $R/head-b > $R/head-b.log 2>&1; stamp head-b) &
(export CUDA_VISIBLE_DEVICES=1; stamp start1
 timeout 330 $T --set compile=max-autotune-no-cudagraphs --out $R/max-autotune > $R/max-autotune.log 2>&1; stamp max-autotune) &
wait
cd $OUT && tar czf results.tgz r && rm -rf r
