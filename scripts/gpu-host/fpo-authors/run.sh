# FPO's speed on the lent host: the authors' own code (time_fpo.py, their flow_policy unmodified) and ours
# (bench.agent_throughput), on the same GPU, one after the other.
# Usage (repo root): bash scripts/gpu-host/fpo-authors/run.sh [ITERS]
#   their code and its wheel in $FPO_AUTHORS (default .fpo-authors, git-excluded; README.md here says how
#   to fill it). Results: $OUT/fpo-speed.tar.gz (their JSON line, our throughput.md/csv, both logs).
set -u
source scripts/gpu-host/gpu_env.sh || exit 1
authors=${FPO_AUTHORS:-.fpo-authors}
iters=${1:-6}
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/fposite "$authors"/wheels/*.whl || exit 1
logs=$(mktemp -d)
PYTHONPATH=$PWD/scripts/gpu-host/fpo-authors:$PWD/$authors/src:/tmp/fposite:$PYTHONPATH \
  python3 scripts/gpu-host/fpo-authors/time_fpo.py --env CheetahRun --iters "$iters" \
  --out "$logs/authors.json" > "$logs/authors.log" 2>&1
echo "authors' code exit status $?"; tail -n 3 "$logs/authors.log"
# ours: the gate's configuration at one seed (like for like: their learner runs at JAX's default, TF32 on
# this GPU, as the `paper` preset's; fp32 beside it), then both Q(λ) arms at the study's five seeds (TF32)
python3 -m bench.agent_throughput --tasks CheetahRun --algos fpo --reps none --seeds 1 --set critic=v \
  --precisions tensorfloat32,highest --env-steps 1966080 --epochs 2 --out "$logs/ours-v" > "$logs/ours-v.log" 2>&1
echo "ours (V, 1 seed) exit status $?"
python3 -m bench.agent_throughput --tasks CheetahRun --algos fpo --reps none,sf2 --seeds 5 \
  --precisions tensorfloat32 --env-steps 1966080 --epochs 2 --out "$logs/ours-q" > "$logs/ours-q.log" 2>&1
echo "ours (Q(λ) arms, 5 seeds) exit status $?"
mkdir -p "$OUT"
tar czf "$OUT/fpo-speed.tar.gz" -C "$logs" .
