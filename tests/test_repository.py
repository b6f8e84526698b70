"""The repository cites only what exists: repository paths that resolve, and no issue numbers.

A reader cannot follow an issue number (the tracker is not part of the repository) nor a path to a file
that was moved or removed. Framework-free and fast: the tracked files are read once. History is cited as
`git show <commit>:<path>`, which is checked against the repository's objects where the commit is present.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CITING = (".md", ".py", ".toml", ".sh")          # the files whose path citations are checked
_TOP = r"(?:bench|results|docs|scripts|packages|studies|tests)/"
# a repository path: starts a token (not inside a URL, a longer path or `commit:path`)
PATH = re.compile(r"(?<![\w./~$:@-])(" + _TOP + r"[\w.\-/]*)([\s\S]?)")
GIT_SHOW = re.compile(r"\b([0-9a-f]{7,40}):(" + _TOP + r"[\w.\-/]*\w)")
WRAPPED = re.compile(r"[ \t#*>\"']*([\w.\-/]*)")   # the rest of a path on its next line
LINK = re.compile(r"\]\(([^)\s]+)\)")            # a markdown link's target
ISSUE = re.compile(r"\bissues?\s+#?\d+", re.IGNORECASE)
# Paths that documented commands create, not files of the repository.
CREATED = {"bench/results/<machine>"}


def _tracked() -> list[str]:
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z"], capture_output=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return []   # not a git checkout (an sdist): nothing to check
    return [p for p in out.stdout.decode().split("\0") if p]


def _text(path: str) -> str | None:
    try:
        data = (ROOT / path).read_bytes()
    except OSError:   # tracked but deleted in the working tree
        return None
    if b"\0" in data[:8192]:
        return None
    return data.decode("utf-8", errors="replace")


def _resolves(token: str, citing: str) -> bool:
    """Whether `token` names a file or folder: from the root, the citing file's folder or its package."""
    parts = Path(citing).parts
    bases = [ROOT, (ROOT / citing).parent]
    if parts[0] == "packages" and len(parts) > 2:
        bases.append(ROOT / "packages" / parts[1])
    return any((base / token).exists() for base in bases)


def _path_problems(path: str, text: str) -> list[str]:
    problems = []
    for m in PATH.finditer(text):
        token, after = m.group(1), m.group(2)
        if token.endswith("-") and after == "\n":   # a path broken at a hyphen across two lines
            rest = WRAPPED.match(text, m.end(2))
            token, after = token + rest.group(1), text[rest.end(1):rest.end(1) + 1]
        if after in ("*", "{", "<", "…", "["):    # a pattern or a placeholder: its folder must exist
            token = token.rsplit("/", 1)[0] if not token.endswith("/") else token
        token = token.rstrip(".-")
        if token in CREATED or f"{token}{after}" in CREATED or _resolves(token, path):
            continue
        problems.append(f"{path}: {token}")
    if path.endswith(".md"):
        for m in LINK.finditer(text):
            target = m.group(1).split("#")[0]
            if not target or "://" in target or target.startswith(("mailto:", "<")):
                continue
            if not (ROOT / path).parent.joinpath(target).exists():
                problems.append(f"{path}: link {m.group(1)}")
    return problems


def _missing_history(citations: set[tuple[str, str, str]]) -> list[str]:
    """The `git show <commit>:<path>` citations whose commit is present but whose path is not in it."""
    if not citations:
        return []
    order = sorted(citations)
    lines = "".join(f"{c}^{{commit}}\n{c}:{p}\n" for _, c, p in order)
    out = subprocess.run(["git", "-C", str(ROOT), "cat-file", "--batch-check"], input=lines.encode(),
                         capture_output=True, check=True).stdout.decode().splitlines()
    problems = []
    for (path, commit, cited), has_commit, has_path in zip(order, out[::2], out[1::2]):
        if not has_commit.endswith("missing") and has_path.endswith("missing"):
            problems.append(f"{path}: git show {commit}:{cited}")
    return problems


def test_cited_repository_paths_exist():
    """Every `bench/…`, `results/…`, `docs/…`, `scripts/…`, `packages/…`, `studies/…`, `tests/…` path and
    every relative markdown link in a tracked .md/.py/.toml/.sh file names a file or folder that exists;
    a `git show <commit>:<path>` citation names a path of that commit."""
    problems, history = [], set()
    for path in _tracked():
        if not path.endswith(CITING) or "/runs/" in path:
            continue
        text = _text(path)
        if text is None:
            continue
        problems += _path_problems(path, text)
        history |= {(path, c, p) for c, p in GIT_SHOW.findall(text)}
    problems += _missing_history(history)
    assert not problems, "cited paths that do not exist:\n" + "\n".join(problems)


def test_no_issue_numbers():
    """No tracked file but CHANGELOG.md cites an issue by its number; say what the issue was instead, or
    cite the upstream tracker by its URL."""
    found = []
    for path in _tracked():
        if Path(path).name == "CHANGELOG.md":
            continue
        text = _text(path)
        if text is None:
            continue
        for number, line in enumerate(text.splitlines(), 1):
            if ISSUE.search(line):
                found.append(f"{path}:{number}: {line.strip()[:120]}")
    assert not found, "issue numbers cited:\n" + "\n".join(found)


def test_the_checks_catch_what_they_should():
    """The scanners on hand-made text: a missing path and a broken link are named; globs, placeholders, a
    path wrapped at a hyphen, URLs and `git show` forms pass; issue numbers are found in their usual forms.
    (The text is assembled here so that this file itself cites nothing missing.)"""
    b, d, i = "bench", "docs", "issue"
    text = (f"see {b}/README.md. and {b}/no-such-module.py, results/fig7-td3/runs/*/x, results/<new>,\n"
            f"https://example.org/docs/x.md, {d}/core-\n    contract.md, git show 0d333e8:{b}/gone.py,\n"
            f"[ok]({b}/README.md) [broken](nowhere.md) [web](https://example.org)")
    assert _path_problems("README.md", text) == [f"README.md: {b}/no-such-module.py",
                                                 "README.md: link nowhere.md"]
    assert GIT_SHOW.findall(text) == [("0d333e8", f"{b}/gone.py")]
    assert all(ISSUE.search(x) for x in (f"{i} 12", f"{i.title()} #6", f"{i}s 3"))
    assert not ISSUE.search(f"{i}s/86")


MODULE_DOC_LINES = 15   # a module docstring says what the module is for; manuals and records live in docs/
DATE = re.compile(r"\b20\d\d-[01]\d-[0-3]\d\b")


def _docstrings(tree):
    """(name, line, text) of the module's, every class's and every function's docstring."""
    import ast

    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                yield getattr(node, "name", "module"), getattr(node, "lineno", 1), doc


def test_docstrings_are_short_and_hold_no_dates():
    """Every tracked Python module's docstring is at most 15 lines, and no docstring holds a date: what
    was measured when, and why something was decided, go to docs/decisions/ and the results' READMEs."""
    import ast

    problems = []
    for path in _tracked():
        text = _text(path) if path.endswith(".py") else None
        if text is None:
            continue
        tree = ast.parse(text)
        for name, line, doc in _docstrings(tree):
            if name == "module" and len(doc.strip().splitlines()) > MODULE_DOC_LINES:
                problems.append(f"{path}: module docstring of {len(doc.strip().splitlines())} lines")
            if date := DATE.search(doc):
                problems.append(f"{path}:{line}: {name}'s docstring holds a date ({date.group(0)})")
    assert not problems, "\n".join(problems)


if __name__ == "__main__":
    test_cited_repository_paths_exist()
    test_no_issue_numbers()
    test_the_checks_catch_what_they_should()
    print("ok")
