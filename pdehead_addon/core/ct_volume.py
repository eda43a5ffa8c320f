"""The CT volume in patient space: the data type every pipeline step shares, and its numeric helpers.

- :class:`CTVolume` and :func:`grid_affine` (the one voxel index -> patient LPS mm map of a grid);
- sampling: :func:`trilinear`, :func:`sample_ct` (intensity at patient points);
- intensity windows for display: :func:`intensity_window`, :func:`apply_window`;
- grids of the volume rendering (section 4.3, eq. 24): :func:`head_mask_on_grid`,
  :func:`ct_grid_for` (its block means: :func:`decimated_block_mean`);
- :func:`downsample_volume` for very large scans.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.ndimage import binary_dilation, map_coordinates, uniform_filter1d

#: The ``ct`` grid of the volume keeps the CT this far around the solid (no table, no air box).
HEAD_MARGIN_MM = 6.0


def grid_affine(spacing, origin, direction) -> np.ndarray:
    """4x4 matrix from voxel index ``(i, j, k, 1)`` to patient LPS ``(x, y, z, 1)`` in mm.

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
    The same map for every grid of the engine (a :class:`CTVolume`, a ``WField``): voxel
    ``(k, j, i)`` lies at ``origin + direction @ (i*dx, j*dy, k*dz)``. The index order is
    ``(i, j, k)`` = (x, y, z) as OpenVDB and Blender use it, the reverse of numpy's ``[k, j, i]``.
    """
    dz, dy, dx = (float(s) for s in spacing)
    m = np.eye(4)
    m[:3, :3] = np.asarray(direction, dtype=np.float64).reshape(3, 3) * np.array([dx, dy, dz])
    m[:3, 3] = np.asarray(origin, dtype=np.float64).reshape(3)
    return m


@dataclass
class CTVolume:
    """A scalar volume placed in patient LPS space (millimetres).

    Parameters
    ----------
    data : ndarray, shape (nz, ny, nx)
        Intensities, stored as float32 in ``[z, y, x]`` = ``[k, j, i]`` order.
        For CT the unit is HU where the source is calibrated.
    spacing : tuple of 3 float
        Voxel size ``(dz, dy, dx)`` in mm.
    origin : array-like of 3 float
        Patient LPS position (x, y, z) in mm of voxel ``(k, j, i) = (0, 0, 0)``.
    direction : ndarray, shape (3, 3)
        Columns are the unit LPS directions of the i, j and k axes. The patient
        position of voxel ``(k, j, i)`` is
        ``origin + direction @ (i*dx, j*dy, k*dz)``.
    meta : dict
        Free-form description of the study (source, modality, series, ...).
    coverage : ndarray of bool, shape (nz, ny, nx), optional
        True where the voxel holds measured data. Only set when the loader
        resampled the slices (gantry tilt, uneven steps): voxels outside the
        scanned slab are filled with air and are ``False`` here, so later steps
        can tell a real skin edge from the edge of the scan.

    Notes
    -----
    The loaders return volumes whose k axis points superior where the source
    says so, so that ``data[k]`` is an axial slice at height
    ``origin[2] + k*dz`` when ``direction`` is the identity.
    """

    data: np.ndarray
    spacing: tuple[float, float, float]
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    direction: np.ndarray = field(default_factory=lambda: np.eye(3))
    meta: dict[str, Any] = field(default_factory=dict)
    coverage: np.ndarray | None = None

    def __post_init__(self) -> None:
        data = np.asarray(self.data)
        if data.ndim != 3:
            raise ValueError(f"CTVolume data must be 3-D [z, y, x], got shape {data.shape}")
        self.data = data.astype(np.float32, copy=False)
        spacing = tuple(float(s) for s in self.spacing)
        if len(spacing) != 3 or not all(np.isfinite(spacing)) or min(spacing) <= 0:
            raise ValueError(f"CTVolume spacing must be 3 positive numbers (dz, dy, dx), got {self.spacing}")
        self.spacing = spacing
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        self.direction = np.asarray(self.direction, dtype=np.float64).reshape(3, 3)
        self.meta = dict(self.meta)
        if self.coverage is not None:
            self.coverage = np.asarray(self.coverage, dtype=bool)
            if self.coverage.shape != self.data.shape:
                raise ValueError(f"CTVolume coverage shape {self.coverage.shape} != data shape {self.data.shape}")

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.data.shape)  # type: ignore[return-value]

    @property
    def affine(self) -> np.ndarray:
        """4x4 matrix mapping homogeneous ``(i, j, k, 1)`` to patient ``(x, y, z, 1)`` in mm (:func:`grid_affine`)."""
        return grid_affine(self.spacing, self.origin, self.direction)

    def index_to_patient(self, kji: np.ndarray) -> np.ndarray:
        """Patient LPS mm of (possibly fractional) voxel indices ``[..., (k, j, i)]``."""
        kji = np.asarray(kji, dtype=np.float64)
        ijk = kji[..., ::-1]
        return ijk @ self.affine[:3, :3].T + self.origin

    def patient_to_index(self, xyz: np.ndarray) -> np.ndarray:
        """Fractional voxel indices ``[..., (k, j, i)]`` of patient LPS points in mm."""
        return self.patient_to_index_map()(xyz)

    def patient_to_index_map(self):
        """:meth:`patient_to_index` as a function with the affine inverted once, for many calls on one grid (the
        inversion cost more than the mapping of a plane of points)."""
        origin, inverse_t = self.origin.copy(), np.linalg.inv(self.affine[:3, :3]).T
        return lambda xyz: ((np.asarray(xyz, dtype=np.float64) - origin) @ inverse_t)[..., ::-1]

    def slice_heights(self) -> np.ndarray:
        """Patient z (mm) of the centre of each axial slice ``data[k]``."""
        k = np.arange(self.shape[0], dtype=np.float64)
        return self.origin[2] + self.direction[2, 2] * self.spacing[0] * k

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned patient-space box (min, max) in mm enclosing all voxel centres."""
        nz, ny, nx = self.shape
        corners = np.array([[k, j, i] for k in (0, nz - 1) for j in (0, ny - 1) for i in (0, nx - 1)], float)
        pts = self.index_to_patient(corners)
        return pts.min(axis=0), pts.max(axis=0)


def trilinear(data: np.ndarray, kji: np.ndarray, cval: float = 0.0) -> np.ndarray:
    """Trilinear interpolation of a 3-D array at fractional indices ``[..., (k, j, i)]``.

    The same values as ``scipy.ndimage.map_coordinates(order=1, mode="constant")`` for
    points inside ``[0, n - 1]`` on every axis; within the outer half voxel (``[-0.5, 0)`` and
    ``(n - 1, n - 0.5]``, still inside the first/last voxel) the edge value, so a point on the
    scan's first slice does not flip between tissue and `cval` with rounding; `cval` beyond.

    Returns
    -------
    ndarray of float32 with shape ``kji.shape[:-1]``.
    """
    a = np.ascontiguousarray(data)
    shape = np.array(a.shape)
    pts = np.asarray(kji, dtype=np.float64).reshape(-1, 3)
    inside = np.all((pts >= -0.5) & (pts <= shape - 0.5), axis=1)
    pts = np.clip(pts, 0.0, shape - 1)
    base = np.clip(np.floor(pts), 0, np.maximum(shape - 2, 0)).astype(np.int64)
    frac = np.clip(pts - base, 0.0, 1.0).astype(np.float32)
    nz, ny, nx = a.shape
    sk = ny * nx if nz > 1 else 0
    sj = nx if ny > 1 else 0
    si = 1 if nx > 1 else 0
    flat = a.ravel()
    idx = (base[:, 0] * ny + base[:, 1]) * nx + base[:, 2]
    fk, fj, fi = frac[:, 0], frac[:, 1], frac[:, 2]

    def row(offset):  # linear along i at (k, j) + offset
        lo = flat[idx + offset]
        return lo + fi * (flat[idx + offset + si] - lo)

    c00, c01 = row(0), row(sj)
    c10, c11 = row(sk), row(sk + sj)
    c0 = c00 + fj * (c01 - c00)
    c1 = c10 + fj * (c11 - c10)
    out = (c0 + fk * (c1 - c0)).astype(np.float32, copy=False)
    out[~inside] = np.float32(cval)
    return out.reshape(np.shape(kji)[:-1])


def intensity_window(ct_or_values, preset="auto") -> tuple[float, float]:
    """Intensity window ``(lo, hi)`` mapping CT values to [0, 1].

    Parameters
    ----------
    ct_or_values : CTVolume or ndarray
        The CT (its ``.data``) or raw intensities.
    preset : {"auto", "full"} or (lo, hi)
        ``"auto"``: the 1st and 99.5th percentiles (robust to metal streaks and
        padding; air maps to ~0 and bone to ~1 on CThead and on HU data).
        ``"full"``: the value range. A pair is returned as given.

    Returns
    -------
    (lo, hi) with hi > lo.
    """
    if not isinstance(preset, str):
        lo, hi = (float(x) for x in preset)
        if not hi > lo:
            raise ValueError(f"intensity window needs hi > lo, got ({lo}, {hi})")
        return lo, hi
    values = np.asarray(getattr(ct_or_values, "data", ct_or_values), dtype=np.float32).ravel()
    values = values[np.isfinite(values)]
    if values.size == 0:
        return 0.0, 1.0
    if preset == "full":
        lo, hi = float(values.min()), float(values.max())
    elif preset == "auto":
        step = max(1, values.size // 2_000_000)  # percentiles of a regular subsample: fast, stable
        lo, hi = (float(x) for x in np.percentile(values[::step], [1.0, 99.5]))
    else:
        raise ValueError(f"unknown intensity window preset {preset!r} (use 'auto', 'full' or (lo, hi))")
    if not hi > lo:
        hi = lo + 1.0
    return lo, hi


def apply_window(values: np.ndarray, window: tuple[float, float], out: np.ndarray | None = None,
                 finite: bool = True) -> np.ndarray:
    """``(values - lo) / (hi - lo)`` clipped to [0, 1], float32.

    The one windowing of the project (segmentation, the volume's intensity grid, the solid's
    and the slice planes' colours). ``out`` may be ``values`` itself (in place) or a float32
    buffer; ``finite=False`` skips the NaN -> 0 pass where the values are known finite (the
    segmentation's whole CT: one full-volume pass and a boolean temporary fewer).
    """
    lo, hi = (float(x) for x in window)
    if not hi > lo:
        raise ValueError(f"intensity window needs hi > lo, got ({lo}, {hi})")
    out = np.subtract(values, np.float32(lo), out=out, dtype=np.float32)
    out *= np.float32(1.0 / (hi - lo))
    np.clip(out, 0.0, 1.0, out=out)
    if finite:
        out[~np.isfinite(out)] = 0.0
    return out


def sample_ct(ct, points_mm: np.ndarray, order: int = 1) -> np.ndarray:
    """CT intensity at patient LPS points (mm), trilinear; the lowest CT value outside the box.

    Points within the outer half voxel take the edge value (:func:`trilinear`): a vertex
    on the scan's first slice must not turn to air when rounding puts it an ulp outside.
    """
    pts = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    kji = ct.patient_to_index(pts)
    cval = float(np.min(ct.data)) if ct.data.size else 0.0
    if order == 1:
        return trilinear(ct.data, kji, cval=cval)
    out = map_coordinates(ct.data, kji.T, order=order, mode="constant", cval=cval, prefilter=False)
    return out.astype(np.float32, copy=False)


def head_mask_on_grid(wfield, shape, spacing, origin, direction, margin_mm: float = HEAD_MARGIN_MM) -> np.ndarray:
    """Voxels of a grid (shape [z, y, x], spacing, origin, direction as in CTVolume) within `margin_mm`
    of the solid (w <= 1 of `wfield`, dilated): the intensity-alpha mode shows the CT there only, so
    neither the air noise of the CT box (a faint box outline) nor the scanner table (bright bars
    behind the head) is rendered. Nearest w-field voxel per grid voxel, one slice at a time."""
    inside = np.asarray(wfield.w) <= 1.0
    steps = int(np.ceil(margin_mm / max(min(wfield.spacing), 1e-6)))
    if steps > 0 and inside.any():
        inside = binary_dilation(inside, iterations=steps)
    to_w = np.linalg.inv(grid_affine(wfield.spacing, wfield.origin, wfield.direction))
    m = to_w @ grid_affine(spacing, origin, direction)  # grid (i, j, k, 1) -> w-field (i, j, k, 1)
    nz, ny, nx = (int(n) for n in shape)
    wz, wy, wx = inside.shape
    lin = m[:3, :3]
    if not np.any(lin - np.diag(np.diag(lin))):
        # axis-aligned grids (the usual case: the CT's decimated grid and the w-field share a direction):
        # each index maps on its own, the same rounded indices as the per-slice loop below (its terms
        # off the diagonal are exact zeros), looked up once as an outer product
        index = [np.rint(lin[a, a] * np.arange(n) + m[a, 3]).astype(np.int64) for a, n in enumerate((nx, ny, nz))]
        ok = [(ix >= 0) & (ix < w) for ix, w in zip(index, (wx, wy, wz))]
        i, j, k = (np.where(o, ix, 0) for o, ix in zip(ok, index))
        return inside[np.ix_(k, j, i)] & ok[2][:, None, None] & ok[1][None, :, None] & ok[0][None, None, :]
    jj, ii = np.mgrid[0:ny, 0:nx]
    base = m[:3, 0][:, None] * ii.ravel() + m[:3, 1][:, None] * jj.ravel() + m[:3, 3][:, None]
    out = np.zeros((nz, ny, nx), bool)
    for k in range(nz):                                # per slice: bounded memory
        ijk = np.rint(base + m[:3, 2][:, None] * k).astype(np.int64)
        ok = (ijk[0] >= 0) & (ijk[0] < wx) & (ijk[1] >= 0) & (ijk[1] < wy) & (ijk[2] >= 0) & (ijk[2] < wz)
        hit = np.zeros(ny * nx, bool)
        hit[ok] = inside[ijk[2, ok], ijk[1, ok], ijk[0, ok]]
        out[k] = hit.reshape(ny, nx)
    return out


def decimated_block_mean(data: np.ndarray, steps, block_bytes: int = 1 << 23) -> np.ndarray:
    """``uniform_filter(data, size=steps, mode="nearest")[::steps[0], ::steps[1], ::steps[2]]``, bit for bit,
    computing only the means the decimation keeps.

    scipy's ``uniform_filter`` is one 1-D pass per axis with a step > 1 (in axis order), each a running
    window sum in float64 divided by the step and rounded to float32. Where that running sum is exact,
    a pass is the window sum at every step-th voxel divided by the step (:func:`_window_means`: a
    third of the sums for a step of 3, no running chain). It is exact for CT numbers (whole numbers
    within 2^16, :func:`_whole_numbers`): the first pass sums whole numbers; its means are multiples of
    2^-(24 + log2 step), so the second pass's sums stay within float64's 53 bits; the third pass's too
    when the data are never negative (no cancellation leaves a tiny residual); a pass that may not be
    exact is scipy's own. For such data the passes run slab by slab along the first axis (a slab of the
    output needs only its slab of the input): small temporaries, no full-size intermediate. Other data
    take scipy's passes one after the other, each on the voxels the passes before it kept.
    """
    steps = tuple(int(s) for s in steps)
    kind = _whole_numbers(data)
    passes, bits = [], 0                        # bits: log2 of the product of the earlier steps (rounded up)
    for done, (axis, n) in enumerate((a, n) for a, n in enumerate(steps) if n > 1):
        exact = kind is not None and (done == 0 and n <= 256 or done == 1 and (n << bits) <= 2048
                                      or done == 2 and kind == "unsigned" and (n << bits) <= 2048)
        passes.append((axis, n, (np.float32 if done == 0 else np.float64) if exact else None))
        bits += int(np.ceil(np.log2(n)))

    def run(block, todo):
        for axis, n, acc in todo:
            if acc is not None:
                block = _window_means(block, n, axis, acc)
            else:
                every_nth = (slice(None),) * axis + (slice(None, None, n),)
                block = uniform_filter1d(block, n, axis=axis, mode="nearest")[every_nth]
        return block

    if kind is None or not passes:
        return run(data, passes)
    count = -(-data.shape[0] // steps[0])
    out = np.empty((count,) + tuple(-(-m // n) for m, n in zip(data.shape[1:], steps[1:])), np.float32)
    rows = max(1, block_bytes // (4 * steps[0] * max(1, data[0].size)))
    first = passes[0] if passes[0][0] == 0 else None      # the pass along the slab axis itself
    for m0 in range(0, count, rows):
        m1 = min(count, m0 + rows)
        if first is not None:
            block = _window_means(data, first[1], 0, first[2], (m0, m1))
        else:
            block = data[m0:m1]
        out[m0:m1] = run(block, passes[1:] if first is not None else passes)
    return out


def _window_means(data: np.ndarray, n: int, axis: int, acc_dtype, outputs=None) -> np.ndarray:
    """float32 means of the windows of every n-th voxel along `axis` (voxels m*n - n//2 ... m*n + n - n//2 - 1,
    clamped to the edge as scipy's mode "nearest") for the samples m in ``outputs = (m0, m1)`` (default all):
    the window sum in `acc_dtype` (the caller makes sure it is exact) divided by n, from strided views."""
    length = data.shape[axis]
    m0, m1 = outputs if outputs is not None else (0, -(-length // n))

    def along(index):
        return data[(slice(None),) * axis + (index,)]

    shape = list(data.shape)
    shape[axis] = m1 - m0
    acc = np.empty(shape, acc_dtype)
    for t in range(-(n // 2), n - n // 2):
        lo = min(max(m0, -(-max(-t, 0) // n)), m1)      # samples lo..hi-1 have their voxel m*n + t in the scan
        hi = max(min(m1, (length - 1 - t) // n + 1), lo)
        inner = slice(lo * n + t, (hi - 1) * n + t + 1, n) if hi > lo else slice(0, 0)
        pieces = ((slice(0, lo - m0), along(slice(0, 1))), (slice(lo - m0, hi - m0), along(inner)),
                  (slice(hi - m0, m1 - m0), along(slice(length - 1, length))))
        for where, values in pieces:
            target = acc[(slice(None),) * axis + (where,)]
            if t == -(n // 2):
                target[...] = values
            else:
                target += values
    np.divide(acc, acc_dtype(n), out=acc)
    return acc.astype(np.float32, copy=False)


def _whole_numbers(data: np.ndarray, slab: int = 4):
    """"unsigned" if the float32 `data` holds only whole numbers in 0 ... 65535, "signed" if in -32768 ... 32767,
    else None (slab by slab: small temporaries)."""
    if data.dtype != np.float32:
        return None
    slabs = [data[k:k + slab] for k in range(0, len(data), slab)]
    with np.errstate(invalid="ignore"):  # NaN and out-of-range values do not survive the round trip
        for kind, dtype in (("unsigned", np.uint16), ("signed", np.int16)):
            if all(np.array_equal(c, c.astype(dtype)) for c in slabs):
                return kind
    return None


def ct_grid_for(ct, wfield):
    """The CT for the ``ct`` grid: (data [z, y, x] float32, spacing, origin, direction).

    The w-field's own grid when it coincides with the CT's; otherwise the CT's
    grid (the whole CT box, as the paper's baseline texture) decimated by block
    means to about the w-field's voxel size, so both grids have a comparable
    resolution and the file stays small.
    """
    same = (tuple(ct.data.shape) == tuple(np.shape(wfield.w))
            and np.allclose(ct.affine, grid_affine(wfield.spacing, wfield.origin, wfield.direction), atol=1e-6))
    if same:
        return ct.data, tuple(wfield.spacing), np.asarray(wfield.origin, float), np.asarray(wfield.direction, float)
    voxel = float(min(wfield.spacing))
    steps = tuple(max(1, int(round(voxel / s))) for s in ct.spacing)  # (k, j, i)
    data, origin = ct.data, np.asarray(ct.origin, float)
    if max(steps) > 1:
        data = decimated_block_mean(data, steps)
        # sample n averages CT voxels n*step - step//2 ... : its centre is shifted for even steps
        shift_kji = np.array([(n - 1) / 2.0 - n // 2 for n in steps])
        origin = origin + np.asarray(ct.direction, float) @ (shift_kji[::-1] * np.array(ct.spacing)[::-1])
    spacing = tuple(float(s) * n for s, n in zip(ct.spacing, steps))
    return np.ascontiguousarray(data, np.float32), spacing, origin, np.asarray(ct.direction, float)


def downsample_volume(ct: CTVolume, factor) -> CTVolume:
    """Block-mean downsampling of a CTVolume by integer factors (for scans too large to segment).

    Parameters
    ----------
    ct : CTVolume
    factor : int or (fz, fy, fx)
        Voxels averaged along each axis; trailing voxels that do not fill a block are dropped.

    Returns
    -------
    CTVolume
        float32 means of ``fz x fy x fx`` blocks; spacing multiplied by the factors; the origin
        moved to the centre of the first block, so every voxel keeps its patient position;
        ``coverage`` (if any) is True where the whole block was covered; ``meta["downsampled"]``
        records the factors. Works slab by slab (one extra slab of float32 at a time).
    """
    fz, fy, fx = (int(f) for f in (np.broadcast_to(np.asarray(factor), 3)))
    if min(fz, fy, fx) < 1:
        raise ValueError(f"downsample factors must be integers >= 1, got {factor!r}")
    nz, ny, nx = (n // f for n, f in zip(ct.shape, (fz, fy, fx)))
    if min(nz, ny, nx) < 1:
        raise ValueError(f"downsample factors {(fz, fy, fx)} are larger than the volume {ct.shape}")
    out = np.empty((nz, ny, nx), dtype=np.float32)
    cover = None if ct.coverage is None else np.empty((nz, ny, nx), dtype=bool)
    for k in range(nz):
        block = ct.data[k * fz:(k + 1) * fz, :ny * fy, :nx * fx].reshape(fz, ny, fy, nx, fx)
        out[k] = block.mean(axis=(0, 2, 4), dtype=np.float32)
        if cover is not None:
            cblock = ct.coverage[k * fz:(k + 1) * fz, :ny * fy, :nx * fx].reshape(fz, ny, fy, nx, fx)
            cover[k] = cblock.all(axis=(0, 2, 4))
    dz, dy, dx = ct.spacing
    shift = np.array([(fx - 1) * dx, (fy - 1) * dy, (fz - 1) * dz]) / 2.0
    meta = dict(ct.meta)
    meta["downsampled"] = (fz, fy, fx)
    meta["shape_before_downsample"] = tuple(ct.shape)
    return CTVolume(out, (dz * fz, dy * fy, dx * fx), ct.origin + ct.direction @ shift, ct.direction, meta,
                    coverage=cover)
