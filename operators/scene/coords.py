"""Patient LPS millimetres <-> Blender world metres.

Blender world coordinates are patient LPS coordinates scaled by 0.001, axes
unchanged: +X is the patient's left, +Y posterior, +Z superior. Blender's front
view (numpad 1) looks along +Y, so it shows the face with the patient's left on
the screen's right; distances measured in Blender are patient mm / 1000.
"""
from __future__ import annotations

import numpy as np

from ...pdehead_addon import grid_affine

MM_TO_M = 0.001


def grid_affine_world(spacing, origin, direction) -> np.ndarray:
    """4x4 matrix from voxel index ``(i, j, k, 1)`` to Blender world metres.

    The engine's :func:`pdehead_addon.core.ct_volume.grid_affine` (same arguments: spacing ``(dz, dy, dx)``
    mm, origin ``(x, y, z)`` LPS mm, direction columns of the i, j, k axes) scaled to metres.
    """
    m = grid_affine(spacing, origin, direction)
    m[:3, :] *= MM_TO_M  # LPS mm -> Blender metres (axes unchanged)
    return m
