"""The project's import graph: layered, with no cycles.

Layers, lowest first: ``core`` <- ``templates`` <- ``training`` <- ``pipeline`` <- ``app``. A module
may import its own layer and the layers below it, never one above; and no group of modules may
import each other in a circle. Every import counts, at module level or inside a function (a
deferred import hides a cycle from Python, not from the design).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ("core", "templates", "training", "pipeline", "app")


def project_modules() -> dict[str, Path]:
    """Dotted name -> file of every module of the project's packages."""
    mods = {}
    for layer in LAYERS:
        for path in sorted((ROOT / layer).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = path
    return mods


def _resolve(name: str, mods: dict[str, Path]) -> str | None:
    """The project module an import of ``name`` loads (its longest known prefix), or None."""
    while name:
        if name in mods:
            return name
        name = name.rpartition(".")[0]
    return None


def import_graph(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the project modules it imports anywhere in its file."""
    graph: dict[str, set[str]] = {}
    for mod, path in mods.items():
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        edges = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(up + ([base] if base else []))
                names = [base] + [f"{base}.{a.name}" for a in node.names]
            else:
                continue
            for name in names:
                target = _resolve(name, mods)
                if target is not None and target != mod:
                    edges.add(target)
        graph[mod] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
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
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_graph_sees_every_kind_of_import(tmp_path):
    """The scanner counts relative imports, ``from pkg import module`` and function-local ones."""
    (tmp_path / "core").mkdir()
    (tmp_path / "core" / "__init__.py").write_text("")
    (tmp_path / "core" / "a.py").write_text("def f():\n    from . import b\n")
    (tmp_path / "core" / "b.py").write_text("from core import a\n")
    mods = {
        "core": tmp_path / "core" / "__init__.py",
        "core.a": tmp_path / "core" / "a.py",
        "core.b": tmp_path / "core" / "b.py",
    }
    graph = import_graph(mods)
    assert graph["core.a"] == {"core", "core.b"}
    assert "core.a" in graph["core.b"]
    assert cycles(graph) == [["core.a", "core.b"]]


def test_no_import_cycles():
    found = cycles(import_graph(project_modules()))
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_imports_only_go_down_the_layers():
    mods = project_modules()
    rank = {layer: i for i, layer in enumerate(LAYERS)}
    upward = sorted(
        f"{a} imports {b}"
        for a, targets in import_graph(mods).items()
        for b in targets
        if rank[b.split(".")[0]] > rank[a.split(".")[0]]
    )
    assert not upward, "imports up a layer: " + "; ".join(upward)
