"""Seed groups (`seeds_per_run` in a study file, sf2_studies.spec): the groups and their folders, bad
values refused, one run per (task, method, group) resolved, selected by `--seeds`, planned and listed by
`study run --dry-run` on their own; the report joins the groups' seeds per (task, method), names the
missing ones and flags methods compared at unequal seed counts. No framework: configs are
sf2_common's `TrainConfig`, run folders are fabricated, every expected number is derived by hand."""

from __future__ import annotations

import argparse
import csv
import json

import pytest
from sf2_common.agents import tasks as task_table
from sf2_common.agents.configs import TrainConfig, schedule
from sf2_studies import commands, runner, spec
from sf2_studies.folder import StudyFolder
from sf2_studies.spec import StudyError

STUDY = """
name = "groups"
seeds = "0-14"
seeds_per_run = 5
tasks = ["A", "B"]
[[methods]]
label = "TD3"
algo = "td3"
representation = "none"
[[methods]]
label = "TD3+SF²"
algo = "td3"
representation = "sf2"
"""


def _load(tmp_path, text=STUDY):
    path = tmp_path / "s.toml"
    path.write_text(text)
    return spec.load(path)


def _make(preset, task, algo, rep, overrides):
    return TrainConfig(task=task, algo=algo, representation=rep, num_timesteps=1000, num_envs=4,
                       min_replay_size=8, num_evals=3)


def _resolve(study, monkeypatch):
    monkeypatch.setattr(task_table, "validate_task", lambda task: task)   # tasks "A", "B": no Playground
    return spec.resolve(study, _make, lambda cfg, seeds: cfg)


def test_groups_and_their_folders(tmp_path):
    study = _load(tmp_path)
    assert study.seed_groups() == (tuple(range(5)), tuple(range(5, 10)), tuple(range(10, 15)))
    assert [study.group_folder(g) for g in study.seed_groups()] == ["seeds-0-4", "seeds-5-9", "seeds-10-14"]
    # 12 seeds by 5: the last group is shorter; non-consecutive seeds keep their file order
    short = _load(tmp_path, STUDY.replace('"0-14"', '"0-11"'))
    assert short.seed_groups() == (tuple(range(5)), tuple(range(5, 10)), (10, 11))
    odd = _load(tmp_path, STUDY.replace('"0-14"', "[0, 2, 4, 6]").replace("= 5", "= 3"))
    assert odd.seed_groups() == ((0, 2, 4), (6,)) and odd.group_folder((0, 2, 4)) == "seeds-0_2_4"
    # without seeds_per_run: one group of every seed, the method's own folder (today's layout)
    plain = _load(tmp_path, STUDY.replace("seeds_per_run = 5\n", ""))
    assert plain.seed_groups() == (tuple(range(15)),) and plain.group_folder(tuple(range(15))) is None


@pytest.mark.parametrize("value", ["0", "16", "true", '"5"', "2.5"])
def test_bad_seeds_per_run(tmp_path, value):
    with pytest.raises(StudyError) as info:
        _load(tmp_path, STUDY.replace("seeds_per_run = 5", f"seeds_per_run = {value}"))
    msg = str(info.value)
    assert str(tmp_path / "s.toml") in msg and "seeds_per_run" in msg and "an int from 1 to 15" in msg


def test_runs_per_group_selected_by_seeds(tmp_path, monkeypatch):
    study = _load(tmp_path)
    runs = _resolve(study, monkeypatch)
    assert [(r.task, r.rel) for r in runs] == [(t, f"{m}/seeds-{g}") for t in "AB" for m in ("td3", "td3-sf2")
                                               for g in ("0-4", "5-9", "10-14")]
    for r in runs:
        i = r.argv.index("--seeds")
        assert r.argv[i + 1] == spec.seeds_text(r.seeds) and r.argv.count("--seeds") == 1
    first = spec.select_runs(study, runs, seeds="0-4")
    assert [(r.task, r.rel) for r in first] == [("A", "td3/seeds-0-4"), ("A", "td3-sf2/seeds-0-4"),
                                                ("B", "td3/seeds-0-4"), ("B", "td3-sf2/seeds-0-4")]
    # only groups wholly inside: 0-7 holds 0-4 but not 5-9; filters combine
    assert spec.select_runs(study, runs, seeds="0-7") == first
    assert [(r.task, r.rel) for r in spec.select_runs(study, runs, ["B"], ["TD3+SF²"], "5-14")] == [
        ("B", "td3-sf2/seeds-5-9"), ("B", "td3-sf2/seeds-10-14")]
    assert len(spec.select_runs(study, runs)) == 12
    for bad in ("1-3", "20-24"):
        with pytest.raises(StudyError, match=rf"--seeds {bad}: no seed group .*groups: 0-4, 5-9, 10-14"):
            spec.select_runs(study, runs, seeds=bad)
    # without seeds_per_run the only group is every seed: today's runs and folders
    plain = _load(tmp_path, STUDY.replace("seeds_per_run = 5\n", ""))
    runs = _resolve(plain, monkeypatch)
    assert [r.rel for r in runs] == ["td3", "td3-sf2"] * 2 and all(r.seeds == plain.seeds for r in runs)
    with pytest.raises(StudyError, match="no seeds_per_run: all seeds are one run.*groups: 0-14"):
        spec.select_runs(plain, runs, seeds="0-4")


def _fabricate(path, run, seeds, last_epoch, walltime=10.0):
    """A run folder as the trainer leaves it: config.json and one row per (epoch <= last_epoch, seed)."""
    path.mkdir(parents=True, exist_ok=True)
    (path / "config.json").write_text(json.dumps({"config": run.config.to_dict(), "seeds": list(seeds),
                                                  "schedule": {"num_epochs": 2}}))
    sched = schedule(run.config)
    rows = [{"epoch": e, "seed": s, "env_steps": e * sched.env_steps_per_epoch, "eval_return": float(e),
             "walltime": walltime * e / 2} for e in range(last_epoch + 1) for s in seeds]
    (path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_plan_and_dry_run_per_group(tmp_path, monkeypatch, capsys):
    """One group finished, one partial, one new per (task, method): plan and `--dry-run` see three runs,
    the progress totals count each group's own seeds."""
    study = _load(tmp_path)
    runs = _resolve(study, monkeypatch)
    folder = StudyFolder(tmp_path / "study")
    folder.open(study, "jax", runs)
    assert schedule(runs[0].config).num_epochs == 2
    for run in runs:
        if run.seeds[0] == 0:
            _fabricate(folder.path_of(run), run, run.seeds, last_epoch=2)
        elif run.seeds[0] == 5:
            _fabricate(folder.path_of(run), run, run.seeds, last_epoch=1)
    todo, done = runner.plan(study, folder, runs)
    assert [j.name for j in done] == [f"{t}/{m}/seeds-0-4" for t in "AB" for m in ("td3", "td3-sf2")]
    assert len(todo) == 8
    per_seed = schedule(runs[0].config).total_env_steps
    for job in todo + done:
        assert job.total_steps == 5 * per_seed
        assert job.path == tmp_path / "study" / "runs" / job.name
    for job in todo:
        assert job.commands[0][job.commands[0].index("--seeds") + 1] == spec.seeds_text(job.run.seeds)
        assert job.commands[0][job.commands[0].index("--out") + 1] == str(job.path)
    # a group folder holding other seeds is refused by name
    bad = runs[2]
    _fabricate(folder.path_of(bad), bad, (10, 11), last_epoch=0)
    with pytest.raises(StudyError, match="seeds: \\[10, 11\\] \\(folder\\) vs \\[10, 11, 12, 13, 14\\]"):
        runner.plan(study, folder, [bad])
    (folder.path_of(bad) / "config.json").unlink()
    (folder.path_of(bad) / "metrics.jsonl").unlink()

    backend = runner.Backend("sf2-fake", "jax", "fake", _make, lambda cfg, seeds: cfg)
    args = argparse.Namespace(file=str(study.path), out=str(folder.path), tasks="A", methods=None,
                              seeds="0-9", workers=None, ray=None, dry_run=True, no_progress=True,
                              finish_within=None, forecast_from=[], log=None)
    assert commands._run(backend, args, "cmd") == 0
    out = capsys.readouterr().out.splitlines()
    assert "4 run(s) selected of 12; seed groups 0-4, 5-9" in out[0]
    assert out[1:] == ["  done     A/td3/seeds-0-4", "  done     A/td3-sf2/seeds-0-4",
                       *[f"  partial  A/{m}/seeds-5-9 (≈ 5s): sf2-fake train --task A --algo td3 --repr "
                         f"{r} --config quick --seeds 5-9 --out {folder.path}/runs/A/{m}/seeds-5-9 "
                         f"--no-progress" for m, r in (("td3", "none"), ("td3-sf2", "sf2"))],
                       # the finished groups took 10 s for their budget; the partial ones stopped halfway
                       # (epoch 1 of 2): half a budget each at 10 s a budget, 2 × that in all; the forecast
                       # draws on every finished run of the folder, the two outside this selection included
                       "estimate: 2 run(s) to do ≈ 10s of training on one worker (at the wall time per env "
                       "step of the 4 finished run(s) here)"]
    with pytest.raises(StudyError, match="--seeds 20: no seed group"):
        commands._run(backend, argparse.Namespace(**{**vars(args), "seeds": "20"}), "cmd")


def test_forecast_from_another_study(tmp_path, monkeypatch, capsys):
    """A new study (SAC) has no finished run to forecast from; `--forecast-from` lends it another study's
    (TD3) finished runs, read only. Its methods have no runs there, so each job takes the slowest finished
    run of its task (runner.Forecast, preference 4) at its seed count: TD3 took 10 s and TD3+SF² 20 s a
    budget of 5 seeds on task A, so every SAC job of 5 seeds on A is forecast 20 s."""
    other = _load(tmp_path)
    other_folder = StudyFolder(tmp_path / "td3-study")
    other_runs = _resolve(other, monkeypatch)
    other_folder.open(other, "jax", other_runs)
    for run in other_runs:
        if run.task == "A" and run.seeds[0] == 0:
            _fabricate(other_folder.path_of(run), run, run.seeds, last_epoch=2,
                       walltime=10.0 if run.folder == "td3" else 20.0)
    before = {f: f.read_bytes() for f in other_folder.path.rglob("*") if f.is_file()}
    sac = _load(tmp_path, STUDY.replace('"groups"', '"sac-groups"').replace('"td3"', '"sac"')
                .replace('"TD3', '"SAC'))
    sac.path.rename(tmp_path / "sac.toml")
    backend = runner.Backend("sf2-fake", "jax", "fake", _make, lambda cfg, seeds: cfg)
    args = argparse.Namespace(file=str(tmp_path / "sac.toml"), out=str(tmp_path / "sac-study"), tasks="A",
                              methods=None, seeds="0-4", workers=None, ray=None, dry_run=True,
                              no_progress=True, finish_within=None, forecast_from=[], log=None)
    assert commands._run(backend, args, "cmd") == 0
    alone = capsys.readouterr().out.splitlines()
    assert len(alone) == 3 and not any("≈" in line or "estimate" in line for line in alone)
    lend = argparse.Namespace(**{**vars(args), "forecast_from": [str(other_folder.path)]})
    assert commands._run(backend, lend, "cmd") == 0
    lent = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in lent[1:3]] == ["  new      A/sac/seeds-0-4 (≈ 20s)",
                                                          "  new      A/sac-sf2/seeds-0-4 (≈ 20s)"]
    assert lent[3] == ("estimate: 2 run(s) to do ≈ 40s of training on one worker (at the wall time per env "
                       f"step of the 2 finished run(s) here and in {other_folder.path})")
    assert {f: f.read_bytes() for f in other_folder.path.rglob("*") if f.is_file()} == before
    # what is not another study's folder is refused by name, nothing run
    for bad, match in ((tmp_path / "nowhere", "--forecast-from .*nowhere: no such folder"),
                       (tmp_path / "sac-study", "is the study folder being run"),
                       (tmp_path, "is not a study folder")):
        with pytest.raises(StudyError, match=match):
            commands._run(backend, argparse.Namespace(**{**vars(args), "forecast_from": [str(bad)]}), "cmd")


def test_skip_done_in_another_folder(tmp_path, monkeypatch, capsys):
    """`--skip-done-in`: a study run into a second folder (to be merged back) does not run again what the
    study's own folder holds finished with exactly its config and seeds: A/td3/seeds-0-4 there is skipped;
    A/td3-sf2/seeds-0-4 there has another adam_eps (as a superseded preset value would) and runs; a run
    begun in the second folder continues there; the own folder is read only; bad folders are refused."""
    study = _load(tmp_path)
    runs = _resolve(study, monkeypatch)
    own = StudyFolder(tmp_path / "own")
    own.open(study, "jax", runs)
    for run in runs:
        if run.task == "A" and run.seeds[0] == 0:
            config = run.config if run.folder == "td3" else run.config.replace(adam_eps=1e-3)
            _fabricate(own.path_of(run), run.__class__(**{**vars(run), "config": config}), run.seeds,
                       last_epoch=2)
    before = {f: f.read_bytes() for f in own.path.rglob("*") if f.is_file()}
    second = StudyFolder(tmp_path / "second")
    backend = runner.Backend("sf2-fake", "jax", "fake", _make, lambda cfg, seeds: cfg)
    args = argparse.Namespace(file=str(study.path), out=str(second.path), tasks="A", methods=None,
                              seeds="0-9", workers=None, ray=None, dry_run=True, no_progress=True,
                              finish_within=None, forecast_from=[], skip_done_in=[str(own.path)], log=None)
    assert commands._run(backend, args, "cmd") == 0
    out = [line.split(":")[0] for line in capsys.readouterr().out.splitlines()[1:]]
    assert out == ["  elsewhere A/td3/seeds-0-4", "  new      A/td3/seeds-5-9",
                   "  new      A/td3-sf2/seeds-0-4", "  new      A/td3-sf2/seeds-5-9"]
    # begun in the second folder: it resumes there, whatever the own folder holds
    td3 = next(r for r in runs if r.task == "A" and r.folder == "td3" and r.seeds[0] == 0)
    second.open(study, "jax", runs)
    _fabricate(second.path_of(td3), td3, td3.seeds, last_epoch=1)
    assert commands._run(backend, args, "cmd") == 0
    out = [line.split(":")[0] for line in capsys.readouterr().out.splitlines()[1:]]
    assert out[0] == "  partial  A/td3/seeds-0-4" and not any("elsewhere" in line for line in out)
    assert {f: f.read_bytes() for f in own.path.rglob("*") if f.is_file()} == before
    for bad, match in ((tmp_path / "nowhere", "--skip-done-in .*nowhere: no such folder"),
                       (second.path, "is the study folder being run"), (tmp_path, "is not a study folder")):
        with pytest.raises(StudyError, match=match):
            commands._run(backend, argparse.Namespace(**{**vars(args), "skip_done_in": [str(bad)]}), "cmd")


REPORT = """
name = "joined"
seeds = "0-3"
seeds_per_run = 2
tasks = ["A", "B"]
[report]
figures = ["aggregate"]
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
"""


def test_report_joins_groups_and_flags_unequal_seeds(tmp_path):
    """Groups 0-1 and 2-3. Seed s of method m on task t has the curve [0, v, v] at env steps 0, 100, 200
    with v = k · (1 + s), k = 1 for TD3 and 3 for TD3+SF²: AUC 3v/4. Both of TD3's groups finish on both
    tasks; TD3+SF²'s group 2-3 finishes on A only (on B it stops at epoch 1). On A v runs from 1 (TD3, seed
    0) to 12 (TD3+SF², seed 3): normalized (v − 1) / 11. On B TD3 has v = 1..4 and TD3+SF² (seeds 0-1)
    v = 3, 6: normalized (v − 1) / 5. TD3+SF² enters the aggregate with seeds 0-1 (no interval: n < 3)."""
    pytest.importorskip("rliable", reason="sf2-studies' dependencies: pip install packages/sf2-studies")
    from sf2_studies.report import report

    study = spec.loads(REPORT, tmp_path / "s.toml")
    folder = StudyFolder(tmp_path / "study")
    folder.open(study, "jax", [])
    for task in "AB":
        for name, k in (("td3", 1), ("td3-sf2", 3)):
            for group, wall in (((0, 1), 10.0), ((2, 3), 20.0)):
                path = folder.run_path(task, f"{name}/{study.group_folder(group)}")
                path.mkdir(parents=True)
                last = 1 if (task, name, group[0]) == ("B", "td3-sf2", 2) else 2
                (path / "config.json").write_text(json.dumps({"config": {}, "seeds": list(group),
                                                              "schedule": {"num_epochs": 2}}))
                rows = [{"epoch": e, "seed": s, "env_steps": 100 * e, "walltime": wall * e / 2,
                         "eval_return": [0.0, k * (1 + s), k * (1 + s)][e]}
                        for e in range(last + 1) for s in group]
                (path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    written = report(folder.path)
    rows = list(csv.DictReader(open(written["results.csv"])))
    assert len(rows) == 4 + 4 + 4 + 2
    for r in rows:
        k = 3 if r["method"] == "TD3+SF²" else 1
        v = k * (1 + int(r["seed"]))
        assert float(r["auc"]) == pytest.approx(0.75 * v)
        assert float(r["normalized_auc"]) == pytest.approx((v - 1) / (11 if r["task"] == "A" else 5))
        assert float(r["wall_time_s"]) == (10.0 if int(r["seed"]) < 2 else 20.0)   # the seed's own run
    assert sorted(int(r["seed"]) for r in rows if r["task"] == "B" and r["method"] == "TD3+SF²") == [0, 1]
    summary = written["summary.md"].read_text()
    assert "Runs: 3 of 4 (task, method) pairs have all 4 of the study's seeds, 1 some of them" in summary
    assert "in seed groups (0-1, 2-3), one run each" in summary
    assert "| TD3 | 4 | 4 |" in summary and "| TD3+SF² | 4 | 2 (missing 2-3) |" in summary
    assert "**Unequal seed counts**: methods are compared at different numbers of seeds on B (TD3: TD3 4, " \
           "TD3+SF² 2)" in summary
    # per-task table: seeds present of the study's; wall time summed over the groups (10 s + 20 s)
    assert "| B | TD3+SF² | 2 of 4 |" in summary and "| A | TD3+SF² | 4 | " in summary
    assert "| 30s |" in summary and "| env steps | wall time, runs summed |" in summary
    assert "Wall time (per task): the wall times of the method's finished runs on that task" in summary
    # the aggregate: every method of the family on the seeds all of them finished on both tasks, 0-1.
    # TD3+SF²: (v − 1)/11 on A and (v − 1)/5 on B for v = 3, 6: per-task means 3.5/11 and 3.5/5, median =
    # mean of the two: (3.5/11 + 3.5/5)/2. TD3: v = 1, 2: per-task means 0.5/11 and 0.5/5.
    line = next(x for x in summary.splitlines() if x.startswith("| TD3+SF² | 2 × 2 |"))
    assert f"{(3.5 / 11 + 3.5 / 5) / 2:.3f} (n < 3: no CI)" in line
    line = next(x for x in summary.splitlines() if x.startswith("| TD3 | 2 × 2 |"))
    assert f"{(0.5 / 11 + 0.5 / 5) / 2:.3f} (n < 3: no CI)" in line
    assert ("**TD3: interim aggregate** over all the study's 2 tasks (A, B), seeds 0-1 (2 of 4). Seeds 2-3 "
            "are finished on these tasks by some methods only and left out") in summary
    assert "Unequal seed counts (TD3)" not in summary     # the aggregate compares equal seeds
    assert "| B | TD3+SF² | 2-3: partial (epoch 1 of 2) |" in summary


def test_listed_groups_split_the_seeds(tmp_path):
    """`seeds_per_run` may list the groups: they must split the study's seeds, each seed in one group."""
    study = _load(tmp_path, STUDY.replace("seeds_per_run = 5", 'seeds_per_run = ["0-4", "5-14"]'))
    assert study.seed_groups() == (tuple(range(5)), tuple(range(5, 15)))
    assert [study.group_folder(g) for g in study.seed_groups()] == ["seeds-0-4", "seeds-5-14"]
    assert study.groups_text == "seed groups 0-4, 5-14"
    assert study.select_groups("5-14") == (tuple(range(5, 15)),)
    for groups, why in (('["0-4", "4-14"]', "in two groups: 4"), ('["0-4", "6-14"]', "in no group: 5"),
                        ('["0-4", "5-15"]', "not seeds of the study: 15"),
                        ('["0-4", "x"]', "group 'x' is invalid"), ("[]", "\\[\\] is invalid")):
        with pytest.raises(StudyError, match=why):
            _load(tmp_path, STUDY.replace("seeds_per_run = 5", f"seeds_per_run = {groups}"))


@pytest.mark.parametrize("on_disk,accepted", [(["seeds-0-4"], True), (["seeds-0-4", "seeds-5-9"], False),
                                              ([], True)])
def test_a_folder_accepts_other_groups_that_keep_its_runs(tmp_path, monkeypatch, on_disk, accepted):
    """A folder made with groups of 5 accepts the groups 0-4, 5-14 while it holds no run folder of a group
    that would be gone (5-9); a folder made without seed groups keeps its layout once it holds a run folder,
    and takes seed groups while it holds none."""
    old = _load(tmp_path)
    folder = StudyFolder(tmp_path / "study")
    folder.open(old, "jax", _resolve(old, monkeypatch))
    for name in on_disk:
        (folder.path / "runs" / "A" / "td3" / name).mkdir(parents=True)
    new = _load(tmp_path, STUDY.replace("seeds_per_run = 5", 'seeds_per_run = ["0-4", "5-14"]'))
    if accepted:
        folder.open(new, "jax", _resolve(new, monkeypatch))
        assert folder.load_study().seed_groups() == new.seed_groups()      # the copy follows the file
    else:
        with pytest.raises(StudyError, match="differ in seeds_per_run"):
            folder.check(new, "jax")
    flat = StudyFolder(tmp_path / "flat")
    ungrouped = _load(tmp_path, STUDY.replace("seeds_per_run = 5", ""))
    flat.open(ungrouped, "jax", _resolve(ungrouped, monkeypatch))
    flat.check(new, "jax")                                                  # no run folder: nothing to keep
    (flat.path / "runs" / "A" / "td3").mkdir(parents=True)
    with pytest.raises(StudyError, match="differ in seeds_per_run"):
        flat.check(new, "jax")


def test_merge_takes_a_source_of_other_groups_that_are_still_groups(tmp_path, monkeypatch):
    """`study merge` into a folder whose study lists the groups 0-4, 5-14 (and holds a run folder of 5-14)
    takes a source made with groups of 5 while the source holds run folders of 0-4 only; one of 5-9 makes
    it refuse, writing nothing."""
    from sf2_studies import merge as merging

    old = _load(tmp_path)
    new = _load(tmp_path, STUDY.replace("seeds_per_run = 5", 'seeds_per_run = ["0-4", "5-14"]'))
    dest = StudyFolder(tmp_path / "dest")
    dest.open(new, "jax", _resolve(new, monkeypatch))
    (dest.path / "runs" / "A" / "td3" / "seeds-5-14").mkdir(parents=True)
    src = StudyFolder(tmp_path / "src")
    src.open(old, "jax", _resolve(old, monkeypatch))
    (src.path / "runs" / "A" / "td3" / "seeds-0-4").mkdir(parents=True)

    def runs_of(study):
        return _resolve(study, monkeypatch)

    out = merging.merge([src.path], dest.path, runs_of, framework="jax", say=lambda line: None)
    assert not out.merged
    (src.path / "runs" / "A" / "td3" / "seeds-5-9").mkdir(parents=True)
    with pytest.raises(StudyError, match="differ in seeds_per_run"):
        merging.merge([src.path], dest.path, runs_of, framework="jax", say=lambda line: None)


def test_merge_regroups_a_folder_that_holds_no_run(tmp_path, monkeypatch):
    """`study merge` of a source made with seed groups into a folder made without them takes the source's
    study while the folder holds no run folder (its study.toml follows, study.json keeps its commands and
    drops its entries of the old layout); once the folder holds one, it refuses, writing nothing."""
    from sf2_studies import merge as merging

    ungrouped = _load(tmp_path, STUDY.replace("seeds_per_run = 5\n", ""))
    grouped = _load(tmp_path, STUDY.replace("seeds_per_run = 5", 'seeds_per_run = ["0-4", "5-14"]'))
    dest = StudyFolder(tmp_path / "dest")
    dest.open(ungrouped, "jax", _resolve(ungrouped, monkeypatch), command="sf2-jax study run old")
    src = StudyFolder(tmp_path / "src")
    src.open(grouped, "jax", _resolve(grouped, monkeypatch), command="sf2-jax study run new")
    (src.path / "runs" / "A" / "td3" / "seeds-0-4").mkdir(parents=True)

    def runs_of(study):
        return _resolve(study, monkeypatch)

    lines = []
    merging.merge([src.path], dest.path, runs_of, framework="jax", say=lines.append)
    assert dest.load_study().seed_groups() == grouped.seed_groups()
    assert any("study.toml of" in line and "replaced by a source's" in line for line in lines)
    state = dest.read_state()
    assert [c["command"] for c in state["commands"]] == ["sf2-jax study run old", "sf2-jax study run new"]
    assert {r["folder"].split("/")[-1] for r in state["runs"]} == {"seeds-0-4", "seeds-5-14"}
    first = dest.method_runs(grouped)[("A", "td3")][tuple(range(5))]
    assert first == dest.path / "runs" / "A" / "td3" / "seeds-0-4"
    again = StudyFolder(tmp_path / "dest2")
    again.open(ungrouped, "jax", _resolve(ungrouped, monkeypatch))
    (again.path / "runs" / "A" / "td3").mkdir(parents=True)
    before = again.study_path.read_text()
    with pytest.raises(StudyError, match="differ in seeds_per_run"):
        merging.merge([src.path], again.path, runs_of, framework="jax", say=lambda line: None)
    assert again.study_path.read_text() == before
