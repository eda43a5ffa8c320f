#!/usr/bin/env python3
"""The architecture measures of issue 25, printed (report only: nothing fails yet).

    python scripts/check_architecture.py            # the measures as text
    python scripts/check_architecture.py --json     # the same as JSON

Each measure and its target (issue 25, "Measured when done"), over the shipped code (``pdehead_addon/``,
``operators/``) unless said otherwise:

1. modules over 700 lines (target none; ``operators/ops.py`` over 600);
2. functions over complexity 20: ruff's C901 (mccabe) with max-complexity 20 (target none; scripts/ listed
   apart);
3. imports of another module's private name: ``from .x import _name`` and ``module._name`` of an imported
   project module (target none; scripts/ listed apart, tests/ may reach into internals); also the imports
   of the engine's internal modules by ``operators/`` (target: the engine's public names only);
4. repeated blocks of 6+ lines in the engine: ``pylint --disable=all --enable=duplicate-code
   --min-similarity-lines=6 pdehead_addon`` (target none);
5. whether the extension zip carries validation code: the sources ``scripts/build_extension.py`` stages,
   checked for the validation modules (metrics, surface quality, surface distances, the DICOM writer) or
   a ``validation`` package (target: not shipped).

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
MAX_LINES, MAX_LINES_OPS, MAX_COMPLEXITY, MIN_SIMILAR = 700, 600, 20, 6
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
        limit = MAX_LINES_OPS if rel(path) == "operators/ops.py" else MAX_LINES
        if n > limit:
            out.append({"module": rel(path), "lines": n, "limit": limit})
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


def measures() -> dict:
    return {
        "modules_over_limit": long_modules(),
        "complex_functions": complex_functions(SHIPPED + ("__init__.py",)),
        "complex_functions_scripts": complex_functions(("scripts",)),
        "private_imports": private_imports(SHIPPED),
        "private_imports_scripts": private_imports(("scripts",)),
        "operators_internal_engine_imports": internal_engine_imports(),
        "duplicate_blocks": duplicate_blocks(),
        "zip": shipped_validation(),
    }


def report(m: dict) -> str:
    lines = []

    def section(title, items, fmt):
        lines.append(f"{title}: {len(items)}")
        lines.extend("  " + fmt(i) for i in items)

    section(f"modules over {MAX_LINES} lines (operators/ops.py over {MAX_LINES_OPS}) [target 0]",
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
