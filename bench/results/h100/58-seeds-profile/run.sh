#!/bin/bash
# Issue 12 item 4 at today's code: where the device time of a 16-seed epoch goes (GEMMs against fusions), to
# set beside the compiled step's bytes and flops (../../h200/57-step-cost). Code of 0f58ec2. Carried: .whl-jax.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
nvidia-smi -L > $R/gpus.txt
timeout 270 python3 -m bench.agent_profile --task AcrobotSwingup --reps sf2,none --seeds 16 --epochs 2 --hlo \
  --out $R/profile-16 > $R/profile-16.log 2>&1
rm -rf $R/profile-16/hlo
cd $OUT && tar czf results.tgz r && rm -rf r
