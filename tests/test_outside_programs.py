"""Every outside program that the project's Python code runs is installed by ``./studio``.

A program counts as installed when it is found on PATH and comes from the project's .venv, or
from a Debian package that ``./studio`` installs (its ``DEBIAN_*`` lists and what they depend
on), or from one of Debian's essential packages (on every Debian system: coreutils, bash,
dpkg...), or is one of a few base-system programs (:data:`BASE_PROGRAMS`). A program installed
by hand (``/usr/local/bin``) or by a package that ``./studio`` does not name fails the test: a
fresh machine would not have it.

Found by reading the code (``ast``): ``subprocess.run/Popen/call/check_call/check_output``
and ``asyncio.create_subprocess_exec`` with a literal program (a list or tuple, a string, a name
bound to one in the enclosing scopes, or ``a + b`` with such a list first), ``os.system``,
``os.popen``, ``subprocess.getoutput`` (the first word of the command), ``os.exec*``,
``os.spawn*``, ``os.posix_spawn*`` and ``shutil.which``. A program name built at run time is
not seen.
"""

from __future__ import annotations

import ast
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Programs every machine that runs ``./studio`` has besides Debian's essential packages
#: (which count as installed): the Python that makes the .venv, and git that cloned the project.
BASE_PROGRAMS = frozenset({"python", "python3", "git"})

#: Folders that hold no project code (caches, outputs, the .venv).
SKIP_DIRS = frozenset({"__pycache__", "out", "projects", "build", "dist", "node_modules"})

#: Calls that run a program named by their first argument: list/tuple/string or a shell line.
_RUN = {"subprocess." + f for f in ("run", "Popen", "call", "check_call", "check_output")} | {
    "asyncio.create_subprocess_exec",
    "asyncio.create_subprocess_shell",
}
_SHELL = {"os.system", "os.popen", "subprocess.getoutput", "subprocess.getstatusoutput"}
#: Calls whose first argument is the program itself.
_PROGRAM = {"shutil.which", "os.posix_spawn", "os.posix_spawnp"} | {
    f"os.exec{s}" for s in ("l", "le", "lp", "lpe", "v", "ve", "vp", "vpe")
}
#: Calls whose second argument is the program (the first is the mode).
_SPAWN = {f"os.spawn{s}" for s in ("l", "le", "lp", "lpe", "v", "ve", "vp", "vpe")}


# --------------------------------------------------------------------------------- the scan


def programs_in_source(source: str) -> list[tuple[str, int]]:
    """The outside programs that Python ``source`` runs: ``(name, line)`` pairs, in order."""
    tree = ast.parse(source)
    found: list[tuple[str, int]] = []
    _scan_scope(tree, {}, _import_aliases(tree), found)
    return sorted(found, key=lambda p: p[1])


_FUNCTIONS = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)


def _scan_scope(scope: ast.AST, outer: dict, aliases: dict[str, str], found: list) -> None:
    """Add the programs run in ``scope`` (a module or a function) and in the functions inside
    it to ``found``. Names resolve as Python does: the function's own assignments and
    parameters (unknown) first, then the enclosing scopes'."""
    nodes = list(_scope_nodes(scope))
    bound = dict(outer)
    if isinstance(scope, _FUNCTIONS):
        a = scope.args
        for arg in [*a.posonlyargs, *a.args, *a.kwonlyargs, a.vararg, a.kwarg]:
            if arg is not None:
                bound[arg.arg] = None
    for node in nodes:
        if isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                if isinstance(target, ast.Name):
                    literal = isinstance(node.value, (ast.List, ast.Tuple, ast.Constant))
                    bound[target.id] = node.value if literal and len(targets) == 1 else None
    for node in nodes:
        if isinstance(node, _FUNCTIONS) and node is not scope:
            _scan_scope(node, bound, aliases, found)
        elif isinstance(node, ast.Call):
            program = _program_of_call(node, bound, aliases)
            if program:
                found.append((program, node.lineno))


def _scope_nodes(scope: ast.AST):
    """The nodes of ``scope`` itself: nested functions are yielded but not entered."""
    todo = list(ast.iter_child_nodes(scope))
    while todo:
        node = todo.pop()
        yield node
        if not isinstance(node, _FUNCTIONS):
            todo += ast.iter_child_nodes(node)


def _program_of_call(node: ast.Call, bound: dict, aliases: dict[str, str]) -> str | None:
    """The program that the call ``node`` runs, when it runs one and its name is literal."""
    name = _dotted(node.func, aliases)
    if name in _RUN or name in _SHELL or name in _PROGRAM:
        arg = node.args[0] if node.args else _keyword(node, ("args", "cmd", "command"))
    elif name in _SPAWN:
        arg = node.args[1] if len(node.args) > 1 else None
    else:
        return None
    value = _literal(arg, bound)
    if isinstance(value, (list, tuple)):
        return value[0] if value and isinstance(value[0], str) else None
    if isinstance(value, str) and name in _PROGRAM | _SPAWN:
        return value
    if isinstance(value, str):  # a command line
        words = shlex.split(value, posix=True) if value.strip() else []
        return words[0] if words else None
    return None


def _import_aliases(tree: ast.Module) -> dict[str, str]:
    """Local name -> dotted origin for ``import x as y`` and ``from x import y as z``."""
    aliases = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                top = a.name.split(".")[0]
                aliases[a.asname or top] = a.name if a.asname else top
        elif isinstance(node, ast.ImportFrom) and node.module:
            for a in node.names:
                aliases[a.asname or a.name] = f"{node.module}.{a.name}"
    return aliases


def _dotted(func: ast.expr, aliases: dict[str, str]) -> str | None:
    """``sp.run`` -> ``subprocess.run`` (through the file's imports); None when not a name."""
    parts = []
    while isinstance(func, ast.Attribute):
        parts.append(func.attr)
        func = func.value
    if not isinstance(func, ast.Name):
        return None
    parts.append(aliases.get(func.id, func.id))
    return ".".join(reversed(parts))


def _keyword(call: ast.Call, names: tuple[str, ...]) -> ast.expr | None:
    return next((k.value for k in call.keywords if k.arg in names), None)


def _literal(node: ast.expr | None, bound: dict[str, ast.expr | None], depth: int = 0):
    """The literal value of ``node`` as far as it is known: a str, a list (its known first
    items; None where unknown) or None."""
    if node is None or depth > 5:
        return None
    if isinstance(node, ast.Constant):
        return node.value if isinstance(node.value, str) else None
    if isinstance(node, (ast.List, ast.Tuple)):
        return [
            None if isinstance(e, ast.Starred) else _literal(e, bound, depth + 1)
            for e in node.elts[:1]
        ]
    if isinstance(node, ast.Name):
        return _literal(bound.get(node.id), bound, depth + 1)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        return _literal(node.left, bound, depth + 1)
    return None


def project_python_files(root: Path = ROOT) -> list[Path]:
    """The project's own Python files (no .venv, caches, hidden folders or outputs)."""
    files = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = [
            d
            for d in dirnames
            if not d.startswith(".") and d not in SKIP_DIRS and not d.endswith(".egg-info")
        ]
        files += [Path(dirpath, f) for f in filenames if f.endswith(".py")]
    return sorted(files)


# ----------------------------------------------------------------- what ./studio installs


def studio_debian_packages(script: Path = ROOT / "studio") -> list[str]:
    """The Debian packages named in ``./studio``'s ``DEBIAN_*=( ... )`` lists."""
    text = script.read_text()
    lists = re.findall(r"^DEBIAN_[A-Z_]+=\(([^)]*)\)", text, re.M)
    assert lists, f"{script}: no DEBIAN_*=(...) package list found"
    return [p for group in lists for p in group.split()]


def installed_closure(packages: list[str]) -> set[str]:
    """``packages``, Debian's essential packages, and every installed package they depend on
    (Depends and Pre-Depends, recursively; virtual packages through Provides), from dpkg's
    database."""
    out = subprocess.run(
        [
            "dpkg-query",
            "-W",
            "-f",
            "${Package}\t${Essential}\t${Provides}\t${Pre-Depends}, ${Depends}\n",
        ],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    depends: dict[str, set[str]] = {}
    providers: dict[str, set[str]] = {}
    todo = list(packages)
    for line in out.splitlines():
        package, essential, provides, deps = (line.split("\t") + ["", "", ""])[:4]
        if essential == "yes":
            todo.append(package)
        depends.setdefault(package, set()).update(_package_names(deps))
        for virtual in _package_names(provides):
            providers.setdefault(virtual, set()).add(package)
    seen: set[str] = set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        todo += depends.get(name, ())
        todo += providers.get(name, ())
    return seen


def _package_names(field: str) -> set[str]:
    """Package names in a Depends/Provides field: ``a (>= 1), b:any | c`` -> {a, b, c}."""
    names = set()
    for alternative in re.split(r"[,|]", field):
        word = alternative.strip().split(" ")[0].split(":")[0]
        if word:
            names.add(word)
    return names


def owning_package(path: str) -> str | None:
    """The Debian package that installed the file at ``path`` (links followed), or None."""
    for candidate in dict.fromkeys((path, os.path.realpath(path))):
        # merged /usr: dpkg knows a program under the folder it was packaged in
        if re.match(r"/usr/s?bin/", candidate):
            variants = (candidate, candidate[4:])
        elif re.match(r"/s?bin/", candidate):
            variants = (candidate, "/usr" + candidate)
        else:
            variants = (candidate,)
        for variant in variants:
            r = subprocess.run(["dpkg-query", "-S", variant], capture_output=True, text=True)
            owners = [ln for ln in r.stdout.splitlines() if not ln.startswith("diversion by")]
            if r.returncode == 0 and owners:
                return owners[0].split(":")[0].split(",")[0].strip()
    return None


def program_problem(program: str, closure: set[str]) -> str | None:
    """Why ``program`` may be missing on a fresh machine, or None when ./studio provides it."""
    if program in BASE_PROGRAMS:
        return None
    path = shutil.which(program)
    if path is None:
        in_venv = Path(sys.prefix, "bin", program)
        if in_venv.exists():
            return f"in {in_venv.parent} but not on PATH (./studio does not activate the .venv)"
        return "not installed here"
    if Path(path).resolve().is_relative_to(Path(sys.prefix).resolve()):
        return None
    package = owning_package(path)
    if package is None:
        return f"{path} comes from no Debian package (installed by hand?)"
    if package not in closure:
        return f"{path} comes from Debian package {package}, which ./studio does not install"
    return None


# --------------------------------------------------------------------------------- tests


def test_the_scan_finds_every_way_of_running_a_program():
    source = """
import os, subprocess
import subprocess as sp
from shutil import which as find_program
TOOL = ["convert", "-resize"]
sp.run(["import", "-window", "root", "x.png"], check=True)
sp.Popen(("ffmpeg", "-i", "a"))
subprocess.check_output("identify -format %w x.png", shell=True)
subprocess.call(TOOL + ["a.png"])
os.system("xdotool search --name studio")
find_program("gnome-screenshot")
os.execvp("xwd", ["xwd", "-root"])
os.spawnlp(os.P_WAIT, "scrot", "scrot")
subprocess.run(args=["xclip"])
subprocess.run([sys.executable, "-m", "app.cli"])
subprocess.run(command)
def run(TOOL):
    subprocess.run(TOOL)
def convert_all():
    TOOL = ["magick"]
    subprocess.run(TOOL)
"""
    found = programs_in_source(source)
    assert [name for name, _ in found] == [
        "import", "ffmpeg", "identify", "convert", "xdotool", "gnome-screenshot", "xwd",
        "scrot", "xclip", "magick",
    ]  # fmt: skip
    assert found[0][1] == 6


def test_package_names_of_a_depends_field():
    assert _package_names("libc6 (>= 2.34), libx11-6 | libx11-dev:any, ") == {
        "libc6",
        "libx11-6",
        "libx11-dev",
    }
    assert _package_names("") == set()


def test_every_outside_program_is_installed_by_studio():
    if shutil.which("dpkg-query") is None:
        pytest.skip("not a Debian system: ./studio installs no system packages here")
    used: dict[str, list[str]] = {}
    for path in project_python_files():
        for program, line in programs_in_source(path.read_text(encoding="utf-8")):
            used.setdefault(program, []).append(f"{path.relative_to(ROOT)}:{line}")
    assert "dpkg-query" in used  # the scan sees this file's own calls
    closure = installed_closure(studio_debian_packages())
    assert "libc6" in closure  # dependencies are followed
    problems = [
        f"{program}: {why}; run at {', '.join(where[:3])}"
        for program, where in sorted(used.items())
        if (why := program_problem(program, closure))
    ]
    assert not problems, (
        "outside programs that ./studio does not install (add their Debian package to a "
        "DEBIAN_* list in ./studio, or do without them):\n" + "\n".join(problems)
    )
