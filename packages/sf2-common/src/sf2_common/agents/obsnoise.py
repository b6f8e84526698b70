"""`PROG eval RUN --obs-noise STDS [--checkpoints N] [--save]`: a run's latest checkpoints evaluated with
Gaussian noise on the observations the policy sees (paper App. C.2.2). `--save` writes RUN/obs_noise.json
(a study's report reads it): {"settings": {"obs_noise", "checkpoints", "episodes", "deterministic"},
"results": [{"noise", "epoch", "env_steps", "deterministic", "returns": {seed: [...]}}]}."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable
from pathlib import Path

from sf2_common.errors import ConfigError
from sf2_common.fileio import atomic_write

from .lock import FolderLock

__all__ = ["OBS_NOISE", "parse_noise", "evaluate_obs_noise", "save", "eval_command"]

OBS_NOISE = "obs_noise.json"


def parse_noise(text: str) -> tuple[float, ...]:
    """'0,0.05,0.1' → (0.0, 0.05, 0.1); `ConfigError` unless every std is a number >= 0."""
    try:
        values = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        values = ()
    if not values or any(not 0 <= v < float("inf") for v in values):
        raise ConfigError(f"--obs-noise {text!r} is invalid: comma-separated noise stds >= 0, e.g. "
                          f"0,0.05,0.1")
    return values


def evaluate_obs_noise(evaluate_noises: Callable, run, noises, checkpoints: int = 1,
                       episodes: int | None = None, deterministic: bool | None = None,
                       log: Callable[[str], None] | None = None) -> dict:
    """The last `checkpoints` checkpoints of `run` (oldest first) at every std of `noises` by the core's
    `evaluate_checkpoint_noises` (`evaluate_noises`): obs_noise.json's content (module docstring)."""
    if not isinstance(checkpoints, int) or checkpoints < 1:
        raise ConfigError(f"--checkpoints {checkpoints!r} is invalid: an int >= 1")
    latest = evaluate_noises(run, None, episodes, deterministic, tuple(noises))
    available = sorted(latest[0]["checkpoints"])
    if len(available) < checkpoints:
        raise ConfigError(f"{run} holds {len(available)} checkpoint(s) ({available}), fewer than the "
                          f"{checkpoints} asked for; train with keep_checkpoints >= {checkpoints}")
    results = []
    for epoch in available[-checkpoints:]:
        batch = (latest if epoch == latest[0]["epoch"]
                 else evaluate_noises(run, epoch, episodes, deterministic, tuple(noises)))
        for noise, res in zip(noises, batch):
            results.append({"noise": noise, "epoch": res["epoch"], "env_steps": res["env_steps"],
                            "deterministic": res["deterministic"], "returns": res["returns"]})
            if log:
                means = [sum(r) / len(r) for r in res["returns"].values()]
                log(f"  epoch {res['epoch']:>4} ({res['env_steps']} env steps), noise {noise:g}: mean return "
                    f"over seeds {sum(means) / len(means):.1f}")
    return {"settings": {"obs_noise": list(noises), "checkpoints": checkpoints, "episodes": episodes,
                         "deterministic": deterministic}, "results": results}


def save(run, result: dict) -> Path:
    """Write `result` as RUN/obs_noise.json, a line per (noise, checkpoint), each return the shortest
    decimal of its float32 (docs/decisions/obs-noise.md); returns the path."""
    import numpy as np

    def short(values):
        return [float(str(x)) for x in np.asarray(values, dtype=np.float32)]

    lines = [json.dumps({**r, "returns": {seed: short(v) for seed, v in r["returns"].items()}},
                        separators=(",", ":")) for r in result["results"]]
    head = json.dumps({"settings": result["settings"]})[:-1]
    path = Path(run) / OBS_NOISE
    atomic_write(path, head + ', "results": [\n' + ",\n".join(lines) + "\n]}\n")
    return path


def eval_command(evaluate_noises: Callable, args, deterministic: bool | None) -> int:
    """`PROG eval RUN --obs-noise STDS [--checkpoints N] [--episodes E] [--save] [--json]`."""
    import numpy as np

    if args.epoch is not None:
        raise ConfigError("--epoch and --obs-noise do not go together: --checkpoints N evaluates the "
                          "latest N")
    noises = parse_noise(args.obs_noise)
    # --save writes into the run folder: one writer at a time (sf2_common.agents.lock)
    with FolderLock(args.run, "eval --save", create=False) if args.save else contextlib.nullcontext():
        result = evaluate_obs_noise(evaluate_noises, args.run, noises, args.checkpoints, args.episodes,
                                    deterministic, log=None if args.json else print)
        path = save(args.run, result) if args.save else None
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{args.run}: mean return over seeds and episodes under observation noise")
        print(f"{'noise std':>10} " + " ".join(f"{'epoch ' + str(e):>11}" for e in
                                                 dict.fromkeys(r["epoch"] for r in result["results"])))
        for noise in noises:
            cells = [np.mean([np.mean(v) for v in r["returns"].values()])
                     for r in result["results"] if r["noise"] == noise]
            print(f"{noise:>10g} " + " ".join(f"{c:>11.1f}" for c in cells))
    if path is not None and not args.json:
        print(f"wrote {path}")
    return 0
