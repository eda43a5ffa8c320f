"""Issue 19: a study animates like any Blender object (keyframes, Render Animation, files of 0.1.0)."""
from __future__ import annotations

import math
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import blender_inspect  # tests/blender/blender_inspect.py

DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture()
def mods(pdehead_ext):
    from types import SimpleNamespace
    name = pdehead_ext.__name__
    return SimpleNamespace(**{m: sys.modules[f"{name}.operators.{m}"]
                              for m in ("animation", "compat", "cutter", "render", "state", "study")})


def _solid_mm(obj) -> np.ndarray:
    return blender_inspect.mesh_world_vertices(obj) * 1000.0


def _expected_solid(mods, coll, **ranges):
    s = mods.state.settings(coll)
    head = mods.study.pde_head(coll)
    nw = ranges.pop("nw", s.nw)
    kw = dict(u_range=tuple(s.u_range), v_range=tuple(s.v_range), w_range=tuple(s.w_range))
    kw.update(ranges)
    return head.solid(s.nu, s.nv, nw, **kw).vertices


def test_settings_keyframed_like_any_property(mods, monkeypatch):
    """keyframe_insert on the study's settings (the README's line), frame_set shows each frame's solid,
    the same frame twice rebuilds nothing, and the keys are F-Curves of the settings object."""
    import bpy
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=4, nu=16, nv=24, nw=3,
                                        build_volume=False) == {'FINISHED'}
    scene = bpy.context.scene
    coll = scene.pdehead.active_study
    s = mods.state.settings(coll)
    owner = s.id_data
    assert owner.type == 'EMPTY' and owner.name in coll.objects and coll.pdehead == s
    full = (0.0, 2 * math.pi)

    # the README's one line, at frame 1 the whole head, at frame 3 half of it
    s.v_range = full
    s.keyframe_insert("v_range", frame=1)
    s.v_range = (0.0, math.pi)
    s.keyframe_insert("v_range", frame=3)
    s.nw = 3
    s.keyframe_insert("nw", frame=1)
    s.nw = 5
    s.keyframe_insert("nw", frame=3)
    paths = {(fc.data_path, fc.array_index) for fc in mods.compat.animation_fcurves(owner)}
    assert {("pdehead.v_range", 0), ("pdehead.v_range", 1), ("pdehead.nw", 0)} <= paths

    solid = s.solid_object
    for frame, v_hi, nw in ((1, 2 * math.pi, 3), (2, 1.5 * math.pi, 4), (3, math.pi, 5), (1, 2 * math.pi, 3)):
        scene.frame_set(frame)
        assert s.last_error == ""
        assert tuple(s.v_range) == pytest.approx((0.0, v_hi), abs=1e-5) and s.nw == nw
        expected = _expected_solid(mods, coll, v_range=(0.0, v_hi), nw=nw)
        got = _solid_mm(solid)
        assert got.shape == expected.shape
        np.testing.assert_allclose(got, expected, atol=0.05)

    # same frame and parameters: no rebuild; another frame: one
    calls = []
    real = mods.study.step_solid
    monkeypatch.setattr(mods.study, "step_solid", lambda c: (calls.append(c.name), real(c)))
    scene.frame_set(1)
    assert calls == []
    scene.frame_set(2)
    assert calls == [coll.name]
    scene.frame_set(2)
    assert calls == [coll.name]


def test_settings_of_a_0_1_0_file_are_migrated(mods, tmp_path):
    """A .blend saved by 0.1.0 (settings on the Collection) opens with every setting, now animatable."""
    import bpy
    blend = tmp_path / "study_0.1.0.blend"
    shutil.copy(DATA / "study_0.1.0.blend", blend)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    coll = bpy.data.collections["Phantom"]
    assert mods.state.is_study(coll) and bpy.context.scene.pdehead.active_study == coll
    s = mods.state.settings(coll)
    stored = mods.compat.registered_id_properties(coll)
    assert s.id_data.type == 'EMPTY' and stored.get("pdehead") is None  # one copy of the settings
    assert (s.source_kind, s.nu, s.nv, s.nw, s.patches) == ('PHANTOM', 16, 24, 3, 4)
    assert tuple(s.v_range) == pytest.approx((0.5, 5.0)) and tuple(s.w_range) == pytest.approx((0.2, 1.0))
    assert (s.low_alpha, s.high_alpha, s.density) == pytest.approx((0.7, 0.1, 3.5))
    assert (s.colour_preset, s.alpha_mode) == ('xray', 'INTENSITY')
    assert s.surface_object.name == "Phantom Surface" and s.solid_object.name == "Phantom Solid"
    assert s.curves_object.name == "Phantom Boundary curves" and len(s.study_id) == 32
    assert mods.state.boundary_set(coll).patches == 4
    # live and animatable after the move
    s.keyframe_insert("w_range", frame=1)
    s.w_range = (0.6, 1.0)
    assert s.last_error == ""
    expected = _expected_solid(mods, coll)
    np.testing.assert_allclose(_solid_mm(s.solid_object), expected, atol=0.05)
    # saved and reopened once more: still there, still keyed
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    s = mods.state.settings(bpy.data.collections["Phantom"])
    assert tuple(s.v_range) == pytest.approx((0.5, 5.0)) and s.colour_preset == 'xray'
    assert ("pdehead.w_range", 0) in {(fc.data_path, fc.array_index)
                                      for fc in mods.compat.animation_fcurves(s.id_data)}

