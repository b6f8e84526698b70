#!/usr/bin/env bash
# Are GPU training runs repeatable bit for bit, and what would it cost to make them so? Two runs of one config
# and seeds on GPUs differ from the first epoch on (results/fig7-td3/README.md, "reproducible in
# distribution": XLA picks its kernels by timing them in each process). This trains one config six times,
# each in its own process, on the lent GPU host, and prints per pair whether the learned values of
# metrics.jsonl are identical (else the first row that differs) and each run's wall time:
#   default-1, -2         as the studies run, but each compiling for itself (no compilation cache): what two
#                         hosts do;
#   deterministic-1, -2   the same with XLA_FLAGS=--xla_gpu_deterministic_ops=true (XLA's run-to-run
#                         determinism: no autotuning, deterministic reductions and scatters);
#   cached-1, -2          sharing one fresh persistent compilation cache (`train`'s default, per host): the
#                         second loads the first's compiled, autotuned program, as a run resumed or repeated
#                         on the same host does;
#   sharded               (named only) one run with the deterministic flag and SF2_SHARD_SEEDS=1, its seeds
#                         spread over two GPUs (Program.mesh), compared with deterministic-1 on one GPU: does
#                         the sharded program evaluate and learn as the one-device program does? The seeds
#                         must divide by two (e.g. --seeds 0-3); a run that did not shard says so.
#
#   bash scripts/gpu-host/gpu_determinism.sh [default] [deterministic] [cached] [sharded] [-- train options]
#   # pairs: the first three unless named; train options by default
#   #   --task AcrobotSwingup --algo td3 --repr sf2 --config paper --seeds 0-4 --set num_timesteps=100000
#
# Answered on H200s: the default pair differs from the first SGD epoch, the deterministic and the cached
# pairs are identical to the bit (docs/decisions/gpu-determinism.md).
#
# With two or more GPUs visible the two runs of the default and of the deterministic pair run at once, one
# per GPU (two hosts' worth; the cached pair stays one after the other on GPU 0, since the second reads the
# first's cache). A 200k-step run took 122–136 s on an H200 (2026-11-26), so six of them one after the
# other outlast a 10-minute command: that command was cut after four, before any verdict. Now each pair's
# verdict (compare.md) and $OUT/determinism.tar.gz (the run folders without checkpoints, the logs,
# compare.md) are written as soon as the pair ends, so a cut command keeps the pairs that finished. On the
# CPU it shows identical runs throughout (checked 2026-11-25 with a `quick` config: the mechanics only).
set -uo pipefail
pairs=()
while [ $# -gt 0 ] && [[ "$1" != -* ]]; do   # pair names first, then train options (after -- or as they come)
  case $1 in
    default|deterministic|cached|sharded) pairs+=("$1") ;;
    *) echo "gpu_determinism.sh: unknown pair '$1' (choose from: default, deterministic, cached, sharded; train options after --)" >&2
       exit 2 ;;
  esac
  shift
done
[ "${1:-}" = "--" ] && shift
[ ${#pairs[@]} -eq 0 ] && pairs=(default deterministic cached)
args=("$@")
if [ ${#args[@]} -eq 0 ]; then
  args=(--task AcrobotSwingup --algo td3 --repr sf2 --config paper --seeds 0-4 --set num_timesteps=100000)
fi
source scripts/gpu-host/gpu_env.sh || exit 1
out=/tmp/determinism; rm -rf "$out"; mkdir -p "$out" "$OUT"
flag=--xla_gpu_deterministic_ops=true
gpus=$(nvidia-smi -L 2>/dev/null | grep -c '^GPU ')
if [ -n "${CUDA_VISIBLE_DEVICES:-}" ]; then gpus=$(tr ',' '\n' <<< "$CUDA_VISIBLE_DEVICES" | grep -c .); fi
first_gpu=${CUDA_VISIBLE_DEVICES:-0}; first_gpu=${first_gpu%%,*}; second_gpu=$(cut -d, -f2 <<< "${CUDA_VISIBLE_DEVICES:-0,1}")

train() {  # train RUN [GPU]: one process, its wall time appended to times.txt
  local run=$1 flags=${XLA_FLAGS:-} cache="" start
  local shard=0
  case $run in deterministic-*) flags="$flags $flag" ;; cached-*) cache=$out/cache ;;
    sharded) flags="$flags $flag"; shard=1 ;; esac
  start=$(date +%s.%N)
  SF2_SHARD_SEEDS=$shard CUDA_VISIBLE_DEVICES=${2:-$first_gpu} XLA_FLAGS="$flags" python3 -m sf2_jax.cli train "${args[@]}" \
    --out "$out/$run" --no-progress --compile-cache "$cache" \
    > "$out/$run.log" 2>&1 || { echo "$run failed:"; tail -5 "$out/$run.log"; }
  echo "$run: $(python3 -c "print(f'{$(date +%s.%N) - $start:.1f}')") s (XLA_FLAGS='${flags# }', compilation cache '${cache}', GPU ${2:-$first_gpu})" \
    | tee -a "$out/times.txt"
}

compare() {  # the verdict of every pair whose runs both ended, then the archive
python3 - "$out" <<'PY' > "$out/compare.md"
import sys
from pathlib import Path

from sf2_common.agents.runfolder import RunFolder
from sf2_studies.merge import rows_difference

out = Path(sys.argv[1])
ended = {line.split(":")[0] for line in (out / "times.txt").read_text().splitlines()}


def rows(name):
    return RunFolder(out / name).read_rows(strict=True) if (out / name).is_dir() else []


print("# Determinism of GPU training runs (scripts/gpu-host/gpu_determinism.sh)\n")
print("Wall times (process start to end, compilation included):\n")
print("".join(f"- {line}\n" for line in (out / "times.txt").read_text().splitlines()))
for a, b in (("default-1", "default-2"), ("deterministic-1", "deterministic-2"), ("cached-1", "cached-2"),
             ("default-1", "deterministic-1"), ("deterministic-1", "sharded")):
    if a not in ended or b not in ended:
        print(f"- {a} against {b}: not run (yet)")
        continue
    if b == "sharded" and "note: this host has" in (out / "sharded.log").read_text():
        print(f"- {a} against {b}: not comparable, the sharded run used one device (see sharded.log)")
        continue
    x, y = rows(a), rows(b)
    if not x or not y:
        print(f"- {a} against {b}: not comparable, {a if not x else b} wrote no metrics (see its .log)")
        continue
    diff = rows_difference(x, y)   # the study merge's comparison: learned values before timing
    verdict = (f"identical learned values ({len(x)} rows)" if diff is None or diff.startswith("equal learned")
               else f"differ; first at {diff}")
    print(f"- {a} against {b}: {verdict}")
    if diff is not None and not diff.startswith("equal learned"):   # how far apart: the first and last evaluation
        ra, rb = ({(r["epoch"], r["seed"]): r.get("eval_return") for r in rs} for rs in (x, y))
        for epoch in sorted({e for e, _ in ra} & {e for e, _ in rb})[::-1][:1] + [0]:
            pairs = [(s, ra[(epoch, s)], rb[(epoch, s)]) for e, s in sorted(ra) if e == epoch and (e, s) in rb]
            print(f"  - eval_return at epoch {epoch}, seed: {a} / {b}: "
                  + "; ".join(f"{s}: {u:.4f} / {v:.4f}" for s, u, v in pairs if u is not None and v is not None))
PY
  grep -- "- .* against \|  - eval_return" "$out/compare.md"
  tar czf "$OUT/determinism.tar.gz" -C "$out" --exclude=checkpoints --exclude=final --exclude='*.npz' \
    --exclude=cache .
}

touch "$out/times.txt"
gpu() { tr ',' '\n' <<< "${CUDA_VISIBLE_DEVICES:-$(seq -s, 0 $((gpus - 1)))}" | sed -n "$1p"; }
for kind in "${pairs[@]}"; do
  if [ "$kind" = sharded ]; then
    [ "$gpus" -ge 2 ] || { echo "sharded: needs two GPUs, this host has $gpus"; continue; }
    # with four GPUs it ran beside the deterministic pair (below); else on the first two after it
    [ -f "$out/sharded.log" ] || train sharded "$(gpu 1),$(gpu 2)"
  elif [ "$kind" = deterministic ] && [ "$gpus" -ge 4 ] && [[ " ${pairs[*]} " == *" sharded "* ]]; then
    train "$kind-1" "$(gpu 1)" & train "$kind-2" "$(gpu 2)" & train sharded "$(gpu 3),$(gpu 4)"; wait
  elif [ "$kind" != cached ] && [ "$gpus" -ge 2 ]; then
    train "$kind-1" "$first_gpu" & train "$kind-2" "$second_gpu"; wait
  else   # the cached pair stays one after the other: the second reads the first's cache
    train "$kind-1"; train "$kind-2"
  fi
  echo "after the $kind pair:"; compare
done
