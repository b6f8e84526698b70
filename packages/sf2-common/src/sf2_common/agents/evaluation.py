"""Evaluating a run folder's checkpoint (`sf2-jax eval`, `sf2-torch eval`; observation noise: paper App.
C.2.2): the framework-free half of both trainers' `evaluate_checkpoint_noises` — which run, which
checkpoint, how many episodes, and the result each std gives. Restoring the checkpoint and acting are each
core's own (`sf2_jax.agents.trainer`, `sf2_torch.agents.trainer`).

Every user mistake here is a `ConfigError` or `FileNotFoundError` naming the folder and the valid choices
(the CLIs exit with status 2); nothing in the folder is written.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sf2_common.errors import ConfigError

from .runfolder import RunFolder, framework_of

__all__ = ["EVAL_KEY_BASE", "RunEvaluation", "open_evaluation", "check_obs_noise"]

# `eval` of checkpoint e draws its noise and fresh start states from the evaluation key of epoch
# EVAL_KEY_BASE + e; training's own evaluation of epoch e uses e, so `eval` never replays those draws.
EVAL_KEY_BASE = 10_000


def check_obs_noise(value) -> float:
    """The observation-noise std of an evaluation as a float; `ConfigError` unless a finite number >= 0
    (both trainers' `evaluate_checkpoint` call this)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < float("inf"):
        raise ConfigError(f"obs_noise = {value!r} is invalid: a noise std >= 0")
    return float(value)


@dataclass(frozen=True)
class RunEvaluation:
    """One evaluation request on one run folder: its config (`cfg`, the core's `TrainConfig`), seeds and
    the observation-noise stds (validated, in order)."""

    out: str
    run: RunFolder
    cfg: Any
    seeds: tuple[int, ...]
    noises: tuple[float, ...]

    def checkpoint(self, available: list[int], epoch: int | None) -> int:
        """The epoch to evaluate: `epoch`, or the latest of `available` when None."""
        if not available:
            raise FileNotFoundError(f"{self.out} has no checkpoint yet")
        if epoch is None:
            return max(available)
        if epoch not in available:
            raise FileNotFoundError(f"{self.out} has no checkpoint {epoch}; available: {available}")
        return epoch

    def episodes(self, num_eval_envs: int | None) -> int | None:
        """None to replay the run's own evaluation starts (`num_eval_envs` unset or the config's), else the
        number of fresh episodes per seed (an int >= 1)."""
        if num_eval_envs is None or num_eval_envs == self.cfg.num_eval_envs:
            return None
        if isinstance(num_eval_envs, bool) or not isinstance(num_eval_envs, int) or num_eval_envs < 1:
            raise ConfigError(f"episodes = {num_eval_envs!r} is invalid: must be an integer >= 1")
        return num_eval_envs

    def eval_config(self, deterministic: bool | None):
        """The config to act with: the run's, `deterministic_eval` replaced when `deterministic` is set."""
        return self.cfg if deterministic is None else self.cfg.replace(deterministic_eval=bool(deterministic))

    def results(self, epoch: int, meta: dict, returns_per_noise, deterministic: bool,
                available: list[int]) -> list[dict]:
        """One dict per noise std (in `noises`' order): {"epoch", "env_steps", "returns": {seed: [episode
        returns]}, "deterministic", "obs_noise", "checkpoints"}; `returns_per_noise[k][i]` holds seed i's
        episode returns under noise k."""
        return [{"epoch": epoch, "env_steps": meta.get("env_steps"),
                 "returns": {int(s): [float(x) for x in returns[i]] for i, s in enumerate(self.seeds)},
                 "deterministic": deterministic, "obs_noise": noise, "checkpoints": available}
                for noise, returns in zip(self.noises, returns_per_noise, strict=True)]


def open_evaluation(out, framework: str, config_class, noises=(0.0,)) -> RunEvaluation:
    """The run folder `out` as `framework` ("jax" or "torch") evaluates it; `FileNotFoundError` when it is
    not a run folder, `ConfigError` when another core trained it or a noise std is invalid."""
    checked = tuple(check_obs_noise(x) for x in noises)
    run = RunFolder(out)
    conf = run.read_config()
    if conf is None:
        raise FileNotFoundError(f"{out} is not a run folder (no {RunFolder.CONFIG})")
    if framework_of(conf) != framework:
        raise ConfigError(f"{out} was trained by sf2-{framework_of(conf)}; evaluate it with that CLI")
    return RunEvaluation(str(Path(out)), run, config_class.from_dict(conf["config"]), tuple(conf["seeds"]),
                         checked)
