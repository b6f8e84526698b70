"""`sf2-jax`: train, evaluate and plot TD3/SAC agents, vanilla or with SF², on MuJoCo Playground.

    sf2-jax train --task CartpoleBalance --algo td3 --repr sf2 --config quick --seeds 0-3 --out runs/cp
    sf2-jax train --task CartpoleBalance --algo td3 --repr sf2,none --config quick --seeds 0-1 --out runs/cmp
    sf2-jax eval runs/cp [--epoch N] [--episodes 20] [--stochastic]
    sf2-jax plot runs/cmp/td3-sf2 runs/cmp/td3-none --out curves.png
    sf2-jax tasks

Every `TrainConfig` field can be overridden, either with its own flag (`--batch-size 128`,
`--hidden-sizes 64,64`) or with `--set batch_size=128` (repeatable). Bad input (unknown task, algo or
representation, a combination that does not exist, a budget smaller than the prefill, ...) is reported
before anything is compiled; exit status 2. A NaN/inf loss stops the run with exit status 3.
Heavy imports (jax, playground) happen after the arguments are parsed, so `--help` is instant.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

__all__ = ["main", "build_parser"]

_RUN_FIELDS_SKIPPED = ("task", "algo", "representation")


def _field_names():
    from sf2_jax.agents.configs import TrainConfig

    return [f.name for f in dataclasses.fields(TrainConfig) if f.name not in _RUN_FIELDS_SKIPPED]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sf2-jax", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)

    t = sub.add_parser("train", help="train one or more methods over several seeds (vmapped)",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    t.add_argument("--task", required=True, help="Playground DM Control task, e.g. CartpoleBalance "
                   "(`sf2-jax tasks` lists them)")
    t.add_argument("--algo", default="td3", help="td3 or sac")
    t.add_argument("--repr", default="sf2", dest="representation",
                   help="representation: none (vanilla), sf2; a comma list trains each and compares them")
    t.add_argument("--config", default="quick", help="preset: paper (Table 1 + the authors' settings) or "
                   "quick (small networks and budget for a CPU)")
    t.add_argument("--seeds", default="0", help="e.g. 0-3 or 0,2,5; all seeds run in one vmapped program")
    t.add_argument("--out", required=True, help="run folder (one method) or parent folder (several)")
    t.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override any config field (repeatable)")
    t.add_argument("--fresh", action="store_true", help="discard what --out holds and start over")
    t.add_argument("--no-resume", action="store_true",
                   help="refuse to continue a run folder that holds checkpoints")
    t.add_argument("--no-progress", action="store_true", help="no progress bar")
    t.add_argument("--stop-after-epoch", type=int, default=None, help=argparse.SUPPRESS)
    t.add_argument("--compile-cache", default=os.environ.get(
                       "SF2_JAX_COMPILE_CACHE", str(Path.home() / ".cache" / "sf2-jax" / "xla")),
                   help="folder for JAX's persistent compilation cache, reused by later runs of the same "
                   "config ('' turns it off; env SF2_JAX_COMPILE_CACHE)")
    fields = t.add_argument_group("config fields (each overrides the preset)")
    for name in _field_names():
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

    p = sub.add_parser("plot", help="learning curves of several run folders (mean and 95%% CI per method)")
    p.add_argument("runs", nargs="+", help="run folders (folders holding run folders are expanded)")
    p.add_argument("--out", default="learning_curves.png", help="PNG to write")

    sub.add_parser("tasks", help="list the valid tasks and the paper preset's budget and action repeat")
    return parser


# ------------------------------------------------------------------------------------------- train
def _resolve_configs(args):
    """All configs of the command, validated; raises ConfigError before anything is compiled."""
    from sf2_jax.agents import configs

    overrides = configs.parse_overrides(args.set)
    for name in _field_names():
        value = getattr(args, f"field_{name}")
        if value is not None:
            overrides[name] = configs.parse_value(name, value)
    seeds = configs.parse_seeds(args.seeds)
    reps = [r.strip() for r in args.representation.split(",") if r.strip()]
    if not reps:
        raise configs.ConfigError("--repr: give at least one representation, e.g. sf2 or none,sf2")
    if len(set(reps)) != len(reps):
        raise configs.ConfigError(f"--repr {args.representation!r} repeats a representation")
    cfgs = []
    for rep in reps:
        cfg = configs.make_config(args.config, args.task, algo=args.algo, representation=rep,
                                  overrides=overrides)
        cfgs.append(configs.validate(cfg, seeds))
    return cfgs, seeds


def _setup_jax(compile_cache: str):
    import jax

    if compile_cache:
        Path(compile_cache).mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", compile_cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def _train(args) -> int:
    from sf2_jax.agents import plotting
    from sf2_jax.agents.trainer import train

    cfgs, seeds = _resolve_configs(args)
    _setup_jax(args.compile_cache)
    out = Path(args.out)
    several = len(cfgs) > 1
    folders, seconds = [], {}
    for cfg in cfgs:
        folder = out / f"{cfg.algo}-{cfg.representation}" if several else out
        label = plotting.method_label(cfg.algo, cfg.representation)
        print(f"== {label} on {cfg.task}, seeds {','.join(map(str, seeds))} → {folder}", file=sys.stderr)
        t0 = time.time()
        train(cfg, seeds, folder, resume=not args.no_resume, fresh=args.fresh,
              progress=not args.no_progress, stop_after_epoch=args.stop_after_epoch)
        seconds[label] = time.time() - t0
        folders.append(folder)
    table = plotting.final_table(folders)
    if several:
        plotting.plot_runs(folders, out / "comparison.png")
    _print_table(table, seconds)
    if several:
        print(f"curves: {out / 'comparison.png'}")
    else:
        print(f"run folder: {folders[0]} (metrics.jsonl, learning_curve.png, checkpoints/)")
    return 0


def _print_table(table, seconds=None):
    head = f"{'task':22} {'method':10} {'seeds':>5} {'env steps':>10} {'final eval return':>22}"
    if seconds:
        head += f" {'wall time':>10}"
    print(head)
    print("-" * len(head))
    for row in table:
        ret = f"{row['final_return']:.1f}"
        if row["seeds"] > 1:
            ret += f" ± {row['ci95']:.1f}"
        line = f"{row['task']:22} {row['method']:10} {row['seeds']:>5} {row['env_steps']:>10} {ret:>22}"
        if seconds:
            s = seconds.get(row["method"])
            line += f" {(f'{s:.0f} s' if s is not None else ''):>10}"
        print(line)
    if any(r["seeds"] > 1 for r in table):
        print("(± is the 95% t-interval of the mean over seeds; per-seed returns are in metrics.jsonl)")


# ------------------------------------------------------------------------------------------- eval, plot
def _eval(args) -> int:
    from sf2_jax.agents.trainer import evaluate_checkpoint

    _setup_jax(os.environ.get("SF2_JAX_COMPILE_CACHE", str(Path.home() / ".cache" / "sf2-jax" / "xla")))
    deterministic = True if args.deterministic else (False if args.stochastic else None)
    res = evaluate_checkpoint(args.run, epoch=args.epoch, num_eval_envs=args.episodes,
                              deterministic=deterministic)
    if args.json:
        print(json.dumps(res))
        return 0
    import numpy as np

    print(f"{args.run}: checkpoint epoch {res['epoch']} ({res['env_steps']} env steps), "
          f"{'deterministic' if res['deterministic'] else 'stochastic'} policy")
    means = []
    for seed, rets in res["returns"].items():
        means.append(np.mean(rets))
        print(f"  seed {seed}: return {np.mean(rets):8.1f} ± {np.std(rets):6.1f} over {len(rets)} episodes")
    print(f"  mean over seeds: {np.mean(means):.1f}")
    return 0


def _expand_runs(paths) -> list[Path]:
    from sf2_jax.agents.runfolder import RunFolder

    out = []
    for p in map(Path, paths):
        if (p / RunFolder.CONFIG).exists():
            out.append(p)
        elif p.is_dir() and (subs := sorted(c.parent for c in p.glob(f"*/{RunFolder.CONFIG}"))):
            out.extend(subs)
        else:
            raise FileNotFoundError(f"{p} is not a run folder (no {RunFolder.CONFIG}) and holds none")
    return out


def _plot(args) -> int:
    from sf2_jax.agents import plotting
    from sf2_jax.errors import ConfigError

    runs = _expand_runs(args.runs)
    try:
        table = plotting.plot_runs(runs, args.out)
    except ValueError as err:
        raise ConfigError(str(err)) from None
    _print_table(table)
    print(f"wrote {args.out}")
    return 0


def _tasks(args) -> int:
    from sf2_jax.agents import envs

    print(f"{'task':24} {'paper budget':>12} {'action repeat':>13}  in paper")
    for task in envs.valid_tasks():
        print(f"{task:24} {envs.paper_budget(task):>12,} {envs.paper_action_repeat(task):>13}  "
              f"{'yes' if task in envs.PAPER_TASKS else ''}")
    return 0


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from sf2_jax.errors import ConfigError

    handlers = {"train": _train, "eval": _eval, "plot": _plot, "tasks": _tasks}
    try:
        return handlers[args.command](args)
    except ConfigError as err:
        print(f"sf2-jax {args.command}: error: {err}", file=sys.stderr)
        return 2
    except FileNotFoundError as err:
        print(f"sf2-jax {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"sf2-jax {args.command}: interrupted; rerun the same command to resume from the last "
              f"checkpoint", file=sys.stderr)
        return 130
    except Exception as err:
        from sf2_jax.agents.checkpoint import CheckpointMismatch
        from sf2_jax.agents.trainer import TrainingDiverged

        if isinstance(err, TrainingDiverged):
            print(f"sf2-jax {args.command}: {err}", file=sys.stderr)
            return 3
        if isinstance(err, CheckpointMismatch):
            print(f"sf2-jax {args.command}: error: {err}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
