"""Command line of the two-Gaussian study: `python -m sf2_jax.experiments.two_gaussians --help`."""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time
from pathlib import Path

from sf2_common.agents.configs import parse_seeds
from sf2_common.errors import ConfigError

from .models import LABELS, MODELS, Settings, make_model
from .train import run_grid

EXAMPLE = ("python -m sf2_jax.experiments.two_gaussians --out results/two-gaussians --seeds 0-4 "
           "--gammas 0.5,0.9,0.99")


def parse_gammas(text: str) -> tuple[float, ...]:
    try:
        gammas = tuple(float(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise ConfigError(f"gammas {text!r} are invalid: use comma-separated numbers, "
                          "e.g. 0.5,0.9,0.99") from None
    if not gammas or any(not 0.0 < g < 1.0 for g in gammas):
        raise ConfigError(f"gammas {text!r} are invalid: each must lie strictly between 0 and 1, "
                          "e.g. 0.5,0.9,0.99")
    if len(set(gammas)) != len(gammas):
        raise ConfigError(f"gammas {text!r} contain duplicates")
    return gammas


def parse_models(text: str) -> tuple[str, ...]:
    models = tuple(t.strip() for t in text.split(",") if t.strip())
    bad = [m for m in models if m not in MODELS]
    if bad or not models:
        raise ConfigError(f"models {text!r} are invalid: choose from {', '.join(MODELS)} (comma-separated)")
    return models


def parse_hidden(text: str) -> tuple[int, ...]:
    try:
        hidden = tuple(int(t) for t in text.split(",") if t.strip())
    except ValueError:
        hidden = ()
    if not hidden or any(h < 1 for h in hidden):
        raise ConfigError(f"hidden {text!r} is invalid: comma-separated positive widths, e.g. 256 or 256,256")
    return hidden


def machine() -> str:
    import jax

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    load = f", load average at start {os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else ""
    return (f"{cpu}, {os.cpu_count()} CPU cores ({jax.default_backend()} backend, JAX {jax.__version__}, "
            f"float32){load}")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m sf2_jax.experiments.two_gaussians",
                                description="Two-Gaussian study of Appendix A.2-A.3 (Figures 3 and 4).",
                                epilog=f"example: {EXAMPLE}")
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument("--seeds", default="0-4", help="e.g. 0-4 or 0,2,5 (default 0-4)")
    p.add_argument("--gammas", default="0.5,0.9,0.99", help="weights of N(-2, 0.3^2) (default 0.5,0.9,0.99)")
    p.add_argument("--models", default=",".join(MODELS), help=f"subset of {','.join(MODELS)}")
    p.add_argument("--hidden", default=",".join(map(str, Settings.hidden)),
                   help="hidden widths of every MLP, e.g. 256 (the default: one layer) or 256,256")
    p.add_argument("--steps", type=int, default=Settings.steps, help="training steps (default 1500)")
    p.add_argument("--batch-size", type=int, default=Settings.batch_size,
                   help="samples per step (the explicit objective: per component) (default 32)")
    return p


def main(argv=None) -> int:
    start, cpu_start = time.perf_counter(), time.process_time()
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    try:
        seeds, gammas = parse_seeds(args.seeds), parse_gammas(args.gammas)
        models, hidden = parse_models(args.models), parse_hidden(args.hidden)
        if args.steps < 1:
            raise ConfigError(f"steps = {args.steps} is invalid: must be >= 1")
        if args.batch_size < 1:
            raise ConfigError(f"batch size = {args.batch_size} is invalid: must be >= 1")
        blocking = next((p for p in (Path(args.out), *Path(args.out).parents) if p.exists()), None)
        if blocking is not None and not blocking.is_dir():   # before the minutes of training, not after
            raise ConfigError(f"--out {args.out}: {blocking} is a file, not a folder")
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    settings = Settings(steps=args.steps, batch_size=args.batch_size, hidden=hidden)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    host = machine()

    samples, seconds = {}, {}
    for name in models:
        t = time.perf_counter()
        samples[name], _ = run_grid(make_model(name, settings), settings, gammas, seeds)
        seconds[name] = time.perf_counter() - t
        print(f"{LABELS[name]}: {len(gammas)} gammas x {len(seeds)} seeds in {seconds[name]:.1f} s",
              file=sys.stderr)

    from . import report

    res = report.Results(gammas, seeds, settings.eval_steps(), samples, seconds)
    report.write_csvs(res, out)
    report.plot_w1_curves(res, out)
    report.plot_histograms(res, out)
    command = "python -m sf2_jax.experiments.two_gaussians " + shlex.join(argv)
    wall = time.perf_counter() - start
    cpu = time.process_time() - cpu_start
    report.write_summary(res, out, command, wall, cpu, host, settings.describe())
    (out / "command.txt").write_text(f"{command}\n# wall time {wall:.0f} s, CPU time {cpu:.0f} s "
                                     f"(measured by the program); {host}\n")
    print(report.summary_table(res))
    print(report.agreement(res))
    print(f"wall time {wall:.0f} s; wrote {out}/", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
