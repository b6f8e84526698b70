#!/bin/bash
# Issue 12: the two rows of ../55-h200-column that its time limits cut (the torch trainer at TF32, CheetahRun
# at 8 seeds), and the 8-seed learner rows, on the same host kind at the same code (084eba7).
# GPU 0: the JAX and torch trainers at one seed, TF32, one process (the torch/JAX ratio); then the JAX trainer
#        at 8 seeds, TD3+SF2 and TD3, TF32.
# GPU 1: CheetahRun TD3+SF2 at 8 seeds, TF32.
# Carried: .whl-jax, .whl-torch.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
T="python3 -m bench.agent_throughput --algos td3 --epochs 3"
nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
(sleep 330; stamp watchdog; pkill -f bench.agent_) & W=$!
(export CUDA_VISIBLE_DEVICES=0; stamp start0
 timeout 200 $T --tasks AcrobotSwingup --reps sf2 --seeds 1 --precisions tensorfloat32 --frameworks jax,torch \
   --env-steps 24000 --out $R/both-1 > $R/both-1.log 2>&1; stamp both-1
 timeout 120 $T --tasks AcrobotSwingup --reps sf2,none --seeds 8 --precisions tensorfloat32 --env-steps 24000 \
   --out $R/jax-8 > $R/jax-8.log 2>&1; stamp jax-8) & P0=$!
(export CUDA_VISIBLE_DEVICES=1; stamp start1
 timeout 300 $T --tasks CheetahRun --reps sf2 --seeds 8 --precisions tensorfloat32 --env-steps 48000 \
   --out $R/cheetah-8 > $R/cheetah-8.log 2>&1; stamp cheetah-8) & P1=$!
wait $P0 $P1; kill $W 2>/dev/null
cd $OUT && tar czf results.tgz r && rm -rf r
