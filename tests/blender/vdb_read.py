"""Reading .vdb files back, for the tests (the add-on only writes them: operators/volume/vdb_grids.py).

Needs Blender's OpenVDB bindings (``openvdb``, before 4.4 ``pyopenvdb``); bpy 4.2 from PyPI has
none (its files come from ``operators/volume/vdb_writer.py``), so callers check :func:`has_openvdb` first.
"""
from __future__ import annotations

import gc

import numpy as np


def _openvdb():
    import bpy

    expose = getattr(bpy.utils, "expose_bundled_modules", None)
    if expose is not None:
        expose()
    for name in ("openvdb", "pyopenvdb"):
        try:
            return __import__(name)
        except ImportError:
            continue
    raise RuntimeError("this Blender has no OpenVDB Python bindings (openvdb/pyopenvdb) to read .vdb files")


def has_openvdb() -> bool:
    try:
        _openvdb()
    except RuntimeError:
        return False
    return True


def read_vdb_grids(path) -> dict[str, dict]:
    """Active voxel box, count, background, value range and index->world transform of each grid."""
    openvdb = _openvdb()
    grids, _meta = openvdb.readAll(str(path))
    out = {}
    try:
        for grid in grids:
            t = grid.transform
            o = np.array(t.indexToWorld((0, 0, 0)))
            out[grid.name] = {
                "active_box": grid.evalActiveVoxelBoundingBox(),
                "active_count": grid.activeVoxelCount(),
                "background": grid.background,
                "min_max": grid.evalMinMax(),
                "origin": o,
                "axes": np.array([np.array(t.indexToWorld(e)) - o for e in ((1, 0, 0), (0, 1, 0), (0, 0, 1))]),
            }
            del t
    finally:
        del grids
        gc.collect()
    return out


def vdb_value(path, grid_name: str, ijk: tuple[int, int, int]) -> float:
    """Value of one voxel ``(i, j, k)`` of a grid in a .vdb file (for tests)."""
    openvdb = _openvdb()
    grid = openvdb.read(str(path), grid_name)
    try:
        return float(grid.getConstAccessor().getValue(tuple(int(x) for x in ijk)))
    finally:
        del grid
        gc.collect()


def read_vdb_array(path, grid_name: str) -> tuple[np.ndarray, tuple[int, int, int]]:
    """A grid of a .vdb file as a dense float32 array ``[i, j, k]`` over its active box, and the box's
    first index (for comparing two files voxel by voxel)."""
    openvdb = _openvdb()
    grid = openvdb.read(str(path), grid_name)
    try:
        lo, hi = grid.evalActiveVoxelBoundingBox()
        shape = tuple(int(h - l + 1) for l, h in zip(lo, hi))  # noqa: E741
        out = np.zeros(shape, np.float32)
        grid.copyToArray(out, ijk=tuple(int(x) for x in lo))
        return out, tuple(int(x) for x in lo)
    finally:
        del grid
        gc.collect()
