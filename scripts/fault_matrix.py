"""Measure the run-folder fault matrix of docs/run-folders.md through a CLI (`sf2-jax` or `sf2-torch`).

    python scripts/fault_matrix.py --framework jax --out /tmp/faults-jax
    python scripts/fault_matrix.py --framework torch --out /tmp/faults-torch

Trains one small reference run (CartpoleBalance, 3 epochs of 48 env steps, the agents tests' tiny
networks) with `PROG train`, then for each case copies it (or starts a new run), applies the fault and runs
the same command again: each kind of file a run folder holds truncated, garbled or deleted; real `kill -9`s
at several points (separate processes); unusable `--out` paths; a negative flag value. Prints one markdown
row per case: the exit status, what the CLI said, where the run resumed, whether the rows then equal the
uninterrupted run's, and whether a refused folder is unchanged (SHA-256 of every file). A few minutes.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import shutil
import sys
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("OMP_NUM_THREADS", "1")  # the killed processes compute the same numbers as this one

TINY = dict(num_timesteps=144, num_evals=4, num_envs=4, num_eval_envs=4, episode_length=60, batch_size=16,
            grad_updates_per_step=2, min_replay_size=32, max_replay_size=512, feature_size=8,
            hidden_sizes=(16,), q_hidden_size=16, zeta_hidden_sizes=(16,), embedding_size=4)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--framework", choices=["jax", "torch"], required=True)
    ap.add_argument("--out", required=True, help="a new folder for the runs")
    args = ap.parse_args(argv)
    import importlib

    from sf2_common.agents.hostloop import WALL_FIELDS
    from sf2_common.agents.runfolder import RunFolder

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "support"))
    from sf2_testing import FAULTS, cli_args, damage, folder_digest, kill9

    module = f"sf2_{args.framework}.cli"
    cli = importlib.import_module(module)
    configs = importlib.import_module(f"sf2_{args.framework}.agents.configs")
    extra = {"compile": "off"} if args.framework == "torch" else {}
    cfg = configs.make_config("quick", "CartpoleBalance", overrides={**TINY, **extra})
    root = Path(args.out)
    if root.exists():
        raise SystemExit(f"{root} exists; pass a new folder")
    cache = str(root / "jax-cache")

    def command(out):
        return cli_args(cfg, out) + ["--compile-cache", cache]

    def run(argv):
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()) as out:
            rc = cli.main(argv)
        return rc, err.getvalue(), out.getvalue()

    def strip(rows):
        return [{k: v for k, v in r.items() if k not in WALL_FIELDS} for r in rows]

    rc, _, _ = run(command(root / "reference"))
    assert rc == 0
    reference = strip(RunFolder(root / "reference").read_rows())
    print(f"| case | exit | what {cli.PROG} said | resumed from | rows = uninterrupted | folder unchanged |")
    print("|---|---|---|---|---|---|")

    def said(err):
        lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("==")]
        keep = [ln for ln in lines if "damaged" in ln or "error" in ln or "resuming" in ln or "complete" in ln
                or "discarding" in ln]
        text = " / ".join(keep or lines[:1])
        text = text.replace(str(root) + "/", "").replace(str(root), "")
        return text.replace("|", "\\|")

    def report(case, out, rc, err, before=None):
        m = re.search(r"from checkpoint (\d+)", err)
        resumed = m.group(1) if m else "complete" if "is complete" in err else "-" if rc else "fresh start"
        rows = "yes" if rc == 0 and strip(RunFolder(out).read_rows()) == reference else ("-" if rc else "NO")
        same = "-" if before is None else ("yes" if folder_digest(out) == before else "NO")
        print(f"| {case} | {rc} | {said(err)} | {resumed} | {rows} | {same} |", flush=True)

    def case_folder(name):
        out = root / "cases" / name
        shutil.copytree(root / "reference", out)
        return out

    # files of a finished run: the newest checkpoint (3), config.json, metrics.jsonl
    if args.framework == "jax":
        files = {"checkpoint data (Orbax array file)": "largest:checkpoints/3/state/d",
                 "checkpoint metadata (meta/metadata)": "checkpoints/3/meta/metadata",
                 "Orbax metadata (_CHECKPOINT_METADATA)": "checkpoints/3/_CHECKPOINT_METADATA"}
    else:
        files = {"checkpoint data (state.pt)": "checkpoints/3/state.pt",
                 "checkpoint env arrays (env.npz)": "checkpoints/3/env.npz",
                 "checkpoint metadata (meta.json)": "checkpoints/3/meta.json"}
    files.update({"checkpoint manifest (sf2-manifest.json)": "checkpoints/3/sf2-manifest.json",
                  "config.json": "config.json", "metrics.jsonl": "metrics.jsonl"})
    for label, rel in files.items():
        for fault in FAULTS:
            out = case_folder(f"{re.sub(r'[^a-z0-9]+', '-', label.lower())}-{fault}")
            if rel.startswith("largest:"):
                path = max((out / rel.split(":", 1)[1]).iterdir(), key=lambda p: p.stat().st_size)
            else:
                path = out / rel
            damage(path, fault)
            before = folder_digest(out)
            rc, err, _ = run(command(out))
            report(f"{label}: {fault}", out, rc, err, before if rc else None)

    out = case_folder("both-checkpoints-damaged")
    for epoch in (2, 3):
        damage(out / "checkpoints" / str(epoch) / ("state.pt" if args.framework == "torch" else
                                                   "meta/metadata"), "garble")
    before = folder_digest(out)
    rc, err, _ = run(command(out))
    report("checkpoints 2 and 3 both garbled", out, rc, err, before)
    out = case_folder("checkpoints-deleted")
    shutil.rmtree(out / "checkpoints")
    before = folder_digest(out)
    rc, err, _ = run(command(out))
    report("checkpoints/ deleted", out, rc, err, before)
    rc, err, _ = run(command(out) + ["--fresh"])
    report("the same with --fresh", out, rc, err)
    rc, err, stdout = run(command(root / "reference"))
    wall = re.search(r"\| (\d+ s)", stdout)
    table = wall.group(1) if wall else "?"
    report(f"rerun of the finished run (table: {table})", root / "reference", rc, err)

    # real kill -9 of the CLI at several points, then the same command
    for label, at in [("kill -9 during epoch 2's training", ("train", 2)),
                      ("kill -9 during epoch 2's evaluation", ("evaluate", 2)),
                      ("kill -9 after epoch 2's rows, before its save", ("save", 2)),
                      ("kill -9 in the middle of checkpoint 2's save", ("mid-save", 2)),
                      ("kill -9 during the first evaluation", ("evaluate", 0))]:
        out = root / "kills" / f"{at[0]}-{at[1]}"
        kill9(module, command(out), at)
        rc, err, _ = run(command(out))
        report(label, out, rc, err)

    # unusable --out paths and a negative value
    file = root / "a-file"
    file.write_text("mine")
    for label, out in [("--out is a regular file", file), ("--out under a regular file", file / "run"),
                       ("--out on an unwritable location (/sys)", Path("/sys/sf2-run"))]:
        rc, err, _ = run(command(out))
        report(label, out if out.exists() else root, rc, err)
    for value in ("-1e-3", "-0.001"):
        rc, err, _ = run(command(root / "negative") + ["--learning-rate", value])
        report(f"--learning-rate {value}", root, rc, err)
    return 0


if __name__ == "__main__":
    sys.exit(main())
