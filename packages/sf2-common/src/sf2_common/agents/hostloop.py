"""The host loop of both trainers: `run_epochs` drives a framework's `Session` through the schedule in one
order (train → NaN guard → evaluate → rows → checkpoint) and writes the same rows, curve and progress bar
for both. A `BatchedEvaluation` session (JAX's off- and on-policy trainers) evaluates the epochs between two
checkpoints in one program, each from its own parameters and keys (docs/decisions/batched-evaluation.md)."""

from __future__ import annotations

import os
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterable
from typing import Protocol

import numpy as np

from ..errors import ConfigError
from .loggers import Sinks
from .runfolder import METRIC_NAME
from .runlog import library_log

__all__ = [
    "WALL_FIELDS", "DEADLINE_VARIABLE", "TrainingDiverged", "Session", "BatchedEvaluation", "run_epochs",
    "deadline_from_environment", "checkpoint_now", "diverged_message",
    "compact", "row_metrics", "make_row", "write_curve", "call_hook", "versions", "hardware", "cpu_model",
    "numerics_environment", "environment_text", "environment_line",
    "progress_bar", "NoBar", "run_title",
]

WALL_FIELDS = ("sps", "epoch_seconds", "eval_seconds", "walltime")  # differ between identical runs
DEADLINE_VARIABLE = "SF2_DEADLINE"   # Unix time by which the run may be killed (a GPU host's command limit)


class TrainingDiverged(RuntimeError):
    """A loss became NaN or inf; the run stopped before writing anything for that epoch."""


def diverged_message(first_bad: dict, sched, epoch: int, seeds, cfg, last_ckpt,
                     order=()) -> str | None:
    """The message naming the epoch's first non-finite loss (lowest SGD step, then `order`), or None.
    `first_bad[name][seed]`: the index (local actor step · `sched.sgd_steps_per_actor_step` + update) of
    the first non-finite value, or −1."""
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


def compact(value) -> float:
    """A number as a Python float; a float32 one as the shortest decimal that reads back as that float32.

    JSON writes a float's shortest float64 repr, up to 17 significant digits for a float32 value; this
    gives at most 9, with no loss: np.float32 of the row's value is the device's
    (docs/decisions/compact-metrics.md).

    Args:
      value: a number, NumPy scalar or 0-d array.

    Returns:
      The float.
    """
    v = np.asarray(value)
    return float(str(v[()])) if v.dtype == np.float32 else float(v)


def row_metrics(means: dict, s_i: int) -> dict:
    """Epoch means of the training metrics of seed `s_i` (none for an epoch that was all prefill), each
    `compact`."""
    row = {name: compact(np.asarray(v)[s_i]) for name, v in sorted(means.items())}
    row["sgd_steps"] = int(row["sgd_steps"])
    return row if row["sgd_steps"] else {"sgd_steps": 0}


def make_row(epoch, seed, env_steps, returns, metrics, sps, eval_seconds, walltime,
             epoch_seconds=None, eval_metrics=None) -> dict:
    """One metrics.jsonl row: the evaluation of `seed` after `epoch` and the epoch's training metrics;
    `eval_metrics(returns)`, when given, adds the evaluation's own ({name: float}); numbers `compact`."""
    own = eval_metrics(np.asarray(returns)) if eval_metrics else {}
    row = {"epoch": epoch, "seed": int(seed), "env_steps": int(env_steps),
           "eval_return": compact(np.mean(returns)), "eval_return_std": compact(np.std(returns)),
           **{name: compact(v) for name, v in own.items()},
           "eval_seconds": round(eval_seconds, 3), "walltime": round(walltime, 3), **metrics}
    if sps is not None:
        row["sps"] = round(sps, 1)
        row["epoch_seconds"] = round(epoch_seconds, 3)
    odd = [name for name in row if not METRIC_NAME.fullmatch(name)]
    if odd:   # a reader would take such a row for damage (`RunFolder.read_rows`)
        raise ConfigError(f"metric names must be identifiers (letters, digits, '_'), found {odd}: rename "
                          f"them in the loss's aux dict or the evaluation's metrics")
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
    """What a run trains on (config.json, train.log): its accelerators' model names ("NVIDIA H100 80GB
    HBM3", "2 x NVIDIA H200"), or "CPU (<model>)" without any."""
    counts = Counter(accelerators)   # in first-seen order
    if not counts:
        return f"CPU ({cpu_model()})"
    return ", ".join(name if n == 1 else f"{n} x {name}" for name, n in counts.items())


# Environment variables that change a run's numbers on a GPU without changing its config.
NUMERICS_ENV = ("XLA_FLAGS", "NVIDIA_TF32_OVERRIDE", "CUBLAS_WORKSPACE_CONFIG")


def numerics_environment(environ=None) -> dict:
    """{name: value} of the `NUMERICS_ENV` variables set in `environ` (default: this process's), which
    config.json keeps as "environment" (docs/decisions/gpu-determinism.md: XLA_FLAGS'
    `--xla_gpu_deterministic_ops`; TF32 in cuBLAS; torch's deterministic cuBLAS)."""
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
        """Episode returns (seeds, episodes) of the evaluation after epoch `epoch` (0: initial policy).
        A session may also offer `eval_metrics(returns) -> {name: float}` of one seed's (episodes,)
        returns: more columns of the evaluation's rows (e.g. the share of successful episodes)."""

    def save(self, epoch: int, env_steps: int) -> None:
        """Write checkpoint `epoch` (it may return before the files are complete and write them in the
        background; a session may then offer `write_seconds() -> float | None`: how long its last
        checkpoint took from `save` until complete on disk, which the deadline then uses)."""

    def loss_order(self) -> tuple[str, ...]:
        """The order the SGD step computes its losses in (ties of the NaN guard's report)."""

    def finish(self) -> None:
        """The run is complete: write the final parameters."""


class BatchedEvaluation(Protocol):
    """What a `Session` may offer besides, used when `cfg.checkpoint_every` > 1: several epochs' evaluations
    in one program (module docstring)."""

    def snapshot(self, epoch: int) -> None:
        """Keep a copy of what the evaluation after epoch `epoch` needs (the policy as it is now)."""

    def evaluate_many(self, epochs: list[int]) -> np.ndarray:
        """(len(epochs), seeds, episodes): per epoch, `Session.evaluate(epoch)`'s returns right after it
        trained (up to float rounding), from those epochs' snapshots, which it then drops."""


def deadline_from_environment() -> float | None:
    """The kill deadline in `SF2_DEADLINE`, if set.

    Returns:
      Unix seconds, or None where the variable is unset or empty.
    """
    text = os.environ.get(DEADLINE_VARIABLE, "").strip()
    if not text:
        return None
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"{DEADLINE_VARIABLE}={text!r} is invalid: must be a Unix time in seconds (e.g. "
                          f"$(( $(date +%s) + 540 ))), or unset") from None


def checkpoint_now(now: float, deadline: float | None, epoch_seconds: float, eval_seconds: float,
                   save_seconds: float) -> bool:
    """Whether to checkpoint the epoch just trained because the next checkpoint would come too late.

    The next one needs this epoch's evaluation and save, one more epoch, its evaluation and save:
    now + epoch_seconds + 2 · (eval_seconds + save_seconds) past the deadline means it would be killed
    first, and every epoch since the last checkpoint trained again.

    Args:
      now: the wall time (Unix seconds).
      deadline: the kill deadline (Unix seconds), or None (never).
      epoch_seconds, eval_seconds, save_seconds: what an epoch, its evaluation and a checkpoint last took.

    Returns:
      True to checkpoint now.
    """
    if deadline is None:
        return False
    return now + epoch_seconds + 2.0 * (eval_seconds + save_seconds) > deadline


def run_epochs(session: Session, *, cfg, sched, seeds, run, title: str, rows: list[dict], start: int,
               last: int | None, walltime: float = 0.0, progress: bool = True,
               hook: Callable[[str, int], None] | None = None, stop_after_epoch: int | None = None,
               plot: bool = True, log=(), deadline: float | None = None) -> list[dict]:
    """The host loop of both trainers, from epoch `start` (0: evaluate the initial policy and write
    checkpoint 0 first) to the schedule's end or `stop_after_epoch`. Per epoch: train → NaN guard
    (`TrainingDiverged`, nothing of the epoch written) → evaluate → append rows → `hook("rows")` →
    checkpoint (every `checkpoint_every` epochs, the last, `stop_after_epoch`) → `hook("checkpoint")` →
    curve; `hook("train"|"evaluate"|"save", epoch)` as each begins (nothing is written during those). A
    `BatchedEvaluation` session with `checkpoint_every` > 1 evaluates the epochs between checkpoints
    together ("evaluate", "rows" once per batch, with its last epoch). `rows`, `last` (the latest
    checkpoint) and `walltime` (spent so far) come from a resume; library logs go to train.log
    (`runlog`), and every row to the sinks `log` names (`loggers`) as `hook("rows")` begins. `deadline`
    (Unix seconds; default `SF2_DEADLINE`'s): an epoch is also checkpointed when the next checkpoint would
    come after it (`checkpoint_now`; a resumed process prices its evaluation from the run's rows until it
    has run one), so a kill at the deadline loses no trained epoch. Returns all rows."""
    deadline = deadline_from_environment() if deadline is None else deadline
    t_start = time.time() - walltime
    with library_log(run), Sinks(log, run, seeds, cfg, rows) as sinks:
        bar = progress_bar(progress, sched.total_env_steps, sched.env_steps_after(max(start - 1, 0)), title)
        try:
            return _run_epochs(session, bar, t_start, cfg=cfg, sched=sched, seeds=seeds, run=run, title=title,
                               rows=rows, start=start, last=last, hook=sinks.hook(hook),
                               stop_after_epoch=stop_after_epoch, plot=plot, deadline=deadline)
        finally:
            bar.close()


def _run_epochs(session, bar, t_start, *, cfg, sched, seeds, run, title, rows, start, last, hook,
                stop_after_epoch, plot, deadline) -> list[dict]:
    """The body of `run_epochs` (its docstring)."""
    cost = {"eval": 0.0, "save": 0.0}   # wall seconds of the last evaluation (per epoch) and checkpoint
    if start > 0:   # a resume: nothing measured in this process yet
        cost["eval"] = _resumed_eval_seconds(rows)
    if start == 0:  # evaluate the initial policy, checkpoint 0
        session.start()
        call_hook(hook, "evaluate", 0)
        t = time.time()
        returns = session.evaluate(0)
        cost["eval"] = time.time() - t
        new = [make_row(0, s, 0, returns[i], {}, None, time.time() - t, time.time() - t_start,
                        eval_metrics=getattr(session, "eval_metrics", None)) for i, s in enumerate(seeds)]
        run.append_rows(new)
        rows += new
        call_hook(hook, "rows", 0)
        call_hook(hook, "save", 0)
        t = time.time()
        session.save(0, 0)
        cost["save"] = time.time() - t
        last = 0
        call_hook(hook, "checkpoint", 0)
        bar.set_postfix_str(f"eval {returns.mean():.1f}")
        start = 1
    batched = cfg.checkpoint_every > 1 and hasattr(session, "evaluate_many")
    pending = []    # trained epochs not yet evaluated (batched): (epoch, means, sps, epoch seconds)
    shown = ""      # the progress bar's last evaluation
    drawn = None    # how many rows the curve written last holds (the last epoch's is the final curve)
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
        evaluations = cost["eval"] * (len(pending) + 1)     # this checkpoint's: the epochs not yet evaluated
        # a save that returns before its files are complete: the deadline needs the whole write
        written = getattr(session, "write_seconds", None)
        saving = max(cost["save"], (written() if written else None) or 0.0)
        if not save and checkpoint_now(time.time(), deadline, epoch_seconds, evaluations, saving):
            save = True
            print(f"checkpoint at epoch {epoch}: the next would come after {DEADLINE_VARIABLE}",
                  file=sys.stderr)
        if batched:
            session.snapshot(epoch)
        pending.append((epoch, means, sps, epoch_seconds))
        if save or not batched:
            t = time.time()
            returns = _evaluate(session, pending, batched, seeds=seeds, sched=sched, run=run, rows=rows,
                                t_start=t_start, hook=hook)
            cost["eval"] = (time.time() - t) / len(pending)
            pending = []
            shown = f", eval {returns.mean():.1f}"
            if save:
                call_hook(hook, "save", epoch)
                t = time.time()
                session.save(epoch, sched.env_steps_after(epoch))
                cost["save"] = time.time() - t
                last = epoch
                call_hook(hook, "checkpoint", epoch)
            if plot:
                write_curve(rows, run, title)
                drawn = len(rows)
        bar.update(sched.env_steps_per_epoch)
        bar.set_postfix_str(f"{sps:,.0f} steps/s{shown}")
        if stop_after_epoch is not None and epoch >= stop_after_epoch:
            break
    else:
        session.finish()
        if plot and drawn != len(rows):
            write_curve(rows, run, title)
    return rows


def _resumed_eval_seconds(rows: list[dict]) -> float:
    """What a resumed process prices an epoch's evaluation at until it has run one (`checkpoint_now`).

    A resumed process compiles its evaluation again, so the price is the largest `eval_seconds` the run's
    rows hold after epoch 0 (a batch's share included its compilation), or epoch 0's where no later row has
    one: dearer than the evaluations that follow, so its error checkpoints early (the save's price stays 0
    until one is measured: no row records it).

    Args:
      rows: the rows a resume keeps (up to its checkpoint).

    Returns:
      Wall seconds per epoch; 0.0 where no row has `eval_seconds`.
    """
    timed = [r for r in rows if r.get("eval_seconds") is not None]
    later = [r["eval_seconds"] for r in timed if r.get("epoch", 0) > 0]
    return float(max(later or [r["eval_seconds"] for r in timed] or [0.0]))


def _evaluate(session, done, batched: bool, *, seeds, sched, run, rows, t_start, hook) -> np.ndarray:
    """Evaluate the trained epochs `done` (batched: those since the last checkpoint, in one program) and
    append their rows, sharing the wall time equally; `hook("evaluate"|"rows", last epoch)`. Returns the
    last epoch's returns (seeds, episodes)."""
    epochs = [d[0] for d in done]
    call_hook(hook, "evaluate", epochs[-1])
    t = time.time()
    returns = session.evaluate_many(epochs) if batched else np.asarray(session.evaluate(epochs[-1]))[None]
    eval_seconds = (time.time() - t) / len(done)
    extra = getattr(session, "eval_metrics", None)
    new = [make_row(epoch, s, sched.env_steps_after(epoch), returns[k][i], row_metrics(means, i), sps,
                    eval_seconds, time.time() - t_start, epoch_seconds, extra)
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
