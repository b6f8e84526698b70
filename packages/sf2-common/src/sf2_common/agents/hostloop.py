"""The framework-free pieces of the training host loop that `sf2_jax.agents.trainer` and
`sf2_torch.agents.trainer` share: metric rows, the NaN guard's message, the learning-curve PNG, the
progress bar, the run title and the package versions written into config.json.

Both trainers run the same order per epoch (train → NaN guard → evaluate → append rows → checkpoint), so
a run folder written by either has the same rows; only the programs that train and evaluate differ.
tqdm is imported only when a progress bar is shown.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable

import numpy as np

__all__ = [
    "WALL_FIELDS", "TrainingDiverged", "diverged_message", "row_metrics", "make_row", "write_curve",
    "call_hook", "versions", "progress_bar", "NoBar", "run_title",
]

WALL_FIELDS = ("sps", "epoch_seconds", "eval_seconds", "walltime")  # differ between identical runs


class TrainingDiverged(RuntimeError):
    """A loss became NaN or inf; the run stopped before writing anything for that epoch."""


def diverged_message(first_bad: dict, sched, epoch: int, seeds, cfg, last_ckpt,
                     order=()) -> str | None:
    """The message naming the first non-finite loss of the epoch: lowest SGD step, then the order the
    SGD step computes them in (`order`), or None if every metric is finite. `first_bad[name][seed]` is
    the index (local actor step · grad_updates_per_step + update) of the first non-finite value, or −1."""
    G = cfg.grad_updates_per_step
    rank = {name: i for i, name in enumerate(order)}
    problems = []
    for name, idx in first_bad.items():
        for s_i, i in enumerate(np.asarray(idx)):
            if i >= 0:
                local, update = divmod(int(i), G)
                actor_step = (epoch - 1) * sched.actor_steps_per_epoch + local
                grad_step = sched.grad_steps_before(actor_step) * G + update
                env_step = (actor_step + 1) * sched.env_steps_per_actor_step
                problems.append((grad_step, rank.get(name, len(rank)), name, seeds[s_i], env_step))
    if not problems:
        return None
    problems.sort()
    g, _, name, seed, env_step = problems[0]
    others = sorted({f"{n} (seed {s})" for _, _, n, s, _ in problems[1:]})
    also = f"; also non-finite in the same epoch: {', '.join(others)}" if others else ""
    keep = (f"the last good checkpoint (epoch {last_ckpt}) is kept" if last_ckpt is not None
            else "no checkpoint was written yet")
    return (f"training diverged: loss '{name}' became NaN/inf at gradient step {g} (env step {env_step}, "
            f"epoch {epoch}, seed {seed}){also}. Nothing of epoch {epoch} was written; {keep}.")


def row_metrics(means: dict, s_i: int) -> dict:
    """Epoch means of the training metrics of seed `s_i` (none for an epoch that was all prefill)."""
    row = {name: float(np.asarray(v)[s_i]) for name, v in sorted(means.items())}
    row["sgd_steps"] = int(row["sgd_steps"])
    return row if row["sgd_steps"] else {"sgd_steps": 0}


def make_row(epoch, seed, env_steps, returns, metrics, sps, eval_seconds, walltime,
             epoch_seconds=None) -> dict:
    """One metrics.jsonl row: the evaluation of `seed` after `epoch` and the epoch's training metrics."""
    row = {"epoch": epoch, "seed": int(seed), "env_steps": int(env_steps),
           "eval_return": float(np.mean(returns)), "eval_return_std": float(np.std(returns)),
           "eval_seconds": round(eval_seconds, 3), "walltime": round(walltime, 3), **metrics}
    if sps is not None:
        row["sps"] = round(sps, 1)
        row["epoch_seconds"] = round(epoch_seconds, 3)
    return row


def run_title(label: str, task: str, seeds) -> str:
    """'TD3+SF² on CartpoleBalance (4 seeds)': the progress bar's and the curve's title."""
    return f"{label} on {task} ({len(seeds)} seed{'s' if len(seeds) > 1 else ''})"


def write_curve(rows, run, title) -> None:
    """The run folder's learning_curve.png; a failure is a warning, never the end of training."""
    try:
        from .plotting import plot_learning_curve

        plot_learning_curve(rows, run.curve_path, title)
    except Exception as err:  # a plot must never stop training
        print(f"warning: could not write {run.curve_path}: {err}", file=sys.stderr)


def call_hook(hook: Callable[[str, int], None] | None, event: str, epoch: int) -> None:
    if hook is not None:
        hook(event, epoch)


def versions(dists: Iterable[str]) -> dict:
    """{distribution: version} of those of `dists` that are installed (written into config.json)."""
    from importlib import metadata

    out = {}
    for dist in dists:
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


class NoBar:
    """The progress bar's interface, doing nothing (`--no-progress`)."""

    def update(self, n):
        pass

    def set_postfix_str(self, s):
        pass

    def close(self):
        pass


def progress_bar(enabled: bool, total: int, initial: int, title: str):
    """A tqdm bar over env steps on stderr, or a `NoBar`."""
    if not enabled:
        return NoBar()
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=title, unit="step", unit_scale=True, dynamic_ncols=True,
                file=sys.stderr, smoothing=0.3)
