"""The GPU host's scripts: the study script refuses a bad limit, starts nothing on too little, archives
before listing; the wheel slimmer drops only what it names and keeps every other byte.

scripts/gpu-host/gpu_study.sh runs on the lent host; the first calls stop before it installs anything there,
so they run here as they would there; the third runs it whole with python3 and nvidia-smi stood in for.
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


def test_slim_wheels_drops_what_training_never_loads_and_keeps_every_other_byte(tmp_path):
    """scripts/gpu-host/slim_wheels.py on two hand-made wheels: mujoco's drops its headers and experimental
    modules and keeps the rest byte for byte, LZMA-compressed; a tiny wheel, where LZMA's header costs more
    than it saves, stays as it was; a second pass changes neither."""
    import importlib.util
    import zipfile

    spec = importlib.util.spec_from_file_location("slim_wheels", ROOT / "scripts/gpu-host/slim_wheels.py")
    slim_wheels = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(slim_wheels)
    mujoco = "mujoco-3.17.0-cp312-cp312-manylinux_2_28_x86_64.whl"
    members = {"mujoco/__init__.py": b"from ._structs import *\n" * 50,
               "mujoco/libmujoco.so.3": bytes(range(256)) * 400,
               "mujoco/include/mujoco/mujoco.h": b"int mj_step(void);\n" * 100,
               "mujoco/experimental/studio.py": b"import filament\n" * 100,
               "mujoco-3.17.0.dist-info/RECORD": b"mujoco/__init__.py,,\n"}
    wheels = {mujoco: members, "brax-0.14.2-py3-none-any.whl": {"brax/__init__.py": b"version = '0.14.2'\n"}}
    for name, files in wheels.items():
        with zipfile.ZipFile(tmp_path / name, "w", zipfile.ZIP_DEFLATED) as z:
            for member, data in files.items():
                z.writestr(member, data)
    tiny = (tmp_path / "brax-0.14.2-py3-none-any.whl").read_bytes()
    before = (tmp_path / mujoco).stat().st_size
    assert slim_wheels.slim(tmp_path / "brax-0.14.2-py3-none-any.whl") == (0, 0)
    assert (tmp_path / "brax-0.14.2-py3-none-any.whl").read_bytes() == tiny
    dropped, saved = slim_wheels.slim(tmp_path / mujoco)
    assert dropped == 2 and saved == before - (tmp_path / mujoco).stat().st_size > 0
    with zipfile.ZipFile(tmp_path / mujoco) as z:
        kept = {i.filename: z.read(i.filename) for i in z.infolist()}
        methods = {i.compress_type for i in z.infolist()}
    dropped_prefixes = ("mujoco/include/", "mujoco/experimental/")
    assert kept == {m: d for m, d in members.items() if not m.startswith(dropped_prefixes)}
    assert methods == {zipfile.ZIP_LZMA}
    again = {name: (tmp_path / name).read_bytes() for name in wheels}
    assert all(slim_wheels.slim(tmp_path / name) == (0, 0) for name in wheels)
    assert again == {name: (tmp_path / name).read_bytes() for name in wheels}
