"""Cycles CPU renders of study objects (operators/scene/render.py): not blank, oriented, eq. 24 vs baseline.

Small pictures (96-160 px, 8-16 samples). Renders are written to pytest's tmp_path; set
PDEHEAD_KEEP_RENDERS=<folder> to keep copies for looking at them.
"""
from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

import blender_inspect  # tests/blender/blender_inspect.py

MM = 0.001


def eevee_engine() -> str:
    """The EEVEE render-engine id: ``BLENDER_EEVEE_NEXT`` in 4.2 - 4.5, ``BLENDER_EEVEE`` before and from 5.0."""
    import bpy

    return "BLENDER_EEVEE_NEXT" if (4, 2, 0) <= bpy.app.version < (5, 0, 0) else "BLENDER_EEVEE"


@pytest.fixture(scope="module")
def cthead_head(cthead_bset):
    from pdehead_addon import solve_pde
    return solve_pde(cthead_bset)


def _keep(path, name):
    folder = os.environ.get("PDEHEAD_KEEP_RENDERS")
    if folder:
        os.makedirs(folder, exist_ok=True)
        shutil.copy(path, os.path.join(folder, name))
    return path


def _emissive(ext, name, rgb):
    import bpy
    mat = bpy.data.materials.new(name)
    bsdf = ext.compat.node_tree(mat).nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*rgb, 1.0)
    bsdf.inputs["Emission Color"].default_value = (*rgb, 1.0)
    bsdf.inputs["Emission Strength"].default_value = 1.0
    mat.cycles.emission_sampling = "NONE"  # a marker, not a lamp: no coloured light spilling onto the head
    return mat


def _marker(ext, coll, name, centre_mm, rgb, size_mm=8.0):
    from pdehead_addon import Mesh
    h = size_mm / 2
    cube = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)]) + np.asarray(centre_mm)
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    obj = ext.scene.objects.build_mesh_object(Mesh(cube, quads), coll, name)
    obj.data.materials.append(_emissive(ext, name, rgb))
    obj.visible_diffuse = obj.visible_glossy = obj.visible_transmission = False  # no light onto the head
    obj.visible_shadow = False
    return obj


def _colour_centroid(path, channel):
    img = B_render_read(path)
    others = [c for c in range(3) if c != channel]
    mask = (img[..., channel] > 0.6) & (img[..., others].max(axis=2) < 0.35)
    assert mask.sum() >= 4, "marker not visible"
    rows, cols = np.nonzero(mask)
    return cols.mean() / img.shape[1], rows.mean() / img.shape[0]


def B_render_read(path):
    from PIL import Image
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), np.float32) / 255.0


def test_front_render_shows_the_face_with_the_patients_left_on_the_right(ext, phantom, phantom_head, tmp_path):
    coll = ext.scene.objects.study_collection("Phantom")
    surface = ext.scene.objects.build_surface(phantom_head, coll, nu=60, nv=90)
    world_mm = blender_inspect.mesh_world_vertices(surface) / MM
    left = np.array([world_mm[:, 0].max() + 12.0, world_mm[:, 1].mean(), 0.0])  # beside the patient's left side
    front = np.asarray(phantom.params["nose_tip"]) + [0.0, -10.0, 25.0]         # in front of the face
    red = _marker(ext, coll, "left marker", left, (1.0, 0.0, 0.0))
    green = _marker(ext, coll, "front marker", front, (0.0, 1.0, 0.0))
    objs = [surface, red, green]
    png = _keep(ext.scene.render.render_objects_png(objs, tmp_path / "front.png", "FRONT", (128, 128), 16),
                "phantom_surface_front.png")
    stats = blender_inspect.image_stats(png)
    assert (stats["width"], stats["height"]) == (128, 128)
    assert 0.05 < stats["foreground_fraction"] < 0.8 and stats["std"] > 0.05
    assert abs(stats["centroid"][0] - 0.5) < 0.1  # the head is centred
    x_red, _ = _colour_centroid(png, 0)
    x_green, _ = _colour_centroid(png, 1)
    assert x_red > 0.75 and abs(x_green - 0.5) < 0.1  # patient's left on screen right; face marker centred
    # the patient's right side (camera at -X): anterior (the green marker) on the screen's right
    png = _keep(ext.scene.render.render_objects_png(objs, tmp_path / "right.png", "RIGHT", (128, 128), 8),
                "phantom_surface_right.png")
    assert _colour_centroid(png, 1)[0] > 0.75
    # top view (numpad 7): patient's left on the right, face at the bottom
    png = ext.scene.render.render_objects_png(objs, tmp_path / "top.png", "TOP", (96, 96), 8)
    assert _colour_centroid(png, 0)[0] > 0.75 and _colour_centroid(png, 1)[1] > 0.75


def test_render_restores_the_scene(ext, phantom_head, tmp_path):
    import bpy
    scene = bpy.context.scene
    coll = ext.scene.objects.study_collection("Phantom")
    surface = ext.scene.objects.build_surface(phantom_head, coll, nu=20, nv=30)
    other = bpy.data.objects.new("user empty", None)
    scene.collection.objects.link(other)
    user_cam = bpy.data.objects.new("user camera", bpy.data.cameras.new("user camera"))
    scene.collection.objects.link(user_cam)
    scene.camera = user_cam
    scene.render.engine = eevee_engine()
    scene.render.resolution_x, scene.render.resolution_y = 1920, 1080
    scene.cycles.samples = 77
    world = scene.world
    counts = {k: len(getattr(bpy.data, k)) for k in ("objects", "cameras", "lights", "worlds", "materials")}
    png = ext.scene.render.render_objects_png([surface], tmp_path / "s.png", "THREE_QUARTER", (96, 96), 8,
                                              transparent=True)
    stats = blender_inspect.image_stats(png)
    assert blender_inspect.read_png(png).shape == (96, 96, 4)
    assert 0.05 < stats["foreground_fraction"] < 0.8  # from alpha
    assert scene.camera == user_cam and scene.render.engine == eevee_engine() and scene.world == world
    assert (scene.render.resolution_x, scene.render.resolution_y, scene.cycles.samples) == (1920, 1080, 77)
    assert not other.hide_render and not scene.render.film_transparent
    assert {k: len(getattr(bpy.data, k)) for k in counts} == counts  # temporaries removed
    with pytest.raises(ValueError):
        ext.scene.render.render_objects_png([surface], tmp_path / "x.png", "DIAGONAL")


def _silhouette(ext, objs, bounds, path, resolution):
    png = ext.scene.render.render_objects_png(objs, path, "FRONT", resolution, 4, transparent=True, bounds=bounds)
    return blender_inspect.image_stats(png)["mask"]


def _dilate(mask, r):
    from scipy.ndimage import binary_dilation
    return binary_dilation(mask, iterations=r)


def _compare_eq24_and_baseline(ext, ct, head, wfield, tmp_path, tag, view="FRONT", res=(128, 128), samples=12):
    coll = ext.scene.objects.study_collection(tag)
    surface = ext.scene.objects.build_surface(head, coll, nu=60, nv=90)
    vol = ext.volume.volume.build_volume(wfield, coll, tmp_path / f"{tag}.vdb", ct=ct)
    bounds = ext.scene.render.world_bounds([vol])  # same framing for every picture: the whole CT box
    kw = dict(resolution=res, samples=samples, bounds=bounds, volume_step_rate=4.0)
    eq24 = _keep(ext.scene.render.render_objects_png([vol], tmp_path / "eq24.png", view, **kw),
                 f"{tag}_volume_eq24.png")
    ext.volume.material.set_volume_settings(vol, alpha_mode="INTENSITY")
    base = _keep(ext.scene.render.render_objects_png([vol], tmp_path / "int.png", view, **kw),
                 f"{tag}_volume_intensity_alpha.png")
    ext.volume.material.set_volume_settings(vol, alpha_mode="EQ24", colour_preset="skin")
    _keep(ext.scene.render.render_objects_png([vol], tmp_path / "skin.png", view, **kw), f"{tag}_volume_eq24_skin.png")
    head_mask = ext.scene.render.render_objects_png([surface], tmp_path / "sil.png", view, res, 4, transparent=True,
                                            bounds=bounds)
    head_mask = _dilate(blender_inspect.image_stats(head_mask)["mask"], 3)
    s24, sint = blender_inspect.image_stats(eq24), blender_inspect.image_stats(base)
    for s in (s24, sint):
        assert 0.05 < s["foreground_fraction"] < 0.8 and s["std"] > 0.03
    diff = np.abs(B_render_read(eq24) - B_render_read(base)).mean()
    outside_24 = (s24["mask"] & ~head_mask).mean()
    outside_int = (sint["mask"] & ~head_mask).mean()
    print(f"{tag}: fg eq24 {s24['foreground_fraction']:.3f} baseline {sint['foreground_fraction']:.3f}; "
          f"mean |diff| {diff:.3f}; outside the head: eq24 {outside_24:.4f} baseline {outside_int:.4f}")
    assert diff > 0.03
    assert outside_24 < 0.005            # eq. 24: nothing outside the PDE solid
    # the baseline (alpha = CT intensity) shows the CT near the head only: neither the air noise of the
    # CT box (a faint box outline) nor the scanner table (bright bars) - the ct grid is masked to
    # HEAD_MARGIN_MM around the solid
    assert outside_int < 0.03
    # inside the head eq. 24 is translucent (alpha 0.1 at the skin): the baseline is brighter there
    assert sint["foreground_mean"] > 0.0 and s24["mask"][head_mask].mean() > 0.5


def test_volume_eq24_differs_from_intensity_alpha_on_the_phantom(ext, phantom, phantom_head, tmp_path):
    wfield = phantom_head.w_field(3.0, ct=phantom.ct)
    _compare_eq24_and_baseline(ext, phantom.ct, phantom_head, wfield, tmp_path, "phantom")


def test_cthead_surface_and_volume_renders(ext, cthead_ct, cthead_head, tmp_path):
    coll = ext.scene.objects.study_collection("CThead")
    surface = ext.scene.objects.build_surface(cthead_head, coll, nu=80, nv=120)
    for view in ("FRONT", "LEFT"):
        png = _keep(ext.scene.render.render_objects_png([surface], tmp_path / f"{view}.png", view, (160, 160), 16),
                    f"cthead_surface_{view.lower()}.png")
        stats = blender_inspect.image_stats(png)
        assert 0.05 < stats["foreground_fraction"] < 0.8 and stats["std"] > 0.05
    wfield = cthead_head.w_field(3.0, ct=cthead_ct)
    _compare_eq24_and_baseline(ext, cthead_ct, cthead_head, wfield, tmp_path, "cthead", view="LEFT")
