#!/bin/bash
# Issue 12 "Done means": every target row of the issue re-measured in one command on one host, at today's
# code (084eba7). Two GPUs of one host; timeouts keep each part inside the device's 10 minutes.
# GPU 0: physics of all seven tasks at 1024 envs; the JAX trainer at one seed, TD3+SF2 and TD3, fp32 and TF32
#        (one process: the one-seed target and SF2/TD3 at one seed).
# GPU 1: the torch trainer at one seed, fp32 and TF32 (the torch/JAX ratio against GPU 0's rows); the JAX
#        trainer at 16 seeds, TD3+SF2 and TD3, TF32 (the all-seeds target, SF2/TD3 at 16 seeds, the one-GPU
#        reference of the two-GPU row); CheetahRun TD3+SF2 at 8 seeds, TF32.
# Then both GPUs together: one process per GPU, 16 seeds each, TD3+SF2, TF32 (the study runner's way).
# Carried: .whl-jax, .whl-torch.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
T="python3 -m bench.agent_throughput --algos td3 --epochs 3"
nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
(sleep 545; stamp watchdog; pkill -f bench.agent_; pkill -f bench.physics) & W=$!
(export CUDA_VISIBLE_DEVICES=0; stamp start0
 timeout 160 python3 -m bench.physics --tasks all --envs 1024 --repeats 3 --out $R/physics > $R/physics.log 2>&1
 stamp physics
 timeout 200 $T --tasks AcrobotSwingup --reps sf2,none --seeds 1 --precisions highest,tensorfloat32 --env-steps 24000 \
   --out $R/jax-1 > $R/jax-1.log 2>&1; stamp jax-1) & P0=$!
(export CUDA_VISIBLE_DEVICES=1; stamp start1
 timeout 130 $T --tasks AcrobotSwingup --reps sf2 --seeds 1 --precisions highest,tensorfloat32 --env-steps 24000 \
   --frameworks torch --out $R/torch-1 > $R/torch-1.log 2>&1; stamp torch-1
 timeout 150 $T --tasks AcrobotSwingup --reps sf2,none --seeds 16 --precisions tensorfloat32 --env-steps 24000 \
   --out $R/jax-16 > $R/jax-16.log 2>&1; stamp jax-16
 timeout 110 $T --tasks CheetahRun --reps sf2 --seeds 8 --precisions tensorfloat32 --env-steps 48000 \
   --out $R/cheetah-8 > $R/cheetah-8.log 2>&1; stamp cheetah-8) & P1=$!
wait $P0 $P1; stamp two-gpus-start
two() {
  CUDA_VISIBLE_DEVICES=$1 timeout 140 $T --tasks AcrobotSwingup --reps sf2 --seeds 16 --precisions tensorfloat32 \
    --env-steps 24000 --out $R/two-gpus-$1 > $R/two-gpus-$1.log 2>&1; stamp two-gpus-$1
}
two 0 & Q0=$!; two 1 & Q1=$!
wait $Q0 $Q1
kill $W 2>/dev/null
cd $OUT && tar czf results.tgz r && rm -rf r
