"""Still renders of study objects with Cycles on the CPU, and picture statistics for tests.

EEVEE and Workbench write blank images headless (no GPU), so every render goes
through Cycles CPU. :func:`render_objects_png` adds a temporary orthographic
camera framing the objects' world bounding box from a named view, a sun light
and a plain world colour, renders, and restores the scene as it was.

Views are named in patient terms (Blender world = LPS x 0.001):

========== =========================== ==================================
view       camera looks along          screen right / up
========== =========================== ==================================
FRONT      +Y (Blender numpad 1)       +X patient left / +Z superior
BACK       -Y                          -X / +Z
RIGHT      +X (sees the patient's right side)  -Y anterior / +Z
LEFT       -X (sees the patient's left side)   +Y posterior / +Z
TOP        -Z (Blender numpad 7)       +X / +Y posterior
THREE_QUARTER  from front-right-above  -
========== =========================== ==================================
"""
from __future__ import annotations

import os
from pathlib import Path
from types import MappingProxyType
from typing import Mapping

import bpy
import numpy as np
from mathutils import Matrix

from ...pdehead_addon import defaults as D
from .. import compat
from ..volume import material as volume_material, volume

#: The named views; read-only (a figure that needs another direction passes it as ``view``, see
#: :func:`view_basis`).
VIEWS: Mapping[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = MappingProxyType({
    # name: (direction the camera looks along, world up)
    "FRONT": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "BACK": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "RIGHT": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "LEFT": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "TOP": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
    "THREE_QUARTER": ((0.6, 1.0, -0.35), (0.0, 0.0, 1.0)),
})
assert set(VIEWS) == set(D.VIEWS), "every named view (defaults.VIEWS) needs its camera direction here"
BACKGROUND_RGB = (0.05, 0.05, 0.06)  # world colour (linear); dark so volumes' emission shows


def view_basis(view) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit (right, up, forward) world vectors of a view (forward = viewing direction).

    ``view`` is a name of :data:`VIEWS` or a ``(forward, up)`` pair of world vectors (a direction no
    named view has, e.g. a figure's camera from below).
    """
    if isinstance(view, str):
        try:
            forward, up = VIEWS[view]
        except KeyError:
            raise ValueError(f"unknown view {view!r}; choose from {sorted(VIEWS)}") from None
    else:
        forward, up = view
    f = np.asarray(forward, float)
    f /= np.linalg.norm(f)
    right = np.cross(f, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, f)
    return right, true_up, f


def world_bounds(objects, tight_volumes: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """World-space axis-aligned box (min, max) in metres of the objects' bounding boxes.

    With `tight_volumes`, a PDE Head Volume object in eq. 24 mode counts with the
    box of its solid only (its file also holds the whole CT box, which is empty
    in that mode); in intensity-alpha mode the whole CT box counts.
    """

    bpy.context.view_layer.update()
    pts = []
    for obj in objects:
        if obj.type == "VOLUME":
            box = volume.solid_box(obj) if tight_volumes else None
            if box is not None and volume_material.get_volume_settings(obj)["alpha_mode"] == "EQ24":
                pts.append(np.array(box))
                continue
            obj.data.grids.load()
        m = np.array(obj.matrix_world)
        corners = np.array([tuple(c) for c in obj.bound_box], float)
        pts.append(corners @ m[:3, :3].T + m[:3, 3])
    if not pts:
        raise ValueError("no objects to frame")
    pts = np.concatenate(pts)
    return pts.min(axis=0), pts.max(axis=0)


def _camera_matrix(right, up, forward, position):
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, -forward, position  # camera looks along -Z
    return Matrix(m.tolist())


#: Still-image file name endings and Blender's file format for them (anything else is refused by the CLI).
IMAGE_FORMATS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}


def _framing(objects, bounds, right, up, forward, res_x: int, res_y: int, margin: float):
    """(centre, span, depth) of the render's orthographic frame: the box of ``bounds`` or of the objects' world
    bounding boxes, its span across the view (times ``margin``, fitted to the image's aspect) and its depth."""
    if bounds is None:
        lo, hi = world_bounds(objects)
    else:
        lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    centre = 0.5 * (lo + hi)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    rel = corners - centre
    width_m = np.ptp(rel @ right)
    height_m = np.ptp(rel @ up)
    depth = float(np.ptp(rel @ forward))
    span = max(width_m, height_m * res_x / res_y) if res_x >= res_y else max(height_m, width_m * res_y / res_x)
    span = max(float(span) * margin, 1e-4)
    return centre, span, depth


def _image_path(path) -> tuple[Path, str]:
    """The resolved output path (its folder made) and Blender's file format for it: PNG unless it ends in a
    known still-image suffix (:data:`IMAGE_FORMATS`)."""
    path = Path(os.fspath(path))
    file_format = IMAGE_FORMATS.get(path.suffix.lower())
    path = (path if file_format else path.with_suffix(".png")).resolve()   # no known suffix: a PNG
    file_format = file_format or "PNG"
    path.parent.mkdir(parents=True, exist_ok=True)
    return path, file_format


def _isolate(scene, objects, extra: set, isolate: bool, hidden: dict, shown: dict) -> None:
    """Show ``objects`` in the render (and, with ``isolate``, hide every other object but the ``extra`` names);
    what it changed goes into ``hidden`` / ``shown`` (name -> object) for the caller to restore."""
    if isolate:
        keep = {o.name for o in objects} | extra
        for o in scene.objects:
            if o.name not in keep and not o.hide_render:
                hidden[o.name] = o
                o.hide_render = True
    for o in objects:  # asked for: rendered even if hidden in renders (e.g. by Frame Study)
        if o.hide_render:
            shown[o.name] = o
            o.hide_render = False


def render_objects_png(objects, path, view: str = D.VIEW.default, resolution=(160, 160),
                       samples: int = D.RENDER_SAMPLES.default,
                       transparent: bool = False, isolate: bool = True, margin: float = 1.08,
                       denoise: bool = False, volume_step_rate: float = 2.0, bounds=None,
                       scene=None) -> Path:
    """Render `objects` to a PNG with Cycles CPU from a named view, leaving the scene as it was.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
        What to frame (their world bounding boxes).
    path : path-like
        Output image: a PNG, or a JPEG when it ends in .jpg / .jpeg (:data:`IMAGE_FORMATS`).
    view : str or (forward, up)
        One of :data:`VIEWS` (FRONT looks along +Y like Blender's numpad 1), or a direction
        (:func:`view_basis`).
    resolution : (int, int)
        Width, height in pixels.
    samples : int
        Cycles samples per pixel.
    transparent : bool
        Transparent film (RGBA PNG) instead of the world colour.
    isolate : bool
        Hide every other object from the render meanwhile.
    margin : float
        Frame size relative to the tight bounding box.
    denoise : bool
        Cycles denoising (OpenImageDenoise), off by default for speed.
    volume_step_rate : float
        Cycles volume step rate (larger: faster, coarser); volumes use the
        biased ray marcher, several times faster and less noisy at low samples.
    bounds : (min, max) world metres, optional
        Frame this box instead of the objects' bounding boxes (e.g. to render
        several pictures with the same framing).

    Returns
    -------
    Path of the written PNG.
    """
    scene = scene or bpy.context.scene
    objects = list(objects)
    right, up, forward = view_basis(view)
    res_x, res_y = (int(r) for r in resolution)
    centre, span, depth = _framing(objects, bounds, right, up, forward, res_x, res_y, margin)
    distance = depth + span + 0.1
    path, file_format = _image_path(path)

    r, c = scene.render, scene.cycles
    saved = {
        "camera": scene.camera, "world": scene.world, "engine": r.engine, "res": (r.resolution_x, r.resolution_y),
        "pct": r.resolution_percentage, "transparent": r.film_transparent, "filepath": r.filepath,
        "format": r.image_settings.file_format, "color_mode": r.image_settings.color_mode,
        "depth": r.image_settings.color_depth, "view_transform": scene.view_settings.view_transform,
        "look": scene.view_settings.look, "exposure": scene.view_settings.exposure,
        "device": c.device, "samples": c.samples, "denoise": c.use_denoising,
        "step_rate": c.volume_step_rate, "biased": compat.cycles_volume_biased(c),
    }
    hidden, shown = {}, {}
    temporaries = []
    try:
        cam_data = bpy.data.cameras.new("PDE Head render camera")
        cam_data.type = "ORTHO"
        cam_data.ortho_scale = span
        cam_data.clip_start = 0.001
        cam_data.clip_end = 2.0 * distance + depth
        cam = bpy.data.objects.new("PDE Head render camera", cam_data)
        temporaries.append((cam, cam_data))
        scene.collection.objects.link(cam)
        cam.matrix_world = _camera_matrix(right, up, forward, centre - forward * distance)

        sun_data = bpy.data.lights.new("PDE Head render light", "SUN")
        sun_data.energy = 3.0
        sun_data.angle = np.radians(10.0)
        sun = bpy.data.objects.new("PDE Head render light", sun_data)
        temporaries.append((sun, sun_data))
        scene.collection.objects.link(sun)
        key = forward - 0.5 * up + 0.35 * right  # light from the camera's upper left, like a key light
        key /= np.linalg.norm(key)
        k_right = np.cross(key, up if abs(np.dot(key, up)) < 0.99 else right)
        k_right /= np.linalg.norm(k_right)
        sun.matrix_world = _camera_matrix(k_right, np.cross(k_right, key), key, centre - key * distance)

        world = bpy.data.worlds.new("PDE Head render world")
        compat.node_tree(world)  # nodes on where Blender < 5.0 starts without
        bg = world.node_tree.nodes.get("Background")
        bg.inputs["Color"].default_value = (*BACKGROUND_RGB, 1.0)
        bg.inputs["Strength"].default_value = 1.0
        temporaries.append((None, world))

        _isolate(scene, objects, {cam.name, sun.name}, isolate, hidden, shown)

        scene.camera = cam
        scene.world = world
        r.engine = "CYCLES"
        c.device = "CPU"
        c.samples = int(samples)
        c.use_denoising = bool(denoise)
        c.volume_step_rate = float(volume_step_rate)
        if saved["biased"] is not None:  # compat.cycles_volume_biased: None before Blender 5.0
            c.volume_biased = True
        r.resolution_x, r.resolution_y, r.resolution_percentage = res_x, res_y, 100
        r.film_transparent = bool(transparent)
        r.image_settings.file_format = file_format
        r.image_settings.color_mode = "RGBA" if transparent and file_format == "PNG" else "RGB"
        if file_format == "PNG":
            r.image_settings.color_depth = "8"
        scene.view_settings.view_transform = "Standard"
        scene.view_settings.look = "None"
        scene.view_settings.exposure = 0.0
        r.filepath = str(path)
        bpy.ops.render.render(write_still=True, scene=scene.name)
    finally:
        for o in hidden.values():
            o.hide_render = False
        for o in shown.values():
            o.hide_render = True
        scene.camera = saved["camera"]
        scene.world = saved["world"]
        r.engine = saved["engine"]
        r.resolution_x, r.resolution_y = saved["res"]
        r.resolution_percentage = saved["pct"]
        r.film_transparent = saved["transparent"]
        r.filepath = saved["filepath"]
        r.image_settings.file_format = saved["format"]
        r.image_settings.color_mode = saved["color_mode"]
        r.image_settings.color_depth = saved["depth"]
        scene.view_settings.view_transform = saved["view_transform"]
        scene.view_settings.look = saved["look"]
        scene.view_settings.exposure = saved["exposure"]
        c.device, c.samples, c.use_denoising = saved["device"], saved["samples"], saved["denoise"]
        c.volume_step_rate = saved["step_rate"]
        if saved["biased"] is not None:
            c.volume_biased = saved["biased"]
        for obj, data in temporaries:
            if obj is not None:
                bpy.data.objects.remove(obj)
            if isinstance(data, bpy.types.World):
                bpy.data.worlds.remove(data)
            elif isinstance(data, bpy.types.Camera):
                bpy.data.cameras.remove(data)
            elif isinstance(data, bpy.types.Light):
                bpy.data.lights.remove(data)
    if not path.is_file():
        raise RuntimeError(f"Cycles did not write {path}")
    return path


