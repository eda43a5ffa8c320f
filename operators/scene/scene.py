"""A scene ready to render: camera and key light on the study's head, one object shown, the view framed.

:func:`frame_study` (operator "Frame Study", and the last step of the pipeline for a new study):

- a perspective camera "<study> Camera" in front of the head (Blender's front view: it looks along
  +Y, so it sees the face with the patient's left on the right), framing the shown object, made the
  scene camera. Its focal length is a driver of the scene's render size, so the head's box fills
  1 / MARGIN of the frame's tight side at any size and shape of picture (square, landscape, portrait);
- an area key light "<study> Key Light" from the camera's upper left and a soft fill light
  "<study> Fill Light" on the camera (its child: it goes where the camera goes), so every face the
  camera sees gets light, a cut face in the key light's shadow too; all three live in the study
  collection (re-used when framing again, removed with the study);
- Blender's untouched startup cube (2 m, around the 0.2 m head, so F12 would render the cube) is
  hidden in the viewport and in renders; a cube the user changed is left alone;
- the chosen object (default: the surface) is shown and the study's other objects, which overlap it,
  are hidden (viewport and render); the user can show them again as usual;
- every 3D view of the open windows looks at the head from the front (headless Blender has none).
"""
from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from ...pdehead_addon import PDEHeadError, defaults as D
from .. import state
from . import render

CAMERA_KIND = "camera"
LIGHT_KIND = "key_light"
FILL_KIND = "fill_light"
SHOW_ITEMS = [
    ("SURFACE", "Surface", "Show the PDE surface, hide the solid, curves and volume"),
    ("SOLID", "Solid", "Show the PDE solid (cutaways), hide the others"),
    ("VOLUME", "Volume", "Show the volume, hide the others"),
    ("CURVES", "Boundary Curves", "Show the boundary curves, hide the others"),
]
assert tuple(key for key, *_ in SHOW_ITEMS) == D.SHOW.choices, "every object Frame Study shows is in defaults.SHOW"
_SHOW_ATTR = {"SURFACE": "surface_object", "SOLID": "solid_object", "VOLUME": "volume_object",
              "CURVES": "curves_object"}
FOCAL_MM = 85.0      # a portrait lens: little perspective distortion of the face
SENSOR_MM = 36.0
MARGIN = 1.15        # frame size relative to the head's extent
#: The fill light's power over the key light's: enough that a face in the key's shadow (a cut face,
#: the far side of a turned head) keeps a fifth of the lit skin's brightness, little enough that the
#: key still models the face.
FILL_RATIO = 0.35


def is_startup_cube(obj) -> bool:
    """True for Blender's default cube as the startup file makes it (name, 8 vertices at +-1 m, at the
    origin, unrotated, unscaled, no modifiers): the one object a new study may hide without asking."""
    if obj is None or obj.type != "MESH" or obj.name != "Cube" or obj.data.name != "Cube":
        return False
    if len(obj.modifiers) or len(obj.data.vertices) != 8:
        return False
    if not np.allclose(np.array(obj.matrix_world), np.eye(4), atol=1e-6):
        return False
    co = np.empty(24, np.float32)
    obj.data.vertices.foreach_get("co", co)
    return bool(np.allclose(np.abs(co), 1.0, atol=1e-6))


def _set_visible(obj, visible: bool, view_layer) -> None:
    obj.hide_render = not visible
    obj.hide_viewport = False  # the global switch stays on; the eye icon (per view layer) hides it
    try:
        obj.hide_set(not visible, view_layer=view_layer)
    except RuntimeError:  # not in this view layer
        pass


def study_object(coll, kind: str):
    for obj in coll.objects:
        if obj.get("pdehead_kind") == kind:
            return obj
    return None


def _look_along(forward, up):
    """Rotation matrix (3x3) of a camera/light looking along `forward` with `up` on top (local -Z forward)."""
    f = np.asarray(forward, float)
    f /= np.linalg.norm(f)
    right = np.cross(f, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, f)
    return np.column_stack([right, true_up, -f])


def _matrix(rotation, position):
    m = np.eye(4)
    m[:3, :3] = rotation
    m[:3, 3] = position
    return Matrix(m.tolist())


def frame_study(context, coll, show: str = D.SHOW.default, view: str = D.VIEW.default, hide_cube: bool = True) -> dict:
    """Set the scene up to render study `coll` (see the module docstring); returns what it did.

    Parameters
    ----------
    show : {"SURFACE", "SOLID", "VOLUME", "CURVES"}
        The study object to show (the others are hidden); falls back to the first that exists.
    view : str
        A view of :data:`render.VIEWS` for the camera (FRONT: the face).
    hide_cube : bool
        Hide the untouched startup cube.
    """

    scene = context.scene
    view_layer = context.view_layer
    s = state.settings(coll)
    order = [show] + [k for k in _SHOW_ATTR if k != show]
    shown = next((getattr(s, _SHOW_ATTR[k]) for k in order if getattr(s, _SHOW_ATTR[k]) is not None), None)
    if shown is None:
        raise PDEHeadError(f"study '{coll.name}' has no object to frame yet: run the pipeline first")
    for attr in _SHOW_ATTR.values():
        obj = getattr(s, attr)
        if obj is not None:
            _set_visible(obj, obj == shown, view_layer)
    hidden_cube = None
    if hide_cube:
        cube = scene.objects.get("Cube")
        if is_startup_cube(cube) and not cube.hide_render:
            _set_visible(cube, False, view_layer)
            hidden_cube = cube.name

    lo, hi = render.world_bounds([shown])
    centre = 0.5 * (lo + hi)
    right, up, forward = render.view_basis(view)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    rel = corners - centre
    width, height = float(np.ptp(rel @ right)), float(np.ptp(rel @ up))
    depth = float(np.ptp(rel @ forward))
    # the box's near face fills 1 / MARGIN of the frame's tight side; at a square frame with the 85 mm lens
    near = FOCAL_MM * MARGIN * max(width, height) / SENSOR_MM
    distance = near + 0.5 * depth
    cam = study_object(coll, CAMERA_KIND)
    if cam is None:
        cam = bpy.data.objects.new(f"{coll.name} Camera", bpy.data.cameras.new(f"{coll.name} Camera"))
        cam["pdehead_kind"] = CAMERA_KIND
        coll.objects.link(cam)
    cam.data.type = "PERSP"
    cam.data.lens, cam.data.sensor_width, cam.data.sensor_fit = FOCAL_MM, SENSOR_MM, "AUTO"
    fit_lens_to_render_size(cam, scene, MARGIN * width / (2.0 * near), MARGIN * height / (2.0 * near))
    cam.data.clip_start = max(1e-3, 0.05 * distance)
    cam.data.clip_end = 10.0 * (distance + depth)
    cam.matrix_world = _matrix(_look_along(forward, up), centre - forward * distance)
    scene.camera = cam

    light = study_object(coll, LIGHT_KIND)
    if light is None:
        light = bpy.data.objects.new(f"{coll.name} Key Light", bpy.data.lights.new(f"{coll.name} Key Light", "AREA"))
        light["pdehead_kind"] = LIGHT_KIND
        coll.objects.link(light)
    size = max(width, height)
    key = forward - 0.6 * up + 0.5 * right  # from the camera's upper left, like a portrait key light
    key /= np.linalg.norm(key)
    light_distance = 2.5 * size + 0.5 * depth
    light.data.shape, light.data.size = "DISK", 1.5 * size
    # ~ the same irradiance at the head for any head size: power grows with distance squared
    light.data.energy = 12.0 * (light_distance / 0.5) ** 2
    light.matrix_world = _matrix(_look_along(key, up), centre - key * light_distance)
    fill = study_object(coll, FILL_KIND)
    if fill is None:
        fill = bpy.data.objects.new(f"{coll.name} Fill Light", bpy.data.lights.new(f"{coll.name} Fill Light", "AREA"))
        fill["pdehead_kind"] = FILL_KIND
        coll.objects.link(fill)
    fill.data.shape, fill.data.size = "DISK", 1.5 * size
    fill.data.energy = FILL_RATIO * 12.0 * (distance / 0.5) ** 2
    fill.parent = cam
    fill.matrix_parent_inverse.identity()
    fill.matrix_basis = _matrix(np.eye(3), np.zeros(3))          # at the camera, looking where it looks
    for obj in (cam, light, fill):
        _set_visible(obj, True, view_layer)
        obj.hide_render = False

    framed = _frame_views(context, centre, distance, forward, up)
    return {"shown": shown.name, "camera": cam.name, "light": light.name, "fill": fill.name, "hidden_cube": hidden_cube,
            "views_framed": framed, "distance_m": distance}


def fit_lens_to_render_size(cam, scene, tan_x: float, tan_y: float) -> None:
    """Drive the camera's focal length by the scene's render size: the widest lens angle that still shows
    ``tan_x`` / ``tan_y`` (half the view's width / height over the distance) at the current aspect.

    With ``sensor_fit`` AUTO the sensor width spans the picture's longer side, so for an aspect ``a = x / y``
    the half angles are ``tan = S / 2f`` along the longer side and ``S / 2f`` times ``min(a, 1 / a)`` along
    the shorter one; the focal length is the smaller of the two that fit. A simple expression (min, /,
    no Python), so it runs in files opened with scripts disabled and at render time from the render size
    of that moment (F12 or the command line's ``-o`` at any resolution).
    """
    half_sensor = 0.5 * float(cam.data.sensor_width)
    cam.data.driver_remove("lens")
    drv = cam.data.driver_add("lens").driver
    drv.type = "SCRIPTED"
    for name, path in (("rx", "render.resolution_x"), ("ry", "render.resolution_y")):
        var = drv.variables.new()
        var.name, var.type = name, "SINGLE_PROP"
        var.targets[0].id_type = "SCENE"
        var.targets[0].id = scene
        var.targets[0].data_path = path
    drv.expression = (f"{half_sensor:.6g} * min(min(rx / max(ry, 1), 1) / {tan_x:.6g}, "
                      f"min(ry / max(rx, 1), 1) / {tan_y:.6g})")
    aspect = scene.render.resolution_x / max(scene.render.resolution_y, 1)
    cam.data.lens = half_sensor * min(min(aspect, 1.0) / tan_x, min(1.0 / aspect, 1.0) / tan_y)


def _frame_views(context, centre, distance, forward, up) -> int:
    """Point every 3D view of the open windows at the head along `forward`; returns how many."""
    wm = getattr(context, "window_manager", None)
    count = 0
    for window in getattr(wm, "windows", []) or []:
        for area in window.screen.areas:
            if area.type != "VIEW_3D":
                continue
            for space in area.spaces:
                if space.type != "VIEW_3D" or space.region_3d is None:
                    continue
                r3d = space.region_3d
                rot = Matrix(_look_along(forward, up).tolist()).to_quaternion()
                r3d.view_rotation = rot
                r3d.view_location = tuple(float(c) for c in centre)
                r3d.view_distance = float(distance)
                r3d.view_perspective = "PERSP"
                if space.clip_end < 10 * distance:
                    space.clip_end = 10 * distance
                count += 1
    return count
