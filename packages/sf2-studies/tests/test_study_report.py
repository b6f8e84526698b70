"""`study report` (sf2_studies.report) on synthetic run folders whose numbers are derived by hand:
AUC, per-task normalization, the aggregates against rliable's own functions, the final-window mean of a
sweep, the observation-noise AUC, and "no interval" below 3 seeds."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

pytest.importorskip("rliable", reason="sf2-studies' dependencies: pip install packages/sf2-studies")
pytest.importorskip("matplotlib", reason="sf2-studies' dependencies: pip install packages/sf2-studies")

from rliable import library, metrics  # noqa: E402
from sf2_common.fileio import compress  # noqa: E402
from sf2_studies import stats  # noqa: E402
from sf2_studies.folder import StudyFolder  # noqa: E402
from sf2_studies.report import report  # noqa: E402
from sf2_studies.spec import StudyError, loads  # noqa: E402

STEPS = [0, 100, 200]


def _study(tmp_path, text):
    folder = StudyFolder(tmp_path / "study")
    study = loads(text, tmp_path / "s.toml")
    folder.open(study, "jax", [], command="sf2-jax study run s.toml --out study")
    return folder


def _write_run(path, seeds, returns, steps=STEPS, walltime=12.0, last_epoch=None, noise=None, hardware=None,
               environment=None):
    """A run folder as the trainers write it: config.json (schedule.num_epochs, `hardware` unless None, as
    before run folders named it) and one metrics row per evaluation and seed; `returns[seed]` is the
    eval-return curve at `steps`."""
    path.mkdir(parents=True)
    epochs = len(steps) - 1
    conf = {"config": {}, "seeds": seeds, "schedule": {"num_epochs": epochs}}
    if hardware is not None:
        conf["hardware"] = hardware
    if environment is not None:
        conf["environment"] = environment
    (path / "config.json").write_text(json.dumps(conf))
    rows = [{"epoch": e, "seed": s, "env_steps": steps[e], "eval_return": float(returns[s][e]),
             "walltime": walltime * e / epochs}
            for e in range(epochs + 1) if last_epoch is None or e <= last_epoch for s in seeds]
    (path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    if noise is not None:
        (path / "obs_noise.json").write_text(json.dumps({"settings": {}, "results": noise}))


FAMILY = """
name = "synthetic"
seeds = "0-3"
tasks = ["A", "B"]
[[methods]]
label = "TD3"
name = "td3"
algo = "td3"
representation = "none"
[[methods]]
label = "TD3+SF²"
name = "td3-sf2"
algo = "td3"
representation = "sf2"
[[methods]]
label = "SAC"
name = "sac"
algo = "sac"
representation = "none"
"""
BASE = {"td3": 0.0, "td3-sf2": 10.0, "sac": 5.0}
SCALE = {"A": 1.0, "B": 10.0}


def test_report_numbers_by_hand_and_by_rliable(tmp_path):
    """Seed s of method m on task t has the curve [0, v, v] at env steps 0, 100, 200 with v = SCALE[t] ·
    (BASE[m] + s). Its AUC is (0 + v)/2 · 100 + v · 100, over 200 env steps: 3v/4. Per task the smallest
    AUC is 0 (TD3, seed 0) and the largest 3/4 · SCALE[t] · 13 (TD3+SF², seed 3), so every normalized AUC
    is (BASE[m] + s) / 13 on both tasks. SAC on B stops an epoch short: incomplete, left out."""
    folder = _study(tmp_path, FAMILY)
    seeds = [0, 1, 2, 3]
    for task in ("A", "B"):
        for m, base in BASE.items():
            v = {s: SCALE[task] * (base + s) for s in seeds}
            last = 1 if (task, m) == ("B", "sac") else None
            _write_run(folder.run_path(task, m), seeds, {s: [0.0, v[s], v[s]] for s in seeds},
                       last_epoch=last, hardware={"A": "NVIDIA H100 80GB HBM3", "B": None}[task])
    written = report(folder.path, command="sf2-jax study report study")
    rows = list(csv.DictReader(open(written["results.csv"])))
    assert len(rows) == 2 * 4 + 2 * 4 + 4    # TD3 and TD3+SF² on A and B, SAC on A
    for r in rows:
        m = {"TD3": "td3", "TD3+SF²": "td3-sf2", "SAC": "sac"}[r["method"]]
        v = SCALE[r["task"]] * (BASE[m] + int(r["seed"]))
        assert float(r["auc"]) == pytest.approx(0.75 * v)
        assert float(r["normalized_auc"]) == pytest.approx((BASE[m] + int(r["seed"])) / 13)
        assert float(r["final_return"]) == pytest.approx(v)
        assert float(r["final_window_return"]) == pytest.approx(2 * v / 3)   # 50k env steps: all of [0, v, v]
        assert int(r["env_steps"]) == 200 and float(r["wall_time_s"]) == 12.0
        assert r["family"] == ("SAC" if m == "sac" else "TD3")

    summary = written["summary.md"].read_text()
    # the five finished runs (SAC on B is not) by their config.json's hardware: three on A, two on B
    assert ("Hardware of the finished run folders (their config.json): NVIDIA H100 80GB HBM3: 3 runs; not "
            "recorded (trained before run folders named it): 2 runs.") in summary
    assert "Their environment" not in summary   # no run recorded one
    # TD3's normalized scores are s/13 on both tasks: per-task means 1.5/13 (median, mean); the pooled
    # 0 0 1 1 2 2 3 3 trimmed by 2 at each end: IQM 1.5/13; optimality gap 1 − 1.5/13.
    td3 = np.array([[s / 13, s / 13] for s in seeds])
    np.testing.assert_allclose(stats.aggregate(td3), [1.5 / 13, 1.5 / 13, 1.5 / 13, 1 - 1.5 / 13])

    def fn(x):
        return np.array([metrics.aggregate_median(x), metrics.aggregate_iqm(x), metrics.aggregate_mean(x),
                         metrics.aggregate_optimality_gap(x)])

    np.random.seed(stats.SEED)
    _, ci = library.get_interval_estimates({"TD3": td3}, fn, reps=stats.RESAMPLES)
    line = next(x for x in summary.splitlines() if x.startswith("| TD3 | 4 × 2 |"))
    for k in range(4):
        p = fn(td3)[k]
        assert f"{p:.3f} [{ci['TD3'][0][k]:.3f}, {ci['TD3'][1][k]:.3f}]" in line, line
    assert "**TD3**: over all 2 tasks, seeds 0-3 (4 of 4)." in summary
    # SAC alone in its family, finished on A only: an interim aggregate over A, its scores (5 + s)/13 for
    # s = 0..3: median = IQM (6, 7 of 5..8) = mean = 6.5/13 = 0.5, optimality gap 0.5
    assert ("**SAC: interim aggregate** over 1 of the study's 2 tasks (A), seeds 0-3 (4 of 4): not the "
            "study's 2-task aggregate. No finished run yet: B.") in summary
    line = next(x for x in summary.splitlines() if x.startswith("| SAC | 4 × 1 |"))
    assert line.count("0.500 [") == 4, line
    assert "| B | SAC | 0-3: partial (epoch 1 of 2) |" in summary
    assert "sf2-jax study run s.toml --out study" in summary and "sf2-jax study report study" in summary
    for name in ("aggregate.png", "aggregate.svg", "curves.png", "curves.svg"):
        assert name in written and written[name].stat().st_size > 1000
    # made again from the same runs, the report's files are the same bytes (a committed report does not
    # change when it is remade): the SVGs carry no date and fixed clip-path ids
    before = {name: path.read_bytes() for name, path in written.items()}
    again = report(folder.path, command="sf2-jax study report study")
    assert {name: path.read_bytes() for name, path in again.items()} == before
    # the same runs stored gzip-compressed (`study merge`, `study compress`): the same report, byte for byte
    files = list(folder.path.rglob("metrics.jsonl"))
    assert len(files) == 6 and all(compress(m) for m in files)   # 2 tasks × 3 methods
    again = report(folder.path, command="sf2-jax study report study")
    assert {name: path.read_bytes() for name, path in again.items()} == before


INTERIM = FAMILY.replace('tasks = ["A", "B"]', 'tasks = ["A", "B", "C"]')


def test_interim_aggregate_covers_the_tasks_and_seeds_every_method_has(tmp_path):
    """TD3 has seeds 0-2 on A and 0-1 on B; TD3+SF² seeds 1-3 on A and 0 on C; SAC nothing. The TD3 family
    is aggregated on A alone (B lacks TD3+SF², C lacks TD3) over the seeds both have there, 1-2: TD3 scores
    0.1 s → 0.1, 0.2; TD3+SF² 0.2 + 0.1 s → 0.3, 0.4. Two seeds: no interval; median = mean = IQM (nothing
    trimmed of 2) = the pair's mean, optimality gap 1 − mean. SAC: no aggregate."""
    from sf2_studies.report import _md_coverage, aggregate_table

    study = loads(INTERIM, tmp_path / "s.toml")
    rows = ([{"task": "A", "method": "TD3", "seed": s, "normalized_auc": 0.1 * s} for s in (0, 1, 2)]
            + [{"task": "B", "method": "TD3", "seed": s, "normalized_auc": 0.5} for s in (0, 1)]
            + [{"task": "A", "method": "TD3+SF²", "seed": s, "normalized_auc": 0.2 + 0.1 * s}
               for s in (1, 2, 3)]
            + [{"task": "C", "method": "TD3+SF²", "seed": 0, "normalized_auc": 0.9}])
    table, covers = aggregate_table(study, rows)
    assert list(table) == ["TD3"]
    td3 = covers["TD3"]
    assert (td3.tasks, td3.seeds, td3.extra_seeds) == (["A"], [1, 2], [0, 3])
    assert td3.left_out == {"B": ["TD3"], "C": ["TD3+SF²"]}
    assert [e[0] for e in table["TD3"]] == ["TD3", "TD3+SF²"]
    for (_, n, points, ci), mean in zip(table["TD3"], (0.15, 0.35)):
        assert n == 2 and ci is None
        np.testing.assert_allclose(points, [mean, mean, mean, 1 - mean])
    text = _md_coverage(study, td3)[0]
    assert text == ("**TD3: interim aggregate** over 1 of the study's 3 tasks (A), seeds 1-2 (2 of 4): "
                    "not the study's 3-task aggregate. Left out: B (finished by TD3 only); C (finished by "
                    "TD3+SF² only). Seeds 0,3 are finished on these tasks by some methods only and left out, "
                    "so that every method is scored on the same seeds.")
    assert _md_coverage(study, covers["SAC"])[0] == (
        "**SAC**: not aggregated yet (no task on which every method has finished seeds; the aggregate scores "
        "every method of the family on the same tasks and seeds).")


def test_interim_aggregate_takes_the_most_tasks_times_seeds(tmp_path):
    """TD3 and TD3+SF² have seeds 0-3 on A and B; on C TD3+SF² has 0-1 only. The seeds common to all three
    tasks (0-1) give 3 × 2 = 6 scores a method, A's and B's own (0-3) give 2 × 4 = 8: the aggregate is A and
    B over seeds 0-3, and C is named as left out for its seeds. TD3 scores 0.1 everywhere, TD3+SF² 0.3:
    median = IQM = mean = the score, optimality gap 1 − it. A tie (C dropped, B at seeds 0-1: 2 × 2 with
    the common seeds against A alone, 1 × 4) goes to more tasks: A and B at seeds 0-1."""
    from sf2_studies.report import _md_coverage, aggregate_table

    study = loads(INTERIM, tmp_path / "s.toml")
    have = {("A", "TD3"): range(4), ("A", "TD3+SF²"): range(4), ("B", "TD3"): range(4),
            ("B", "TD3+SF²"): range(4), ("C", "TD3"): range(4), ("C", "TD3+SF²"): range(2)}
    value = {"TD3": 0.1, "TD3+SF²": 0.3}
    rows = [{"task": t, "method": m, "seed": s, "normalized_auc": value[m]} for (t, m), ss in have.items()
            for s in ss]
    table, covers = aggregate_table(study, rows)
    td3 = covers["TD3"]
    assert (td3.tasks, td3.seeds, td3.extra_seeds) == (["A", "B"], [0, 1, 2, 3], [])
    assert td3.left_out == {} and td3.fewer_seeds == {"C": [("TD3+SF²", "0-1")]}
    for (label, n, points, _), v in zip(table["TD3"], (0.1, 0.3)):
        assert n == 4 and label == ("TD3" if v == 0.1 else "TD3+SF²")
        np.testing.assert_allclose(points, [v, v, v, 1 - v])
    assert _md_coverage(study, td3)[0] == (
        "**TD3: interim aggregate** over 2 of the study's 3 tasks (A, B), seeds 0-3 (4 of 4): not the "
        "study's 3-task aggregate. Left out until its seeds catch up (with it, every task would be scored on "
        "fewer seeds): C (TD3+SF² has seeds 0-1).")
    tie = [r for r in rows if r["task"] != "C" and not (r["task"] == "B" and r["seed"] > 1)]
    tied = aggregate_table(study, tie)[1]["TD3"]
    assert (tied.tasks, tied.seeds, tied.extra_seeds) == (["A", "B"], [0, 1], [2, 3])


def test_provisional_normalization_is_flagged(tmp_path):
    """Task A has finished runs of all three methods, task B of TD3 only: B's normalization rests on one
    of the three methods, and summary.md says so for B and not for A; with SAC+SF² and SAC on B the flag
    goes."""
    folder = _study(tmp_path, FAMILY)
    curves = {s: [0, 1 + s, 1 + s] for s in range(4)}
    for m in ("td3", "td3-sf2", "sac"):
        _write_run(folder.run_path("A", m), [0, 1, 2, 3], curves)
    _write_run(folder.run_path("B", "td3"), [0, 1, 2, 3], curves)
    summary = report(folder.path)["summary.md"].read_text()
    flag = [line for line in summary.splitlines() if line.startswith("**Provisional normalization**")]
    assert len(flag) == 1 and flag[0].endswith(": B (1 of 3 methods: TD3).")
    for m in ("td3-sf2", "sac"):
        _write_run(folder.run_path("B", m), [0, 1, 2, 3], curves)
    assert "Provisional normalization" not in report(folder.path)["summary.md"].read_text()


def test_incomplete_runs_compact(tmp_path):
    """One line for the tasks no method has started, one row per (task, method) elsewhere with its
    unfinished seed groups and their state."""
    text = INTERIM.replace('seeds = "0-3"', 'seeds = "0-3"\nseeds_per_run = 2')
    folder = _study(tmp_path, text)
    for m in ("td3", "td3-sf2", "sac"):
        _write_run(folder.run_path("A", f"{m}/seeds-0-1"), [0, 1], {0: [0, 1, 1], 1: [0, 2, 2]})
    _write_run(folder.run_path("A", "td3/seeds-2-3"), [2, 3], {2: [0, 1, 1], 3: [0, 2, 2]}, last_epoch=1)
    _write_run(folder.run_path("B", "sac/seeds-2-3"), [2, 3], {2: [0, 1, 1], 3: [0, 2, 2]})
    summary = report(folder.path)["summary.md"].read_text()
    # four finished seed groups (A's td3 2-3 is not), none of whose config.json names its hardware
    assert ("Hardware: not recorded in the config.json of the 4 finished run folder(s) (they trained before "
            "run folders named it).") in summary
    part = summary[summary.index("## Incomplete runs"):]
    assert part.splitlines()[2:] == [
        "Not started by any method: C (1 of 3 tasks, every seed group).", "",
        "| task | method | seeds not finished: state |", "|---|---|---|",
        "| A | TD3 | 2-3: partial (epoch 1 of 2) |",
        "| A | TD3+SF² | 2-3: not started |",
        "| A | SAC | 2-3: not started |",
        "| B | TD3 | 0-1, 2-3: not started |",
        "| B | TD3+SF² | 0-1, 2-3: not started |",
        "| B | SAC | 0-1: not started |"]


SWEEP = """
name = "sweep"
seeds = "0-1"
tasks = ["A"]
[report]
final_window = 100
[evaluation]
obs_noise = [0.0, 0.1]
checkpoints = 2
[[sweeps]]
field = "tau_zeta"
values = [0.01, 0.1]
methods = [{ label = "TD3+SF²", name = "td3-sf2", algo = "td3", representation = "sf2" }]
"""


def test_sweep_and_obs_noise_with_two_seeds(tmp_path):
    """Final-window mean over the evaluations at >= 200 − 100 env steps: the last two. Observation noise:
    per seed the AUC of the checkpoints' mean returns over their env steps; with 2 seeds no interval."""
    folder = _study(tmp_path, SWEEP)
    for i, name in enumerate(["td3-sf2-tau-zeta-0.01", "td3-sf2-tau-zeta-0.1"]):
        noise = [{"noise": sigma, "epoch": e, "env_steps": 100 * e,
                  "returns": {str(s): [10.0 * e - 100 * sigma + s + d for d in (0, 2)] for s in (0, 1)}}
                 for sigma in (0.0, 0.1) for e in (1, 2)]
        _write_run(folder.run_path("A", name), [0, 1], {s: [0.0, 2.0 + i + s, 4.0 + i + s] for s in (0, 1)},
                   noise=noise)
    written = report(folder.path)
    rows = list(csv.DictReader(open(written["results.csv"])))
    for r in rows:
        i = 0 if "0.01" in r["method"] else 1
        s = int(r["seed"])
        # (2 + i + s + 4 + i + s) / 2
        assert float(r["final_window_return"]) == pytest.approx(3 + i + s)
    summary = written["summary.md"].read_text()
    # mean over the seeds of 3 + i + s: 3.5 + i; no interval with 2 seeds
    assert "| tau_zeta | TD3+SF² | 0.01 | 2 | 3.500 (n < 3: no CI) |" in summary
    assert "| tau_zeta | TD3+SF² | 0.1 | 2 | 4.500 (n < 3: no CI) |" in summary
    # seed s, noise σ: mean returns 10e − 100σ + s + 1 at env steps 100e (e = 1, 2): AUC 15 − 100σ + s + 1;
    # the IQM of two seeds is their mean: 16.5 − 100σ
    assert "| TD3+SF² (tau_zeta=0.01) | 0 | 2 | 16.5 (n < 3: no CI) |" in summary
    assert "| TD3+SF² (tau_zeta=0.01) | 0.1 | 2 | 6.500 (n < 3: no CI) |" in summary
    for name in ("sweeps.png", "obs_noise.png", "curves.png"):
        assert name in written
    # obs_noise.json and metrics.jsonl gzip-compressed: the same numbers
    before = written["summary.md"].read_text()
    stored = [*folder.path.rglob("obs_noise.json"), *folder.path.rglob("metrics.jsonl")]
    assert stored and all(compress(p) for p in stored)
    assert report(folder.path)["summary.md"].read_text() == before


def test_sweep_scored_by_the_iqm_of_normalized_auc(tmp_path):
    """`report.sweep_score = "iqm_auc"` (paper Fig. 9 left): a sweep's point is its method's aggregate IQM.
    Value i (0: 0.01, 1: 0.1), seed s, task t: the curve [0, v, v] with v = SCALE[t] · (4i + s), AUC 3v/4,
    normalized per task (min 0, max 3/4 · SCALE[t] · 7) to (4i + s)/7 on both tasks; the IQM of the eight
    pooled scores keeps s = 1, 1, 2, 2: (4i + 1.5)/7. The interval is the aggregate table's."""
    text = SWEEP.replace('seeds = "0-1"', 'seeds = "0-3"').replace('tasks = ["A"]', 'tasks = ["A", "B"]')
    text = text.replace("final_window = 100", 'sweep_score = "iqm_auc"').split("[evaluation]")[0] + \
        "[[sweeps]]" + text.split("[[sweeps]]")[1]
    folder = _study(tmp_path, text)
    seeds = [0, 1, 2, 3]
    for i, name in enumerate(["td3-sf2-tau-zeta-0.01", "td3-sf2-tau-zeta-0.1"]):
        for task in ("A", "B"):
            v = {s: SCALE[task] * (4 * i + s) for s in seeds}
            _write_run(folder.run_path(task, name), seeds, {s: [0.0, v[s], v[s]] for s in seeds})
    written = report(folder.path)
    summary = written["summary.md"].read_text()
    assert "## Sweeps: IQM of the normalized AUC over the tasks (paper Fig. 9 left)" in summary
    for i, value in enumerate(("0.01", "0.1")):
        row = f"| TD3+SF² (tau_zeta={value}) | 4 × 2 |"
        aggregate = next(x for x in summary.splitlines() if x.startswith(row))
        iqm = f"{(4 * i + 1.5) / 7:.3f} ["
        cell = aggregate.split(" | ")[3]   # Median, IQM, Mean, Optimality Gap
        assert cell.startswith(iqm), aggregate
        assert f"| tau_zeta | TD3+SF² | {value} | 4 | {cell} |" in summary
    assert "sweeps.png" in written


def test_a_damaged_run_file_stops_the_report_naming_it(tmp_path):
    """A finished run whose metrics.jsonl.gz is cut (a bad copy), whose metrics.jsonl has a line that is no
    row in the middle (an edit), or whose obs_noise.json is not JSON is never reported as unfinished or
    left out silently: `StudyError` naming the file and the choices, and no report file is written."""
    from sf2_studies.spec import StudyError

    folder = _study(tmp_path, SWEEP)
    for name in ("td3-sf2-tau-zeta-0.01", "td3-sf2-tau-zeta-0.1"):
        noise = [{"noise": 0.0, "epoch": 2, "env_steps": 200, "returns": {"0": [1.0], "1": [2.0]}}]
        _write_run(folder.run_path("A", name), [0, 1], {s: [0.0, 1.0, 2.0] for s in (0, 1)}, noise=noise)
    run = folder.run_path("A", "td3-sf2-tau-zeta-0.1")
    rows, results = (run / "metrics.jsonl").read_text(), (run / "obs_noise.json").read_text()

    def cut_gzip():
        assert compress(run / "metrics.jsonl")
        data = (run / "metrics.jsonl.gz").read_bytes()
        (run / "metrics.jsonl.gz").write_bytes(data[: len(data) // 2])

    cases = [(cut_gzip, r"metrics.jsonl.gz is damaged gzip data"),
             (lambda: (run / "metrics.jsonl").write_text(rows.replace("\n", "\nnot a row\n", 1)),
              r"metrics.jsonl line 2 is not a metrics row"),
             (lambda: (run / "obs_noise.json").write_text("{"),
              r"obs_noise.json is not an evaluation's results")]
    for damage_it, message in cases:
        (run / "metrics.jsonl.gz").unlink(missing_ok=True)
        (run / "metrics.jsonl").write_text(rows)
        (run / "obs_noise.json").write_text(results)
        damage_it()
        with pytest.raises(StudyError, match=message) as err:
            report(folder.path)
        assert f"move the run folder {run} out" in str(err.value) and "restore the file" in str(err.value)
        assert not (folder.path / "report").exists()
    (tmp_path / "file").write_text("mine")
    with pytest.raises(StudyError, match=r"report folder .*file/report: .*file is a file, not a folder"):
        report(folder.path, out=tmp_path / "file" / "report")
    assert (tmp_path / "file").read_text() == "mine"


def test_reruns_compared_with_their_runs_by_hand_and_left_out_of_the_results(tmp_path):
    """A rerun (rerun/<task>-<method>/<seeds>[.k], as `study merge --keep-reruns` writes it) against the
    run it repeats. AUC over env steps 0, 100, 200 of returns (a, b, c) = (a + 2b + c) / 4. TD3 on A: seeds
    0-3 with curves (0, 1, 1), (0, 2, 2), (0, 1, 1), (0, 2, 2) → AUC 0.75, 1.5, 0.75, 1.5 (mean 1.125). Its
    rerun of seeds 0-1: (0, 3, 3), (0, 2, 2) → 2.25, 1.5: difference +1.5, 0 (mean 0.75; two seeds, no
    interval); the method's mean with the rerun's seeds in place: (2.25 + 1.5 + 0.75 + 1.5) / 4 = 1.5. A
    second rerun '.2': (0, 1, 1), (0, 0, 0) → 0.75, 0: differences 0, −1.5 (mean −0.75; largest seed 1).
    First difference, the first row in (epoch, seed) order with another learned value: the first rerun's at
    epoch 1 seed 0 (1 → 3), the second's at epoch 1 seed 1 (2 → 0; seed 0 is equal throughout). On B, TD3
    seeds 2-3 again with equal returns and another wall time: no learned value differs."""
    import csv as csv_

    text = FAMILY.replace('seeds = "0-3"', 'seeds = "0-3"\nseeds_per_run = 2')
    folder = _study(tmp_path, text)
    curve = {0: [0, 1, 1], 1: [0, 2, 2], 2: [0, 1, 1], 3: [0, 2, 2]}
    for task in ("A", "B"):
        for m in ("td3", "td3-sf2", "sac"):
            for seeds in ([0, 1], [2, 3]):
                _write_run(folder.run_path(task, f"{m}/seeds-{seeds[0]}-{seeds[1]}"), seeds, curve)
    _write_run(folder.rerun_path("A", "td3", (0, 1)), [0, 1], {0: [0, 3, 3], 1: [0, 2, 2]})
    _write_run(folder.rerun_path("A", "td3", (0, 1), 2), [0, 1], {0: [0, 1, 1], 1: [0, 0, 0]})
    _write_run(folder.path / "rerun/A-td3/seeds-7-8", [7, 8], {7: [0, 1, 1], 8: [0, 1, 1]})   # no such run
    _write_run(folder.rerun_path("B", "td3", (2, 3)), [2, 3], curve, walltime=13.0)
    written = report(folder.path)
    summary = written["summary.md"].read_text()
    part = summary[summary.index("## Reruns"):].splitlines()
    rows = [line for line in part if line.startswith("| A |")]
    assert rows == [
        "| A | TD3 | 0-1 | `rerun/A-td3/seeds-0-1` | 1.125 | 1.875 | 0.750 (n < 3: no CI) | seed 0: 0.750 → "
        "2.250 | epoch 1, seed 0: eval_return 1 → 3 | 1.125 → 1.500 (4) |",
        "| A | TD3 | 0-1 | `rerun/A-td3/seeds-0-1.2` | 1.125 | 0.375 | -0.750 (n < 3: no CI) | seed 1: 1.500 "
        "→ 0.000 | epoch 1, seed 1: eval_return 2 → 0 | 1.125 → 0.750 (4) |"]
    assert [line for line in part if line.startswith("| B |")] == [
        "| B | TD3 | 2-3 | `rerun/B-td3/seeds-2-3` | 1.125 | 1.125 | 0.000 (n < 3: no CI) | seed 2: 0.750 → "
        "0.750 | none: equal learned values | 1.125 → 1.125 (4) |"]
    assert "Ignored (under `rerun/` but repeating no finished run of this study): `rerun/A-td3/seeds-7-8`." \
        in part
    with open(written["reruns.csv"]) as f:
        got = [(r["seed"], float(r["auc_run"]), float(r["auc_rerun"]), r["rerun"])
               for r in csv_.DictReader(f)]
    assert got == [("0", 0.75, 2.25, "rerun/A-td3/seeds-0-1"), ("1", 1.5, 1.5, "rerun/A-td3/seeds-0-1"),
                   ("0", 0.75, 0.75, "rerun/A-td3/seeds-0-1.2"), ("1", 1.5, 0.0, "rerun/A-td3/seeds-0-1.2"),
                   ("2", 0.75, 0.75, "rerun/B-td3/seeds-2-3"), ("3", 1.5, 1.5, "rerun/B-td3/seeds-2-3")]
    # results.csv holds the runs' AUCs only
    with open(written["results.csv"]) as f:
        td3 = [float(r["auc"]) for r in csv_.DictReader(f) if r["task"] == "A" and r["method"] == "TD3"]
    assert td3 == [0.75, 1.5, 0.75, 1.5]
    # a rerun whose seeds are not its run's stops the report, naming it; nothing is rewritten
    before = written["summary.md"].read_bytes()
    _write_run(folder.rerun_path("A", "sac", (2, 3)), [2], {2: [0, 1, 1]})
    with pytest.raises(StudyError, match=r"rerun .*A-sac/seeds-2-3 holds seeds \[2\], its run .* seeds "
                                         r"\[2, 3\]: not a rerun of it"):
        report(folder.path)
    assert written["summary.md"].read_bytes() == before


def test_learning_curves_layout_and_seed_titles_by_hand():
    from sf2_studies.figures import grid, seeds_title

    # seven tasks at four to a row: two rows (4 + 3, the eighth panel holds the legend); three tasks: one row
    assert grid(7) == (2, 4) and grid(8) == (2, 4) and grid(9) == (3, 4)
    assert grid(3) == (1, 3) and grid(1) == (1, 1)
    # every method at 15 seeds; one method behind (the count most methods have comes first); a tie between
    # counts takes the larger
    assert seeds_title({"TD3": 15, "TD3+SF²": 15}) == "n=15"
    assert seeds_title({"TD3": 15, "TD3+SF²": 15, "TD3+SPR": 5}) == "n=15 (TD3+SPR: 5)"
    assert seeds_title({"TD3": 5, "TD3+SF²": 15}) == "n=15 (TD3: 5)"
    assert seeds_title({}) == ""


CURVES = """
name = "curves"
seeds = "0-3"
tasks = ["A"]
[report]
figures = ["curves"]
{statistic}
[[methods]]
label = "TD3"
name = "td3"
algo = "td3"
representation = "none"
"""


@pytest.mark.parametrize("setting,expected", [
    ("", [0.0, 27.25, 53.75]),                              # default: the mean over the four seeds
    ('curve_statistic = "median"', [0.0, 4.0, 6.5]),       # paper Fig. 8: (3 + 5) / 2, (4 + 9) / 2
])
def test_learning_curves_draw_the_study_statistic(tmp_path, monkeypatch, setting, expected):
    """The curve of four seeds whose returns at step 100 are 1, 3, 5, 100 and at step 200 2, 4, 9, 200:
    its line is their mean or median (by hand, above) as `[report] curve_statistic` says, its band the
    bootstrap interval of that statistic, within the seeds' range; the title names the statistic."""
    from sf2_studies import figures

    drawn = []
    monkeypatch.setattr(figures, "_save", lambda fig, stem: drawn.append(fig) or {})
    folder = _study(tmp_path, CURVES.format(statistic=setting))
    returns = {0: [0, 1, 2], 1: [0, 3, 4], 2: [0, 5, 9], 3: [0, 100, 200]}
    _write_run(folder.path / "runs" / "A" / "td3", [0, 1, 2, 3], returns)
    report(folder.path)
    (fig,) = drawn
    ax = fig.axes[0]
    (line,) = ax.get_lines()
    np.testing.assert_allclose(line.get_ydata(), expected)
    (band,) = ax.collections
    ys = band.get_paths()[0].vertices[:, 1]
    assert ys.min() >= 0.0 and ys.max() <= 200.0
    statistic = "median" if setting else "mean"
    assert f"line: {statistic} eval return" in fig._suptitle.get_text()
    # the same numbers from stats: the median's interval holds the median
    point, lo, hi = stats.column_interval(np.array([returns[s] for s in range(4)]), "median", resamples=500)
    np.testing.assert_allclose(point, [0.0, 4.0, 6.5])
    assert np.all(lo <= point) and np.all(point <= hi)


def test_curve_statistic_is_checked(tmp_path):
    with pytest.raises(StudyError, match=r"curve_statistic = 'iqm' is invalid: one of 'mean', 'median'"):
        loads(CURVES.format(statistic='curve_statistic = "iqm"'), tmp_path / "s.toml")
    # below 3 seeds no interval, and no rliable needed: the plain median
    point, lo, hi = stats.column_interval([[1.0, 2.0], [3.0, 5.0]], "median")
    np.testing.assert_allclose(point, [2.0, 3.5])
    assert lo is None and hi is None
    # an unknown statistic is named
    with pytest.raises(ValueError, match="statistic 'mode': one of mean, median, iqm"):
        stats.column_interval([[1.0]], "mode")


def test_report_counts_the_environments_that_change_the_numbers(tmp_path):
    """Once a finished run's config.json records an environment variable that changes the numbers
    (hostloop.numerics_environment, e.g. XLA's deterministic GPU ops), the summary counts the runs per
    environment: here 2 with the flag (TD3 and TD3+SF² on A), 1 with none (SAC on A), 3 that predate the
    record (task B)."""
    folder = _study(tmp_path, FAMILY)
    flag = {"XLA_FLAGS": "--xla_gpu_deterministic_ops=true"}
    for task in ("A", "B"):
        for m in BASE:
            env = None if task == "B" else (flag if m != "sac" else {})
            _write_run(folder.run_path(task, m), [0, 1, 2, 3], {s: [0.0, s, s] for s in range(4)},
                       environment=env)
    summary = report(folder.path)["summary.md"].read_text()
    assert ("Their environment (config.json's \"environment\"): not recorded (trained before run folders "
            "named it): 3 runs; XLA_FLAGS='--xla_gpu_deterministic_ops=true': 2 runs; none of XLA_FLAGS, "
            "NVIDIA_TF32_OVERRIDE, CUBLAS_WORKSPACE_CONFIG set: 1 run.") in summary, summary


def _family_study(tmp_path, name, family, bases, folder_name=None):
    """A two-task study of one family (vanilla and +SF²) whose seed s of method m scores the curve
    [0, v, v], v = SCALE[task] · (bases[m] + s), with one claim: SF² above vanilla (IQM); its folder is
    tmp_path / (folder_name or name)."""
    low = family.lower()
    text = f"""
name = "{name}"
seeds = "0-3"
tasks = ["A", "B"]
[[methods]]
label = "{family}"
name = "{low}"
algo = "{low}"
representation = "none"
[[methods]]
label = "{family}+SF²"
name = "{low}-sf2"
algo = "{low}"
representation = "sf2"
[[claims]]
text = "SF² above vanilla"
method = "{low}-sf2"
above = ["{low}"]
"""
    folder = StudyFolder(tmp_path / (folder_name or name))
    folder.open(loads(text, tmp_path / f"{name}.toml"), "jax", [], command=f"sf2-jax study run {name}.toml")
    for task in ("A", "B"):
        for m, base in bases.items():
            v = {s: SCALE[task] * (base + s) for s in range(4)}
            _write_run(folder.run_path(task, f"{low}{m}"), [0, 1, 2, 3], {s: [0.0, v[s], v[s]] for s in v})
    return folder


def test_compare_puts_each_studys_own_numbers_side_by_side(tmp_path):
    """Study `t` (TD3: vanilla base 0, SF² base 10) and study `s` (SAC: vanilla base 10, SF² base 0). As in
    test_report_numbers_by_hand_and_by_rliable, every normalized AUC is (base + s)/13, so the IQM over
    the 4 seeds × 2 tasks is (base + 1.5)/13 and SF² − vanilla is +10/13 = +0.769 in `t` (supported: every
    SF² score is above every vanilla one) and −10/13 in `s` (contradicted). `compare` shows both on one row,
    each study's aggregate table as its own report gives it, and one figure with both families."""
    from sf2_studies.compare import claim_key, compare
    from sf2_studies.spec import kind

    assert (kind("TD3+SF² (γ=0)", "TD3"), kind("SAC", "SAC"), kind("SAC+Sim", "SAC")) == \
        ("SF² (γ=0)", "vanilla", "Sim")
    # fig7-td3's and fig7-sac's per-task claim differ only by the family's name; another claim stays apart
    assert claim_key("SF² above vanilla TD3", {"TD3"}) == claim_key("SF² above vanilla SAC", {"SAC"})
    assert claim_key("SF² above vanilla TD3", {"TD3"}) != claim_key("own Adam above shared", {"TD3"})
    t = _family_study(tmp_path, "t", "TD3", {"": 0.0, "-sf2": 10.0})
    s = _family_study(tmp_path, "s", "SAC", {"": 10.0, "-sf2": 0.0})
    written = compare([t.path, s.path], tmp_path / "cmp", command="sf2-jax study compare t s --out cmp")
    summary = written["summary.md"].read_text()
    row = next(x for x in summary.splitlines() if x.startswith("| all 2 tasks | SF² − vanilla |"))
    cells = row.split(" | ")[2:]
    assert cells[0].startswith(f"+{10 / 13:.3f} [") and cells[0].endswith(": supported"), row
    assert cells[1].startswith(f"-{10 / 13:.3f} [") and cells[1].endswith(": contradicted |"), row
    assert "Verdicts: `t` **supported**; `s` **contradicted**." in summary
    # each study's aggregate line, as its own report writes it: TD3's IQM 1.5/13, SAC's 11.5/13
    own = {"t": report(t.path)["summary.md"].read_text(), "s": report(s.path)["summary.md"].read_text()}
    for name, label in (("t", "| TD3 | 4 × 2 |"), ("s", "| SAC | 4 × 2 |")):
        line = next(x for x in own[name].splitlines() if x.startswith(label))
        assert line in summary
    assert f"{1.5 / 13:.3f} [" in next(x for x in own["t"].splitlines() if x.startswith("| TD3 | 4 × 2 |"))
    assert f"{11.5 / 13:.3f} [" in next(x for x in own["s"].splitlines() if x.startswith("| SAC | 4 × 2 |"))
    # per task, in returns: the AUC of seed s is 3v/4, so SF²'s mean on B is 0.75 · 10 · (10 + 1.5) = 86.25
    # in `t` and 0.75 · 10 · 1.5 = 11.25 in `s`; vanilla's the other way round
    rows = {tuple(x.split(" | ")[:2]): x for x in summary.splitlines() if x.startswith("| B | ")}
    def means(row):
        return [c.split(" [")[0] for c in row.split(" | ")[2:4]]

    assert means(rows[("| B", "SF²")]) == [f"{86.25:.1f}", f"{11.25:.1f}"]
    assert means(rows[("| B", "vanilla")]) == [f"{11.25:.1f}", f"{86.25:.1f}"]
    assert rows[("| B", "SF²")].endswith("(4) |")
    assert written["aggregate.png"].stat().st_size > 1000 and "sf2-jax study compare t s" in summary


def test_compare_names_columns_by_folder_so_one_study_in_two_folders_compares(tmp_path):
    """One study file run into two folders (as fig7-sac at Adam ε 1e-5 and, in results/fig7-sac-eps1e-8, at
    1e-8): study `t` in folder `t` (SF² base 10, vanilla 0) and in folder `t-rerun` (the bases swapped).
    As in test_compare_puts_each_studys_own_numbers_side_by_side, SF² − vanilla is +10/13 in the first and
    −10/13 in the second; each column is named by its folder, the heading says which study it holds, and
    two folders of one name are told apart by their paths."""
    from sf2_studies.compare import compare

    t = _family_study(tmp_path, "t", "TD3", {"": 0.0, "-sf2": 10.0})
    r = _family_study(tmp_path, "t", "TD3", {"": 10.0, "-sf2": 0.0}, folder_name="t-rerun")
    summary = compare([t.path, r.path], tmp_path / "cmp")["summary.md"].read_text()
    assert summary.startswith("# Studies compared: `t`, `t-rerun` (study `t`)\n")
    assert "Verdicts: `t` **supported**; `t-rerun` **contradicted**." in summary
    row = next(x for x in summary.splitlines() if x.startswith("| all 2 tasks | SF² − vanilla |"))
    cells = row.split(" | ")[2:]
    assert cells[0].startswith(f"+{10 / 13:.3f} [") and cells[1].startswith(f"-{10 / 13:.3f} ["), row
    assert "| scope | comparison | `t` | `t-rerun` |" in summary
    # two folders named `t` under different parents: each column is its path
    a = _family_study(tmp_path / "a", "t", "TD3", {"": 0.0, "-sf2": 10.0})
    b = _family_study(tmp_path / "b", "t", "TD3", {"": 10.0, "-sf2": 0.0})
    summary = compare([a.path, b.path], tmp_path / "cmp2")["summary.md"].read_text()
    assert f"| scope | comparison | `{a.path}` | `{b.path}` |" in summary


def test_compare_refuses_one_folder_the_same_folder_twice_and_a_file_as_out(tmp_path):
    from sf2_studies.compare import compare

    t = _family_study(tmp_path, "t", "TD3", {"": 0.0, "-sf2": 10.0})
    with pytest.raises(StudyError, match="two or more study folders; got 1"):
        compare([t.path], tmp_path / "cmp")
    with pytest.raises(StudyError, match="the same study folder twice"):
        compare([t.path, t.path], tmp_path / "cmp")
    s = _family_study(tmp_path, "s", "SAC", {"": 10.0, "-sf2": 0.0})
    (tmp_path / "file").write_text("keep")
    with pytest.raises(StudyError, match="is a file, not a folder; nothing was written"):
        compare([t.path, s.path], tmp_path / "file" / "cmp")
    assert (tmp_path / "file").read_text() == "keep" and not (tmp_path / "cmp").exists()


def test_a_sweep_with_both_families_draws_them_apart(monkeypatch):
    """fig9-left's panel holds TD3+SF² and SAC+SF² (one method kind): each line its own color and marker,
    shifted 2.5% of the x span apart (values 1–8: ∓0.0875 about each value) so their error bars do not
    overlap, and an IQM over 1 of 4 tasks named interim in the title and the axis label."""
    from types import SimpleNamespace

    from sf2_studies import figures

    drawn = {}
    monkeypatch.setattr(figures, "_save", lambda fig, stem: drawn.setdefault("fig", fig) and {})
    study = SimpleNamespace(name="fig9-left", tasks=("A", "B", "C", "D"), report=SimpleNamespace(
        sweeps=(("k", "flow steps"),), sweep_score="iqm_auc"))
    entries = [(str(k), float(k), 10, 0.1 * k, 0.05 * k, 0.2 * k) for k in (1, 2, 4, 8)]
    figures.sweeps(study, {"k": {"TD3+SF²": entries, "SAC+SF²": entries}}, None, tasks={1})
    ax = drawn["fig"].axes[0]
    td3, sac = (line for line in ax.lines if line.get_label().endswith("(n=10)"))
    assert td3.get_color() != sac.get_color() and td3.get_marker() != sac.get_marker()
    np.testing.assert_allclose(td3.get_xdata(), [0.9125, 1.9125, 3.9125, 7.9125])
    np.testing.assert_allclose(sac.get_xdata(), [1.0875, 2.0875, 4.0875, 8.0875])
    np.testing.assert_allclose(td3.get_ydata(), [0.1, 0.2, 0.4, 0.8])
    assert [t.get_text() for t in ax.get_xticklabels()] == ["1", "2", "4", "8"]
    assert "over 1 of 4 tasks (interim: summary.md says which) and seeds" in drawn["fig"]._suptitle.get_text()
    assert ax.get_ylabel() == "IQM of normalized AUC over 1 of 4 tasks"
    figures._plt().close(drawn["fig"])
