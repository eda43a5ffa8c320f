"""A file saved by an earlier version reopens with everything it had, and stays live.

``data/forensic_0.1.0.blend`` was saved by ``make_forensic_fixture.py`` (the version of 2026-12-02,
before the architecture step of issue 25, on Blender 5.0.1): two phantom studies, one with the
pipeline only, one with the bone skull, automatic landmarks and the face from the skull through its
pegs (one peg dragged). Its manifest ``forensic_0.1.0.json`` holds what the file held when it was saved.
A refactor that renames modules, classes or stored keys fails here.

The forensic state of that file (format 0: JSON custom properties of the collection) is read into the
study's forensic PropertyGroup when the file is loaded (format 1, ``operators/forensic/props.py``): the
custom properties it had are gone and the group holds their exact contents (the JSON the old version
wrote is rebuilt from the group and has the SHA-256 the manifest recorded).
"""
from __future__ import annotations

import hashlib
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import make_forensic_fixture as maker  # tests/blender/make_forensic_fixture.py

DATA = Path(__file__).resolve().parent / "data"
BLEND = DATA / "forensic_0.1.0.blend"


@pytest.fixture()
def reopened(pdehead_ext, tmp_path):
    """The fixture opened from a copy (the repository's file is never written)."""
    import bpy
    if bpy.app.version[:2] < (5, 0):
        pytest.skip("the fixture was saved by Blender 5.0.1, a newer file format than this Blender reads")
    blend = tmp_path / BLEND.name
    shutil.copy(BLEND, blend)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    state = sys.modules[f"{pdehead_ext.__name__}.operators.state"]
    return bpy, state, json.loads(BLEND.with_suffix(".json").read_text())


def _sha(text: str) -> str:
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()


def _legacy_json(props, p) -> dict:
    """The custom properties of format 0 rebuilt from a study's forensic PropertyGroup ``p`` (as 0.1.0 wrote them)."""
    out = {}
    if p.depth_table:
        out[props.LEGACY_DEPTH_TABLE] = p.depth_table
    if len(p.landmark_flags):
        out[props.LEGACY_LANDMARK_FLAGS] = json.dumps({f.name: [f.flag, f.evidence] for f in p.landmark_flags})
    if p.face_build:
        out[props.LEGACY_FACE_OPTIONS] = json.dumps(props.face_options_of(p))
    return out


def test_every_study_reopens_with_its_settings_objects_and_forensic_state(reopened):
    bpy, state, saved = reopened
    props = sys.modules[state.__name__.rpartition(".")[0] + ".forensic.props"]
    legacy = (props.LEGACY_DEPTH_TABLE, props.LEGACY_LANDMARK_FLAGS, props.LEGACY_FACE_OPTIONS)
    # the forensic state of format 0, read into the PropertyGroup on load: nothing lost, byte for byte
    for name, was in saved["studies"].items():
        coll = bpy.data.collections[name]
        p = props.forensic_settings(coll)
        assert p.format_version == props.FORMAT_VERSION == 1, name
        assert not any(key in coll for key in legacy), name
        rebuilt = {key: _sha(text) for key, text in _legacy_json(props, p).items()}
        assert rebuilt == {key: v for key, v in was["custom"].items() if key in legacy}, name
    p = props.forensic_settings(bpy.data.collections["Phantom forensic"])
    assert len(p.landmark_flags) == 50 and len(p.face_pegs) == 36 and p.depth_table_name.startswith("T-Table 2023")
    now = maker.manifest(bpy, state)
    assert now["active_study"] == saved["active_study"] == "Phantom forensic"
    assert sorted(now["studies"]) == sorted(saved["studies"]) == ["Phantom forensic", "Phantom pipeline only"]
    for name, was in saved["studies"].items():
        study = now["studies"][name]
        assert {k: v for k, v in study["settings"].items() if k in was["settings"]} == was["settings"], name
        assert set(was["settings"]) <= set(study["settings"]), name
        # settings added since the file was saved (the CT detail map's) come up at their declared defaults
        rna = bpy.data.collections[name].pdehead.bl_rna.properties
        added = {k: v for k, v in study["settings"].items() if k not in was["settings"]}
        assert added == {k: rna[k].default for k in added}, (name, added)
        # the rest of the collection's custom properties: derived caches, CT table, face model
        assert study["custom"] == {k: v for k, v in was["custom"].items() if k not in legacy}, name
        assert study["children"] == was["children"], name
        assert sorted(study["objects"]) == sorted(was["objects"]), name
        for obj_name, obj in was["objects"].items():
            got = study["objects"][obj_name]
            assert (got["type"], got["parent"], got["custom"]) == (obj["type"], obj["parent"], obj["custom"]), obj_name
            for key in ("vertices", "faces"):
                assert got.get(key) == obj.get(key), (obj_name, key)
            for key in ("centroid_mm", "location_mm"):
                if key in obj:
                    np.testing.assert_allclose(got[key], obj[key], atol=1e-3, err_msg=obj_name)
    forensic = saved["studies"]["Phantom forensic"]["objects"]
    assert sum(1 for o in forensic.values() if "pdehead_peg" in o["custom"]) == 36
    assert sum(1 for o in forensic.values() if "pdehead_landmark" in o["custom"]) == 50


def _to_face(obj, vertices_mm, point_mm) -> float:
    """Distance (mm) of a point to the mesh of ``obj`` with its vertices at ``vertices_mm``."""
    from pdehead_addon.validation.surface_metrics import point_surface_distance
    obj.data.calc_loop_triangles()
    tri = np.empty(len(obj.data.loop_triangles) * 3, np.int64)
    obj.data.loop_triangles.foreach_get("vertices", tri)
    return float(point_surface_distance(np.asarray(point_mm, float)[None], vertices_mm, tri.reshape(-1, 3))[0])


def test_the_reopened_face_follows_a_dragged_peg_and_both_studies_stay_live(reopened):
    bpy, state, _ = reopened
    from mathutils import Vector
    face_ops = sys.modules[state.__name__.rpartition(".")[0] + ".study.face_handler"]
    coll = bpy.data.collections["Phantom forensic"]
    face = next(o for o in coll.all_objects if o.name.endswith(" Face"))
    peg = next(o for o in coll.all_objects if o.get("pdehead_peg") == "Nasion")
    # The first drag may re-prepare the face model (a model kept by another version is refused and
    # made again by this one): the face then passes through the dragged peg's tip.
    peg.matrix_world.translation += Vector((0.0, 0.003, 0.0))  # back by the 3 mm it was dragged forward
    bpy.context.view_layer.update()
    assert state.settings(coll).last_error == ""
    fs = face_ops.forensic_of(coll)
    tip = fs.face.peg_tips(["Nasion"])[0]
    before = maker.world_mm(face)
    assert _to_face(face, before, tip) < 1.0                        # 0.49 mm measured
    # and follows the next drag at once: at the peg (and the nose it carries), nowhere else
    peg.matrix_world.translation += Vector((0.0, -0.002, 0.0))
    bpy.context.view_layer.update()
    after = maker.world_mm(face)
    moved = np.linalg.norm(after - before, axis=1)
    # up to 4.61 mm measured since issue 23's sixth session: the nose it carries has a near-horizontal underside
    # (the columella, the alae), where a ray of the radial face meets the moved nose further along than 2 mm
    assert 1.0 < moved.max() < 6.0
    tip = fs.face.peg_tips(["Nasion"])[0]
    # the skin at the peg came to the tip (measured on this 48 x 80 face: 2.07 -> 1.06 mm; the mesh's
    # facets between its rows cut the narrow bump the 2 mm drag makes)
    gap_before, gap_after = _to_face(face, before, tip), _to_face(face, after, tip)
    assert gap_after < 1.5 and gap_before - gap_after > 0.8
    assert np.median(moved) < 0.01

    other = bpy.data.collections["Phantom pipeline only"]
    s = state.settings(other)
    s.nv = 48
    assert s.last_error == "" and len(s.surface_object.data.vertices) > 953


def test_forensic_state_of_format_0_is_read_into_the_property_group(pdehead_ext):
    """The migration alone (any Blender, no fixture file): format-0 custom properties -> the PropertyGroup."""
    import bpy
    props = sys.modules[f"{pdehead_ext.__name__}.operators.forensic.props"]
    from pdehead_addon.forensic.depth_table import default_table
    coll = bpy.data.collections.new("format 0")
    table = default_table().to_json()
    flags = {"Nasion": ["ok", ""], "Menton": ["not_found", "no mandible in the bone mask"]}
    opts = dict(build="b" * 32, table=table, sex="female", options={}, flags={"Nasion": "ok"},
                landmarks={"Nasion": [1.0000000001, -80.25, 12.5]}, pegs=["Nasion"])
    coll[props.LEGACY_DEPTH_TABLE] = table
    coll[props.LEGACY_LANDMARK_FLAGS] = json.dumps(flags)
    coll[props.LEGACY_FACE_OPTIONS] = json.dumps(opts)
    p = props.forensic_settings(coll)
    assert p.format_version == 0
    assert props.migrate(coll) is True
    assert p.format_version == 1 and not any(k.startswith("pdehead_") for k in coll.keys() if k != props.PROP)
    assert p.depth_table == table and p.depth_table_name == default_table().label
    assert {f.name: [f.flag, f.evidence] for f in p.landmark_flags} == flags
    assert props.face_options_of(p) == opts                     # float64 landmarks kept exactly
    assert json.dumps(props.face_options_of(p)) == json.dumps(opts)
    assert props.migrate(coll) is False                         # once only
    bpy.data.collections.remove(coll)
