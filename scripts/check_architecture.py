#!/usr/bin/env python3
"""The architecture measures, printed; tests/test_architecture.py holds each at its value or better.

    python scripts/check_architecture.py            # the measures as text
    python scripts/check_architecture.py --json     # the same as JSON

Each measure and its target, over the shipped code (``pdehead_addon/``, ``operators/``, the extension's
``__init__.py``) unless said otherwise:

1. modules over 600 lines (target none);
2. functions over complexity 15: ruff's C901 (mccabe) with max-complexity 15 (target none; scripts/ listed
   apart);
3. imports of another module's private name: ``from .x import _name`` and ``module._name`` of an imported
   project module (target none; scripts/ listed apart, tests/ may reach into internals); also the imports
   of the engine's internal modules by ``operators/`` (target: the engine's public names only);
4. uses of another module's private attribute: ``obj._name`` (``obj`` not ``self`` or ``cls``) where
   ``_name`` is defined by another project module and not by this one (target none);
5. repeated blocks of 6+ lines in the engine: ``pylint --disable=all --enable=duplicate-code
   --min-similarity-lines=6 pdehead_addon`` (target none);
6. whether the extension zip carries validation code (target: not shipped);
7. import cycles between packages (``pdehead_addon.curves``, ``pdehead_addon.pde``, ...): every import
   counts, inside functions too (target none);
8. module-level mutable state in ``operators/``: a module-level dict, list or set that the module writes,
   and ``global`` writes (target none);
9. settings declared twice: a property of a PropertyGroup declared again on an Operator (the same name
   and type of property; target none);
10. "issue N" in the shipped code's comments and docstrings (target none: history lives in docs/ and git);
11. README.md lines (target at most 250);
12. ruff: findings of ``ruff check`` with the project's configuration (target none) and the files on its
    temporary per-file-ignores ratchet in pyproject.toml (target none);
13. mixins of the study entity classes (:data:`STUDY_ENTITIES`: ``Study``, ``ForensicStudy``): each base class
    they inherit methods from (target none: the parts are components the entity holds, ``fs.face``);
14. CLI steps driven through operators: ``bpy.ops.pdehead.*`` calls and ``REGISTRY.last_exception`` reads in
    ``scripts/pdehead.py`` (target none: it calls the study's methods and reports their outcomes);
15. imports inside functions without a reason: an ``import`` in a function body whose lines carry no
    ``# deferred: <why>`` comment (target none: imports sit at the module top unless a heavy or optional
    dependency is deferred, and the comment says which and what it costs).

ruff and pylint are pinned in requirements.txt; they are run as ``python -m ruff`` / ``python -m pylint``
of the Python running this script.
"""
from __future__ import annotations

import argparse
import ast
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ("pdehead_addon", "operators")
MAX_LINES, MAX_COMPLEXITY, MIN_SIMILAR, MAX_README_LINES = 600, 15, 6, 250
#: Validation code (measures for the tests and the benchmarks) as it sits today, and the package it goes to.
VALIDATION_FILES = ("pdehead_addon/validation/metrics.py", "pdehead_addon/validation/surface_quality.py",
                    "pdehead_addon/validation/surface_metrics.py", "pdehead_addon/validation/dicom_export.py")
VALIDATION_PACKAGE = "pdehead_addon/validation"


def python_files(*folders: str) -> list[Path]:
    return sorted(p for f in folders for p in (ROOT / f).rglob("*.py") if "__pycache__" not in p.parts)


def rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


# ------------------------------------------------------------------------------------------- 1. module size
def long_modules() -> list[dict]:
    out = []
    for path in python_files(*SHIPPED):
        n = len(path.read_text(encoding="utf-8").splitlines())
        if n > MAX_LINES:
            out.append({"module": rel(path), "lines": n, "limit": MAX_LINES})
    return sorted(out, key=lambda m: -m["lines"])


# ------------------------------------------------------------------------------------------- 2. complexity
def complex_functions(folders) -> list[dict]:
    cmd = [sys.executable, "-m", "ruff", "check", "--isolated", "--select", "C901", "--config",
           f"lint.mccabe.max-complexity = {MAX_COMPLEXITY}", "--output-format", "json",
           *[str(ROOT / f) for f in folders]]
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if result.returncode not in (0, 1):
        raise RuntimeError(f"ruff failed: {result.stderr}")
    out = []
    for item in json.loads(result.stdout or "[]"):
        m = re.match(r"`(.+)` is too complex \((\d+) > \d+\)", item["message"])
        out.append({"function": m.group(1) if m else item["message"], "complexity": int(m.group(2)) if m else None,
                    "where": f"{rel(Path(item['filename']))}:{item['location']['row']}"})
    return sorted(out, key=lambda f: -(f["complexity"] or 0))


# ------------------------------------------------------------------------------------------- 3. private names
def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def resolve(importer: str, is_package: bool, module: str | None, level: int) -> str:
    """The absolute (repository-relative) module name of an import's ``from`` part."""
    if level == 0:
        return module or ""
    base = importer.split(".") if is_package else importer.split(".")[:-1]
    base = base[:len(base) - (level - 1)] if level > 1 else base
    return ".".join(base + ([module] if module else []))


def is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def project_module(name: str, known: set[str]) -> bool:
    return name in known or name.split(".")[0] in ("pdehead_addon", "operators")


def private_imports(folders) -> list[dict]:
    """``from <project module> import _x`` and ``m._x`` where ``m`` names an imported project module."""
    files = python_files(*folders)
    known = {module_name(p) for p in python_files(*SHIPPED)}
    out = []
    for path in files:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        me, is_package = module_name(path), path.name == "__init__.py"
        aliases: dict[str, str] = {}        # local name -> project module it is bound to
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                source = resolve(me, is_package, node.module, node.level)
                if source.startswith("pdehead_dev"):        # scripts' dev shim of the add-on
                    source = source.split(".", 1)[1] if "." in source else ""
                if not (project_module(source, known) or node.level):
                    continue
                for a in node.names:
                    full = f"{source}.{a.name}" if source else a.name
                    if full in known:
                        aliases[a.asname or a.name] = full
                    elif is_private(a.name) and source != me:
                        out.append({"where": f"{rel(path)}:{node.lineno}", "name": a.name, "of": source})
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if project_module(a.name, known) and a.asname:
                        aliases[a.asname] = a.name
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and is_private(node.attr) and isinstance(node.value, ast.Name)
                    and node.value.id in aliases and aliases[node.value.id] != me):
                out.append({"where": f"{rel(path)}:{node.lineno}", "name": node.attr, "of": aliases[node.value.id]})
    return out


# ------------------------------------------------------------------------------------------- 4. private attributes
def _owned_private_names(tree: ast.AST) -> set[str]:
    """Private names a module defines: its functions, classes and methods, names it assigns, and the
    attributes it assigns (``x._name = ...``, ``self._name = ...``)."""
    owned = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            owned.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            owned.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, (ast.Store, ast.Del)):
            owned.add(node.attr)
    return {n for n in owned if is_private(n)}


def private_attribute_uses(folders=SHIPPED) -> list[dict]:
    """``obj._name`` (``obj`` not ``self``/``cls``/``super()``) in a module that does not define ``_name``
    while another project module does: a reach into another module's internals. Names no project module
    defines (``sys._getframe``, ``bpy``'s own) are not counted."""
    trees = {p: ast.parse(p.read_text(encoding="utf-8")) for p in python_files(*SHIPPED)}
    owners: dict[str, set[Path]] = {}
    for path, tree in trees.items():
        for name in _owned_private_names(tree):
            owners.setdefault(name, set()).add(path)
    out = []
    for path in python_files(*folders):
        tree = trees.get(path) or ast.parse(path.read_text(encoding="utf-8"))
        mine = _owned_private_names(tree)
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Load) and is_private(node.attr)):
                continue
            base = node.value
            if isinstance(base, ast.Name) and base.id in ("self", "cls"):
                continue
            if isinstance(base, ast.Call) and isinstance(base.func, ast.Name) and base.func.id == "super":
                continue
            if node.attr in mine or not owners.get(node.attr, set()) - {path}:
                continue
            out.append({"where": f"{rel(path)}:{node.lineno}", "name": node.attr,
                        "of": sorted(rel(o) for o in owners[node.attr] if o != path)})
    return out


#: Engine modules the Blender layer may import whole: the one table of defaults, ranges and labels.
PUBLIC_ENGINE_MODULES = {"pdehead_addon.defaults"}


def internal_engine_imports() -> list[dict]:
    """Imports in operators/ of an engine module other than the package itself (``..pdehead_addon.x``)."""
    out = []
    for path in python_files("operators"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        me, is_package = module_name(path), path.name == "__init__.py"
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                source = resolve(me, is_package, node.module, node.level)
                targets = [source] if source != "pdehead_addon" else [f"pdehead_addon.{a.name}" for a in node.names]
                for t in targets:
                    if t in PUBLIC_ENGINE_MODULES:
                        continue
                    if t.startswith("pdehead_addon.") and (ROOT / (t.replace(".", "/") + ".py")).exists() \
                            or t.startswith("pdehead_addon.") and (ROOT / t.replace(".", "/")).is_dir():
                        out.append({"where": f"{rel(path)}:{node.lineno}", "module": t})
    return out


# ------------------------------------------------------------------------------------------- 4. duplicates
def duplicate_blocks() -> list[dict]:
    cmd = [sys.executable, "-m", "pylint", "--persistent=n", "--disable=all", "--enable=duplicate-code",
           f"--min-similarity-lines={MIN_SIMILAR}", "--score=n", "pdehead_addon"]
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if result.returncode & 1 or result.returncode & 32:          # fatal / usage error (8 = refactor messages)
        raise RuntimeError(f"pylint failed ({result.returncode}): {result.stderr}")
    out = []
    for block in result.stdout.split("R0801: ")[1:]:
        where = re.findall(r"^==(\S+):\[(\d+):(\d+)\]", block, flags=re.M)
        lines = max((int(b) - int(a) for _, a, b in where), default=0)
        out.append({"lines": lines, "where": [f"{m.split('pdehead_addon', 1)[-1].lstrip('.') or m}:{int(a) + 1}-{b}"
                                              for m, a, b in where]})
    return out


# ------------------------------------------------------------------------------------------- 5. the zip
def shipped_validation() -> dict:
    sys.path.insert(0, str(ROOT / "scripts"))
    import build_extension
    with tempfile.TemporaryDirectory(prefix="pdehead-arch-") as tmp:
        stage = Path(tmp) / "stage"
        build_extension.stage_sources(stage)
        found = [f for f in VALIDATION_FILES if (stage / f).exists()]
        if (stage / VALIDATION_PACKAGE).is_dir():
            found.append(VALIDATION_PACKAGE + "/")
    return {"carries_validation": bool(found), "files": found}


# ------------------------------------------------------------------------------------------- 7. package cycles
def _import_graph_module():
    """tests/test_import_graph.py: the module-level import graph (every import, function bodies included)."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("pdehead_import_graph", Path(__file__).resolve().parents[1]
                                                  / "tests" / "test_import_graph.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module               # dataclasses look their module up while it loads
    spec.loader.exec_module(module)
    return module


def package_of(module: str) -> str:
    """The package a module belongs to for the package graph: ``pdehead_addon.curves.boundaries`` ->
    ``pdehead_addon.curves``; a module directly in ``pdehead_addon/`` or ``operators/`` (or the extension's
    root) is its own node."""
    parts = module.split(".")
    if len(parts) >= 2 and (ROOT / parts[0] / parts[1]).is_dir():
        return ".".join(parts[:2])
    return module


def package_cycles() -> list[dict]:
    """Strongly connected groups of packages: each a list of packages and the imports that close the loop."""
    graph_mod = _import_graph_module()
    graph = graph_mod.build_graph(ROOT, SHIPPED)
    succ: dict[str, dict[str, list[str]]] = {package_of(m): {} for m in graph.files}
    for e in graph.project_edges():
        a, b = package_of(e.source), package_of(e.target)
        if a != b:
            succ[a].setdefault(b, []).append(f"{graph.label(e.source)}:{e.line} -> {e.target}")
    out = []
    for comp in graph_mod.strong_components(succ):
        if len(comp) > 1:
            members = set(comp)
            out.append({"packages": comp, "imports": sorted(i for a in comp for b, imps in succ[a].items()
                                                             if b in members for i in imps)})
    return out


# ------------------------------------------------------------------------------------------- 8. mutable state
MUTATORS = {"append", "extend", "insert", "add", "update", "setdefault", "pop", "popitem", "clear", "remove",
            "discard", "__setitem__"}
CONTAINER_CALLS = {"dict", "list", "set", "defaultdict", "OrderedDict", "deque", "WeakKeyDictionary",
                   "WeakValueDictionary", "WeakSet", "Counter"}


def _is_container(value: ast.expr) -> bool:
    if isinstance(value, (ast.Dict, ast.List, ast.Set, ast.DictComp, ast.ListComp, ast.SetComp)):
        return True
    if isinstance(value, ast.Call):
        f = value.func
        name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
        return name in CONTAINER_CALLS
    return False


def _top_level_names(tree: ast.Module) -> dict[str, tuple[int, bool]]:
    """Names a module binds at its top level: name -> (line, bound to a mutable container)."""
    names = {}
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] \
            if isinstance(node, ast.AnnAssign) and node.value is not None else []
        for t in targets:
            if isinstance(t, ast.Name):
                names[t.id] = (node.lineno, _is_container(node.value))
    return names


def _written_from_outside(trees: dict[Path, ast.AST]) -> dict[tuple[str, str], str]:
    """``m.name = ...``, ``m.name[k] = ...`` and ``m.name.append(...)`` anywhere: (m's last dotted
    component, name) -> the first place it happens."""
    out = {}
    for path, tree in trees.items():
        for node in ast.walk(tree):
            attr = None
            if isinstance(node, ast.Attribute) and isinstance(node.ctx, (ast.Store, ast.Del)):
                attr = node
            elif isinstance(node, ast.Subscript) and isinstance(node.ctx, (ast.Store, ast.Del)) \
                    and isinstance(node.value, ast.Attribute):
                attr = node.value
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                    and node.func.attr in MUTATORS and isinstance(node.func.value, ast.Attribute):
                attr = node.func.value
            if attr is None:
                continue
            base = attr.value
            owner = base.id if isinstance(base, ast.Name) else base.attr if isinstance(base, ast.Attribute) else None
            if owner not in (None, "self", "cls"):
                out.setdefault((owner, attr.attr), f"{rel(path)}:{node.lineno}")
    return out


def module_mutable_state(folder: str = "operators") -> list[dict]:
    """Module-level state of ``folder``'s modules that is written after import: a module-level container
    the module writes (item assignment or deletion, a mutating method), a name written through ``global``
    in a function, and a module-level name another module (operators/ or scripts/) writes as
    ``module.name = ...``, ``module.name[k] = ...`` or ``module.name.append(...)``."""
    trees = {p: ast.parse(p.read_text(encoding="utf-8")) for p in python_files(folder, "scripts")}
    outside = _written_from_outside(trees)
    out = []
    for path in python_files(folder):
        tree = trees[path]
        top = _top_level_names(tree)
        written, globals_ = set(), {}
        for node in ast.walk(tree):
            if isinstance(node, ast.Global):
                for name in node.names:
                    globals_.setdefault(name, node.lineno)
            elif isinstance(node, ast.Subscript) and isinstance(node.ctx, (ast.Store, ast.Del)) \
                    and isinstance(node.value, ast.Name):
                written.add(node.value.id)
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                    and node.func.attr in MUTATORS and isinstance(node.func.value, ast.Name):
                written.add(node.func.value.id)
        found = {}
        for name, (line, container) in top.items():
            if container and name in written:
                found[name] = {"where": f"{rel(path)}:{line}", "name": name, "kind": "module-level container written"}
            elif (path.stem, name) in outside:
                found[name] = {"where": f"{rel(path)}:{line}", "name": name,
                               "kind": f"written from {outside[(path.stem, name)]}"}
        for name, line in globals_.items():
            found.setdefault(name, {"where": f"{rel(path)}:{line}", "name": name, "kind": "global write"})
        out.extend(found.values())
    return sorted(out, key=lambda i: i["where"])


# ------------------------------------------------------------------------------------------- 9. settings twice
def _bpy_properties(cls: ast.ClassDef) -> dict[str, str]:
    """Names annotated with a ``*Property(...)`` call in a class body, with the property's type."""
    out = {}
    for node in cls.body:
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and isinstance(node.annotation,
                                                                                                 ast.Call):
            f = node.annotation.func
            name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
            if name.endswith("Property"):
                out[node.target.id] = name
    return out


def _base_names(cls: ast.ClassDef) -> set[str]:
    return {b.id if isinstance(b, ast.Name) else b.attr if isinstance(b, ast.Attribute) else "" for b in cls.bases}


def settings_declared_twice(folder: str = "operators") -> list[dict]:
    """Properties of a PropertyGroup (a study's settings) that an Operator declares again.

    Again means under the same name as the same type of property. Two properties that share a name but
    not a type are two settings, not one written twice: the study's ``source`` (a StringProperty, the
    folder or file its CT was read from) and Run Pipeline's ``source`` (an EnumProperty, where to take
    the CT from) hold different values, and neither name can change (saved files and users' scripts
    read them).
    """
    groups: dict[tuple[str, str], list[str]] = {}
    operators: dict[tuple[str, str], list[str]] = {}
    for path in python_files(folder):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.ClassDef):
                continue
            bases = _base_names(node)
            into = groups if "PropertyGroup" in bases else operators if "Operator" in bases else None
            if into is not None:
                for name, kind in _bpy_properties(node).items():
                    into.setdefault((name, kind), []).append(f"{rel(path)}:{node.name}")
    return [{"setting": n, "group": groups[(n, k)], "operators": operators[(n, k)]}
            for n, k in sorted(groups) if (n, k) in operators]


# ------------------------------------------------------------------------------------------- 10. issue numbers
ISSUE_REF = re.compile(r"\bissues?\s+#?\d+", re.IGNORECASE)


def issue_references(folders=SHIPPED + ("__init__.py",)) -> list[dict]:
    """"issue N" in the comments and strings of the shipped code."""
    import io
    import tokenize
    out = []
    paths = [p for f in folders for p in ([ROOT / f] if f.endswith(".py") else python_files(f))]
    for path in paths:
        with open(path, encoding="utf-8") as fh:
            for tok in tokenize.generate_tokens(io.StringIO(fh.read()).readline):
                if tok.type in (tokenize.COMMENT, tokenize.STRING):
                    for m in ISSUE_REF.finditer(tok.string):
                        line = tok.start[0] + tok.string[:m.start()].count("\n")
                        out.append({"where": f"{rel(path)}:{line}", "text": m.group(0)})
    return out


# ------------------------------------------------------------------------------------------- 11, 12. README, ruff
def readme_lines() -> int:
    return len((ROOT / "README.md").read_text(encoding="utf-8").splitlines())


def ruff_findings() -> list[dict]:
    """``ruff check`` of the whole repository with the configuration in pyproject.toml."""
    cmd = [sys.executable, "-m", "ruff", "check", "--output-format", "json", "--no-cache", str(ROOT)]
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if result.returncode not in (0, 1):
        raise RuntimeError(f"ruff failed: {result.stderr}")
    return [{"where": f"{rel(Path(i['filename']))}:{i['location']['row']}", "code": i["code"]}
            for i in json.loads(result.stdout or "[]")]


def ruff_ratchet() -> list[str]:
    """The files on the temporary per-file-ignores list of pyproject.toml."""
    import tomllib
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    return sorted(config.get("tool", {}).get("ruff", {}).get("lint", {}).get("per-file-ignores", {}))


#: The study entity classes (file, class) whose base classes :func:`study_entity_mixins` counts.
STUDY_ENTITIES = (("operators/study/entity.py", "Study"), ("operators/forensic/study.py", "ForensicStudy"))


def study_entity_mixins() -> list[dict]:
    """The base classes of each study entity class: one entry per (class, base)."""
    out = []
    for file, name in STUDY_ENTITIES:
        path = ROOT / file
        if not path.is_file():
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef) and node.name == name:
                out.extend({"class": name, "base": base, "where": f"{file}:{node.lineno}"}
                           for base in sorted(_base_names(node) - {"object", ""}))
    return out


def cli_operator_calls(file: str = "scripts/pdehead.py") -> list[dict]:
    """Where the CLI drives a step through an operator (``bpy.ops.pdehead``) or reads an operator's failure
    through the registry (``last_exception``)."""
    path = ROOT / file
    if not path.is_file():
        return []
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Attribute) and (
                node.attr == "last_exception" or (node.attr == "pdehead" and isinstance(node.value, ast.Attribute)
                                                  and node.value.attr == "ops")):
            out.append({"where": f"{file}:{node.lineno}", "name": node.attr, "line": node.lineno})
    return sorted(out, key=lambda i: i["line"])


# ------------------------------------------------------------------------------------------- 15. deferred imports
DEFERRED_REASON = re.compile(r"#\s*deferred:\s*\S")


def _own_nodes(fn: ast.AST):
    """The nodes of a function's body, not those of the functions nested in it (they are walked on their own)."""
    stack = list(fn.body)
    while stack:
        node = stack.pop()
        yield node
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            stack.extend(ast.iter_child_nodes(node))


def unexplained_function_imports(folders=SHIPPED) -> list[dict]:
    """Imports inside a function body (methods and nested functions too) with no ``# deferred: <why>``
    comment on any of their lines."""
    out = []
    for path in python_files(*folders):
        source = path.read_text(encoding="utf-8")
        lines = source.splitlines()
        for fn in ast.walk(ast.parse(source)):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in _own_nodes(fn):
                if not isinstance(node, (ast.Import, ast.ImportFrom)):
                    continue
                if not any(DEFERRED_REASON.search(lines[i - 1]) for i in range(node.lineno, node.end_lineno + 1)):
                    names = ", ".join(a.name for a in node.names)
                    what = f"from {'.' * node.level}{node.module or ''} import {names}" \
                        if isinstance(node, ast.ImportFrom) else f"import {names}"
                    out.append({"where": f"{rel(path)}:{node.lineno}", "function": fn.name, "import": what})
    return sorted(out, key=lambda i: (i["where"].split(":")[0], int(i["where"].split(":")[1])))


def measures() -> dict:
    return {
        "modules_over_limit": long_modules(),
        "complex_functions": complex_functions(SHIPPED + ("__init__.py",)),
        "complex_functions_scripts": complex_functions(("scripts",)),
        "private_imports": private_imports(SHIPPED),
        "private_imports_scripts": private_imports(("scripts",)),
        "operators_internal_engine_imports": internal_engine_imports(),
        "private_attribute_uses": private_attribute_uses(),
        "duplicate_blocks": duplicate_blocks(),
        "zip": shipped_validation(),
        "package_cycles": package_cycles(),
        "operators_mutable_state": module_mutable_state(),
        "settings_declared_twice": settings_declared_twice(),
        "issue_references": issue_references(),
        "readme_lines": readme_lines(),
        "ruff_findings": ruff_findings(),
        "ruff_ratchet_files": ruff_ratchet(),
        "study_entity_mixins": study_entity_mixins(),
        "cli_operator_calls": cli_operator_calls(),
        "unexplained_function_imports": unexplained_function_imports(),
    }


def report(m: dict) -> str:
    lines = []

    def section(title, items, fmt):
        lines.append(f"{title}: {len(items)}")
        lines.extend("  " + fmt(i) for i in items)

    section(f"modules over {MAX_LINES} lines [target 0]",
            m["modules_over_limit"], lambda i: f"{i['module']}: {i['lines']}")
    section(f"functions over complexity {MAX_COMPLEXITY} in pdehead_addon/ and operators/ (ruff C901) [target 0]",
            m["complex_functions"], lambda i: f"{i['where']} {i['function']}: {i['complexity']}")
    section(f"functions over complexity {MAX_COMPLEXITY} in scripts/", m["complex_functions_scripts"],
            lambda i: f"{i['where']} {i['function']}: {i['complexity']}")
    def distinct(items, key):
        return len({(i["where"].split(":")[0], i[key]) for i in items})

    for key, where in (("private_imports", "pdehead_addon/ and operators/"), ("private_imports_scripts", "scripts/")):
        section(f"uses of another module's private name in {where} ({distinct(m[key], 'name')} distinct "
                f"file-name pairs) [target 0]", m[key], lambda i: f"{i['where']} {i['name']} of {i['of']}")
    items = m["operators_internal_engine_imports"]
    files = {i["where"].split(":")[0] for i in items}
    section(f"imports of the engine's internal modules by operators/ ({distinct(items, 'module')} distinct "
            f"file-module pairs in {len(files)} files) [target 0]", items, lambda i: f"{i['where']} {i['module']}")
    section(f"repeated blocks of {MIN_SIMILAR}+ lines in pdehead_addon/ (pylint duplicate-code) [target 0]",
            m["duplicate_blocks"], lambda i: f"{i['lines']} lines: " + ", ".join(i["where"]))
    section("uses of another module's private attribute in pdehead_addon/ and operators/ [target 0]",
            m["private_attribute_uses"], lambda i: f"{i['where']} {i['name']} (defined in {', '.join(i['of'])})")
    section("import cycles between packages [target 0]", m["package_cycles"],
            lambda i: " <-> ".join(i["packages"]) + ": " + "; ".join(i["imports"]))
    section("module-level mutable state in operators/ [target 0]", m["operators_mutable_state"],
            lambda i: f"{i['where']} {i['name']}: {i['kind']}")
    section("settings declared on a PropertyGroup and again on an Operator [target 0]",
            m["settings_declared_twice"], lambda i: f"{i['setting']}: {i['group']} and {i['operators']}")
    section('"issue N" in the shipped code [target 0]', m["issue_references"],
            lambda i: f"{i['where']} {i['text']}")
    lines.append(f"README.md lines [target <= {MAX_README_LINES}]: {m['readme_lines']}")
    section("ruff findings [target 0]", m["ruff_findings"], lambda i: f"{i['where']} {i['code']}")
    section("files on ruff's temporary per-file-ignores ratchet (pyproject.toml) [target 0]",
            m["ruff_ratchet_files"], str)
    section("mixin base classes of the study entity classes [target 0]", m["study_entity_mixins"],
            lambda i: f"{i['class']}({i['base']})")
    section("CLI steps driven through operators (scripts/pdehead.py) [target 0]", m["cli_operator_calls"],
            lambda i: f"{i['where']} {i['name']}")
    section("imports inside functions without a '# deferred: <why>' comment in pdehead_addon/ and operators/ "
            "[target 0]", m["unexplained_function_imports"], lambda i: f"{i['where']} {i['function']}: {i['import']}")
    z = m["zip"]
    lines.append(f"the extension zip carries validation code [target no]: {'yes' if z['carries_validation'] else 'no'}"
                 + (f" ({', '.join(z['files'])})" if z["files"] else ""))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true", help="print the measures as JSON")
    args = ap.parse_args(argv)
    m = measures()
    print(json.dumps(m, indent=1) if args.json else report(m))
    return 0


if __name__ == "__main__":
    sys.exit(main())
