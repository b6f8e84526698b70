"""The torch agents' `TrainConfig`: `sf2_common.agents.configs.TrainConfig` (the same fields, defaults,
presets, parsing and messages as the JAX agents') plus the torch-only run fields `device`, `compile` and
`cudagraphs` (at the end of the dataclass); their validation and resolution; `make_config` and `validate`
bound to this class and to the torch agents' representation registry. Everything else (parsing, seeds,
the schedule) is `sf2_common.agents.configs`.
"""

from __future__ import annotations

from dataclasses import dataclass

from sf2_common.agents import configs as _configs
from sf2_common.agents.configs import bad_field

__all__ = ["TrainConfig", "TORCH_FIELDS", "COMPILE_MODES", "make_config", "validate", "resolve_device",
           "resolve_compile", "resolve_cudagraphs"]

TORCH_FIELDS = ("device", "compile", "cudagraphs")
# "auto": compile on CUDA, eager on the CPU; "off"; or a torch.compile mode ("max-autotune-no-cudagraphs":
# Inductor's autotuned GEMMs, the trainer makes the CUDA graphs itself). docs/decisions/torch-compile-modes.md
COMPILE_MODES = ("auto", "off", "default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")


@dataclass(frozen=True)
class TrainConfig(_configs.TrainConfig):
    """One training run (all seeds share it): the shared fields, then where and how the SGD step runs.
    Frozen and hashable: it keys the program cache."""

    device: str = "auto"          # "auto" (cuda if available, else cpu), "cpu", "cuda", "cuda:1", ...
    compile: str = "auto"         # torch.compile of the SGD step: "auto", "off", or a torch.compile mode
    cudagraphs: str = "auto"      # CUDA graphs (StepGraph) of the SGD step, eval acting: auto/on/off


def make_config(preset: str, task: str, algo: str = "td3", representation: str = "sf2",
                overrides: dict | None = None) -> TrainConfig:
    """The `preset` for `task` with `overrides` (field → value, already typed or strings) applied.
    Raises `ConfigError` for an unknown preset, task or field; call `validate` for the rest."""
    return _configs.make_config(preset, task, algo, representation, overrides, config_class=TrainConfig)


def validate(cfg: TrainConfig, seeds=(0,)) -> TrainConfig:
    """Check everything that can be checked without building a program (the representation against the
    torch agents' registry, then the torch-only fields). Raises `ConfigError`."""
    from . import representations

    if cfg.algo == "crl":
        raise _configs.ConfigError("--algo crl (ant-goal, docs/crl.md) trains with sf2-jax's goal-conditioned"
                                   " trainer; the torch core has CRL's losses (sf2_torch.losses_crl), not its"
                                   " trainer: use sf2-jax")
    _configs.validate(cfg, seeds, representations.REGISTRY)
    _validate_torch_fields(cfg)
    return cfg


# ------------------------------------------------------------------------------------------- torch fields
def _validate_torch_fields(cfg: TrainConfig) -> None:
    import torch

    if cfg.compile not in COMPILE_MODES:
        bad_field("compile", cfg.compile, f"must be one of {', '.join(COMPILE_MODES)}")
    if cfg.cudagraphs not in ("auto", "on", "off"):
        bad_field("cudagraphs", cfg.cudagraphs, "must be one of auto, on, off")
    if not isinstance(cfg.device, str):
        bad_field("device", cfg.device, "must be a string such as auto, cpu, cuda, cuda:0")
    if cfg.device == "auto":
        return
    try:
        device = torch.device(cfg.device)
    except (RuntimeError, ValueError):
        bad_field("device", cfg.device, "must be auto, cpu, cuda or cuda:N")
    if device.type not in ("cpu", "cuda"):
        bad_field("device", cfg.device, "must be auto, cpu, cuda or cuda:N")
    if device.type == "cuda":
        if not torch.cuda.is_available():
            bad_field("device", cfg.device, "CUDA is not available on this machine (torch "
                 f"{torch.__version__}); use cpu or auto")
        if device.index is not None and device.index >= torch.cuda.device_count():
            bad_field("device", cfg.device, f"this machine has {torch.cuda.device_count()} CUDA device(s)")
    if cfg.cudagraphs == "on" and device.type != "cuda":
        bad_field("cudagraphs", cfg.cudagraphs, "CUDA graphs need a CUDA device (device = "
             f"{cfg.device!r}); use auto or off")


def resolve_device(cfg: TrainConfig):
    """The torch device of `cfg.device` ("auto": cuda if available, else cpu)."""
    import torch

    if cfg.device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(cfg.device)
    if device.type == "cuda" and device.index is None:
        device = torch.device("cuda", torch.cuda.current_device())
    return device


def resolve_compile(cfg: TrainConfig, device) -> str | None:
    """The torch.compile mode of the SGD step, or None for eager ("auto": compile on CUDA only)."""
    if cfg.compile == "off":
        return None
    if cfg.compile == "auto":
        return "default" if device.type == "cuda" else None
    return cfg.compile


def resolve_cudagraphs(cfg: TrainConfig, device) -> bool:
    """Whether the SGD step runs as CUDA graphs ("auto": on CUDA)."""
    if device.type != "cuda":
        return False
    return cfg.cudagraphs in ("auto", "on")
