#!/bin/bash
# Issue 12, third device call of 2026-11-27 (code 7f02dcb, the one-seed programs without the vmap):
# GPU 0: how much of the one-seed SGD step the `train` selects cost (`jnp.where(train, n, o)` over every
#   parameter and Adam array in Trainer._sgd_steps: 57 select kernels per SGD step at one seed, 14 at two,
#   results/h200x2/46-unbatched-one-seed): a probe copy (probe/, `git archive HEAD packages/sf2-core-jax/src`
#   with that lambda replaced by `lambda n, o: n`, which also trains on the prefill: timed epochs only) against
#   HEAD, one after the other, twice, in opposite orders;
# GPU 1: the H200 column's 16- and 32-seed rows (TF32).
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
PROBE=$PWD/probe/packages/sf2-core-jax/src
T="python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2,none --env-steps 24000 --epochs 4 --precisions tensorfloat32"
nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
(export CUDA_VISIBLE_DEVICES=0
 stamp start0
 timeout 130 $T --seeds 1 --out $R/head-a > $R/head-a.log 2>&1; stamp head-a
 PYTHONPATH=$PROBE:$PYTHONPATH timeout 130 $T --seeds 1 --out $R/noselect-a > $R/noselect-a.log 2>&1; stamp noselect-a
 PYTHONPATH=$PROBE:$PYTHONPATH timeout 130 $T --seeds 1 --out $R/noselect-b > $R/noselect-b.log 2>&1; stamp noselect-b
 timeout 130 $T --seeds 1 --out $R/head-b > $R/head-b.log 2>&1; stamp head-b) &
(export CUDA_VISIBLE_DEVICES=1
 stamp start1
 timeout 520 $T --seeds 16,32 --out $R/seeds-16-32 > $R/seeds-16-32.log 2>&1; stamp seeds-16-32) &
wait
cd $OUT && tar czf results.tgz r && rm -rf r
