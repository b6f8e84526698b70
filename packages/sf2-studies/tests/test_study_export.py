"""`study export` (sf2_studies.export) on a small study folder made of real run folders (results/own-adam's
TD3 runs and an unfinished one of results/fig7-sac): rliable's functions fed from the table give the
report's numbers; CSV and Parquet round trips; bad input exits 2 and writes nothing. No framework."""

from __future__ import annotations

import gzip
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rliable", reason="sf2-studies' dependencies: pip install packages/sf2-studies")
pytest.importorskip("matplotlib", reason="sf2-studies' dependencies: pip install packages/sf2-studies")

import pandas as pd  # noqa: E402
from rliable import library, metrics  # noqa: E402
from sf2_common.cli import new_parser, run  # noqa: E402
from sf2_common.errors import ConfigError  # noqa: E402
from sf2_studies import commands, export, runner, stats  # noqa: E402
from sf2_studies.folder import StudyFolder  # noqa: E402
from sf2_studies.report import aggregate_table, report  # noqa: E402
from sf2_studies.spec import StudyError, loads  # noqa: E402

RESULTS = Path(__file__).resolve().parents[3] / "results"
TASKS = ("AcrobotSwingup", "CheetahRun")
TD3 = {"td3-none": "TD3", "td3-sf2": "TD3+SF² (shared Adam)", "td3-sf2-own-adam": "TD3+SF², own Adam"}
STUDY = f"""
name = "export-check"
seeds = "0-14"
seeds_per_run = ["0-4", "5-14"]
tasks = {json.dumps(list(TASKS))}
[[methods]]
label = "{TD3['td3-none']}"
name = "td3-none"
algo = "td3"
representation = "none"
[[methods]]
label = "{TD3['td3-sf2']}"
name = "td3-sf2"
algo = "td3"
representation = "sf2"
overrides = {{ gamma_su = 0.99 }}
[[methods]]
label = "{TD3['td3-sf2-own-adam']}"
name = "td3-sf2-own-adam"
algo = "td3"
representation = "sf2"
overrides = {{ gamma_su = 0.99, shared_adam = false }}
[[methods]]
label = "SAC"
name = "sac-none"
algo = "sac"
representation = "none"
"""
PARTIAL_EPOCH = 20   # the SAC run on CheetahRun stops here (of 99): unfinished


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    """The study folder: the TD3 methods' run folders of results/own-adam on two tasks, both seed groups
    (finished; read where own-adam reads them, some in fig7-td3: `study borrow`); SAC's seeds 0-4 on
    CheetahRun from results/fig7-sac cut after epoch 20 (unfinished); SAC on AcrobotSwingup and SAC's
    seeds 5-14 not started. Then `study report` on it."""
    root = tmp_path_factory.mktemp("export")
    folder = StudyFolder(root / "study")
    folder.open(loads(STUDY, root / "s.toml"), "jax", [], command="sf2-jax study run s.toml --out study")
    own = StudyFolder(RESULTS / "own-adam")
    for task in TASKS:
        for name in TD3:
            for group in ("seeds-0-4", "seeds-5-14"):
                src = own.borrowed().get((task, f"{name}/{group}")) or own.run_path(task, f"{name}/{group}")
                dst = folder.run_path(task, f"{name}/{group}")
                dst.mkdir(parents=True)
                for f in ("config.json", "metrics.jsonl.gz"):
                    shutil.copy(src / f, dst / f)
    src = RESULTS / "fig7-sac" / "runs" / "CheetahRun" / "sac-none" / "seeds-0-4"
    dst = folder.run_path("CheetahRun", "sac-none/seeds-0-4")
    dst.mkdir(parents=True)
    shutil.copy(src / "config.json", dst / "config.json")
    lines = gzip.decompress((src / "metrics.jsonl.gz").read_bytes()).decode().splitlines(keepends=True)
    (dst / "metrics.jsonl").write_text("".join(x for x in lines if json.loads(x)["epoch"] <= PARTIAL_EPOCH))
    report(folder.path, command="sf2-jax study report study")
    return folder.path


def _auc(steps, returns):
    """The paper's AUC (§4.2), written here from the definition: the trapezoidal area under the curve over
    the env steps it spans."""
    return np.trapezoid(returns, steps) / (steps[-1] - steps[0])


def test_rliable_from_the_export_gives_the_reports_numbers(study_dir, tmp_path):
    """AUC per seed → min–max per task over every finished run → rliable's IQM with its stratified bootstrap
    interval, all from the exported CSV, equal the report's results.csv and its TD3 aggregate."""
    out = tmp_path / "runs.csv"
    done = export.export(study_dir, out)
    table = pd.read_csv(out)
    assert list(table.columns[:len(export.COLUMNS)]) == list(export.COLUMNS)
    # a field that differs between the runs of a task: the own-Adam runs record shared_adam = false, the
    # others true, or nothing where they trained before the field existed (an empty cell)
    recorded = {}
    for path in study_dir.glob("runs/*/*/*/config.json"):
        conf = json.loads(path.read_text())
        recorded.update({(path.parts[-4], path.parts[-3], s): conf["config"].get("shared_adam")
                         for s in conf["seeds"]})
    cells = {k: g.shared_adam.iloc[0] for k, g in table.groupby(["task", "method_name", "seed"])}
    assert {k: None if pd.isna(v) else v for k, v in cells.items()} == recorded
    assert {None, True, False} <= set(recorded.values())
    # 12 finished run folders of 5 or 10 seeds × 100 evaluations, and SAC's 5 seeds × 21 evaluations
    assert len(table) == done.rows == 2 * 3 * 15 * 100 + 5 * (PARTIAL_EPOCH + 1)
    assert (done.runs, done.unfinished) == (13, 1)
    sac = table[table.method_name == "sac-none"]
    assert not sac.finished.any() and set(sac.task) == {"CheetahRun"} and sac.env_step.max() > 0
    assert table[table.method_name != "sac-none"].finished.all()
    assert set(table.study) == {"export-check"} and table.commit.isna().all()   # tmp_path: no git repository
    assert set(table.framework) == {"jax"} and set(table.algo) == {"td3", "sac"}

    finished = table[table.finished]
    auc = {key: _auc(g.env_step.to_numpy(float), g["return"].to_numpy())
           for key, g in finished.sort_values("env_step").groupby(["task", "method", "seed"])}
    lo = {t: min(v for k, v in auc.items() if k[0] == t) for t in TASKS}
    hi = {t: max(v for k, v in auc.items() if k[0] == t) for t in TASKS}
    norm = {k: (v - lo[k[0]]) / (hi[k[0]] - lo[k[0]]) for k, v in auc.items()}
    reported = pd.read_csv(study_dir / "report" / "results.csv")
    assert len(reported) == len(norm) == 2 * 3 * 15
    for r in reported.itertuples():
        np.testing.assert_allclose(auc[(r.task, r.method, r.seed)], r.auc, rtol=1e-14)
        np.testing.assert_allclose(norm[(r.task, r.method, r.seed)], r.normalized_auc, rtol=1e-14, atol=1e-15)

    study = StudyFolder(study_dir).load_study()
    table_td3 = aggregate_table(study, reported.to_dict("records"))[0]["TD3"]
    summary = (study_dir / "report" / "summary.md").read_text()
    for label, n, points, ci in table_td3:
        scores = np.array([[norm[(t, label, s)] for t in TASKS] for s in range(15)])
        np.random.seed(stats.SEED)
        point, interval = library.get_interval_estimates(
            {label: scores}, lambda x: np.array([metrics.aggregate_iqm(x)]), reps=stats.RESAMPLES)
        assert n == 15
        np.testing.assert_allclose(point[label][0], points[1], rtol=1e-12)
        np.testing.assert_allclose(interval[label][:, 0], ci[:, 1], rtol=1e-12)
        row = next(x for x in summary.splitlines() if x.startswith(f"| {label} | 15 × 2 |"))
        assert row.split(" | ")[3] == (f"{point[label][0]:.3f} [{interval[label][0, 0]:.3f}, "
                                       f"{interval[label][1, 0]:.3f}]"), row


def test_csv_and_parquet_round_trip(study_dir, tmp_path):
    """Read back, the CSV and the Parquet file hold the rows `export.rows` made, with the same columns and
    values (ints, floats to the last bit, booleans; in the CSV the empty commit and unrecorded fields read
    back as missing)."""
    columns, rows, _ = export.rows(study_dir)
    expected = pd.DataFrame(rows, columns=columns)
    # pandas' default float parser may be an ulp off; float_precision="round_trip" reads them exactly
    csv = pd.read_csv(export.export(study_dir, tmp_path / "t.csv").path, float_precision="round_trip")
    pd.testing.assert_frame_equal(csv.drop(columns=["commit", "shared_adam"]),
                                  expected.drop(columns=["commit", "shared_adam"]), check_exact=True)
    assert csv["return"].to_list() == expected["return"].to_list()
    assert csv.commit.isna().all() and (expected.commit == "").all()
    assert csv.shared_adam.isna().sum() == expected.shared_adam.isna().sum() > 0
    pytest.importorskip("pyarrow", reason="Parquet: pip install pyarrow")
    parquet = pd.read_parquet(export.export(study_dir, tmp_path / "t.parquet").path)
    pd.testing.assert_frame_equal(parquet, expected, check_exact=True)


def test_commit_is_the_head_of_the_repository_holding_the_folder(study_dir, tmp_path):
    """In a git repository (committed or not) each row names its HEAD; the command line says which."""
    repo = tmp_path / "repo"
    shutil.copytree(study_dir, repo / "studies" / "s")
    git = ["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "commit", "-q", "--allow-empty", "-m", "x"], check=True)
    head = subprocess.run([*git, "rev-parse", "HEAD"], check=True, capture_output=True, text=True)
    head = head.stdout.strip()
    assert export.commit_of(repo / "studies" / "s") == head and export.commit_of(tmp_path / "none") == ""
    code, out, _ = _cli(["study", "export", str(repo / "studies" / "s"), "--out", str(tmp_path / "t.csv")])
    assert code == 0 and f"commit {head} (HEAD of the git repository holding" in out
    assert set(pd.read_csv(tmp_path / "t.csv").commit) == {head}


def _cli(argv):
    """`sf2-fake ARGV` through sf2_common.cli.run, as a core runs `study`: (exit status, stdout, stderr)."""
    import contextlib
    import io

    parser, sub = new_parser("sf2-fake", "a core")
    commands.add_parser(sub, "sf2-fake")
    sub.choices["study"].set_defaults(sf2_plugin=commands.COMMAND)
    backend = runner.Backend("sf2-fake", "jax", "fake", None, None)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = run("sf2-fake", parser, {}, lambda: backend, argv)
    return code, out.getvalue(), err.getvalue()


def _files(path: Path) -> set:
    return {p.relative_to(path) for p in path.rglob("*")}


@pytest.mark.parametrize("case", ["not a study folder", "no such folder", "unknown suffix", "no suffix",
                                  "a folder", "under a file", "no parquet engine"])
def test_bad_input_exits_2_naming_it_and_writes_nothing(study_dir, tmp_path, monkeypatch, case):
    (tmp_path / "a-file").write_text("x")
    (tmp_path / "a-folder.csv").mkdir()
    source, out, said = {
        "not a study folder": (tmp_path, tmp_path / "t.csv", f"{tmp_path} is not a study folder"),
        "no such folder": (tmp_path / "nothing", tmp_path / "t.csv", "nothing: no such folder"),
        "unknown suffix": (study_dir, tmp_path / "t.xlsx", "unknown suffix '.xlsx'"),
        "no suffix": (study_dir, tmp_path / "t", "unknown suffix '(none)'"),
        "a folder": (study_dir, tmp_path / "a-folder.csv", "a-folder.csv is a folder"),
        "under a file": (study_dir, tmp_path / "a-file" / "t.csv", "a-file is a file, not a folder"),
        "no parquet engine": (study_dir, tmp_path / "t.parquet", "needs the package pyarrow"),
    }[case]
    if case == "no parquet engine":   # as where pyarrow is not installed
        real = export.importlib.util.find_spec
        monkeypatch.setattr(export.importlib.util, "find_spec",
                            lambda name, *a: None if name == "pyarrow" else real(name, *a))
        with pytest.raises(ConfigError, match="pip install pyarrow"):
            export.export(study_dir, out)
    before, study_before = _files(tmp_path), _files(study_dir)
    code, stdout, stderr = _cli(["study", "export", str(source), "--out", str(out)])
    assert code == 2 and said in stderr and stdout == "", stderr
    assert _files(tmp_path) == before and _files(study_dir) == study_before


def test_a_failed_write_leaves_nothing(study_dir, tmp_path, monkeypatch):
    """A write that fails midway (a full disk, say) leaves neither the file nor its temporary sibling, and
    an existing file as it was."""
    out = tmp_path / "t.csv"
    out.write_text("old")

    def full(self, path, **kw):
        Path(path).write_text("half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pd.DataFrame, "to_csv", full)
    with pytest.raises(StudyError, match="No space left on device"):
        export.export(study_dir, out)
    assert _files(tmp_path) == {Path("t.csv")} and out.read_text() == "old"


def test_export_is_registered_as_a_study_command():
    parser, sub = new_parser("sf2-fake", "a core")
    commands.add_parser(sub, "sf2-fake")
    args = parser.parse_args(["study", "export", "d", "--out", "t.csv"])
    assert (args.study_command, args.dir, args.out) == ("export", "d", "t.csv")
