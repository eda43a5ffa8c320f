"""The layout table of docs/development.md is the tree: every engine subpackage has a row, and the row names
each of its modules (and nothing that is not there)."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ENGINE = ROOT / "pdehead_addon"


def layout_rows() -> dict[str, str]:
    text = (ROOT / "docs" / "development.md").read_text(encoding="utf-8")
    section = text.split("## Layout", 1)[1].split("\n## ", 1)[0]
    return {m.group(1): m.group(2) for m in re.finditer(r"^\| `(pdehead_addon/[\w/]*)` \| (.*) \|$", section, re.M)}


def subpackages() -> list[Path]:
    return sorted(p for p in ENGINE.iterdir() if (p / "__init__.py").is_file())


def test_every_subpackage_has_a_row_naming_its_modules():
    rows = layout_rows()
    assert subpackages(), "no engine subpackages found"
    for pkg in subpackages():
        key = f"pdehead_addon/{pkg.name}/"
        assert key in rows, f"docs/development.md layout table has no row for {key}"
        named = set(re.findall(r"`(\w+)`", rows[key]))
        modules = {p.stem for p in pkg.rglob("*.py") if p.stem != "__init__" and "__pycache__" not in p.parts} | {
            p.parent.name for p in pkg.rglob("__init__.py") if p.parent != pkg}
        assert modules - named == set(), f"{key}: docs/development.md does not name {sorted(modules - named)}"
        assert named - modules == set(), f"{key}: docs/development.md names {sorted(named - modules)}, not in the tree"
    assert set(rows) - {"pdehead_addon/"} == {f"pdehead_addon/{p.name}/" for p in subpackages()}


def test_test_folders_mirror_the_subpackages():
    tests = ROOT / "tests"
    folders = {p.name for p in tests.iterdir() if p.is_dir() and p.name not in ("blender", "fixtures", "__pycache__")
               and not p.name.startswith(".")}
    assert folders and folders <= {p.name for p in subpackages()}, folders


def test_the_engine_top_level_is_only_the_api_and_the_defaults():
    top = sorted(p.name for p in ENGINE.glob("*.py"))
    assert top == ["__init__.py", "defaults.py"], top


def test_the_scripts_rows_name_every_script():
    """The `scripts/` and `scripts/bench/` rows name each script in that folder, and nothing that is not there."""
    text = (ROOT / "docs" / "development.md").read_text(encoding="utf-8")
    section = text.split("## Layout", 1)[1].split("\n## ", 1)[0]
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| `(scripts/[\w/]*)` \| (.*) \|$", section, re.M)}
    assert set(rows) == {"scripts/", "scripts/bench/"}, sorted(rows)
    for key, row in rows.items():
        named = set(re.findall(r"`(\w+\.(?:py|sh))`", row))
        files = {p.name for p in (ROOT / key).iterdir() if p.suffix in (".py", ".sh")}
        assert files - named == set(), f"{key}: docs/development.md does not name {sorted(files - named)}"
        assert named - files == set(), f"{key}: docs/development.md names {sorted(named - files)}, not in the folder"


def test_every_operators_subpackage_has_a_row_naming_its_modules():
    """The `operators/<concern>/` rows name each module of that subpackage, and nothing that is not there."""
    text = (ROOT / "docs" / "development.md").read_text(encoding="utf-8")
    section = text.split("## Layout", 1)[1].split("\n## ", 1)[0]
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| `(operators/\w+/)` \| (.*) \|$", section, re.M)}
    packages = sorted(p for p in (ROOT / "operators").iterdir() if (p / "__init__.py").is_file())
    assert packages and set(rows) == {f"operators/{p.name}/" for p in packages}, sorted(rows)
    for pkg in packages:
        named = set(re.findall(r"`(\w+)`", rows[f"operators/{pkg.name}/"]))
        modules = {p.stem for p in pkg.glob("*.py") if p.stem != "__init__"}
        assert modules - named == set(), f"operators/{pkg.name}/: the layout does not name {sorted(modules - named)}"
        words = {"Study", "ForensicStudy", "EngineJob", "REGISTRY", "execute"}     # named, but not modules
        assert named - words <= modules, f"operators/{pkg.name}/: the layout names {sorted(named - words - modules)}"
