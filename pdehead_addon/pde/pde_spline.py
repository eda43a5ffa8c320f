"""A C2 Bloor-Wilson surface through every boundary curve (eq. 1, 7-12 with derivative conditions).

The paper's patches (section 4.1) each interpolate four *position* curves and
share only their end curve with the next patch, so the surface is C0 there: the
normal jumps by tens of degrees at every joint (measured in
:mod:`.surface_quality`). The classic Bloor-Wilson boundary conditions are
position *and* u-derivative at both ends of a patch. Here every span between
two consecutive curves is such a patch: per harmonic h of eq. 7 its amplitude
``A_h`` solves ``(d^2/du^2 - a^2 h^2)^2 A_h = 0`` (eq. 1 separated, eq. 9-10) with
``A_h(u_j) = P_j``, ``A_h(u_{j+1}) = P_{j+1}`` and derivatives ``D_j, D_{j+1}``
shared with the neighbouring spans. The derivatives are the solution of one
tridiagonal system per harmonic that makes the second u-derivative continuous
too: the surface is C2 in u across every curve. For a -> 0 each harmonic is the
natural cubic spline through the curves (eq. 8 in every span); a larger a damps
the higher harmonics between the curves (less overshoot, less detail between
them). Harmonics above ``modes`` (N) share the remainder exponent
``omega = a (N + 1)`` of eq. 12.

Two extensions make the head what a user expects to see:

* **approximation along u** (``approximation_mm``): before interpolation, the
  curves' harmonics are replaced by a natural cubic *smoothing* spline in
  height (Reinsch 1967): it minimises
  ``sum_j w_j |Y_j - P_j|^2 + lambda int |Y''(z)|^2 dz`` with ``w_j`` the
  curves' height spacing (mm) and ``lambda = L^4``, a low-pass along the head
  axis with gain 1/2 at wavelength ``2 pi L``. Slice-to-slice steps (thick or
  tilted series) and streaks that change from slice to slice are not
  reproduced; the surface leaves each curve by at most ``head.curve_deviation``.
* **the crown as a dome**: the last knot is a degenerate curve, the vertex,
  above the top curve. There every harmonic h >= 1 vanishes, the height has a
  zero u-derivative and the harmonics h >= 2 have a zero derivative too, so the
  rings shrink to a point with a horizontal tangent plane (near the pole
  ``z ~ z_v - c (1-u)^2`` while the rings shrink like ``(1-u)``): a round
  crown instead of a flat fan. With the approximation on, the curves' harmonics
  h >= 3 pass first through :func:`crown_low_pass`, wider where the slices cut
  the skin at a grazing angle (the crown), so slice steps there do not run
  across it as radial ridges.

References
----------
Bloor, M. I. G. and Wilson, M. J. (1989). Generating blend surfaces using
partial differential equations. Computer-Aided Design 21(3), 165-171.
Reinsch, C. H. (1967). Smoothing by spline functions. Numer. Math. 10, 177-183.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.linalg.lapack import dgtsv, dpbsv

from .pde_basis import basis_derivatives, inverse_4x4, small_matmul

#: Exponent per harmonic of eq. 1 inside the dome span (local s): ripples of the top curve fade
#: toward the pole instead of converging there as radial ridges (harmonic h decays like e^{-0.25 h s}).
DOME_DAMPING = 0.25
#: Inside the dome span the ring's non-circular part fades toward the pole (else a "star" shows on the
#: crown). The radius harmonics n >= 3 of a smooth pole shrink like r^n (r: the distance from the pole);
#: the Hermite data alone make every harmonic h >= 2 shrink like r^2 and the ring's ellipticity like r,
#: which keeps the slope ripple n A_n / r of the radius constant into the pole. Harmonic h >= 2 of the
#: ring is multiplied by ``dome_fade(DOME_FADE_EXTRA + h - 1, 1 - s)``, the elliptic part of h = 1 and the
#: spine's sideways offset from the pole by ``dome_fade(DOME_FADE_EXTRA, 1 - s)``: value and u-derivative
#: at the top curve are kept (C1 with the tube, as before), the dome's height and its tangent plane at the
#: pole too (the spine's height and the circular part of h = 1 are not faded).
DOME_FADE_EXTRA = 3
#: The crown's low-pass (:func:`crown_low_pass`): the Gaussian's width along a boundary curve is this many
#: millimetres times the cotangent of the skin's angle to the slice plane there, so a wall cut square by
#: its slices keeps its curve as it is and the crown, cut at a grazing angle, is smoothed most. 3 mm is the
#: scale of the large-scale head the crown is compared with (marching cubes of the mask smoothed by a 3 mm
#: Gaussian); chosen on CThead, checked on GE and the phantom (docs/benchmarks.md, section up-close).
CROWN_SIGMA_MM = 3.0
#: Dome height limits, as fractions of the top curve's equivalent radius sqrt(area / pi).
DOME_MIN_FRACTION = 0.15
DOME_MAX_FRACTION = 1.2


def hermite_systems(k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hermite interpolation in the space of exponent k on s in [0, 1].

    Parameters
    ----------
    k : ndarray
        Exponents (any shape).

    Returns
    -------
    G_inv : ndarray, shape ``k.shape + (4, 4)``
        Maps the data ``(f(0), f(1), f'(0), f'(1))`` to the coefficients of
        :func:`~.pde_basis.basis`.
    alpha : ndarray, shape ``k.shape + (4,)``
        ``f''(0) = alpha @ data``; by the reflection symmetry of the space
        ``f''(1) = alpha[1] f(0) + alpha[0] f(1) - alpha[3] f'(0) - alpha[2] f'(1)``.
        For k = 0: ``(-6, 6, -4, -2)`` (the cubic).
    """
    k = np.asarray(k, dtype=np.float64)
    d0 = basis_derivatives(k, 0.0)
    d1 = basis_derivatives(k, 1.0)
    G = np.stack([d0[..., 0, :], d1[..., 0, :], d0[..., 1, :], d1[..., 1, :]], axis=-2)
    G_inv = inverse_4x4(G)
    alpha = np.einsum("...i,...ij->...j", d0[..., 2, :], G_inv)
    return G_inv, alpha


@lru_cache(maxsize=4)
def _cubic_system() -> tuple[np.ndarray, np.ndarray]:
    G_inv, alpha = hermite_systems(np.zeros(1))
    G_inv.flags.writeable = False
    alpha.flags.writeable = False
    return G_inv[0], alpha[0]


def tridiagonal_solve(lower: np.ndarray, diag: np.ndarray, upper: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Thomas algorithm along axis 0, vectorised over the trailing (batch) axes.

    ``lower[0]`` and ``upper[-1]`` are ignored. The systems here are diagonally
    dominant (spline derivative systems), so no pivoting is needed.
    """
    n = diag.shape[0]
    c = np.empty(np.broadcast_shapes(upper.shape, diag.shape), dtype=np.result_type(upper, diag))
    d = np.empty(np.broadcast_shapes(rhs.shape, diag.shape), dtype=np.result_type(rhs, diag))
    beta = diag[0]
    c[0] = upper[0] / beta
    d[0] = rhs[0] / beta
    for i in range(1, n):
        beta = diag[i] - lower[i] * c[i - 1]
        c[i] = upper[i] / beta
        d[i] = (rhs[i] - lower[i] * d[i - 1]) / beta
    for i in range(n - 2, -1, -1):
        d[i] = d[i] - c[i] * d[i + 1]
    return d


def natural_spline_matrix(x: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``A`` with ``f(s) = A @ y`` for the natural cubic spline through ``(x, y)``; shape (len(s), len(x))."""
    m = len(x)
    h = np.diff(x)
    A = np.zeros((len(s), m))
    span = np.clip(np.searchsorted(x, s, side="right") - 1, 0, m - 2)
    t = (s - x[span]) / h[span]
    rows = np.arange(len(s))
    A[rows, span] += 1.0 - t
    A[rows, span + 1] += t
    if m > 2:
        # second derivatives at the knots: T M = D y, M_0 = M_{m-1} = 0
        k = m - 2
        D = np.zeros((k, m))
        flat = np.arange(k) * (m + 1)                                   # D[i, i]
        D.flat[flat] = 6.0 / h[:-1]
        D.flat[flat + 1] = -6.0 / h[:-1] - 6.0 / h[1:]
        D.flat[flat + 2] = 6.0 / h[1:]
        Mpp = np.zeros((m, m))
        Mpp[1:-1] = _tridiagonal_lapack(h[1:-1], 2.0 * (h[:-1] + h[1:]), D)
        hs = h[span]
        a = hs ** 2 / 6.0 * ((1.0 - t) ** 3 - (1.0 - t))
        b = hs ** 2 / 6.0 * (t ** 3 - t)
        A += a[:, None] * Mpp[span] + b[:, None] * Mpp[span + 1]
    return A


@lru_cache(maxsize=1)
def _lapack():
    """LAPACK's ``gtsv`` (tridiagonal) and ``pbsv`` (symmetric positive definite band) for float64.

    Called directly: scipy's ``solve_banded`` / ``solveh_banded`` call the same routines with the same
    arguments (so the same numbers, bit for bit) after checks that cost more than these small solves
    (the automatic selection makes ~900 of each: 0.25 s of wrappers on CThead). Never a dense BLAS /
    LAPACK call, whose OpenBLAS worker threads made the selection's ~800 small solves cost 0.4-2.8 s
    of CPU in identical runs on two busy cores.
    """
    return dgtsv, dpbsv


def _tridiagonal_lapack(off: np.ndarray, diag: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve the symmetric tridiagonal system (``off`` below and above ``diag``) for ``rhs`` (k, ...)."""
    if len(diag) == 1:                                  # as solve_banded: LAPACK wants one off-diagonal
        return rhs / diag[0]
    gtsv = _lapack()[0]
    x, info = gtsv(off, diag, off, rhs)[3:]
    if info != 0:
        raise np.linalg.LinAlgError(f"tridiagonal spline system: LAPACK gtsv info {info}")
    return x


def smoothing_spline_values(x: np.ndarray, y: np.ndarray, length: float) -> np.ndarray:
    """Values at the knots of the natural cubic smoothing spline (Reinsch 1967).

    Parameters
    ----------
    x : ndarray, shape (m,)
        Strictly increasing knot positions (mm).
    y : ndarray, shape (m, ...)
        Data at the knots (real or complex; trailing axes are independent series).
    length : float
        Smoothing length L (mm): ``lambda = L^4`` with the data weighted by the
        knots' spacing, so the filter halves wavelengths of ``2 pi L``.
        0 returns ``y`` unchanged.

    Returns
    -------
    ndarray, shape of y
        Linear functions of x are reproduced exactly for any L.
    """
    m = len(x)
    if length <= 0 or m < 3:
        return y
    S = _smoother(np.ascontiguousarray(x, dtype=np.float64).tobytes(), float(length))
    yy = y.reshape(m, -1)
    if np.iscomplexobj(yy):
        return (small_matmul(S, yy.real) + 1j * small_matmul(S, yy.imag)).reshape(y.shape)
    return small_matmul(S, yy).reshape(y.shape)


@lru_cache(maxsize=32)
def _smoother(x_bytes: bytes, length: float) -> np.ndarray:
    """The smoothing spline's linear map ``Y = S y`` for knots x (cached: a study's knots do not change
    while its sliders move).

    ``S = I - lam W^-1 Q A^-1 Q^T`` with ``A = R + lam Q^T W^-1 Q`` (Reinsch 1967): ``Q`` (m x m-2)
    has three entries per column and ``R`` is tridiagonal, so ``A`` is a symmetric positive definite
    band of half-width 2. It is built as that band and solved by a banded Cholesky factorisation
    (LAPACK ``pbsv``); the product with ``Q`` is three shifted rows. Nothing goes through a dense BLAS / LAPACK call,
    whose OpenBLAS worker
    threads made the automatic selection's ~800 small solves cost 0.4-2.8 s of CPU in identical runs
    on two busy cores (0.03 s with one thread). Same matrix as the dense solve within ~1e-12
    (``tests/segment/test_speed_identities.py``).

    References
    ----------
    Reinsch, C. H. (1967). Smoothing by spline functions. Numer. Math. 10, 177-183.
    """
    x = np.frombuffer(x_bytes, dtype=np.float64)
    m = len(x)
    h = np.diff(x)
    w = np.empty(m)
    w[1:-1] = 0.5 * (h[:-1] + h[1:])
    w[0], w[-1] = 0.5 * h[0], 0.5 * h[-1]
    n = m - 2
    # column j of Q: a_j at row j, b_j at row j+1, c_j at row j+2
    a, b, c = 1.0 / h[:-1], -1.0 / h[:-1] - 1.0 / h[1:], 1.0 / h[1:]
    lam = float(length) ** 4
    band = np.zeros((3, n))                             # upper form: band[2 + i - j, j] = A[i, j]
    band[2] = (h[:-1] + h[1:]) / 3.0 + lam * (a * a / w[:-2] + b * b / w[1:-1] + c * c / w[2:])
    band[1, 1:] = h[1:-1] / 6.0 + lam * (b[:-1] * a[1:] / w[1:-2] + c[:-1] * b[1:] / w[2:-1])
    band[0, 2:] = lam * c[:-2] * a[2:] / w[2:-2]
    rhs = np.zeros((n, m))                              # Q^T
    j = np.arange(n)
    rhs[j, j], rhs[j, j + 1], rhs[j, j + 2] = a, b, c
    X, info = _lapack()[1](band, rhs)[1:]               # A^-1 Q^T, (n, m): LAPACK pbsv, upper form
    if info != 0:
        raise np.linalg.LinAlgError(f"smoothing spline system: LAPACK pbsv info {info}")
    # the smoother is linear, so one small solve serves every harmonic and coordinate (real and
    # imaginary parts alike)
    QX = np.zeros((m, m))
    QX[:n] += a[:, None] * X
    QX[1:n + 1] += b[:, None] * X
    QX[2:] += c[:, None] * X
    S = QX * (-lam / w)[:, None]
    S.flat[::m + 1] += 1.0
    S.flags.writeable = False
    return S


def dome_height(curves: np.ndarray, heights: np.ndarray, vertex_z: float | None = None) -> float:
    """Height (mm) of the crown above the top curve.

    ``vertex_z`` (the mask's top, when known) wins if it lies above the top curve
    (within the limits below); otherwise the area of the top three curves is
    extrapolated linearly to zero (a sphere's cap area is linear in height near
    its pole). The result is kept within ``[DOME_MIN_FRACTION, DOME_MAX_FRACTION]``
    times the top curve's equivalent radius.
    """
    xy = curves[..., :2]
    area = 0.5 * np.abs((xy[..., 0] * np.roll(xy[..., 1], -1, axis=1)
                         - np.roll(xy[..., 0], -1, axis=1) * xy[..., 1]).sum(axis=1))
    r_top = float(np.sqrt(area[-1] / np.pi))
    lo, hi = DOME_MIN_FRACTION * r_top, DOME_MAX_FRACTION * r_top
    z = np.asarray(heights, float)
    if vertex_z is not None and np.isfinite(vertex_z) and vertex_z > z[-1]:
        return float(np.clip(vertex_z - z[-1], lo, hi))
    k = min(3, len(z))
    zz, aa = z[-k:], area[-k:]
    slope = np.polyfit(zz - zz[-1], aa, 1)[0] if k >= 2 else 0.0
    if slope < 0:                                       # area shrinking upward: extrapolate to zero
        return float(np.clip(-aa[-1] / slope, lo, hi))
    return float(np.sqrt(lo * hi))


def crown_low_pass(curves: np.ndarray, heights: np.ndarray, spec: np.ndarray, dome_height_mm: float,
                   sigma_mm: float = CROWN_SIGMA_MM) -> np.ndarray:
    """The curves' harmonics with the crown's ripples removed: harmonic h >= 3 of curve k times
    ``exp(-(h sigma_k / R_k)^2 / 2)`` (a Gaussian of width ``sigma_k`` along a circle of radius ``R_k``).

    Parameters
    ----------
    curves : ndarray, shape (m, M, 3)
        The boundary curves (bottom to top), patient mm.
    heights : ndarray, shape (m,)
        Their heights along the slice axis.
    spec : ndarray of complex, shape (m, H, 3)
        Their harmonics (:func:`.pde_basis.curve_harmonics`, possibly smoothed along u).
    dome_height_mm : float
        The dome's height above the top curve (:func:`dome_height`).
    sigma_mm : float
        Width per unit cotangent (:data:`CROWN_SIGMA_MM`).

    Returns
    -------
    ndarray
        A filtered copy of ``spec``; harmonics 0-2 (position, the head's oval) are kept.

    Notes
    -----
    Where a slice cuts the skin at an angle phi to the slice plane, a step of the slices or a speck in
    the mask moves the boundary by about ``dz cot(phi)`` sideways, and harmonics of the curve that the
    skin does not have turn into radial ridges across the crown (the height field ``h(rho, theta)`` of a
    smooth crown has its n-th harmonic shrink like ``rho^n`` toward the pole). ``cot(phi)`` of curve k is
    the shrink of its equivalent radius ``R = sqrt(area / pi)`` to the next curve toward the crown over
    their height gap (0 where the next curve is wider: walls, the nose's underside), and for the top curve
    that of the dome (``R / (2 height)``, a paraboloid's rim), at least its lower neighbour's. Walls
    (cot ~ 0.1-0.5 on a face) stay as they are.
    """
    xy = curves[..., :2]
    area = 0.5 * np.abs((xy[..., 0] * np.roll(xy[..., 1], -1, axis=1)
                         - np.roll(xy[..., 0], -1, axis=1) * xy[..., 1]).sum(axis=1))
    R = np.maximum(np.sqrt(area / np.pi), 1e-9)
    z = np.asarray(heights, dtype=np.float64)
    cot = np.zeros(len(z))
    if len(z) > 1:
        cot[:-1] = np.maximum(R[:-1] - R[1:], 0.0) / np.maximum(np.abs(np.diff(z)), 1e-9)
        cot[-1] = cot[-2]
    cot[-1] = max(cot[-1], R[-1] / (2.0 * max(float(dome_height_mm), 1e-9)))
    h = np.arange(spec.shape[1], dtype=np.float64)
    gain = np.exp(-0.5 * (h[None, :] * (sigma_mm * cot / R)[:, None]) ** 2)
    gain[:, :3] = 1.0
    return spec * gain[..., None]


def dome_fade(power: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``t^p (1 + p (1 - t))``: 1 with zero slope at t = 1 (the top curve), ``~ t^p`` at t = 0 (the pole).

    Increasing on [0, 1] for p >= 0, so a faded harmonic never grows; ``power`` and ``t`` broadcast.
    """
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)
    p = np.asarray(power, dtype=np.float64)
    return t ** p * (1.0 + p * (1.0 - t))


def fade_dome_amplitudes(amp: np.ndarray, s: np.ndarray, pole: np.ndarray, minor: int) -> np.ndarray:
    """The dome span's ring amplitudes with the non-circular part faded toward the pole (in place).

    Parameters
    ----------
    amp : ndarray of complex, shape (n, H, 3)
        Harmonic amplitudes at local s of the dome span (s = 0 the top curve, 1 the pole).
    s : ndarray, shape (n,)
    pole : ndarray, shape (3,)
        The vertex.
    minor : {+1, -1}
        Which rotating part of harmonic 1 in the axial plane is the ellipticity: the one
        turning against the ring (-1: ``e^{-iv}``, the usual counter-clockwise ring).

    Notes
    -----
    Harmonic 1's x and y are split into the parts turning with and against the ring,
    ``x + i y = alpha e^{iv} + conj(gamma) e^{-iv}`` with ``alpha = (a_x + i a_y) / 2`` and
    ``gamma = (a_x - i a_y) / 2``; only the smaller (the ring's ellipticity) is faded, so
    the ring tends to a circle about the pole. See :data:`DOME_FADE_EXTRA`.
    """
    t = 1.0 - np.asarray(s, dtype=np.float64)
    H = amp.shape[1]
    extra = float(DOME_FADE_EXTRA)
    if H > 2:
        amp[:, 2:] *= dome_fade(extra + np.arange(1, H - 1)[None, :], t[:, None])[..., None]
    base = dome_fade(extra, t)
    pole = np.asarray(pole, dtype=np.float64)
    amp[:, 0, :2] = pole[:2] + (amp[:, 0, :2] - pole[:2]) * base[:, None]
    if H > 1:
        ax, ay = amp[:, 1, 0], amp[:, 1, 1]
        alpha, gamma = 0.5 * (ax + 1j * ay), 0.5 * (ax - 1j * ay)
        if minor < 0:
            gamma = gamma * base
        else:
            alpha = alpha * base
        amp[:, 1, 0] = alpha + gamma
        amp[:, 1, 1] = -1j * (alpha - gamma)
    return amp


def _pole_clamped(H: int) -> np.ndarray:
    """Which (harmonic, coordinate) have a clamped (zero) derivative at the pole, shape (H, 3)."""
    clamp = np.zeros((H, 3), bool)
    clamp[0, 2] = True                                           # horizontal tangent plane at the vertex
    clamp[2:] = True                                             # rings tend to an ellipse at the pole
    return clamp


def _derivative_system(alpha: np.ndarray, du: np.ndarray, p: np.ndarray, clamp: np.ndarray | None):
    """Tridiagonal C2 system for the knot derivatives (see the module docstring), solved.

    alpha : (S, B, 4) Hermite second-derivative weights per span and batch column;
    p : (n, B, C) knot values; clamp : (B, C) bool, columns with a zero derivative at the last knot.
    Returns dA/du at the knots, shape (n, B, C).
    """
    n = p.shape[0]
    a = alpha[:, :, None, :]
    dd = du[:, None, None]
    shape = (n,) + p.shape[1:]
    lower = np.zeros((n,) + alpha.shape[1:2] + (1,))
    diag = np.zeros_like(lower)
    upper = np.zeros_like(lower)
    rhs = np.zeros(shape, p.dtype)
    # right-hand span of knots 0 .. n-2 (span j), left-hand span of knots 1 .. n-1 (span j-1)
    diag[:-1] -= a[..., 2] / dd
    upper[:-1] -= a[..., 3] / dd
    rhs[:-1] += (a[..., 0] * p[:-1] + a[..., 1] * p[1:]) / dd ** 2
    lower[1:] -= a[..., 3] / dd
    diag[1:] -= a[..., 2] / dd
    rhs[1:] -= (a[..., 1] * p[:-1] + a[..., 0] * p[1:]) / dd ** 2
    lower, diag, upper = (np.broadcast_to(x, shape).copy() for x in (lower, diag, upper))
    if clamp is not None:
        lower[-1][clamp], diag[-1][clamp], upper[-1][clamp], rhs[-1][clamp] = 0.0, 1.0, 0.0, 0.0
    return tridiagonal_solve(lower, diag, upper, rhs)


@lru_cache(maxsize=32)
def _cubic_operator(u_bytes: bytes, pole: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """For a = 0 the C2 surface is linear in the knot values, with one system for every harmonic:
    the maps from the n knot values to the (S, 4) span coefficients, natural end and (with a pole)
    clamped end, shape (S * 4, n) each. Cached per knot vector (a study's sliders keep its knots)."""
    u = np.frombuffer(u_bytes, dtype=np.float64)
    n = len(u)
    du = np.diff(u)
    g0, a0 = _cubic_system()
    alpha = np.broadcast_to(a0, (n - 1, n, 4))
    eye = np.eye(n)[:, :, None]                                  # (n knots, n unit columns, 1)
    ops = []
    for clamp in ((False, True) if pole else (False,)):
        d = _derivative_system(alpha, du, eye, np.full((n, 1), True) if clamp else None)
        data = np.stack([eye[:-1], eye[1:], d[:-1] * du[:, None, None], d[1:] * du[:, None, None]], axis=2)
        coef = np.matmul(g0, data)[..., 0]                         # (S, n columns, 4)
        op = np.ascontiguousarray(coef.transpose(0, 2, 1).reshape(-1, n))
        op.flags.writeable = False
        ops.append(op)
    return ops[0], (ops[1] if pole else None)


def c2_spans(spec: np.ndarray, u: np.ndarray, smoothing: float, modes: int,
             pole: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Basis coefficients of the C2 surface through the curves' harmonics.

    Parameters
    ----------
    spec : ndarray of complex, shape (m, H, 3)
        Harmonics of the m curves (``X(v) = Re sum_h spec[j, h] e^{i h v}``).
    u : ndarray, shape (m,) or (m + 1,) with a pole
        Strictly increasing knots in [0, 1], ``u[0] = 0``, ``u[-1] = 1``.
    smoothing : float
        a of eq. 1 (global u); exponent of harmonic h on span i: ``a min(h, N+1) du_i``.
    modes : int
        N of eq. 11.
    pole : ndarray, shape (3,), optional
        The vertex: an extra last knot where every harmonic h >= 1 is 0 and the
        spine passes through ``pole`` with zero z-derivative.

    Returns
    -------
    exponents : ndarray, shape (S, H)
    coefficients : ndarray of complex, shape (S, H, 4, 3)
        ``A_h(s) = basis(exponents[i, h], s) @ coefficients[i, h]`` on span i.
    """
    m, H, _ = spec.shape
    p = spec
    if pole is not None:
        tip = np.zeros((1, H, 3), complex)
        tip[0, 0] = pole
        p = np.concatenate([spec, tip])
    n = p.shape[0]                                               # knots
    S = n - 1
    du = np.diff(u)
    hh = np.minimum(np.arange(H), modes + 1).astype(np.float64)
    exponents = float(smoothing) * du[:, None] * hh[None, :]     # (S, H)
    clamp = _pole_clamped(H) if pole is not None else None
    if smoothing == 0.0:                                         # linear in p, one map for all harmonics
        natural, clamped = _cubic_operator(np.ascontiguousarray(u, dtype=np.float64).tobytes(), pole is not None)
        flat = p.reshape(n, -1)
        pr = np.concatenate([flat.real, flat.imag], axis=1)      # (n, 2 * H * 3)
        if clamped is None:
            out = small_matmul(natural, pr).reshape(S, 4, 2, H, 3)
        else:                  # each column by the one map it uses (the clamped: h >= 2, most of them)
            cols = np.tile(clamp.ravel(), 2)                     # pr's columns: (re / im, h, xyz)
            out = np.empty((S * 4, pr.shape[1]))
            out[:, ~cols] = small_matmul(natural, np.ascontiguousarray(pr[:, ~cols]))
            out[:, cols] = small_matmul(clamped, np.ascontiguousarray(pr[:, cols]))
            out = out.reshape(S, 4, 2, H, 3)
        coefficients = (out[:, :, 0] + 1j * out[:, :, 1]).transpose(0, 2, 1, 3)   # (S, H, 4, 3)
        if pole is not None:
            exponents, coefficients = _damp_dome(exponents, coefficients, H)
        return exponents, coefficients
    G_inv, alpha = hermite_systems(exponents)
    d = _derivative_system(alpha, du, p, clamp)                  # (n, H, 3) dA/du
    data = np.stack([p[:-1], p[1:], d[:-1] * du[:, None, None], d[1:] * du[:, None, None]], axis=2)
    coefficients = np.einsum("shij,shjc->shic", G_inv, data)   # (S, H, 4, 3); einsum: see _damp_dome
    if pole is not None:
        exponents, coefficients = _damp_dome(exponents, coefficients, H)
    return exponents, coefficients


@lru_cache(maxsize=8)
def _dome_system(H: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cubic Hermite data -> coefficients, and the damped space's Hermite inverse, for the dome span."""
    k = DOME_DAMPING * np.arange(H, dtype=np.float64)
    g_inv, _ = hermite_systems(k)
    cubic_g = _cubic_G()
    for a in (k, g_inv):
        a.flags.writeable = False
    return k, g_inv, cubic_g


@lru_cache(maxsize=1)
def _cubic_G() -> np.ndarray:
    d0, d1 = basis_derivatives(0.0, 0.0), basis_derivatives(0.0, 1.0)
    G = np.stack([d0[0], d1[0], d0[1], d1[1]])
    G.flags.writeable = False
    return G


def _damp_dome(exponents: np.ndarray, coefficients: np.ndarray, H: int) -> tuple[np.ndarray, np.ndarray]:
    """Let the harmonics fade quickly inside the dome span (eq. 1 with the exponent DOME_DAMPING h there).

    The Hermite data at both ends of the span are kept (value and derivative at the top
    curve, zero at the pole), so the surface stays C1 there; only the shape between
    changes: a ripple of harmonic h on the top curve decays like ``e^{-DOME_DAMPING h s}``
    instead of being carried to the pole as a radial ridge (the "star" of a fan).
    """
    k, g_inv, G = _dome_system(H)
    k_old = exponents[-1]
    if np.any(k_old):                                             # a > 0: the span's own basis
        d0, d1 = basis_derivatives(k_old, 0.0), basis_derivatives(k_old, 1.0)
        G = np.stack([d0[:, 0], d1[:, 0], d0[:, 1], d1[:, 1]], axis=1)
        k = np.maximum(k_old, k)
        g_inv, _ = hermite_systems(k)
    c = coefficients[-1]                                           # (H, 4, 3)
    # einsum, not matmul: a stack of 4x4 products is one BLAS call each, and BLAS threads cost more
    # than the products (measured 7.6 ms against 1.0 ms per solve on 2 busy cores)
    data = np.einsum("ij,hjc->hic" if G.ndim == 2 else "hij,hjc->hic", G, c)   # (f(0), f(1), f'(0), f'(1))
    damped = np.einsum("hij,hjc->hic", g_inv, data)
    exponents = exponents.copy()
    exponents[-1] = k
    coefficients = coefficients.copy()
    coefficients[-1] = damped
    return exponents, coefficients
