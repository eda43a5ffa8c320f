"""Patient LPS millimetres <-> Blender world metres.

Blender world coordinates are patient LPS coordinates scaled by 0.001, axes
unchanged: +X is the patient's left, +Y posterior, +Z superior. Blender's front
view (numpad 1) looks along +Y, so it shows the face with the patient's left on
the screen's right; distances measured in Blender are patient mm / 1000.
"""
from __future__ import annotations

import numpy as np

MM_TO_M = 0.001


def lps_to_blender(points_mm: np.ndarray) -> np.ndarray:
    """Blender world coordinates (metres) of patient LPS points in mm, shape preserved."""
    return np.asarray(points_mm, dtype=np.float64) * MM_TO_M


def blender_to_lps(points_m: np.ndarray) -> np.ndarray:
    """Patient LPS mm of Blender world points in metres (inverse of :func:`lps_to_blender`)."""
    return np.asarray(points_m, dtype=np.float64) / MM_TO_M


def grid_affine_world(spacing, origin, direction) -> np.ndarray:
    """4x4 matrix from voxel index ``(i, j, k, 1)`` to Blender world metres.

    Parameters
    ----------
    spacing : (dz, dy, dx)
        Voxel size in mm, in the engine's ``[z, y, x]`` order.
    origin : (x, y, z)
        Patient LPS mm of voxel ``(k, j, i) = (0, 0, 0)``.
    direction : (3, 3)
        Columns are the LPS unit vectors of the i, j and k axes.

    Notes
    -----
    The index order is ``(i, j, k)`` = (x, y, z) as OpenVDB and Blender use it,
    i.e. the reverse of the numpy ``[k, j, i]`` array order (see
    :class:`pdehead_addon.CTVolume`).
    """
    dz, dy, dx = (float(s) for s in spacing)
    m = np.eye(4)
    m[:3, :3] = np.asarray(direction, dtype=np.float64).reshape(3, 3) * np.array([dx, dy, dz]) * MM_TO_M
    m[:3, 3] = np.asarray(origin, dtype=np.float64).reshape(3) * MM_TO_M
    return m


def grid_matrix_world(spacing, origin, direction):
    """:func:`grid_affine_world` as a ``mathutils.Matrix`` (voxel index -> world metres)."""
    from mathutils import Matrix

    return Matrix(grid_affine_world(spacing, origin, direction).tolist())
