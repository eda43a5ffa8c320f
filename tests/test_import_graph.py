"""The project's import graph: no import cycles, and the engine never reaches Blender.

Every module of ``pdehead_addon/`` and ``operators/`` (and the extension's root
``__init__.py``) is parsed with :mod:`ast`. Every import statement counts, at
the top of a module and inside functions and methods alike: an import inside a
function closes a loop as surely as one at the top, it only runs later. Imports
under ``if TYPE_CHECKING:`` never run and are left out; imports built at run
time (``importlib.import_module`` with a computed name) cannot be seen.

Resolution follows Python: ``from .. import x`` is an edge to the submodule
``x`` when there is one, else to the package's ``__init__``; ``import a.b.c``
and ``from a.b import c`` reach the deepest module that exists. Importing a
submodule is not counted as importing its parent package (Python runs the
parent's ``__init__`` first, but that never deadlocks: the parent is already in
``sys.modules`` while its own imports run).
"""
from __future__ import annotations

import ast
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pdehead_addon", "operators")
ENGINE = "pdehead_addon"
#: Modules that exist only inside Blender; the engine must run without them.
BLENDER_MODULES = frozenset({"bpy", "bpy_extras", "bmesh", "mathutils", "gpu", "blf", "bl_math", "idprop"})


@dataclass(frozen=True)
class Edge:
    """One import statement: ``source`` imports ``target`` at ``line`` (module names relative to the root)."""

    source: str
    target: str
    line: int
    external: bool = False        # target is not a project module (numpy, bpy, ...): its top-level name


@dataclass
class ImportGraph:
    files: dict[str, Path]        # module name -> file ("" is the extension's root __init__.py)
    edges: list[Edge]

    def project_edges(self) -> list[Edge]:
        return [e for e in self.edges if not e.external]

    def label(self, module: str) -> str:
        return self.files[module].relative_to(self.root).as_posix()

    root: Path = ROOT


def _module_files(root: Path, packages) -> dict[str, Path]:
    files: dict[str, Path] = {}
    if (root / "__init__.py").is_file():
        files[""] = root / "__init__.py"
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            files[".".join(parts)] = path
    return files


def _imports(tree: ast.AST):
    """Every Import/ImportFrom node, function bodies included, except under ``if TYPE_CHECKING:``."""
    def type_checking(test: ast.expr) -> bool:
        return ((isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
                or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))

    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
            continue
        if isinstance(node, ast.If) and type_checking(node.test):
            stack.extend(node.orelse)
            continue
        stack.extend(ast.iter_child_nodes(node))


def _deepest(name: str, modules) -> str | None:
    """The longest prefix of dotted ``name`` that is a project module."""
    parts = name.split(".") if name else []
    for n in range(len(parts), -1, -1):
        candidate = ".".join(parts[:n])
        if candidate in modules and (n or name == ""):
            return candidate
    return None


def build_graph(root: Path = ROOT, packages=PACKAGES) -> ImportGraph:
    """Parse every module of ``packages`` under ``root`` and resolve its imports."""
    files = _module_files(root, packages)
    tops = set(packages) | {""}
    edges: list[Edge] = []
    for module, path in files.items():
        is_package = path.name == "__init__.py"
        package = module if is_package else module.rpartition(".")[0]
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in _imports(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    top = alias.name.split(".")[0]
                    target = _deepest(alias.name, files) if top in packages else None
                    edges.append(Edge(module, target, node.lineno) if target is not None
                                 else Edge(module, top, node.lineno, external=True))
                continue
            if node.level:
                parts = package.split(".") if package else []
                up = node.level - 1
                if up > len(parts):
                    raise ValueError(f"{path}:{node.lineno}: relative import goes above the project root")
                base = ".".join(parts[:len(parts) - up])
            else:
                base = ""
            full = ".".join(p for p in (base, node.module or "") if p)
            top = full.split(".")[0]
            if not node.level and top not in packages:
                edges.append(Edge(module, top, node.lineno, external=True))
                continue
            if top not in tops:
                raise ValueError(f"{path}:{node.lineno}: relative import of {full!r} leaves the project")
            for alias in node.names:
                sub = f"{full}.{alias.name}" if full else alias.name
                target = sub if alias.name != "*" and sub in files else _deepest(full, files)
                if target is None:
                    raise ValueError(f"{path}:{node.lineno}: {full!r} is not a module of the project")
                edges.append(Edge(module, target, node.lineno))
    edges.sort(key=lambda e: (e.source, e.line, e.target))
    return ImportGraph(files, edges, root)


@dataclass
class Cycle:
    """A strongly connected set of modules and one shortest import loop through its first module."""

    members: list[str]
    edges: list[Edge]


def strong_components(succ: dict) -> list[list[str]]:
    """The strongly connected components of the graph ``succ`` (node -> its successors), Tarjan's algorithm."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    components: list[list[str]] = []

    def connect(v: str) -> None:                        # ~50 modules: recursion depth is no issue
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in succ[v]:
            if w not in index:
                connect(w)
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
            components.append(sorted(comp))

    for v in sorted(succ):
        if v not in index:
            connect(v)
    return components


def _shortest_loop(succ: dict[str, dict[str, Edge]], comp: list[str]) -> list[Edge]:
    """A shortest loop from the component's first module back to it, inside the component (breadth-first)."""
    start, members = comp[0], set(comp)
    prev: dict[str, Edge] = {}
    queue = deque([start])
    found = None
    while queue and found is None:
        v = queue.popleft()
        for w, e in sorted(succ[v].items()):
            if w not in members:
                continue
            if w == start:
                found = e
                break
            if w not in prev:
                prev[w] = e
                queue.append(w)
    path = [found]
    while path[0].source != start:
        path.insert(0, prev[path[0].source])
    return path


def find_cycles(graph: ImportGraph) -> list[Cycle]:
    """One shortest cycle per strongly connected component of the project modules (Tarjan)."""
    succ: dict[str, dict[str, Edge]] = {m: {} for m in graph.files}
    for e in graph.project_edges():
        succ[e.source].setdefault(e.target, e)          # the first statement importing it
    return [Cycle(comp, _shortest_loop(succ, comp)) for comp in strong_components(succ)
            if len(comp) > 1 or comp[0] in succ[comp[0]]]


def describe(graph: ImportGraph, cycle: Cycle) -> str:
    """``a.py:12 -> b.py:140 -> a.py``: each file with the line of its import of the next (and the
    other modules of the same tangle, when there are more)."""
    steps = [f"{graph.label(e.source)}:{e.line}" for e in cycle.edges]
    text = " -> ".join(steps + [graph.label(cycle.edges[0].source)])
    others = [graph.label(m) for m in cycle.members if m not in {e.source for e in cycle.edges}]
    return text + (f" (same tangle: {', '.join(others)})" if others else "")


def cycles_in(graph: ImportGraph, package: str) -> list[Cycle]:
    """The cycles whose modules all belong to ``package`` (the extension root counts with operators)."""
    def inside(module: str) -> bool:
        return module == package or module.startswith(package + ".") or (module == "" and package != ENGINE)
    return [c for c in find_cycles(graph) if all(inside(m) for m in c.members)]


def engine_violations(graph: ImportGraph, engine: str = ENGINE) -> list[str]:
    """Imports of Blender modules or of non-engine project modules from inside the engine."""
    out = []
    for e in graph.edges:
        if not (e.source == engine or e.source.startswith(engine + ".")):
            continue
        if e.external and e.target in BLENDER_MODULES:
            out.append(f"{graph.label(e.source)}:{e.line} imports {e.target}")
        elif not e.external and not (e.target == engine or e.target.startswith(engine + ".")):
            out.append(f"{graph.label(e.source)}:{e.line} imports {graph.label(e.target)}")
    return out


# ---------------------------------------------------------------------------------------------- the project

@pytest.fixture(scope="module")
def graph() -> ImportGraph:
    return build_graph()


@pytest.mark.parametrize("package", [ENGINE, "operators"])  # operators/: layered since issue 13 (study.py)
def test_no_import_cycles(graph, package):
    cycles = cycles_in(graph, package)
    assert not cycles, f"{len(cycles)} import cycle(s) in {package}/:\n" + "\n".join(
        describe(graph, c) for c in cycles)


def test_engine_never_imports_blender_or_operators(graph):
    bad = engine_violations(graph)
    assert not bad, "the engine must stay Blender-free:\n" + "\n".join(bad)


def test_the_walk_sees_every_module_and_every_kind_of_import(graph):
    """Guards the walker itself: known edges of each kind must be found, else the checks above prove nothing."""
    py_files = [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py") if "__pycache__" not in p.parts]
    assert len(graph.files) == len(py_files) + 1            # + the extension's root __init__.py
    pairs = {(e.source, e.target) for e in graph.project_edges()}
    assert ("pdehead_addon", "pdehead_addon.io.ct_import") in pairs  # from .ct_import import ...
    assert ("pdehead_addon.io.ct_import.load", "pdehead_addon.io.input_checks") in pairs  # from .. import input_checks
    # from ..ct_volume import ...
    assert ("pdehead_addon.io.ct_import.load", "pdehead_addon.core.ct_volume") in pairs
    assert ("pdehead_addon.pde.pde_head", "pdehead_addon.pde.pde_solid") in pairs              # inside a method
    assert ("operators.ui.ops", "pdehead_addon") in pairs                                 # from ..pdehead_addon import
    assert ("", "operators") in pairs                                                  # from . import operators
    external = {(e.source, e.target) for e in graph.edges if e.external}
    assert ("operators", "bpy") in external
    assert ("pdehead_addon.segment.chan_vese", "numpy") in external


# ---------------------------------------------------------------------------------------------- the checks can fail

def _write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_a_cycle_through_a_function_body_is_found_and_its_path_reported(tmp_path):
    _write(tmp_path, {
        "eng/__init__.py": "from .a import f\n",
        "eng/a.py": "from . import b\n\ndef f():\n    return b.g()\n",
        "eng/b.py": "def g():\n    from .sub import c\n    return c.h()\n",
        "eng/sub/__init__.py": "",
        "eng/sub/c.py": "import numpy as np\n\ndef h():\n    from .. import a   # the loop closes here\n    return a\n",
        "eng/d.py": "from .a import f\nfrom eng.sub import c\n",           # imports into the loop, not part of it
    })
    g = build_graph(tmp_path, ("eng",))
    cycles = find_cycles(g)
    assert len(cycles) == 1
    assert cycles[0].members == ["eng.a", "eng.b", "eng.sub.c"]
    assert [e.source for e in cycles[0].edges] == ["eng.a", "eng.b", "eng.sub.c"]
    assert describe(g, cycles[0]) == "eng/a.py:1 -> eng/b.py:2 -> eng/sub/c.py:4 -> eng/a.py"
    assert cycles_in(g, "eng") == cycles
    assert ("eng.d", "eng.sub.c") in {(e.source, e.target) for e in g.edges}             # absolute import


def test_a_self_import_and_type_checking_imports(tmp_path):
    _write(tmp_path, {
        "eng/__init__.py": "",
        "eng/a.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import B\n",
        "eng/b.py": "from .a import x\n",
        "eng/c.py": "def f():\n    from . import c\n",
    })
    g = build_graph(tmp_path, ("eng",))
    assert [describe(g, c) for c in find_cycles(g)] == ["eng/c.py:2 -> eng/c.py"]     # a <-> b only for mypy


def test_engine_reaching_blender_or_the_ui_is_reported(tmp_path):
    _write(tmp_path, {
        "__init__.py": "",
        "eng/__init__.py": "",
        "eng/a.py": "import numpy\n\ndef draw():\n    import bpy\n",
        "eng/b.py": "from mathutils import Vector\n",
        "eng/c.py": "from ..ui import panel\n",
        "ui/__init__.py": "",
        "ui/panel.py": "import bpy\nfrom ..eng import a\n",
    })
    g = build_graph(tmp_path, ("eng", "ui"))
    assert engine_violations(g, "eng") == ["eng/a.py:4 imports bpy", "eng/b.py:1 imports mathutils",
                                           "eng/c.py:1 imports ui/panel.py"]
    assert find_cycles(g) == []
