"""Every operator and panel after undo, after reopening, and with several studies in one file.

Background Blender has no window, so Ctrl+Z is exercised with the undo operators that run headless
(``bpy.ops.ed.undo_push`` / ``bpy.ops.ed.undo`` / ``bpy.ops.ed.redo``: memfile undo, which rebuilds
every datablock as Ctrl+Z does). Not testable here: the undo steps the UI pushes by itself after
an operator or a slider drag in the sidebar (headless, bpy.ops calls from Python push none), and
undo while a modal operator runs.
"""
from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import blender_inspect  # tests/blender/blender_inspect.py
from panel_recorder import RecordingLayout as _Layout  # noqa: E402

ALL_OPERATORS = ("segment", "extract_boundaries", "reconstruct_surface", "build_solid", "build_volume",
                 "frame_study", "add_cutter")


def draw_panels(ext):
    import bpy
    log = []
    for cls in ext.ui.panel.CLASSES:
        if hasattr(cls, "poll") and not cls.poll(bpy.context):
            continue
        cls.draw(SimpleNamespace(layout=_Layout(log), study=cls.study), bpy.context)
    return log


def run_every_operator(ext, study: str):
    import bpy
    for name in ALL_OPERATORS:
        assert getattr(bpy.ops.pdehead, name)(study=study) == {'FINISHED'}, name
    log = draw_panels(ext)
    assert ("operator", "pdehead.add_cutter") in log and any(x[0] == "prop" and x[1] == "v_range" for x in log)


def _study(ext, name):
    import bpy
    coll = bpy.data.collections[name]
    assert ext.state.is_study(coll)
    return coll, coll.pdehead


def test_undo_restores_the_study_and_every_operator_works_after_it(ext, tmp_path):
    import bpy
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "undo.blend"))
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=4, nu=24, nv=36, nw=3,
                                        voxel_size=6.0) == {'FINISHED'}
    name = bpy.context.scene.pdehead.active_study.name
    coll, s = _study(ext, name)
    n_full = len(s.solid_object.data.vertices)
    vdb_first = Path(bpy.path.abspath(s.volume_object.data.filepath))
    bpy.ops.ed.undo_push(message="built")

    assert bpy.ops.pdehead.add_cutter() == {'FINISHED'}
    _, s = _study(ext, name)
    assert s.use_cutter and s.v_range[1] - s.v_range[0] < 2 * math.pi - 0.5
    assert bpy.ops.pdehead.build_volume() == {'FINISHED'}
    vdb_second = Path(bpy.path.abspath(s.volume_object.data.filepath))
    assert vdb_second != vdb_first and vdb_first.is_file()  # the old file stays until a save drops it
    bpy.ops.ed.undo_push(message="cut")

    assert bpy.ops.ed.undo() == {'FINISHED'}  # Ctrl+Z: back to "built"
    coll, s = _study(ext, name)  # every datablock is new after undo
    assert ext.scene.cutter.cutter_of(coll) is None and not s.use_cutter
    assert tuple(s.v_range) == pytest.approx((0.0, 2 * math.pi))
    assert len(s.solid_object.data.vertices) == n_full
    assert Path(bpy.path.abspath(s.volume_object.data.filepath)) == vdb_first
    assert ext.volume.volume.check_volume(s.volume_object) is None  # the file the undone state needs is there

    # live parameters and every operator work on the restored study
    s.nw = 4
    assert s.last_error == "" and len(s.solid_object.data.vertices) > n_full
    s.v_range = (math.pi / 2, 2 * math.pi)
    assert s.last_error == ""
    run_every_operator(ext, name)

    assert bpy.ops.ed.redo.poll() or True  # redo after new actions has nothing to redo: no crash either way
    bpy.ops.ed.undo_push(message="after")
    assert bpy.ops.ed.undo() == {'FINISHED'}
    coll, s = _study(ext, name)
    assert s.solid_object is not None and ext.study.entity.Study.of(coll).head is not None


def test_two_studies_after_reopening_each_operator_acts_on_its_own_study(ext, tmp_path):
    import bpy
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "two.blend"))
    for _ in range(2):
        assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=4, nu=20, nv=30, nw=3,
                                            voxel_size=6.0) == {'FINISHED'}
    names = sorted(c.name for c in ext.state.studies())
    assert len(names) == 2
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "two.blend"))
    ext.state.drop_cache()  # as in a new session

    first, second = (_study(ext, n) for n in names)
    before = blender_inspect.mesh_world_vertices(second[1].solid_object).copy()
    vdb_second = second[1].volume_object.data.filepath
    assert bpy.ops.pdehead.build_solid(study=names[0], nw=5) == {'FINISHED'}
    assert first[1].nw == 5 and second[1].nw == 3
    np.testing.assert_array_equal(blender_inspect.mesh_world_vertices(second[1].solid_object), before)
    run_every_operator(ext, names[0])
    assert second[1].volume_object.data.filepath == vdb_second  # the other study's volume is untouched
    assert ext.scene.cutter.cutter_of(second[0]) is None
    bpy.context.scene.pdehead.active_study = second[0]
    run_every_operator(ext, "")  # the active study
    cams = {c.name: next(o for o in c.objects if o.get("pdehead_kind") == "camera") for c in (first[0], second[0])}
    assert bpy.context.scene.camera == cams[names[1]] and cams[names[0]] != cams[names[1]]
    bpy.ops.wm.save_mainfile()
    files = sorted(p.name for p in (tmp_path / "pdehead_vdb").iterdir())
    assert len(files) == 2  # one current .vdb per study; replaced ones removed by the save
