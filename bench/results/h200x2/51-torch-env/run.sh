#!/bin/bash
# Issue 12: the torch trainer's env keeps the JAX state packed (one buffer per dtype) and returns the
# transition as one array (144a2ee); h200x2/50 found the torch host at 1.276 ms per SGD step against 1.104 ms
# of device work, the env step 0.465 ms of it. old/ = `git archive 452d1c3 packages/sf2-core-torch/src`.
# Carried: .whl-jax, .whl-torch, old.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
OLD=$PWD/old/packages/sf2-core-torch/src
T="python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2 --seeds 1 --precisions tensorfloat32 --frameworks torch --env-steps 24000 --epochs 4"
nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
# GPU 0: torch one seed TF32, old and new twice each (opposite orders); the new code's profile; then the
# JAX trainer's one-seed bf16 row of the H200 column (TD3+SF² and TD3)
(export CUDA_VISIBLE_DEVICES=0; stamp start0
 PYTHONPATH=$OLD:$PYTHONPATH timeout 100 $T --out $R/old-a > $R/old-a.log 2>&1; stamp old-a
 timeout 100 $T --out $R/new-a > $R/new-a.log 2>&1; stamp new-a
 timeout 100 $T --out $R/new-b > $R/new-b.log 2>&1; stamp new-b
 PYTHONPATH=$OLD:$PYTHONPATH timeout 100 $T --out $R/old-b > $R/old-b.log 2>&1; stamp old-b
 timeout 150 python3 -m bench.agent_profile --task AcrobotSwingup --reps sf2 --seeds 1 --epochs 2 \
   --framework torch --out $R/profile-new > $R/profile-new.log 2>&1; stamp profile-new
 timeout 150 python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2,none --seeds 1 \
   --precisions bfloat16 --env-steps 24000 --epochs 4 --out $R/jax-bf16 > $R/jax-bf16.log 2>&1; stamp jax-bf16) & P0=$!
# GPU 1: the one-seed benchmark (JAX and torch, fp32 and TF32, one process), then the torch tests
(export CUDA_VISIBLE_DEVICES=1; stamp start1
 timeout 300 python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2 --seeds 1 \
   --precisions highest,tensorfloat32 --frameworks jax,torch --env-steps 24000 --epochs 4 \
   --out $R/acro-both > $R/acro-both.log 2>&1; stamp acro-both
 timeout 150 python3 -m pytest -q -rs packages/sf2-core-torch/tests/agents/test_torch_graphs.py \
   packages/sf2-core-torch/tests/agents/test_torch_envs.py > $R/gpu-tests.log 2>&1; stamp gpu-tests) & P1=$!
(sleep 540; stamp watchdog; pkill -f bench.agent_ ; pkill -f pytest) & W=$!
wait $P0 $P1; kill $W 2>/dev/null
cd $OUT && tar czf results.tgz r && rm -rf r
