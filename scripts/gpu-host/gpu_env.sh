# Sourced by the scripts that run on the lent GPU host (scripts/gpu-host/gpu_study.sh, scripts/gpu-host/gpu_scaling.sh):
# installs the carried wheels (.whl-jax, git-excluded; recipe in scripts/gpu-host/gpu_study.sh) once per host into
# /tmp/site and puts the packages' src/ folders on PYTHONPATH. The torch trainer also needs TorchRL and
# tensordict (4 MB): carry `.whl-torch` too (recipe in scripts/gpu-host/gpu_study.sh) and they are installed with them.
# One marker per wheel folder: a host that ran a study (.whl-jax only) and is then called with .whl-torch
# too installs the torch wheels then (one marker for both skipped them: 2026-11-25, "No module named
# 'tensordict'").
for wheels in .whl-jax .whl-torch; do
  if [ -d "$wheels" ] && [ ! -f "/tmp/site/.done$wheels" ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
      "$wheels"/*.whl || return 1
    touch "/tmp/site/.done$wheels"
  fi
done
export MUJOCO_GL=disable   # no rendering on the host: mujoco imports no GL backend (PyOpenGL is not carried)
export PYTHONPATH=/tmp/site:$PWD/packages/sf2-common/src:$PWD/packages/sf2-studies/src:$PWD/packages/sf2-core-jax/src:$PWD/packages/sf2-core-torch/src:$PWD/packages/sf2-baselines/src
# The baselines register their representations, sf2-studies its `study` command, as entry points: on
# PYTHONPATH alone they would not be found, so a dist-info folder carries each one's entry points (from its
# pyproject.toml).
python3 - <<'PY' || return 1
import pathlib, tomllib
for package in ("sf2-baselines", "sf2-studies", "sf2-core-jax", "sf2-core-torch"):
    project = tomllib.load(open(f"packages/{package}/pyproject.toml", "rb"))["project"]
    info = pathlib.Path(f"/tmp/site/{package.replace('-', '_')}-0+src.dist-info")
    info.mkdir(parents=True, exist_ok=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {package}\nVersion: 0+src\n")
    (info / "entry_points.txt").write_text("".join(
        f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in eps.items()) + "\n"
        for group, eps in project.get("entry-points", {}).items()))
PY
