#!/usr/bin/env bash
# Runs part of a study on the lent GPU host (see README "Studies") and brings back what a study folder
# keeps: every run's config.json, metrics.jsonl, train.log (and eval results), never checkpoints or
# parameters. One command there is at most 10 minutes and the host keeps its disk only while it stays
# held, so the study folder lives at /tmp/study-<name> on the host: a run cut by the time limit resumes
# from its last checkpoint in the next command on the same (still warm) host.
#
#   bash scripts/gpu_study.sh STUDY.toml SECONDS [study run options: --tasks ... --methods ... --seeds ...]
#
# Wheels: .whl-jax (git-excluded) = the output of ../shared/device/wheels.sh without TorchRL, plus
# pandas 2.3 (the host's pandas 3 breaks arch, rliable's dependency) and its pytz/tzdata/dateutil/six.
# The archive $OUT/<name>.tar.gz is a study folder (no checkpoints); merge it here with
#   sf2-jax study merge <name>.tar.gz --into results/<name>   then   sf2-jax study report results/<name>
set -uo pipefail
study=$1; limit=$2; shift 2
name=$(basename "$study" .toml)
folder=/tmp/study-$name
if [ ! -f /tmp/site/.done ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
    .whl-jax/*.whl || exit 1
  touch /tmp/site/.done
fi
export PYTHONPATH=/tmp/site:$PWD/packages/sf2-common/src:$PWD/packages/sf2-core-jax/src:$PWD/packages/sf2-baselines/src
# The baselines register their representations as entry points: on PYTHONPATH alone they would not be
# found, so a dist-info folder carries sf2-baselines' entry points (from its pyproject.toml).
python3 - <<'PY' || exit 1
import pathlib, tomllib
project = tomllib.load(open("packages/sf2-baselines/pyproject.toml", "rb"))["project"]
info = pathlib.Path("/tmp/site/sf2_baselines-0+src.dist-info")
info.mkdir(parents=True, exist_ok=True)
(info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: sf2-baselines\nVersion: 0+src\n")
(info / "entry_points.txt").write_text("".join(
    f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in eps.items()) + "\n"
    for group, eps in project["entry-points"].items()))
PY
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
start=$(date +%s)
timeout --signal=TERM "$limit" python3 -m sf2_jax.cli study run "$study" --out "$folder" --no-progress "$@"
rc=$?
echo "study run exit status $rc after $(( $(date +%s) - start )) s"
python3 -m sf2_jax.cli study run "$study" --out "$folder" --dry-run "$@" || true
mkdir -p "$OUT"
tar czf "$OUT/$name.tar.gz" -C "$folder" --exclude='checkpoints' --exclude='final' --exclude='damaged' \
  --exclude='*.npz' --exclude='.study-lock' .
exit $rc
