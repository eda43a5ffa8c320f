"""Write ``tests/blender/data/forensic_<version>.blend`` and its manifest ``.json`` (not shipped).

The file a user of this version would have saved after the whole forensic route: two studies of the
built-in phantom (one with the pipeline only and a few settings changed, one with pipeline, bone
skull, automatic landmarks and the face from the skull with its pegs, one peg dragged 3 mm forward),
the second one active. The
manifest records what the file holds, read back from Blender before saving: every study's settings, its
objects, its custom properties (strings by their SHA-256), the landmarks and pegs in patient mm and the
face's vertices. ``test_forensic_fixture.py`` reopens the file with the version under test and checks
that all of it is still there and still live: a later version (a refactor in particular) must open what
this one saved.

Run from the repository root, with the venv of the Blender that saves it::

    PYTHONPATH=. ~/.cache/pdehead/venv-bpy5.0.1-py311/bin/python tests/blender/make_forensic_fixture.py \
        tests/blender/data/forensic_0.1.0.blend
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="pdehead-fixture-user-"))
ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))


def _plain(value):
    """An RNA or ID-property value as JSON (vectors as lists, IDs by name)."""
    if hasattr(value, "name") and hasattr(value, "users"):
        return value.name
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    try:
        return [_plain(v) for v in value]
    except TypeError:
        return str(value)


def settings_of(s) -> dict:
    """Every registered setting of a study (pointers by their target's name)."""
    out = {}
    for prop in s.bl_rna.properties:
        if prop.identifier in {"rna_type", "name"} or prop.type == 'COLLECTION':
            continue
        out[prop.identifier] = _plain(getattr(s, prop.identifier))
    return out


def custom_of(idblock) -> dict:
    """The custom properties of an ID: strings by SHA-256 (JSON states can be large), the rest as JSON."""
    out = {}
    for key in idblock.keys():
        if key in {"pdehead", "pdehead_forensic", "_RNA_UI"}:      # registered properties (Blender < 5.0 lists them)
            continue
        value = idblock[key]
        if isinstance(value, str):
            out[key] = "sha256:" + hashlib.sha256(value.encode()).hexdigest()
        else:
            out[key] = _plain(value.to_dict() if hasattr(value, "to_dict") else value)
    return out


def world_mm(obj):
    import numpy as np
    co = np.empty(len(obj.data.vertices) * 3, np.float64)
    obj.data.vertices.foreach_get("co", co)
    m = np.array(obj.matrix_world)
    return (co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]) / 0.001


def manifest(bpy, state) -> dict:
    studies = {}
    for coll in bpy.data.collections:
        if not state.is_study(coll):
            continue
        objects = {}
        for obj in coll.all_objects:
            entry = {"type": obj.type, "parent": obj.parent.name if obj.parent else None,
                     "custom": custom_of(obj)}
            if obj.type == 'MESH':
                v = world_mm(obj)
                entry.update(vertices=len(v), faces=len(obj.data.polygons),
                             centroid_mm=v.mean(axis=0).round(6).tolist())
            if obj.type == 'EMPTY':
                entry["location_mm"] = [round(c / 0.001, 6) for c in obj.matrix_world.translation]
            objects[obj.name] = entry
        studies[coll.name] = {"settings": settings_of(state.settings(coll)), "custom": custom_of(coll),
                              "children": sorted(c.name for c in coll.children), "objects": objects}
    return {"blender": list(bpy.app.version), "active_study": bpy.context.scene.pdehead.active_study.name,
            "studies": studies}


def main(out: Path) -> None:
    import _common
    addon = _common.load_addon(register=True)
    from importlib import import_module

    import bpy
    state = import_module(addon.__name__ + ".operators.state")
    # a small file: the face's mesh at 48 x 80 instead of the defaults (the sidebar has no such setting;
    # the model records it, so the face kept in the file is the one solved at that size)
    D = import_module(addon.__name__ + ".pdehead_addon.defaults")
    D.FACE_NU, D.FACE_NV = (dataclasses.replace(p, default=n) for p, n in ((D.FACE_NU, 48), (D.FACE_NV, 80)))
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 beside it
    out.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(out))
    small = dict(source='PHANTOM', patches=4, nu=24, nv=40, nw=3, build_volume=False)
    assert bpy.ops.pdehead.run_pipeline(**small) == {'FINISHED'}
    first = bpy.context.scene.pdehead.active_study
    first.name = "Phantom pipeline only"
    s = state.settings(first)
    s.v_range, s.colour_preset = (0.5, 5.0), 'xray'
    assert bpy.ops.pdehead.run_pipeline(**dict(small, patches=6, nu=40, nv=80)) == {'FINISHED'}
    coll = bpy.context.scene.pdehead.active_study
    coll.name = "Phantom forensic"
    assert bpy.ops.pdehead.build_skull(bone_step=4) == {'FINISHED'}  # a smaller file
    assert bpy.ops.pdehead.find_landmarks() == {'FINISHED'}
    assert bpy.ops.pdehead.build_face() == {'FINISHED'}
    from mathutils import Vector
    peg = next(o for o in coll.all_objects if o.get("pdehead_peg") == "Nasion")
    peg.matrix_world.translation += Vector((0.0, -0.003, 0.0))  # 3 mm anterior (patient -y)
    bpy.context.view_layer.update()
    bpy.ops.wm.save_mainfile(compress=True)
    data = manifest(bpy, state)
    out.with_suffix(".json").write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB) and {out.with_suffix('.json').name}: "
          f"{len(data['studies'])} studies, "
          f"{sum(len(v['objects']) for v in data['studies'].values())} objects")


if __name__ == "__main__":
    main(Path(sys.argv[1]).absolute())
