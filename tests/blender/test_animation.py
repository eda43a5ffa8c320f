"""Issue 19: a study animates like any Blender object (keyframes, Render Animation, files of 0.1.0)."""
from __future__ import annotations

import math
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import blender_inspect  # tests/blender/blender_inspect.py

DATA = Path(__file__).resolve().parent / "data"


def _solid_mm(obj) -> np.ndarray:
    return blender_inspect.mesh_world_vertices(obj) * 1000.0


def _expected_solid(ext, coll, **ranges):
    s = ext.state.settings(coll)
    head = ext.study.entity.Study.of(coll).head
    nw = ranges.pop("nw", s.nw)
    v_range = tuple(min(float(v), 2 * math.pi) for v in s.v_range)  # float32 2π is a hair above float64 2π
    kw = dict(u_range=tuple(s.u_range), v_range=v_range, w_range=tuple(s.w_range))
    kw.update(ranges)
    return head.solid(s.nu, s.nv, nw, **kw).vertices


def test_settings_keyframed_like_any_property(ext, monkeypatch):
    """keyframe_insert on the study's settings (the README's line), frame_set shows each frame's solid,
    the same frame twice rebuilds nothing, and the keys are F-Curves of the settings object."""
    import bpy
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=4, nu=16, nv=24, nw=3,
                                        build_volume=False) == {'FINISHED'}
    scene = bpy.context.scene
    coll = scene.pdehead.active_study
    s = ext.state.settings(coll)
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
    paths = {(fc.data_path, fc.array_index) for fc in ext.compat.animation_fcurves(owner)}
    assert {("pdehead.v_range", 0), ("pdehead.v_range", 1), ("pdehead.nw", 0)} <= paths

    solid = s.solid_object
    for frame, v_hi, nw in ((1, 2 * math.pi, 3), (2, 1.5 * math.pi, 4), (3, math.pi, 5), (1, 2 * math.pi, 3)):
        scene.frame_set(frame)
        assert s.last_error == ""
        assert tuple(s.v_range) == pytest.approx((0.0, v_hi), abs=1e-5) and s.nw == nw
        expected = _expected_solid(ext, coll, v_range=(0.0, v_hi), nw=nw)
        got = _solid_mm(solid)
        assert got.shape == expected.shape
        np.testing.assert_allclose(got, expected, atol=0.05)

    # same frame and parameters: no rebuild; another frame: one
    calls = []
    real = ext.study.entity.Study.solid
    monkeypatch.setattr(ext.study.entity.Study, "solid", lambda study, live=False: (calls.append(study.name),
                                                                                    real(study, live))[1])
    scene.frame_set(1)
    assert calls == []
    scene.frame_set(2)
    assert calls == [coll.name]
    scene.frame_set(2)
    assert calls == [coll.name]
    monkeypatch.undo()

    # a driver (a simple expression: no Python auto-run needed) moves the inner w bound with the frame
    driver = s.driver_add("w_range", 0).driver
    driver.type = 'SCRIPTED'
    driver.expression = "(frame - 1) * 0.25"
    for frame in (3, 1):
        scene.frame_set(frame)
        assert s.w_range[0] == pytest.approx((frame - 1) * 0.25) and s.last_error == ""
        np.testing.assert_allclose(_solid_mm(solid), _expected_solid(ext, coll), atol=0.05)


@pytest.mark.parametrize("saved_by", [(4, 2), (5, 0)], ids=["blender4.2", "blender5.0"])
def test_settings_of_a_0_1_0_file_are_migrated(ext, tmp_path, saved_by):
    """A .blend saved by 0.1.0 (settings on the Collection) opens with every setting, now animatable
    (saved by Blender 4.2.23 and by 5.0.1, which stores registered properties apart from custom ones)."""
    import bpy
    if bpy.app.version[:2] < saved_by:
        pytest.skip(f"a file saved by Blender {saved_by[0]}.{saved_by[1]} is newer than this Blender")
    name = "study_0.1.0.blend" if saved_by == (5, 0) else "study_0.1.0_blender4.2.blend"
    blend = tmp_path / "study_0.1.0.blend"
    shutil.copy(DATA / name, blend)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    coll = bpy.data.collections["Phantom"]
    assert ext.state.is_study(coll) and bpy.context.scene.pdehead.active_study == coll
    s = ext.state.settings(coll)
    stored = ext.compat.registered_id_properties(coll)
    assert s.id_data.type == 'EMPTY' and stored.get("pdehead") is None  # one copy of the settings
    assert coll.get("pdehead") is None  # and no stale custom property
    assert (s.source_kind, s.nu, s.nv, s.nw, s.patches) == ('PHANTOM', 16, 24, 3, 4)
    assert tuple(s.v_range) == pytest.approx((0.5, 5.0)) and tuple(s.w_range) == pytest.approx((0.2, 1.0))
    assert (s.low_alpha, s.high_alpha, s.density) == pytest.approx((0.7, 0.1, 3.5))
    assert (s.colour_preset, s.alpha_mode) == ('xray', 'INTENSITY')
    assert s.surface_object.name == "Phantom Surface" and s.solid_object.name == "Phantom Solid"
    assert s.curves_object.name == "Phantom Boundary curves" and len(s.study_id) == 32
    assert ext.study.entity.Study.of(coll).boundary_set().patches == 4
    # live and animatable after the move
    s.keyframe_insert("w_range", frame=1)
    s.w_range = (0.6, 1.0)
    assert s.last_error == ""
    expected = _expected_solid(ext, coll)
    np.testing.assert_allclose(_solid_mm(s.solid_object), expected, atol=0.05)
    # saved and reopened once more: still there, still keyed
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    s = ext.state.settings(bpy.data.collections["Phantom"])
    assert tuple(s.v_range) == pytest.approx((0.5, 5.0)) and s.colour_preset == 'xray'
    assert ("pdehead.w_range", 0) in {(fc.data_path, fc.array_index)
                                      for fc in ext.compat.animation_fcurves(s.id_data)}



def _render_setup(scene, tmp_path):
    scene.render.engine = 'CYCLES'
    scene.cycles.device = 'CPU'
    scene.cycles.samples = 4
    scene.cycles.seed = 0
    scene.cycles.use_animated_seed = False
    scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = int(os.environ.get("PDEHEAD_ANIMATION_PIXELS", 48))
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = 'PNG'
    scene.render.image_settings.color_mode = 'RGB'
    scene.frame_start, scene.frame_end = 1, 3


def _strip(rows, path):
    """Frames (top row) over stills (bottom row), one PNG, for people to look at."""
    from PIL import Image
    grid = np.concatenate([np.concatenate(row, axis=1) for row in rows], axis=0)
    Image.fromarray((np.clip(grid, 0, 1) * 255).astype(np.uint8)).resize(
        (grid.shape[1] * 2, grid.shape[0] * 2), Image.NEAREST).save(path)


def test_render_animation_renders_what_each_frame_shows(ext, tmp_path):
    """Keyframed cutter (outside the head at frame 1, over its front-left quarter at frame 3), keyframed
    w range and keyframed lα: each frame of Render Animation equals the still of the same frame."""
    import bpy
    from mathutils import Matrix
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=4, nu=24, nv=36, nw=3,
                                        voxel_size=6.0) == {'FINISHED'}
    scene = bpy.context.scene
    coll = scene.pdehead.active_study
    s = ext.state.settings(coll)
    for obj, shown in ((s.surface_object, False), (s.curves_object, False), (s.solid_object, True),
                       (s.volume_object, True)):
        obj.hide_render = not shown
    _render_setup(scene, tmp_path)
    scene.camera.data.lens *= 2.0  # the head fills the small frame

    scene.frame_set(1)
    assert bpy.ops.pdehead.add_cutter() == {'FINISHED'}
    box = ext.scene.cutter.cutter_of(coll)
    inside = box.matrix_world.copy()
    box.matrix_world = Matrix.Translation((1.0, 0.0, 0.0)) @ inside  # a metre to the side: nothing cut
    for path in ("location", "rotation_euler", "scale"):
        box.keyframe_insert(path, frame=1)
    box.matrix_world = inside
    for path in ("location", "rotation_euler", "scale"):
        box.keyframe_insert(path, frame=3)
    s.w_range = (0.0, 1.0)
    s.keyframe_insert("w_range", frame=1)
    s.w_range = (0.5, 1.0)
    s.keyframe_insert("w_range", frame=3)
    s.low_alpha = 0.1
    s.keyframe_insert("low_alpha", frame=1)
    s.low_alpha = 0.9
    s.keyframe_insert("low_alpha", frame=3)

    scene.frame_set(3)  # the file's current frame is the last: Render Animation must go back to 1
    scene.render.filepath = str(tmp_path / "anim" / "frame_")
    assert bpy.ops.render.render(animation=True) == {'FINISHED'}
    frames = [blender_inspect.read_png(tmp_path / "anim" / f"frame_{f:04d}.png")[..., :3] for f in (1, 2, 3)]

    stills, shapes = [], []
    for f in (1, 2, 3):
        scene.frame_set(f)
        assert s.last_error == ""
        shapes.append((tuple(round(x, 3) for x in s.v_range), round(s.w_range[0], 3), round(s.low_alpha, 3)))
        scene.render.filepath = str(tmp_path / f"still_{f}.png")
        assert bpy.ops.render.render(write_still=True) == {'FINISHED'}
        stills.append(blender_inspect.read_png(tmp_path / f"still_{f}.png")[..., :3])
    if os.environ.get("PDEHEAD_ANIMATION_STRIP"):
        _strip([frames, stills], os.environ["PDEHEAD_ANIMATION_STRIP"])

    # the stills differ as the keys say: frame 1 whole (no cut, w from 0, lα 0.1), frame 3 cut
    assert shapes[0] == ((0.0, round(2 * math.pi, 3)), 0.0, 0.1)
    assert shapes[2][0] != shapes[0][0] and shapes[2][1:] == (0.5, 0.9)
    assert float(np.abs(stills[0] - stills[2]).mean()) > 0.01
    for f, (frame, still) in enumerate(zip(frames, stills), start=1):
        diff = float(np.abs(frame - still).mean())
        assert diff <= 0.005, f"frame {f}: Render Animation differs from the still by {diff:.4f}"


def test_render_animation_with_the_ct_gone_says_so(ext, tmp_path, capfd):
    """A keyframed study whose CT cannot be re-read: Render Animation names the study and the cause and
    leaves the solid out of the frames it cannot rebuild, instead of rendering the stale solid."""
    import bpy
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=4, nu=16, nv=24, nw=3,
                                        build_volume=False) == {'FINISHED'}
    scene = bpy.context.scene
    coll = scene.pdehead.active_study
    name = coll.name
    s = ext.state.settings(coll)
    s.surface_object.hide_render, s.solid_object.hide_render = True, False
    _render_setup(scene, tmp_path)
    scene.cycles.samples = 2
    scene.render.resolution_x = scene.render.resolution_y = 24
    s.keyframe_insert("w_range", frame=1)
    s.w_range = (0.5, 1.0)
    s.keyframe_insert("w_range", frame=3)
    scene.frame_set(1)
    gone = tmp_path / "moved-away"
    s.source_kind, s.source, s.source_absolute = 'FILES', str(gone), str(gone)  # the CT's folder is gone
    blend = tmp_path / "gone.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    ext.state.drop_cache()  # as in a new Blender session: nothing in memory, the CT must be re-read
    scene = bpy.context.scene
    # the .blend carries the solid's CT table (issue 20): the cutaway animates without the CT
    capfd.readouterr()
    scene.render.filepath = str(tmp_path / "kept" / "frame_")
    assert bpy.ops.render.render(animation=True) == {'FINISHED'}
    err = capfd.readouterr().err
    assert "hidden from the render" not in err
    kept = [blender_inspect.read_png(tmp_path / "kept" / f"frame_{f:04d}.png")[..., :3] for f in (1, 2, 3)]
    corner = kept[0][0, 0]
    assert all(float((np.abs(img - corner).max(axis=2) > 0.05).mean()) > 0.05 for img in kept)  # the solid stays
    # a file without that table (saved before it existed) and without its CT: said, not rendered stale
    coll = bpy.data.collections[name]
    coll.pop(ext.state.CT_TABLE_KEY, None)
    coll.pop(ext.state.CT_TABLE_FOR, None)
    ext.state.drop_cache()
    capfd.readouterr()
    scene.render.filepath = str(tmp_path / "anim" / "frame_")
    assert bpy.ops.render.render(animation=True) == {'FINISHED'}
    err = capfd.readouterr().err
    assert f"study '{name}'" in err and "frame 2" in err and str(gone) in err
    assert f"hidden from the render: {name} Solid" in err
    frames = [blender_inspect.read_png(tmp_path / "anim" / f"frame_{f:04d}.png")[..., :3] for f in (1, 2, 3)]
    background = frames[2][0, 0]
    shown = [float((np.abs(img - background).max(axis=2) > 0.05).mean()) for img in frames]
    assert shown[0] > 0.05 and shown[1] == 0.0 and shown[2] == 0.0  # frame 1 is what was saved


def test_turntable_orbits_the_camera_around_the_head(ext):
    """Turntable (8 frames): the study camera circles the head's vertical axis, 45° a frame, always
    looking at the head, and frame 9 would be frame 1 again (a seamless loop)."""
    import bpy
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=4, nu=16, nv=24, nw=3,
                                        build_volume=False) == {'FINISHED'}
    scene = bpy.context.scene
    coll = scene.pdehead.active_study
    s = ext.state.settings(coll)
    assert bpy.ops.pdehead.turntable(frames=8) == {'FINISHED'}
    assert (scene.frame_start, scene.frame_end) == (1, 8)
    camera = scene.camera
    assert camera.get("pdehead_kind") == "camera" and camera.name in coll.objects
    lo, hi = ext.scene.render.world_bounds([s.surface_object])
    centre = 0.5 * (lo + hi)
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector
    positions = []
    for frame in (1, 2, 3, 5, 9):
        scene.frame_set(frame)
        p = np.array(camera.matrix_world.translation) - centre
        positions.append(p)
        co = world_to_camera_view(scene, camera, Vector(centre))
        assert (co.x, co.y) == pytest.approx((0.5, 0.5), abs=1e-3), frame  # the head stays in the middle
    radius = [np.hypot(p[0], p[1]) for p in positions]
    assert np.ptp(radius) < 1e-4 and radius[0] > 0.2 and np.ptp([p[2] for p in positions]) < 1e-4
    angle = [math.degrees(math.atan2(p[1], p[0])) for p in positions]
    turned = [(a - angle[0]) % 360.0 for a in angle]
    assert turned == pytest.approx([0.0, 45.0, 90.0, 180.0, 0.0], abs=1e-3)
    np.testing.assert_allclose(positions[-1], positions[0], atol=1e-6)


def test_cli_turntable_renders_the_frames(tmp_path):
    """scripts/pdehead.py --turntable 3 --render-animation DIR writes DIR/frame_0001.png ... frame_0003.png
    (the head seen from three sides); a DIR that cannot be written is exit 2 before any work."""
    import subprocess
    cli = Path(__file__).resolve().parents[2] / "scripts" / "pdehead.py"
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender-user"))

    def run(*args):
        return subprocess.run([sys.executable, str(cli), *map(str, args)], capture_output=True, text=True,
                              env=env, cwd=tmp_path)

    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    bad = run("--phantom", "--turntable", 3, "--render-animation", blocker / "frames")
    assert bad.returncode == 2 and "--render-animation" in bad.stderr and len(bad.stderr.splitlines()) == 1
    assert run("--phantom", "--render-animation", tmp_path / "x").returncode == 2  # needs --turntable

    frames = tmp_path / "turn"
    result = run("--phantom", "--no-volume", "--patches", 4, "--nu", 16, "--nv", 24, "--nw", 3, "--turntable", 3,
                 "--render-animation", frames, "--resolution", 32, "--render-samples", 2)
    assert result.returncode == 0, result.stderr[-3000:]
    assert sorted(p.name for p in frames.iterdir()) == ["frame_0001.png", "frame_0002.png", "frame_0003.png"]
    images = [blender_inspect.read_png(frames / f"frame_{f:04d}.png")[..., :3] for f in (1, 2, 3)]
    assert all(img.shape == (32, 32, 3) and img.std() > 0.02 for img in images)
    assert float(np.abs(images[0] - images[1]).mean()) > 0.005  # the camera moved between frames
    assert "turntable 3 frames" in result.stdout and "Fra:" not in result.stdout
