"""A scene ready to render: the pipeline in Blender's startup scene gives a camera, a key light and F12 shows the face.

Renders with the scene's own camera (what F12 does), Cycles CPU at 96 px. Set PDEHEAD_KEEP_RENDERS=<folder>
to keep the picture.
"""
from __future__ import annotations

import os
import shutil

import numpy as np

import blender_inspect  # tests/blender/blender_inspect.py


def _f12(scene, path):
    import bpy
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 8
    scene.render.filepath = str(path)
    scene.render.image_settings.file_format = "PNG"
    bpy.ops.render.render(write_still=True)
    return path


def test_pipeline_in_the_startup_scene_frames_the_face_and_f12_renders_it(ext, tmp_path):
    import bpy
    bpy.ops.wm.read_homefile(use_empty=False)  # Blender's startup scene: cube, camera, light
    scene = bpy.context.scene
    cube = scene.objects["Cube"]
    assert ext.scene.is_startup_cube(cube)
    scene.render.resolution_x = scene.render.resolution_y = 96
    scene.render.resolution_percentage = 100
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=6, nu=40, nv=80, nw=4,
                                        build_volume=False) == {'FINISHED'}
    coll = scene.pdehead.active_study
    s = coll.pdehead
    # the 2 m startup cube (around the 0.2 m head) is hidden; surface shown; solid and curves hidden
    assert cube.hide_render and cube.hide_get()
    assert not s.surface_object.hide_render and not s.surface_object.hide_get()
    for obj in (s.solid_object, s.curves_object):
        assert obj.hide_render and obj.hide_get()
    cam = scene.camera
    assert cam.get("pdehead_kind") == "camera" and cam.name in coll.objects and cam.data.type == "PERSP"
    head_lo, head_hi = ext.render.world_bounds([s.surface_object])
    m = np.array(cam.matrix_world)
    assert m[1, 3] < head_lo[1] - 0.1  # in front of the face (anterior is -Y)
    np.testing.assert_allclose(-m[:3, 2], [0.0, 1.0, 0.0], atol=1e-6)  # looking along +Y: the front view
    np.testing.assert_allclose(m[:3, 1], [0.0, 0.0, 1.0], atol=1e-6)  # head up
    centre = 0.5 * (head_lo + head_hi)
    assert abs(m[0, 3] - centre[0]) < 1e-3 and abs(m[2, 3] - centre[2]) < 1e-3
    light = next(o for o in coll.objects if o.get("pdehead_kind") == "key_light")
    assert light.type == "LIGHT" and not light.hide_render

    png = _f12(scene, tmp_path / "f12.png")
    if os.environ.get("PDEHEAD_KEEP_RENDERS"):
        os.makedirs(os.environ["PDEHEAD_KEEP_RENDERS"], exist_ok=True)
        shutil.copy(png, os.path.join(os.environ["PDEHEAD_KEEP_RENDERS"], "scene_f12.png"))
    stats = blender_inspect.image_stats(png)
    # the head fills the middle of the frame (not the cube, which would fill all of it), skin-coloured
    assert 0.25 < stats["foreground_fraction"] < 0.8, stats["foreground_fraction"]
    cx, cy = stats["centroid"]
    assert abs(cx - 0.5) < 0.08 and abs(cy - 0.5) < 0.12
    img = blender_inspect.read_png(png)
    fg = img[stats["mask"]][:, :3]
    assert fg[:, 0].mean() > fg[:, 2].mean() + 0.05  # warm skin, lit
    x0, y0, x1, y1 = stats["bbox"]
    assert x0 > 2 and x1 < 93 and y0 > 0  # the whole head is inside the picture

    # framing again with the solid: the same camera moves, the solid is shown, the surface hidden
    assert bpy.ops.pdehead.frame_study(show='SOLID') == {'FINISHED'}
    assert scene.camera == cam and len([o for o in coll.objects if o.get("pdehead_kind") == "camera"]) == 1
    assert not s.solid_object.hide_render and s.surface_object.hide_render


def test_a_changed_cube_is_left_alone_and_each_study_gets_its_camera(ext):
    import bpy
    bpy.ops.wm.read_homefile(use_empty=False)
    scene = bpy.context.scene
    cube = scene.objects["Cube"]
    cube.scale = (0.05, 0.05, 0.05)  # the user's own object now
    bpy.context.view_layer.update()
    assert not ext.scene.is_startup_cube(cube)
    for _ in range(2):
        assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=4, nu=20, nv=30, nw=3,
                                            build_volume=False) == {'FINISHED'}
    assert not cube.hide_render and not cube.hide_get()
    studies = ext.state.studies()
    assert len(studies) == 2
    cams = [next(o for o in c.objects if o.get("pdehead_kind") == "camera") for c in studies]
    assert cams[0] != cams[1] and scene.camera == cams[1]  # the newest study is framed
    scene.pdehead.active_study = studies[0]
    assert bpy.ops.pdehead.frame_study() == {'FINISHED'}
    assert scene.camera == cams[0]
    assert bpy.ops.pdehead.remove_study(study=studies[0].name) == {'FINISHED'}
    assert cams[1].name in bpy.data.objects and not any(c.users == 0 for c in bpy.data.cameras)
