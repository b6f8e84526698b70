"""The packages as a user outside this repository gets them: builds every package's sdist and wheel, checks
them, installs both cores (and sf2-baselines) from the wheel folder into a fresh virtual environment in a
temporary directory outside the checkout (`-c constraints.txt` keeps torch the CPU build), and runs the
README's API examples and `sf2-jax --help` / `sf2-torch --help` there. `tox -e wheels` runs it.

    python scripts/check_wheels.py [--keep]      # --keep: leave the temporary folder and print its path

It fails (exit status 1, every problem listed) when the packages' versions differ; a Requires-Dist holds a
direct reference or names a sibling at anything but `==` the repository's version; a wheel or sdist lacks
the root's LICENSE or does not say MIT; `twine check --strict` fails; an install or example fails; or a
module imports from outside the new environment. It prints each wheel's Requires-Dist lines and the time
of each phase."""

from __future__ import annotations

import argparse
import email
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
import zipfile
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = sorted(p for p in (ROOT / "packages").iterdir() if (p / "pyproject.toml").is_file())
# What the README's examples need (tests/test_readme.py runs the same blocks in the dev env)
INSTALL = ["sf2-core-jax", "sf2-core-torch", "sf2-baselines[jax,torch]"]
BLOCKS = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(encoding="utf-8"), re.S)
# tests/test_readme.py's check, and where each sf2 module came from
CHECK = """
import math, sys
assert math.isfinite(float(loss)) and sorted(aux) == ['loss_boot', 'loss_p'], aux
for name in ('sf2_common', 'sf2_jax', 'sf2_torch'):
    file = getattr(sys.modules.get(name), '__file__', None) or sys.prefix
    assert file.startswith(sys.prefix), (name, file, sys.prefix)
"""
PROBE = """
import importlib.metadata as md, sys
import sf2_common, sf2_jax, sf2_torch, sf2_baselines
for m in (sf2_common, sf2_jax, sf2_torch, sf2_baselines):
    assert m.__file__.startswith(sys.prefix), (m.__name__, m.__file__, sys.prefix)
    print(f"  {m.__name__} {m.__version__} from {m.__file__}")
assert not [p for p in sys.path if p and p.startswith(ROOT)], sys.path
for name in ('sf2-common', 'sf2-core-jax', 'sf2-core-torch', 'sf2-baselines'):
    assert md.version(name) == VERSION, (name, md.version(name))
    assert md.metadata(name)['License-Expression'] == 'MIT', name
"""
problems: list[str] = []


def fail(message: str) -> None:
    problems.append(message)
    print(f"FAIL {message}", flush=True)


def run(cmd: list[str], label: str = "", **kw) -> subprocess.CompletedProcess:
    done = subprocess.run(cmd, text=True, capture_output=True, **kw)
    if done.returncode:
        output = done.stdout[-3000:] + done.stderr[-3000:]
        fail(f"{label or ' '.join(map(str, cmd))} exited {done.returncode}:\n{output}")
    return done


def versions() -> dict[str, str]:
    """Each package's `__version__`, read from its source (no import)."""
    found = {}
    for pkg in PACKAGES:
        inits = list((pkg / "src").glob("*/__init__.py"))
        match = [m for i in inits for m in re.findall(r'^__version__ = "([^"]+)"$', i.read_text(), re.M)]
        found[pkg.name] = match[0] if len(match) == 1 else f"<{len(match)} __version__ lines>"
    return found


def check_metadata(path: Path, metadata: str, siblings: set[str], version: str) -> None:
    msg = email.message_from_string(metadata)
    name = canonicalize_name(msg["Name"])
    if msg["Version"] != version:
        fail(f"{path.name}: version {msg['Version']}, not the repository's {version}")
    if msg["License-Expression"] != "MIT":
        fail(f"{path.name}: License-Expression {msg['License-Expression']!r}, not MIT")
    for line in msg.get_all("Requires-Dist") or []:
        if path.suffix == ".whl":
            print(f"  Requires-Dist: {line}")
        req = Requirement(line)
        if req.url or "@" in line.split(";")[0] or "file://" in line:
            fail(f"{path.name}: direct reference in Requires-Dist: {line}")
        if canonicalize_name(req.name) in siblings and str(req.specifier) != f"=={version}":
            fail(f"{path.name}: sibling {req.name} at {req.specifier or 'any version'}, not =={version}")
    if name not in siblings:
        fail(f"{path.name}: unknown package {name}")


def check_dists(dist: Path, version: str) -> None:
    license_text = (ROOT / "LICENSE").read_bytes()
    siblings = {canonicalize_name(p.name) for p in PACKAGES}
    for pkg in PACKAGES:
        if (pkg / "LICENSE").read_bytes() != license_text:
            fail(f"{pkg.relative_to(ROOT)}/LICENSE differs from the root's LICENSE")
    for wheel in sorted(dist.glob("*.whl")):
        print(wheel.name)
        with zipfile.ZipFile(wheel) as z:
            names = z.namelist()
            meta = next(n for n in names if n.endswith(".dist-info/METADATA"))
            lic = meta.replace("METADATA", "licenses/LICENSE")
            if lic not in names or z.read(lic) != license_text:
                fail(f"{wheel.name}: no {lic} equal to the root's LICENSE")
            check_metadata(wheel, z.read(meta).decode(), siblings, version)
    for sdist in sorted(dist.glob("*.tar.gz")):
        with tarfile.open(sdist) as t:
            base = sdist.name[: -len(".tar.gz")]
            try:
                lic = t.extractfile(f"{base}/LICENSE").read()
            except KeyError:
                lic = None
            if lic != license_text:
                fail(f"{sdist.name}: no {base}/LICENSE equal to the root's LICENSE")
            check_metadata(sdist, t.extractfile(f"{base}/PKG-INFO").read().decode(), siblings, version)
    built = {canonicalize_name(w.name.split("-")[0]) for w in dist.glob("*.whl")}
    sdists = {canonicalize_name(s.name.rsplit("-", 1)[0]) for s in dist.glob("*.tar.gz")}
    for missing in sorted((siblings - built) | (siblings - sdists)):
        fail(f"{missing}: no wheel or no sdist built")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = parser.parse_args()
    start = time.perf_counter()

    found = versions()
    version = found.get("sf2-common", "?")
    print("versions:", ", ".join(f"{k} {v}" for k, v in found.items()))
    if len(set(found.values())) != 1:
        fail(f"the packages' __version__s differ: {found}")

    tmp = Path(tempfile.mkdtemp(prefix="sf2-wheels-")).resolve()
    if tmp.is_relative_to(ROOT):
        tmp = Path(tempfile.mkdtemp(prefix="sf2-wheels-", dir="/tmp")).resolve()
    assert not tmp.is_relative_to(ROOT), tmp
    dist, venv = tmp / "dist", tmp / "venv"
    try:
        t = time.perf_counter()
        for pkg in PACKAGES:  # sdist, then the wheel from the sdist (proves the sdist complete)
            run([sys.executable, "-m", "build", "--outdir", str(dist), str(pkg)])
        print(f"built {len(list(dist.glob('*')))} files in {time.perf_counter() - t:.0f} s", flush=True)
        run([sys.executable, "-m", "twine", "check", "--strict", *map(str, sorted(dist.glob("*")))])
        check_dists(dist, version)
        if problems:
            return report(start, tmp, args.keep)

        t = time.perf_counter()
        run([sys.executable, "-m", "venv", str(venv)])
        python = str(venv / "bin" / "python")
        env = {k: v for k, v in os.environ.items()
               if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV") and not k.startswith("JAX_ENABLE")}
        env |= {"JAX_PLATFORMS": "cpu", "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
        names = ",".join(canonicalize_name(p.name) for p in PACKAGES)
        done = run([python, "-m", "pip", "install", "-q", "--find-links", str(dist), "--only-binary", names,
                    "-c", str(ROOT / "constraints.txt"), *INSTALL], cwd=tmp, env=env)
        print(f"installed {' '.join(INSTALL)} from the wheels in {time.perf_counter() - t:.0f} s", flush=True)
        if done.returncode:
            return report(start, tmp, args.keep)

        t = time.perf_counter()
        probe = f"ROOT, VERSION = {str(ROOT)!r}, {version!r}\n" + PROBE
        done = run([python, "-c", probe], "the import probe", cwd=tmp, env=env)
        print(done.stdout, end="")
        for i, block in enumerate(BLOCKS):
            work = tmp / f"example-{i}"
            work.mkdir()
            done = run([python, "-c", block + CHECK], f"README example {i}", cwd=work, env=env, timeout=600)
            if not done.returncode and not (work / "params.npz").exists():
                fail(f"README example {i} wrote no params.npz")
            print(f"README example {i} ({block.splitlines()[0].split('#')[0].strip()}): "
                  f"{'ok' if not done.returncode else 'FAILED'}", flush=True)
        for script in ("sf2-jax", "sf2-torch"):  # the cores' commands, without [train]
            done = run([str(venv / "bin" / script), "--help"], f"{script} --help", cwd=tmp, env=env)
            print(f"{script} --help: {'ok' if not done.returncode else 'FAILED'}", flush=True)
        if len(BLOCKS) < 2:
            fail(f"README.md has {len(BLOCKS)} python blocks, expected one per core")
        print(f"examples in {time.perf_counter() - t:.0f} s")
        return report(start, tmp, args.keep)
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)


def report(start: float, tmp: Path, keep: bool) -> int:
    print(f"total {time.perf_counter() - start:.0f} s" + (f"; kept {tmp}" if keep else ""))
    if problems:
        print(f"{len(problems)} problem(s):\n" + "\n".join(f"- {p.splitlines()[0]}" for p in problems))
        return 1
    print("wheels OK")
    return 0


if __name__ == "__main__":
    sys.exit(main())
