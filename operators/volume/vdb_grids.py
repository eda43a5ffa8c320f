"""What a volume's .vdb holds and how it is written: the grids ``w``, ``intensity`` and ``ct``
(see :mod:`.volume`), the default voxel size that keeps the file and the w-field within budget,
and the write itself (Blender's ``openvdb`` module where it has one, else :mod:`.vdb_writer`).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ...pdehead_addon import (
    OUTSIDE_W,
    WriteError,
    apply_window,
    check_size,
    checked_output,
    ct_grid_for,
    defaults as D,
    disk_full,
    head_mask_on_grid,
)
from .. import compat
from ..coords import grid_affine_world
from . import vdb_writer
from .vdb_files import mark_written

GRID_NAMES = ("w", "intensity", "ct")
REQUIRED_GRIDS = ("w", "intensity")


# ----------------------------------------------------------------------------- default voxel size
INSIDE_FRACTION = 0.6             #: share of the solid's bounding box inside the solid (heads: ~0.5)


def estimate_vdb(ct, solid_box_mm, voxel: float) -> tuple[float, float]:
    """(bytes of the .vdb, voxels of the w-field grid) at isotropic `voxel` mm.

    ``w`` is float32 and ``intensity`` half-float over the voxels inside the solid (outside is
    the background, stored sparsely); ``ct`` is half-float over the whole CT box on the CT's grid
    decimated by whole steps (:func:`ct_volume.ct_grid_for`).
    """
    extent = np.asarray(solid_box_mm[1], float) - np.asarray(solid_box_mm[0], float) + 2.0 * voxel
    grid_voxels = float(np.prod(np.ceil(extent / voxel) + 1))
    steps = np.array([max(1, int(round(voxel / sp))) for sp in ct.spacing], float)
    ct_voxels = float(np.prod(np.ceil(np.array(ct.shape) / steps)))
    return INSIDE_FRACTION * grid_voxels * (4 + 2) + ct_voxels * 2, grid_voxels


def auto_voxel_size(ct, head, max_bytes: float = D.MAX_VDB_BYTES.default,
                    max_voxels: float = D.MAX_WFIELD_VOXELS.default) -> float:
    """Default volume voxel size (mm): the CT's finest spacing, coarsened in 5 % steps only until the
    .vdb estimate fits `max_bytes` and the w-field grid `max_voxels` (:func:`estimate_vdb`).

    CThead (1 x 1 x 2 mm) gives about 1.3 mm (the w-field's voxel budget decides), the GE series
    (0.49 mm pixels) the same; a scan with 3 mm voxels keeps 3 mm.
    """
    pts = head.surface(32, 64).vertices
    box = (pts.min(axis=0), pts.max(axis=0))
    voxel = max(float(min(ct.spacing)), D.VOXEL_SIZE.min)
    for _ in range(200):
        size, count = estimate_vdb(ct, box, voxel)
        if size <= max_bytes and count <= max_voxels:
            break
        voxel *= 1.05
    return round(voxel, 2)


# ----------------------------------------------------------------------------- the write
def write_vdb(wfield, path, window, *, ct=None, origin_m=(0.0, 0.0, 0.0)) -> Path:
    """Write the w-field as an OpenVDB file with float grids ``w``, ``intensity`` and ``ct``.

    Parameters
    ----------
    wfield : WField
        ``.w`` float [z, y, x] (in [0, 1] inside the solid, > 1 outside),
        ``.intensity`` float [z, y, x] raw CT units (0 outside), ``.spacing``
        (dz, dy, dx) mm, ``.origin`` (x, y, z) LPS mm, ``.direction`` 3x3.
    path : path-like
        Output file (parent folders are created).
    window : (lo, hi)
        Intensity window (:func:`intensity_window`); the ``intensity`` and ``ct``
        grids hold windowed values in [0, 1] (Cycles needs non-negative densities).
    ct : CTVolume, optional
        The full CT for the ``ct`` grid, which covers the whole CT box: on the
        w-field grid when that is the CT's grid, else on the CT's own grid
        decimated to about the w-field voxel size (:func:`ct_grid_for`; a grid
        has its own transform). Without it the ``ct`` grid repeats
        ``intensity``, so the intensity-alpha baseline then shows the solid only.
    origin_m : (3,) metres
        World position of the Volume object's origin; grid transforms are
        relative to it, so the object at ``origin_m`` puts voxel (k, j, i) at
        world ``LPS(k, j, i) * 0.001`` exactly.

    Returns
    -------
    Path of the written file.
    """
    openvdb = compat.openvdb_module()
    path = Path(os.fspath(path))
    path.parent.mkdir(parents=True, exist_ok=True)

    w = np.asarray(wfield.w, dtype=np.float32)
    if w.ndim != 3:
        raise ValueError(f"w-field must be 3-D [z, y, x], got shape {w.shape}")
    if np.shape(wfield.intensity) != w.shape:
        raise ValueError(f"w-field intensity shape {np.shape(wfield.intensity)} differs from w {w.shape}")
    inside = w <= 1.0  # NaN and OUTSIDE_W (2.0) are outside
    affine = grid_affine_world(wfield.spacing, wfield.origin, wfield.direction)
    affine[:3, 3] -= np.asarray(origin_m, dtype=np.float64)
    transform_rows = affine.T.tolist()  # OpenVDB uses row vectors: translation in the last row

    def grids():
        """(name, [z, y, x] float32 data, background, half floats, transform), one at a time: bounded memory."""
        yield ("w", np.where(inside, np.clip(w, 0.0, 1.0), np.float32(OUTSIDE_W)), OUTSIDE_W,
               False, transform_rows)
        intensity = apply_window(wfield.intensity, window)
        intensity[~inside] = 0.0
        yield "intensity", intensity, 0.0, True, transform_rows
        if ct is None:
            yield "ct", intensity, 0.0, True, transform_rows
            return
        data, spacing, ct_origin, ct_direction = ct_grid_for(ct, wfield)
        ct_affine = grid_affine_world(spacing, ct_origin, ct_direction)
        ct_affine[:3, 3] -= np.asarray(origin_m, dtype=np.float64)
        windowed = apply_window(data, window)
        windowed[~head_mask_on_grid(wfield, windowed.shape, spacing, ct_origin, ct_direction)] = 0.0
        yield "ct", windowed, 0.0, True, ct_affine.T.tolist()

    window_meta = f"{float(window[0])!r} {float(window[1])!r}"
    if openvdb is None:  # no bindings (bpy 4.2 from PyPI): our own writer, same grids and values (leaves
        # only where a voxel differs from the background: the bounds of a pruned grid)
        vdb_writer.write_vdb(path, (
            vdb_writer.DenseGrid(name, data.transpose(2, 1, 0), background, half, rows,
                                 {"pdehead_window": window_meta} if name == "w" else {})
            for name, data, background, half, rows in grids()))
        mark_written(path)
        return path
    written = []
    try:
        for name, data, background, half, rows in grids():
            grid = openvdb.FloatGrid(background=float(background))
            # numpy [k, j, i] -> OpenVDB (i, j, k): transpose (a copy) so index x is the CT's i axis
            grid.copyFromArray(np.ascontiguousarray(data.transpose(2, 1, 0)), tolerance=0.0)
            del data
            if hasattr(grid, "prune"):  # drop all-background tiles: Blender's bounds follow the kept data
                grid.prune()
            grid.name = name
            grid.transform = openvdb.createLinearTransform(rows)
            grid.gridClass = openvdb.GridClass.FOG_VOLUME
            grid.saveFloatAsHalf = half  # display data in [0, 1]: half precision is plenty, half the file
            written.append(grid)
        written[0]["pdehead_window"] = window_meta
        # OpenVDB's write can fail without an error on a full disk: written to a temporary name, read
        # back grid by grid (a short file does not read), then renamed (:mod:`.safe_io`)
        with checked_output(path) as tmp:
            openvdb.write(str(tmp), grids=written)
            check_size(tmp, minimum=64)
            for grid in written:
                try:
                    openvdb.read(str(tmp), grid.name)
                except Exception as exc:  # noqa: BLE001 - OpenVDB raises its own types
                    why = "no space left on device" if disk_full(tmp) else f"{exc}; disk full?"
                    raise WriteError(f"{path}: cannot be written (the file does not read back: {why})") from None
        mark_written(path)
    finally:
        # free the grids now (they hold no reference cycle: no gc.collect, which walks the whole of Blender's
        # heap, ~0.05 s); nanobind reports "leaked" objects at exit otherwise
        del written[:]
    return path
