"""The command line of both cores, written once: `sf2-jax` and `sf2-torch` are this module with a
`Framework` (the program name, help texts and environment, and the core's functions the commands call:
its TrainConfig class, validation, training and evaluation). Each core's cli.py builds its `Framework`
from small functions that import the core's agents only when called, so `PROG --help` and `PROG tasks`
import no framework.

    PROG train --task CartpoleBalance --algo td3 --repr sf2 --config quick --seeds 0-3 --out runs/cp
    PROG train --task CartpoleBalance --algo td3 --repr sf2,none,sim --config quick --seeds 0-1 --out runs/cmp
    PROG eval runs/cp [--epoch N] [--episodes 20] [--stochastic]
    PROG plot runs/cmp/td3-sf2 runs/cmp/td3-none --out curves.png
    PROG study run studies/fig7-td3.toml --out results/fig7-td3    (sf2_studies.commands)
    PROG study report results/fig7-td3
    PROG tasks

Every `TrainConfig` field can be overridden, either with its own flag (`--batch-size 128`,
`--hidden-sizes 64,64`) or with `--set batch_size=128` (repeatable). Bad input (unknown task, algo or
representation, a combination that does not exist, a budget smaller than the prefill, ...) is reported
before anything is compiled; exit status 2. A NaN/inf loss stops the run with exit status 3.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import sys
import time
from collections.abc import Callable
from pathlib import Path

from sf2_studies import commands as study_commands

from sf2_common.agents import configs, plotting
from sf2_common.agents.hostloop import TrainingDiverged
from sf2_common.agents.registry import Registry
from sf2_common.agents.runfolder import RunFolder
from sf2_common.errors import ConfigError

__all__ = ["Framework", "build_parser", "main", "print_table", "expand_runs"]

_RUN_FIELDS_SKIPPED = ("task", "algo", "representation")


@dataclasses.dataclass(frozen=True)
class Framework:
    """What differs between `sf2-jax` and `sf2-torch`: names and texts, and the core's functions."""

    prog: str                     # "sf2-jax"
    package: str                  # "sf2_jax" (its command line is the module `{package}.cli`)
    doc: str                      # the CLI module's docstring (its first paragraph is the --help text)
    seeds_help: str               # how the seeds run
    cache_env: str                # environment variable of the JAX compilation cache folder
    config_class: type            # the core's TrainConfig (sf2_common's, or torch's with its run fields)
    registry: Callable[[], Registry]      # the core's representation registry (names, labels)
    validate: Callable            # validate(cfg, seeds) -> cfg: everything checkable before building
    train: Callable               # the core's agents.trainer.train
    evaluate_checkpoint: Callable  # the core's agents.trainer.evaluate_checkpoint
    evaluate_checkpoint_noises: Callable  # ... evaluate_checkpoint_noises (several noise stds, one restore)
    env_defaults: tuple[tuple[str, str], ...] = ()   # environment defaults set before JAX is imported

    def compile_cache(self) -> str:
        return os.environ.get(self.cache_env, str(Path.home() / ".cache" / self.prog / "xla"))

    def method_label(self, algo: str, representation: str) -> str:
        return plotting.method_label(algo, representation, self.registry())


def _field_names(fw: Framework) -> list[str]:
    return [f.name for f in dataclasses.fields(fw.config_class) if f.name not in _RUN_FIELDS_SKIPPED]


def build_parser(fw: Framework) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=fw.prog, description=fw.doc.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)

    t = sub.add_parser("train", help="train one or more methods over several seeds",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    t.add_argument("--task", required=True, help="Playground DM Control task, e.g. CartpoleBalance "
                   f"(`{fw.prog} tasks` lists them)")
    t.add_argument("--algo", default="td3", help="td3 or sac")
    t.add_argument("--repr", default="sf2", dest="representation",
                   help="representation: none (vanilla), sf2; with sf2-baselines installed also sim, simlap, "
                   "simlap_authors, spr; a comma list trains each and compares them")
    t.add_argument("--config", default="quick", help="preset: paper (Table 1 + the authors' settings) or "
                   "quick (small networks and budget for a CPU)")
    t.add_argument("--seeds", default="0", help=f"e.g. 0-3 or 0,2,5; {fw.seeds_help}")
    t.add_argument("--out", required=True, help="run folder (one method) or parent folder (several)")
    t.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override any config field (repeatable)")
    t.add_argument("--fresh", action="store_true", help="discard what --out holds and start over")
    t.add_argument("--no-resume", action="store_true",
                   help="refuse to continue a run folder that holds checkpoints")
    t.add_argument("--no-progress", action="store_true", help="no progress bar")
    t.add_argument("--stop-after-epoch", type=int, default=None, help=argparse.SUPPRESS)
    t.add_argument("--compile-cache", default=fw.compile_cache(),
                   help="folder for JAX's persistent compilation cache, reused by later runs of the same "
                   f"config ('' turns it off; env {fw.cache_env})")
    fields = t.add_argument_group("config fields (each overrides the preset)")
    for name in _field_names(fw):
        fields.add_argument(f"--{name.replace('_', '-')}", dest=f"field_{name}", default=None, metavar="V",
                            help=argparse.SUPPRESS if name in ("keep_checkpoints",) else None)

    e = sub.add_parser("eval", help="evaluate a run folder's checkpoint")
    e.add_argument("run", help="run folder")
    e.add_argument("--epoch", type=int, default=None, help="checkpoint epoch (default: latest)")
    e.add_argument("--episodes", type=int, default=None, help="episodes per seed (default: the config's "
                   "num_eval_envs)")
    mode = e.add_mutually_exclusive_group()
    mode.add_argument("--deterministic", action="store_true", default=None, help="act without noise")
    mode.add_argument("--stochastic", action="store_true", default=None, help="act with the acting noise")
    e.add_argument("--json", action="store_true", help="print the returns as JSON")
    e.add_argument("--obs-noise", default=None, metavar="STDS", help="Gaussian noise stds added to the "
                   "observations the policy sees, e.g. 0,0.05,0.1,0.2 (paper App. C.2.2): each at the "
                   "latest --checkpoints checkpoints")
    e.add_argument("--checkpoints", type=int, default=1, help="with --obs-noise: how many of the latest "
                   "checkpoints (default 1)")
    e.add_argument("--save", action="store_true", help="with --obs-noise: write RUN/obs_noise.json (what "
                   "`study report` reads)")

    p = sub.add_parser("plot", help="learning curves of several run folders (mean and 95%% CI per method)")
    p.add_argument("runs", nargs="+", help="run folders (folders holding run folders are expanded)")
    p.add_argument("--out", default="learning_curves.png", help="PNG to write")

    study_commands.add_parser(sub, fw.prog)
    sub.add_parser("tasks", help="list the valid tasks and the paper preset's budget and action repeat")
    return parser


# ------------------------------------------------------------------------------------------- train
def resolve_configs(fw: Framework, args):
    """All configs of the command, validated; raises ConfigError before anything is compiled."""
    overrides = configs.parse_overrides(args.set, fw.config_class)
    for name in _field_names(fw):
        value = getattr(args, f"field_{name}")
        if value is not None:
            overrides[name] = configs.parse_value(name, value, fw.config_class)
    seeds = configs.parse_seeds(args.seeds)
    reps = [r.strip() for r in args.representation.split(",") if r.strip()]
    if not reps:
        raise ConfigError("--repr: give at least one representation, e.g. sf2 or none,sf2")
    if len(set(reps)) != len(reps):
        raise ConfigError(f"--repr {args.representation!r} repeats a representation")
    cfgs = []
    for rep in reps:
        cfg = configs.make_config(args.config, args.task, algo=args.algo, representation=rep,
                                  overrides=overrides, config_class=fw.config_class)
        cfgs.append(fw.validate(cfg, seeds))
    return cfgs, seeds


def _setup_jax(compile_cache: str):
    """JAX's persistent compilation cache (both cores: the Playground envs are JAX programs)."""
    import jax

    if compile_cache:
        Path(compile_cache).mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", compile_cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def _train(fw: Framework, args) -> int:
    cfgs, seeds = resolve_configs(fw, args)
    out = Path(args.out)
    several = len(cfgs) > 1
    plan = [(cfg, out / f"{cfg.algo}-{cfg.representation}" if several else out) for cfg in cfgs]
    RunFolder(out).check_usable()
    for _, folder in plan:  # every run folder is checked before anything is compiled
        if args.fresh:
            RunFolder(folder).check_usable()
        else:
            RunFolder(folder).preflight()
    _setup_jax(args.compile_cache)
    folders, seconds = [], {}
    for cfg, folder in plan:
        label = fw.method_label(cfg.algo, cfg.representation)
        print(f"== {label} on {cfg.task}, seeds {','.join(map(str, seeds))} → {folder}", file=sys.stderr)
        t0 = time.time()
        result = fw.train(cfg, seeds, folder, resume=not args.no_resume, fresh=args.fresh,
                          progress=not args.no_progress, stop_after_epoch=args.stop_after_epoch)
        # the training's own wall time (a rerun of a finished run takes seconds)
        seconds[label] = max((r.get("walltime", 0.0) for r in result.rows), default=time.time() - t0)
        folders.append(folder)
    table = plotting.final_table(folders)
    if several:
        plotting.plot_runs(folders, out / "comparison.png")
    print_table(table, seconds)
    if several:
        print(f"curves: {out / 'comparison.png'}")
    else:
        print(f"run folder: {folders[0]} (metrics.jsonl, learning_curve.png, checkpoints/)")
    return 0


def print_table(table, seconds=None) -> None:
    """The final-return table of `plotting.final_table` (and the wall time per method, if given): mean
    over seeds, its 95% bootstrap interval, and each seed's return."""
    head = (f"{'task':22} {'method':12} {'seeds':>5} {'env steps':>10} {'final eval return':>18} "
            f"{'95% CI':>17}  per seed")
    if seconds:
        head += f" {'| wall time':>12}"
    print(head)
    print("-" * len(head))
    for row in table:
        ci = f"[{row['ci_low']:.1f}, {row['ci_high']:.1f}]" if row["ci_low"] == row["ci_low"] else (
            "n < 3" if row["seeds"] < 3 else "no rliable")
        per_seed = ", ".join(f"{x:.1f}" for x in row["per_seed"])
        line = (f"{row['task']:22} {row['method']:12} {row['seeds']:>5} {row['env_steps']:>10} "
                f"{row['final_return']:>18.1f} {ci:>17}  {per_seed}")
        if seconds:
            s = seconds.get(row["method"])
            line += f" | {(f'{s:.0f} s' if s is not None else '')}"
        print(line)
    if any(r["seeds"] > 1 for r in table):
        print("(final eval return: mean over seeds of each seed's mean over its evaluation episodes; 95% CI: "
              "percentile bootstrap of that mean over seeds (rliable, 5000 resamples); none below 3 seeds, "
              "where it would not be informative, and none without rliable installed)")


# ------------------------------------------------------------------------------------------- eval, plot
def _eval(fw: Framework, args) -> int:
    import numpy as np

    _setup_jax(fw.compile_cache())
    deterministic = True if args.deterministic else (False if args.stochastic else None)
    if args.obs_noise is not None:
        from sf2_studies import robustness

        return robustness.eval_command(fw.evaluate_checkpoint_noises, args, deterministic)
    res = fw.evaluate_checkpoint(args.run, epoch=args.epoch, num_eval_envs=args.episodes,
                              deterministic=deterministic)
    if args.json:
        print(json.dumps(res))
        return 0
    print(f"{args.run}: checkpoint epoch {res['epoch']} ({res['env_steps']} env steps), "
          f"{'deterministic' if res['deterministic'] else 'stochastic'} policy")
    means = []
    for seed, rets in res["returns"].items():
        means.append(np.mean(rets))
        print(f"  seed {seed}: return {np.mean(rets):8.1f} ± {np.std(rets):6.1f} over {len(rets)} episodes")
    print(f"  mean over seeds: {np.mean(means):.1f}")
    return 0


def expand_runs(paths) -> list[Path]:
    """Run folders, with folders that hold run folders replaced by those."""
    from sf2_common.agents.runfolder import RunFolder

    out = []
    for p in map(Path, paths):
        if (p / RunFolder.CONFIG).exists():
            out.append(p)
        elif p.is_dir() and (subs := sorted(c.parent for c in p.glob(f"*/{RunFolder.CONFIG}"))):
            out.extend(subs)
        else:
            raise FileNotFoundError(f"{p} is not a run folder (no {RunFolder.CONFIG}) and holds none")
    return out


def _plot(fw: Framework, args) -> int:
    runs = expand_runs(args.runs)
    try:
        table = plotting.plot_runs(runs, args.out)
    except ValueError as err:  # runs of one method that share no evaluation points
        raise ConfigError(str(err)) from None
    print_table(table)
    print(f"wrote {args.out}")
    return 0


def _tasks(fw: Framework, args) -> int:
    from sf2_common.agents import tasks

    print(f"{'task':24} {'paper budget':>12} {'action repeat':>13}  in paper")
    for task in tasks.valid_tasks():
        print(f"{task:24} {tasks.paper_budget(task):>12,} {tasks.paper_action_repeat(task):>13}  "
              f"{'yes' if task in tasks.PAPER_TASKS else ''}")
    return 0


_HANDLERS = {"train": _train, "eval": _eval, "plot": _plot, "study": study_commands.main, "tasks": _tasks}


_NEGATIVE = re.compile(r"-(\d|\.\d|inf$|nan$)", re.IGNORECASE)


def join_negative_values(argv: list[str]) -> list[str]:
    """`--flag -1e-3` → `--flag=-1e-3`: argparse takes a value starting with '-' for an option unless it
    looks like a plain negative number (-0.001, not -1e-3 or -inf), so a negative value that is not reaches
    the config's validation, which names the field and what is valid."""
    out: list[str] = []
    for tok in argv:
        if out and _NEGATIVE.match(tok) and out[-1].startswith("--") and "=" not in out[-1]:
            out[-1] = f"{out[-1]}={tok}"
        else:
            out.append(tok)
    return out


def main(fw: Framework, argv=None) -> int:
    """Run one command; the exit status: 0 done, 2 bad input (a ConfigError, e.g. a run folder that
    cannot be used or a checkpoint of another run; an OSError naming the path), 3 training diverged,
    130 interrupted."""
    for name, value in fw.env_defaults:
        os.environ.setdefault(name, value)
    argv = join_negative_values(list(sys.argv[1:] if argv is None else argv))
    args = build_parser(fw).parse_args(argv)
    args.argv = argv
    try:
        return _HANDLERS[args.command](fw, args)
    except (ConfigError, FileNotFoundError) as err:
        print(f"{fw.prog} {args.command}: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:  # a path that cannot be written or read: the message names it
        where = f"{err.filename}: " if err.filename else ""
        print(f"{fw.prog} {args.command}: error: {where}{err.strerror or err}", file=sys.stderr)
        return 2
    except TrainingDiverged as err:
        print(f"{fw.prog} {args.command}: {err}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print(f"{fw.prog} {args.command}: interrupted; rerun the same command to resume from the last "
              f"checkpoint", file=sys.stderr)
        return 130
