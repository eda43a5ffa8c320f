"""Face from Skull in Blender (issue 23, points 2 and 5): Build Face, live pegs, table switch, undo, reopen.

One phantom study (pipeline, bone skull, automatic landmarks, face) is built once and saved; each test
reopens that file. A peg is dragged the way a script drags it (its location changed, then a depsgraph
update): the face's handler re-solves and rewrites the same mesh.
"""
from __future__ import annotations

import json
import sys

import numpy as np
import pytest


@pytest.fixture(scope="module")
def face_blend(pdehead_ext, tmp_path_factory):
    import bpy
    bpy.ops.wm.read_homefile(use_empty=True)
    blend = tmp_path_factory.mktemp("face") / "face.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=6, nu=40, nv=80, nw=4, voxel_size=6.0,
                                        build_volume=False) == {'FINISHED'}
    assert bpy.ops.pdehead.build_skull() == {'FINISHED'}
    assert bpy.ops.pdehead.find_landmarks() == {'FINISHED'}
    assert bpy.ops.pdehead.build_face() == {'FINISHED'}
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.read_homefile(use_empty=True)
    return blend


def _mods(pdehead_ext):
    """(the face module, a function giving a study collection's ForensicStudy, the state module)."""
    name = pdehead_ext.__name__
    forensic_study = sys.modules[f"{name}.operators.forensic.study"]
    study_entity = sys.modules[f"{name}.operators.study.entity"]

    def forensic(coll):
        return forensic_study.ForensicStudy.of(study_entity.Study.of(coll))
    return sys.modules[f"{name}.operators.forensic.face"], forensic, sys.modules[f"{name}.operators.state"]


def _world_vertices(obj) -> np.ndarray:
    """The object's vertices in patient mm (world / 0.001; no Frankfurt in these tests)."""
    co = np.empty(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", co)
    m = np.array(obj.matrix_world)
    return (co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]) / 0.001


def _open(blend):
    import bpy
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    coll = bpy.context.scene.pdehead.active_study
    return coll


def _drag(peg, delta_mm):
    """Move a peg as G does from a script: its location changed, then the depsgraph evaluated."""
    import bpy
    from mathutils import Vector
    peg.matrix_world.translation += Vector(np.asarray(delta_mm, float) * 0.001)
    bpy.context.view_layer.update()


def _nearest_peg_vertex_motion(before, after, tip, k=5):
    """(the k face vertices nearest ``tip`` before, how far the surface moved at each vertex (mm): its distance
    to the face after, and its distance from ``tip``). The face's caps may gain or lose a vertex between two
    solves, so the motion is measured to the nearest vertex of the face after, not vertex by vertex."""
    from scipy.spatial import cKDTree
    d = np.linalg.norm(before - tip, axis=1)
    near = np.zeros(len(d), bool)
    near[np.argsort(d)[:k]] = True
    return near, cKDTree(after).query(before)[0], d


def test_build_face_and_live_pegs(pdehead_ext, face_blend, tmp_path):
    import bpy
    face, fs, state = _mods(pdehead_ext)
    coll = _open(face_blend)
    obj = fs(coll).face.face_object()
    # the face: its own object in the study, shaded smooth, closed, with the label and provenance on it
    assert obj is not None and obj.name in coll.objects and obj["pdehead_kind"] == "face"
    me = obj.data
    assert len(me.vertices) > 1000 and all(p.use_smooth for p in me.polygons[:50])
    assert obj[face.LABEL_PROP] == "approximation — not an identification"
    prov = json.loads(obj[face.PROVENANCE_PROP])
    assert prov["label"] == obj[face.LABEL_PROP] and prov["table"].startswith("T-Table 2023")
    assert prov["software"].startswith("PDE Head ") and set(prov["landmarks"].values()) <= {"ok", "uncertain"}
    names = fs(coll).face.face_options()["pegs"]
    pegs = fs(coll).face.peg_objects(names)
    assert len(names) >= 10 and set(pegs) == set(names)
    assert all(p.parent == obj for p in pegs.values())                   # the pegs are the face's children
    # the face passes through the pegs' tips (within the engine's fit)
    verts = _world_vertices(obj)
    tips = fs(coll).face.peg_tips(names)
    gap = np.array([np.linalg.norm(verts - t, axis=1).min() for t in tips])
    assert np.median(gap) < 1.5, dict(zip(names, gap.round(1)))         # measured 0.78-0.90 mm (largest 4.1-9.8)

    # the panel's Face from Skull section: table, Find Landmarks, Build Face, the label, the pegs' depths
    from types import SimpleNamespace

    from panel_recorder import RecordingLayout
    forensic = sys.modules[f"{pdehead_ext.__name__}.operators.ui.forensic_ops"]
    log = []
    forensic.PDEHEAD_PT_forensic.draw(SimpleNamespace(layout=RecordingLayout(log)), bpy.context)
    assert ("operator", "pdehead.build_face") in log and ("operator", "pdehead.face_sd_range") in log
    assert ("prop", "face_table") in log and ("label", obj[face.LABEL_PROP]) in log
    assert sum(1 for x in log if x[0] == "prop" and x[1] == '["depth_mm"]') == len(names)

    # drag: one peg 4 mm outward along its normal -> the face near it follows, far away it does not move
    name = "Glabella" if "Glabella" in pegs else names[0]
    i = names.index(name)
    peg = pegs[name]
    normal = np.array(peg.matrix_world)[:3, 2]
    normal /= np.linalg.norm(normal)
    before = _world_vertices(obj)
    n_meshes = len(bpy.data.meshes)
    me_name = obj.data.name
    _drag(peg, 4.0 * normal)
    after = _world_vertices(obj)
    assert len(bpy.data.meshes) == n_meshes and obj.data.name == me_name     # same mesh, no new datablock
    near, moved, dist = _nearest_peg_vertex_motion(before, after, tips[i])
    # measured (5.0.1): 3.29-3.79 mm near the peg (engine versions), 95th percentile 0.09 mm beyond 60 mm
    assert np.median(moved[near]) == pytest.approx(4.0, abs=1.5), np.median(moved[near])
    assert np.percentile(moved[dist > 60.0], 95) < 0.3
    assert fs(coll).face.peg_tips(names)[i] == pytest.approx(tips[i] + 4.0 * normal, abs=1e-3)

    # depth: the same peg 2 mm longer -> the face near its tip moves out about 2 mm more
    before = after
    depth = float(peg[face.PEG_DEPTH_PROP])
    assert fs(coll).face.set_face_peg_depth(peg, depth + 2.0) == pytest.approx(depth + 2.0)
    bpy.context.view_layer.update()
    after = _world_vertices(obj)
    near, moved, dist = _nearest_peg_vertex_motion(before, after, tips[i] + 4.0 * normal)
    assert np.median(moved[near]) == pytest.approx(2.0, abs=0.7)          # measured 1.83-2.07 mm

    # undo: one step per drag (memfile undo: the peg and the face go back together)
    bpy.ops.ed.undo_push(message="before drag")
    snapshot = _world_vertices(obj)
    _drag(peg, -3.0 * normal)
    bpy.ops.ed.undo_push(message="drag")
    assert _nearest_peg_vertex_motion(snapshot, _world_vertices(obj), tips[i])[1].max() > 1.0
    bpy.ops.ed.undo()
    coll = bpy.context.scene.pdehead.active_study
    obj = fs(coll).face.face_object()
    bpy.context.view_layer.update()
    back = _world_vertices(obj)
    assert back.shape == snapshot.shape and np.abs(back - snapshot).max() < 1e-3

    # table switch: a table with Glabella 10 mm deeper re-solves the face at once, the peg shows the mean
    table = tmp_path / "table.csv"
    table.write_text("# test values, not a published table\nlandmark,mean_mm,sd_mm\n" +
                     "".join(f"{n},{15.5 if n == name else 6.0},1.0\n" for n in names))
    s = state.settings(coll)
    pegs = fs(coll).face.peg_objects(names)
    before = _world_vertices(obj)
    s.face_table_file = str(table)
    s.face_table = 'FILE'
    assert s.last_error == ""
    assert pegs[name][face.PEG_DEPTH_PROP] == 15.5 and pegs[name]["table_name"] == "table"
    after = _world_vertices(obj)
    tip = fs(coll).face.peg_tips(names)[i]
    assert np.linalg.norm(after - tip, axis=1).min() < 1.5                 # the face reaches the new tip: 0.36-0.51 mm
    assert json.loads(obj[face.PROVENANCE_PROP])["table"] == "table"
    s.face_table = 'DEFAULT'
    assert pegs[name][face.PEG_DEPTH_PROP] == pytest.approx(5.5 if name == "Glabella" else pegs[name]["table_mean_mm"])

    # the +-1 SD faces: thinner and thicker than the face everywhere a peg stands
    assert bpy.ops.pdehead.face_sd_range() == {'FINISHED'}
    lo, hi = coll[face.SD_FACE_KEYS["minus"]], coll[face.SD_FACE_KEYS["plus"]]
    c = _world_vertices(obj).mean(0)
    r = [np.linalg.norm(_world_vertices(o) - c, axis=1).mean() for o in (lo, obj, hi)]
    assert r[0] < r[1] < r[2], r                                       # measured 95.3 < 96.3 < 97.3 mm
    assert lo[face.LABEL_PROP] == obj[face.LABEL_PROP]

    # Build Face is one undo step: undone, the study has its earlier face (same build) and pegs again
    build = fs(coll).face.face_options()["build"]
    bpy.ops.ed.undo_push(message="before Build Face")
    assert bpy.ops.pdehead.build_face() == {'FINISHED'}
    assert fs(coll).face.face_options()["build"] != build
    bpy.ops.ed.undo_push(message="Build Face")
    bpy.ops.ed.undo()
    coll = bpy.context.scene.pdehead.active_study
    assert fs(coll).face.face_options()["build"] == build
    assert set(fs(coll).face.peg_objects(names)) == set(names)


def test_face_follows_a_peg_after_reopening(pdehead_ext, face_blend, tmp_path):
    import bpy
    face, fs, state = _mods(pdehead_ext)
    coll = _open(face_blend)
    names = fs(coll).face.face_options()["pegs"]
    # what this session's model (prepared by Build Face) gives for the drag made after reopening
    model = fs(coll).face.face_model()
    normal = np.array(fs(coll).face.peg_objects(names)[names[0]].matrix_world)[:3, 2]
    normal /= np.linalg.norm(normal)
    # a peg dragged before the save: the saved face is a solve with it held, and the model kept in the file
    # must give that face to be used (it was prepared again, 8 s on CThead, when the check ignored held pegs)
    other = fs(coll).face.peg_objects(names)[names[1]]
    _drag(other, 1.0 * np.array(other.matrix_world)[:3, 2])
    assert json.loads(fs(coll).face.face_object()[face.PROVENANCE_PROP])["pegs_held"] == [names[1]]
    dragged = fs(coll).face.peg_tips(names)
    dragged[0] += 3.0 * normal
    expected = model.solve(tips=dragged, held=[names[0], names[1]]).mesh.vertices   # a dragged peg is held
    assert len(coll[face.FACE_MODEL_KEY]) < 1_000_000            # the kept model: budget 1 MB (measured 0.4 MB)
    saved = tmp_path / "again.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(saved))
    state.drop_cache()                                  # as in a new Blender session: no model in memory
    bpy.ops.wm.open_mainfile(filepath=str(saved))
    coll = bpy.context.scene.pdehead.active_study
    obj = fs(coll).face.face_object()
    pegs = fs(coll).face.peg_objects(names)
    assert obj is not None and set(pegs) == set(names) and fs(coll).landmarks()
    assert obj[face.LABEL_PROP] == "approximation — not an identification"
    before = _world_vertices(obj)
    bpy.context.view_layer.update()                     # nothing moved: no re-solve, no model prepared
    assert np.array_equal(_world_vertices(obj), before)
    cache = state.cache_for(state.settings(coll).study_id).forensic
    assert cache.get("face_model") is None
    prepared = state.REGISTRY.face_prepare_calls
    name = names[0]
    peg = pegs[name]
    tip = fs(coll).face.peg_tips(names)[0]
    _drag(peg, 3.0 * normal)
    after = _world_vertices(obj)
    near, moved, dist = _nearest_peg_vertex_motion(before, after, tip)
    assert np.median(moved[near]) == pytest.approx(3.0, abs=1.0)          # measured 2.54-2.95 mm (far: 0.07)
    assert np.percentile(moved[dist > 60.0], 95) < 0.3
    # the model came from the file, not from preparing it again, and gives the face the first session's gives
    assert state.REGISTRY.face_prepare_calls == prepared and cache["face_model_source"] == "file"
    assert cache["face_timings"]["fast"] and not cache["face_timings"]["refilled"]
    assert np.abs(fs(coll).face._mesh_positions(obj) - expected).max() < 1e-3     # float32 metres: ~1e-5 mm
    from types import SimpleNamespace

    from panel_recorder import RecordingLayout
    log = []
    sys.modules[f"{pdehead_ext.__name__}.operators.ui.forensic_ops"].PDEHEAD_PT_forensic.draw(
        SimpleNamespace(layout=RecordingLayout(log)), bpy.context)
    assert ("label", "Live: vertex positions only, model from the file") in log
    # a kept model that does not belong to this face (another build): prepared again, the face still follows
    coll[face.FACE_MODEL_KEY] = "another build\n" + coll[face.FACE_MODEL_KEY].partition("\n")[2]
    state.drop_cache()
    _drag(peg, -1.0 * normal)
    assert state.REGISTRY.face_prepare_calls == prepared + 1 and cache_source(state, coll) == "prepared"
    assert np.abs(fs(coll).face.peg_tips(names)[0] - (tip + 2.0 * normal)).max() < 1e-3

    # a peg deleted: the face solves once with that peg back at the table's mean, then stays (no solve per update)
    cache = state.cache_for(state.settings(coll).study_id).forensic
    bpy.data.objects.remove(pegs[names[1]])
    bpy.context.view_layer.update()
    assert cache["face_timings"] is not None and state.settings(coll).last_error == ""
    cache["face_timings"] = None
    bpy.context.view_layer.update()
    assert cache["face_timings"] is None


def cache_source(state, coll) -> str:
    return state.cache_for(state.settings(coll).study_id).forensic.get("face_model_source")


def _tip_to_mesh_mm(pdehead_ext, obj, tip) -> float:
    """The exact distance (mm) from ``tip`` (patient mm) to the face object's triangles (brute force)."""
    import importlib
    geometry = importlib.import_module(f"{pdehead_ext.__name__}.pdehead_addon.core.mesh_geometry")
    me = obj.data
    me.calc_loop_triangles()
    tris = np.empty(len(me.loop_triangles) * 3, np.int64)
    me.loop_triangles.foreach_get("vertices", tris)
    v = _world_vertices(obj)
    t = tris.reshape(-1, 3)
    return float(geometry.point_triangle_distance(np.asarray(tip, float)[None], v[t[:, 0]], v[t[:, 1]],
                                                  v[t[:, 2]]).min())


def _panel_labels(pdehead_ext) -> list:
    from types import SimpleNamespace

    import bpy

    from panel_recorder import RecordingLayout
    forensic = sys.modules[f"{pdehead_ext.__name__}.operators.ui.forensic_ops"]
    log = []
    forensic.PDEHEAD_PT_forensic.draw(SimpleNamespace(layout=RecordingLayout(log)), bpy.context)
    return log


def test_pegs_off_the_face_are_shown_held_and_warned(pdehead_ext, face_blend):
    """Issue 23: each peg carries its tip's distance to the face and the panel lists those more than 2 mm off and
    why; a held peg (toggled in the panel, or dragged) is followed (tip within 0.5 mm); a peg pushed into the bone
    or dragged 200 mm out is named in a warning while the face still solves; Build Face lets every peg go."""
    import bpy
    face, fs, state = _mods(pdehead_ext)
    coll = _open(face_blend)
    study = fs(coll)
    obj = study.face.face_object()
    names = study.face.face_peg_names()
    pegs = study.face.peg_objects(names)
    assert all(not p[face.HELD_PROP] for p in pegs.values())
    gaps = {n: float(p[face.TIP_TO_FACE_PROP]) for n, p in pegs.items()}
    tips = study.face.peg_tips(names)
    for n in ("Glabella", "Supra M2 L", "Gonion R"):        # the property is the tip's distance to the face
        assert gaps[n] == pytest.approx(_tip_to_mesh_mm(pdehead_ext, obj, tips[names.index(n)]), abs=0.05)
    prov = json.loads(obj[face.PROVENANCE_PROP])
    off = {o["peg"]: o for o in prov["pegs_off_face"]}
    # the property is rounded to 0.01 mm: a peg at 2.00 mm may be either side of the report's 2 mm
    assert {n for n, g in gaps.items() if g > 2.01} <= set(off) <= {n for n, g in gaps.items() if g > 1.99}, gaps
    assert off
    assert prov["peg_warnings"] == [] and prov["pegs_held"] == []
    damped = [n for n, o in off.items() if o["why"].startswith("damped: disagrees with its neighbours by")]
    assert "Supra M2 L" in damped or "Supra M2 R" in damped, off
    labels = [x[1] for x in _panel_labels(pdehead_ext) if x[0] == "label" and x[1]]
    for n, o in off.items():
        assert any(t.startswith(f"{n}: {o['tip_to_face_mm']:.1f} mm, ") for t in labels), (n, labels)

    # hold the farthest damped peg (the pin in the panel): the face passes through its tip
    name = max(damped, key=lambda n: gaps[n])
    peg = pegs[name]
    peg[face.HELD_PROP] = True
    peg.update_tag()
    bpy.context.view_layer.update()
    i = names.index(name)
    held_gap = _tip_to_mesh_mm(pdehead_ext, obj, study.face.peg_tips(names)[i])
    # measured on the phantom (5.0.1): Supra M2 3.6 -> 0.2 mm
    assert held_gap <= 0.5 and peg[face.TIP_TO_FACE_PROP] == pytest.approx(held_gap, abs=0.05), (name, gaps[name])
    assert json.loads(obj[face.PROVENANCE_PROP])["pegs_held"] == [name]

    # a peg pushed 3 mm into the bone: a warning naming it (a panel line), the face still solves, the peg is held
    glabella = pegs["Glabella"]
    normal = np.array(glabella.matrix_world)[:3, 2]
    normal /= np.linalg.norm(normal)
    _drag(glabella, -(float(glabella[face.PEG_DEPTH_PROP]) + 3.0) * normal)
    warnings = study.face.peg_warnings()
    assert [(w["peg"], w["kind"]) for w in warnings] == [("Glabella", "into_bone")], warnings
    assert glabella[face.HELD_PROP] and not study.settings.last_error
    assert any(t == warnings[0]["text"] for t in (x[1] for x in _panel_labels(pdehead_ext) if x[0] == "label"))
    # ... and pulled back then dragged 200 mm out sideways: a warning that it is far from its landmark
    _drag(glabella, (float(glabella[face.PEG_DEPTH_PROP]) + 3.0) * normal)
    assert study.face.peg_warnings() == []
    pogonion = pegs["Pogonion"]
    _drag(pogonion, [200.0, 0.0, 0.0])
    warnings = study.face.peg_warnings()
    assert [(w["peg"], w["kind"]) for w in warnings][:1] == [("Pogonion", "far")], warnings
    assert "200 mm off" in warnings[0]["text"] and not study.settings.last_error
    assert np.isfinite(_world_vertices(obj)).all() and pogonion[face.HELD_PROP]       # the face still solves

    # Build Face again: every peg let go
    assert bpy.ops.pdehead.build_face() == {'FINISHED'}
    pegs = study.face.peg_objects(study.face.face_peg_names())
    assert pegs and all(not p[face.HELD_PROP] for p in pegs.values())


def test_export_for_printing_writes_the_face_beside_the_head(pdehead_ext, face_blend, tmp_path):
    """Export for Printing writes the study's face from the skull (as it stands: after a dragged peg) beside the
    skull and the skin, in patient mm, the label first in the STL header and in the PLY comments, and its
    provenance's landmark flags those of landmarks.csv (issue 23's tester: the face was not written)."""
    import csv

    import bpy
    from scipy.spatial import cKDTree

    from file_readers import read_stl
    face, fs, state = _mods(pdehead_ext)
    coll = _open(face_blend)
    names = fs(coll).face.face_options()["pegs"]
    _drag(fs(coll).face.peg_objects(names)[names[0]], (0.0, -3.0, 0.0))
    obj = fs(coll).face.face_object()
    shown = _world_vertices(obj)                            # patient mm (no Frankfurt here)
    out = tmp_path / "print"
    assert bpy.ops.pdehead.export_print(directory=str(out), format='stl') == {'FINISHED'}
    written = sorted(p.name for p in out.iterdir())
    assert written == ["face.stl", "landmarks.csv", "provenance.json", "skin.stl", "skull.stl",
                       "skull_envelope.stl", "tissue_depth.csv"], written
    stl = read_stl(out / "face.stl")
    # issue 41 item 3: meshed at print resolution (the skin's path), watertight, <= 2 M triangles, its chord
    # error over the face window <= 0.05 mm; before, face.stl was the viewport's mesh (as many vertices as shown)
    engine = pdehead_ext.pdehead_addon
    ddx = sys.modules[f"{pdehead_ext.__name__}.pdehead_addon.pde.detail_displace"]
    head = fs(coll).face.face_for_export()[0]
    # the face as shown: the exported surface at the viewport's resolution is the face object, vertex for vertex
    opts = fs(coll).face.face_model().options
    view = head.surface(int(opts["nu"]), int(opts["nv"]), caps=True)
    assert len(view.vertices) == len(shown) and cKDTree(view.vertices).query(shown)[0].max() < 1e-3
    fexport = sys.modules[f"{pdehead_ext.__name__}.operators.forensic.export"]
    printed = fexport.print_face(head)                                # what the export wrote, the same vertex count
    rows, nv = engine.print_resolution(head)
    assert stl.is_watertight() and stl.face_count <= 2_000_000 and len(stl.vertices) > 4 * len(shown), \
        (stl.face_count, len(stl.vertices), len(shown))
    assert len(stl.vertices) == len(printed.vertices)
    assert cKDTree(printed.vertices).query(stl.vertices)[0].max() < 1e-3          # in mm (float32)
    window = ddx.surface_window(head)
    with ddx.print_columns(head, window):                 # the print's columns: denser over the face
        assert ddx.chord_error(head, len(rows), nv, window, rows=rows)["max"] <= 0.05
    assert (out / "face.stl").read_bytes()[:80].startswith(b"approximation - not an identification; face")
    skull = read_stl(out / "skull.stl")
    assert np.all(stl.vertices[:, :2].min(0) < skull.vertices[:, :2].min(0))   # the face wraps the bone
    prov = json.loads((out / "provenance.json").read_text())
    rows = [line for line in (out / "landmarks.csv").read_text().splitlines() if not line.startswith("#")]
    flags = {row["landmark"]: row["flag"] for row in csv.DictReader(rows)}
    assert "face.stl" in prov["files"] and prov["face"]["label"] == "approximation — not an identification"
    assert prov["face"]["landmark_flags"] == flags and len(flags) >= 40
    # ... and after the export the study says what its files say: the face object's provenance (the panel's
    # source) and the landmarks' flags (an ``ok`` one the CT's depth did not support is now ``uncertain`` there)
    shown_prov = json.loads(obj[face.PROVENANCE_PROP])
    assert shown_prov["landmark_flags"] == flags
    assert {n: f for n, f in fs(coll).flag_names().items() if n in flags} == \
        {n: f for n, f in flags.items() if n in fs(coll).flag_names()}
    _drag(fs(coll).face.peg_objects(names)[names[0]], (0.0, 1.0, 0.0))      # ... and after the next solve too
    assert json.loads(fs(coll).face.face_object()[face.PROVENANCE_PROP])["landmark_flags"] == flags
    assert bpy.ops.pdehead.export_print(directory=str(tmp_path / "ply"), format='ply') == {'FINISHED'}
    head = (tmp_path / "ply" / "face.ply").read_bytes().split(b"end_header\n", 1)[0]
    assert b"comment label: approximation - not an identification" in head


def test_sex_shows_for_a_table_with_a_sex_column_and_picks_its_rows(pdehead_ext, face_blend):
    """A depth table with a `sex` column (tests/fixtures/depth_table_by_sex.csv) is read (it was refused:
    "Glabella is given twice"), the panel then shows Sex, and choosing it sets the pegs to that sex's means
    and re-solves the face; the shipped pooled table shows no Sex. Back to the T-Table 2023 with Sex = Male
    (hidden now): the pooled table is used pooled (the switch failed with "...pooled...no male values", the
    face kept the male table, Build Face raised it), and the setting is kept for the sex table again."""
    from pathlib import Path
    from types import SimpleNamespace

    import bpy

    from panel_recorder import RecordingLayout
    face, fs, state = _mods(pdehead_ext)
    forensic = sys.modules[f"{pdehead_ext.__name__}.operators.ui.forensic_ops"]
    coll = _open(face_blend)

    def panel():
        log = []
        forensic.PDEHEAD_PT_forensic.draw(SimpleNamespace(layout=RecordingLayout(log)), bpy.context)
        return log

    assert ("prop", "face_sex") not in panel()                    # the T-Table 2023 is pooled
    ttable = json.loads(fs(coll).face.face_object()[face.PROVENANCE_PROP])["table"]
    ttable_json = fs(coll).face.face_options()["table"]

    def depths():
        return {n: p[face.PEG_DEPTH_PROP] for n, p in fs(coll).face.peg_objects(fs(coll).face.face_peg_names()).items()}
    t_depths = depths()                                            # the T-Table's means
    s = state.settings(coll)
    s.face_table_file = str(Path(__file__).resolve().parents[1] / "fixtures" / "depth_table_by_sex.csv")
    s.face_table = 'FILE'
    assert s.last_error == ""
    assert ("prop", "face_sex") in panel()
    obj = fs(coll).face.face_object()
    glabella = fs(coll).face.peg_objects(["Glabella"])["Glabella"]
    assert glabella[face.PEG_DEPTH_PROP] == 5.5                   # pooled rows
    for sex, depth in (('MALE', 6.0), ('FEMALE', 5.0)):
        s.face_sex = sex
        assert s.last_error == "" and glabella[face.PEG_DEPTH_PROP] == depth
        prov = json.loads(obj[face.PROVENANCE_PROP])
        assert prov["sex"] == sex.lower() and prov["table"] == f"Small table by sex, {sex.lower()}"

    # Sex = Male, then back to the pooled T-Table 2023: Sex is hidden, kept, and ignored
    s.face_sex = 'MALE'
    s.face_table = 'DEFAULT'
    assert s.last_error == "" and ("prop", "face_sex") not in panel() and s.face_sex == 'MALE'
    assert fs(coll).face.face_options()["table"] == ttable_json and not fs(coll).face.face_options()["sex"]
    assert depths() == t_depths and t_depths["Pogonion"] != 12.0     # the T-Table's means, not the male rows
    prov = json.loads(obj[face.PROVENANCE_PROP])
    assert prov["sex"] == "pooled" and prov["table"] == ttable
    assert bpy.ops.pdehead.build_face() == {'FINISHED'}
    obj = fs(coll).face.face_object()
    prov = json.loads(obj[face.PROVENANCE_PROP])
    assert prov["sex"] == "pooled" and prov["table"] == ttable and fs(coll).face.face_options()["table"] == ttable_json
    assert depths() == t_depths
    glabella = fs(coll).face.peg_objects(["Glabella"])["Glabella"]
    # ... and the sex table again: its male rows
    s.face_table = 'FILE'
    assert s.last_error == "" and ("prop", "face_sex") in panel()
    assert glabella[face.PEG_DEPTH_PROP] == 6.0
    prov = json.loads(obj[face.PROVENANCE_PROP])
    assert prov["sex"] == "male" and prov["table"] == "Small table by sex, male"


def test_export_for_printing_after_face_from_skull_only(pdehead_ext, tmp_path, capfd):
    """A face-from-skull study (CT imported, Build Skull, Find Landmarks, Build Face; the head pipeline never
    run): Export for Printing writes what the study has (skull, envelope, face, landmarks.csv, provenance.json)
    and says what it left out and why (the tester's: it failed "no boundary curves yet: run Extract Boundaries")."""
    import csv

    import bpy

    from file_readers import read_stl
    assert bpy.ops.pdehead.load_phantom() == {'FINISHED'}
    for step in ("build_skull", "find_landmarks", "build_face"):
        assert getattr(bpy.ops.pdehead, step)() == {'FINISHED'}, step
    out = tmp_path / "print"
    capfd.readouterr()
    assert bpy.ops.pdehead.export_print(directory=str(out), format='stl') == {'FINISHED'}
    said = "".join(capfd.readouterr())
    written = sorted(p.name for p in out.iterdir())
    assert written == ["face.stl", "landmarks.csv", "provenance.json", "skull.stl", "skull_envelope.stl"], written
    assert read_stl(out / "face.stl").is_watertight() and read_stl(out / "skull.stl").is_watertight()
    prov = json.loads((out / "provenance.json").read_text())
    rows = [line for line in (out / "landmarks.csv").read_text().splitlines() if not line.startswith("#")]
    flags = {row["landmark"]: row["flag"] for row in csv.DictReader(rows)}
    assert prov["files"] == [n for n in prov["files"] if n in written] and "face.stl" in prov["files"]
    assert prov["face"]["landmark_flags"] == flags and len(flags) >= 40
    # what was left out, and why: in provenance.json and in the operator's report
    assert sorted(prov["not_written"]) == ["skin.stl", "tissue_depth.csv"]
    assert all("Extract Boundaries" in why for why in prov["not_written"].values())
    line = next((ln for ln in said.splitlines() if "not written" in ln), "")
    assert "skin.stl" in line and "tissue_depth.csv" in line and "Extract Boundaries" in line, said
