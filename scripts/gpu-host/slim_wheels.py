"""Shrinks the GPU host's wheels so they travel with the working tree (the device tool carries 64 MiB in
all, this repository included): drops from the wheels in FOLDER what training never loads, in place.

    python scripts/gpu-host/slim_wheels.py .whl-jax

mujoco: `mujoco/experimental/` (15.7 MB compressed), `mujoco/testdata/`, the C headers and the filament
renderer's and the viewer's extension modules (2.5 MB; only `mujoco.mjrf` and `mujoco.viewer` import them,
and training imports neither: checked with a train and an eval that block them); mujoco-mjx:
`mujoco/mjx/test_data/` (6.5 MB); playground: the locomotion and manipulation robots' assets (7.6 MB; their
Python modules stay, as the registry imports them). The seven DM Control tasks of the studies load and step
with what is left (checked with Python 3.12, the host's); pip installs such a wheel (it writes its own
RECORD), stored LZMA-compressed where that is smaller (zip's method 14, which pip's zipfile reads).
"""

import sys
import zipfile
from pathlib import Path

DROP = {
    "mujoco-": lambda n: n.startswith(("mujoco/experimental/", "mujoco/testdata/", "mujoco/include/",
                                       "mujoco/_render_filament.", "mujoco/_simulate.")),
    "mujoco_mjx-": lambda n: n.startswith("mujoco/mjx/test_data/"),
    "playground-": lambda n: n.startswith(("mujoco_playground/_src/locomotion/",
                                           "mujoco_playground/_src/manipulation/")) and not n.endswith(".py"),
}


def slim(wheel: Path) -> tuple[int, int]:
    """Rewrites `wheel` without the files DROP names for it, every member LZMA-compressed.

    Args:
      wheel: a .whl file, rewritten in place when that drops files or makes it smaller.

    Returns:
      (files dropped, bytes saved).
    """
    drop = next((rule for prefix, rule in DROP.items() if wheel.name.startswith(prefix)), lambda n: False)
    before = wheel.stat().st_size
    tmp = wheel.with_suffix(".tmp")
    with zipfile.ZipFile(wheel) as zin, zipfile.ZipFile(tmp, "w") as zout:
        keep = [i for i in zin.infolist() if not drop(i.filename)]
        dropped = len(zin.infolist()) - len(keep)
        for info in keep:
            data = zin.read(info.filename)
            info.compress_type = zipfile.ZIP_LZMA
            zout.writestr(info, data)
    if dropped or tmp.stat().st_size < before:
        tmp.replace(wheel)
    else:
        tmp.unlink()
    return dropped, before - wheel.stat().st_size


if __name__ == "__main__":
    folder = Path(sys.argv[1] if len(sys.argv) > 1 else ".whl-jax")
    total = 0
    for wheel in sorted(folder.glob("*.whl")):
        n, saved = slim(wheel)
        total += saved
        if n:
            print(f"{wheel.name}: {n} files dropped, {wheel.stat().st_size / 2**20:.1f} MiB left")
    print(f"{folder}: {total / 2**20:.1f} MiB saved in all")
