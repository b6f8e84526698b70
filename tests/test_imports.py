"""The packages' imports point down: no import circle within a package (function-level imports included),
and nothing in sf2-common or the cores imports sf2-studies (it drives the cores through their command
line and run folders; they find its commands by entry point). Read with `ast`; nothing is imported.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# packages whose source must not import sf2_studies
BELOW_STUDIES = ("sf2-common", "sf2-core-jax", "sf2-core-torch")


def _modules(src: Path) -> dict[str, Path]:
    """{dotted module name: file} of every module under a package's src/ folder."""
    out = {}
    for path in sorted(src.rglob("*.py")):
        parts = path.relative_to(src).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _imports(name: str, path: Path) -> list[tuple[str, tuple[str, ...]]]:
    """What `path` (the module `name`) imports, at any depth of its code: (module, names) per statement,
    relative imports resolved; names is () for `import module`."""
    is_package = path.name == "__init__.py"
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, ()) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:
                base = name.split(".") if is_package else name.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            found.append((module, tuple(alias.name for alias in node.names)))
    return found


def _graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """{module: the modules of its package it imports}: `from X import y` imports X.y when that is a module,
    else X."""
    graph = {}
    for name, path in modules.items():
        targets = set()
        for module, names in _imports(name, path):
            named = [f"{module}.{n}" if f"{module}.{n}" in modules else module for n in names]
            targets.update(t for t in named or [module] if t in modules and t != name)
        graph[name] = targets
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _packages():
    return sorted(p for p in (ROOT / "packages").glob("*/src") if p.is_dir())


def test_every_package_is_read():
    names = {src.parent.name for src in _packages()}
    assert {"sf2-common", "sf2-core-jax", "sf2-core-torch", "sf2-studies", "sf2-baselines"} <= names


def test_no_import_circle_within_a_package():
    circles = []
    for src in _packages():
        for cycle in _cycles(_graph(_modules(src))):
            circles.append(f"{src.parent.name}: {' <-> '.join(cycle)}")
    assert not circles, "modules that import each other (directly or around a circle):\n" + "\n".join(circles)


def test_nothing_below_the_studies_imports_them():
    found = []
    for package in BELOW_STUDIES:
        src = ROOT / "packages" / package / "src"
        for name, path in _modules(src).items():
            for module, _ in _imports(name, path):
                if module.split(".")[0] == "sf2_studies":
                    found.append(f"{path.relative_to(ROOT)} imports {module}")
    assert not found, "\n".join(sorted(set(found)))


def test_the_graph_sees_function_level_and_relative_imports(tmp_path):
    """A circle closed only by an import inside a function, through a relative import, is found."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from .b import thing\n")
    (pkg / "b.py").write_text("def thing():\n    from pkg import a\n    return a\n")
    (pkg / "c.py").write_text("from . import b\nimport pkg.a\n")
    graph = _graph(_modules(tmp_path))
    assert graph == {"pkg": set(), "pkg.a": {"pkg.b"}, "pkg.b": {"pkg.a"}, "pkg.c": {"pkg.a", "pkg.b"}}
    assert _cycles(graph) == [["pkg.a", "pkg.b"]]
