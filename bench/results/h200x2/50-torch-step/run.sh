#!/bin/bash
# Issue 12: a cheaper torch SGD step at one seed (h200x2/48: torch's device work 1.49x JAX's; GEMMs 123 against
# 67 launches, the fused Adam 5 launches taking 0.183 ms). Two changes, each also alone (probe/):
#   twinq: TwinQ evaluates both Q heads as one product (sf2_torch/networks.py);
#   adam:  on CUDA the Adam steps and target lerps are compiled (sf2_torch/agents/algorithms.py).
# old/ is `git archive HEAD packages/sf2-core-torch/src` (4b0b9f6); probe/twinq and probe/adam are old/ with
# one of the two files of the working tree. Carried: .whl-jax, .whl-torch, old, probe.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
src() { echo $PWD/$1/packages/sf2-core-torch/src; }
T="python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2 --seeds 1 --precisions tensorfloat32 --frameworks torch --env-steps 24000 --epochs 4"
nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
run() {  # run NAME CODE(old|new|probe/twinq|probe/adam) TIMEOUT
  local pp=$PYTHONPATH; [ "$2" != new ] && pp=$(src $2):$PYTHONPATH
  PYTHONPATH=$pp timeout $3 $T --out $R/$1 > $R/$1.log 2>&1; stamp $1
}
# GPU 0: torch one seed TF32, old and new twice each (opposite orders), and each change alone
(export CUDA_VISIBLE_DEVICES=0; stamp start0
 run old-a old 100; run new-a new 160; run twinq probe/twinq 100; run adam probe/adam 160
 run new-b new 160; run old-b old 100) & P0=$!
# GPU 1: the torch tests on CUDA (graphs, compiled updates), the new step's profile, then the issue's
# one-seed benchmark (JAX and torch, fp32 and TF32, one process)
(export CUDA_VISIBLE_DEVICES=1; stamp start1
 timeout 150 python3 -m pytest -q -rs packages/sf2-core-torch/tests/agents/test_torch_graphs.py \
   packages/sf2-core-torch/tests/test_torch_networks.py > $R/gpu-tests.log 2>&1; stamp gpu-tests
 timeout 200 python3 -m bench.agent_profile --task AcrobotSwingup --reps sf2 --seeds 1 --epochs 2 \
   --framework torch --out $R/profile-new > $R/profile-new.log 2>&1; stamp profile-new
 timeout 300 python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2 --seeds 1 \
   --precisions highest,tensorfloat32 --frameworks jax,torch --env-steps 24000 --epochs 4 \
   --out $R/acro-both > $R/acro-both.log 2>&1; stamp acro-both) & P1=$!
# whatever has finished comes back even if the call's limit is near
(sleep 540; stamp watchdog; pkill -f bench.agent_ ; pkill -f pytest) & W=$!
wait $P0 $P1; kill $W 2>/dev/null
cd $OUT && tar czf results.tgz r && rm -rf r
