#!/bin/bash
# Issue 12 item 4 (several seeds per device; TD3+SF2 at 16-32 seeds is 50-52k env steps/s, the GPU busy):
# what would the LayerNorm's single-pass variance (flax's `use_fast_variance=True`, var = E[x^2] - E[x]^2;
# the JAX core uses the two-pass formula torch uses) and XLA's all-fusions-with-Triton switch buy at 8 and 16
# seeds? A probe only: probe/fastvar = `git archive HEAD packages/sf2-core-jax/src` (e003e29) with
# use_fast_variance=True in sf2_jax/networks.py MLP; not committed (it changes the numbers). Also the torch
# env test's CUDA case (JAX on the GPU). Carried: .whl-jax, .whl-torch, probe.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
PROBE=$PWD/probe/fastvar/packages/sf2-core-jax/src
T="python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2 --precisions tensorfloat32 --env-steps 24000 --epochs 4"
nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
# GPU 0: HEAD then fast variance (8 and 16 seeds), then HEAD at 8 seeds with the Triton switch
(export CUDA_VISIBLE_DEVICES=0; stamp start0
 timeout 190 $T --seeds 8,16 --out $R/head-a > $R/head-a.log 2>&1; stamp head-a
 PYTHONPATH=$PROBE:$PYTHONPATH timeout 190 $T --seeds 8,16 --out $R/fastvar-a > $R/fastvar-a.log 2>&1; stamp fastvar-a
 XLA_FLAGS=--xla_gpu_experimental_all_fusions_with_triton=true timeout 120 $T --seeds 8 --out $R/triton \
   > $R/triton.log 2>&1; stamp triton) & P0=$!
# GPU 1: the torch env test on CUDA, then fast variance then HEAD (8 and 16 seeds)
(export CUDA_VISIBLE_DEVICES=1; stamp start1
 JAX_PLATFORMS=cuda,cpu timeout 90 python3 -m pytest -q -rs packages/sf2-core-torch/tests/agents/test_torch_envs.py \
   > $R/gpu-tests.log 2>&1; stamp gpu-tests
 PYTHONPATH=$PROBE:$PYTHONPATH timeout 190 $T --seeds 8,16 --out $R/fastvar-b > $R/fastvar-b.log 2>&1; stamp fastvar-b
 timeout 190 $T --seeds 8,16 --out $R/head-b > $R/head-b.log 2>&1; stamp head-b) & P1=$!
(sleep 540; stamp watchdog; pkill -f bench.agent_ ; pkill -f pytest) & W=$!
wait $P0 $P1; kill $W 2>/dev/null
cd $OUT && tar czf results.tgz r && rm -rf r
