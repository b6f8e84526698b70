"""Regenerate the printed output that README.md shows for its main command (the Quick start).

Runs the README's quick-start training command (the part after the install) in a new temporary working
folder, and writes what it printed to stdout, with the wall time and the
commit, between the README's markers `<!-- quickstart-output -->` and `<!-- /quickstart-output -->`.
`--check` compares instead and exits 1 when the README shows something else.

    python3 scripts/readme_outputs.py [--check]
"""

from __future__ import annotations

import argparse
import re
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
BEGIN, END = "<!-- quickstart-output -->", "<!-- /quickstart-output -->"


def quickstart_command(readme: str) -> list[str]:
    """The README's main command without its install part: the `python3 -m sf2_jax.cli train ...` after `&&`.

    Args:
      readme: the README's text.

    Returns:
      The command's argv.
    """
    line = next(ln for ln in readme.splitlines() if "sf2_jax.cli train" in ln and "&&" in ln)
    return shlex.split(line.split("&&", 1)[1])


def run(argv: list[str]) -> tuple[str, float]:
    """Run the command in a new temporary working folder (its `--out` lands there); stdout and seconds."""
    argv = [sys.executable if argv[0] in ("python", "python3") else argv[0], *argv[1:]]
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        done = subprocess.run(argv, cwd=tmp, capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(f"the quick start failed (exit {done.returncode}):\n{done.stderr[-3000:]}")
        return done.stdout, time.perf_counter() - start


def block(stdout: str, seconds: float) -> str:
    """The README's text between the markers."""
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    return (f"{BEGIN}\nIt prints (commit {commit}, {seconds:.0f} s of training and compiling on a 2-core "
            f"CPU):\n```\n{stdout.rstrip()}\n```\n{END}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="compare, do not write; exit 1 on a difference")
    args = parser.parse_args(argv)
    text = README.read_text(encoding="utf-8")
    found = re.search(re.escape(BEGIN) + r".*?" + re.escape(END), text, re.S)
    if found is None:
        raise SystemExit(f"{README} has no {BEGIN} ... {END} block")
    stdout, seconds = run(quickstart_command(text))
    shown = re.search(r"```\n(.*?)```", found.group(0), re.S)
    if args.check:
        same = shown is not None and shown.group(1).rstrip() == stdout.rstrip()
        print("README output: " + ("as printed" if same else f"differs; it prints:\n{stdout}"))
        return 0 if same else 1
    README.write_text(text[:found.start()] + block(stdout, seconds) + text[found.end():], encoding="utf-8")
    print(stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
