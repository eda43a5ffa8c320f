"""Where the M samples of each boundary curve sit: low-pass along the curve and correspondence.

The PDE (eq. 1-13) interpolates, for every v, the four points ``P_j(v)`` of a
patch (eq. 3-6): the sample index is the correspondence between curves. Two
things spoil it on real slices:

* **pixel jaggedness.** The sub-pixel contour of a mask still carries a few
  hundredths of a millimetre of pixel-grid ripple; every slice of a volume
  shares the same grid, so the ripple repeats at the same (x, y) on all curves
  and the surface shows vertical streaks. :func:`smooth_closed_curve` removes
  it with a periodic Gaussian along arc length (sigma ~ one pixel: wavelengths
  of a few pixels go, the nose and lips, tens of pixels, stay).
* **arc-length drift.** Sampled uniformly in arc length, a feature present on
  one curve only (nose tip, ear flap, nostril notch) shifts the arc length of
  everything after it, so equal v joins points on different sides of the head
  and the surface folds into flanges between the curves.
  :func:`~pdehead_addon.core.curve_alignment.align_parameterisation` (shared with
  the PDE stage, hence in ``core``) re-samples every curve along its own polyline
  so that equal v means corresponding points (dynamic time warping between
  neighbouring curves).
"""
from __future__ import annotations

import numpy as np

from ..core.errors import BoundaryError

__all__ = ["smooth_closed_curve", "PARAMETERISATIONS"]

#: Names accepted by ``extract_boundaries(parameterisation=...)``.
PARAMETERISATIONS = ("aligned", "arc-length")


def closed_arc_length(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Cumulative chord length along a closed polyline (last point not repeated).

    Returns
    -------
    s : ndarray, shape (Q,)
        Strictly increasing arc length of each kept vertex, from 0 to the perimeter.
    closed : ndarray, shape (Q, d)
        The vertices with the first repeated at the end; zero-length steps dropped
        (so ``s`` can be an ``np.interp`` abscissa).
    length : float
        The perimeter.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or len(p) < 3:
        raise BoundaryError(f"need a closed polyline of at least 3 points, got shape {p.shape}")
    closed = np.vstack([p, p[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    length = float(s[-1])
    if not length > 0:
        raise BoundaryError("degenerate curve of zero length")
    keep = np.concatenate([[True], seg > 0])
    return s[keep], closed[keep], length


def smooth_closed_curve(points: np.ndarray, sigma: float, step: float | None = None) -> np.ndarray:
    """Periodic Gaussian low-pass of a closed polyline along its arc length.

    Parameters
    ----------
    points : ndarray, shape (P, d)
        Closed polyline, last point not repeated.
    sigma : float
        Standard deviation of the Gaussian along the curve, in the unit of
        ``points`` (e.g. mm). 0 returns the points unchanged.
    step : float, optional
        Arc-length spacing of the returned points; default ``sigma / 4`` but at
        least as many points as given.

    Returns
    -------
    ndarray, shape (Q, d)
        The smoothed closed polyline, uniform in arc length, starting at
        ``points[0]``'s arc-length position. Coordinates that are constant on
        the input (a curve in a plane z = const) stay exactly constant.
    """
    p = np.asarray(points, dtype=np.float64)
    sigma = float(sigma)
    if not (np.isfinite(sigma) and sigma >= 0):
        raise BoundaryError(f"curve smoothing sigma must be >= 0, got {sigma!r}")
    s, closed, length = closed_arc_length(p)
    if sigma == 0:
        return p.copy()
    step = sigma / 4.0 if step is None else float(step)
    n = max(len(p), int(np.ceil(length / step)))
    target = length * np.arange(n) / n
    dense = np.stack([np.interp(target, s, closed[:, d]) for d in range(p.shape[1])], axis=1)
    freq = np.fft.rfftfreq(n, d=length / n)                                 # cycles per unit length
    gain = np.exp(-0.5 * (2.0 * np.pi * freq * sigma) ** 2)
    out = np.fft.irfft(np.fft.rfft(dense, axis=0) * gain[:, None], n=n, axis=0)
    constant = np.ptp(p, axis=0) == 0
    out[:, constant] = p[0, constant]
    return out
