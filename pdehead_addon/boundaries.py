"""Step 3: per-slice boundary curves (paper eq. 22) and the choice of 3t+1 of them (section 4.1).

The paper extracts the head boundary of a segmented slice ``I`` with the
morphological boundary operator

    beta(I) = I - (I erode S)                                     (eq. 22)

and feeds 3t+1 such boundaries, one per chosen axial slice, to t fourth-order
PDE patches that share their end curves (section 4.1). A pixel ring is not
yet a PDE boundary condition: the PDE needs each boundary as a closed curve
P(v), v in [0, 2 pi), sampled the same way on every slice. This module turns the
eq. 22 ring into such a curve:

1. the main (largest) connected component of the cleaned mask slice, with its
   holes filled and inlets narrower than ~2 x ``closing_mm`` bridged
   (:func:`close_region`), is the head's *outer region*; its eq. 22 ring
   (:func:`boundary_ring`) is the outer head boundary in pixels;
2. the returned curve is the sub-pixel refinement of that ring: the 0.5 level
   line (marching squares, :func:`skimage.measure.find_contours`) of the outer
   region smoothed by a Gaussian of ``sigma`` pixels (or, with
   ``level_field="probability"``, of the soft segmentation probability clamped
   to a ``band`` of pixels around the ring). With the default 4-connected
   structuring element, the pixels the unsmoothed level line passes are exactly
   the eq. 22 ring pixels; the ring is used to validate the curve (every curve
   point lies within ``band + 1`` pixel of a ring pixel) and to report how much
   of the ring the curve follows (``meta["ring_coverage"]``);
3. the curve is mapped to patient LPS mm, oriented counter-clockwise seen from
   above (from +z, superior), low-passed along its arc length (Gaussian of
   ``curve_sigma`` pixels: the pixel-grid ripple repeats on every slice and
   would streak the surface), started at its posterior midline point (the seam
   v = 0, at the back of the head, so the face is seam-free) and resampled at M
   points uniformly in arc length;
4. by default (``parameterisation="aligned"``) the samples are then moved
   along each curve so that equal v means corresponding points on neighbouring
   curves (:func:`~.parameterisation.align_parameterisation`).

Conventions of every curve returned (shared with :class:`BoundarySet`):

* orientation: counter-clockwise in the patient (x, y) plane seen from +z,
  i.e. positive signed (shoelace) area in (x, y). In LPS, starting at the back
  (+y), v runs back -> patient right (-x) -> face (-y) -> patient left (+x) ->
  back. For a surface X(u, v) with u increasing superior (inferior -> superior
  curve order) the OUTWARD normal is ``dX/dv x dX/du``.
* seam: sample 0 is where the curve crosses the ray from its area centroid
  toward +y (posterior) along x = centroid x (the outermost such crossing).
* spacing: with ``parameterisation="arc-length"`` the M samples are equally
  spaced in arc length along the smoothed polyline (periodic linear
  interpolation of cumulative chord length), so the parameterisation of
  neighbouring curves does not twist (:func:`parameter_offsets` measures it),
  but features on one side only (an ear, the nose) move the samples of the
  next curve by a few steps (CThead, t = 10, M = 256: median 0-1, maximum 7).
  The default ``"aligned"`` keeps the same polylines and the same seam and
  re-spaces the samples by dynamic time warping between neighbours; on CThead
  (t = 10) the mean distance between equal-v samples of neighbouring centred
  curves drops from ~9.3 to ~4.9 mm and the PDE surface's mean distance to
  marching cubes from 0.67 to 0.45 mm.

Choice of slices (section 4.1): the paper picks 3t+1 slices by hand and calls
an automatic choice an open problem (section 6). Here a slice is *usable* if
its mask area is at least ``min_area_fraction`` (5 %) of the largest slice
area, which leaves out the degenerate vertex cap and stray voxels at the ends;
the head's extent runs from the lowest to the highest usable slice. The
strategy is pluggable (:data:`SELECTION_STRATEGIES`): ``"uniform"`` (evenly
spaced in height) and ``"shape-change"`` (denser where the cross-section
changes fast: chin, nose, vertex), a callable, or explicit indices. ``"auto"``
(:mod:`.slice_selection`) traces every usable slice and keeps the curves whose
C2 surface is closest to all of their outlines; with ``tolerance_mm`` it also
chooses how many (the default C2 surface takes any count, not only 3t+1).

Limits: one curve per slice, so a part of the head that is a separate
component in a slice (an ear lobe cut off in that plane) is dropped, while an
opening connected to the outside (ear canal, nostril) is followed into the
head. Where the scan does not cover the whole head (the lowest slices of a
tilted series), the curve closes along the edge of the data.
"""
from __future__ import annotations

import math
from numbers import Integral
from typing import Callable, Sequence, Union

import numpy as np
from scipy import ndimage as ndi
from skimage import measure

from .boundary_set import MIN_CURVES, BoundarySet, knots_from_heights
from .envelope import ENVELOPE_CLOSING_MM, ENVELOPE_SIGMA_MM, head_envelope, outer_region
from .errors import BoundaryError, report_progress
from .parameterisation import PARAMETERISATIONS, align_parameterisation, closed_arc_length, smooth_closed_curve

__all__ = [
    "extract_boundaries", "boundary_ring", "outer_region", "close_region", "outer_contour", "contour_from_mask",
    "resample_closed_curve", "orient_and_resample", "signed_area", "polygon_centroid",
    "parameter_offsets", "self_intersections", "usable_slices", "select_uniform",
    "select_shape_change", "register_selection", "SELECTION_STRATEGIES", "PARAMETERISATIONS",
]

SelectionFunc = Callable[..., Sequence[int]]
Selection = Union[str, SelectionFunc, Sequence[int], np.ndarray]

#: Largest share of a slice's outline that may be the edge of the scanned slab (tilted series).
MAX_SCAN_EDGE_FRACTION = 0.1
#: Default fraction of the largest slice area below which a slice counts as degenerate.
MIN_AREA_FRACTION = 0.05
#: Default closing radius (mm) of each slice's outline: bridges nostrils, mouth slit, ear canal.
CLOSING_MM = 3.0
#: Default low-pass along each curve (Gaussian sigma, pixels) against the pixel-grid ripple.
CURVE_SIGMA_PX = 1.0
#: The same for the envelope's curves: its 3-D smoothing makes neighbouring outlines agree, so what
#: is left of the CT noise on the outline repeats from curve to curve as vertical wrinkles. 0.5 px
#: (issue 21; was 1.5): on top of the envelope's Gaussian a 1.5 px low-pass only took the face off.
ENVELOPE_CURVE_SIGMA_PX = 0.5
#: Star hull: bound on |d ln r / d theta| (3: the normal stays within 72 degrees of the ray). Issue 21:
#: 2 (63 degrees) filled the groove beside the nose wings, whose sides run almost along the ray; at 3
#: CThead's mouth corners keep no pit any more (notch fraction 0 with the 1 mm envelope).
STAR_MAX_SLOPE = 3.0
#: Smoothing length (mm) of the centroid track that the angular parameterisation is centred on.
SPINE_SMOOTHING_MM = 10.0
#: Sources of the level line traced per slice.
LEVEL_FIELDS = ("envelope", "mask", "probability")


# --------------------------------------------------------------------------- eq. 22 and outer region
def boundary_ring(mask2d: np.ndarray, structure: np.ndarray | None = None) -> np.ndarray:
    """The morphological boundary of a binary slice, paper eq. 22: ``beta(I) = I - (I erode S)``.

    Parameters
    ----------
    mask2d : ndarray of bool, shape (ny, nx)
        The segmented slice ``I``.
    structure : ndarray of bool, optional
        The structuring element ``S``. Default: the 3x3 cross (4-connectivity),
        whose ring is the set of object pixels with a 4-neighbour outside the
        object, i.e. exactly the object pixels a marching-squares level line
        of ``I`` passes next to. Pixels outside the image count as background,
        so object pixels on the image border are boundary pixels.

    Returns
    -------
    ndarray of bool, shape (ny, nx)
        The boundary pixels ``beta(I)``; a subset of ``I``.
    """
    mask = np.asarray(mask2d, dtype=bool)
    if mask.ndim != 2:
        raise BoundaryError(f"boundary_ring needs a 2-D mask, got shape {mask.shape}")
    if structure is None:
        # I erode (3x3 cross) by array shifts: same result as scipy's binary_erosion, ~10x faster.
        eroded = mask.copy()
        eroded[1:, :] &= mask[:-1, :]
        eroded[:-1, :] &= mask[1:, :]
        eroded[:, 1:] &= mask[:, :-1]
        eroded[:, :-1] &= mask[:, 1:]
        eroded[[0, -1], :] = False
        eroded[:, [0, -1]] = False
    else:
        eroded = ndi.binary_erosion(mask, structure=structure, border_value=0)
    return mask & ~eroded


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Binary dilation by a (2r+1)^2 square (separable maximum filter: fast)."""
    return ndi.maximum_filter(mask, size=2 * radius + 1, mode="constant", cval=0) if radius else mask


def _window_any(image: np.ndarray, points: np.ndarray, radius: int) -> np.ndarray:
    """For integer pixels ``points[:, (row, col)]``: is any ``image`` pixel set within ``radius`` (Chebyshev)?"""
    padded = np.pad(image, radius)
    offsets = np.arange(-radius, radius + 1)
    rows = points[:, 0, None, None] + radius + offsets[None, :, None]
    cols = points[:, 1, None, None] + radius + offsets[None, None, :]
    return padded[rows, cols].reshape(len(points), -1).any(axis=1)


def _erode(mask: np.ndarray, radius: int) -> np.ndarray:
    """Binary erosion by a (2r+1)^2 square, outside the image counting as background."""
    return ndi.minimum_filter(mask, size=2 * radius + 1, mode="constant", cval=0) if radius else mask


def _crop(array: np.ndarray, r0: int, r1: int, c0: int, c1: int, fill=0) -> np.ndarray:
    """``array[r0:r1, c0:c1]`` where rows/columns outside the image read as ``fill``."""
    out = np.full((r1 - r0, c1 - c0), fill, dtype=array.dtype)
    ny, nx = array.shape
    a0, a1, b0, b1 = max(r0, 0), min(r1, ny), max(c0, 0), min(c1, nx)
    if a0 < a1 and b0 < b1:
        out[a0 - r0:a1 - r0, b0 - c0:b1 - c0] = array[a0:a1, b0:b1]
    return out


def _shoelace(xy: np.ndarray) -> float:
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def close_region(region: np.ndarray, radius: float) -> np.ndarray:
    """Morphological closing by a disk of ``radius`` pixels, holes filled afterwards.

    Fills inlets of the outline narrower than about ``2 * radius`` pixels
    (nostrils, a slightly open mouth, the gap behind an ear flap) while
    leaving convex parts of the outline where they are. ``region`` needs a
    background margin of at least ``radius + 1`` pixels.
    """
    if radius <= 0:
        return region
    grown = ndi.distance_transform_edt(~region) <= radius
    closed = ndi.distance_transform_edt(grown) > radius
    return outer_region(closed | region)


def outer_contour(mask2d: np.ndarray, sigma: float = 0.7, probability: np.ndarray | None = None,
                  band: int = 1, connectivity: int = 2, return_info: bool = False, closing: float = 0.0):
    """Sub-pixel outer contour of a slice's main component (refinement of its eq. 22 ring).

    Parameters
    ----------
    mask2d : ndarray of bool, shape (ny, nx)
        The cleaned segmentation of one slice.
    sigma : float
        Gaussian smoothing (pixels) of the level field before the 0.5 level
        line is traced; removes the pixel staircase. 0 disables it.
    probability : ndarray of float, shape (ny, nx), optional
        Soft membership in [0, 1] (paper eq. 16). When given, the level field is
        1 inside the outer region eroded by ``band`` pixels, 0 outside it dilated
        by ``band`` pixels and ``probability`` in between, so the curve follows
        the soft segmentation but never strays more than ``band`` pixels from the
        cleaned mask's boundary.
    band : int
        Half-width (pixels) of that band; also the validation tolerance.
    connectivity : {1, 2}
        Connectivity of the main component (see :func:`outer_region`).
    return_info : bool
        Also return a dict with the pixel area of the outer region and the
        eq. 22 ring coverage.
    closing : float
        Radius (pixels) of a disk closing of the outer region first
        (:func:`close_region`); the eq. 22 ring is then that of the closed
        region. 0 = none.

    Returns
    -------
    contour : ndarray, shape (P, 2)
        Closed polyline (last point not repeated) in fractional pixel
        coordinates ``(row, col)`` of ``mask2d``, in marching-squares order.
    info : dict
        Only with ``return_info``: ``area_px`` (pixels in the outer region),
        ``ring_coverage`` (fraction of eq. 22 ring pixels within 1 pixel, or
        ``band + 1`` pixels with ``probability``, of a contour point).

    Raises
    ------
    BoundaryError
        Empty slice, or no closed contour could be traced.
    """
    mask = np.asarray(mask2d, dtype=bool)
    if mask.ndim != 2:
        raise BoundaryError(f"outer_contour needs a 2-D mask, got shape {mask.shape}")
    if probability is not None:
        probability = np.asarray(probability, dtype=np.float32)
        if probability.shape != mask.shape:
            raise BoundaryError(f"probability shape {probability.shape} != mask shape {mask.shape}")
    sigma = float(sigma)
    band = int(band)
    if sigma < 0 or band < 0:
        raise BoundaryError(f"sigma and band must be >= 0, got {sigma}, {band}")
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size == 0:
        raise BoundaryError("the slice mask is empty: no boundary to extract")
    cols = np.flatnonzero(mask.any(axis=0))
    # Work on a crop with a zero margin so every level line closes, also when
    # the head touches the image border (it is then closed along the border).
    pad = int(math.ceil(4 * sigma)) + band + 2 + int(math.ceil(closing))
    r0, r1, c0, c1 = rows[0] - pad, rows[-1] + 1 + pad, cols[0] - pad, cols[-1] + 1 + pad
    reg = close_region(outer_region(_crop(mask, r0, r1, c0, c1), connectivity), float(closing))
    if probability is None:
        field = reg.astype(np.float32)
    else:
        prob = np.clip(_crop(probability, r0, r1, c0, c1), 0.0, 1.0)
        field = np.where(_erode(reg, band), np.float32(1), np.where(_dilate(reg, band), prob, np.float32(0)))
    if sigma > 0:
        field = ndi.gaussian_filter(field, sigma, mode="constant", cval=0.0)
    contours = [c for c in measure.find_contours(field, 0.5, fully_connected="high")
                if len(c) >= 4 and np.allclose(c[0], c[-1])]
    if not contours:
        raise BoundaryError("no closed outer contour found in the slice (mask too small or too thin)")
    # The outer contour encloses the largest area; holes were filled, but
    # smoothing may split off thin parts, which are dropped with the rest.
    contour = max(contours, key=lambda c: abs(_shoelace(c[:-1])))[:-1]

    # Validate against the eq. 22 ring: every curve point within band+1 px
    # (Chebyshev) of a ring pixel.
    ring = boundary_ring(reg)
    idx = np.rint(contour).astype(np.intp)
    if not _window_any(ring, idx, band + 1).all():
        raise BoundaryError("sub-pixel contour departs from the eq. 22 boundary ring (smoothing too strong?)")
    contour = contour + np.array([r0, c0], dtype=np.float64)
    if not return_info:
        return contour
    reach = 1 if probability is None else band + 1   # how far the curve may lie from the ring
    traced = np.zeros_like(ring)
    traced[idx[:, 0], idx[:, 1]] = True
    ring_px = np.argwhere(ring)
    info = dict(area_px=int(reg.sum()),
                ring_coverage=float(_window_any(traced, ring_px, reach).mean()) if len(ring_px) else 0.0)
    return contour, info


def contour_from_field(field: np.ndarray, origin: tuple[int, int] = (0, 0)) -> tuple[np.ndarray, dict]:
    """The largest closed 0.5 level line of a soft 2-D field, in (row, col) pixels of the volume.

    Parameters
    ----------
    field : ndarray of float, shape (ny, nx)
        A slice of :func:`~.envelope.head_envelope` (0 at its border).
    origin : (int, int)
        Row and column of ``field[0, 0]`` in the volume's slice.

    Returns
    -------
    contour : ndarray, shape (P, 2)
    info : dict
        ``area_px`` (pixels enclosed) and ``ring_coverage`` (NaN: the envelope is not an eq. 22 ring).
    """
    if not np.any(field >= 0.5):
        raise BoundaryError("the head envelope is empty in this slice (nothing above the 0.5 level)")
    padded = np.pad(np.asarray(field, np.float32), 1)
    contours = [c for c in measure.find_contours(padded, 0.5, fully_connected="high")
                if len(c) >= 4 and np.allclose(c[0], c[-1])]
    if not contours:
        raise BoundaryError("no closed outer contour found in the head envelope")
    contour = max(contours, key=lambda c: abs(_shoelace(c[:-1])))[:-1]
    area = abs(_shoelace(contour))
    return contour + np.array([origin[0] - 1, origin[1] - 1], float), dict(area_px=area, ring_coverage=float("nan"))


def _max_thickness(value) -> float | None:
    """The largest slice thickness (mm) a source recorded (a number or a list), or None."""
    try:
        arr = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        return None
    arr = arr[np.isfinite(arr) & (arr > 0)]
    return float(arr.max()) if arr.size else None


def _head_top(mask: np.ndarray, slice_z: np.ndarray, dz: float) -> float | None:
    """Patient z of the crown (the top face of the most superior head slice), if the head ends in the scan."""
    occupied = np.flatnonzero(mask.reshape(len(mask), -1).any(axis=1))
    if occupied.size == 0:
        return None
    superior_is_last = slice_z[-1] >= slice_z[0]
    top = occupied[-1] if superior_is_last else occupied[0]
    if top in (0, len(mask) - 1):                      # cut off by the scan: the crown is not known
        return None
    return float(slice_z[top] + 0.5 * abs(dz))


# --------------------------------------------------------------------------- curve parameterisation
def signed_area(xy: np.ndarray) -> float:
    """Signed (shoelace) area of a closed polygon ``[..., (x, y)]``; > 0 if counter-clockwise."""
    return _shoelace(np.asarray(xy, dtype=np.float64)[:, :2])


def polygon_centroid(xy: np.ndarray) -> np.ndarray:
    """Area centroid ``(x, y)`` of a closed simple polygon (last vertex not repeated)."""
    p = np.asarray(xy, dtype=np.float64)[:, :2]
    q = np.roll(p, -1, axis=0)
    cross = p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]
    area = 0.5 * cross.sum()
    if abs(area) < 1e-12:
        return p.mean(axis=0)
    return ((p + q) * cross[:, None]).sum(axis=0) / (6.0 * area)


def resample_closed_curve(points: np.ndarray, samples: int, start: float = 0.0) -> np.ndarray:
    """Resample a closed polyline at equal arc-length steps.

    Parameters
    ----------
    points : ndarray, shape (P, d)
        Closed polyline, last point not repeated.
    samples : int
        Number M of output points.
    start : float
        Arc length (same unit as ``points``) from ``points[0]`` at which sample
        0 is placed.

    Returns
    -------
    ndarray, shape (M, d)
        Points on the polyline at arc lengths ``start + L*m/M`` (periodic linear
        interpolation of cumulative chord length, L = perimeter).
    """
    p = np.asarray(points, dtype=np.float64)
    s, closed, length = closed_arc_length(p)
    target = np.mod(start + length * np.arange(samples) / samples, length)
    return np.stack([np.interp(target, s, closed[:, d]) for d in range(p.shape[1])], axis=1)


def _posterior_seam(xy: np.ndarray, center: np.ndarray) -> float:
    """Arc length (from vertex 0) of the outermost crossing of the curve with the +y ray at x = center x."""
    closed = np.vstack([xy, xy[:1]])
    seg_len = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg_len)])
    x0, x1 = closed[:-1, 0] - center[0], closed[1:, 0] - center[0]
    # Half-open test so that a vertex exactly on the line counts once.
    hit = np.flatnonzero(((x0 <= 0) & (x1 > 0)) | ((x0 > 0) & (x1 <= 0)))
    if hit.size == 0:  # cannot happen for a closed curve around its centroid; be safe
        i = int(np.argmax(xy[:, 1]))
        return float(s[i])
    tau = x0[hit] / (x0[hit] - x1[hit])
    y = closed[hit, 1] + tau * (closed[hit + 1, 1] - closed[hit, 1])
    behind = y > center[1]
    pick = int(np.argmax(np.where(behind, y, -np.inf))) if behind.any() else int(np.argmax(y))
    return float(s[hit[pick]] + tau[pick] * seg_len[hit[pick]])


def _lipschitz_envelope(f: np.ndarray, step: float) -> np.ndarray:
    """Smallest periodic g >= f with |g[i+1] - g[i]| <= step (two sweeps each way, twice round)."""
    n = len(f)
    g = np.concatenate([f, f, f])
    idx = np.arange(len(g)) * step
    # forward: g[i] = max_j<=i (f[j] - (i - j) step) = max.accumulate(f + j step) - i step
    g = np.maximum(g, np.maximum.accumulate(g + idx) - idx)
    g = np.maximum(g, (np.maximum.accumulate((g - idx)[::-1]))[::-1] + idx)
    return g[n:2 * n]


def star_hull(points: np.ndarray, centre: np.ndarray | None = None, angles: int = 1440,
              step: float = 0.2, max_slope: float | None = STAR_MAX_SLOPE) -> np.ndarray:
    """The smallest region star-shaped around ``centre`` that contains a closed curve.

    Along every ray from the centre the farthest point of the curve is kept, so
    inlets whose walls face the centre - the notch behind an ear, a nostril, a
    crater in the concha - are filled and the ear becomes a smooth bump. With
    ``max_slope`` the radius is moreover raised to the smallest function with
    ``|d ln r / d theta| <= max_slope``: the filling is a web sloping at most
    ``atan(max_slope)`` away from the circle (the outward normal stays within that
    angle of the ray), not a radial wall. A curve that already satisfies this (most
    of a head's outline, the nose) is returned as it is, up to the angular sampling.

    Parameters
    ----------
    points : ndarray, shape (P, 2) or (P, 3)
        Closed polyline (x, y[, z]), last point not repeated.
    centre : ndarray, shape (2,), optional
        Default: the polygon's area centroid.
    angles : int
        Rays (the hull's vertices), equally spaced in angle.
    step : float
        The curve is first resampled to this spacing (unit of ``points``) so every
        ray meets a sample.
    max_slope : float or None
        Bound on ``|d ln r / d theta|``; None: the plain star-shaped hull.

    Returns
    -------
    ndarray, shape (angles, d)
        Counter-clockwise; z (if given) of the farthest point on each ray.
    """
    p = np.asarray(points, dtype=np.float64)
    c = polygon_centroid(p[:, :2]) if centre is None else np.asarray(centre, float)[:2]
    length = float(closed_arc_length(p[:, :2])[-1])
    dense = resample_closed_curve(p, max(len(p), int(np.ceil(length / step))))
    d = dense[:, :2] - c
    theta = np.arctan2(d[:, 1], d[:, 0])
    r = np.hypot(d[:, 0], d[:, 1])
    k = np.floor((theta + np.pi) / (2 * np.pi) * angles).astype(np.int64) % angles
    order = np.lexsort((r, k))                        # within each bin, the farthest point last
    last = np.ones(len(order), bool)
    last[:-1] = k[order][1:] != k[order][:-1]
    best = order[last]
    filled = np.zeros(angles, bool)
    filled[k[best]] = True
    radius = np.zeros(angles)
    radius[k[best]] = r[best]
    bins = np.flatnonzero(filled)
    grid = np.arange(angles)
    radius = np.interp(grid, bins, radius[bins], period=angles)
    if max_slope is not None and max_slope > 0:
        radius = np.exp(_lipschitz_envelope(np.log(np.maximum(radius, 1e-9)), max_slope * 2 * np.pi / angles))
    phi = (grid + 0.5) / angles * 2 * np.pi - np.pi
    out = np.empty((angles, p.shape[1]))
    out[:, 0] = c[0] + radius * np.cos(phi)
    out[:, 1] = c[1] + radius * np.sin(phi)
    if p.shape[1] > 2:
        zz = np.zeros(angles)
        zz[k[best]] = dense[best, 2]
        out[:, 2] = np.interp(grid, bins, zz[bins], period=angles)
    return out


def spine_centres(outlines: Sequence[np.ndarray], length: float = SPINE_SMOOTHING_MM) -> np.ndarray:
    """Area centroids (x, y) of the outlines, smoothed along their height (a smooth spine), shape (n, 2)."""
    from .pde_spline import smoothing_spline_values
    c = np.stack([polygon_centroid(o[:, :2]) for o in outlines])
    z = np.array([float(np.mean(o[:, 2])) for o in outlines])
    order = np.argsort(z)
    zs = z[order]
    if len(z) >= 3 and np.all(np.diff(zs) > 0):
        c[order] = smoothing_spline_values(zs, c[order], length)
    return c


def angular_curves(outlines: Sequence[np.ndarray], samples: int, smooth: float = 0.0,
                   max_slope: float | None = STAR_MAX_SLOPE) -> np.ndarray:
    """Curves sampled at equal angles around a smooth spine: sample m at angle ``pi/2 + 2 pi m / M``.

    Each outline is replaced by its :func:`star_hull` around its point of the smoothed
    centroid track (:func:`spine_centres`) and sampled along the rays of the angles
    ``theta_m = pi/2 + 2 pi m / M`` (m = 0: posterior, +y; counter-clockwise seen from
    +z). Equal v is then the same direction from the spine on every curve: the
    correspondence varies as smoothly from curve to curve as the spine, with no
    alignment step. ``smooth`` (mm) low-passes ``r(theta)`` (Gaussian in arc length at
    the mean radius).

    Returns
    -------
    ndarray, shape (n, samples, 3)
    """
    centres = spine_centres(outlines)
    out = np.empty((len(outlines), samples, 3))
    theta = 0.5 * np.pi + 2 * np.pi * np.arange(samples) / samples
    for i, (o, c) in enumerate(zip(outlines, centres)):
        hull = star_hull(o, centre=c, max_slope=max_slope)
        phi = np.arctan2(hull[:, 1] - c[1], hull[:, 0] - c[0])
        r = np.hypot(hull[:, 0] - c[0], hull[:, 1] - c[1])
        order = np.argsort(phi)
        period = 2 * np.pi
        if smooth > 0:
            sig = smooth / max(float(r.mean()), 1e-9) / (period / len(r))     # in hull samples
            r = ndi.gaussian_filter1d(r[order], sig, mode="wrap")[np.argsort(order)]
        rr = np.interp(theta, phi[order], r[order], period=period)
        out[i, :, 0] = c[0] + rr * np.cos(theta)
        out[i, :, 1] = c[1] + rr * np.sin(theta)
        out[i, :, 2] = np.interp(theta, phi[order], hull[order, 2], period=period)
    return out


def orient_and_resample(points: np.ndarray, samples: int, smooth: float = 0.0) -> np.ndarray:
    """Give a closed curve the shared parameterisation of all boundary curves.

    The curve is made counter-clockwise in (x, y) (seen from +z), optionally
    low-passed along its arc length (:func:`smooth_closed_curve`), started at
    its posterior midline (the crossing with the ray from its area centroid
    toward +y at x = centroid x) and resampled at ``samples`` points equally
    spaced in arc length.

    Parameters
    ----------
    points : ndarray, shape (P, 2) or (P, 3)
        Closed polyline ``(x, y[, z])``, last point not repeated.
    samples : int
    smooth : float
        Standard deviation (unit of ``points``) of the Gaussian low-pass along
        the curve; 0 = none.

    Returns
    -------
    ndarray, shape (samples, d)
    """
    p = np.asarray(points, dtype=np.float64)
    if _shoelace(p[:, :2]) < 0:
        p = p[::-1]
    if smooth > 0:
        p = smooth_closed_curve(p, smooth)
    start = _posterior_seam(p[:, :2], polygon_centroid(p))
    return resample_closed_curve(p, samples, start=start)


def contour_from_mask(mask2d: np.ndarray, spacing_yx: tuple[float, float] = (1.0, 1.0), samples: int = 256,
                      sigma: float = 0.7, probability: np.ndarray | None = None, band: int = 1,
                      connectivity: int = 2) -> np.ndarray:
    """Closed outer boundary curve of a 2-D mask, arc-length resampled (eq. 22 refined to sub-pixel).

    Parameters
    ----------
    mask2d : ndarray of bool, shape (ny, nx)
    spacing_yx : (float, float)
        Pixel size (dy, dx); (1, 1) gives pixel units.
    samples : int
        Number M of points.
    sigma, probability, band, connectivity
        See :func:`outer_contour`.

    Returns
    -------
    ndarray, shape (M, 2)
        Columns ``(x, y) = (col * dx, row * dy)``: counter-clockwise in (x, y),
        sample 0 on the +y (increasing row; posterior for loader-oriented
        slices) ray from the area centroid, uniform in arc length.
    """
    samples = _check_samples(samples)
    dy, dx = (float(s) for s in spacing_yx)
    rc = outer_contour(mask2d, sigma=sigma, probability=probability, band=band, connectivity=connectivity)
    return orient_and_resample(np.column_stack([rc[:, 1] * dx, rc[:, 0] * dy]), samples)


# --------------------------------------------------------------------------- quality measures
def parameter_offsets(curves: np.ndarray) -> np.ndarray:
    """Cyclic parameter offset between consecutive curves (0 = no twist).

    For curves ``a = curves[k]`` and ``b = curves[k+1]``, both centred on their
    mean (x, y) and scaled to unit RMS radius, the offset is the integer shift s
    in ``(-M/2, M/2]`` minimising ``sum_i |a_i - b_{i+s}|^2`` over the (x, y)
    coordinates.

    Parameters
    ----------
    curves : ndarray, shape (n, M, 2 or 3)

    Returns
    -------
    ndarray of int, shape (n - 1,)
    """
    c = np.asarray(curves, dtype=np.float64)[..., :2]
    c = c - c.mean(axis=1, keepdims=True)
    c /= np.sqrt((c ** 2).sum(axis=2).mean(axis=1))[:, None, None]
    m = c.shape[1]
    fa = np.fft.fft(c[:-1], axis=1)
    fb = np.fft.fft(c[1:], axis=1)
    # corr[s] = sum_i a_i . b_{i+s}; maximal correlation = minimal squared distance.
    corr = np.fft.ifft(np.conj(fa) * fb, axis=1).real.sum(axis=2)
    shift = corr.argmax(axis=1)
    return np.where(shift > m // 2, shift - m, shift).astype(np.int64)


def self_intersections(xy: np.ndarray) -> int:
    """Number of pairs of non-adjacent edges of a closed polygon that intersect (0 = simple).

    Parameters
    ----------
    xy : ndarray, shape (M, 2+)
        Closed polygon (last vertex not repeated); only x, y are used.
    """
    p = np.asarray(xy, dtype=np.float64)[:, :2]
    a, b = p, np.roll(p, -1, axis=0)
    m = len(p)
    i, j = np.triu_indices(m, k=2)
    keep = ~((i == 0) & (j == m - 1))  # first and last edges share vertex 0
    i, j = i[keep], j[keep]

    def orient(p1, p2, p3):
        return np.sign((p2[:, 0] - p1[:, 0]) * (p3[:, 1] - p1[:, 1]) - (p2[:, 1] - p1[:, 1]) * (p3[:, 0] - p1[:, 0]))

    o1, o2 = orient(a[i], b[i], a[j]), orient(a[i], b[i], b[j])
    o3, o4 = orient(a[j], b[j], a[i]), orient(a[j], b[j], b[i])
    return int(np.count_nonzero((o1 * o2 < 0) & (o3 * o4 < 0)))


# --------------------------------------------------------------------------- slice selection
def usable_slices(mask: np.ndarray, heights: np.ndarray, min_area_fraction: float = MIN_AREA_FRACTION) -> np.ndarray:
    """Slices whose mask area is at least ``min_area_fraction`` of the largest, sorted by height.

    The tiny cross-sections at the ends of the head (the vertex cap, stray
    voxels above it) give degenerate curves and are left out; the head's extent
    for the selection is the height range of the slices returned.
    """
    mask = np.asarray(mask)
    areas = np.count_nonzero(mask.reshape(mask.shape[0], -1), axis=1)
    if areas.max(initial=0) == 0:
        raise BoundaryError("the segmentation mask is empty: no head to extract boundaries from")
    usable = np.flatnonzero(areas >= max(min_area_fraction * areas.max(), 1))
    return usable[np.argsort(np.asarray(heights)[usable], kind="stable")]


def _assign_monotone(candidate_heights: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Strictly increasing candidate positions j_0 < ... < j_{n-1} minimising sum |h[j_i] - target_i|.

    Dynamic programming, O(n * N): unlike rounding each target to its nearest
    slice, it never picks a slice twice when slices are spaced unevenly.
    """
    h = np.asarray(candidate_heights, float)
    n, count = len(targets), len(h)
    cost = np.abs(h[None, :] - np.asarray(targets, float)[:, None])
    total = cost[0].copy()
    arg = np.zeros(cost.shape, dtype=np.intp)
    positions = np.arange(count)
    for i in range(1, n):
        best = np.minimum.accumulate(total)                        # best[j] = min(total[:j+1])
        where = np.maximum.accumulate(np.where(total == best, positions, 0))
        new = np.full(count, np.inf)
        new[1:] = cost[i, 1:] + best[:-1]                          # previous pick strictly before j
        arg[i, 1:] = where[:-1]
        total = new
    picks = np.empty(n, dtype=np.intp)
    picks[-1] = int(np.argmin(total))
    for i in range(n - 1, 0, -1):
        picks[i - 1] = arg[i, picks[i]]
    return picks


def _select_by_density(mask: np.ndarray, n: int, heights: np.ndarray, density: np.ndarray | None,
                       usable: np.ndarray) -> np.ndarray:
    h = np.asarray(heights, float)[usable]
    if len(usable) < n:
        most = (len(usable) - 1) // 3
        advice = (f"use fewer patches (t <= {most})" if most >= 1 else
                  "a PDE head needs at least 4 slices with a head cross-section (t = 1)")
        raise BoundaryError(f"only {len(usable)} slices have a usable head cross-section, but 3t+1 = {n} "
                            f"are needed; {advice}")
    if density is None:
        targets = np.linspace(h[0], h[-1], n)
    else:
        # Place targets at equal quantiles of the integral of the density over height.
        cum = np.concatenate([[0.0], np.cumsum(density * np.diff(h))])
        targets = np.interp(np.linspace(0.0, cum[-1], n), cum, h)
    return usable[_assign_monotone(h, targets)]


def select_uniform(mask: np.ndarray, n: int, heights: np.ndarray,
                   min_area_fraction: float = MIN_AREA_FRACTION) -> np.ndarray:
    """``"uniform"``: n slices evenly spaced in height over the head's extent.

    The extent runs from the lowest to the highest slice whose area is at least
    ``min_area_fraction`` of the largest (:func:`usable_slices`); both ends are
    always chosen. Returns slice indices sorted inferior -> superior.
    """
    usable = usable_slices(mask, heights, min_area_fraction)
    return _select_by_density(mask, n, heights, None, usable)


def select_shape_change(mask: np.ndarray, n: int, heights: np.ndarray,
                        min_area_fraction: float = MIN_AREA_FRACTION, gain: float = 1.0) -> np.ndarray:
    """``"shape-change"``: more slices where the cross-section changes fast (nose, chin, vertex).

    Between consecutive usable slices the mean outward displacement of the
    boundary per mm of height is estimated as
    ``|M_k xor M_k+1| * dA / (perimeter * dz)``, with the perimeter of the
    equal-area disk. Slices are placed at equal quantiles of the density
    ``1 + gain * slope / mean(slope)``: half of them (gain = 1) follow the
    shape change, the rest keep the extent covered uniformly. This is the
    "intelligent selection of the medical slices" the paper leaves open
    (section 6). Returns slice indices sorted inferior -> superior.
    """
    usable = usable_slices(mask, heights, min_area_fraction)
    if len(usable) < n:
        return _select_by_density(mask, n, heights, None, usable)
    flat = np.asarray(mask, bool)[usable].reshape(len(usable), -1)
    change = np.count_nonzero(flat[1:] ^ flat[:-1], axis=1).astype(float)
    area = np.count_nonzero(flat, axis=1).astype(float)
    perimeter = 2.0 * np.sqrt(np.pi * np.maximum(0.5 * (area[1:] + area[:-1]), 1.0))
    dh = np.abs(np.diff(np.asarray(heights, float)[usable]))
    slope = change / (perimeter * np.maximum(dh, 1e-9))  # pixel units cancel only for square pixels;
    mean = slope.mean()                                   # the density is relative, so that is fine
    density = np.ones_like(slope) if mean <= 0 else 1.0 + float(gain) * slope / mean
    return _select_by_density(mask, n, heights, density, usable)


#: Named slice-selection strategies: ``f(mask, n, heights, **options) -> indices``.
SELECTION_STRATEGIES: dict[str, SelectionFunc] = {
    "uniform": select_uniform,
    "shape-change": select_shape_change,
}


def register_selection(name: str, func: SelectionFunc) -> None:
    """Add a named slice-selection strategy ``func(mask, n, heights, **options) -> indices``."""
    if not callable(func):
        raise BoundaryError(f"selection strategy {name!r} must be callable")
    SELECTION_STRATEGIES[str(name)] = func


def _check_curves(curves) -> int:
    if isinstance(curves, bool) or not isinstance(curves, Integral) or curves < MIN_CURVES:
        raise BoundaryError(f"curves must be an integer >= {MIN_CURVES}, got {curves!r}")
    return int(curves)


def _check_samples(samples) -> int:
    if isinstance(samples, bool) or not isinstance(samples, Integral) or samples < 8:
        raise BoundaryError(f"samples must be an integer >= 8, got {samples!r}")
    return int(samples)


def _validate_indices(indices, n: int, mask: np.ndarray, heights: np.ndarray, what: str) -> np.ndarray:
    try:
        raw = np.asarray(indices)
    except Exception as exc:  # noqa: BLE001 - anything unusable is a user error here
        raise BoundaryError(f"{what}: slice indices are not an array of integers ({exc})") from None
    if raw.ndim != 1 or raw.size == 0 or not (np.issubdtype(raw.dtype, np.integer)
                                              or (np.issubdtype(raw.dtype, np.floating)
                                                  and np.all(np.isfinite(raw)) and np.all(raw == np.round(raw)))):
        raise BoundaryError(f"{what}: slice indices must be a 1-D sequence of integers, got {indices!r}")
    idx = raw.astype(np.int64)
    if idx.size != n:
        raise BoundaryError(f"{what}: {idx.size} slices given, but 3t+1 = {n} are needed")
    nz = mask.shape[0]
    bad = idx[(idx < 0) | (idx >= nz)]
    if bad.size:
        raise BoundaryError(f"{what}: slice indices {bad.tolist()} out of range 0..{nz - 1}")
    if np.unique(idx).size != idx.size:
        raise BoundaryError(f"{what}: slice indices repeat: {idx.tolist()}")
    empty = [int(k) for k in idx if not mask[k].any()]
    if empty:
        raise BoundaryError(f"{what}: slices {empty} have an empty head mask")
    if not np.all(np.diff(heights[idx]) > 0):
        raise BoundaryError(f"{what}: slices must be sorted inferior -> superior (increasing height), "
                            f"got indices {idx.tolist()} at heights {np.round(heights[idx], 2).tolist()}")
    return idx


def scan_edge_slices(mask: np.ndarray, coverage: np.ndarray | None,
                     max_fraction: float = MAX_SCAN_EDGE_FRACTION) -> np.ndarray:
    """Slices whose outline is, in more than ``max_fraction`` of its length, the edge of the scan.

    After a tilted or unevenly spaced series is resampled (``CTVolume.coverage``),
    the lowest and highest axial planes are only partly inside the scanned slab;
    there part of the mask ends at the slab's straight edge instead of the skin.
    A slice is flagged when more than ``max_fraction`` of its eq. 22 boundary
    ring pixels touch unscanned voxels: its curve would invent a flat wall.

    Returns
    -------
    ndarray of bool, shape (nz,)
    """
    mask = np.asarray(mask, bool)
    if coverage is None:
        return np.zeros(mask.shape[0], bool)
    from scipy import ndimage

    cross = ndimage.generate_binary_structure(2, 1)[None]  # in-plane neighbours only: eq. 22 per slice
    near_edge = ~ndimage.binary_erosion(np.asarray(coverage, bool), structure=cross, border_value=1)
    ring = mask & ~ndimage.binary_erosion(mask, structure=cross, border_value=0)
    ring_px = np.count_nonzero(ring, axis=(1, 2))
    at_edge = np.count_nonzero(ring & near_edge, axis=(1, 2))
    return at_edge > max_fraction * np.maximum(ring_px, 1)


# --------------------------------------------------------------------------- the pipeline step
def max_patches(seg, min_area_fraction: float = MIN_AREA_FRACTION) -> int:
    """The largest t for which the named selections find 3t+1 usable slices in ``seg``.

    Usable slices are those :func:`usable_slices` keeps, less the slices whose
    outline is the edge of the scan (:func:`scan_edge_slices`). Returns 0 when
    not even 4 slices are usable.
    """
    mask = np.asarray(seg.mask, bool)
    ct = seg.ct
    selectable = mask.copy()
    selectable[scan_edge_slices(mask, getattr(ct, "coverage", None))] = False
    if not selectable.any():
        return 0
    nz, ny, nx = mask.shape
    centre = np.column_stack([np.arange(nz, dtype=float), np.full(nz, (ny - 1) / 2), np.full(nz, (nx - 1) / 2)])
    usable = usable_slices(selectable, ct.index_to_patient(centre)[:, 2], min_area_fraction)
    return max((len(usable) - 1) // 3, 0)


def patches_for_scan(seg, patches: int) -> tuple[int, str | None]:
    """The patches a scan can give: ``patches`` when it has 3t+1 usable slices for them, else the largest t
    it has (:func:`max_patches`, e.g. the tilted GE slab: 28 usable slices, t <= 9), with the message that
    says so. One rule for the add-on and the batch. With not even t = 1 usable, ``patches`` unchanged and
    no message: :func:`extract_boundaries` then says why it cannot."""
    limit = max_patches(seg)
    if 1 <= limit < patches:
        return limit, (f"the scan has usable head outlines for at most {limit} patches "
                       f"({3 * limit + 1} slices): patches reduced from {patches} to {limit}")
    return patches, None


def extract_boundaries(seg, patches: int = 10, samples: int = 256, selection: Selection = "uniform",
                       min_area_fraction: float = MIN_AREA_FRACTION, sigma: float = 0.7,
                       level_field: str = "envelope", band: int = 1, parameterisation: str = "angular",
                       curve_sigma: float | None = None, max_stretch: float = 8.0,
                       closing_mm: float | None = None, envelope_sigma_mm: float = ENVELOPE_SIGMA_MM,
                       star_shaped: bool = True, star_slope: float = STAR_MAX_SLOPE, curves: int | None = None,
                       tolerance_mm: float | None = None, max_tolerance_mm: float | None = None,
                       progress=None) -> BoundarySet:
    """The 3t+1 PDE boundary curves of a segmented head (paper eq. 22, sections 3 and 4.1).

    Parameters
    ----------
    seg : Segmentation
        ``seg.mask`` (bool [z, y, x]) is the cleaned head mask, ``seg.ct`` gives
        the geometry (``index_to_patient``), ``seg.probability`` the soft
        membership (only with ``level_field="probability"``).
    patches : int
        Number t >= 1 of PDE patches; 3t+1 slices are used.
    samples : int
        Number M >= 8 of points per curve.
    selection : str, callable or sequence of int
        How the 3t+1 slices are chosen: ``"auto"`` (the curves whose surface best
        follows *every* usable slice's outline, :mod:`.slice_selection`; ``meta``
        records the achieved error), a name in :data:`SELECTION_STRATEGIES`
        (``"uniform"``: evenly spaced in height; ``"shape-change"``: denser
        where the cross-section changes fast), a callable
        ``f(mask, n, heights) -> indices`` (``heights`` = patient z of each
        slice centre), or the slice indices themselves. Indices from a callable
        or given explicitly must be 3t+1 unique, in range, non-empty slices
        sorted inferior -> superior.
    min_area_fraction : float
        Named strategies only use slices whose mask area is at least this
        fraction of the largest slice area (leaves out the degenerate vertex
        cap and stray voxels at the ends of the head).
    sigma, band : float, int
        Sub-pixel contour smoothing and probability band, see :func:`outer_contour`.
    level_field : {"envelope", "mask", "probability"}
        ``"envelope"`` (default): trace the 0.5 level of the head's 3-D envelope
        (:func:`~.envelope.head_envelope`: the mask closed in 3-D by a ball of
        ``closing_mm`` and smoothed by a 3-D Gaussian of ``envelope_sigma_mm``),
        so that neighbouring curves agree and inlets are bridged consistently.
        ``"mask"``: the 0.5 level of each slice's cleaned mask (2-D closing by
        ``closing_mm``, Gaussian of ``sigma`` pixels); ``"probability"``: of the
        soft probability clamped to the cleaned mask's boundary band.
    parameterisation : {"aligned", "arc-length"}
        Where the M samples sit on each curve. ``"arc-length"``: equally
        spaced in arc length from the seam. ``"aligned"`` (default): first
        that, then :func:`align_parameterisation` moves the samples along each
        curve so that equal v means corresponding points on neighbouring
        curves (no folds between curves at the nose, lips, ears).
    curve_sigma : float, optional
        Default ``ENVELOPE_CURVE_SIGMA_PX`` (1.5) for the envelope, ``CURVE_SIGMA_PX`` (1) else.
        Gaussian low-pass along each curve, standard deviation in pixels
        (converted with the mean in-plane spacing): removes the pixel-grid
        ripple that repeats on every slice (vertical streaks on the surface).
        0 disables it.
    max_stretch : float
        Bound on the local stretch of the sample spacing of the alignment.
    star_shaped : bool
        Replace each outline by its :func:`star_hull` around its centroid: inlets
        whose walls face the centre (behind the ears, nostrils) are filled, so the
        surface has no notches there and the ears are smooth bumps.
    star_slope : float
        The hull's bound on ``|d ln r / d theta|`` (:func:`star_hull`'s ``max_slope``).
    envelope_sigma_mm : float
        Standard deviation (mm) of the envelope's 3-D Gaussian (``"envelope"`` only).
    closing_mm : float, optional
        Default: ``ENVELOPE_CLOSING_MM`` (3 mm) for the envelope, ``CLOSING_MM`` (3 mm) for the others.
        Radius (mm) of the envelope's 3-D ball closing, or (``"mask"``,
        ``"probability"``) of a disk closing of each slice's outer region before the
        contour is traced (:func:`close_region`): inlets narrower than about
        twice that (nostrils, a slightly open mouth, ear canal, the gap behind
        an ear flap) are bridged. Such inlets exist on one curve and not on
        its neighbours 5-10 mm away, so the PDE would fold there. 0 disables it.

    curves : int, optional
        Number of curves instead of 3t+1 (any n >= 4: the default C2 surface takes
        any count; the paper's patches need 3t+1).
    tolerance_mm, max_tolerance_mm : float, optional
        Instead of a count: the fewest curves whose default surface (``solve_pde``)
        keeps a mean (and/or largest) distance from every usable slice's outline
        within these bounds (:func:`~.slice_selection.select_for_tolerance`); implies
        ``selection="auto"`` and ignores ``patches``/``curves``. If even every usable
        slice misses the bound, all of them are used and a
        :class:`~.slice_selection.SelectionWarning` names the achieved error.

    Returns
    -------
    BoundarySet
        Curves (3t+1, M, 3) in patient LPS mm ordered inferior -> superior,
        counter-clockwise seen from +z, sample 0 at the posterior midline,
        uniform in arc length or aligned (``meta["parameterisation"]``);
        ``heights`` = mean patient z of each curve; ``u_knots`` from
        :func:`knots_from_heights`. With ``selection="auto"`` (or a tolerance),
        ``meta`` also holds ``selection_curves``, ``selection_candidates``,
        ``selection_mean_mm``, ``selection_max_mm``, ``selection_p95_mm`` (the real
        surface's distance from all usable slices' outlines), ``selection_tolerance_mm``,
        ``selection_max_tolerance_mm`` and ``selection_tolerance_met`` (None without a tolerance).

    Raises
    ------
    BoundaryError
        Bad parameters, an empty mask, fewer usable slices than 3t+1, a bad
        selection, or a slice without a closed contour.
    """
    if isinstance(patches, bool) or not isinstance(patches, Integral) or patches < 1:
        raise BoundaryError(f"patches must be an integer >= 1, got {patches!r}")
    samples = _check_samples(samples)
    if level_field not in LEVEL_FIELDS:
        raise BoundaryError(f"level_field must be one of {list(LEVEL_FIELDS)}, got {level_field!r}")
    if parameterisation not in PARAMETERISATIONS + ("angular",):
        raise BoundaryError(f"parameterisation must be one of {list(PARAMETERISATIONS) + ['angular']}, "
                            f"got {parameterisation!r}")
    if curve_sigma is None:
        curve_sigma = ENVELOPE_CURVE_SIGMA_PX if level_field == "envelope" else CURVE_SIGMA_PX
    if not (np.isfinite(curve_sigma) and curve_sigma >= 0):
        raise BoundaryError(f"curve_sigma must be >= 0 (pixels), got {curve_sigma!r}")
    if closing_mm is None:
        closing_mm = ENVELOPE_CLOSING_MM if level_field == "envelope" else CLOSING_MM
    if not (np.isfinite(closing_mm) and closing_mm >= 0):
        raise BoundaryError(f"closing_mm must be >= 0, got {closing_mm!r}")
    if not (np.isfinite(max_stretch) and max_stretch > 1):
        raise BoundaryError(f"max_stretch must be > 1, got {max_stretch!r}")
    if not 0.0 <= float(min_area_fraction) < 1.0:
        raise BoundaryError(f"min_area_fraction must be in [0, 1), got {min_area_fraction!r}")
    mask = np.asarray(getattr(seg, "mask", None))
    ct = getattr(seg, "ct", None)
    if mask.ndim != 3 or ct is None or tuple(mask.shape) != tuple(ct.shape):
        raise BoundaryError(f"segmentation mask must be 3-D with the CT's shape, got {mask.shape}")
    if mask.dtype != bool:
        mask = mask.astype(bool)
    if not mask.any():
        raise BoundaryError("the segmentation mask is empty: no head to extract boundaries from")
    n = 3 * int(patches) + 1 if curves is None else _check_curves(curves)
    auto = selection == "auto" or tolerance_mm is not None or max_tolerance_mm is not None
    if auto and not (isinstance(selection, str) and selection in ("auto", "uniform")):
        raise BoundaryError(f"a tolerance chooses the slices itself (selection 'auto'), got selection {selection!r}")
    if auto and parameterisation != "angular":
        raise BoundaryError("selection 'auto' needs parameterisation='angular' (its candidates share one spine)")
    nz, ny, nx = mask.shape
    centre = np.column_stack([np.arange(nz, dtype=float), np.full(nz, (ny - 1) / 2), np.full(nz, (nx - 1) / 2)])
    slice_z = ct.index_to_patient(centre)[:, 2]

    cut_off = scan_edge_slices(mask, getattr(ct, "coverage", None))
    selectable = mask
    if cut_off.any():  # named strategies never pick a slice whose outline is the edge of the scan
        selectable = mask.copy()
        selectable[cut_off] = False
    if auto:
        selection_name = "auto"
        from . import slice_selection as S
        chosen = usable_slices(selectable, slice_z, min_area_fraction)        # every candidate, traced below
        if tolerance_mm is None and max_tolerance_mm is None:
            chosen = S.thin_candidates(chosen, n)
        else:
            chosen = S.thin_candidates(chosen)
        if len(chosen) < MIN_CURVES:
            raise BoundaryError(f"only {len(chosen)} slices have a usable head cross-section; a PDE head "
                                f"needs at least {MIN_CURVES}")
        if tolerance_mm is None and max_tolerance_mm is None and n > len(chosen):
            most = (len(chosen) - 1) // 3
            raise BoundaryError(f"only {len(chosen)} slices have a usable head cross-section, but {n} curves "
                                f"are needed; use fewer patches (t <= {most})")
    elif isinstance(selection, str):
        strategy = SELECTION_STRATEGIES.get(selection)
        if strategy is None:
            raise BoundaryError(f"unknown selection {selection!r}; known: {sorted(SELECTION_STRATEGIES) + ['auto']}")
        chosen = _validate_indices(strategy(selectable, n, slice_z, min_area_fraction=min_area_fraction),
                                   n, mask, slice_z, f"selection {selection!r}")
        selection_name = selection
    elif callable(selection):
        selection_name = f"callable:{getattr(selection, '__name__', type(selection).__name__)}"
        chosen = _validate_indices(selection(mask, n, slice_z), n, mask, slice_z, selection_name)
    else:
        selection_name = "explicit"
        chosen = _validate_indices(selection, n, mask, slice_z, "explicit selection")

    probability = None
    if level_field == "probability":
        probability = np.asarray(getattr(seg, "probability", None))
        if probability.shape != mask.shape:
            raise BoundaryError(f"segmentation probability shape {probability.shape} != mask shape {mask.shape}")
    dz, dy, dx = ct.spacing
    closing_px = float(closing_mm) / (0.5 * (dy + dx))
    if level_field == "envelope":
        if not (np.isfinite(envelope_sigma_mm) and envelope_sigma_mm >= 0):
            raise BoundaryError(f"envelope_sigma_mm must be >= 0, got {envelope_sigma_mm!r}")
        report_progress(progress, 0.0, "the head's envelope")
        field, window = head_envelope(mask, (dz, dy, dx), closing_mm=float(closing_mm),
                                      sigma_mm=float(envelope_sigma_mm), slices=chosen)
    outlines, areas, coverage = [], [], []
    for c, k in enumerate(chosen):
        if c % 8 == 0:
            report_progress(progress, 0.3 + 0.3 * c / len(chosen), f"tracing slice {c + 1} of {len(chosen)}")
        try:
            if level_field == "envelope":
                rc, info = contour_from_field(field[k - window[0].start], origin=(window[1].start, window[2].start))
            else:
                rc, info = outer_contour(mask[k], sigma=sigma, band=band, return_info=True, closing=closing_px,
                                         probability=None if probability is None else probability[k])
        except BoundaryError as exc:
            raise BoundaryError(f"slice {int(k)}: {exc}") from None
        kji = np.column_stack([np.full(len(rc), float(k)), rc])
        outlines.append(ct.index_to_patient(kji))
        areas.append(info["area_px"] * dy * dx)
        coverage.append(info["ring_coverage"])
    smooth_mm = float(curve_sigma) * 0.5 * (dy + dx)
    if parameterisation == "angular":
        curves_out = angular_curves(outlines, samples, smooth=smooth_mm, max_slope=star_slope if star_shaped else None)
    else:
        curves_out = np.stack([orient_and_resample(star_hull(o, max_slope=star_slope) if star_shaped else o,
                                                   samples, smooth=smooth_mm)
                               for o in outlines])
    meta = dict(
        source=ct.meta.get("source", ct.meta.get("path")),
        selection=selection_name, patches=int(patches), samples=samples,
        spacing=[float(s) for s in ct.spacing], min_area_fraction=float(min_area_fraction),
        sigma=float(sigma), level_field=level_field, band=int(band),
        scan_edge_slices=np.flatnonzero(cut_off).tolist(),
        orientation="ccw seen from +z (superior); outward normal = dX/dv x dX/du",
        seam="posterior midline (+y ray from each curve's area centroid)",
        curve_sigma=float(curve_sigma), closing_mm=float(closing_mm),
        parameterisation="angular" if parameterisation == "angular" else "arc-length",
        envelope_sigma_mm=float(envelope_sigma_mm) if level_field == "envelope" else None,
        star_shaped=bool(star_shaped), star_slope=float(star_slope) if star_shaped else None,
        source_slice_step_mm=float(ct.meta.get("source_slice_step_mm") or dz),
        source_slice_thickness_mm=_max_thickness(ct.meta.get("slice_thickness_mm")),
        gantry_tilt_deg=float(ct.meta.get("gantry_tilt_deg") or 0.0),
    )
    top = _head_top(mask, slice_z, dz)
    if top is not None:
        meta["vertex_z"] = top

    def make_bset(pos) -> BoundarySet:
        pos = np.asarray(pos, np.int64)
        cv = curves_out[pos]
        h = cv[:, :, 2].mean(axis=1)
        m = dict(meta, slice_areas_mm2=[float(areas[p]) for p in pos],
                 ring_coverage=[float(coverage[p]) for p in pos])
        if curves is not None or len(pos) != 3 * int(patches) + 1:
            m["patches"] = BoundarySet.patches_for(len(pos))
        return BoundarySet(cv, np.asarray(chosen)[pos], h, knots_from_heights(h), m)

    report_progress(progress, 0.6, "choosing the curves" if auto else "the curves")
    if not auto:
        bset = make_bset(np.arange(len(chosen)))
    else:
        from . import slice_selection as S
        cand = S.Candidates(np.asarray(chosen), curves_out, meta)
        if tolerance_mm is None and max_tolerance_mm is None:
            pos = S.select_curves(cand, n)
            bset = make_bset(pos)
            err, met = S.surface_error(bset, cand), None
        else:
            pos, bset, err, met = S.select_for_tolerance(cand, make_bset, tolerance_mm, max_tolerance_mm)
        bset.meta.update(S.selection_record(err, len(pos), tolerance_mm, max_tolerance_mm, met, cand.count))
        bset.meta["selection_per_slice_mm"] = [round(float(e), 4) for e in err["per_slice_mm"]]
        S.attach_candidates(bset, cand)
    if parameterisation == "aligned":
        bset = align_parameterisation(bset, max_stretch=max_stretch)
    report_progress(progress, 1.0, "boundary curves done")
    return bset
