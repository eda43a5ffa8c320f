#!/usr/bin/env python3
"""Two measures of the Blender layer (``operators/``) as one study entity, read from the source (no bpy).

    python scripts/study_measures.py            # the measures as text
    python scripts/study_measures.py --json     # the same as JSON

1. **Settings declared twice**: a parameter of ``pdehead_addon/defaults.py`` written out as a property
   (``name: XProperty(... D.NAME ...)``) under its own name by more than one class of ``operators/`` (the
   study's property group and an operator that mirrors it, say). Properties generated from the one table
   (``operators/study/props.py``'s ``SETTINGS``) are written out nowhere else.
2. **Module-level mutable state**: a module-level name (or an attribute of a module-level class) bound to a
   dict, list or set (a literal, a comprehension or a call of ``dict``/``list``/``set``/``defaultdict``/
   ``WeakKeyDictionary``/...) that the code writes (item assignment or deletion, a mutating method), a
   ``global`` statement whose name a function assigns, and an assignment to another project module's
   attribute (``state.audience = ...``). The one registry (``operators/state.py``'s ``REGISTRY``, an
   instance of its ``Registry`` class) is where this state lives instead: attributes of an instance are not
   counted.

Both are meant to be 0 (see tests/test_study_measures.py for what is held today).
"""
from __future__ import annotations

import argparse
import ast
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OPERATORS = "operators"

MUTABLE_CALLS = {"dict", "list", "set", "defaultdict", "OrderedDict", "WeakKeyDictionary", "WeakValueDictionary",
                 "WeakSet", "deque", "Counter"}
MUTATING_METHODS = {"append", "extend", "insert", "add", "update", "pop", "popitem", "clear", "setdefault",
                    "remove", "discard", "appendleft", "popleft"}


def _modules(root: Path, folder: str) -> list[Path]:
    return sorted(p for p in (root / folder).rglob("*.py") if "__pycache__" not in p.parts)


def _name(node) -> str:
    """The last name of ``a.b.c`` / ``c``."""
    if isinstance(node, ast.Attribute):
        return node.attr
    if isinstance(node, ast.Name):
        return node.id
    return ""


def _is_property_call(node) -> bool:
    return isinstance(node, ast.Call) and _name(node.func).endswith("Property")


def _param_names(root: Path) -> dict[str, str]:
    """``{"PATCHES": "patches", ...}``: the module attributes of ``pdehead_addon/defaults.py`` bound to
    ``_param("name", ...)``."""
    tree = ast.parse((root / "pdehead_addon" / "defaults.py").read_text(encoding="utf-8"))
    out = {}
    for stmt in tree.body:
        if (isinstance(stmt, ast.Assign) and isinstance(stmt.value, ast.Call) and _name(stmt.value.func) == "_param"
                and stmt.value.args and isinstance(stmt.value.args[0], ast.Constant)):
            out.update({t.id: stmt.value.args[0].value for t in stmt.targets if isinstance(t, ast.Name)})
    return out


def _class_declarations(tree: ast.Module, params: dict[str, str]):
    """(class name, property name) of every class attribute ``name: XProperty(...)`` that reads the defaults
    table's parameter of the same name (``D.NAME``)."""
    for node in ast.walk(tree):
        if not isinstance(node, ast.ClassDef):
            continue
        for stmt in node.body:
            if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
                continue
            call = stmt.annotation if _is_property_call(stmt.annotation) else stmt.value
            if not _is_property_call(call):
                continue
            read = {params.get(n.attr) for n in ast.walk(call) if isinstance(n, ast.Attribute)}
            if stmt.target.id in read:
                yield node.name, stmt.target.id


def settings_declared_twice(root: Path = ROOT) -> list[dict]:
    """Parameters of the defaults table declared as a property under their own name by more than one class
    of ``operators/`` (the study's property group and an operator, say).

    Returns one entry per setting, ``{"setting": name, "where": ["module:Class", ...]}``, sorted by name.
    """
    params = _param_names(root)
    where: dict[str, list[str]] = {}
    for path in _modules(root, OPERATORS):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        module = path.relative_to(root).as_posix()
        for cls, name in _class_declarations(tree, params):
            where.setdefault(name, []).append(f"{module}:{cls}")
    return [{"setting": name, "where": classes} for name, classes in sorted(where.items()) if len(classes) > 1]


def _is_mutable_value(node) -> bool:
    if isinstance(node, (ast.Dict, ast.List, ast.Set, ast.DictComp, ast.ListComp, ast.SetComp)):
        return True
    return isinstance(node, ast.Call) and _name(node.func) in MUTABLE_CALLS


def _module_level_bindings(tree: ast.Module) -> set[str]:
    names = set()
    for stmt in tree.body:
        targets, value = [], None
        if isinstance(stmt, ast.Assign):
            targets, value = stmt.targets, stmt.value
        elif isinstance(stmt, ast.AnnAssign) and stmt.value is not None:
            targets, value = [stmt.target], stmt.value
        if value is not None and _is_mutable_value(value):
            names |= {t.id for t in targets if isinstance(t, ast.Name)}
    return names


def _class_level_bindings(tree: ast.Module) -> set[tuple[str, str]]:
    """(class, attribute) of the module-level classes' attributes bound to a dict, list or set."""
    out = set()
    for cls in tree.body:
        if not isinstance(cls, ast.ClassDef):
            continue
        for stmt in cls.body:
            value = stmt.value if isinstance(stmt, (ast.Assign, ast.AnnAssign)) else None
            targets = stmt.targets if isinstance(stmt, ast.Assign) else [getattr(stmt, "target", None)]
            if value is not None and _is_mutable_value(value):
                out |= {(cls.name, t.id) for t in targets if isinstance(t, ast.Name)}
    return out


def _written_base(node) -> tuple[str, str] | None:
    """For ``X[...]`` / ``mod.X[...]`` / ``X.method(...)`` targets: (module alias or "", X)."""
    if isinstance(node, ast.Name):
        return "", node.id
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
        return node.value.id, node.attr
    return None


def _project_module_aliases(tree: ast.Module) -> set[str]:
    """Names bound by ``from . import x`` / ``from .. import x`` (modules of the project)."""
    aliases = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            for alias in node.names:
                aliases.add(alias.asname or alias.name)
    return aliases


def _targets(node) -> list:
    """What an assignment, augmented assignment or ``del`` writes to (nothing for other nodes)."""
    if isinstance(node, (ast.Assign, ast.Delete)):
        return node.targets
    if isinstance(node, (ast.AugAssign, ast.AnnAssign)):
        return [node.target]
    return []


def _global_writes(tree: ast.Module):
    """(name, line) of every assignment to a name a function declares ``global``."""
    for func in ast.walk(tree):
        if not isinstance(func, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        declared = {n for stmt in ast.walk(func) if isinstance(stmt, ast.Global) for n in stmt.names}
        for stmt in ast.walk(func):
            for t in _targets(stmt):
                if isinstance(t, ast.Name) and t.id in declared:
                    yield t.id, stmt.lineno


class _ModuleState:
    """The mutable bindings of one module of ``trees`` and who owns what a write reaches."""

    def __init__(self, where: str, tree: ast.Module, bindings: dict[str, set], by_stem: dict[str, str]):
        self.where, self.bindings, self.by_stem = where, bindings, by_stem
        self.aliases = _project_module_aliases(tree)
        self.by_attr = {attr: cls for cls, attr in _class_level_bindings(tree)}

    def class_owner(self, node) -> str | None:
        """``Class.attr`` when ``node`` is ``cls.attr`` / ``self.attr`` / ``Class.attr`` of a class attribute
        bound to a dict, list or set, else None."""
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.attr in self.by_attr
                and node.value.id in {"cls", "self", self.by_attr[node.attr]}):
            return f"{self.by_attr[node.attr]}.{node.attr}"
        return None

    def owner(self, node) -> tuple[str, str] | None:
        """(module, name) of the module-level mutable binding ``node`` (``X`` or ``mod.X``) names, or None."""
        base = _written_base(node)
        if base is None:
            return None
        alias, name = base
        if alias == "" and name in self.bindings[self.where]:
            return self.where, name
        module = self.by_stem.get(alias) if alias in self.aliases else None
        if module is not None and name in self.bindings[module]:
            return module, name
        return None

    def module_attribute(self, node) -> tuple[str, str] | None:
        """(module, attribute) when ``node`` is ``mod.attr`` of another project module, else None."""
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in self.aliases
                and node.value.id in self.by_stem):
            return self.by_stem[node.value.id], node.attr
        return None

    def writes(self, node):
        """(module, name, kind) of each write of mutable state ``node`` makes."""
        for t in _targets(node):
            if isinstance(t, ast.Subscript):
                if self.class_owner(t.value):
                    yield self.where, self.class_owner(t.value), "class attribute item write"
                if self.owner(t.value):
                    yield (*self.owner(t.value), "item write")
            elif not isinstance(node, ast.Delete) and self.module_attribute(t):
                yield (*self.module_attribute(t), "attribute set from another module")
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in MUTATING_METHODS:
            if self.owner(node.func.value):
                yield (*self.owner(node.func.value), "mutating call")
            if self.class_owner(node.func.value):
                yield self.where, self.class_owner(node.func.value), "class attribute mutating call"


def module_mutable_state(root: Path = ROOT, folder: str = OPERATORS) -> list[dict]:
    """Module-level mutable state of ``folder`` that is written; one entry per (module, name, kind)."""
    trees = {p.relative_to(root).as_posix(): ast.parse(p.read_text(encoding="utf-8"))
             for p in _modules(root, folder)}
    bindings = {where: _module_level_bindings(tree) for where, tree in trees.items()}
    by_stem = {Path(where).stem: where for where in trees}
    found: dict[tuple, dict] = {}
    for where, tree in trees.items():
        module = _ModuleState(where, tree, bindings, by_stem)
        writes = [(where, name, "global write", line) for name, line in _global_writes(tree)]
        writes += [(*w, node.lineno) for node in ast.walk(tree) for w in module.writes(node)]
        for owner, name, kind, line in writes:
            found.setdefault((owner, name, kind), {"module": owner, "name": name, "kind": kind, "line": line})
    return sorted(found.values(), key=lambda e: (e["module"], e["name"], e["kind"]))


def measures(root: Path = ROOT) -> dict:
    return {"settings_declared_twice": settings_declared_twice(root),
            "module_mutable_state": module_mutable_state(root)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print the measures as JSON")
    parser.add_argument("--root", type=Path, default=ROOT, help="the repository to measure (default: this one)")
    args = parser.parse_args(argv)
    m = measures(args.root)
    if args.json:
        print(json.dumps(m, indent=1))
        return 0
    twice = m["settings_declared_twice"]
    print(f"settings declared twice: {len(twice)}")
    for entry in twice:
        print(f"  {entry['setting']}: {', '.join(entry['where'])}")
    state = m["module_mutable_state"]
    names = sorted({(e["module"], e["name"]) for e in state})
    print(f"module-level mutable state in {OPERATORS}/: {len(names)} names")
    for module, name in names:
        kinds = sorted({e["kind"] for e in state if (e["module"], e["name"]) == (module, name)})
        print(f"  {module}: {name} ({', '.join(kinds)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
