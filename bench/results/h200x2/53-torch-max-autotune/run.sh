#!/bin/bash
# Issue 12: the torch trainer at one seed with Inductor's max-autotune (Triton GEMM templates with fused
# epilogues, autotuned against cuBLAS); h200x2/49 stopped it still compiling at 330 s. Code of d1a7c4e.
# GPU 0: max-autotune-no-cudagraphs (the trainer's StepGraph makes the CUDA graphs), up to 500 s;
# GPU 1, same host: the default compile and the JAX trainer, for the ratios. Carried: .whl-jax, .whl-torch.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
T="python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2 --seeds 1 --precisions tensorfloat32 --env-steps 24000 --epochs 4"
nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
(export CUDA_VISIBLE_DEVICES=0; stamp start0
 timeout 500 $T --frameworks torch --set compile=max-autotune-no-cudagraphs --out $R/max-autotune \
   > $R/max-autotune.log 2>&1; stamp max-autotune) & P0=$!
(export CUDA_VISIBLE_DEVICES=1; stamp start1
 timeout 120 $T --frameworks torch --out $R/default-a > $R/default-a.log 2>&1; stamp default-a
 timeout 150 $T --frameworks jax --out $R/jax > $R/jax.log 2>&1; stamp jax
 timeout 120 $T --frameworks torch --out $R/default-b > $R/default-b.log 2>&1; stamp default-b) & P1=$!
(sleep 530; stamp watchdog; pkill -f bench.agent_) & W=$!
wait $P0 $P1; kill $W 2>/dev/null
grep -c "AUTOTUNE" $R/max-autotune.log > $R/autotune-count.txt 2>/dev/null
cd $OUT && tar czf results.tgz r && rm -rf r
