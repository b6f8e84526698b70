"""The GPU host's study script: refuses a bad limit, starts nothing on too little, archives before listing.

scripts/gpu-host/gpu_study.sh runs on the lent host; the first calls stop before it installs anything there,
so they run here as they would there; the last runs it whole with python3 and nvidia-smi stood in for.
"""
import pathlib
import subprocess

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _gpu_study(seconds: str, out: pathlib.Path) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "scripts/gpu-host/gpu_study.sh", "studies/smoke.toml", seconds],
                          cwd=ROOT, env={"PATH": "/usr/bin:/bin", "OUT": str(out)}, capture_output=True,
                          text=True, timeout=60)


def test_a_limit_that_is_not_a_number_is_refused(tmp_path):
    done = _gpu_study("abc", tmp_path)
    assert done.returncode == 2
    assert "SECONDS must be a whole number of seconds, not 'abc'" in done.stderr
    assert not list(tmp_path.iterdir())


def test_too_little_time_starts_nothing(tmp_path):
    for seconds in ("-12", "0", "59"):
        done = _gpu_study(seconds, tmp_path)
        assert done.returncode == 0, done.stderr
        assert f"{seconds} s left for smoke: under 60 s, not started" in done.stdout
        assert not list(tmp_path.iterdir())


FAKE_PYTHON = """#!/bin/bash
# the host's python3, stood in for: pip and the entry-point heredoc do nothing, a study run writes one
# finished run and one checkpoint, the listing after it records whether the archive is already there
case "$*" in
  *--dry-run*) if [ -f "$OUT/$NAME.tar.gz" ]; then echo present; else echo absent; fi > "$OUT/../listing";;
  *"study run"*)
    while [ "$1" != --out ]; do shift; done
    mkdir -p "$2/runs/t/m/seeds-0-4/checkpoints"
    echo '{"step": 1}' > "$2/runs/t/m/seeds-0-4/metrics.jsonl"
    echo weights > "$2/runs/t/m/seeds-0-4/checkpoints/1.npz";;
  *) cat > /dev/null;;
esac
"""


def test_the_archive_is_written_before_the_listing(tmp_path):
    """A lane stopped while the study's listing runs still brings back the runs that finished."""
    work, bin_, out = tmp_path / "work", tmp_path / "bin", tmp_path / "out"
    (work / "scripts" / "gpu-host").mkdir(parents=True)
    for script in ("gpu_study.sh", "gpu_env.sh"):
        source = ROOT / "scripts" / "gpu-host" / script
        (work / "scripts" / "gpu-host" / script).write_text(source.read_text())
    bin_.mkdir()
    (bin_ / "python3").write_text(FAKE_PYTHON)
    (bin_ / "nvidia-smi").write_text("#!/bin/bash\necho 'NVIDIA H200, 143771 MiB'\n")
    for fake in bin_.iterdir():
        fake.chmod(0o755)
    name = f"archive-first-{tmp_path.name}"
    try:
        done = subprocess.run(
            ["bash", "scripts/gpu-host/gpu_study.sh", "studies/smoke.toml", "120"], cwd=work,
            env={"PATH": f"{bin_}:/usr/bin:/bin", "OUT": str(out), "NAME": name,
                 "STUDY_RESULTS": f"results/{name}"}, capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
        assert (tmp_path / "listing").read_text().strip() == "present"
        members = subprocess.run(["tar", "tzf", str(out / f"{name}.tar.gz")], capture_output=True,
                                 text=True, check=True).stdout.split()
        assert "./runs/t/m/seeds-0-4/metrics.jsonl" in members
        assert not [m for m in members if "checkpoints" in m or m.endswith(".npz")]
    finally:
        subprocess.run(["rm", "-rf", f"/tmp/study-{name}"], check=True)
