"""The correspondence of neighbouring boundary curves: equal v on corresponding points.

The PDE (eq. 1-13) interpolates, for every v, the four points ``P_j(v)`` of a
patch (eq. 3-6): the sample index is the correspondence between curves.
Sampled uniformly in arc length, a feature present on one curve only (nose tip,
ear flap, nostril notch) shifts the arc length of everything after it, so equal v
joins points on different sides of the head and the surface folds into flanges
between the curves. :func:`align_parameterisation` re-samples every curve along
its own polyline so that equal v means corresponding points (dynamic time warping
between neighbouring curves); :func:`correspondence_error` measures how far equal
v misses. The curve stage (``extract_boundaries(parameterisation="aligned")``) and
the PDE stage (``solve_pde(align=True)``) both apply it.
"""
from __future__ import annotations

import numpy as np

from .boundary_set import BoundarySet
from .errors import BoundaryError

__all__ = ["align_parameterisation", "correspondence_error"]


def _dtw_maps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dynamic time warping of closed curves with a common seam, vectorised over pairs.

    Parameters
    ----------
    a, b : ndarray, shape (P, M, d)
        P pairs of curves (centred), sample 0 of both at the seam.

    Returns
    -------
    ndarray, shape (P, M + 1)
        For every sample i = 0..M of ``a`` (M = the seam again) the mean fractional
        index of the samples of ``b`` matched to it: a monotone map with f(0) = 0, f(M) = M.
    """
    P, M, _ = a.shape
    a2 = np.concatenate([a, a[:, :1]], axis=1).astype(np.float32)
    b2 = np.concatenate([b, b[:, :1]], axis=1).astype(np.float32)
    n = M + 1
    cost = ((a2[:, :, None, :] - b2[:, None, :, :]) ** 2).sum(axis=-1)       # (P, n, n)
    D = np.full((P, n + 1, n + 1), np.inf, np.float32)
    D[:, 0, 0] = 0.0
    for d in range(2, 2 * n + 1):                                            # anti-diagonal sweep
        i = np.arange(max(1, d - n), min(n, d - 1) + 1)
        j = d - i
        D[:, i, j] = cost[:, i - 1, j - 1] + np.minimum(np.minimum(D[:, i - 1, j - 1], D[:, i - 1, j]),
                                                        D[:, i, j - 1])
    # backtrack all pairs together; accumulate the matched j of every i
    pr = np.arange(P)
    i = np.full(P, n)
    j = np.full(P, n)
    total = np.zeros((P, n))
    count = np.zeros((P, n))
    active = np.ones(P, bool)
    while np.any(active):
        pa, ia, ja = pr[active], i[active], j[active]
        total[pa, ia - 1] += ja - 1
        count[pa, ia - 1] += 1
        step = np.argmin(np.stack([D[pa, ia - 1, ja - 1], D[pa, ia - 1, ja], D[pa, ia, ja - 1]]), axis=0)
        i[pa] = ia - (step != 2)
        j[pa] = ja - (step != 1)
        active = (i > 0) & (j > 0)
    return total / np.maximum(count, 1)


def _bounded_increments(sigma: np.ndarray, M: int, max_stretch: float) -> np.ndarray:
    """Smooth a monotone sample map and bound its local stretch to [1/max_stretch, max_stretch].

    DTW maps are staircases; three passes of a 5-tap triangle filter on the
    spacing (about +-4 samples) remove the steps without moving features.
    """
    d = np.maximum(np.diff(np.append(sigma, M)), 0.0)
    kernel = np.array([1.0, 2.0, 3.0, 2.0, 1.0]) / 9.0
    for _ in range(3):
        d = np.convolve(np.concatenate([d[-2:], d, d[:2]]), kernel, mode="valid")
    for _ in range(8):  # clip-and-renormalise converges in a few rounds
        d = np.clip(d, 1.0 / max_stretch, max_stretch)
        d *= M / d.sum()
    return np.concatenate([[0.0], np.cumsum(d)[:-1]])


def _resample_at(curve: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Points of the closed polyline through ``curve``'s samples at fractional sample ``positions``."""
    M = len(curve)
    closed = np.concatenate([curve, curve[:1]])
    i0 = np.clip(np.floor(positions).astype(np.int64), 0, M - 1)
    f = (positions - i0)[:, None]
    out = closed[i0] * (1.0 - f) + closed[i0 + 1] * f
    if np.ptp(curve[:, 2]) == 0:
        out[:, 2] = curve[0, 2]                                              # planar curves stay exactly planar
    return out


def align_parameterisation(bset: BoundarySet, max_stretch: float = 8.0) -> BoundarySet:
    """Re-sample the curves so that equal v means corresponding points on neighbouring curves.

    The PDE interpolates, for every v, the four points ``P_j(v)`` of a patch
    (eq. 3-6). With curves sampled uniformly in arc length a feature present
    on one curve only (nose tip, ear, nostril notch) shifts the arc length of
    everything after it, so equal v joins points on different sides of the
    head and the surface between the curves folds into flanges. This function
    keeps every curve's geometry (the new samples lie on the polyline through
    the old ones, the seam sample 0 stays put) and chooses where along it the
    M samples sit: each curve is matched to its lower neighbour by dynamic time
    warping of the centred curves (minimal sum of squared distances between
    matched samples, monotone, seam fixed), the maps are composed from the
    first curve (kept uniform in arc length) upward, smoothed, and their local
    stretch bounded to ``[1/max_stretch, max_stretch]`` of the uniform spacing
    so that no part of a curve loses its samples.

    A set whose ``meta["parameterisation"]`` is already ``"aligned"`` is
    returned unchanged (aligning twice would only re-blur the maps).

    Parameters
    ----------
    bset : BoundarySet
        Curves with a common seam and orientation (as :func:`extract_boundaries`
        returns them), best uniform in arc length.
    max_stretch : float
        Bound on the local compression/expansion of the sample spacing (> 1).

    Returns
    -------
    BoundarySet
        Same slices, heights and knots; ``meta["parameterisation"] = "aligned"``.
        The curves are no longer uniform in arc length.
    """
    if not isinstance(bset, BoundarySet):
        raise BoundaryError(f"align_parameterisation needs a BoundarySet, got {type(bset).__name__}")
    if not (np.isfinite(max_stretch) and max_stretch > 1.0):
        raise BoundaryError(f"max_stretch must be > 1, got {max_stretch!r}")
    if bset.meta.get("parameterisation") == "aligned":
        return bset
    curves = bset.curves
    n_curves, M, _ = curves.shape
    centred = curves - curves.mean(axis=1, keepdims=True)
    maps = _dtw_maps(centred[:-1], centred[1:])                              # (n-1, M+1)
    grid = np.arange(M + 1, dtype=np.float64)
    out = np.empty_like(curves)
    out[0] = curves[0]
    sigma = np.arange(M, dtype=np.float64)
    for j in range(1, n_curves):
        sigma = _bounded_increments(np.interp(sigma, grid, maps[j - 1]), M, max_stretch)
        out[j] = _resample_at(curves[j], sigma)
    meta = dict(bset.meta)
    meta["parameterisation"] = "aligned"
    meta["align_max_stretch"] = float(max_stretch)
    return BoundarySet(out, bset.slice_indices.copy(), bset.heights.copy(), bset.u_knots.copy(), meta)


def correspondence_error(curves: np.ndarray) -> np.ndarray:
    """How far equal v misses the nearest point, between neighbouring curves (mm, 0 = ideal).

    For curves ``a = curves[j]`` and ``b = curves[j+1]``, each centred on its
    area centroid, the mean over samples i of ``|a_i - b_i| - min_k |a_i - b_k|``:
    how much farther the equal-v partner is than the closest sample of the
    neighbour. A change of size or shape between the curves costs nothing; equal
    v joining points on different parts of the head (the cause of folds between
    the curves) does.

    Parameters
    ----------
    curves : ndarray, shape (n, M, 2 or 3)

    Returns
    -------
    ndarray, shape (n - 1,)
    """
    c = np.asarray(curves, dtype=np.float64)[..., :2]
    q = np.roll(c, -1, axis=1)
    cross = c[..., 0] * q[..., 1] - q[..., 0] * c[..., 1]
    centroid = ((c + q) * cross[..., None]).sum(axis=1) / (3.0 * cross.sum(axis=1))[:, None]
    c = c - centroid[:, None]
    a, b = c[:-1], c[1:]
    equal = np.linalg.norm(a - b, axis=2)                                    # (n-1, M)
    nearest = np.sqrt(((a[:, :, None] - b[:, None]) ** 2).sum(-1).min(axis=2))
    return (equal - nearest).mean(axis=1)
