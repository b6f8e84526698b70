# MinAtar's speed table on the lent host: pgx's example (time_example.py: its update, imported unmodified,
# timed to a blocking call) and ours (bench.agent_throughput), on the same GPU, one after the other.
# Usage (repo root): bash scripts/gpu-host/pgx-example/speed.sh "GAMES" ITERS ["PARTS"]   e.g. breakout 6
#   ITERS updates of 4096 envs x 128 steps per case, the first holding the compilation (>= 2); PARTS any of
#   example (theirs), gate (our gate's arms, one seed), paper (the paper's arms, five seeds); default all
#   three. train.py and its wheels in $PGX_EXAMPLE (default .pgx-example), as for run.sh. EXAMPLE_SET
#   ("key=value ...") and OURS_SET ("--set k=v ...") shrink both sides for a smoke test on a CPU.
# Results: $OUT/minatar-speed-gpu<N>.tar.gz (the example's JSON lines, our throughput.md/csv, every log,
#   named by part and games; every earlier call's on this host and GPU too), packed again after each step
#   so that a lane stopped at its deadline returns what finished.
set -u
games=${1:-breakout asterix freeway seaquest space_invaders}
iters=${2:-6}
parts=${3:-example gate paper}
[ "$iters" -ge 2 ] 2>/dev/null || { echo "ITERS: $iters is not a number >= 2 (the first update compiles)"; exit 2; }
for g in $games; do
  case $g in breakout|asterix|freeway|seaquest|space_invaders) ;;
    *) echo "GAMES: $g unknown; valid: breakout, asterix, freeway, seaquest, space_invaders"; exit 2;; esac
done
for part in $parts; do
  case $part in example|gate|paper) ;; *) echo "PARTS: $part unknown; valid: example, gate, paper"; exit 2;; esac
done
source scripts/gpu-host/gpu_env.sh || exit 1
source scripts/gpu-host/pgx-example/install.sh || exit 1
gpu=${CUDA_VISIBLE_DEVICES:-0}
logs=/tmp/minatar-speed/gpu${gpu//,/}
tag=$(echo $games | tr ' ' '+')
mkdir -p "$logs" "$OUT"
pack() { tar czf "$OUT/minatar-speed-gpu${gpu//,/}.tar.gz" -C "$logs" .; }
# gpu_lanes.sh stops a lane at its deadline with TERM to its process group: pack what finished (agent_throughput
# writes its csv after each case) before the KILL that follows 5 s later
trap 'echo "stopped: packing what finished"; pack; exit 143' TERM
nvidia-smi --query-gpu=name --format=csv,noheader 2>/dev/null | head -1 > "$logs/gpu.txt"
# theirs: one seed per game (its own config: 4096 envs x 128 steps, 3 passes of 128 minibatches of 4096;
# no precision set, so JAX's default: TF32 matmuls on an H100/H200)
for g in $games; do
  [[ " $parts " == *" example "* ]] || break
  PYTHONPATH=$PWD/scripts/gpu-host/pgx-example:/tmp/pgxsite:$PYTHONPATH python3 scripts/gpu-host/pgx-example/time_example.py \
    --example "$example/train.py" --game "$g" --iters "$iters" --out "$logs/example-$g.json" ${EXAMPLE_SET:-} \
    > "$logs/example-$g.log" 2>&1
  echo "example $g exit status $?"; tail -n 1 "$logs/example-$g.log"; pack
done
# ours: --env-steps E with --epochs E is one update per timed epoch (agent_throughput rounds up to whole
# updates); its warm-up epoch is the first update, so ITERS updates in all, as theirs
tasks=$(printf 'minatar-%s,' $games)
epochs=$(( iters - 1 ))
ours() {
  local name=$1-$tag; shift
  python3 -m bench.agent_throughput --tasks "$tasks" --algos ppo --env-steps "$epochs" --epochs "$epochs" \
    --out "$logs/$name" "$@" ${OURS_SET:-} > "$logs/$name.log" 2>&1
  echo "ours ($name) exit status $?"; tail -n 2 "$logs/$name/throughput.csv" 2>/dev/null; pack
}
gate="--set critic=v --set discount=0.99 --set deterministic_eval=false --set num_eval_envs=100"
# the gate's arm (studies/minatar-sanity.toml, ppo-pgx) at one seed, TF32 (like for like) and fp32; then its
# second arm, pgx's shared torso and joint step (ppo-v-shared), at TF32
if [[ " $parts " == *" gate "* ]]; then
  ours gate-v --reps none --seeds 1 $gate --precisions tensorfloat32,highest
  ours gate-shared --reps none --seeds 1 $gate --set shared_torso=true --precisions tensorfloat32
fi
# the paper's arms (studies/fig10-minatar.toml: PPO-Q, SF² w/o AE, SF² w AE) at the study's five seeds per
# run, the paper preset's TF32
if [[ " $parts " == *" paper "* ]]; then
  ours paper --reps none,sf2,sf2-ae --seeds 5 --precisions tensorfloat32
fi
