"""The package's layer contract: one folder per stage of the data flow, each importing only the
stages below it, and no import circles between modules.

The import graph is read from the source with :mod:`ast` (every ``import``, also inside
functions and under ``TYPE_CHECKING``: a lazy import is still a dependency), so the contract
holds whatever runs first.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE_DIR = Path(__file__).resolve().parents[1] / "virtualgps"

# Top first. A module may import its own layer and those below it, never one above.
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("command line", ("virtualgps.cli", "virtualgps.__main__")),
    ("gap tool", ("virtualgps.gap",)),
    ("running receivers", ("virtualgps.run",)),
    ("poses", ("virtualgps.poses",)),
    ("device", ("virtualgps.device",)),
    ("receiver", ("virtualgps.receiver",)),
    ("sky", ("virtualgps.sky",)),
    ("base", ("virtualgps", "virtualgps.geodesy", "virtualgps.constants",
              "virtualgps.exceptions", "virtualgps.usercache", "virtualgps.bundled",
              "virtualgps.tomlfile", "virtualgps.plot")),
]


def module_name(path: Path, package_dir: Path) -> str:
    """Dotted name of a source file under ``package_dir`` (a package's is its folder's)."""
    parts = [package_dir.name, *path.relative_to(package_dir).with_suffix("").parts]
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def import_graph(package_dir: Path) -> dict[str, set[str]]:
    """Every module of the package and the package modules it imports.

    ``from a.b import c`` counts as importing ``a.b.c`` where that is a module, else ``a.b``.
    """
    files = {module_name(p, package_dir): p for p in package_dir.rglob("*.py")}
    top = package_dir.name
    graph: dict[str, set[str]] = {}
    for mod, path in files.items():
        is_pkg = path.name == "__init__.py"
        here = mod.split(".") if is_pkg else mod.split(".")[:-1]
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name.split(".")[0] == top)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = here[: len(here) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if target.split(".")[0] != top:
                    continue
                for alias in node.names:
                    sub = f"{target}.{alias.name}"
                    deps.add(sub if sub in files else target)
        graph[mod] = {d for d in deps if d != mod}
    return graph


def layer_of(mod: str, layers=LAYERS) -> int | None:
    """Index of the layer owning ``mod`` (the longest matching prefix), None if none does."""
    best, best_len = None, -1
    for i, (_, prefixes) in enumerate(layers):
        for p in prefixes:
            if (mod == p or mod.startswith(p + ".")) and len(p) > best_len:
                best, best_len = i, len(p)
    return best


def upward_imports(graph: dict[str, set[str]], layers=LAYERS) -> list[str]:
    """'a -> b' for every import from a lower layer up, or of or from an unassigned module."""
    bad = []
    for mod, deps in sorted(graph.items()):
        lm = layer_of(mod, layers)
        if lm is None:
            bad.append(f"{mod}: in no layer")
            continue
        for dep in sorted(deps):
            ld = layer_of(dep, layers)
            if ld is None or ld < lm:
                bad.append(f"{mod} -> {dep} ({layers[lm][0]} imports "
                           f"{layers[ld][0] if ld is not None else 'no layer'})")
    return bad


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_stage_imports_a_stage_above_it():
    assert upward_imports(import_graph(PACKAGE_DIR)) == []


def test_no_import_circles():
    # A package's __init__ re-exporting its own modules is not a circle of concerns, but none
    # does today; the rule stays simple.
    assert cycles(import_graph(PACKAGE_DIR)) == []


@pytest.fixture
def toy_package(tmp_path):
    """A package whose low layer imports its high one, and two modules that import each other."""
    pkg = tmp_path / "virtualgps"
    (pkg / "sky").mkdir(parents=True)
    (pkg / "receiver").mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "sky" / "__init__.py").write_text("")
    (pkg / "receiver" / "__init__.py").write_text("")
    (pkg / "sky" / "scene.py").write_text(
        "def f():\n    from virtualgps.receiver import core\n")
    (pkg / "receiver" / "core.py").write_text("from . import state\n")
    (pkg / "receiver" / "state.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
        "    from virtualgps.receiver.core import x\n")
    return pkg


def test_the_contract_catches_an_upward_import_and_a_circle(toy_package):
    graph = import_graph(toy_package)
    assert graph["virtualgps.sky.scene"] == {"virtualgps.receiver.core"}
    assert graph["virtualgps.receiver.core"] == {"virtualgps.receiver.state"}
    bad = upward_imports(graph)
    assert bad == ["virtualgps.sky.scene -> virtualgps.receiver.core (sky imports receiver)"]
    assert cycles(graph) == [["virtualgps.receiver.core", "virtualgps.receiver.state"]]


# Import name of each runtime dependency (the distribution's name where they differ).
IMPORT_NAMES = {"pyserial": "serial"}


def test_every_runtime_dependency_is_imported_by_the_package():
    import tomllib

    deps = tomllib.loads((PACKAGE_DIR.parent / "pyproject.toml").read_text())["project"]
    names = {re.split(r"[<>=!~\[ ;]", d, maxsplit=1)[0].lower() for d in deps["dependencies"]}
    imported: set[str] = set()
    for path in PACKAGE_DIR.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                imported.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                imported.add(node.module.split(".")[0])
    unused = sorted(n for n in names if IMPORT_NAMES.get(n, n) not in imported)
    assert unused == [], f"runtime dependencies nothing in virtualgps/ imports: {unused}"
