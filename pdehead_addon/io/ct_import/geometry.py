"""Geometry: canonical reorientation, resampling of tilted/oblique/uneven slices, headerless stacks.

Every reader ends in the same grid: ``data[k, j, i]`` with k toward the
patient's SUPERIOR side, j POSTERIOR, i LEFT (``direction`` the identity).
Axis-aligned sources are only flipped and transposed (:func:`to_canonical`);
parallel slices that are tilted, oblique or unevenly spaced are resampled
linearly (:func:`resample_slices`) so that every source pixel keeps its true
patient position ``IPP + col*dc*rowdir + row*dr*coldir``.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy import ndimage

from ... import defaults
from ...core.ct_volume import CTVolume
from ...core.errors import CTImportError
from .. import input_checks

# Tolerances of the axis checks (the stack checks of .dicom._stack_geometry and of .nifti use them too).
ALIGNED_TOL = 1e-3        # direction cosine off an axis before the grid counts as oblique (0.25 mm at 250 mm)
_IDENTITY_SNAP = 1e-5      # below this the direction is reported as the exact identity


def _flip_in_place(data: np.ndarray, axes: Sequence[int]) -> np.ndarray:
    """Reverse ``data`` along ``axes`` in its own memory (C-contiguous float32): slices swapped pairwise
    through one slice of scratch, rows and columns per slice. A flipped copy of a 512 x 512 x 300 scan
    costs ~0.35 s, mostly the first touch of a new 300 MB array; this writes nothing new."""
    n = data.shape[0]
    if 0 in axes:
        scratch = np.empty_like(data[0])
        for k in range(n // 2):
            scratch[...] = data[k]
            data[k] = data[n - 1 - k]
            data[n - 1 - k] = scratch
    inner = tuple(slice(None, None, -1) if a in axes else slice(None) for a in (1, 2))
    if inner != (slice(None), slice(None)):
        for k in range(n):
            data[k] = data[k][inner].copy()
    return data


def to_canonical(data: np.ndarray, axis_dirs: Sequence[np.ndarray], axis_spacing: Sequence[float],
               origin: np.ndarray, in_place: bool = False) -> tuple[np.ndarray, tuple, np.ndarray, np.ndarray]:
    """Flip/transpose a regular axis-aligned grid to ``[z, y, x]`` with k superior, j posterior, i left.

    Parameters
    ----------
    data : ndarray (n0, n1, n2)
    axis_dirs : three unit LPS vectors, the directions of array axes 0, 1, 2
    axis_spacing : the step (mm) along array axes 0, 1, 2
    origin : LPS position of ``data[0, 0, 0]``
    in_place : bool
        ``data`` is the caller's own scratch (a reader's fresh float32 stack): a flip without a transpose
        reverses it in its own memory instead of copying it.

    Returns
    -------
    data, spacing (dz, dy, dx), origin, direction (columns: i, j, k)
    """
    dirs = np.array(axis_dirs, dtype=np.float64)
    patient_axis = np.argmax(np.abs(dirs), axis=1)          # patient axis (0=x,1=y,2=z) of each array axis
    if len(set(patient_axis.tolist())) != 3:
        raise ValueError("grid is not axis-aligned")
    origin = np.asarray(origin, dtype=np.float64).copy()
    index = [slice(None)] * 3
    for m in range(3):
        sign = np.sign(dirs[m, patient_axis[m]])
        if sign < 0:                                        # flip this array axis
            origin += (data.shape[m] - 1) * axis_spacing[m] * dirs[m]
            dirs[m] = -dirs[m]
            index[m] = slice(None, None, -1)
    # array axis that holds patient z, y, x (in that order)
    perm = [int(np.flatnonzero(patient_axis == p)[0]) for p in (2, 1, 0)]
    flipped = [m for m in range(3) if index[m] != slice(None)]
    if (in_place and perm == [0, 1, 2] and data.dtype == np.float32 and data.flags.c_contiguous
            and data.flags.writeable):
        data = _flip_in_place(data, flipped)
    else:
        data = np.ascontiguousarray(data[tuple(index)].transpose(perm), dtype=np.float32)
    spacing = tuple(float(axis_spacing[m]) for m in perm)
    direction = np.stack([dirs[perm[2]], dirs[perm[1]], dirs[perm[0]]], axis=1)  # columns i, j, k
    if np.abs(direction - np.eye(3)).max() < _IDENTITY_SNAP:
        direction = np.eye(3)
    return data, spacing, origin, direction


def _output_grid(positions, u, v, n, dr, dc, rows, cols, steps, resample_spacing):
    """Axis-aligned LPS box around all pixel centres: its low corner, its spacing and its voxel counts
    (x, y, z order), and its extent in mm (``hi - lo``)."""
    corners = np.array([[0, 0], [0, cols - 1], [rows - 1, 0], [rows - 1, cols - 1]], dtype=np.float64)
    in_plane = corners[:, 0:1] * dr * v + corners[:, 1:2] * dc * u
    points = positions[:, None, :] + in_plane[None, :, :]
    lo, hi = points.reshape(-1, 3).min(axis=0), points.reshape(-1, 3).max(axis=0)
    if resample_spacing is not None:
        dz, dy, dx = (float(s) for s in resample_spacing)
        spacing_xyz = np.array([dx, dy, dz])
    else:
        # each patient axis takes the spacing of the source axis closest to it
        median_step = float(np.median(steps)) if len(steps) else 1.0
        spacing_xyz = np.full(3, np.nan)
        for vec, sp in ((u, dc), (v, dr), (n, median_step)):
            a = int(np.argmax(np.abs(vec)))
            spacing_xyz[a] = sp if np.isnan(spacing_xyz[a]) else min(spacing_xyz[a], sp)
        spacing_xyz[np.isnan(spacing_xyz)] = min(dr, dc, median_step)
    with np.errstate(all="ignore"):
        counts = np.floor((hi - lo) / spacing_xyz + 1e-6)
    counts = np.where(np.isfinite(counts), np.minimum(counts, 2 ** 40), 2 ** 40).astype(np.int64) + 1
    return lo, spacing_xyz, counts, hi - lo


def resample_limit(source_voxels: int) -> int:
    """Most voxels a resampled grid may have for ``source_voxels`` measured ones: a tilt or an uneven step
    adds a few times the source (GE's 18.5 deg tilt: 4.3 times); more means corrupt positions. At least 64 M
    voxels, at most what the import memory budget holds (float32 values and the coverage mask)."""
    return int(min(defaults.IMPORT_MEMORY_BUDGET_BYTES // 5, max(64_000_000, 32 * int(source_voxels))))


def resample_slices(stack: np.ndarray, positions: np.ndarray, u: np.ndarray, v: np.ndarray, dr: float,
                     dc: float, steps: np.ndarray, resample_spacing, fill: float,
                     max_voxels: int = 600_000_000, label=None) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Resample parallel slices (any tilt, spacing or orientation) onto a regular LPS grid.

    A point X of the output grid lies between the two source slices that
    bracket its coordinate along the slice normal n; it takes their values at
    its perpendicular foot points ``(X - IPP_k) . (u, v)`` (bilinear in each
    slice) mixed linearly along n. Every source pixel therefore keeps its true
    patient position ``IPP + col*dc*u + row*dr*v``; points outside the slab of
    the source slices get ``fill``.

    Parameters
    ----------
    stack : float32 (nslices, rows, cols), sorted along n
    positions : (nslices, 3) ImagePositionPatient of each slice
    u, v : unit directions of increasing column and row index
    dr, dc : row and column pixel spacing (mm)
    steps : (nslices - 1,) slice steps along n (mm)
    resample_spacing : (dz, dy, dx) or None
    fill : value outside the source slab

    Returns
    -------
    data (nz, ny, nx) float32, origin (3,), spacing (dz, dy, dx), coverage (nz, ny, nx) bool
        ``coverage`` is False where the point lies outside the source slab (filled with ``fill``).
    """
    nslices, rows, cols = stack.shape
    n = np.cross(u, v)
    n /= np.linalg.norm(n)
    lo, sp, counts, extent = _output_grid(positions, u, v, n, dr, dc, rows, cols, steps, resample_spacing)
    if not np.all(np.isfinite(counts.astype(np.float64))) or np.any(counts > 10 ** 7):
        raise CTImportError(f"the slices' positions span {np.round(extent, 1).tolist()} mm (x, y, z): no scan "
                            "measures this (corrupt positions or spacing)", label)
    total = int(np.prod(counts.astype(np.int64)))
    if total > max_voxels:
        raise CTImportError(f"resampled grid would have {counts[::-1].tolist()} voxels ({total / 1e6:.0f} M, "
                            f"the slices hold {stack.size / 1e6:.3g} M): the slice positions spread far more than "
                            "a tilted or uneven scan does (corrupt positions?), or pass a coarser "
                            "resample_spacing=(dz, dy, dx)", label)
    along = positions @ n
    out = None
    # Fast path: one image axis is a patient axis and the slices do not move along it (the usual
    # gantry tilt: rows along x, tilt in the y-z plane). Then each output line along that axis is
    # a linear mix of whole source rows, so we only interpolate in the other two axes.
    for line_dir, line_sp, other_dir, other_sp, lines_are_rows in ((u, dc, v, dr, True), (v, dr, u, dc, False)):
        a = int(np.argmax(np.abs(line_dir)))
        if (abs(line_dir[a]) > 1 - 1e-9 and np.ptp(positions[:, a]) < 1e-3
                and abs(sp[a] - line_sp) < 1e-9):
            source = stack if lines_are_rows else np.ascontiguousarray(stack.transpose(0, 2, 1))
            if line_dir[a] < 0:
                source = np.ascontiguousarray(source[:, :, ::-1])
            out, coverage = _resample_lines(source, positions, other_dir, other_sp, n, along, lo, sp, counts,
                                            a, fill)
            break
    if out is None:
        out, coverage = _resample_general(stack, positions, u, v, dr, dc, n, along, lo, sp, counts, fill)
    return out, lo, (float(sp[2]), float(sp[1]), float(sp[0])), coverage


def _bracket(delta: np.ndarray, along: np.ndarray):
    """Lower slice index, weight of the upper slice, and the inside-the-slab mask for normal coords."""
    nslices = len(along)
    tol = 1e-4
    inside = (delta >= along[0] - tol) & (delta <= along[-1] + tol)
    frac_index = np.interp(delta, along, np.arange(nslices, dtype=np.float64))
    k0 = np.clip(np.floor(frac_index).astype(np.intp), 0, max(nslices - 2, 0))
    weight = np.clip(frac_index - k0, 0.0, 1.0).astype(np.float32)
    if nslices == 1:
        weight[:] = 0.0
    k1 = np.minimum(k0 + 1, nslices - 1)
    return k0, k1, weight, inside


def _resample_lines(source, positions, other_dir, other_sp, n, along, lo, sp, counts, a, fill):
    """Fast path of :func:`resample_slices`: output lines along patient axis ``a`` copy source lines."""
    nslices, nlines, line_len = source.shape
    assert line_len == counts[a]
    b, c = [p for p in (2, 1, 0) if p != a]                 # output array order is z, y, x
    xb = lo[b] + sp[b] * np.arange(counts[b])
    xc = lo[c] + sp[c] * np.arange(counts[c])
    grid_b, grid_c = np.meshgrid(xb, xc, indexing="ij")
    delta = (grid_b * n[b] + grid_c * n[c]).ravel()
    proj = (grid_b * other_dir[b] + grid_c * other_dir[c]).ravel()
    k0, k1, weight, inside = _bracket(delta, along)
    offset = positions @ other_dir
    t0 = (proj - offset[k0]) / other_sp                     # line index in slice k0 (fractional)
    t1 = (proj - offset[k1]) / other_sp
    inside &= (t0 > -0.5) & (t0 < nlines - 0.5) & (t1 > -0.5) & (t1 < nlines - 0.5)
    flat = source.reshape(nslices * nlines, line_len)
    out2 = np.empty((delta.size, line_len), dtype=np.float32)
    chunk = max(1, 1_000_000 // line_len)           # ~4 MB per gathered block

    def lerp_lines(k, t, sl):
        t = np.clip(t[sl], 0.0, nlines - 1.0)
        t_lo = np.minimum(np.floor(t).astype(np.intp), max(nlines - 2, 0))
        w = (t - t_lo).astype(np.float32)[:, None]
        base = k[sl] * nlines + t_lo
        lower = flat[base]
        upper = flat[np.minimum(base + 1, flat.shape[0] - 1)]
        upper -= lower
        upper *= w
        lower += upper
        return lower

    for start in range(0, delta.size, chunk):
        sl = slice(start, min(start + chunk, delta.size))
        lower = lerp_lines(k0, t0, sl)
        upper = lerp_lines(k1, t1, sl)
        upper -= lower
        upper *= weight[sl, None]
        lower += upper
        lower[~inside[sl]] = fill
        out2[sl] = lower
    out = out2.reshape(counts[b], counts[c], line_len)
    covered = np.broadcast_to(inside.reshape(counts[b], counts[c], 1), out.shape)
    order = [b, c, a]
    perm = [order.index(p) for p in (2, 1, 0)]
    if perm == [0, 1, 2]:
        return out, np.ascontiguousarray(covered)
    return np.ascontiguousarray(out.transpose(perm)), np.ascontiguousarray(covered.transpose(perm))


def _resample_general(stack, positions, u, v, dr, dc, n, along, lo, sp, counts, fill):
    """General path of :func:`resample_slices` (double-oblique planes): bilinear lookups per slab."""
    nslices, rows, cols = stack.shape
    nx, ny, nz = (int(c) for c in counts)
    out = np.empty((nz, ny, nx), dtype=np.float32)
    coverage = np.empty((nz, ny, nx), dtype=bool)
    xs = lo[0] + sp[0] * np.arange(nx)
    ys = lo[1] + sp[1] * np.arange(ny)
    pu, pv = positions @ u, positions @ v
    planes_per_chunk = max(1, 2_000_000 // (nx * ny))
    gy, gx = np.meshgrid(ys, xs, indexing="ij")
    for z0 in range(0, nz, planes_per_chunk):
        zs = lo[2] + sp[2] * np.arange(z0, min(z0 + planes_per_chunk, nz))
        gz = zs[:, None, None]
        delta = (gx * n[0] + gy * n[1])[None] + gz * n[2]
        xu = (gx * u[0] + gy * u[1])[None] + gz * u[2]
        xv = (gx * v[0] + gy * v[1])[None] + gz * v[2]
        k0, k1, weight, inside = _bracket(delta.ravel(), along)
        values = []
        for k in (k0, k1):
            col = (xu.ravel() - pu[k]) / dc
            row = (xv.ravel() - pv[k]) / dr
            inside &= (col > -0.5) & (col < cols - 0.5) & (row > -0.5) & (row < rows - 0.5)
            coords = np.stack([k.astype(np.float64), row, col])
            values.append(ndimage.map_coordinates(stack, coords, order=1, mode="nearest", output=np.float32))
        lower, upper = values
        upper -= lower
        upper *= weight
        lower += upper
        lower[~inside] = fill
        out[z0:z0 + len(zs)] = lower.reshape(len(zs), ny, nx)
        coverage[z0:z0 + len(zs)] = inside.reshape(len(zs), ny, nx)
    return out, coverage



def headerless_volume(data, label, fmt, spacing, axes, oriented, hu, warns, extra) -> CTVolume:
    """Place a stack without geometry, in file order ``[file, row, column]``, by the orientation
    code's axis directions ``axes = [column, row, slice]`` (default LPS: row -> posterior,
    column -> patient left, later files superior); the origin stays at 0 (no patient position)."""
    if spacing is None:
        spacing = (1.0, 1.0, 1.0)
        warns.append("no spacing given: assumed (dz, dy, dx) = (1, 1, 1) mm; pass spacing=(dz, dy, dx)")
    spacing = _spacing_option(spacing, label)
    col, row, sl = axes
    data, spacing, _, direction = to_canonical(data, [sl, row, col], spacing, np.zeros(3), in_place=True)
    code = input_checks.orientation_code(col, row, sl)
    meta = {
        "source": label,
        "format": fmt,
        "modality": "",
        "series_uid": "",
        "series_description": "",
        "original_slice_count": int(data.shape[0]),
        "first_slice": "inferior" if sl[2] > 0 else "superior" if sl[2] < 0 else "",
        "orientation": code,
        "gantry_tilt_deg": 0.0,
        "resampled": False,
        "resample_reason": "",
        "units": "HU" if hu else "stored value (not calibrated HU)",
        "hu_range": (float(data.min()), float(data.max())) if data.size else (0.0, 0.0),
    }
    if not oriented:
        meta["orientation_assumed"] = (f"{code}: row 0 anterior, column 0 patient right, files stacked "
                                       f"{'upward' if sl[2] > 0 else 'downward'}; pass orientation= if not")
    meta.update(extra)
    return CTVolume(data, spacing, np.zeros(3), direction, meta)



def _spacing_option(spacing, label) -> tuple[float, float, float]:
    try:
        values = tuple(float(s) for s in spacing)
    except (TypeError, ValueError):
        raise CTImportError(f"spacing must be three numbers (dz, dy, dx) in mm, got {spacing!r}", label) from None
    if len(values) != 3 or not all(math.isfinite(s) and s > 0 for s in values):
        raise CTImportError(f"spacing must be three positive numbers (dz, dy, dx) in mm, got {spacing!r}", label)
    if not all(1e-3 <= s <= 1e3 for s in values):
        raise CTImportError(f"spacing {values!r} mm (dz, dy, dx): a scan's voxels measure between 0.001 and "
                            "1000 mm", label)
    return values
