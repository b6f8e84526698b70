# pgx's own MinAtar PPO example (examples/minatar-ppo/train.py, unmodified) beside ours, on the lent host.
# Usage (repo root): bash scripts/gpu-host/pgx-example/run.sh "GAMES" "SEEDS" SECONDS
#   e.g. "breakout asterix" "0 1 2 3 4" 500; train.py and its wheels in $PGX_EXAMPLE (default .pgx-example,
#   git-excluded; README.md here says how to fill it).
# Stand-ins: wandb (no-op: the example prints its logs), omegaconf (key=value parsing), distrax.Categorical
# (TFP does not import with this jax). A queue on the host's disk: several processes (one per GPU, each
# with its CUDA_VISIBLE_DEVICES) take (game, seed) jobs from it; a job done in an earlier command on the
# same host is skipped; none is started when less time is left than the longest job so far took (+10%).
# Every finished job's log so far comes back in $OUT/pgx-gpu<N>.tar.gz.
set -u
source scripts/gpu-host/gpu_env.sh || exit 1
source scripts/gpu-host/pgx-example/install.sh || exit 1
export PYTHONPATH=$PWD/scripts/gpu-host/pgx-example:/tmp/pgxsite:${PYTHONPATH:-}
deadline=$(( $(date +%s) + $3 ))
logs=/tmp/pgx-logs; claims=/tmp/pgx-claims/$(echo "$OUT" | md5sum | cut -c1-12)
mkdir -p "$logs" "$claims" "$OUT"
gpu=${CUDA_VISIBLE_DEVICES:-0}
for s in $2; do for g in $1; do
  job=$g-seed$s
  [ -f "$logs/$job.done" ] && continue
  mkdir "$claims/$job" 2>/dev/null || continue
  longest=$(cat "$logs"/*.wall 2>/dev/null | sort -n | tail -1); longest=${longest:-60}
  remaining=$(( deadline - $(date +%s) ))
  if [ "$remaining" -lt $(( longest * 11 / 10 )) ]; then rmdir "$claims/$job"; break; fi
  start=$(date +%s)
  timeout "$remaining" python3 "$example"/train.py env_name=minatar-$g seed=$s > "$logs/$job.log" 2> "$logs/$job.err"
  rc=$?; wall=$(( $(date +%s) - start ))
  echo "$g seed $s gpu $gpu host $(hostname) rc $rc wall $wall s" >> "$logs/times.txt"
  if [ "$rc" = 0 ]; then echo "$wall" > "$logs/$job.wall"; touch "$logs/$job.done"; fi
done; done
nvidia-smi --query-gpu=name --format=csv,noheader | head -1 > "$logs/gpu.txt"
cat "$logs/times.txt" 2>/dev/null
tar czf "$OUT/pgx-gpu${gpu//,/}.tar.gz" -C "$logs" .
