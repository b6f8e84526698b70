"""`study merge` (sf2_studies.merge): runs of study folders and their .tar.gz archives joined into one
study folder. No framework: configs are sf2_common's `TrainConfig`, run folders are fabricated as the
trainer leaves them (config.json, metrics.jsonl, train.log, plus what a merge must never copy:
checkpoints/, final/*.npz, learning_curve.png)."""

from __future__ import annotations

import gzip
import json
import shutil
import tarfile

import pytest
from sf2_common.agents import tasks as task_table
from sf2_common.agents.configs import TrainConfig, schedule
from sf2_common.agents.runfolder import RunFolder, RunFolderError
from sf2_common.fileio import read_text
from sf2_studies import merge as merging
from sf2_studies import spec
from sf2_studies.folder import StudyFolder
from sf2_studies.spec import StudyError
from sf2_testing import folder_digest

STUDY = """
name = "merging"
seeds = "0-3"
seeds_per_run = 2
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


def _make(preset, task, algo, rep, overrides):
    return TrainConfig(task=task, algo=algo, representation=rep, num_timesteps=1000, num_envs=4,
                       min_replay_size=8, num_evals=3)


@pytest.fixture
def runs_of(monkeypatch):
    monkeypatch.setattr(task_table, "validate_task", lambda task: task)   # tasks "A", "B": no Playground
    return lambda study: spec.resolve(study, _make, lambda cfg, seeds: cfg)


def _source(tmp_path, name, runs_of, finished=(), partial=(), commands=(), text=STUDY, ret=0.0):
    """A study folder as `study run` leaves it: study.toml, study.json with `commands` (times), and the
    run folders named in `finished` / `partial` ('A/td3/seeds-0-1')."""
    study = spec.loads(text, tmp_path / f"{name}.toml")
    runs = {f"{r.task}/{r.rel}": r for r in runs_of(study)}
    folder = StudyFolder(tmp_path / name)
    folder.open(study, "jax", list(runs.values()))
    state = folder.read_state()
    state["commands"] = [{"command": f"sf2-jax study run {c}", "host": name, "time": c} for c in commands]
    (folder.path / "study.json").write_text(json.dumps(state, indent=2))
    sched = schedule(next(iter(runs.values())).config)
    assert sched.num_epochs == 2
    for rel, last in [(r, 2) for r in finished] + [(r, 1) for r in partial]:
        run = runs[rel]
        path = folder.path_of(run)
        path.mkdir(parents=True)
        conf = {"config": run.config.to_dict(), "seeds": list(run.seeds), "schedule": {"num_epochs": 2}}
        (path / "config.json").write_text(json.dumps(conf))
        rows = [{"epoch": e, "seed": s, "env_steps": e * sched.env_steps_per_epoch,
                 "eval_return": ret + e + s} for e in range(last + 1) for s in run.seeds]
        (path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
        (path / "train.log").write_text(f"trained on {name}\n")
        (path / "learning_curve.png").write_bytes(b"png")
        (path / "checkpoints" / str(last)).mkdir(parents=True)
        (path / "checkpoints" / str(last) / "state").write_bytes(b"big")
        (path / "final").mkdir()
        (path / "final" / "params_seed0.npz").write_bytes(b"params")
    return folder.path


def _merge(sources, dest, runs_of, **kw):
    lines = []
    out = merging.merge(sources, dest, runs_of, framework="jax", say=lines.append, **kw)
    return out, "\n".join(lines)


def test_merge_into_a_new_folder_copies_finished_runs_only_their_kept_files(tmp_path, runs_of):
    src = _source(tmp_path, "gpu", runs_of, finished=["A/td3/seeds-0-1", "B/td3-sf2/seeds-2-3"],
                  partial=["A/td3-sf2/seeds-0-1"], commands=["2026-01-01 10:00:00"])
    dest = tmp_path / "results"
    out, said = _merge([src], dest, runs_of)
    assert out.created and sorted(out.merged) == ["A/td3/seeds-0-1", "B/td3-sf2/seeds-2-3"]
    assert "A/td3-sf2/seeds-0-1 in " in said and "--partial merges unfinished runs" in said
    have = folder_digest(dest)
    mine = folder_digest(src)
    assert (dest / "study.toml").read_text() == (src / "study.toml").read_text()
    assert json.loads((dest / "study.json").read_text()) == json.loads((src / "study.json").read_text())
    # exactly config.json, metrics.jsonl (gzip-compressed), train.log of the finished runs, byte for byte
    finished = ("A/td3/seeds-0-1", "B/td3-sf2/seeds-2-3")
    expected = {f"runs/{r}/{f}" for r in finished
                for f in ("config.json", "metrics.jsonl.gz", "train.log")} | {"study.toml", "study.json"}
    assert set(have) == expected
    plain = {k for k in expected if not k.endswith((".gz", "study.json"))}  # study.json: equal as JSON above
    assert all(have[k] == mine[k] for k in plain)
    for r in finished:
        assert (gzip.decompress((dest / f"runs/{r}/metrics.jsonl.gz").read_bytes())
                == (src / f"runs/{r}/metrics.jsonl").read_bytes())
    # --partial: the unfinished run too (DEST has none of it)
    out, _ = _merge([src], dest, runs_of, partial=True)
    assert out.merged == ["A/td3-sf2/seeds-0-1"]
    assert (dest / "runs/A/td3-sf2/seeds-0-1/metrics.jsonl.gz").exists()


def test_two_sources_with_disjoint_runs_and_their_commands_in_time_order(tmp_path, runs_of):
    one = _source(tmp_path, "one", runs_of, finished=["A/td3/seeds-0-1"],
                  commands=["2026-01-01 10:00:00", "2026-01-03 10:00:00"])
    two = _source(tmp_path, "two", runs_of, finished=["B/td3/seeds-2-3"], commands=["2026-01-02 10:00:00"])
    dest = tmp_path / "results"
    out, _ = _merge([one, two], dest, runs_of)
    assert out.merged == ["A/td3/seeds-0-1", "B/td3/seeds-2-3"] and out.commands_added == 3
    state = json.loads((dest / "study.json").read_text())
    assert [c["time"] for c in state["commands"]] == ["2026-01-01 10:00:00", "2026-01-02 10:00:00",
                                                      "2026-01-03 10:00:00"]
    assert state["id"] == json.loads((one / "study.json").read_text())["id"]
    assert len(state["runs"]) == 8     # 2 tasks × 2 methods × 2 seed groups, once each
    assert {(r["task"], r["folder"]) for r in state["runs"]} == {
        (t, f"{m}/seeds-{g}") for t in "AB" for m in ("td3", "td3-sf2") for g in ("0-1", "2-3")}
    # a later source replaces DEST's unfinished run with its finished one; DEST keeps its id
    three = _source(tmp_path, "three", runs_of, partial=["A/td3-sf2/seeds-0-1"])
    four = _source(tmp_path, "four", runs_of, finished=["A/td3-sf2/seeds-0-1"],
                   commands=["2026-01-02 10:00:00"])
    _merge([three], dest, runs_of, partial=True)
    assert len(read_text(dest / "runs/A/td3-sf2/seeds-0-1/metrics.jsonl").splitlines()) == 2 * 2
    out, said = _merge([four], dest, runs_of)
    # DEST's: 2 seeds at epoch 1 of 2
    sched = schedule(_make("quick", "A", "td3", "sf2", {}))
    assert out.replaced == ["A/td3-sf2/seeds-0-1"] and (
        f"DEST's was unfinished, {2 * sched.env_steps_per_epoch:,} of {2 * sched.total_env_steps:,} env steps"
        in said)
    assert len(read_text(dest / "runs/A/td3-sf2/seeds-0-1/metrics.jsonl").splitlines()) == 3 * 2
    assert json.loads((dest / "study.json").read_text())["id"] == state["id"]
    # four's command has two's time but another host: another command
    assert len(json.loads((dest / "study.json").read_text())["commands"]) == 4
    # a finished DEST run stays when a source brings it unfinished
    out, said = _merge([three], dest, runs_of, partial=True)
    assert out.skipped == ["A/td3-sf2/seeds-0-1"] and "DEST's is finished" in said


def test_identical_merge_again_changes_nothing(tmp_path, runs_of):
    src = _source(tmp_path, "gpu", runs_of, finished=["A/td3/seeds-0-1"], commands=["2026-01-01 10:00:00"])
    dest = tmp_path / "results"
    _merge([src], dest, runs_of)
    before = folder_digest(dest)
    out, said = _merge([src, src], dest, runs_of)
    assert not out.merged and not out.replaced and out.commands_added == 0
    assert "identical to DEST's" in said and folder_digest(dest) == before


def test_conflicting_finished_run_is_refused_and_nothing_written(tmp_path, runs_of):
    ours = _source(tmp_path, "ours", runs_of, finished=["A/td3/seeds-0-1"], commands=["2026-01-01 10:00:00"])
    theirs = _source(tmp_path, "theirs", runs_of, finished=["A/td3/seeds-0-1", "B/td3/seeds-0-1"],
                     commands=["2026-01-02 10:00:00"], ret=0.5)
    dest = tmp_path / "results"
    _merge([ours], dest, runs_of)
    before = folder_digest(dest)
    with pytest.raises(StudyError) as info:
        _merge([theirs], dest, runs_of)
    msg = str(info.value)
    # the first differing row: epoch 0 seed 0, eval_return 0 + 0 + 0 (DEST) vs 0.5 + 0 + 0 (source)
    assert "A/td3/seeds-0-1: DEST and " in msg and "epoch 0 seed 0: eval_return 0.0 vs 0.5" in msg
    assert "nothing was written" in msg
    assert folder_digest(dest) == before and not (dest / "runs/B").exists()   # B's run not merged either
    # two hosts' runs differ in their timing fields on every row: the message names the first learned value
    # that differs (epoch 1 seed 0 here), and says so when only the timing differs
    timed = _source(tmp_path, "timed", runs_of, finished=["A/td3/seeds-0-1"],
                    commands=["2026-01-03 10:00:00"])
    metrics = timed / "runs/A/td3/seeds-0-1/metrics.jsonl"
    rows = [json.loads(line) for line in metrics.read_text().splitlines()]
    for r in rows:
        r["walltime"] = r["eval_seconds"] = 100.0 + r["epoch"]
    metrics.write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(StudyError, match=r"equal learned values, only timing differs; first epoch 0 seed 0: "
                                         r"eval_seconds None vs 100.0"):
        _merge([timed], dest, runs_of)
    rows[2]["eval_return"] = 7.0   # rows: (epoch 0, seeds 0 1), then (epoch 1, seed 0)
    metrics.write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(StudyError, match=r"epoch 1 seed 0: eval_return 1.0 vs 7.0"):
        _merge([timed], dest, runs_of)
    assert folder_digest(dest) == before


def test_archive_source_as_gpu_study_writes_it(tmp_path, runs_of):
    src = _source(tmp_path, "gpu", runs_of, finished=["A/td3/seeds-0-1"], partial=["B/td3/seeds-2-3"],
                  commands=["2026-01-01 10:00:00"])
    archive = tmp_path / "merging.tar.gz"
    with tarfile.open(archive, "w:gz") as tar:   # what scripts/gpu-host/gpu_study.sh packs: ./ of the folder
        tar.add(src, arcname=".", filter=lambda m: None if m.name.endswith(("checkpoints", "final")) else m)
    by_folder, by_archive = tmp_path / "by-folder", tmp_path / "by-archive"
    _merge([src], by_folder, runs_of)
    out, _ = _merge([str(archive)], by_archive, runs_of)
    assert out.merged == ["A/td3/seeds-0-1"] and folder_digest(by_archive) == folder_digest(by_folder)
    # a truncated archive, an empty one (scripts/gpu-host/gpu_study.sh after a failed command), a file that is
    # none
    data = archive.read_bytes()
    (tmp_path / "cut.tar.gz").write_bytes(data[: len(data) // 2])
    with tarfile.open(tmp_path / "empty.tar.gz", "w:gz"):
        pass
    (tmp_path / "notes.txt").write_text("hello")
    for bad, why in (("cut.tar.gz", "not a readable .tar.gz archive"),
                     ("empty.tar.gz", "not a study folder archive: it holds no study.toml"),
                     ("notes.txt", "not a readable .tar.gz archive")):
        with pytest.raises(StudyError, match=why):
            _merge([str(tmp_path / bad)], tmp_path / "never", runs_of)
    assert not (tmp_path / "never").exists()


def test_wrong_source_is_refused_with_dest_unchanged(tmp_path, runs_of):
    src = _source(tmp_path, "gpu", runs_of, finished=["A/td3/seeds-0-1"])
    dest = tmp_path / "results"
    _merge([src], dest, runs_of)
    before = folder_digest(dest)
    other = _source(tmp_path, "other", runs_of, finished=["A/td3/seeds-0-1"],
                    text=STUDY.replace('"merging"', '"other"'))
    with pytest.raises(StudyError, match="holds study 'other', not the study of --into .*differ in name"):
        _merge([other], dest, runs_of)
    with pytest.raises(StudyError, match="is not a study folder: it holds no study.toml"):
        _merge([tmp_path / "gpu" / "runs"], dest, runs_of)
    with pytest.raises(StudyError, match="does not exist"):
        _merge([tmp_path / "nowhere"], dest, runs_of)
    # a run folder whose config.json is not the study's config for that run
    bad = _source(tmp_path, "bad", runs_of, finished=["B/td3/seeds-0-1"])
    conf = bad / "runs/B/td3/seeds-0-1/config.json"
    conf.write_text(conf.read_text().replace('"num_envs": 4', '"num_envs": 8'))
    with pytest.raises(StudyError, match=r"num_envs: 8 \(folder\) vs 4 \(now\)"):
        _merge([bad], dest, runs_of)
    # runs of the other framework
    state = json.loads((src / "study.json").read_text())
    (src / "study.json").write_text(json.dumps({**state, "framework": "torch"}))
    with pytest.raises(StudyError, match="holds runs of sf2-torch; merge it with `sf2-torch study merge`"):
        _merge([src], dest, runs_of)
    assert folder_digest(dest) == before
    # a damaged study.json, in a source or in DEST: named, with the remedy; nothing written
    from sf2_studies.report import report

    for content in ("{", "[1, 2]"):
        (src / "study.json").write_text(content)
        with pytest.raises(StudyError, match=r"gpu: .*gpu/study.json is not a study's state .*nothing was "
                                             r"merged. Restore it"):
            _merge([src], dest, runs_of)
        damaged = folder_digest(src)
        for command in (lambda: _merge([dest], src, runs_of), lambda: report(src),
                        lambda: StudyFolder(src).open(StudyFolder(src).load_study(), "jax", [])):
            with pytest.raises(StudyError, match=r"study.json is not a study's state .*delete it and "
                                                 r"`study run` again"):
                command()
        assert folder_digest(src) == damaged
    assert folder_digest(dest) == before


def test_a_source_that_adds_a_method_gives_dest_its_study_file(tmp_path, runs_of):
    """DEST ran the study; a host ran it with an ablation added (a third method): the merge takes that
    method's runs and DEST's study.toml becomes the larger study's. Merging DEST's older study into the
    larger DEST afterwards changes nothing; a source that changes a method is still refused."""
    grown = STUDY + '[[methods]]\nlabel = "SAC+SF²"\nname = "own"\nalgo = "sac"\nrepresentation = "sf2"\n'
    old = _source(tmp_path, "old", runs_of, finished=["A/td3/seeds-0-1"])
    dest = tmp_path / "results"
    _merge([old], dest, runs_of)
    new = _source(tmp_path, "new", runs_of, finished=["A/own/seeds-0-1"], text=grown)
    outcome, said = _merge([new], dest, runs_of)
    assert "A/own/seeds-0-1" in outcome.merged and "replaced by a source's" in said
    assert StudyFolder(dest).load_study().data == spec.loads(grown, tmp_path / "g.toml").data
    assert (dest / "runs" / "A" / "td3" / "seeds-0-1" / "metrics.jsonl.gz").exists()
    before = folder_digest(dest)
    _merge([old], dest, runs_of)
    assert folder_digest(dest) == before
    relabeled = grown.replace('label = "SAC+SF²"', 'label = "SAC+SF2"')   # a changed method
    changed = _source(tmp_path, "changed", runs_of, text=relabeled)
    with pytest.raises(StudyError, match="differ in methods"):
        _merge([changed], dest, runs_of)
    assert folder_digest(dest) == before


def test_sources_adding_different_methods_are_refused_together(tmp_path, runs_of):
    """Two hosts each added a different method: no one study file holds both, so the merge refuses, naming
    both sources and writing nothing; into a folder of a study that holds both, each merges."""
    extra = '[[methods]]\nlabel = "{0}"\nname = "{1}"\nalgo = "sac"\nrepresentation = "{2}"\n'
    with_sac = STUDY + extra.format("SAC", "sac", "none")
    with_sac_sf2 = STUDY + extra.format("SAC+SF²", "sac-sf2", "sf2")
    dest = tmp_path / "results"
    _merge([_source(tmp_path, "old", runs_of, finished=["A/td3/seeds-0-1"])], dest, runs_of)
    one = _source(tmp_path, "one", runs_of, finished=["A/sac/seeds-0-1"], text=with_sac)
    two = _source(tmp_path, "two", runs_of, finished=["A/sac-sf2/seeds-0-1"], text=with_sac_sf2)
    before = folder_digest(dest)
    with pytest.raises(StudyError, match=f"{one}, {two} add different tasks or methods"):
        _merge([one, two], dest, runs_of)
    assert folder_digest(dest) == before
    both = tmp_path / "both"
    _source(tmp_path, "both", runs_of, text=with_sac + extra.format("SAC+SF²", "sac-sf2", "sf2"))
    outcome, _ = _merge([one, two], both, runs_of)
    assert sorted(outcome.merged) == ["A/sac-sf2/seeds-0-1", "A/sac/seeds-0-1"]


def test_compressed_runs_read_merge_and_resume_as_plain_ones(tmp_path, runs_of):
    """A study folder in results/ keeps finished runs' metrics gzip-compressed (`study merge`, `study
    compress`): the run states, the rows, a merge of the same runs in plain form (a host that trained them
    from a plain copy) and a trainer appending to a compressed run all see what the plain files hold."""
    src = _source(tmp_path, "gpu", runs_of, finished=["A/td3/seeds-0-1", "B/td3/seeds-2-3"],
                  partial=["A/td3-sf2/seeds-0-1"], commands=["2026-01-01 10:00:00"])
    folder = StudyFolder(src)
    study = folder.load_study()
    runs = runs_of(study)
    states = {r.rel + r.task: folder.run_state(r, study) for r in runs}
    rows = {r.rel + r.task: RunFolder(folder.path_of(r)).read_rows(strict=True) for r in runs}
    plain = src.with_name("plain")
    import shutil

    shutil.copytree(src, plain)
    # `study compress`: finished runs only (the partial one's trainer appends to it)
    assert sorted(folder.compress_runs(runs, study)) == ["A/td3/seeds-0-1", "B/td3/seeds-2-3"]
    assert not (src / "runs/A/td3/seeds-0-1/metrics.jsonl").exists()
    assert (src / "runs/A/td3-sf2/seeds-0-1/metrics.jsonl").exists()
    assert folder.compress_runs(runs, study) == []   # nothing left to do
    assert {r.rel + r.task: folder.run_state(r, study) for r in runs} == states
    assert {r.rel + r.task: RunFolder(folder.path_of(r)).read_rows(strict=True) for r in runs} == rows
    # the same runs, one side compressed and the other plain, are identical to a merge
    dest = tmp_path / "results"
    _merge([plain], dest, runs_of)
    before = folder_digest(dest)
    out, said = _merge([src], dest, runs_of)
    assert sorted(out.skipped) == ["A/td3-sf2/seeds-0-1", "A/td3/seeds-0-1", "B/td3/seeds-2-3"]
    assert "A/td3/seeds-0-1: identical to DEST's" in said and folder_digest(dest) == before
    # appending to a compressed run continues its rows in a plain file (the .gz goes)
    run = RunFolder(src / "runs/A/td3/seeds-0-1")
    run.append_rows([{"epoch": 3, "seed": 0, "eval_return": 9.0}])
    assert not (run.path / "metrics.jsonl.gz").exists()
    assert run.read_rows() == rows["td3/seeds-0-1A"] + [{"epoch": 3, "seed": 0, "eval_return": 9.0}]
    # damaged compressed data: the run's rows cannot be read, and the error names the file
    bad = RunFolder(src / "runs/B/td3/seeds-2-3")
    data = (bad.path / "metrics.jsonl.gz").read_bytes()
    (bad.path / "metrics.jsonl.gz").write_bytes(data[: len(data) // 2])
    with pytest.raises(Exception, match=r"metrics.jsonl.gz is damaged gzip data"):
        bad.read_rows(strict=True)
    # ... and a merge from or into it is refused naming the file and the remedy; nothing is written
    before = folder_digest(dest)
    with pytest.raises(StudyError, match=r"gpu: .*seeds-2-3/metrics.jsonl.gz is damaged gzip data.*nothing "
                                         r"was merged: restore the file, or merge without this source"):
        _merge([src], dest, runs_of)
    assert folder_digest(dest) == before
    damaged = folder_digest(src)
    # `study compress` checks every run before it compresses any (A/td3, appended to above, is plain again)
    assert (src / "runs/A/td3/seeds-0-1/metrics.jsonl").exists()
    with pytest.raises(RunFolderError, match=r"seeds-2-3/metrics.jsonl.gz is damaged gzip data"):
        folder.compress_runs(runs, study)
    assert folder_digest(src) == damaged
    with pytest.raises(StudyError, match=r"DEST: .*metrics.jsonl.gz is damaged gzip data.*move the run "
                                         r"folder .*seeds-2-3 out of DEST"):
        _merge([plain], src, runs_of)
    assert folder_digest(src) == damaged


def test_evaluated_runs_stay_done_when_their_obs_noise_is_compressed(tmp_path, runs_of):
    """With an [evaluation], a run is done once obs_noise.json holds the study's settings; compressed (by
    `study compress` here, by the merge in DEST) it stays done, and DEST keeps it compressed."""
    from sf2_studies.folder import evaluation_settings

    src = _source(tmp_path, "gpu", runs_of, finished=["A/td3/seeds-0-1"],
                  text=STUDY + "[evaluation]\nobs_noise = [0.0, 0.1]\n")
    folder = StudyFolder(src)
    study = folder.load_study()
    runs = runs_of(study)
    run = next(r for r in runs if f"{r.task}/{r.rel}" == "A/td3/seeds-0-1")
    assert folder.run_state(run, study).status == "trained"   # trained, not evaluated yet
    noise = {"settings": evaluation_settings(study), "results": [{"noise": 0.1, "epoch": 2, "returns": {}}]}
    (folder.path_of(run) / "obs_noise.json").write_text(json.dumps(noise))
    assert folder.run_state(run, study).status == "done"
    dest = tmp_path / "results"
    out, _ = _merge([src], dest, runs_of)
    assert out.merged == ["A/td3/seeds-0-1"]
    kept = dest / "runs/A/td3/seeds-0-1"
    assert json.loads(gzip.decompress((kept / "obs_noise.json.gz").read_bytes())) == noise
    assert not (kept / "obs_noise.json").exists()
    assert folder.compress_runs(runs, study) == ["A/td3/seeds-0-1"]
    assert folder.run_state(run, study).status == "done"
    assert StudyFolder(dest).run_state(run, study).status == "done"
    out, said = _merge([src], dest, runs_of)   # compressed on both sides: identical
    assert out.skipped == ["A/td3/seeds-0-1"] and "identical to DEST's" in said


def test_keep_reruns_puts_a_differing_finished_run_beside_dest_and_merges_the_rest(tmp_path, runs_of):
    """`--keep-reruns`: the same config and seeds trained twice (on GPUs they differ from epoch 1) come back
    twice; DEST keeps its run, the other goes to rerun/<task>-<method>/<seeds>/ with only the kept files, and
    the source's other runs merge. Again: identical reruns are skipped; a third draw gets '.2'."""
    ours = _source(tmp_path, "ours", runs_of, finished=["A/td3/seeds-0-1"], commands=["2026-01-01 10:00:00"])
    theirs = _source(tmp_path, "theirs", runs_of, finished=["A/td3/seeds-0-1", "B/td3/seeds-0-1"],
                     commands=["2026-01-02 10:00:00"], ret=0.5)
    dest = tmp_path / "results"
    _merge([ours], dest, runs_of)
    kept = folder_digest(dest / "runs/A/td3/seeds-0-1")
    out, said = _merge([theirs], dest, runs_of, reruns=True)
    assert out.merged == ["B/td3/seeds-0-1"] and out.reruns == ["rerun/A-td3/seeds-0-1"]
    assert "kept as rerun/A-td3/seeds-0-1, out of the report" in said
    assert "epoch 0 seed 0: eval_return 0.0 vs 0.5" in said
    assert folder_digest(dest / "runs/A/td3/seeds-0-1") == kept          # DEST's run untouched
    rerun = dest / "rerun/A-td3/seeds-0-1"
    assert sorted(p.name for p in rerun.iterdir()) == ["config.json", "metrics.jsonl.gz", "train.log"]
    assert (gzip.decompress((rerun / "metrics.jsonl.gz").read_bytes())
            == (theirs / "runs/A/td3/seeds-0-1/metrics.jsonl").read_bytes())
    # the run folders the report reads (`StudyFolder.method_runs`) are DEST's runs/, never the rerun
    folder = StudyFolder(dest)
    paths = folder.method_runs(folder.load_study())
    read = [p for groups in paths.values() for p in groups.values()]
    assert dest / "runs/A/td3/seeds-0-1" in read and not any(StudyFolder.RERUN in p.parts for p in read)
    before = folder_digest(dest)
    out, said = _merge([theirs], dest, runs_of, reruns=True)
    assert not out.reruns and "identical to a rerun DEST keeps" in said and folder_digest(dest) == before
    third = _source(tmp_path, "third", runs_of, finished=["A/td3/seeds-0-1"], ret=0.25)
    out, _ = _merge([third], dest, runs_of, reruns=True)
    assert out.reruns == ["rerun/A-td3/seeds-0-1.2"]
    # without the flag the same source is still refused, naming the flag
    fourth = _source(tmp_path, "fourth", runs_of, finished=["A/td3/seeds-0-1"], ret=0.75)
    with pytest.raises(StudyError, match="--keep-reruns"):
        _merge([fourth], dest, runs_of)


def test_rows_difference_names_a_learned_value_before_timing():
    """merge.rows_difference (the merge's refusal, scripts/gpu-host/gpu_determinism.sh's verdicts): None for
    equal rows in any order; a learned value of a later row before a timing field of an earlier one; timing
    only said as such; a row only one side has."""
    from sf2_studies.merge import rows_difference

    a = [{"epoch": 0, "seed": 0, "eval_return": 1.0, "walltime": 1.0},
         {"epoch": 1, "seed": 0, "eval_return": 2.0, "walltime": 2.0}]
    assert rows_difference(a, list(reversed(a))) is None
    timed = [dict(r, walltime=r["walltime"] + 5) for r in a]
    assert rows_difference(a, timed) == "equal learned values, only timing differs; first epoch 0 seed 0: " \
        "walltime 1.0 vs 6.0"
    learned = [timed[0], dict(timed[1], eval_return=3.0)]
    assert rows_difference(a, learned) == "epoch 1 seed 0: eval_return 2.0 vs 3.0"
    assert rows_difference(a, a[:1]) == "epoch 1 seed 0: a row in one only"
    # the same as tuples (merge.first_difference: the report's "Reruns" column)
    from sf2_studies.merge import first_difference

    assert first_difference(a, learned) == (1, 0, "eval_return", 2.0, 3.0)
    assert first_difference(a, timed) is None and first_difference(a, timed, learned=False) == (
        0, 0, "walltime", 1.0, 6.0)
    assert first_difference(a, a[:1]) == (1, 0, None, None, None)


def test_study_file_takes_the_runs_another_study_shares_and_nothing_else(tmp_path, runs_of):
    """`--study`: a new study (the baselines of "merging" and a method of its own) takes "merging"'s runs
    of the methods both have, at the same paths with the same configs; a run at a shared path whose config
    differs, the other study's own methods and its commands stay out, and DEST records the merge command.
    A later file that adds a claim replaces DEST's copy and nothing else."""
    own = ('[[methods]]\nlabel = "TD3+SF², own Adam"\nname = "td3-sf2-own"\nalgo = "td3"\n'
           'representation = "sf2"\n')
    mine = STUDY.replace('"merging"', '"reuse"').replace(
        '[[methods]]\nlabel = "TD3+SF²"\nalgo = "td3"\nrepresentation = "sf2"\n', "") + own
    (tmp_path / "reuse.toml").write_text(mine)
    src = _source(tmp_path, "other", runs_of, commands=["2026-01-01 10:00:00"],
                  finished=["A/td3/seeds-0-1", "B/td3/seeds-2-3", "A/td3-sf2/seeds-0-1"])
    conf = src / "runs/B/td3/seeds-2-3/config.json"   # same path, another config: not this study's run
    conf.write_text(conf.read_text().replace('"num_envs": 4', '"num_envs": 8'))
    dest = tmp_path / "results"
    before = folder_digest(src)
    out, said = _merge([src], dest, runs_of, study_file=tmp_path / "reuse.toml",
                       command="sf2-jax study merge X")
    assert out.created and out.merged == ["A/td3/seeds-0-1"]
    assert "B/td3/seeds-2-3 in " in said and "num_envs: 8 (folder) vs 4 (now)" in said
    assert "ignored   1 run folder(s)" in said        # td3-sf2: no run of "reuse" has its path
    assert (dest / "study.toml").read_text() == mine and folder_digest(src) == before
    state = json.loads((dest / "study.json").read_text())
    assert state["name"] == "reuse" and [c["command"] for c in state["commands"]] == ["sf2-jax study merge X"]
    assert [(r["task"], r["folder"]) for r in state["runs"]] == [("A", "td3/seeds-0-1")]
    assert (gzip.decompress((dest / "runs/A/td3/seeds-0-1/metrics.jsonl.gz").read_bytes())
            == (src / "runs/A/td3/seeds-0-1/metrics.jsonl").read_bytes())
    # the copy counts as done for `study run`: the folder's state of that run
    study = StudyFolder(dest).load_study()
    run = next(r for r in runs_of(study) if f"{r.task}/{r.rel}" == "A/td3/seeds-0-1")
    assert StudyFolder(dest).run_state(run, study).status == "done"
    # again: nothing changes, not even the record of commands
    held = folder_digest(dest)
    out, said = _merge([src], dest, runs_of, study_file=tmp_path / "reuse.toml", command="again")
    assert not out.merged and "identical to DEST's" in said and folder_digest(dest) == held
    # a study file that only adds a claim: DEST's copy follows it, its runs and commands stay as they were
    claimed = mine + '[[claims]]\ntext = "t"\nmethod = "td3-sf2-own"\nabove = ["td3"]\n'
    (tmp_path / "reuse.toml").write_text(claimed)
    out, said = _merge([src], dest, runs_of, study_file=tmp_path / "reuse.toml", command="claims")
    assert not out.merged and "changes what no run depends on (description, report, claims)" in said
    assert (dest / "study.toml").read_text() == claimed
    assert json.loads((dest / "study.json").read_text())["commands"] == state["commands"]
    held = folder_digest(dest)
    # a DEST of another study is refused, nothing written
    (tmp_path / "merging.toml").write_text(STUDY)
    with pytest.raises(StudyError, match="holds study 'reuse', not the study of .*merging.toml"):
        _merge([src], dest, runs_of, study_file=tmp_path / "merging.toml")
    assert folder_digest(dest) == held


def test_study_file_may_rewrite_a_method_whose_runs_dest_holds_as_they_are(tmp_path, monkeypatch):
    """After a preset value changed, a study file pins a method to the value its runs trained with (and
    relabels it): `--study` takes the file into DEST, whose runs of it are runs of the rewritten method
    (`StudyFolder.refit`), and `study run`'s check passes. Pinned to another value, both refuse, DEST
    unchanged."""
    monkeypatch.setattr(task_table, "validate_task", lambda task: task)

    def make(preset, task, algo, rep, overrides):
        cfg = _make(preset, task, algo, rep, overrides)
        return cfg.replace(**{k: float(v) for k, v in overrides.items()})

    runs_of = lambda study: spec.resolve(study, make, lambda cfg, seeds: cfg)  # noqa: E731
    src = _source(tmp_path, "gpu", runs_of, finished=["A/td3/seeds-0-1"])
    dest = tmp_path / "results"
    _merge([src], dest, runs_of)
    tau = TrainConfig.tau

    def pinned(value):
        path = tmp_path / f"pinned-{value}.toml"
        path.write_text(STUDY.replace('label = "TD3"\n', f'label = "TD3, τ {value}"\nname = "td3"\n'
                                      f'overrides = {{ tau = {value} }}\n'))
        return path

    with pytest.raises(StudyError, match="differ in methods"):
        _merge([src], dest, runs_of, study_file=pinned(2 * tau))
    before = folder_digest(dest)
    with pytest.raises(StudyError, match="was made from another study file"):
        StudyFolder(dest).check(spec.load(pinned(2 * tau)), "jax", runs_of(spec.load(pinned(2 * tau))))
    assert folder_digest(dest) == before
    out, said = _merge([src], dest, runs_of, study_file=pinned(tau), command="merge --study")
    assert "identical to DEST's" in said and not out.merged
    assert "rewrites a method whose runs DEST holds" in said
    assert (dest / "study.toml").read_text() == pinned(tau).read_text()
    study = spec.load(pinned(tau))
    StudyFolder(dest).check(study, "jax", runs_of(study))
    run = next(r for r in runs_of(study) if f"{r.task}/{r.rel}" == "A/td3/seeds-0-1")
    assert StudyFolder(dest).run_state(run, study).status == "done"


# ------------------------------------------------------------------------------------------- borrowing
def _borrow(dest, lend, runs_of, **kw):
    from sf2_studies.borrow import borrow

    lines = []
    out = borrow(dest, lend, runs_of, framework="jax", say=lines.append, **kw)
    return out, "\n".join(lines)


def _lender_and_copy(tmp_path, runs_of, finished):
    """Two sibling study folders: "lend" (study "merging" as `study run` left it: plain metrics,
    checkpoints) and "reuse" (study "reuse", the same runs) holding merged copies of `finished`."""
    lend = tmp_path / "results" / "lend"
    _source(tmp_path / "results", "lend", runs_of, finished=finished)
    (tmp_path / "reuse.toml").write_text(STUDY.replace('"merging"', '"reuse"'))
    dest = tmp_path / "results" / "reuse"
    _merge([lend], dest, runs_of, study_file=tmp_path / "reuse.toml", command="sf2-jax study merge lend")
    return lend, dest


def test_borrow_reads_identical_runs_in_the_other_folder_and_removes_only_identical_copies(tmp_path, runs_of):
    """`study borrow`: a run DIR holds identically (gzip or not) is read in OTHER and DIR's copy removed
    (with the folders it leaves empty), one DIR lacks is taken, one whose file differs stays DIR's; the
    report reads the same returns; OTHER is never written; --dry-run and a second borrow change nothing."""
    from sf2_studies import report

    lend, dest = _lender_and_copy(tmp_path, runs_of,
                                  ["A/td3/seeds-0-1", "B/td3/seeds-2-3", "A/td3-sf2/seeds-0-1"])
    folder, study = StudyFolder(dest), StudyFolder(dest).load_study()
    returns = {(d.task, d.method.name): d.returns for d in report.collect(study, folder)}
    shutil.rmtree(dest / "runs/B/td3/seeds-2-3")                       # DEST lacks it
    log = dest / "runs/A/td3-sf2/seeds-0-1/train.log"                   # DEST's differs
    log.write_text(log.read_text() + "resumed\n")
    lent, held = folder_digest(lend), folder_digest(dest)
    copy = sum(p.stat().st_size for p in (dest / "runs/A/td3").rglob("*") if p.is_file())
    out, said = _borrow(dest, lend, runs_of, dry_run=True)
    assert "would borrow A/td3/seeds-0-1" in said and folder_digest(dest) == held
    out, said = _borrow(dest, lend, runs_of)
    assert out.removed == ["A/td3/seeds-0-1"] and out.taken == ["B/td3/seeds-2-3"]
    assert out.kept == ["A/td3-sf2/seeds-0-1"] and "train.log differs from OTHER's" in said
    assert out.freed == copy > 0
    assert not (dest / "runs/A/td3").exists() and (dest / "runs/A/td3-sf2/seeds-0-1").is_dir()
    state = json.loads((dest / "study.json").read_text())
    entries = {(r["task"], r["folder"]): r.get("from") for r in state["runs"]}
    assert entries[("A", "td3/seeds-0-1")] == entries[("B", "td3/seeds-2-3")] == "../lend"
    assert sum(v is not None for v in entries.values()) == 2 and folder_digest(lend) == lent
    after = report.collect(study, folder)
    assert {(d.task, d.method.name) for d in after} == returns.keys()
    for d in after:
        assert {s: list(r) for s, r in d.returns.items()} == {
            s: list(r) for s, r in returns[(d.task, d.method.name)].items()}
    held = folder_digest(dest)
    out, said = _borrow(dest, lend, runs_of)
    assert not (out.removed or out.taken) and folder_digest(dest) == held


def test_a_borrowed_run_is_read_where_it_lies_and_never_written(tmp_path, runs_of):
    """A borrowed run is done for `study run` and kept by its rewrite of study.json; `compress` and a merge
    never write it (an identical source's run is skipped, a different one refused); a source's borrowings are
    its own; a missing OTHER, or a borrowed run that is not finished there, stops the command by name."""
    from sf2_studies import report, reruns, runner

    lend, dest = _lender_and_copy(tmp_path, runs_of, ["A/td3/seeds-0-1"])
    _borrow(dest, lend, runs_of)
    folder, study = StudyFolder(dest), StudyFolder(dest).load_study()
    runs = runs_of(study)
    todo, done = runner.plan(study, folder, runs)
    assert [j.path for j in done] == [lend / "runs/A/td3/seeds-0-1"] and len(todo) == 7
    assert folder.groups_on_disk(study) == {(0, 1)}
    folder.open(study, "jax", runs, "sf2-jax study run reuse.toml")
    assert json.loads((dest / "study.json").read_text())["runs"][0]["from"] == "../lend"
    assert reruns.collect(folder, report.collect(study, folder)) == ([], [])
    lent = folder_digest(lend)
    assert folder.compress_runs(runs, study) == [] and folder_digest(lend) == lent   # plain metrics stay
    out, said = _merge([lend], dest, runs_of, study_file=tmp_path / "reuse.toml", command="again")
    assert out.skipped == ["A/td3/seeds-0-1"] and "identical to DEST's" in said
    assert folder_digest(lend) == lent
    other = _source(tmp_path, "other", runs_of, finished=["A/td3/seeds-0-1"], ret=5.0)
    with pytest.raises(StudyError, match="both hold it finished with different metrics"):
        _merge([other], dest, runs_of, study_file=tmp_path / "reuse.toml", command="other")
    out, _ = _merge([dest], tmp_path / "copy", runs_of)          # DEST as a source: its own runs only
    assert out.merged == [] and all("from" not in r for r in
                                    json.loads((tmp_path / "copy/study.json").read_text())["runs"])
    copy = tmp_path / "host" / "tmp" / "study-reuse"            # gpu_study.sh's copy, named from its place
    shutil.copytree(dest, copy)
    with pytest.raises(StudyError, match="which is not there"):
        StudyFolder(copy).borrowed()
    assert StudyFolder(copy).rebase(dest) == 1
    assert json.loads((copy / "study.json").read_text())["runs"][0]["from"] == "../../../results/lend"
    assert StudyFolder(copy).borrowed() == {("A", "td3/seeds-0-1"): lend / "runs/A/td3/seeds-0-1"}
    metrics = lend / "runs/A/td3/seeds-0-1/metrics.jsonl"       # unfinished there: never trained here
    full = metrics.read_text()
    metrics.write_text("".join(full.splitlines(keepends=True)[:4]))
    with pytest.raises(StudyError, match="never trains another's run"):
        runner.plan(study, folder, runs)
    metrics.write_text(full)
    lend.rename(tmp_path / "moved")
    for call in (lambda: runner.plan(study, folder, runs), lambda: report.collect(study, folder)):
        with pytest.raises(StudyError, match=r"lives in the study folder '\.\./lend'.*which is not there"):
            call()
