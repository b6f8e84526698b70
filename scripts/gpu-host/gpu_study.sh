#!/usr/bin/env bash
# Runs part of a study on the lent GPU host (see README "Studies") and brings back what a study folder
# keeps: every run's config.json, metrics.jsonl, train.log (and eval results), never checkpoints or
# parameters. One command there is at most 10 minutes and the host keeps its disk only while it stays
# held, so the study folder lives at /tmp/study-<name> on the host: a run cut by the time limit resumes
# from its last checkpoint in the next command on the same (still warm) host.
#
#   bash scripts/gpu-host/gpu_study.sh STUDY.toml SECONDS [study run options: --tasks ... --methods ... --seeds ...]
#
# On a lease's last command add `--finish-within <about 0.7 x the seconds the lease has left>`: runs
# forecast to end later are not started (their checkpoints would go back with the host); a run can take up
# to ~1.4x its forecast (`python -m bench.lab.forecast_check`, results/fig7-sac/README.md "Cost per run"; once a
# study has most of its runs, `--leave-one-out` there shows how its next forecasts fare: fig7-sac's 77 runs,
# one per GPU, took 0.44-0.93x theirs).
# A study with no finished run of its own (fig7-sac at first) forecasts from another's: `--forecast-from results/fig7-td3` (it travels with the repo).
#
# Wheels: .whl-jax (git-excluded), what the host's image lacks for training and evaluation, nothing more:
#   bash ../shared/device/wheels.sh .whl-jax pgx==2.6.0 svgwrite \
#     && rm .whl-jax/{torchrl,tensordict,rliable,arch,pyopengl,flask,flask_cors,mediapy,tensorboardx}-* \
#     && python3 scripts/gpu-host/slim_wheels.py .whl-jax
# (pgx and svgwrite, which pgx imports, for the MinAtar tasks: 0.3 MB)
# For the torch trainer (e.g. `bench.agent_throughput --frameworks torch,jax`) keep TorchRL and tensordict
# apart and carry both folders (`carry: [".whl-jax", ".whl-torch"]`; scripts/gpu-host/gpu_env.sh installs both):
#   python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 -d .whl-torch torchrl==0.14.1 tensordict==0.14.3 \
#     && python3 scripts/gpu-host/slim_wheels.py .whl-torch
# This repository (its results/ included) and the wheels travel within 64 MiB. Statistics stay here: without
# rliable (and arch, and the pandas < 3 it needs: 14 MB) `train`'s final table and learning_curve.png have
# means and no interval (a warning says so), and reports are made here from the archive. PyOpenGL, Flask,
# mediapy and tensorboardX serve rendering and Brax's viewer only (gpu_env.sh sets MUJOCO_GL=disable): a
# CPU train and eval with them blocked run as before (2026-11-25).
# The archive $OUT/<name>.tar.gz is a study folder (no checkpoints); merge it here with
#   sf2-jax study merge <name>.tar.gz --into results/<name>   then   sf2-jax study report results/<name>
# <name> is the study file's name, or with STUDY_RESULTS=results/<folder> that folder's (a study file run
# into a second folder, e.g. fig7-sac.toml into results/fig7-sac-eps1e-8).
set -uo pipefail
study=$1; limit=$2; shift 2
results=${STUDY_RESULTS:-results/$(basename "$study" .toml)}
name=$(basename "$results")
# A lane's later study may be left too little of the command (`$(( $(left) - 30 ))` at or below zero made
# `timeout` refuse it and tar find no folder): say so and start nothing; what an earlier command of the
# held host left in /tmp/study-<name> stays there for the next
if ! [[ "$limit" =~ ^-?[0-9]+$ ]]; then
  echo "gpu_study.sh: SECONDS must be a whole number of seconds, not '$limit'" >&2
  exit 2
fi
if [ "$limit" -lt 60 ]; then
  echo "gpu_study.sh: $limit s left for $name: under 60 s, not started (nothing archived)"
  exit 0
fi
folder=/tmp/study-$name
source scripts/gpu-host/gpu_env.sh || exit 1
# A new host starts from the runs this repository already holds (results/<name>), so finished runs are
# not run again; the merge of the archive back into results/<name> skips them as identical.
# The first line says which: a fresh host where the previous command's host was meant to be kept (a lease
# that went back between calls) means that command's unfinished runs start again here.
if [ ! -d "$folder" ]; then
  echo "host $(hostname): fresh (no $folder); runs start from $results's finished ones"
  if [ -d "$results/runs" ]; then
    cp -r "$results" "$folder"
    # runs it reads in another study folder (`study borrow`): named from the copy's place
    python3 -c "import sys; from sf2_studies.folder import StudyFolder as F; F(sys.argv[1]).rebase(sys.argv[2])" \
      "$folder" "$results" || exit 2
  fi
else
  echo "host $(hostname): kept from an earlier command ($folder is here; its unfinished runs resume)"
fi
# A study run into a second folder (STUDY_RESULTS) also forecasts from the study's own folder, whose other
# arms and seeds have run on its tasks, unless the command names --forecast-from itself; and it does not
# run again what that folder holds finished with exactly the same config and seeds (--skip-done-in: a
# run that kept a superseded preset value there, as fig7-sac's, is another config and runs here)
own=results/$(basename "$study" .toml)
forecast=()
if [ "$results" != "$own" ] && [ -d "$own/runs" ]; then
  if [[ " $* " != *" --forecast-from "* ]]; then forecast+=(--forecast-from "$own"); fi
  if [[ " $* " != *" --skip-done-in "* ]]; then forecast+=(--skip-done-in "$own"); fi
fi
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
start=$(date +%s)
# the trainers checkpoint the last epoch that ends before the kill (sf2_common.agents.hostloop.checkpoint_now)
export SF2_DEADLINE=$(( start + limit ))
timeout --signal=TERM "$limit" python3 -m sf2_jax.cli study run "$study" --out "$folder" --no-progress "$@" ${forecast[@]+"${forecast[@]}"}
rc=$?
echo "study run exit status $rc after $(( $(date +%s) - start )) s"
# The archive first, then the listing of what is left: a lane stopped during the listing (fig7-sac's takes
# seconds to check its tasks and forecast) still brings back every run that finished
mkdir -p "$OUT"
tar czf "$OUT/$name.tar.gz" -C "$folder" --exclude='checkpoints' --exclude='final' --exclude='damaged' \
  --exclude='*.npz' --exclude='.study-lock' --exclude='.sf2-lock' .
timeout 60 python3 -m sf2_jax.cli study run "$study" --out "$folder" --dry-run "$@" ${forecast[@]+"${forecast[@]}"} || true
exit $rc
