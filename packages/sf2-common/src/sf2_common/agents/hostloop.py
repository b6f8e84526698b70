"""The training host loop of both trainers, framework-free: `run_epochs` drives a framework's `Session`
(train an epoch, evaluate, save a checkpoint) through the schedule and writes the metric rows, the NaN
guard's message, the learning curve and the progress bar, so both cores run the same order per epoch
(train → NaN guard → evaluate → append rows → checkpoint) and write the same rows. A `BatchedEvaluation`
session (the JAX trainer) evaluates the epochs between two checkpoints in one program, each from its own
parameters and keys, its rows written before the checkpoint (docs/decisions/batched-evaluation.md)."""

from __future__ import annotations

import sys
import time
from collections import Counter
from collections.abc import Callable, Iterable
from typing import Protocol

import numpy as np

from .loggers import Sinks
from .runlog import library_log

__all__ = [
    "WALL_FIELDS", "TrainingDiverged", "Session", "BatchedEvaluation", "run_epochs", "diverged_message",
    "row_metrics", "make_row", "write_curve", "call_hook", "versions", "hardware", "cpu_model",
    "numerics_environment", "environment_text", "environment_line",
    "progress_bar", "NoBar", "run_title",
]

WALL_FIELDS = ("sps", "epoch_seconds", "eval_seconds", "walltime")  # differ between identical runs


class TrainingDiverged(RuntimeError):
    """A loss became NaN or inf; the run stopped before writing anything for that epoch."""


def diverged_message(first_bad: dict, sched, epoch: int, seeds, cfg, last_ckpt,
                     order=()) -> str | None:
    """The message naming the first non-finite loss of the epoch: lowest SGD step, then the order the
    SGD step computes them in (`order`), or None if every metric is finite. `first_bad[name][seed]` is
    the index (local actor step · SGD steps per actor step + update) of the first non-finite value, or −1
    (`sched.sgd_steps_per_actor_step`: grad_updates_per_step, or an on-policy update's SGD steps)."""
    G = sched.sgd_steps_per_actor_step
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


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo; else what `platform` knows)."""
    import platform

    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def hardware(accelerators: Iterable[str]) -> str:
    """What a run trains on, for config.json and train.log: the model names of the accelerators its program
    uses ("NVIDIA H100 80GB HBM3", "2 x NVIDIA H200"), or "CPU (<model>)" without any. Wall times and the
    study runner's forecasts are those of this hardware (results/fig7-td3/README.md, "Cost per run")."""
    counts = Counter(accelerators)   # in first-seen order
    if not counts:
        return f"CPU ({cpu_model()})"
    return ", ".join(name if n == 1 else f"{n} x {name}" for name, n in counts.items())


# Environment variables that change a run's numbers on a GPU without changing its config.
NUMERICS_ENV = ("XLA_FLAGS", "NVIDIA_TF32_OVERRIDE", "CUBLAS_WORKSPACE_CONFIG")


def numerics_environment(environ=None) -> dict:
    """{name: value} of the `NUMERICS_ENV` variables set (non-empty) in `environ` (default: this process's):
    XLA_FLAGS (`--xla_gpu_deterministic_ops=true` makes GPU runs repeat bit for bit and changes their
    numbers: docs/decisions/gpu-determinism.md), NVIDIA_TF32_OVERRIDE (TF32 in cuBLAS),
    CUBLAS_WORKSPACE_CONFIG (torch's deterministic cuBLAS). config.json keeps them as "environment", so a run
    folder says how it was trained, and train.log names them each session (`environment_line`)."""
    import os

    environ = os.environ if environ is None else environ
    return {name: environ[name] for name in NUMERICS_ENV if environ.get(name)}


def environment_text(env: dict) -> str:
    """`numerics_environment()`'s result in words, e.g. "XLA_FLAGS='...'" (train.log, study reports)."""
    return ", ".join(f"{k}={v!r}" for k, v in env.items()) if env else \
        "none of " + ", ".join(NUMERICS_ENV) + " set"


def environment_line(env: dict) -> str:
    """train.log's line for `numerics_environment()`'s result, e.g. "environment: XLA_FLAGS='...'"."""
    return "environment: " + environment_text(env)


class Session(Protocol):
    """What `run_epochs` needs of a framework: one run's programs and state, seeds and checkpointer."""

    def start(self) -> None:
        """Build the initial state (called once, only when the run does not resume)."""

    def train_epoch(self, epoch: int) -> tuple[dict, dict]:
        """Train epoch `epoch` (1-based): ({metric: (seeds,) host means, "sgd_steps": (seeds,)},
        {metric: (seeds,) index of the first non-finite value or −1}), as `diverged_message` reads them."""

    def evaluate(self, epoch: int) -> np.ndarray:
        """Episode returns (seeds, episodes) of the evaluation after epoch `epoch` (0: initial policy)."""

    def save(self, epoch: int, env_steps: int) -> None:
        """Write checkpoint `epoch`."""

    def loss_order(self) -> tuple[str, ...]:
        """The order the SGD step computes its losses in (ties of the NaN guard's report)."""

    def finish(self) -> None:
        """The run is complete: write the final parameters."""


class BatchedEvaluation(Protocol):
    """What a `Session` may offer besides: several epochs' evaluations in one program (module docstring).
    `run_epochs` uses it when the session has it and `cfg.checkpoint_every` > 1."""

    def snapshot(self, epoch: int) -> None:
        """Keep a copy of what the evaluation after epoch `epoch` needs (the policy as it is now)."""

    def evaluate_many(self, epochs: list[int]) -> np.ndarray:
        """Returns (len(epochs), seeds, episodes): for each epoch, the returns `Session.evaluate(epoch)`
        gives right after that epoch trained (up to float rounding of the batched program), from the
        snapshots of those epochs, which it then drops."""


def run_epochs(session: Session, *, cfg, sched, seeds, run, title: str, rows: list[dict], start: int,
               last: int | None, walltime: float = 0.0, progress: bool = True,
               hook: Callable[[str, int], None] | None = None, stop_after_epoch: int | None = None,
               plot: bool = True, log=()) -> list[dict]:
    """The host loop of both trainers, from epoch `start` (0: evaluate the initial policy and write
    checkpoint 0 first) to the end of the schedule or `stop_after_epoch`. Per epoch: train → NaN guard
    (`TrainingDiverged` before anything of the epoch is written) → evaluate → append rows → `hook("rows")`
    → checkpoint (every `checkpoint_every` epochs, the last and `stop_after_epoch`) → `hook("checkpoint")`
    → learning curve. `hook("train"|"evaluate"|"save", epoch)` is called as each of those begins (a kill
    there is a kill during it: nothing is written while an epoch trains or evaluates). With a
    `BatchedEvaluation` session and `checkpoint_every` > 1 the epochs between checkpoints are evaluated
    together before each checkpoint (module docstring): "evaluate" and "rows" are then called once per
    batch, with its last epoch. `rows` (the folder's rows so far) and `last` (the latest checkpoint) come
    from a resume; `walltime` is the wall time the run had already spent. What libraries log goes to the
    run's train.log (`sf2_common.agents.runlog`). `log` names the sinks (tensorboard, wandb) that get
    every row too, as `hook("rows")` begins (`sf2_common.agents.loggers`). Returns all rows."""
    t_start = time.time() - walltime
    with library_log(run), Sinks(log, run, seeds, cfg, rows) as sinks:
        bar = progress_bar(progress, sched.total_env_steps, sched.env_steps_after(max(start - 1, 0)), title)
        try:
            return _run_epochs(session, bar, t_start, cfg=cfg, sched=sched, seeds=seeds, run=run, title=title,
                               rows=rows, start=start, last=last, hook=sinks.hook(hook),
                               stop_after_epoch=stop_after_epoch, plot=plot)
        finally:
            bar.close()


def _run_epochs(session, bar, t_start, *, cfg, sched, seeds, run, title, rows, start, last, hook,
                stop_after_epoch, plot) -> list[dict]:
    """The body of `run_epochs` (its docstring)."""
    if start == 0:  # evaluate the initial policy, checkpoint 0
        session.start()
        call_hook(hook, "evaluate", 0)
        t = time.time()
        returns = session.evaluate(0)
        new = [make_row(0, s, 0, returns[i], {}, None, time.time() - t, time.time() - t_start)
               for i, s in enumerate(seeds)]
        run.append_rows(new)
        rows += new
        call_hook(hook, "rows", 0)
        call_hook(hook, "save", 0)
        session.save(0, 0)
        last = 0
        call_hook(hook, "checkpoint", 0)
        bar.set_postfix_str(f"eval {returns.mean():.1f}")
        start = 1
    batched = cfg.checkpoint_every > 1 and hasattr(session, "evaluate_many")
    pending = []    # trained epochs not yet evaluated (batched): (epoch, means, sps, epoch seconds)
    shown = ""      # the progress bar's last evaluation
    for epoch in range(start, sched.num_epochs + 1):
        call_hook(hook, "train", epoch)
        t0 = time.time()
        means, first_bad = session.train_epoch(epoch)
        epoch_seconds = time.time() - t0
        message = diverged_message(first_bad, sched, epoch, seeds, cfg, last, session.loss_order())
        if message:
            if pending:   # the good epochs' rows, as the per-epoch order would have written them
                _evaluate(session, pending, batched, seeds=seeds, sched=sched, run=run, rows=rows,
                          t_start=t_start, hook=hook)
            raise TrainingDiverged(message)
        sps = sched.env_steps_per_epoch / epoch_seconds
        save = epoch % cfg.checkpoint_every == 0 or epoch == sched.num_epochs or epoch == stop_after_epoch
        if batched:
            session.snapshot(epoch)
        pending.append((epoch, means, sps, epoch_seconds))
        if save or not batched:
            returns = _evaluate(session, pending, batched, seeds=seeds, sched=sched, run=run, rows=rows,
                                t_start=t_start, hook=hook)
            pending = []
            shown = f", eval {returns.mean():.1f}"
            if save:
                call_hook(hook, "save", epoch)
                session.save(epoch, sched.env_steps_after(epoch))
                last = epoch
                call_hook(hook, "checkpoint", epoch)
            if plot:
                write_curve(rows, run, title)
        bar.update(sched.env_steps_per_epoch)
        bar.set_postfix_str(f"{sps:,.0f} steps/s{shown}")
        if stop_after_epoch is not None and epoch >= stop_after_epoch:
            break
    else:
        session.finish()
        if plot:
            write_curve(rows, run, title)
    return rows


def _evaluate(session, done, batched: bool, *, seeds, sched, run, rows, t_start, hook) -> np.ndarray:
    """Evaluate the trained epochs `done` (one, or in batched mode those since the last checkpoint: one
    program, `BatchedEvaluation.evaluate_many`) and append their rows, each with an equal share of the
    evaluation's wall time. `hook("evaluate"|"rows", e)` with e the last of them. Returns the last
    epoch's returns (seeds, episodes)."""
    epochs = [d[0] for d in done]
    call_hook(hook, "evaluate", epochs[-1])
    t = time.time()
    returns = session.evaluate_many(epochs) if batched else np.asarray(session.evaluate(epochs[-1]))[None]
    eval_seconds = (time.time() - t) / len(done)
    new = [make_row(epoch, s, sched.env_steps_after(epoch), returns[k][i], row_metrics(means, i), sps,
                    eval_seconds, time.time() - t_start, epoch_seconds)
           for k, (epoch, means, sps, epoch_seconds) in enumerate(done) for i, s in enumerate(seeds)]
    run.append_rows(new)
    rows += new
    call_hook(hook, "rows", epochs[-1])
    return returns[-1]


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
