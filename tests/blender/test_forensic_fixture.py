"""A file saved by an earlier version reopens with everything it had, and stays live.

``data/forensic_0.1.0.blend`` was saved by ``make_forensic_fixture.py`` (the version of 2026-12-02,
before the architecture step of issue 25, on Blender 5.0.1): two phantom studies, one with the
pipeline only, one with the bone skull, automatic landmarks and the face from the skull through its
pegs (one peg dragged). Its manifest ``forensic_0.1.0.json`` holds what the file held when it was saved.
A refactor that renames modules, classes or stored keys fails here.
"""
from __future__ import annotations

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


def test_every_study_reopens_with_its_settings_objects_and_forensic_state(reopened):
    bpy, state, saved = reopened
    now = maker.manifest(bpy, state)
    assert now["active_study"] == saved["active_study"] == "Phantom forensic"
    assert sorted(now["studies"]) == sorted(saved["studies"]) == ["Phantom forensic", "Phantom pipeline only"]
    for name, was in saved["studies"].items():
        study = now["studies"][name]
        assert study["settings"] == was["settings"], name
        assert study["custom"] == was["custom"], name          # forensic state, CT table, face model
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
    face_ops = sys.modules[state.__name__.rsplit(".", 1)[0] + ".face"]
    coll = bpy.data.collections["Phantom forensic"]
    face = next(o for o in coll.all_objects if o.name.endswith(" Face"))
    peg = next(o for o in coll.all_objects if o.get("pdehead_peg") == "Nasion")
    # The first drag may re-prepare the face model (a model kept by another version is refused and
    # made again by this one): the face then passes through the dragged peg's tip.
    peg.matrix_world.translation += Vector((0.0, 0.003, 0.0))  # back by the 3 mm it was dragged forward
    bpy.context.view_layer.update()
    assert state.settings(coll).last_error == ""
    tip = face_ops.peg_tips(coll, ["Nasion"])[0]
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
    tip = face_ops.peg_tips(coll, ["Nasion"])[0]
    # the skin at the peg came to the tip (measured on this 48 x 80 face: 2.07 -> 1.06 mm; the mesh's
    # facets between its rows cut the narrow bump the 2 mm drag makes)
    gap_before, gap_after = _to_face(face, before, tip), _to_face(face, after, tip)
    assert gap_after < 1.5 and gap_before - gap_after > 0.8
    assert np.median(moved) < 0.01

    other = bpy.data.collections["Phantom pipeline only"]
    s = state.settings(other)
    s.nv = 48
    assert s.last_error == "" and len(s.surface_object.data.vertices) > 953
