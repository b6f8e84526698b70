"""Issue 12's throughput targets, read from result folders: each target's measured figure, whether it is
reached, and the rows it comes from.

    python -m bench.targets RESULT_FOLDER [RESULT_FOLDER ...] [--out targets.md]
    python -m bench.targets bench/results/h200x2/55-h200-column bench/results/h200x2/56-h200-column-rest

Reads every `throughput.csv` (`python -m bench.agent_throughput`) and `physics.csv` (`python -m
bench.physics`) below the folders. `bash scripts/gpu_column.sh` writes one folder that holds them all. The
rows of a folder named `two-gpus-<i>` are one process per GPU running at the same time. Their sum is the
several-GPU aggregate, compared with the one-GPU row of the same case elsewhere.

The targets (issue 12; H200, `paper` preset, TD3, medians after compile):
- physics of every paper task ≥ 100,000 env steps/s at 1024 envs;
- TD3+SF², AcrobotSwingup, one seed ≥ 15,000 env steps/s, at the preset's learner precision;
- TD3+SF², AcrobotSwingup, all seeds on one GPU (≤ 32) ≥ 150,000;
- TD3+SF², CheetahRun, 8 seeds ≥ 50,000;
- 2 GPUs ≥ 1.9× one GPU's aggregate;
- TD3+SF² / TD3 time per env step ≤ 1.5× (rows of one process: same folder, seeds and precision);
- the torch trainer at one seed ≥ 0.8× the JAX trainer (the same process where there is one).
"""

from __future__ import annotations

import argparse
import csv
import sys
from dataclasses import dataclass
from pathlib import Path

PHYSICS_MIN, ONE_SEED_MIN, ALL_SEEDS_MIN, CHEETAH_MIN = 100_000, 15_000, 150_000, 50_000
TWO_GPUS_MIN, SF2_OVER_TD3_MAX, TORCH_OVER_JAX_MIN = 1.9, 1.5, 0.8
MAX_SEEDS_ONE_GPU = 32
_WRITER = {"throughput.csv": "bench.agent_throughput", "physics.csv": "bench.physics"}


@dataclass(frozen=True)
class Row:
    """One `throughput.csv` row and the folder it came from."""

    folder: str
    framework: str
    task: str
    rep: str
    seeds: int
    precision: str
    sps: float

    @property
    def two_gpus(self) -> bool:
        return Path(self.folder).name.startswith("two-gpus-")

    def label(self) -> str:
        return f"{self.folder}: {self.framework} {self.rep} x{self.seeds} {self.precision} {self.sps:,.0f}"


@dataclass(frozen=True)
class Target:
    name: str
    measured: str
    reached: bool | None          # None: no rows for it
    sources: tuple[str, ...]


def read(folders) -> tuple[list[Row], dict[str, tuple[float, str]]]:
    """(throughput rows, {task: (env steps/s at 1024 envs, folder)}) below `folders`. Raises
    `FileNotFoundError` naming a folder that does not exist or holds neither file, `ValueError` naming the
    file and line of a row that is not the bench's."""
    rows, physics = [], {}
    for folder in map(Path, folders):
        if not folder.is_dir():
            raise FileNotFoundError(f"no result folder {folder}")
        files = sorted(folder.rglob("throughput.csv")) + sorted(folder.rglob("physics.csv"))
        if not files:
            raise FileNotFoundError(f"{folder} holds no throughput.csv or physics.csv")
        for f in files:
            with f.open(newline="") as fh:
                for line, r in enumerate(csv.DictReader(fh), start=2):
                    try:
                        if f.name == "physics.csv":
                            if int(r["num_envs"]) == 1024:
                                physics[r["task"]] = (float(r["env_steps_per_s"]), str(f.parent))
                        elif r["algo"] == "td3":
                            rows.append(Row(str(f.parent), r["framework"], r["task"], r["rep"],
                                            int(r["seeds"]), r["learner_precision"], float(r["sps_total"])))
                    except (KeyError, TypeError, ValueError) as err:
                        raise ValueError(f"{f}, line {line}: not a row of `python -m {_WRITER[f.name]}` "
                                         f"({type(err).__name__}: {err})") from None
    return rows, physics


def _pick(rows, **want) -> list[Row]:
    return [r for r in rows if all(getattr(r, k) == v for k, v in want.items())]


def _best(rows) -> Row | None:
    return max(rows, key=lambda r: r.sps, default=None)


def evaluate(rows: list[Row], physics: dict, tasks: tuple[str, ...], precision: str) -> list[Target]:
    """The targets (module docstring) from `rows` and `physics`; `tasks`: the paper's tasks that the
    physics target covers; `precision`: the preset's learner precision."""
    one_gpu = [r for r in rows if not r.two_gpus]
    jax_acro = _pick(one_gpu, framework="jax", task="AcrobotSwingup")
    out = []

    missing = [t for t in tasks if t not in physics]
    if physics:
        low = min(physics, key=lambda t: physics[t][0])
        measured = f"lowest {low} {physics[low][0]:,.0f} ({len(physics)} tasks)" + (
            f"; missing {', '.join(missing)}" if missing else "")
        out.append(Target(f"physics of every task ≥ {PHYSICS_MIN:,} at 1024 envs", measured,
                          not missing and physics[low][0] >= PHYSICS_MIN,
                          tuple(sorted({f for _, f in physics.values()}))))
    else:
        out.append(Target(f"physics of every task ≥ {PHYSICS_MIN:,} at 1024 envs", "no rows", None, ()))

    def threshold(name, candidates, minimum):
        best = _best(candidates)
        if best is None:
            return Target(name, "no rows", None, ())
        others = [f"{r.sps:,.0f} at {r.seeds}" for r in sorted(candidates, key=lambda r: -r.sps)
                  if r is not best]
        return Target(name, f"{best.sps:,.0f} at {best.seeds} seed(s)"
                      + (f" (also {', '.join(others)})" if others else ""),
                      best.sps >= minimum, tuple(r.label() for r in candidates))

    out.append(threshold(f"TD3+SF², AcrobotSwingup, one seed ≥ {ONE_SEED_MIN:,} ({precision})",
                         _pick(jax_acro, rep="sf2", seeds=1, precision=precision), ONE_SEED_MIN))
    out.append(threshold(f"TD3+SF², AcrobotSwingup, all seeds on one GPU ≥ {ALL_SEEDS_MIN:,} ({precision})",
                         [r for r in _pick(jax_acro, rep="sf2", precision=precision)
                          if r.seeds <= MAX_SEEDS_ONE_GPU], ALL_SEEDS_MIN))
    out.append(threshold(f"TD3+SF², CheetahRun, 8 seeds ≥ {CHEETAH_MIN:,} ({precision})",
                         _pick(one_gpu, framework="jax", task="CheetahRun", rep="sf2", seeds=8,
                               precision=precision), CHEETAH_MIN))

    # two GPUs: the two two-gpus-<i> folders' rows of one case, summed, against that case on one GPU
    groups: dict[tuple, list[Row]] = {}
    for r in rows:
        if r.two_gpus:
            groups.setdefault((r.framework, r.task, r.rep, r.seeds, r.precision), []).append(r)
    ratios = []
    for (fw, task, rep, seeds, prec), parts in groups.items():
        alone = _best(_pick(one_gpu, framework=fw, task=task, rep=rep, seeds=seeds, precision=prec))
        if alone is not None and len(parts) == 2:
            total = sum(p.sps for p in parts)
            ratios.append((total / alone.sps, f"{total:,.0f} on two / {alone.sps:,.0f} on one ({task} {rep} "
                           f"x{seeds} per GPU, {prec})", [p.label() for p in parts] + [alone.label()]))
    name = f"2 GPUs ≥ {TWO_GPUS_MIN}× one"
    if ratios:
        ratio, text, src = min(ratios)
        out.append(Target(name, f"{ratio:.2f}×: {text}", ratio >= TWO_GPUS_MIN, tuple(src)))
    else:
        out.append(Target(name, "no rows", None, ()))

    # SF²/TD3: pairs of one process (same folder, seeds, precision)
    pairs = []
    for sf2 in _pick(jax_acro, rep="sf2"):
        for td3 in _pick(jax_acro, rep="none", folder=sf2.folder, seeds=sf2.seeds, precision=sf2.precision):
            pairs.append((td3.sps / sf2.sps, sf2, td3))
    if pairs:
        pairs.sort(key=lambda p: (p[1].seeds, p[1].precision))
        text = "; ".join(f"{q:.2f}× (x{s.seeds} {s.precision})" for q, s, _ in pairs)
        met = [f"x{s.seeds} {s.precision}" for q, s, _ in pairs if q <= SF2_OVER_TD3_MAX]
        out.append(Target(f"TD3+SF² / TD3 time per env step ≤ {SF2_OVER_TD3_MAX}×", text
                          + (f"; met at {', '.join(met)}" if met and len(met) < len(pairs) else ""),
                          len(met) == len(pairs), tuple(x.label() for _, s, t in pairs for x in (s, t))))
    else:
        out.append(Target(f"TD3+SF² / TD3 time per env step ≤ {SF2_OVER_TD3_MAX}×", "no rows", None, ()))

    # torch / JAX at one seed: the same process where there is one, else the best JAX row of the precision
    found = []
    for t in _pick(one_gpu, framework="torch", task="AcrobotSwingup", rep="sf2", seeds=1):
        same = _pick(jax_acro, rep="sf2", seeds=1, precision=t.precision, folder=t.folder)
        j = _best(same or _pick(jax_acro, rep="sf2", seeds=1, precision=t.precision))
        if j is not None:
            found.append((t.sps / j.sps, t, j, bool(same)))
    if found:
        found.sort(key=lambda x: x[1].precision)
        text = "; ".join(f"{q:.2f}× ({t.precision}{', one process' if same else ', two processes'})"
                         for q, t, _, same in found)
        out.append(Target(f"torch trainer, one seed ≥ {TORCH_OVER_JAX_MIN}× JAX", text,
                          all(q >= TORCH_OVER_JAX_MIN for q, *_ in found),
                          tuple(x.label() for _, t, j, _ in found for x in (t, j))))
    else:
        out.append(Target(f"torch trainer, one seed ≥ {TORCH_OVER_JAX_MIN}× JAX", "no rows", None, ()))
    return out


def markdown(targets: list[Target]) -> str:
    word = {True: "**reached**", False: "not reached", None: "not measured"}
    lines = ["| target | measured | |", "|---|---|---|"]
    lines += [f"| {t.name} | {t.measured} | {word[t.reached]} |" for t in targets]
    lines += ["", "Rows used:", ""]
    lines += [f"- {t.name}: " + "; ".join(t.sources) for t in targets if t.sources]
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.targets", description=__doc__.split("\n\n")[0])
    p.add_argument("folders", nargs="+", help="result folders (searched recursively)")
    p.add_argument("--out", help="also write the table here")
    args = p.parse_args(argv)
    from sf2_common.agents import tasks
    from sf2_common.agents.configs import make_config

    try:
        rows, physics = read(args.folders)
    except (FileNotFoundError, ValueError) as err:
        p.error(str(err))
    precision = make_config("paper", "AcrobotSwingup").learner_precision
    text = markdown(evaluate(rows, physics, tuple(tasks.PAPER_TASKS), precision))
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
