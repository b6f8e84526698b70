#!/bin/bash
# Issue 12 item 6: at one seed the SGD step compiles to ~420 kernels, at 8 seeds to ~256 (the LayerNorms
# become one Triton block-level fusion each: 43-sharded-profile). Do XLA's experimental fusion switches
# give the one-seed program the same? Each GPU: the flag and the default, one after the other.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
nvidia-smi -L > $R/gpus.txt
T="python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2,none --env-steps 24000 --epochs 4 --seeds 1 --precisions tensorfloat32"
pair() {  # pair GPU NAME FLAG ORDER: ORDER "flag-first" or "default-first"
  export CUDA_VISIBLE_DEVICES=$1
  if [ "$4" = flag-first ]; then
    XLA_FLAGS="$3" timeout 220 $T --out $R/$2 > $R/$2.log 2>&1
    timeout 220 $T --out $R/default-gpu$1 > $R/default-gpu$1.log 2>&1
  else
    timeout 220 $T --out $R/default-gpu$1 > $R/default-gpu$1.log 2>&1
    XLA_FLAGS="$3" timeout 220 $T --out $R/$2 > $R/$2.log 2>&1
  fi
}
# the second call (two GPUs) ran the last two flags, then 8 seeds at the default on each GPU
case ${1:-first} in
  first)
    pair 0 fusion-autotuner --xla_gpu_experimental_enable_fusion_autotuner=true default-first &
    pair 1 block-level-rewriter --xla_gpu_experimental_enable_fusion_block_level_rewriter=true flag-first & ;;
  second)
    (pair 0 heroless-priority --xla_gpu_experimental_enable_triton_heroless_priority_fusion=true default-first
     CUDA_VISIBLE_DEVICES=0 timeout 200 ${T/--seeds 1/--seeds 8} --out $R/default-8-gpu0 > $R/default-8-gpu0.log 2>&1) &
    (pair 1 all-triton --xla_gpu_experimental_all_fusions_with_triton=true flag-first
     CUDA_VISIBLE_DEVICES=1 timeout 200 ${T/--seeds 1/--seeds 8} --out $R/default-8-gpu1 > $R/default-8-gpu1.log 2>&1) & ;;
esac
wait
cd $OUT && tar czf results.tgz r && rm -rf r
