#!/usr/bin/env bash
# bench/results/h100/63-torch-acting-graphs: the torch trainer's explore and normalizer update as CUDA-graph
# replays (Algorithm._graphed), against the code before (probe/old-acting = `git archive 2cf4c6b
# packages/sf2-core-torch/src/sf2_torch`). One GPU; .whl-jax, .whl-torch, probe/old-acting carried.
set -uo pipefail
source scripts/gpu_env.sh || exit 1
R=/tmp/r; mkdir -p $R; nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
timeout 150 python3 -m pytest -q -rs -p no:cacheprovider packages/sf2-core-torch/tests/agents/test_torch_graphs.py > $R/gpu-tests.log 2>&1; stamp "tests exit $?"
T="python3 -m bench.agent_throughput --algos td3 --epochs 3 --tasks AcrobotSwingup --env-steps 24000 --seeds 1 --precisions tensorfloat32"
PYTHONPATH=$PWD/probe/old-acting:$PYTHONPATH timeout 170 $T --reps sf2,none --frameworks torch --out $R/old > $R/old.log 2>&1; stamp "old exit $?"
timeout 230 $T --reps sf2,none --frameworks jax,torch --out $R/new > $R/new.log 2>&1; stamp "new exit $?"
tar czf $OUT/r.tgz -C /tmp r
tail -3 $R/gpu-tests.log; cat $R/times.txt; grep -h "^| torch\|^| jax\|torch / JAX" $R/*/throughput.md
