"""Readers of files the engine writes, for the tests' round-trip checks (not shipped in the add-on).

The engine only writes these formats (:func:`pdehead_addon.io.export.export_mesh`,
:func:`pdehead_addon.forensic.tissue_depth.write_depth_csv`); the tests read them back to
check what was written.
"""
from __future__ import annotations

import csv
import os
import struct

import numpy as np

from pdehead_addon import PDEHeadError
from pdehead_addon.core.mesh import Mesh


def read_stl(path: str | os.PathLike) -> Mesh:
    """A binary STL as a Mesh with shared vertices (exact float32 coordinates merged)."""
    path = os.fspath(path)
    with open(path, "rb") as fh:
        data = fh.read()
    if len(data) < 84:
        raise PDEHeadError(f"{path}: too short for a binary STL")
    (count,) = struct.unpack_from("<I", data, 80)
    if len(data) != 84 + 50 * count:
        raise PDEHeadError(f"{path}: size does not match {count} binary STL facets")
    rec = np.frombuffer(data, dtype=[("n", "<f4", 3), ("p", "<f4", (3, 3)), ("attr", "<u2")], count=count, offset=84)
    corners = rec["p"].reshape(-1, 3) + np.float32(0.0)          # -0.0 as 0.0: merged as equal values
    # np.unique(corners, axis=0)'s groups, by a lexicographic sort: the same vertices in the same order, ~8 x faster
    order = np.lexsort(corners.T[::-1])
    ranked = corners[order]
    starts = np.concatenate([[True], np.any(ranked[1:] != ranked[:-1], axis=1)])
    inverse = np.empty(len(corners), np.int64)
    inverse[order] = np.cumsum(starts) - 1
    return Mesh(vertices=ranked[starts], quads=np.zeros((0, 4), np.int64), triangles=inverse.reshape(-1, 3))


def read_depth_csv(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 3) and depth (n,) (NaN where empty) of a file written by
    :func:`pdehead_addon.forensic.tissue_depth.write_depth_csv`."""
    path = os.fspath(path)
    try:
        with open(path, newline="") as fh:
            rows = [r for r in csv.reader(fh) if r and not r[0].startswith("#")]   # provenance lines
    except OSError as exc:
        raise PDEHeadError(f"{path}: cannot read ({exc.strerror})") from None
    if not rows or rows[0][:4] != ["x_mm", "y_mm", "z_mm", "depth_mm"]:
        raise PDEHeadError(f"{path}: not a tissue-depth CSV (header x_mm,y_mm,z_mm,depth_mm expected)")
    body = rows[1:]
    pts = np.array([[float(r[0]), float(r[1]), float(r[2])] for r in body]).reshape(-1, 3)
    depth = np.array([float(r[3]) if r[3] else np.nan for r in body])
    return pts, depth
