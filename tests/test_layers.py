"""The project's import graph: layered, with no cycles, and imports at module level unless
they are heavy.

Layers, lowest first: ``core`` <- ``templates`` <- ``training`` <- ``pipeline`` <- ``app``. A module
may import its own layer and the layers below it, never one above; and no group of modules may
import each other in a circle. Every import counts, at module level or inside a function (a
deferred import hides a cycle from Python, not from the design).

An import inside a function is a deferral, and only a heavy one is allowed: a library that takes
long to load or is optional (:data:`HEAVY`), or a project module that loads one at module level.
Commands, the studio window and the torch-only path start without them that way; everything
else is imported at the top of its module.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ("core", "templates", "training", "pipeline", "app")
#: Libraries whose import is deferred into the functions that need them: slow to load (torch,
#: open3d, warp, newton, scipy, vtk...) or not on every machine the code runs on (the torch-only
#: path's GPU machine has torch and numpy alone).
HEAVY = frozenset({
    "torch", "open3d", "warp", "newton", "scipy", "trimesh", "igl", "pyvista", "vtk",
    "xatlas", "fast_simplification", "tqdm", "PIL", "imageio", "imageio_ffmpeg", "matplotlib",
    "pxr", "pygltflib", "mpl_toolkits", "cv2",
})  # fmt: skip


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


def _targets(node: ast.AST, mod: str, mods: dict[str, Path]) -> list[str]:
    """What an import statement names: project modules (resolved) or top-level libraries."""
    package = mod if mods[mod].name == "__init__.py" else mod.rpartition(".")[0]
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        base = node.module or ""
        if node.level:
            up = package.split(".")[: len(package.split(".")) - node.level + 1]
            base = ".".join(up + ([base] if base else []))
        names = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
    return [_resolve(n, mods) or n.split(".")[0] for n in names]


def deferred_imports(mods: dict[str, Path]) -> list[tuple[str, int, list[str]]]:
    """(module, line, what it imports) of every import inside a function, outside a ``try``
    (an optional import's fallback)."""
    found = []
    for mod, path in mods.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        parent = {c: n for n in ast.walk(tree) for c in ast.iter_child_nodes(n)}
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            chain, up = [], node
            while up in parent:
                up = parent[up]
                chain.append(up)
            in_function = any(isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) for n in chain)
            if in_function and not any(isinstance(n, ast.Try) for n in chain):
                found.append((mod, node.lineno, _targets(node, mod, mods)))
    return found


def heavy_modules(mods: dict[str, Path]) -> set[str]:
    """Project modules that load a :data:`HEAVY` library when imported (at module level, or
    through their packages or the project modules they import at module level)."""
    top: dict[str, list[str]] = {}
    for mod, path in mods.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        top[mod] = [
            t
            for node in tree.body
            if isinstance(node, (ast.Import, ast.ImportFrom))
            for t in _targets(node, mod, mods)
        ]
    heavy: set[str] = set()
    changed = True
    while changed:
        changed = False
        for mod in mods:
            if mod in heavy:
                continue
            parts = mod.split(".")
            loads = top[mod] + [".".join(parts[:i]) for i in range(1, len(parts))]
            if any(t in HEAVY or t in heavy for t in loads):
                heavy.add(mod)
                changed = True
    return heavy


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


def test_only_heavy_imports_are_deferred():
    mods = project_modules()
    heavy = heavy_modules(mods)
    light = sorted(
        f"{mod}:{line} imports {', '.join(targets)}"
        for mod, line, targets in deferred_imports(mods)
        if not any(t in HEAVY or t in heavy for t in targets)
    )
    assert not light, "deferred imports of light modules (import them at the top): " + "; ".join(
        light
    )


def test_deferral_rule_sees_heaviness_through_modules(tmp_path):
    """A project module is heavy when it, its package or a module it imports loads a heavy
    library; a function-local import inside ``try`` (an optional dependency) is not a deferral."""
    (tmp_path / "core").mkdir()
    files = {
        "core/__init__.py": "",
        "core/a.py": "import torch\n",
        "core/b.py": "from core import a\n",
        "core/c.py": "import json\n\ndef f():\n    from core import b\n    import json\n",
        "core/d.py": "def f():\n    try:\n        import json\n    except ImportError:\n        pass\n",
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    mods = {
        "core": tmp_path / "core/__init__.py",
        **{f"core.{n}": tmp_path / f"core/{n}.py" for n in "abcd"},
    }
    assert heavy_modules(mods) == {"core.a", "core.b"}
    assert deferred_imports(mods) == [("core.c", 4, ["core.b"]), ("core.c", 5, ["json"])]
