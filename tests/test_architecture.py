"""The package's import graph, read from the source with ``ast`` (nothing is imported): no cycles, and
the layering rules of the architecture (flashnav never imports services; learn and sim never import
bench; the GPU raycaster never imports numba).

Every ``import`` / ``from ... import`` counts, at module level and inside functions alike: a lazy
import is still a dependency, it only moves the failure to run time. Imports under
``if TYPE_CHECKING:`` are skipped (they never run). Importing ``a.b.c`` is an edge to the module
``a.b.c`` only, not to the packages ``a`` and ``a.b`` whose ``__init__`` Python also runs: counting
those would make every package's ``__init__`` that re-exports a submodule a "cycle".
"""

from __future__ import annotations

import ast
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("flashnav", "services")


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every .py file of the project's packages."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def imported_names(tree: ast.AST, module: str, is_package: bool) -> list[tuple[str, int]]:
    """(absolute dotted name, line) of every import in ``tree``; ``from X import y`` gives ``X.y``
    (resolved against the known modules later) and relative imports are made absolute."""
    out: list[tuple[str, int]] = []

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            out.extend((alias.name, node.lineno) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                here = module.split(".") if is_package else module.split(".")[:-1]
                here = here[: len(here) - (node.level - 1)]
                base = ".".join(here + ([base] if base else []))
            out.extend((f"{base}.{alias.name}" if alias.name != "*" else base, node.lineno) for alias in node.names)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return out


def resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The project module that importing ``name`` loads: the longest known prefix (``from a.b import
    f`` names ``a.b.f``, which is a module only if a file says so); None outside the project."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        candidate = ".".join(parts[:k])
        if candidate in modules:
            return candidate
    return None


def import_graph(root: Path = ROOT) -> tuple[dict[str, dict[str, int]], dict[str, list[tuple[str, int]]]]:
    """(project edges: module -> {imported project module: line}, every import: module -> [(name, line)])."""
    modules = module_files(root)
    edges: dict[str, dict[str, int]] = {}
    raw: dict[str, list[tuple[str, int]]] = {}
    for mod, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        names = imported_names(tree, mod, path.name == "__init__.py")
        raw[mod] = names
        edges[mod] = {}
        for name, line in names:
            target = resolve(name, modules)
            if target is not None and target != mod:
                edges[mod].setdefault(target, line)
    return edges, raw


def find_cycles(edges: dict[str, dict[str, int]]) -> list[list[str]]:
    """One cycle per strongly connected component with more than one module (Tarjan), as a closed
    path ``[a, b, ..., a]`` found by a depth-first search inside the component."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []
    counter = [0]

    def strongconnect(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, {}):
            if w not in index:
                strongconnect(w)
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
                components.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            strongconnect(v)

    cycles = []
    for comp in components:
        members, start = set(comp), comp[0]
        path, seen = [start], {start}

        def dfs(v: str) -> bool:
            for w in sorted(edges[v]):
                if w == start:
                    path.append(w)
                    return True
                if w in members and w not in seen:
                    seen.add(w)
                    path.append(w)
                    if dfs(w):
                        return True
                    path.pop()
            return False

        dfs(start)
        cycles.append(path)
    return cycles


def describe(cycle: list[str], edges: dict[str, dict[str, int]]) -> str:
    return " -> ".join(f"{a} (line {edges[a][b]})" for a, b in zip(cycle, cycle[1:])) + f" -> {cycle[-1]}"


@pytest.fixture(scope="module")
def graph():
    return import_graph()


def test_no_import_cycles(graph):
    edges, _ = graph
    cycles = find_cycles(edges)
    assert not cycles, "import cycles:\n" + "\n".join(describe(c, edges) for c in cycles)


def _violations(raw, importer_prefixes, forbidden_prefixes):
    def under(name, prefixes):
        return any(name == p or name.startswith(p + ".") for p in prefixes)

    return [f"{mod}:{line} imports {name}" for mod, names in sorted(raw.items()) if under(mod, importer_prefixes)
            for name, line in names if under(name, forbidden_prefixes)]


def test_the_library_never_imports_the_service(graph):
    _, raw = graph
    bad = _violations(raw, ["flashnav"], ["services"])
    assert not bad, "flashnav must not import services/:\n" + "\n".join(bad)


def test_training_and_simulation_never_import_the_benchmarks(graph):
    _, raw = graph
    bad = _violations(raw, ["flashnav.learn", "flashnav.sim"], ["flashnav.bench"])
    assert not bad, "flashnav.learn / flashnav.sim must not import flashnav.bench:\n" + "\n".join(bad)


def test_the_gpu_raycaster_never_imports_numba(graph):
    _, raw = graph
    bad = _violations(raw, ["flashnav.sim.raycast_torch"], ["numba", "flashnav.sim.raycast_numba"])
    assert not bad, "raycast_torch must not import numba (absent or slow on GPU machines):\n" + "\n".join(bad)


# ---- the checker itself, on a synthetic package ------------------------------------------------------
def _write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))


def test_checker_finds_function_level_and_relative_cycles(tmp_path):
    _write(tmp_path, {
        "flashnav/__init__.py": "",
        "flashnav/a.py": "from flashnav.b import f\n",
        "flashnav/b.py": "def f():\n    from . import c\n",
        "flashnav/c.py": "import flashnav.a\n",
        "flashnav/d.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from flashnav import e\n",
        "flashnav/e.py": "from flashnav.d import x\n",
        "services/__init__.py": "",
    })
    edges, raw = import_graph(tmp_path)
    assert edges["flashnav.b"] == {"flashnav.c": 2}
    cycles = find_cycles(edges)
    assert cycles == [["flashnav.a", "flashnav.b", "flashnav.c", "flashnav.a"]]
    assert describe(cycles[0], edges) == ("flashnav.a (line 1) -> flashnav.b (line 2) -> flashnav.c (line 1)"
                                          " -> flashnav.a")
    assert _violations(raw, ["flashnav"], ["services"]) == []
