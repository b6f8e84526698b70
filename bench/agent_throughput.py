"""Training throughput of the agents: env steps per second of whole training epochs.

    python -m bench.agent_throughput --tasks AcrobotSwingup --algos td3 --reps none,sf2 --seeds 1,8 \
        --precisions highest,tensorfloat32 --env-steps 600000 --epochs 3 --out OUT

Each case is the task's `paper` preset with its budget cut to `--env-steps`, split into `--epochs` timed
epochs after warm-up epochs that hold the compilation, the random prefill and the first SGD step
(`warmup_s`, never mixed into the rate); every timed epoch is SGD from its first step to its last. An
epoch is the trainer's own program (env steps, buffer inserts, `grad_updates_per_step` SGD steps, the
seeds vmapped; no evaluation or checkpoint), timed from dispatch to completion. Reported: the median over
the timed epochs of env steps/s per seed and over all seeds. `--precisions` sets the learner's matmul
precision (default `highest`, not the preset's, which throughput.md names where a row differs; physics at
fp32 `highest`); `--frameworks jax,torch` adds torch. `--algos ppo` (MinAtar), `fpo` (Playground), `crl`
(ant-goal) time the JAX on-policy and goal-conditioned trainers: an epoch is whole updates (`--env-steps`
rounded up), the first its warm-up.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

COLUMNS = ["framework", "task", "algo", "rep", "seeds", "learner_precision", "env_steps_per_epoch",
           "sgd_steps_per_epoch", "timed_epochs", "warmup_epochs", "warmup_s", "median_epoch_s",
           "sps_per_seed", "sps_total", "epoch_s"]


def _names(s: str) -> tuple[str, ...]:
    return tuple(x for x in s.split(",") if x)


def _arms(s: str) -> tuple[str, ...]:
    """`--reps`'s comma list, split only outside brackets: `sf2@zeta_hidden_sizes=(128,128)` is one arm."""
    parts, depth, start = [], 0, 0
    for i, ch in enumerate(s):
        depth += (ch in "([") - (ch in ")]")
        if ch == "," and depth == 0:
            parts.append(s[start:i])
            start = i + 1
    return tuple(x for x in (*parts, s[start:]) if x)


def _block(framework: str, x):
    if framework == "jax":
        import jax

        jax.block_until_ready(x)
    else:
        import torch

        if torch.cuda.is_available():
            torch.cuda.synchronize()


def warm_up(env_steps: int, epochs: int, prefill_env_steps: int) -> tuple[int, int]:
    """Split a measurement into epochs so that every timed epoch is all SGD.

    Args:
        env_steps: timed env steps per seed, all epochs.
        epochs: timed epochs.
        prefill_env_steps: env steps of random prefill before the first SGD step.

    Returns:
        (env steps per epoch, warm-up epochs): the warm-up runs up to and including the epoch that holds
        the first SGD step.
    """
    per_epoch = -(-env_steps // epochs)
    return per_epoch, prefill_env_steps // per_epoch + 1


def framework_configs(framework: str, seeds: tuple[int, ...]):
    """Find a framework's trainer configs.

    Args:
        framework: "jax" (configs of sf2-common) or "torch" (which adds device and compile fields).
        seeds: the seeds a config will train.

    Returns:
        (the configs module, a check raising `ConfigError` for an invalid config).
    """
    if framework == "jax":
        from sf2_common.agents import configs
        from sf2_jax.agents.configs import validate

        return configs, lambda c: validate(c, seeds)
    from sf2_torch.agents import configs

    return configs, lambda c: configs.validate(c, seeds)


def parse_sets(items, frameworks) -> dict:
    """Type `--set FIELD=VALUE` items by the configs of the frameworks measured.

    Args:
        items: the `FIELD=VALUE` strings.
        frameworks: the frameworks measured; with torch alone, the torch trainer's own fields
            (`sf2_torch.agents.configs.TORCH_FIELDS`) are accepted too.

    Returns:
        {field: typed value}; a `ConfigError` names a bad field and the valid ones.
    """
    from sf2_common.agents import configs
    from sf2_common.errors import ConfigError

    if not items:
        return {}
    if set(frameworks) == {"torch"}:
        return configs.parse_overrides(items, framework_configs("torch", (0,))[0].TrainConfig)
    try:
        return configs.parse_overrides(items)
    except ConfigError as err:
        try:
            from sf2_torch.agents.configs import TORCH_FIELDS
        except ImportError:
            raise err from None
        names = {item.split("=", 1)[0].strip().replace("-", "_") for item in items}
        if names & set(TORCH_FIELDS):
            raise ConfigError(f"{err} (the torch trainer's fields {', '.join(TORCH_FIELDS)} need the torch "
                              "framework alone)") from None
        raise


def parse_reps(text: str, frameworks) -> list[tuple[str, str, dict]]:
    """Split `--reps` into arms: a representation, optionally with config fields of its own after `@`.

    `none,sf2,sf2@contract_zeta=false` measures three arms, the third SF² with the oracle ζ; each
    `@FIELD=VALUE` is typed like `--set` and applied after it. A size list goes in brackets, whose commas do
    not split arms: `sf2@zeta_hidden_sizes=(128,128)`.

    Args:
        text: the comma list.
        frameworks: the frameworks measured (`parse_sets`).

    Returns:
        [(label, representation, {field: typed value})], in the order given; a `ConfigError` names a bad
        field, a `ValueError` an empty arm.
    """
    arms = []
    for label in _arms(text):
        rep, *items = label.split("@")
        if not rep or any(not item for item in items):
            raise ValueError(f"--reps: {label!r} is not REP or REP@FIELD=VALUE[@FIELD=VALUE...]")
        arms.append((label, rep, parse_sets(items, frameworks)))
    return arms


def config_for(task: str, algo: str, rep: str, n_seeds: int, env_steps: int, epochs: int, overrides: dict,
               framework: str = "jax"):
    """Build the validated `paper` config of one measurement.

    Args:
        task, algo, rep: the case.
        n_seeds: vmapped seeds.
        env_steps: timed env steps per seed, rounded up to whole actor steps per epoch.
        epochs: timed epochs.
        overrides: config fields to set.
        framework: "jax" or "torch".

    Returns:
        (config, warm-up epochs); a `ConfigError` names an invalid field.
    """
    from sf2_common.agents.configs import schedule

    seeds = tuple(range(n_seeds))
    configs, check = framework_configs(framework, seeds)
    sched = schedule(configs.make_config("paper", task, algo, rep, overrides))
    unit = sched.env_steps_per_actor_step   # an epoch is whole actor steps (an on-policy update is ~1M)
    env_steps = -(-env_steps // (epochs * unit)) * epochs * unit
    per_epoch, warm = warm_up(env_steps, epochs, sched.prefill_env_steps)
    values = {"num_timesteps": per_epoch * (warm + epochs), "num_evals": warm + epochs + 1, **overrides}
    cfg = configs.make_config("paper", task, algo, rep, values)
    check(cfg)
    return cfg, warm


def measure(task: str, algo: str, rep: str, n_seeds: int, env_steps: int, epochs: int,
            overrides: dict, framework: str = "jax", log=print, label: str | None = None) -> dict:
    """Time training epochs of one case after its warm-up epochs.

    Args:
        task, algo, rep: the case.
        n_seeds: vmapped seeds.
        env_steps: timed env steps per seed.
        epochs: timed epochs.
        overrides: config fields to set.
        framework: "jax" or "torch".
        log: a callable taking one line.
        label: the row's `rep` (default `rep`; an arm of `parse_reps`, e.g. "sf2@contract_zeta=false").

    Returns:
        One row of `COLUMNS`.
    """
    seeds = tuple(range(n_seeds))
    cfg, warm = config_for(task, algo, rep, n_seeds, env_steps, epochs, overrides, framework)
    if framework == "jax":
        from sf2_jax.agents.trainers import trainer_module

        get_program = trainer_module(task, algo).get_program
    else:
        from sf2_torch.agents.trainer import get_program
    program = get_program(cfg)
    sched = program.sched
    state = program.init(seeds)
    t = time.perf_counter()
    for e in range(1, warm + 1):
        state, means, _ = program.epoch(state, e)
        _block(framework, (state, means))
    first = time.perf_counter() - t
    label = label or rep
    tag = f"{framework} {task} {algo}+{label} x{n_seeds} {cfg.learner_precision}"
    log(f"  {tag}: warm-up ({warm} epoch{'s' * (warm > 1)}: compile, prefill, first SGD step) {first:.1f} s")
    times, sgds = [], []
    for e in range(warm + 1, warm + epochs + 1):
        t = time.perf_counter()
        state, means, _ = program.epoch(state, e)
        _block(framework, (state, means))
        times.append(time.perf_counter() - t)
        sgds.append(int(np.asarray(means["sgd_steps"])[0]))
        log(f"  {tag}: epoch {e} {times[-1]:.2f} s "
            f"({sched.env_steps_per_epoch / times[-1]:,.0f} env steps/s per seed)")
    if len(set(sgds)) > 1:
        raise RuntimeError(f"{tag}: the timed epochs did {sgds} SGD steps; a rate needs the same work in "
                           f"each (warm_up)")
    med = statistics.median(times)
    sgd = sgds[0]
    del state
    return {"framework": framework, "task": task, "algo": algo, "rep": label, "seeds": n_seeds,
            "learner_precision": cfg.learner_precision,
            "env_steps_per_epoch": sched.env_steps_per_epoch, "sgd_steps_per_epoch": sgd,
            "timed_epochs": epochs, "warmup_epochs": warm, "warmup_s": round(first, 2),
            "median_epoch_s": round(med, 4),
            "sps_per_seed": round(sched.env_steps_per_epoch / med, 1),
            "sps_total": round(n_seeds * sched.env_steps_per_epoch / med, 1),
            "epoch_s": ";".join(f"{x:.4f}" for x in times)}


def preset_precisions(tasks, algos, arms, frameworks, overrides: dict) -> dict[str, str]:
    """The learner precision each case's `paper` preset trains at (a study's runs), `--precisions` aside.

    Args:
        tasks, algos: the cases' tasks and algorithms.
        arms: `parse_reps` arms (label, representation, the arm's own fields).
        frameworks: "jax" and/or "torch".
        overrides: `--set`'s fields (a `learner_precision` there is the runs' too).

    Returns:
        {"FRAMEWORK TASK ALGO+LABEL": learner_precision}.
    """
    out = {}
    for fw in frameworks:
        configs, _ = framework_configs(fw, (0,))
        for task, algo, (label, rep, own) in itertools.product(tasks, algos, arms):
            cfg = configs.make_config("paper", task, algo, rep, {**overrides, **own})
            out[_case(fw, task, algo, label)] = cfg.learner_precision
    return out


def _case(framework: str, task: str, algo: str, rep: str) -> str:
    """A case's name in `preset_learner_precision` and its note: 'FRAMEWORK TASK ALGO+REP'."""
    return f"{framework} {task} {algo}+{rep}"


def markdown(rows: list[dict], info: dict) -> str:
    """Render the rows and the ratios between them (SF²/vanilla, seeds, precisions, torch/JAX).

    Args:
        rows: `measure` rows.
        info: the machine description.

    Returns:
        throughput.md's text.
    """
    tasks = ", ".join(dict.fromkeys(r["task"] for r in rows))
    lines = [f"# Agents: training throughput, `paper` preset, {tasks}", "",
             "Command:", "", "```", info["command"], "```", "",
             f"- machine: {info.get('cpu')}; GPU: {info.get('gpu')} ({info.get('nvidia_smi')})",
             f"- versions: {json.dumps(info.get('versions'))}; jax backend {info.get('jax_backend')}; "
             f"physics at fp32 `highest`, the learner at the row's `learner_precision`",
             *_preset_note(rows, info.get("preset_learner_precision") or {}),
             "",
             "One epoch = the trainer's program over `env_steps_per_epoch` env steps per seed (env steps, "
             "buffer inserts, SGD steps; no evaluation). Warm-up epochs (compilation, random prefill, the "
             "first SGD step) reported apart; rates are medians over the timed epochs, each all SGD.", "",
             "| framework | task | algo | representation | learner precision | seeds | env steps / epoch / "
             "seed | SGD steps / epoch | warm-up s (epochs) | median epoch s | env steps/s per seed | env "
             "steps/s, all seeds | 1M steps per seed at this rate |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        one_m = 1_000_000 / r["sps_per_seed"]
        lines.append(f"| {r['framework']} | {r['task']} | {r['algo']} | {r['rep']} | "
                     f"{r['learner_precision']} | {r['seeds']} | {r['env_steps_per_epoch']:,} | "
                     f"{r['sgd_steps_per_epoch']:,} | {r['warmup_s']} ({r['warmup_epochs']}) | "
                     f"{r['median_epoch_s']} | "
                     f"{r['sps_per_seed']:,.0f} | {r['sps_total']:,.0f} | {one_m:,.0f} s |")
    key = ("framework", "task", "algo", "rep", "learner_precision", "seeds")
    by = {tuple(r[k] for k in key): r for r in rows}
    notes = []
    for (fw, task, algo, rep, prec, n), r in by.items():
        base = by.get((fw, task, algo, "none", prec, n))
        if rep != "none" and base:
            notes.append(f"- {fw} {task} {algo}+{rep} / {algo} ({prec}, {n} seed{'s' * (n > 1)}): time per "
                         f"env step {base['sps_per_seed'] / r['sps_per_seed']:.2f}×")
        plain_rep = rep.split("@")[0]
        plain = by.get((fw, task, algo, plain_rep, prec, n))
        if plain_rep != rep and plain:
            notes.append(f"- {fw} {task} {algo}+{rep} / {algo}+{plain_rep} ({prec}, {n} "
                         f"seed{'s' * (n > 1)}): time per env step "
                         f"{plain['sps_per_seed'] / r['sps_per_seed']:.2f}×")
        one = by.get((fw, task, algo, rep, prec, 1))
        if n > 1 and one:
            total = r["sps_total"] / one["sps_total"]
            notes.append(f"- {fw} {task} {algo}+{rep} ({prec}): {n} vmapped seeds give {total:.2f}× the "
                         f"env steps/s of 1 seed")
        high = by.get((fw, task, algo, rep, "highest", n))
        if prec != "highest" and high:
            notes.append(f"- {fw} {task} {algo}+{rep} ({n} seed{'s' * (n > 1)}): {prec} gives "
                         f"{r['sps_total'] / high['sps_total']:.2f}× the env steps/s of highest")
        jx = by.get(("jax", task, algo, rep, prec, n))
        if fw == "torch" and jx:
            notes.append(f"- {task} {algo}+{rep} ({prec}, {n} seed{'s' * (n > 1)}): torch / JAX env "
                         f"steps/s {r['sps_total'] / jx['sps_total']:.2f}×")
    if notes:
        lines += ["", "Ratios (same run, same machine):", ""] + notes
    algos = {r["algo"] for r in rows}
    if algos & {"td3", "sac"}:
        lines += ["", "Paper (§4.4, RTX 4090, 10M steps): TD3 659 s, TD3+SF² about 1300 s, i.e. about 15k "
                  "and 7.7k env steps/s for one seed."]
    if "crl" in algos:
        lines += ["", "JaxGCRL's README: CRL, 10M env steps in about 10 minutes on one V100, i.e. about "
                  "16.7k env steps/s for one seed."]
    return "\n".join(lines) + "\n"


def _preset_note(rows: list[dict], trained: dict[str, str]) -> list[str]:
    """throughput.md's line naming the precision the `paper` preset trains at, where a row times another."""
    off = sorted({f"{k}: {trained[k]}" for r in rows
                  if (k := _case(r["framework"], r["task"], r["algo"], r["rep"])) in trained
                  and trained[k] != r["learner_precision"]})
    if not off:
        return []
    return [f"- **not the preset's learner precision**: the `paper` preset trains {'; '.join(off)}; rows at "
            "another precision time a learner its runs do not use (`--precisions` names the timed one)"]


def main(argv=None) -> int:
    """Run `python -m bench.agent_throughput`.

    Args:
        argv: the command line after the module name (default `sys.argv[1:]`).

    Returns:
        The exit status (2, before anything is compiled or written, for an invalid argument).
    """
    p = argparse.ArgumentParser(prog="python -m bench.agent_throughput", description=__doc__.split("\n\n")[0])
    p.add_argument("--tasks", "--task", default="AcrobotSwingup", type=_names, help="comma list of tasks")
    p.add_argument("--algos", default="td3", type=_names)
    p.add_argument("--reps", default="none,sf2",
                   help="comma list of representations, each optionally REP@FIELD=VALUE[@...] (an arm's own "
                        "config fields, e.g. sf2@contract_zeta=false)")
    p.add_argument("--seeds", default="1,8", help="numbers of vmapped seeds to measure, e.g. 1,8")
    p.add_argument("--precisions", default="highest", type=_names,
                   help="learner_precision values (highest, tensorfloat32, bfloat16); default highest, "
                        "whatever the preset trains at (a note names it where they differ)")
    p.add_argument("--frameworks", default="jax", type=_names, help="jax and/or torch")
    p.add_argument("--env-steps", type=int, default=600_000, help="timed env steps per seed (all epochs)")
    p.add_argument("--epochs", type=int, default=3, help="timed epochs (after the warm-up ones)")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override a config field of the paper preset (repeatable)")
    p.add_argument("--out", required=True, help="folder for throughput.csv / throughput.md / machine.json")
    args = p.parse_args(argv)
    from sf2_common.errors import ConfigError

    from .machine import describe

    # every combination checked before anything is compiled or written (exit status 2 naming the problem)
    bad = [f for f in args.frameworks if f not in ("jax", "torch")]
    if bad:
        p.error(f"--frameworks: {', '.join(map(repr, bad))} unknown; valid: jax, torch")
    try:
        seed_counts = [int(x) for x in args.seeds.split(",") if x.strip()]
    except ValueError:
        seed_counts = []
    if not seed_counts or min(seed_counts) < 1:
        p.error(f"--seeds: {args.seeds!r} is not a comma list of seed counts >= 1")
    if args.epochs < 1 or args.env_steps < 1:
        p.error(f"--epochs {args.epochs}, --env-steps {args.env_steps}: each must be >= 1")
    try:
        overrides = parse_sets(args.set, args.frameworks)
        arms = parse_reps(args.reps, args.frameworks)
        for task, fw, prec, algo, (_, rep, own) in itertools.product(args.tasks, args.frameworks,
                                                                     args.precisions, args.algos, arms):
            config_for(task, algo, rep, max(seed_counts), args.env_steps, args.epochs,
                       {**overrides, **own, "learner_precision": prec}, framework=fw)
    except (ConfigError, ValueError) as err:
        p.error(str(err))
    trained = preset_precisions(args.tasks, args.algos, arms, args.frameworks, overrides)
    for case, prec in trained.items():
        if any(timed != prec for timed in args.precisions):
            print(f"note: the `paper` preset trains {case} at learner_precision = {prec!r}; --precisions "
                  f"times {', '.join(args.precisions)}", file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = "python -m bench.agent_throughput " + " ".join(argv if argv is not None else sys.argv[1:])
    info = describe(str(Path(__file__).resolve().parents[1]), command)
    info["preset_learner_precision"] = trained
    (out / "machine.json").write_text(json.dumps(info, indent=2))
    rows = []
    for task in args.tasks:
        for n in seed_counts:
            for fw in args.frameworks:
                for prec in args.precisions:
                    for algo in args.algos:
                        for label, rep, own in arms:
                            rows.append(measure(task, algo, rep, n, args.env_steps, args.epochs,
                                                {**overrides, **own, "learner_precision": prec},
                                                framework=fw, label=label))
                            with open(out / "throughput.csv", "w", newline="") as f:
                                w = csv.DictWriter(f, fieldnames=COLUMNS)
                                w.writeheader()
                                w.writerows(rows)
                            (out / "throughput.md").write_text(markdown(rows, info))
    text = markdown(rows, info)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
