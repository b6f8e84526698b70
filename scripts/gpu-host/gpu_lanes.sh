#!/usr/bin/env bash
# Runs several commands at once on one lent host, each on its own GPUs (a "lane"), and waits for all of
# them: e.g. two studies and a measurement on a four-GPU host in one command. Each lane is "GPUS: COMMAND";
# the command runs under `bash -c` with CUDA_VISIBLE_DEVICES=GPUS and can read `left` (seconds to the
# deadline, SECONDS after this script starts) to size its own limit; a lane still running 10 s before the
# deadline is stopped (exit status 124 in its log). Each lane's output comes back in
# $OUT/lanes.tar.gz; what a lane writes to $OUT itself (gpu_study.sh's archive) comes back as it is.
#
#   bash scripts/gpu-host/gpu_lanes.sh SECONDS "0,1: bash scripts/gpu-host/gpu_study.sh studies/own-adam.toml \$(( \$(left) - 30 ))" \
#                                              "2: bash scripts/gpu-host/gpu_study.sh studies/fpo-gate.toml \$(( \$(left) - 30 ))"
# (30 s for gpu_study.sh's archive, then its listing, after its own limit, before the lane's stop)
# Wheels are installed once, before the lanes start (two lanes installing into /tmp/site at once would race).
set -uo pipefail
limit=$1; shift
source scripts/gpu-host/gpu_env.sh || exit 1
export SF2_DEADLINE=$(( $(date +%s) + limit ))
left() { echo $(( SF2_DEADLINE - $(date +%s) )); }
export -f left
mkdir -p "$OUT"
logs=$(mktemp -d)
# Lanes that share a GPU (a one-GPU host: "0: A" "0: B") split its memory: JAX takes 75% of it by default,
# so a second process on the GPU would fail to allocate; each gets 0.9 / (most lanes on one GPU).
share=$(for lane in "$@"; do echo "${lane%%:*}" | tr ',' '\n'; done | sort | uniq -c | sort -rn | awk 'NR==1{print $1}')
if [ "${share:-1}" -gt 1 ]; then
  export XLA_PYTHON_CLIENT_MEM_FRACTION=$(python3 -c "print(round(0.9 / $share, 2))")
  echo "lanes share GPUs (up to $share on one): XLA_PYTHON_CLIENT_MEM_FRACTION=$XLA_PYTHON_CLIENT_MEM_FRACTION"
fi
nvidia-smi --query-gpu=index,name,memory.total --format=csv,noheader > "$logs/gpus.txt"
i=0
for lane in "$@"; do
  gpus=${lane%%:*}; cmd=${lane#*:}
  (
    start=$(date +%s)
    echo "lane $i on GPUs $gpus: $cmd"
    # a lane still running at the deadline is stopped 10 s before it, so that every lane's log and what
    # the lanes wrote under $OUT come back (the device tool returns nothing of a command it kills)
    CUDA_VISIBLE_DEVICES=$gpus timeout --signal=TERM --kill-after=5 $(( $(left) > 11 ? $(left) - 10 : 1 )) bash -c "$cmd"
    echo "lane $i exit status $? after $(( $(date +%s) - start )) s"
  ) > "$logs/lane$i.log" 2>&1 &
  i=$((i + 1))
done
wait
for f in "$logs"/lane*.log; do echo "== $f"; tail -n 6 "$f"; done
tar czf "$OUT/lanes.tar.gz" -C "$logs" .
