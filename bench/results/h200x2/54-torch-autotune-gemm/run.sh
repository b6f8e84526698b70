#!/bin/bash
# Issue 12: which part of max-autotune makes the torch trainer's one-seed step faster, and whether Inductor's
# on-disk caches let a second process skip the autotuning. Code of 084eba7. Inductor's settings through its
# environment variables (torch/_inductor/config.py): TORCHINDUCTOR_MAX_AUTOTUNE_GEMM=1 autotunes the GEMMs
# alone (Triton templates with fused epilogues against cuBLAS), without max-autotune's coordinate-descent
# tuning of every other kernel. Each group of runs has its own TORCHINDUCTOR_CACHE_DIR.
# GPU 0: GEMM autotuning twice (the second process with the first one's cache), the default compile, the JAX
#        trainer (fp32 and TF32), all TF32 but the last;
# GPU 1: compile=max-autotune-no-cudagraphs at fp32 `highest` (measured so far at TF32 only).
# Carried: .whl-jax, .whl-torch.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
A="python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2 --seeds 1 --env-steps 24000 --epochs 4"
T="$A --precisions tensorfloat32"
nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
(export CUDA_VISIBLE_DEVICES=0; stamp start0
 export TORCHINDUCTOR_CACHE_DIR=/tmp/inductor-gemm
 TORCHINDUCTOR_MAX_AUTOTUNE_GEMM=1 timeout 300 $T --frameworks torch --out $R/gemm-a > $R/gemm-a.log 2>&1; stamp gemm-a
 du -sh /tmp/inductor-gemm > $R/cache-size.txt 2>&1
 TORCHINDUCTOR_MAX_AUTOTUNE_GEMM=1 timeout 100 $T --frameworks torch --out $R/gemm-b > $R/gemm-b.log 2>&1; stamp gemm-b
 export TORCHINDUCTOR_CACHE_DIR=/tmp/inductor-default
 timeout 90 $T --frameworks torch --out $R/default > $R/default.log 2>&1; stamp default
 timeout 100 $A --precisions highest,tensorfloat32 --frameworks jax --out $R/jax > $R/jax.log 2>&1; stamp jax) & P0=$!
(export CUDA_VISIBLE_DEVICES=1; stamp start1
 export TORCHINDUCTOR_CACHE_DIR=/tmp/inductor-full
 timeout 500 $A --precisions highest --frameworks torch --set compile=max-autotune-no-cudagraphs \
   --out $R/full-fp32 > $R/full-fp32.log 2>&1; stamp full-fp32) & P1=$!
(sleep 540; stamp watchdog; pkill -f bench.agent_) & W=$!
wait $P0 $P1; kill $W 2>/dev/null
for f in gemm-a gemm-b full-fp32; do echo "$f $(grep -c AUTOTUNE $R/$f.log)"; done > $R/autotune-count.txt 2>/dev/null
cd $OUT && tar czf results.tgz r && rm -rf r
