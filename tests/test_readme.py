"""The README's Python blocks run as written, each in a fresh interpreter (as a user pastes them: no x64,
no fixtures), in an empty folder; each must end with a finite `loss` and the aux keys of `flow_loss`."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
CHECK = "\nimport math\nassert math.isfinite(float(loss)) and sorted(aux) == ['loss_boot', 'loss_p'], aux\n"


def test_readme_has_a_block_per_core():
    assert [b.splitlines()[0].split("#")[0].strip() for b in BLOCKS] == [
        "import jax, numpy as np, sf2_jax", "import torch, sf2_torch"]


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_block_runs(tmp_path, index):
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_ENABLE")} | {"JAX_PLATFORMS": "cpu"}
    done = subprocess.run([sys.executable, "-c", BLOCKS[index] + CHECK], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "params.npz").exists()
