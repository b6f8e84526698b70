"""The GPU host's study script refuses a bad time limit and starts nothing when a lane leaves it too little.

scripts/gpu-host/gpu_study.sh runs on the lent host; these calls stop before it installs anything there, so
they run here as they would there.
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
