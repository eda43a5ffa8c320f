"""The PDE head volume: a .vdb of the w-field and the CT, rendered by paper eq. 24 in shader nodes.

Section 4.3 of the paper renders the head by 3D texture mapping the CT onto the
PDE solid (eq. 23) with the opacity of each texel tied linearly to the solid's
parameter w (eq. 24)::

    alpha = (l_alpha - h_alpha) * w + h_alpha,   0 <= w <= 1

so the spine (w = 0) is the most opaque and the outer surface (w = 1) the most
transparent, and nothing outside the solid is drawn. Here the w-field sampled on
a voxel grid (the engine's ``WField``) goes into an OpenVDB file with three
float grids:

``w``
    w in [0, 1] inside the solid; outside voxels hold the engine's background value
    ``OUTSIDE_W`` (> 1, :mod:`pdehead_addon.pde.pde_solid`), which the shader maps to zero density.
``intensity``
    the CT intensity inside the solid, windowed to [0, 1]; 0 outside.
``ct``
    the whole CT box windowed to [0, 1] (on the w-field's grid when that is the
    CT's grid, else on the CT's own grid at about the same voxel size): the input of the
    paper's baseline "intuitive texture mapping" (Fig. 8a / 15a), whose alpha is
    the pixel value itself, noise outside the head included.

A Volume object (this module) reads the file by a relative path (``//pdehead_vdb/<study>.vdb``)
because .vdb files cannot be packed into a .blend. Its material computes the
density from the ``w`` grid *in shader nodes* (node group "PDE Head eq. 24"), so
l_alpha, h_alpha and the density scale change live without rewriting the file.

The modules: :mod:`.vdb_files` (where the files go), :mod:`.vdb_grids` (the grids and the write),
:mod:`.material` (eq. 24 in shader nodes) and this one (the Volume object).
"""
from __future__ import annotations

import os
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from ...pdehead_addon import intensity_window
from ..coords import grid_affine_world, study_origin
from .material import ensure_volume_material, set_volume_settings
from .vdb_files import VDB_FOLDER_NAME, blender_filepath, fresh_vdb_path, supersede
from .vdb_grids import REQUIRED_GRIDS, write_vdb


# ----------------------------------------------------------------------------- the Volume object
def build_volume(wfield, collection, vdb_path, name: str = "Volume", obj=None, *, window=None, ct=None,
                 **settings):
    """Write `wfield` to `vdb_path` and show it as a Volume object with the eq. 24 material.

    Parameters
    ----------
    wfield : WField
        From ``PDEHead.w_field``.
    collection : bpy.types.Collection
        The study collection (its stored origin becomes the object's origin).
    vdb_path : path-like
        Absolute path of the .vdb (see :func:`vdb_path_for`); stored as
        ``//``-relative when it lies beside the saved .blend.
    obj : bpy.types.Object, optional
        An existing Volume object to update in place (keeps its material).
    window : (lo, hi), optional
        Intensity window; default :func:`intensity_window` of `ct` (or of the
        w-field's intensity inside the solid).
    ct : CTVolume, optional
        Full CT for the ``ct`` grid (intensity-alpha baseline).
    **settings
        Passed to :func:`set_volume_settings`.
    """

    if window is None:
        if ct is not None:
            window = intensity_window(ct)
        else:
            inside = np.asarray(wfield.w) <= 1.0
            window = intensity_window(np.asarray(wfield.intensity)[inside]) if inside.any() else (0.0, 1.0)
    bounds_m = _grid_corners_world(wfield)
    origin = study_origin(collection, bounds_m)
    previous = None
    if obj is not None and obj.type == "VOLUME" and obj.data.filepath:
        previous = Path(bpy.path.abspath(obj.data.filepath)).resolve()
    # a new file every time: the current one (perhaps with CT data this build lacks) stays intact
    path = write_vdb(wfield, fresh_vdb_path(vdb_path), window, ct=ct, origin_m=origin)

    if obj is None:
        data = bpy.data.volumes.new(name)
        obj = bpy.data.objects.new(name, data)
        collection.objects.link(obj)
    elif obj.type != "VOLUME":
        raise TypeError(f"object {obj.name!r} is not a Volume object")
    data = obj.data
    data.grids.unload()
    data.filepath = blender_filepath(path)
    data.grids.load()
    if previous is not None and previous != Path(path).resolve():
        supersede(previous)
    obj.matrix_world = Matrix.Translation(origin)
    box = _solid_box_world(wfield)
    if box is not None:
        obj["pdehead_solid_box_m"] = [float(x) for x in (*(box[0] - origin), *(box[1] - origin))]
    elif "pdehead_solid_box_m" in obj.keys():
        del obj["pdehead_solid_box_m"]
    obj["pdehead_kind"] = "volume"
    obj["pdehead_window"] = [float(window[0]), float(window[1])]
    obj["pdehead_origin_m"] = list(origin)
    ensure_volume_material(obj)
    set_volume_settings(obj, **settings)
    return obj


def _solid_box_world(wfield):
    """World (min, max) metres of the voxels inside the solid (w <= 1), half a voxel added; None if empty."""
    inside = np.asarray(wfield.w) <= 1.0
    ranges = []
    for axes in ((1, 2), (0, 2), (0, 1)):  # k, j, i
        idx = np.flatnonzero(inside.any(axis=axes))
        if idx.size == 0:
            return None
        ranges.append((idx[0] - 0.5, idx[-1] + 0.5))
    (k0, k1), (j0, j1), (i0, i1) = ranges
    corners = np.array([[i, j, k, 1.0] for i in (i0, i1) for j in (j0, j1) for k in (k0, k1)])
    pts = (corners @ grid_affine_world(wfield.spacing, wfield.origin, wfield.direction).T)[:, :3]
    return pts.min(axis=0), pts.max(axis=0)


def solid_box(obj):
    """World (min, max) metres of the solid inside a PDE Head Volume object, or None if unknown."""
    box = obj.get("pdehead_solid_box_m") if obj is not None else None
    if box is None or len(box) != 6:
        return None
    m = np.array(obj.matrix_world)
    lo, hi = np.array(box[:3]), np.array(box[3:])
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pts = corners @ m[:3, :3].T + m[:3, 3]
    return pts.min(axis=0), pts.max(axis=0)


def _grid_corners_world(wfield) -> np.ndarray:
    nz, ny, nx = np.shape(wfield.w)
    corners = np.array([[i, j, k, 1.0] for i in (0, nx - 1) for j in (0, ny - 1) for k in (0, nz - 1)])
    return (corners @ grid_affine_world(wfield.spacing, wfield.origin, wfield.direction).T)[:, :3]


def check_volume(obj) -> str | None:
    """None if the Volume object's .vdb loads with grids w and intensity, else a message for the user."""
    if obj is None or obj.type != "VOLUME":
        return "This is not a PDE Head volume object."
    data = obj.data
    if not data.filepath:
        return f"Volume '{obj.name}' has no .vdb file: rebuild the volume."
    path = bpy.path.abspath(data.filepath)
    if not os.path.isfile(path):
        return (f"Volume file not found: {path}. .vdb files are not packed into the .blend; keep the "
                f"'{VDB_FOLDER_NAME}' folder beside the .blend or rebuild the volume.")
    if not data.grids.load():
        return f"Cannot read volume file {path}: {data.grids.error_message or 'unknown error'}. Rebuild the volume."
    names = {g.name for g in data.grids}
    missing = [g for g in REQUIRED_GRIDS if g not in names]
    if missing:
        return f"Volume file {path} lacks the grid(s) {', '.join(missing)}: rebuild the volume."
    return None
