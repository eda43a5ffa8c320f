"""Boundary curves from outlines: star hulls, the angular samples around a spine, arc-length samples.

The stage of :func:`~.boundaries.extract_boundaries` that turns each traced outline (patient LPS mm)
into a PDE boundary curve of M samples with the shared conventions of :class:`~.boundary_set.BoundarySet`
(counter-clockwise seen from +z, sample 0 at the posterior midline): :func:`angular_curves` (the
default: equal angles around a smooth spine, :func:`spine_centres`, of star hulls, :func:`star_hull`)
or :func:`orient_and_resample` (equal arc length from the seam); and the measures of a set of curves
(:func:`parameter_offsets`, :func:`self_intersections`).
"""
from __future__ import annotations

from numbers import Integral
from typing import Sequence

import numpy as np
from scipy import ndimage as ndi

from ..core.errors import BoundaryError
from ..pde.pde_spline import smoothing_spline_values
from .parameterisation import closed_arc_length, smooth_closed_curve
from .slice_outlines import outer_contour, shoelace

__all__ = [
    "signed_area", "polygon_centroid", "resample_closed_curve", "star_hull", "spine_centres", "angular_curves",
    "orient_and_resample", "contour_from_mask", "parameter_offsets", "self_intersections", "check_samples",
    "STAR_MAX_SLOPE", "STAR_FILLET_MM", "STAR_FILLET_MIN_TURN_DEG", "SPINE_SMOOTHING_MM", "polar_turns",
    "round_sharp_polar_corners",
]

#: Star hull: bound on |d ln r / d theta| (3: the normal stays within 72 degrees of the ray). The former
#: 2 (63 degrees) filled the groove beside the nose wings, whose sides run almost along the ray; at 3
#: CThead's mouth corners keep no pit any more (notch fraction 0 with the 1 mm envelope).
STAR_MAX_SLOPE = 3.0
#: Star hull: radius (mm) of the arcs its sharp concave corners are filled to (where a web meets the outline
#: behind an ear): the viewport's 240 columns lie about 2.4 mm apart on a head, and a corner sharper than
#: the columns' spacing shows as a slit. Chosen on CThead, checked on GE (docs/benchmarks.md, up close).
STAR_FILLET_MM = 3.0
#: Star hull: a concave corner where a web meets the outline is filled when the outline turns there by more
#: than this (degrees, over a quarter of the fillet on either side); the rest keeps its shape (the tube's
#: fidelity to the CT). Chosen on CThead, checked on GE.
STAR_FILLET_MIN_TURN_DEG = 60.0
#: Smoothing length (mm) of the centroid track that the angular parameterisation is centred on.
SPINE_SMOOTHING_MM = 10.0


def check_samples(samples) -> int:
    """``samples`` as an int if it is an integer >= 8 (points per curve), else ``BoundaryError``."""
    if isinstance(samples, bool) or not isinstance(samples, Integral) or samples < 8:
        raise BoundaryError(f"samples must be an integer >= 8, got {samples!r}")
    return int(samples)


def signed_area(xy: np.ndarray) -> float:
    """Signed (shoelace) area of a closed polygon ``[..., (x, y)]``; > 0 if counter-clockwise."""
    return shoelace(np.asarray(xy, dtype=np.float64)[:, :2])


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


def _ball_offsets(step_mm: float, radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Sample offsets k (|k step| <= radius) and the ball's height sqrt(radius^2 - (k step)^2) over them."""
    w = int(np.floor(radius_mm / step_mm))
    k = np.arange(-w, w + 1)
    return k, np.sqrt(np.maximum(radius_mm ** 2 - (k * step_mm) ** 2, 0.0))


def _ball_pass(f: np.ndarray, k: np.ndarray, height: np.ndarray, dilate: bool) -> np.ndarray:
    """Periodic grey-level dilation (max of f + ball) or erosion (min of f - ball) of a sampled graph."""
    window = f[(np.arange(len(f))[:, None] + k[None, :]) % len(f)]
    return (window + height).max(axis=1) if dilate else (window - height).min(axis=1)


def polar_turns(radius: np.ndarray, chord_mm: float) -> np.ndarray:
    """Signed turn (degrees, + to the left) of a closed curve ``r(theta)`` (equal angles, counter-clockwise)
    at each sample, between its chords to the samples ``chord_mm`` of arc length before and after;
    negative turns are concave corners."""
    r = np.asarray(radius, dtype=np.float64)
    n = len(r)
    phi = np.arange(n) * 2.0 * np.pi / n
    xy = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
    k = max(1, int(round(chord_mm / (float(np.median(r)) * 2.0 * np.pi / n))))
    a = xy - np.roll(xy, k, axis=0)
    b = np.roll(xy, -k, axis=0) - xy
    return np.degrees(np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], (a * b).sum(axis=1)))


def round_sharp_polar_corners(radius: np.ndarray, fillet_mm: float, min_turn_deg: float,
                              only_near: np.ndarray | None = None) -> np.ndarray:
    """Fill the sharp concave corners of a closed star-shaped curve ``r(theta)`` (equal angles) to arcs
    of ``fillet_mm``.

    The graph of r over the arc length ``s = median(r) theta`` is closed by a ball of radius ``fillet_mm``
    (grey-level morphology with a spherical structuring function, Sternberg's rolling ball, rolled along
    the outside) [1]_; of what the closing raises, only the stretches that hold a concave corner turning
    by more than ``min_turn_deg`` between the chords a quarter of ``fillet_mm`` long on either side (and,
    with ``only_near``, within that reach of a flagged sample: a star hull's web, so that the corners
    are where a web meets the outline, behind an ear) are kept: the rest of the outline, its gentle
    valleys and the CT's own creases included, is unchanged. r never
    decreases (the hull still contains the outline) and stays continuous (the closing meets r at the ends
    of each stretch it raises). Convex tips (an ear's edge, the nose) are left as they are.

    References
    ----------
    .. [1] S. R. Sternberg, "Grayscale morphology", Computer Vision, Graphics, and Image Processing
       35(3):333-355, 1986.
    """
    r = np.asarray(radius, dtype=np.float64)
    step = float(np.median(r)) * 2.0 * np.pi / len(r)
    if not (fillet_mm > 0 and step > 0 and fillet_mm >= step):
        return r
    k, h = _ball_offsets(step, float(fillet_mm))
    closed = np.maximum(r, _ball_pass(_ball_pass(r, k, h, dilate=True), k, h, dilate=False))
    raised = closed > r + 1e-9
    if not raised.any():
        return r
    chord = 0.25 * fillet_mm                       # the corner's own turn, not the outline's curvature around it
    sharp = polar_turns(r, chord) < -float(min_turn_deg)
    if only_near is not None:
        reach = np.arange(-max(1, int(round(chord / step))), max(1, int(round(chord / step))) + 1)
        sharp &= np.asarray(only_near, bool)[(np.arange(len(r))[:, None] + reach[None, :]) % len(r)].any(axis=1)
    if raised.all():
        return closed if (sharp & raised).any() else r
    # label the periodic runs of raised samples, starting after a sample that is not raised
    start = int(np.flatnonzero(~raised)[0])
    order = (np.arange(len(r)) + start) % len(r)
    run = np.cumsum(np.r_[False, raised[order][1:] & ~raised[order][:-1]])
    label = np.empty(len(r), np.int64)
    label[order] = run
    keep = np.zeros(run.max() + 1, bool)
    keep[label[raised & sharp]] = True
    return np.where(raised & keep[label], closed, r)


def star_hull(points: np.ndarray, centre: np.ndarray | None = None, angles: int = 1440,
              step: float = 0.2, max_slope: float | None = STAR_MAX_SLOPE, fillet_mm: float = STAR_FILLET_MM,
              min_turn_deg: float = STAR_FILLET_MIN_TURN_DEG) -> np.ndarray:
    """The smallest region star-shaped around ``centre`` that contains a closed curve.

    Along every ray from the centre the farthest point of the curve is kept, so
    inlets whose walls face the centre - the notch behind an ear, a nostril, a
    crater in the concha - are filled and the ear becomes a smooth bump. With
    ``max_slope`` the radius is moreover raised to the smallest function with
    ``|d ln r / d theta| <= max_slope``: the filling is a web sloping at most
    ``atan(max_slope)`` away from the circle (the outward normal stays within that
    angle of the ray), not a radial wall; where a web lands on the outline at a sharp
    concave corner, the corner becomes an arc (:func:`round_sharp_polar_corners`). A
    curve that already satisfies the bound (most of a head's outline, the nose) is
    returned as it is, up to the angular sampling.

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
    fillet_mm, min_turn_deg : float
        Where a web meets the outline at a concave corner turning by more than ``min_turn_deg``, the
        corner becomes an arc of ``fillet_mm`` (:func:`round_sharp_polar_corners`); ``fillet_mm`` 0 keeps it,
        and so does the plain hull (``max_slope`` None).

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
        raw = radius
        radius = np.exp(_lipschitz_envelope(np.log(np.maximum(radius, 1e-9)), max_slope * 2 * np.pi / angles))
        radius = round_sharp_polar_corners(radius, fillet_mm, min_turn_deg, only_near=radius > raw * (1 + 1e-6))
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
    if shoelace(p[:, :2]) < 0:
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
    samples = check_samples(samples)
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
