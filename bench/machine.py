"""Description of the machine and software a run measured: CPU/GPU model, versions, precision."""

from __future__ import annotations

import datetime
import os
import platform
import re
import subprocess
import sys
from importlib import metadata

from sf2_common.agents.hostloop import cpu_model


def _version(name: str) -> str:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        mod = sys.modules.get(name)
        return getattr(mod, "__version__", "absent") if mod else "absent"


def _git_commit(root: str) -> str:
    try:
        out = subprocess.run(["git", "-C", root, "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, timeout=10)
        dirty = subprocess.run(["git", "-C", root, "status", "--porcelain", "--", "packages", "bench"],
                               capture_output=True, text=True, timeout=10)
        if out.returncode:
            return "unknown"
        return out.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def gpu_name() -> str:
    """Name the first GPU that torch or JAX sees.

    Returns:
        The device name, or "" without a GPU.
    """
    try:
        import torch

        if torch.cuda.is_available():
            return torch.cuda.get_device_name(0)
    except Exception:  # noqa: BLE001
        pass
    try:
        import jax

        devs = [d for d in jax.devices() if d.platform == "gpu"]
        if devs:
            return devs[0].device_kind
    except Exception:  # noqa: BLE001
        pass
    return ""


def _nvidia_smi() -> str:
    try:
        out = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,driver_version,memory.total,clocks.max.sm,power.limit",
             "--format=csv,noheader"], capture_output=True, text=True, timeout=20)
        return out.stdout.strip() if out.returncode == 0 else ""
    except (OSError, subprocess.SubprocessError):
        return ""


def default_name() -> str:
    """Name this machine for its results folder.

    Returns:
        An `h200`-style name on a GPU host, `cpu-<model>` otherwise.
    """
    gpu = gpu_name()
    name = gpu or "cpu-" + cpu_model()
    name = re.sub(r"^nvidia[ -]+", "", name.lower())
    name = re.sub(r"\(r\)|\(tm\)|processor|\d+-core", "", name)
    return re.sub(r"[^a-z0-9]+", "-", name).strip("-")[:40] or "machine"


ENV_PREFIXES = ("XLA_", "JAX_", "TF_", "CUDA_VISIBLE", "OMP_", "TORCH", "MKL_", "NVIDIA_TF32", "CUBLAS_",
                "SF2_")


def describe(root: str, command: str) -> dict:
    """Describe what a reader needs to place the numbers: hardware, versions, precision settings.

    Args:
        root: the repository root (its git commit is recorded, "+dirty" with local changes).
        command: the command line that measured.

    Returns:
        A JSON-serializable dict (machine.json).
    """
    info = {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "command": command,
        "git_commit": _git_commit(root),
        "host": platform.node(),
        "os": platform.platform(),
        "python": sys.version.split()[0],
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "gpu": gpu_name() or "none",
        "nvidia_smi": _nvidia_smi() or "n/a",
        "load_average": (", ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg")
                         else "n/a"),
        "versions": {n: _version(n) for n in ("jax", "jaxlib", "flax", "optax", "torch", "numpy")},
        # what can change the numbers: XLA and framework flags, TF32 and cuBLAS overrides, devices,
        # threads, and this project's own switches (SF2_SHARD_SEEDS: seeds sharded over the devices)
        "env": {k: v for k, v in os.environ.items() if k.startswith(ENV_PREFIXES)},
    }
    try:
        import jax

        info["jax_backend"] = jax.default_backend()
        info["jax_devices"] = [str(d) for d in jax.devices()]
        info["jax_default_matmul_precision"] = str(jax.config.jax_default_matmul_precision)
    except Exception:  # noqa: BLE001
        pass
    try:
        import torch

        info["torch_threads"] = torch.get_num_threads()
        info["torch_allow_tf32_matmul"] = bool(torch.backends.cuda.matmul.allow_tf32)
        info["torch_allow_tf32_cudnn"] = bool(torch.backends.cudnn.allow_tf32)
        info["torch_float32_matmul_precision"] = torch.get_float32_matmul_precision()
        info["torch_cuda"] = torch.version.cuda or "none"
    except Exception:  # noqa: BLE001
        pass
    return info
