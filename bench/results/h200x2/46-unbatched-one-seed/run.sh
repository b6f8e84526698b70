#!/bin/bash
# Issue 12 item 6: the one-seed programs without the vmap (trainer._seed_map; the working tree had
# bench/results/h100x4/43-sharded-profile/unbatched-one-seed.patch applied to 9ade605, with get_program's
# lru_cache kept on get_program) against 9ade605 itself (old/, `git archive HEAD packages/sf2-core-jax/src`).
# Two GPUs, one job each; every throughput pair on one GPU, one after the other, in opposite orders.
source scripts/gpu_env.sh || exit 1
R=$OUT/r; mkdir -p $R
OLD=$PWD/old/packages/sf2-core-jax/src
T="python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2,none --env-steps 24000 --epochs 4 --seeds 1"
P="python3 -m bench.agent_profile --task AcrobotSwingup --reps sf2 --epochs 2"
nvidia-smi -L > $R/gpus.txt
stamp() { echo "$(date +%s) $*" >> $R/times.txt; }
case ${1:-first} in
  first)
    # GPU 0: TF32, old then new; then the new code's profile at 1 and 2 seeds with its kernels per phase
    (export CUDA_VISIBLE_DEVICES=0
     stamp start0
     PYTHONPATH=$OLD:$PYTHONPATH timeout 150 $T --precisions tensorfloat32 --out $R/old-tf32-a > $R/old-tf32-a.log 2>&1; stamp old-tf32-a
     timeout 150 $T --precisions tensorfloat32 --out $R/new-tf32-a > $R/new-tf32-a.log 2>&1; stamp new-tf32-a
     timeout 240 $P --seeds 1,2 --hlo --out $R/profile-new > $R/profile-new.log 2>&1; stamp profile-new) &
    # GPU 1: TF32, new then old; then fp32, old then new
    (export CUDA_VISIBLE_DEVICES=1
     stamp start1
     timeout 150 $T --precisions tensorfloat32 --out $R/new-tf32-b > $R/new-tf32-b.log 2>&1; stamp new-tf32-b
     PYTHONPATH=$OLD:$PYTHONPATH timeout 150 $T --precisions tensorfloat32 --out $R/old-tf32-b > $R/old-tf32-b.log 2>&1; stamp old-tf32-b
     PYTHONPATH=$OLD:$PYTHONPATH timeout 120 $T --precisions highest --out $R/old-fp32 > $R/old-fp32.log 2>&1; stamp old-fp32
     timeout 120 $T --precisions highest --out $R/new-fp32 > $R/new-fp32.log 2>&1; stamp new-fp32) &
    ;;
  second)
    # (the first call's profile found no module named *epoch_one*: the unvmapped program was compiled as
    # `one`; _seed_map now keeps fn's name with functools.wraps)
    # GPU 0: the new code's profile at 1 and 2 seeds with its kernels per phase; the old code's at 1 seed
    (export CUDA_VISIBLE_DEVICES=0
     stamp start0
     timeout 300 $P --seeds 1,2 --hlo --out $R/profile-new > $R/profile-new.log 2>&1; stamp profile-new
     PYTHONPATH=$OLD:$PYTHONPATH timeout 200 $P --seeds 1 --out $R/profile-old > $R/profile-old.log 2>&1; stamp profile-old) &
    # GPU 1: the one-seed benchmark (JAX and torch, fp32 and TF32, one process) at the new code; then
    # TD3 at fp32, new then old
    (export CUDA_VISIBLE_DEVICES=1
     stamp start1
     timeout 300 python3 -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps sf2 --seeds 1 \
       --precisions highest,tensorfloat32 --frameworks jax,torch --env-steps 24000 --epochs 4 \
       --out $R/acro-torch > $R/acro-torch.log 2>&1; stamp acro-torch
     timeout 110 ${T/sf2,none/none} --precisions highest --out $R/new-fp32-td3 > $R/new-fp32-td3.log 2>&1; stamp new-fp32-td3
     PYTHONPATH=$OLD:$PYTHONPATH timeout 110 ${T/sf2,none/none} --precisions highest --out $R/old-fp32-td3 > $R/old-fp32-td3.log 2>&1; stamp old-fp32-td3) &
    ;;
esac
wait
cd $OUT && tar czf results.tgz r && rm -rf r
