"""Where the device time of a training epoch goes: a `jax.profiler` trace of the JAX trainer's epochs, or
(`--framework torch`) a `torch.profiler` trace of the torch trainer's, with its host time per phase.

    python -m bench.agent_profile --task AcrobotSwingup --algo td3 --reps none,sf2 --seeds 1,8 --out OUT
    python -m bench.agent_profile --framework torch --reps sf2 --seeds 1 --out OUT
    python -m bench.agent_profile --task minatar-seaquest --algo ppo --reps sf2 --seeds 5 --out OUT

Each case builds the trainer's own program (the `paper` preset cut so an epoch holds `--actor-steps` actor
steps and the random prefill at most one epoch; on-policy an actor step is one update: take 1), runs one
epoch (compilation, prefill), then traces `--epochs` epochs, per SGD step (comparable with `python -m bench
run --profile`'s single updates); `--hlo` adds the kernels and kernel time per phase, from the compiled
epoch (`bench.hlo`). The torch case times on the host each phase of an actor step and of an evaluation
env step (as trained, then drained around each), then traces the kernels and the CUDA calls that can make
the host wait: host time near the wall time means the host paces the epoch, busy time the device. Each
summary lists where the device idles (`bench.profile.idle_gaps`); the torch case writes its trace too.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


class _EpochRunner:
    """`bench.profile.trace`'s runner protocol over the trainer's epochs."""

    def __init__(self, program, state, sgd_per_epoch: int):
        self.program, self.state, self.epoch = program, state, 2
        self.per_call = sgd_per_epoch

    def step(self):
        self.state, self.means, _ = self.program.epoch(self.state, self.epoch)
        self.epoch += 1

    def sync(self):
        import jax

        jax.block_until_ready((self.state, self.means))


def _config(task, algo, rep, n_seeds, actor_steps, epochs, overrides, framework="jax"):
    """The `paper` preset cut so an epoch holds `actor_steps` actor steps and the random prefill at most
    one epoch (an SGD step's cost does not depend on what the buffer holds; CRL's paper prefill alone is
    1000 actor steps of 32 SGD steps each), validated (`ConfigError` naming the problem). An on-policy actor
    step is one update."""
    from sf2_common.agents.configs import schedule

    from .agent_throughput import framework_configs

    configs, check = framework_configs(framework, tuple(range(n_seeds)))
    base = configs.make_config("paper", task, algo, rep, overrides)
    sched = schedule(base)
    if sched.prefill_actor_steps > actor_steps:
        base = base.replace(min_replay_size=actor_steps * base.num_envs)
    total = actor_steps * (2 * epochs + 4)
    cfg = base.replace(num_timesteps=total * sched.env_steps_per_actor_step, num_evals=2 * epochs + 5)
    check(cfg)
    return cfg


def _file_part(arm: str) -> str:
    """An arm's name as part of a plain file name: "sf2@contract_zeta=false" → "sf2+contract_zeta-false",
    "sf2@zeta_hidden_sizes=(128,128)" → "sf2+zeta_hidden_sizes-128x128"."""
    for old, new in (("@", "+"), ("=", "-"), (",", "x"), *((c, "") for c in " ()[]")):
        arm = arm.replace(old, new)
    return arm


def profile_case(task, algo, rep, n_seeds, actor_steps, epochs, overrides, log=print, hlo_dump=None,
                 label=None) -> dict:
    """Profile the JAX trainer's epochs with `jax.profiler`.

    Args:
        task, algo, rep: the case.
        n_seeds: vmapped seeds.
        actor_steps: actor steps per epoch.
        epochs: epochs traced.
        overrides: config fields to set.
        log: a callable taking one line.
        hlo_dump: the folder XLA dumps to (set in `main` before JAX starts): also count the epoch's
            kernels per phase (`bench.hlo`) and sum the traced kernels' time per phase.
        label: the arm's name (default `rep`; `bench.agent_throughput.parse_reps`'s REP@FIELD=VALUE).

    Returns:
        `bench.profile.trace`'s summary per SGD step, with "phases" (and each device's "by_phase") when
        `hlo_dump` is given.
    """
    import contextlib

    import jax
    from sf2_jax.agents.trainers import trainer_module

    from . import hlo
    from .profile import trace

    cfg = _config(task, algo, rep, n_seeds, actor_steps, epochs, overrides)
    seeds = tuple(range(n_seeds))
    program = trainer_module(task, algo).get_program(cfg)
    with hlo.fresh_compilation() if hlo_dump is not None else contextlib.nullcontext():
        state = program.init(seeds)   # compiled here, dumped with this code's scopes
        state, means, _ = program.epoch(state, 1)
        jax.block_until_ready((state, means))
    sgd = program.sched.actor_steps_per_epoch * program.sched.sgd_steps_per_actor_step
    how = ("no vmap" if n_seeds == 1 else "in turn" if cfg.seed_loop == "map" else "vmapped")   # _seed_map
    arm = label or rep
    label = f"{task} {algo}+{arm}, {n_seeds} seed{'s' * (n_seeds > 1)} ({how}), per SGD step"
    log(f"  tracing {label}: {epochs} epochs of {program.sched.actor_steps_per_epoch} actor steps")
    module, kernel_phase = None, None
    if hlo_dump is not None:
        module = hlo.find_module(Path(hlo_dump))   # the newest: this case's epoch program, compiled above
        kernel_phase = hlo.kernel_phases(module.read_text(), hlo.phases())
    out = trace(_EpochRunner(program, state, sgd), updates=epochs, label=label, kernel_phase=kernel_phase)
    if module is not None:
        out["phases"] = {**hlo.count(module.read_text(), hlo.phases()), "sgd_steps": sgd,
                         "file": module.name}
        module.rename(Path(hlo_dump) / f"case-{algo}-{_file_part(arm)}-{n_seeds}seeds-{module.name}")
    return out


class _PhaseTimer:
    """Host seconds spent inside wrapped callables, by phase. Unsynchronized (`synced` False): the time the
    host spends in the call, which includes any wait the call itself makes for work queued before it.
    Synchronized: the device is drained before the call and after it, so a phase's time is its own host
    work plus its own device work, as if it ran alone."""

    def __init__(self, sync):
        self.seconds: dict[str, float] = {}
        self.sync, self.synced = sync, False

    def wrap(self, phase: str, fn):
        import time

        def timed(*args, **kwargs):
            if self.synced:
                self.sync()
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                if self.synced:
                    self.sync()
                self.seconds[phase] = self.seconds.get(phase, 0.0) + time.perf_counter() - t
        return timed

    def take(self, updates: int, wall: float) -> dict:
        """ms per update of the epochs just run: their wall time, each phase, the rest; then reset."""
        phases = {k: v / updates * 1e3 for k, v in sorted(self.seconds.items(), key=lambda kv: -kv[1])}
        out = {"wall_ms": wall / updates * 1e3, "phases_ms": phases,
               "rest_ms": (wall - sum(self.seconds.values())) / updates * 1e3}
        self.seconds = {}
        return out


_SYNC_CALLS = ("Synchronize", "cudaMemcpy", "cuMemcpyDtoH", "cuMemcpyHtoD", "cudaStreamWaitEvent",
               "cuStreamWaitEvent", "cudaGraphLaunch", "cuGraphLaunch")


def _runtime_calls(events: list[dict], updates: int) -> list[dict]:
    """The CUDA runtime and driver calls of a torch.profiler trace (torch's and, through CUPTI, JAX's),
    per update: those that can make the host wait (synchronizations, blocking copies) and graph launches
    first, then the costliest others."""
    by = {}
    for e in events:
        if e.get("ph") == "X" and e.get("cat") in ("cuda_runtime", "cuda_driver"):
            c = by.setdefault(e.get("name", "?"), [0, 0.0])
            c[0] += 1
            c[1] += e.get("dur", 0.0)
    rows = [{"name": k, "count": v[0] / updates, "ms": v[1] / 1e3 / updates} for k, v in by.items()]
    waits = sorted((r for r in rows if any(w in r["name"] for w in _SYNC_CALLS)), key=lambda r: -r["ms"])
    rest = sorted((r for r in rows if r not in waits), key=lambda r: -r["ms"])[:6]
    return waits + rest


def profile_torch_case(task, algo, rep, n_seeds, actor_steps, epochs, overrides, log=print,
                       events_to=None, label=None) -> dict:
    """Profile the torch trainer's epochs: host time per phase, then a `torch.profiler` trace.

    Args:
        task, algo, rep: the case.
        n_seeds: seeds (the torch trainer runs them one after the other).
        actor_steps: actor steps per epoch.
        epochs: epochs timed per way (as trained, drained, traced).
        overrides: config fields to set.
        log: a callable taking one line.
        events_to: a path for the trace's device and CUDA runtime/driver events (gzipped JSON).
        label: the arm's name (default `rep`; `bench.agent_throughput.parse_reps`'s REP@FIELD=VALUE).

    Returns:
        The summary: `host` (phases as trained and drained), `runtime` (CUDA calls that can wait) and
        `devices` (`bench.profile.summarize_kernels`), per SGD step.
    """
    import gzip
    import tempfile
    import time

    import torch
    from sf2_torch.agents.trainer import get_program

    from .profile import summarize_kernels

    cfg = _config(task, algo, rep, n_seeds, actor_steps, epochs, overrides, "torch")
    seeds = tuple(range(n_seeds))
    program = get_program(cfg)
    state = program.init(seeds)

    def sync():
        if torch.cuda.is_available():
            torch.cuda.synchronize()

    epoch = 1
    while True:   # the prefill, then the epoch of the first SGD step (its compile and graph capture)
        state, means, _ = program.epoch(state, epoch)
        sync()
        epoch += 1
        if int(means["sgd_steps"][0]):
            break
    sgd = program.sched.actor_steps_per_epoch * cfg.grad_updates_per_step
    timer = _PhaseTimer(sync)
    program._env_step = timer.wrap("env_step", program._env_step)
    program._observe = timer.wrap("observe", program._observe)
    for ag in state.agents:
        for phase, obj, name in (("explore", ag.algo, "explore"), ("step_noise", ag.algo, "step_noise"),
                                 ("sgd_step", ag.algo, "sgd_step"), ("sample", ag.replay, "sample")):
            setattr(obj, name, timer.wrap(phase, getattr(obj, name)))
    arm = label or rep
    label = f"{task} {algo}+{arm}, {n_seeds} seed{'s' * (n_seeds > 1)} (torch trainer), per SGD step"
    log(f"  timing and tracing {label}: 3 × {epochs} epochs of "
        f"{program.sched.actor_steps_per_epoch} actor steps")
    updates = epochs * sgd
    host = {}
    for synced in (False, True):
        timer.synced = synced
        t = time.perf_counter()
        for _ in range(epochs):
            state, means, _ = program.epoch(state, epoch)
            epoch += 1
        sync()
        host["synced" if synced else "as trained"] = timer.take(updates, time.perf_counter() - t)
    timer.synced = False
    evaluation = time_evaluation(program, state, epoch, sync)
    # on CUDA the device activity alone (kernels, copies, CUDA runtime/driver calls through CUPTI): the
    # summary reads nothing else, and recording every CPU op as well slows the host several times over,
    # which hides where the device idles
    activities = [torch.profiler.ProfilerActivity.CUDA if torch.cuda.is_available()
                  else torch.profiler.ProfilerActivity.CPU]
    t = time.perf_counter()
    with torch.profiler.profile(activities=activities) as prof:
        for _ in range(epochs):
            state, means, _ = program.epoch(state, epoch)
            epoch += 1
        sync()
    traced_wall = time.perf_counter() - t
    with tempfile.TemporaryDirectory(prefix="sf2prof") as d:
        path = f"{d}/trace.json"
        prof.export_chrome_trace(path)
        with open(path) as f:
            events = json.load(f)["traceEvents"]
    if events_to:
        kept = [e for e in events if e.get("cat") in ("kernel", "gpu_memcpy", "gpu_memset", "cuda_runtime",
                                                      "cuda_driver")]
        with gzip.open(events_to, "wt") as f:
            json.dump(kept, f)
    kernels = [e for e in events
               if e.get("ph") == "X" and e.get("cat") in ("kernel", "gpu_memcpy", "gpu_memset")]
    device = f"GPU {torch.cuda.get_device_name()}" if torch.cuda.is_available() else "CPU"
    return {"label": label, "updates": updates, "wall_ms_per_update": traced_wall / updates * 1e3,
            "host": host, "evaluation": evaluation, "runtime": _runtime_calls(events, updates),
            "devices": [summarize_kernels(kernels, updates, device)] if kernels else []}


def time_evaluation(program, state, epoch: int, sync) -> dict:
    """Time the torch trainer's evaluation (`Program.evaluate`) per env step, by phase: the seeds' policies
    (`act`: `Program.eval_policy`, one CUDA graph replay a step where the trainer graphs it) and the env
    step, unsynchronized and synchronized (`_PhaseTimer`), after one untimed episode.

    Args:
        program: the torch trainer's `Program`.
        state: its `TrainState` (the agents act, its `eval_keys` give the start states).
        epoch: the epoch the acting noise is drawn for.
        sync: a callable that drains the device.

    Returns:
        {"as trained": …, "synced": …}, each `_PhaseTimer.take`'s ms per evaluation env step.
    """
    import time

    from sf2_torch.agents.trainer import _eval_env

    timer = _PhaseTimer(sync)
    env = _eval_env(program, state.seeds)
    env.step_actions = timer.wrap("env_step", env.step_actions)
    own_policy = program.eval_policy
    program.eval_policy = lambda agents, gens: timer.wrap("act", own_policy(agents, gens))
    steps, out = program.sched.eval_actor_steps, {}
    for how in (None, "as trained", "synced"):   # None: the untimed episode (compilation)
        timer.synced = how == "synced"
        t = time.perf_counter()
        program.evaluate(state.agents, state.eval_keys, state.seeds, epoch, env)
        sync()
        taken = timer.take(steps, time.perf_counter() - t)
        if how:
            out[how] = taken
    del program.eval_policy   # the class's own again
    return out


def main(argv=None) -> int:
    """Run `python -m bench.agent_profile`.

    Args:
        argv: the command line after the module name (default `sys.argv[1:]`).

    Returns:
        The exit status (2, before anything is built or written, for an invalid argument).
    """
    p = argparse.ArgumentParser(prog="python -m bench.agent_profile", description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="AcrobotSwingup")
    p.add_argument("--algo", default="td3")
    p.add_argument("--reps", default="none,sf2",
                   help="comma list of representations, each optionally REP@FIELD=VALUE[@...] (an arm's own "
                        "config fields, e.g. sf2@contract_zeta=false)")
    p.add_argument("--seeds", default="1,8", help="numbers of vmapped seeds, e.g. 1,8")
    p.add_argument("--actor-steps", type=int, default=64, help="actor steps per traced epoch")
    p.add_argument("--epochs", type=int, default=2, help="traced epochs per case")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    p.add_argument("--framework", default="jax", choices=("jax", "torch"),
                   help="whose trainer: jax (jax.profiler) or torch (host phases and torch.profiler)")
    p.add_argument("--hlo", action="store_true",
                   help="jax: also count each epoch's compiled kernels per phase (bench.hlo; "
                        "the optimized HLO is kept in OUT/hlo)")
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    from sf2_common.errors import ConfigError

    from .agent_throughput import parse_reps, parse_sets
    from .machine import describe
    from .profile import markdown

    try:   # every case's config, before anything is built or written
        overrides = parse_sets(args.set, [args.framework])
        arms = parse_reps(args.reps, [args.framework])
        cases = [(int(x), arm) for x in args.seeds.split(",") for arm in arms]
        for n, (_, rep, own) in cases:
            _config(args.task, args.algo, rep, n, args.actor_steps, args.epochs, {**overrides, **own},
                    args.framework)
    except (ConfigError, ValueError) as err:
        p.error(str(err))
    if args.hlo and args.framework != "jax":
        p.error("--hlo counts the JAX trainer's compiled kernels; the torch trainer has no XLA dump")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    hlo_dump = None
    if args.hlo:   # before JAX starts its backend, which reads XLA_FLAGS once
        import os
        import tempfile

        hlo_dump = tempfile.mkdtemp(prefix="sf2hlo")
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + f" --xla_dump_to={hlo_dump} "
                                   "--xla_dump_hlo_as_text --xla_dump_hlo_module_re=.*epoch_one.*").strip()
    command = "python -m bench.agent_profile " + " ".join(argv if argv is not None else sys.argv[1:])
    summaries = []
    case = profile_torch_case if args.framework == "torch" else profile_case
    for n, (arm, rep, own) in cases:
        extra = {"hlo_dump": hlo_dump} if hlo_dump else {}
        if args.framework == "torch":
            extra = {"events_to": out / f"trace-{_file_part(arm)}-x{n}.json.gz"}
        summaries.append(case(args.task, args.algo, rep, n, args.actor_steps, args.epochs,
                              {**overrides, **own}, label=arm, **extra))
        (out / "agent_profile.md").write_text(f"Command: `{command}`\n\n" + markdown(summaries))
    (out / "agent_profile.json").write_text(json.dumps(summaries, indent=1))
    if hlo_dump:
        import shutil

        (out / "hlo").mkdir(exist_ok=True)
        for f in Path(hlo_dump).glob("case-*"):
            shutil.copy(f, out / "hlo" / f.name)
    (out / "machine.json").write_text(json.dumps(describe(str(Path(__file__).resolve().parents[1]), command),
                                                 indent=2))
    print((out / "agent_profile.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
