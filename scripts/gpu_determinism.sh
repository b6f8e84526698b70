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
#                         on the same host does.
#
#   bash scripts/gpu_determinism.sh [train options]
#   # default: --task AcrobotSwingup --algo td3 --repr sf2 --config paper --seeds 0-4 --set num_timesteps=200000
#
# Writes $OUT/determinism.tar.gz (the run folders without checkpoints, the logs, compare.md). On the CPU it
# shows identical runs throughout (checked 2026-11-25 with a `quick` config: the mechanics only).
set -uo pipefail
args=("$@")
if [ ${#args[@]} -eq 0 ]; then
  args=(--task AcrobotSwingup --algo td3 --repr sf2 --config paper --seeds 0-4 --set num_timesteps=200000)
fi
source scripts/gpu_env.sh || exit 1
out=/tmp/determinism; rm -rf "$out"; mkdir -p "$out"
flag=--xla_gpu_deterministic_ops=true
for run in default-1 default-2 deterministic-1 deterministic-2 cached-1 cached-2; do
  flags=${XLA_FLAGS:-}; cache=""
  case $run in deterministic-*) flags="$flags $flag" ;; cached-*) cache=$out/cache ;; esac
  start=$(date +%s.%N)
  XLA_FLAGS="$flags" python3 -m sf2_jax.cli train "${args[@]}" --out "$out/$run" --no-progress \
    --compile-cache "$cache" \
    > "$out/$run.log" 2>&1 || { echo "$run failed:"; tail -5 "$out/$run.log"; }
  echo "$run: $(python3 -c "print(f'{$(date +%s.%N) - $start:.1f}')") s (XLA_FLAGS='${flags# }', compilation cache '${cache}')" \
    | tee -a "$out/times.txt"
done
python3 - "$out" <<'PY' | tee "$out/compare.md"
import sys
from pathlib import Path

from sf2_common.agents.hostloop import WALL_FIELDS
from sf2_common.agents.runfolder import RunFolder

out = Path(sys.argv[1])


def learned(name):
    if not (out / name).is_dir():
        return {}
    rows = RunFolder(out / name).read_rows(strict=True)
    return {(r["epoch"], r["seed"]): {k: v for k, v in r.items() if k not in WALL_FIELDS} for r in rows}


print("# Determinism of GPU training runs (scripts/gpu_determinism.sh)\n")
print("Wall times (process start to end, compilation included):\n")
print("".join(f"- {line}\n" for line in (out / "times.txt").read_text().splitlines()))
for a, b in (("default-1", "default-2"), ("deterministic-1", "deterministic-2"), ("cached-1", "cached-2"),
             ("default-1", "deterministic-1")):
    x, y = learned(a), learned(b)
    if not x or not y:
        print(f"- {a} against {b}: not comparable, {a if not x else b} wrote no metrics (see its .log)")
        continue
    first = next(((k, f, x[k].get(f), y.get(k, {}).get(f)) for k in sorted(set(x) | set(y))
                  for f in sorted(set(x.get(k, {})) | set(y.get(k, {})))
                  if x.get(k, {}).get(f) != y.get(k, {}).get(f)), None)
    verdict = ("identical learned values ({} rows)".format(len(x)) if first is None else
               "differ; first at epoch {0[0]} seed {0[1]}: {1} {2!r} vs {3!r}".format(*first))
    print(f"- {a} against {b}: {verdict}")
PY
mkdir -p "$OUT"
tar czf "$OUT/determinism.tar.gz" -C "$out" --exclude=checkpoints --exclude=final --exclude='*.npz' \
  --exclude=cache .
