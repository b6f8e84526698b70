"""The framework-free half of both cores' `evaluate_checkpoint(_noises)` (`PROG eval`; observation noise:
paper App. C.2.2): which run, checkpoint and episodes, the checkpointer's lifetime, the result per std. A
core's `CheckpointEvaluator` supplies its checkpointer, restore and act. A user mistake is a `ConfigError`
or `FileNotFoundError` naming the folder and the valid choices; nothing in the folder is written."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sf2_common.errors import ConfigError

from .runfolder import RunFolder, framework_of

__all__ = ["EVAL_KEY_BASE", "RunEvaluation", "open_evaluation", "check_obs_noise", "CheckpointJob",
           "CheckpointEvaluator"]

# `eval` of checkpoint e draws its noise and fresh start states from the evaluation key of epoch
# EVAL_KEY_BASE + e; training's own evaluation of epoch e uses e, so `eval` never replays those draws.
EVAL_KEY_BASE = 10_000


def check_obs_noise(value) -> float:
    """The observation-noise std of an evaluation as a float; `ConfigError` unless a finite number >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < float("inf"):
        raise ConfigError(f"obs_noise = {value!r} is invalid: a noise std >= 0")
    return float(value)


@dataclass(frozen=True)
class RunEvaluation:
    """One evaluation request on one run folder: its `TrainConfig`, seeds and noise stds (in order)."""

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
        """One `evaluate_checkpoint` result per noise std, in order; `returns_per_noise[k][i]` holds seed
        i's episode returns under noise k."""
        return [{"epoch": epoch, "env_steps": meta.get("env_steps"),
                 "returns": {int(s): [float(x) for x in returns[i]] for i, s in enumerate(self.seeds)},
                 "deterministic": deterministic, "obs_noise": noise, "checkpoints": available}
                for noise, returns in zip(self.noises, returns_per_noise, strict=True)]


def open_evaluation(out, framework: str, config_class, noises=(0.0,)) -> RunEvaluation:
    """The run folder `out` as `framework` ("jax", "torch") evaluates it; `FileNotFoundError` if it is no
    run folder, `ConfigError` if another core trained it or a noise std is invalid."""
    checked = tuple(check_obs_noise(x) for x in noises)
    run = RunFolder(out)
    conf = run.read_config()
    if conf is None:
        raise FileNotFoundError(f"{out} is not a run folder (no {RunFolder.CONFIG})")
    if framework_of(conf) != framework:
        raise ConfigError(f"{out} was trained by sf2-{framework_of(conf)}; evaluate it with that CLI")
    return RunEvaluation(str(Path(out)), run, config_class.from_dict(conf["config"]), tuple(conf["seeds"]),
                         checked)


@dataclass(frozen=True)
class CheckpointJob:
    """One checkpoint to evaluate, as a core's `CheckpointEvaluator.restore` and `act` receive it."""

    cfg: Any                      # the run's TrainConfig
    eval_cfg: Any                 # the config to act with (`RunEvaluation.eval_config`)
    seeds: tuple[int, ...]
    epoch: int                    # the checkpoint
    episodes: int | None          # None: the run's own evaluation start states; else fresh ones per seed
    key: int                      # the evaluation key's epoch, EVAL_KEY_BASE + epoch
    noises: tuple[float, ...]     # observation-noise stds, validated, in order


@dataclass(frozen=True)
class CheckpointEvaluator:
    """A core's half of checkpoint evaluation; its methods are the core's `evaluate_checkpoint(_noises)`.
    `checkpointer(folder, keep)` opens the core's checkpointer (`all()`, `close()`; closed on every path),
    `restore(checkpointer, job)` returns (what acting needs, the checkpoint's meta), `act(restored, job)` one
    array of episode returns (seeds, episodes) per std of `job.noises`."""

    framework: str                                   # "jax" or "torch"
    config_class: type
    checkpointer: Callable[[Path, int], Any]
    restore: Callable[[Any, CheckpointJob], tuple[Any, dict]]
    act: Callable[[Any, CheckpointJob], Sequence]

    def evaluate_checkpoint(self, out, epoch: int | None = None, num_eval_envs: int | None = None,
                            deterministic: bool | None = None, obs_noise: float = 0.0) -> dict:
        """Evaluate one checkpoint of a run folder, the policy seeing Gaussian observation noise.

        Args:
          out: the run folder, trained by this core.
          epoch: the checkpoint to evaluate; None for the latest.
          num_eval_envs: episodes per seed; None (or the run's own `num_eval_envs`) replays the run's
            evaluation start states, another number acts on that many fresh start states.
          deterministic: act with the deterministic policy (True) or the acting one (False); None for the
            run's `deterministic_eval`.
          obs_noise: the std of the Gaussian noise added to every observation the policy sees (paper App.
            C.2.2); 0 is the training's own evaluation.

        Returns:
          {"epoch", "env_steps", "returns": {seed: [episode returns]}, "deterministic", "obs_noise",
          "checkpoints": the epochs of the folder's checkpoints}.

        Raises:
          FileNotFoundError: `out` is not a run folder, or has no checkpoint (`epoch`).
          ConfigError: another core trained `out`, `obs_noise` < 0, `num_eval_envs` is not an integer >= 1,
            or the checkpoint does not fit the run's program (`CheckpointMismatch`).
        """
        return self.evaluate_checkpoint_noises(out, epoch, num_eval_envs, deterministic, (obs_noise,))[0]

    def evaluate_checkpoint_noises(self, out, epoch: int | None = None, num_eval_envs: int | None = None,
                                   deterministic: bool | None = None, noises=(0.0,)) -> list[dict]:
        """Evaluate one checkpoint at several observation-noise stds from one restore of it (the checkpoint
        holds the whole training state, replay buffers included).

        Args:
          out, epoch, num_eval_envs, deterministic: as `evaluate_checkpoint`'s.
          noises: the observation-noise stds, each >= 0.

        Returns:
          One result per std of `noises`, in order, each as `evaluate_checkpoint`'s.

        Raises:
          FileNotFoundError, ConfigError: as `evaluate_checkpoint`.
        """
        ev = open_evaluation(out, self.framework, self.config_class, noises)
        with contextlib.closing(self.checkpointer(ev.run.checkpoint_dir, ev.cfg.keep_checkpoints)) as ckpt:
            available = ckpt.all()
            epoch = ev.checkpoint(available, epoch)
            job = CheckpointJob(cfg=ev.cfg, eval_cfg=ev.eval_config(deterministic), seeds=ev.seeds,
                                epoch=epoch, episodes=ev.episodes(num_eval_envs), key=EVAL_KEY_BASE + epoch,
                                noises=ev.noises)
            restored, meta = self.restore(ckpt, job)
        returns = self.act(restored, job)
        return ev.results(epoch, meta, returns, job.eval_cfg.deterministic_eval, available)
