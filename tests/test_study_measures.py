"""The Blender layer as one study entity, measured from the source (``scripts/study_measures.py``): every
study setting declared once (the defaults table generates the property group's and the operators' properties)
and no module-level mutable state in ``operators/``. Each measure is also shown to fail on a small made-up
tree."""
from __future__ import annotations

import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import study_measures  # noqa: E402


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    (tmp_path / "pdehead_addon").mkdir()
    (tmp_path / "pdehead_addon" / "defaults.py").write_text(
        'PATCHES = _param("patches", 15, min=1, max=60)\nNU = _param("nu", 120)\nSKULL_NU = _param("skull_nu", 0)\n')
    (tmp_path / "operators").mkdir()
    for name, text in files.items():
        (tmp_path / "operators" / name).write_text(textwrap.dedent(text))
    return tmp_path


def test_settings_declared_twice_are_counted_on_a_made_up_tree(tmp_path):
    root = _tree(tmp_path, {
        "props.py": """
            class Settings(bpy.types.PropertyGroup):
                patches: IntProperty(name=D.PATCHES.label, **D.PATCHES.limits())
                nu: IntProperty(**D.NU.limits())
                source: StringProperty(name="Source")
            """,
        "ops.py": """
            class OT_a(Operator):
                patches: IntProperty(name=D.PATCHES.label, **D.PATCHES.limits())
                source: EnumProperty(items=[])            # another meaning, same name: no table parameter
                nu: IntProperty(**D.SKULL_NU.limits())     # another parameter under the name nu
            class OT_b(Operator):
                patches: bpy.props.IntProperty(**D.PATCHES.limits())
            """})
    found = study_measures.settings_declared_twice(root)
    assert [e["setting"] for e in found] == ["patches"]
    assert found[0]["where"] == ["operators/ops.py:OT_a", "operators/ops.py:OT_b", "operators/props.py:Settings"]


def test_module_mutable_state_is_counted_on_a_made_up_tree(tmp_path):
    root = _tree(tmp_path, {
        "state.py": """
            _CACHE: dict = {}
            CONSTANT_TABLE = {"a": 1}          # never written: not state
            last_error = None
            _count = 0
            def remember(key, value):
                _CACHE[key] = value
            def bump():
                global _count
                _count += 1
            """,
        "progress.py": """
            HOOK = [None]
            PENDING = set()
            def later(x):
                PENDING.add(x)
            """,
        "ops.py": """
            from . import progress, state
            def run(exc):
                progress.HOOK[0] = print
                state.last_error = exc
                local = {}
                local["x"] = 1
            class Study:
                _registry: dict = {}
                KINDS = ("a", "b")
                @classmethod
                def of(cls, key):
                    cls._registry[key] = cls()
            class Registry:
                def __init__(self):
                    self.caches = {}
            REGISTRY = Registry()
            def remember(key):
                REGISTRY.caches[key] = 1          # the one registry: an instance's attribute
            """})
    found = {(e["module"], e["name"], e["kind"]) for e in study_measures.module_mutable_state(root)}
    assert found == {("operators/state.py", "_CACHE", "item write"),
                     ("operators/state.py", "_count", "global write"),
                     ("operators/progress.py", "PENDING", "mutating call"),
                     ("operators/progress.py", "HOOK", "item write"),
                     ("operators/state.py", "last_error", "attribute set from another module"),
                     ("operators/ops.py", "Study._registry", "class attribute item write")}


def test_no_study_setting_is_declared_twice():
    """The study's settings are declared once (``operators/study/props.py``'s ``SETTINGS`` over the defaults
    table);
    the forensic maximum depth (the forensic settings' and the Tissue Depth operator's) is the one left."""
    found = study_measures.settings_declared_twice()
    assert [e["setting"] for e in found] in ([], ["max_depth"]), found


def test_operators_keep_no_module_level_mutable_state():
    """Every study entity, its cache and the session's state live in ``operators/state.py``'s ``REGISTRY``
    (18 names in 11 modules before: caches, busy flags, the progress hook, the last exception, ...)."""
    assert study_measures.module_mutable_state() == []
