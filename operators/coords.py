"""Patient LPS millimetres <-> Blender world metres.

Blender world coordinates are patient LPS coordinates scaled by 0.001, axes
unchanged: +X is the patient's left, +Y posterior, +Z superior. Blender's front
view (numpad 1) looks along +Y, so it shows the face with the patient's left on
the screen's right; distances measured in Blender are patient mm / 1000.
"""
from __future__ import annotations

import numpy as np
from mathutils import Vector

from ..pdehead_addon import grid_affine

MM_TO_M = 0.001

#: The study collection's custom property holding its world origin (metres).
ORIGIN_KEY = "pdehead_origin_m"


def grid_affine_world(spacing, origin, direction) -> np.ndarray:
    """4x4 matrix from voxel index ``(i, j, k, 1)`` to Blender world metres.

    The engine's :func:`pdehead_addon.core.ct_volume.grid_affine` (same arguments: spacing ``(dz, dy, dx)``
    mm, origin ``(x, y, z)`` LPS mm, direction columns of the i, j, k axes) scaled to metres.
    """
    m = grid_affine(spacing, origin, direction)
    m[:3, :] *= MM_TO_M  # LPS mm -> Blender metres (axes unchanged)
    return m


def study_origin(collection, points_m: np.ndarray | None = None):
    """World origin (metres, ``mathutils.Vector``) shared by the study's objects.

    The first call with points stores the centre of their bounding box on the
    collection; later calls return the stored value, so every object of the
    study pivots about the same point and rebuilding never moves it.
    """
    if ORIGIN_KEY in collection.keys():
        return Vector(tuple(collection[ORIGIN_KEY]))
    if points_m is None or len(points_m) == 0:
        return Vector((0.0, 0.0, 0.0))
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    collection[ORIGIN_KEY] = [float(c) for c in centre]
    return Vector(tuple(float(c) for c in centre))
