"""The pieces of `sf2-jax` and `sf2-torch`: each core's cli.py builds its parser from these and calls its own
trainer; other packages' commands (`study`) come by the entry points `sf2.commands`. Exit status: 0 done,
2 bad input (before anything is compiled), 3 a NaN/inf loss stopped training, 130 interrupted."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import sys
import time
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

from sf2_common.agents import configs, loggers, plotting
from sf2_common.agents.hostloop import TrainingDiverged
from sf2_common.agents.runfolder import RunFolder
from sf2_common.errors import ConfigError

__all__ = ["Backend", "BACKENDS_GROUP", "backend_of", "COMMANDS_GROUP", "PLUGINS", "compile_cache",
           "new_parser", "add_train_parser", "add_shared_parsers", "plugin_commands", "resolve_configs",
           "train_runs", "print_table", "eval_command", "expand_runs", "plot_command", "tasks_command",
           "join_negative_values", "run"]

COMMANDS_GROUP = "sf2.commands"
BACKENDS_GROUP = "sf2.backends"   # each core's `backend()`, for a study whose methods run on another core
# commands other packages provide: name → how to get them (said when one is asked for and absent)
PLUGINS = {"study": "the study commands come with sf2-studies: pip install packages/sf2-studies"}
_RUN_FIELDS_SKIPPED = ("task", "algo", "representation")


@dataclasses.dataclass(frozen=True)
class Backend:
    """What a command of another package (`sf2.commands`) gets from the core that runs it."""

    prog: str                       # "sf2-jax"
    name: str                       # "jax" (study files' `framework`)
    cli_module: str                 # "sf2_jax.cli": children run `python -m cli_module train ...`
    make_config: Callable           # (preset, task, algo, representation, overrides) -> TrainConfig
    validate: Callable              # (cfg, seeds) -> cfg, raises ConfigError


def backend_of(name: str, running: Backend) -> Backend:
    """The `Backend` of the core `name` ("jax", "torch"): `running` itself, or the installed core's.

    Args:
      name: the framework a study's method runs on.
      running: the backend of the core running the command.

    Returns:
      That core's `Backend` (from the entry point group `sf2.backends`).

    Raises:
      ConfigError: that core is not installed; the message says how to install it.
    """
    if name == running.name:
        return running
    found = {ep.name: ep for ep in metadata.entry_points(group=BACKENDS_GROUP)}
    if name not in found:
        have = ", ".join(sorted(found)) or "none"
        raise ConfigError(f"framework {name!r} is not installed (installed: {have}); pip install "
                          f"packages/sf2-core-{name}[train] beside {running.prog}")
    return found[name].load()()


def compile_cache(prog: str, cache_env: str) -> str:
    """The folder of JAX's persistent compilation cache: `$cache_env`, else ~/.cache/PROG/xla."""
    return os.environ.get(cache_env, str(Path.home() / ".cache" / prog / "xla"))


def new_parser(prog: str, doc: str):
    """(An argument parser described by the first paragraph of `doc`, its subparsers for the commands)."""
    parser = argparse.ArgumentParser(prog=prog, description=doc.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    return parser, parser.add_subparsers(dest="command", required=True)


def _field_names(config_class) -> list[str]:
    return [f.name for f in dataclasses.fields(config_class) if f.name not in _RUN_FIELDS_SKIPPED]


def add_train_parser(sub, prog: str, config_class, seeds_help: str, cache_env: str) -> None:
    """Add `train` to the subparsers `sub`, with a flag for every field of the core's `config_class`;
    `seeds_help` says how the core runs several seeds, `cache_env` names the compilation cache's variable."""
    t = sub.add_parser("train", help="train one or more methods over several seeds",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       epilog="Environment: SF2_DEADLINE=<Unix seconds> (the time a batch system kills the "
                       "job) also checkpoints the last epoch that ends before it, so a resume trains no "
                       "epoch twice.")
    t.add_argument("--task", required=True, help="a Playground task, e.g. CartpoleBalance or Go1Getup; a "
                   f"MinAtar game, e.g. minatar-breakout (`{prog} tasks` lists them); or your own env, "
                   "module:callable or an entry point of sf2.tasks (docs/agents.md)")
    t.add_argument("--algo", default="td3", help="td3, sac or fpo (Playground); ppo (MinAtar)")
    t.add_argument("--repr", default="sf2", dest="representation",
                   help="representation: none (vanilla), sf2; with sf2-baselines installed also sim, simlap, "
                   "simlap_authors, spr; with ppo: none, sf2, sf2-ae; a comma list trains each and compares "
                   "them")
    t.add_argument("--config", default="quick", help="preset: paper (Table 1 + the authors' settings) or "
                   "quick (small networks and budget for a CPU)")
    t.add_argument("--seeds", default="0", help=f"e.g. 0-3 or 0,2,5; {seeds_help}")
    t.add_argument("--out", required=True, help="run folder (one method) or parent folder (several)")
    t.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override any config field (repeatable)")
    t.add_argument("--fresh", action="store_true", help="discard what --out holds and start over")
    t.add_argument("--no-resume", action="store_true",
                   help="refuse to continue a run folder that holds checkpoints")
    t.add_argument("--no-progress", action="store_true", help="no progress bar")
    t.add_argument("--log", default=None, metavar="SINKS", help="also log every metrics.jsonl row to "
                   "tensorboard, wandb, or tensorboard,wandb (in the run folder; wandb offline unless "
                   "WANDB_MODE is set; docs/agents.md, Loggers)")
    t.add_argument("--stop-after-epoch", type=int, default=None, help=argparse.SUPPRESS)
    t.add_argument("--compile-cache", default=compile_cache(prog, cache_env),
                   help="folder for JAX's persistent compilation cache, reused by later runs of the same "
                   f"config ('' turns it off; env {cache_env})")
    fields = t.add_argument_group("config fields (each overrides the preset)")
    for name in _field_names(config_class):
        fields.add_argument(f"--{name.replace('_', '-')}", dest=f"field_{name}", default=None, metavar="V",
                            help=argparse.SUPPRESS if name in ("keep_checkpoints",) else None)


def add_shared_parsers(sub, prog: str) -> None:
    """Add the commands that take nothing of the core: eval, plot, the plugin commands (`sf2.commands`:
    each found, and for each of `PLUGINS` not installed one that says how to install it), tasks."""
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
    plugins = plugin_commands()
    for name, command in plugins.items():
        command.add_parser(sub, prog)
        sub.choices[name].set_defaults(sf2_plugin=command)
    for name in sorted(PLUGINS.keys() - plugins.keys()):
        missing = sub.add_parser(name, help=f"({PLUGINS[name]})", add_help=False)
        missing.set_defaults(sf2_missing=PLUGINS[name])
    sub.add_parser("tasks", help="list the valid tasks and the paper preset's budget and action repeat")


def plugin_commands() -> dict:
    """{name: command} of the entry-point group `sf2.commands`; a command has `add_parser(subparsers,
    prog)` and `main(backend, args) -> int`."""
    found = {}
    for ep in metadata.entry_points(group=COMMANDS_GROUP):
        found.setdefault(ep.name, ep)
    return {name: ep.load() for name, ep in sorted(found.items())}


# ------------------------------------------------------------------------------------------- train
def resolve_configs(args, config_class, make_config: Callable, validate: Callable):
    """(configs, one per representation of `--repr`, seeds) of parsed `train` arguments, made and checked
    by the core's `make_config` and `validate` before anything is compiled; ConfigError on bad input."""
    overrides = configs.parse_overrides(args.set, config_class)
    for name in _field_names(config_class):
        value = getattr(args, f"field_{name}")
        if value is not None:
            overrides[name] = configs.parse_value(name, value, config_class)
    seeds = configs.parse_seeds(args.seeds)
    reps = [r.strip() for r in args.representation.split(",") if r.strip()]
    if not reps:
        raise ConfigError("--repr: give at least one representation, e.g. sf2 or none,sf2")
    if len(set(reps)) != len(reps):
        raise ConfigError(f"--repr {args.representation!r} repeats a representation")
    cfgs = [validate(make_config(args.config, args.task, args.algo, rep, overrides), seeds) for rep in reps]
    return cfgs, seeds


def _setup_jax(cache: str) -> None:
    """JAX's persistent compilation cache (both cores: the Playground envs are JAX programs)."""
    import jax

    if cache:
        Path(cache).mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def train_runs(args, cfgs, seeds, train: Callable, method_label: Callable) -> int:
    """`train`: each of `resolve_configs`' configs into its run folder with the core's `train`, then the
    final-return table (`method_label(algo, representation)` names each method); exit status 0."""
    out = Path(args.out)
    log = loggers.parse_log(args.log)   # a missing package stops here, before anything is compiled
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
        label = method_label(cfg.algo, cfg.representation)
        print(f"== {label} on {cfg.task}, seeds {','.join(map(str, seeds))} → {folder}", file=sys.stderr)
        t0 = time.time()
        result = train(cfg, seeds, folder, resume=not args.no_resume, fresh=args.fresh,
                       progress=not args.no_progress, stop_after_epoch=args.stop_after_epoch, log=log)
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
    """Print `plotting.final_table`'s rows: mean over seeds, its 95% bootstrap interval, each seed's
    return, and the wall time per method if `seconds` ({method: seconds}) is given."""
    head = (f"{'task':22} {'method':12} {'seeds':>5} {'env steps':>10} {'final eval return':>18} "
            f"{'95% CI':>17}  per seed")
    if seconds:
        head += f" {'| wall time':>12}"
    print(head)
    print("-" * len(head))
    for row in table:
        ci = f"[{row['ci_low']:.1f}, {row['ci_high']:.1f}]" if row["ci_low"] == row["ci_low"] else "n < 3"
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
              "where it would not be informative)")


# ------------------------------------------------------------------------------------------- eval, plot
def eval_command(args, evaluate_checkpoint: Callable, evaluate_checkpoint_noises: Callable,
                 cache: str) -> int:
    """`eval`: a checkpoint's returns per seed (or as JSON), or `eval --obs-noise`, by the core's two
    evaluation functions, with JAX's compilation cache in the folder `cache`; exit status 0."""
    import numpy as np

    from sf2_common.agents import obsnoise

    _setup_jax(cache)
    deterministic = True if args.deterministic else (False if args.stochastic else None)
    if args.obs_noise is not None:
        return obsnoise.eval_command(evaluate_checkpoint_noises, args, deterministic)
    res = evaluate_checkpoint(args.run, epoch=args.epoch, num_eval_envs=args.episodes,
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
    out = []
    for p in map(Path, paths):
        if (p / RunFolder.CONFIG).exists():
            out.append(p)
        elif p.is_dir() and (subs := sorted(c.parent for c in p.glob(f"*/{RunFolder.CONFIG}"))):
            out.extend(subs)
        else:
            raise FileNotFoundError(f"{p} is not a run folder (no {RunFolder.CONFIG}) and holds none")
    return out


def plot_command(args) -> int:
    """`plot`: the learning curves of run folders and their final-return table; exit status 0."""
    runs = expand_runs(args.runs)
    try:
        table = plotting.plot_runs(runs, args.out)
    except ValueError as err:  # runs of one method that share no evaluation points
        raise ConfigError(str(err)) from None
    print_table(table)
    print(f"wrote {args.out}")
    return 0


def tasks_command(args) -> int:
    """`tasks`: the valid tasks with their kind (Playground's suites, MinAtar, users' entry points), the
    paper preset's budget, episode length and action repeat; without Playground, its install line instead
    of its tasks; then how to name your own environment; exit status 0."""
    from sf2_common.agents import tasks

    try:
        names, missing = tasks.valid_tasks(), None
    except ImportError:
        names, missing = tuple(tasks.TASKS), tasks.KINDS["playground"]
    print(f"{'task':36} {'kind':23} {'paper budget':>12} {'episode':>7} {'repeat':>6}  in paper")
    for task in names:
        print(f"{task:36} {tasks.task_kind(task).label:23} {tasks.paper_budget(task):>12,} "
              f"{tasks.episode_length(task):>7} {tasks.paper_action_repeat(task):>6}  "
              f"{'yes' if task in tasks.PAPER_TASKS else ''}".rstrip())
    if missing is not None:
        print(f"(Playground tasks: not installed; {missing.install})")
    print(f"(your own environment: --task module:callable, or an entry point of {tasks.GROUP!r}; "
          f"docs/agents.md)")
    return 0


# ------------------------------------------------------------------------------------------- running
_NEGATIVE = re.compile(r"-(\d|\.\d|inf$|nan$)", re.IGNORECASE)


def join_negative_values(argv: list[str]) -> list[str]:
    """`--flag -1e-3` → `--flag=-1e-3`: argparse takes '-1e-3' or '-inf' (not '-0.001') for an option, so
    such a value reaches the config's validation, which names the field and what is valid."""
    out: list[str] = []
    for tok in argv:
        if out and _NEGATIVE.match(tok) and out[-1].startswith("--") and "=" not in out[-1]:
            out[-1] = f"{out[-1]}={tok}"
        else:
            out.append(tok)
    return out


def run(prog: str, parser, commands: dict, backend: Callable, argv=None) -> int:
    """Parse `argv` (default: sys.argv[1:]) with the core's `parser` and run the command: one of the core's
    `commands` ({name: handler(args)}) or a plugin command, given `backend()`.

    Returns:
        The exit status: 0 done, 2 bad input (a ConfigError, e.g. a run folder that cannot be used or a
        checkpoint of another run; an OSError naming the path), 3 training diverged, 130 interrupted.
    """
    argv = join_negative_values(list(sys.argv[1:] if argv is None else argv))
    args, unknown = parser.parse_known_args(argv)
    if unknown and not hasattr(args, "sf2_missing"):
        parser.parse_args(argv)     # argparse's own message, exit status 2
    args.argv = argv
    try:
        if hasattr(args, "sf2_missing"):
            raise ConfigError(args.sf2_missing)
        if args.command in commands:
            return commands[args.command](args)
        return args.sf2_plugin.main(backend(), args)
    except (ConfigError, FileNotFoundError) as err:
        print(f"{prog} {args.command}: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:  # a path that cannot be written or read: the message names it
        where = f"{err.filename}: " if err.filename else ""
        print(f"{prog} {args.command}: error: {where}{err.strerror or err}", file=sys.stderr)
        return 2
    except TrainingDiverged as err:
        print(f"{prog} {args.command}: {err}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print(f"{prog} {args.command}: interrupted; rerun the same command to resume from the last "
              f"checkpoint", file=sys.stderr)
        return 130
