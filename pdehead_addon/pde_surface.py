"""Step 4: the Bloor-Wilson PDE surface (paper eq. 1-13), t patches along u.

The head is ``t`` PDE patches stacked along u (paper section 4.1). Patch ``k``
covers the global ``u in [k/t, (k+1)/t]``; inside it a local parameter
``s in [0, 1]`` runs from curve ``3k`` to curve ``3k+3`` and the PDE

    (d^2/ds^2 + a^2 d^2/dv^2)^2 X(s, v) = 0                          (eq. 1)

is solved under the four positional conditions ``X(p_j, v) = P_j(v)`` at
``p = (0, p1, p2, 1)`` (eq. 3-6), with ``p1, p2`` taken from
``BoundarySet.u_knots`` (the curves' heights), not fixed thirds.

Method
------
Each curve is sampled at M points uniformly in v, so its trigonometric
interpolant has the harmonics ``h = 0 .. M//2``. Separation of variables
(eq. 7-10) turns eq. 1 into one ODE per harmonic ``h``,
``(d^2/ds^2 - k_h^2)^2 A_h(s) = 0`` with ``k_h = a*h``; its 4-dimensional
solution space is spanned by ``{e^{ks}, s e^{ks}, e^{-ks}, s e^{-ks}}``
(a cubic for ``h = 0``, eq. 8). The four positional conditions make the
coefficients the solution of a 4x4 interpolation system per harmonic.
Harmonics ``h <= N`` (``modes``) use their own exponent ``a*h``; the
remainder R of eq. 11-12, which carries the difference between the curves
and the truncated series F (eq. 13), uses the single exponent
``omega = a*(N+1)`` for all harmonics ``h > N``. R's functions r_1..r_4(v)
are determined at the M samples and continued between them by trigonometric
interpolation, so the surface passes exactly through every curve (every
harmonic is interpolated at all four knots).

Numerics: for small ``k`` the exponential basis degenerates (``e^{ks}`` and
``e^{-ks}`` both tend to 1), so a basis that tends to the cubic monomials in
``s - 1/2`` is used (``cosh x``, ``s sinhc x``, ``s^2 sinhc x``,
``s^3 psi(x)`` with ``x = k (s - 1/2)``); for larger ``k`` the rescaled
exponentials ``e^{k(s-1)}, s e^{k(s-1)}, e^{-ks}, s e^{-ks}`` (all <= 1 on
[0, 1]). The 4x4 condition numbers (1-norm) stay below ~2e2 in the stable range;
they are kept in ``PDEHead.condition``.

Choice of the smoothing parameter a
-----------------------------------
With four *positional* conditions the per-harmonic interpolation is only
well posed while ``k * gap`` is moderate: a function of the solution space
that is 0 at s = 0 and 1 at s = p1 behaves like ``(s/p1) e^{k(p1-s)}`` and
so overshoots by ~``e^{k p1}/(k p1)`` between the knots. Two measures are
used, both per patch (they depend on its knots):

* the Lebesgue constant ``Lambda(k) = max_s sum_j |L_j(s)|`` of the cardinal
  functions ``L_j`` (noise amplification): 1.63 for thirds at k = 0 (cubic
  Lagrange), within 10 % up to ``k ~ 4.8``, then ``e^{k/3}`` growth: 3.6 at
  k = 10, 44 at k = 20, 810 at k = 30;
* the departure ``Delta(k) = max_s sum_j |L_j^k(s) - L_j^0(s)|`` from the
  cubic interpolation, per mm of a harmonic's amplitude: constants and
  linear functions are not solutions of eq. 1 for n >= 1, so even equal
  circles give a cylinder only up to ``O(k^4)`` (``Delta ~ k^4 / 2000`` for
  thirds); with the main harmonic's ~80 mm this is what makes a naive a = 1
  bulge by tens of mm and a = 2 by metres. The bound
  ``sum_h amp_h Delta(k_h)`` (``amp_h``: largest amplitude of harmonic h on
  the patch's curves) limits how far the surface can move from the a = 0
  surface.

The isotropic choice ``a_iso = H / r`` (patch height H in mm over the mean
radius r of its curves: it makes ``d/ds`` and ``a d/dv`` equal physical
rates, the biharmonic in arc length) is ~0.3 for t = 10 on CThead; with
N = 128 that means exponents up to ~40 and overshoots of metres. So

* the default a is the largest value ``<= a_iso`` with ``Lambda(a (N+1)) <=
  DEFAULT_LEBESGUE_GROWTH * Lambda(0)`` and a departure bound ``<=
  DEFAULT_DEVIATION_MM`` (with N = M/2 this is ~0.03-0.04: every harmonic is
  interpolated almost like the cubic Lagrange blend of the four curves, the
  ``a -> 0`` limit of eq. 1, ``d^4 X/ds^4 = 0``; with few modes the
  isotropic a is reachable for the modes kept);
* user values are accepted from 0 (the cubic limit) up to the a where
  ``Lambda`` reaches ``MAX_LEBESGUE_GROWTH * Lambda(0)`` or the departure
  bound ``MAX_DEVIATION_MM``; above, :class:`PDEError` names the limit
  (:func:`smoothing_bounds` gives both per patch, e.g. for a slider).

Default N is M//2: all harmonics of the sampled curves carry their own
exponent, R is identically zero and X solves eq. 1 exactly. With N < M//2,
F (eq. 13) solves eq. 1 exactly and every harmonic h > N of R solves
``(d^2/ds^2 - omega^2)^2 R_h = 0`` instead (R is not a solution of eq. 1).

Correspondence of the curves
----------------------------
The PDE joins, for each v, the points ``P_j(v)`` of the four curves. With
curves sampled uniformly in arc length, a feature on one curve only (nose
tip, ear, nostril) shifts the arc length of everything after it and the
surface folds between the curves. :func:`extract_boundaries` therefore
returns, by default (``parameterisation="aligned"``), curves re-sampled by
:func:`align_parameterisation` (module :mod:`.parameterisation`: same
polylines, same seam, equal v = corresponding points); on CThead (t = 10) it
cuts the mean distance to the marching-cubes surface by about a third.
:func:`solve_pde` itself reproduces the curves it is given exactly
(``align=True`` aligns an arc-length set first).
"""
from __future__ import annotations

from functools import lru_cache
from typing import Sequence

import numpy as np

from .boundary_set import BoundarySet
from .errors import PDEError
from .mesh import Mesh
from .pde_basis import basis, basis_grid, curve_harmonics, inverse_4x4, small_matmul
from .pde_spline import c2_spans, dome_height, fade_dome_amplitudes, smoothing_spline_values
# (signed_volume and _tube_mesh are also imported from here by scripts/bench_pde.py and scripts/bench_smooth.py)
from .surface_mesh import (_check_count, _fan_caps, _fan_indices, _tube_mesh, column_density, column_v,
                           disc_caps, signed_volume)
from .parameterisation import align_parameterisation  # noqa: F401  (re-export; solve_pde(align=True))

#: The default a keeps the top harmonic's Lebesgue constant within this factor of the cubic one.
DEFAULT_LEBESGUE_GROWTH = 1.10
#: User smoothing values are accepted while the Lebesgue constant stays within this factor.
MAX_LEBESGUE_GROWTH = 2.0
#: The default a moves the surface at most this far (mm) from the a = 0 (cubic) solution.
DEFAULT_DEVIATION_MM = 0.1
#: User smoothing values are accepted while the surface stays this close (mm) to the a = 0 solution.
MAX_DEVIATION_MM = 1.0
#: Exponents are searched up to this value (beyond it every knot set is hopeless anyway).
_K_SEARCH_MAX = 200.0

TWO_PI = 2.0 * np.pi

#: The surface's continuity across the curves: the C2 spans (default) or the paper's four-curve patches.
CONTINUITIES = ("c2", "paper")
DEFAULT_CONTINUITY = "c2"
#: Default C2 smoothing a as a fraction of the head's isotropic a = height / radius.
DEFAULT_C2_SMOOTHING = 0.0
#: Default approximation length along u: this many axial slice steps of the scan (0.5, not 1: the
#: envelope's 3-D Gaussian already smooths the slice steps; one step took the lips and the nose's
#: underside off the face, issue 21) ...
APPROXIMATION_PER_SLICE = 0.5
#: ... but at most this many mean gaps between the chosen curves.
APPROXIMATION_PER_GAP = 0.5
#: ... and for thick or tilted series at least this many source slice thicknesses along z.
APPROXIMATION_PER_THICKNESS = 0.6
#: The approximation slider's top: this many mean gaps between the curves.
APPROXIMATION_MAX_PER_GAP = 1.5


# ----------------------------------------------------------------------------- basis


def _cardinal(k: np.ndarray, knots: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Cardinal functions ``L_j(s)`` (``L_j(p_i) = delta_ij``) for each k: shape (len(k), len(s), 4).

    ``knots`` is (4,) or (len(k), 4).
    """
    k = np.atleast_1d(np.asarray(k, dtype=np.float64))
    knots = np.broadcast_to(np.asarray(knots, dtype=np.float64), k.shape + (4,))
    g_nodes = basis(k[:, None], knots)                                  # (K, 4 nodes, 4 basis)
    g_eval = basis(k[:, None], np.asarray(s, dtype=np.float64)[None, :])  # (K, S, 4 basis)
    return np.linalg.solve(np.swapaxes(g_nodes, 1, 2), np.swapaxes(g_eval, 1, 2)).swapaxes(1, 2)


_LEBESGUE_S = np.linspace(0.0, 1.0, 257)


def lebesgue_constant(k: np.ndarray | float, knots: Sequence[float] | np.ndarray) -> np.ndarray:
    """Lebesgue constant ``max_s sum_j |L_j(s)|`` of the 4-knot interpolation with exponent k.

    It bounds how much a harmonic can grow between the knots relative to its
    values at the curves (1.63 for the cubic with thirds, growing like
    ``e^{k p}`` for large k): the overshoot measure used to bound a.
    ``knots`` is (4,) or one row per k.
    """
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        L = _cardinal(np.atleast_1d(np.asarray(k, dtype=np.float64)), knots, _LEBESGUE_S)
        lam = np.abs(L).sum(axis=2).max(axis=1)
    lam[~np.isfinite(lam)] = np.inf
    return lam


_K_SCAN = np.concatenate([np.linspace(0.0, 20.0, 41)[1:], np.linspace(22.0, _K_SEARCH_MAX, 30)])


@lru_cache(maxsize=256)
def _stable_exponent(knots: tuple[float, float, float, float], growth: float) -> float:
    """Largest K such that Lambda(k) <= growth * Lambda(0) for all k in [0, K] (scan, then bisection)."""
    lam0 = float(lebesgue_constant(0.0, knots)[0])
    bound = growth * lam0
    lam = lebesgue_constant(_K_SCAN, knots)
    bad = np.nonzero(lam > bound)[0]
    if bad.size == 0:
        return _K_SEARCH_MAX
    hi = _K_SCAN[bad[0]]
    lo = _K_SCAN[bad[0] - 1] if bad[0] > 0 else 0.0
    while hi - lo > 1e-3 * hi:
        mid = 0.5 * (lo + hi)
        if lebesgue_constant(mid, knots)[0] > bound:
            hi = mid
        else:
            lo = mid
    return lo


# ----------------------------------------------------------------------------- set-up helpers


def _require_3t_plus_1(bset: BoundarySet) -> None:
    if not bset.is_3t_plus_1:
        raise PDEError(f"continuity='paper' needs 3t+1 curves (four per patch, shared ends), got "
                       f"{bset.curves.shape[0]}; use the default continuity='c2' for any count")


def _local_knots(bset: BoundarySet) -> np.ndarray:
    """Per-patch knots ``(0, p1, p2, 1)`` in local s, shape (t, 4); validates ``bset.u_knots``."""
    _require_3t_plus_1(bset)
    t = bset.patches
    u = np.asarray(bset.u_knots, dtype=np.float64)
    if u.shape != (3 * t + 1,) or not np.all(np.isfinite(u)):
        raise PDEError(f"u_knots must be {3 * t + 1} finite numbers, got shape {u.shape}")
    ends = np.arange(t + 1) / t
    if np.max(np.abs(u[::3] - ends)) > 1e-9:
        raise PDEError("u_knots[3k] must equal k/t (the patch ends); rebuild them with knots_from_heights")
    local = np.stack([u[3 * k:3 * k + 4] * t - k for k in range(t)])
    local[:, 0], local[:, 3] = 0.0, 1.0
    gaps = np.diff(local, axis=1)
    if np.any(gaps <= 1e-6):
        bad = int(np.nonzero(np.any(gaps <= 1e-6, axis=1))[0][0])
        raise PDEError(f"patch {bad}: u_knots are not strictly increasing ({local[bad].round(6).tolist()})")
    return local


def _patch_geometry(bset: BoundarySet) -> tuple[np.ndarray, np.ndarray]:
    """Per-patch height H (mm) and mean curve radius r (mm) for the isotropic a = H / r."""
    t = bset.patches
    c = bset.curves
    centroid = c.mean(axis=1, keepdims=True)
    radius = np.linalg.norm(c - centroid, axis=2).mean(axis=1)     # (3t+1,)
    heights = np.asarray(bset.heights, float)
    H = np.abs(heights[3:][::3] - heights[:-3][::3])
    # fall back to the spine chord where heights are not informative
    chord = np.linalg.norm(centroid[3::3, 0] - centroid[:-3:3, 0], axis=1)
    H = np.where(H > 0, H, chord)
    r = np.array([radius[3 * k:3 * k + 4].mean() for k in range(t)])
    return H, r


def _check_modes(modes: int | None, samples: int) -> int:
    top = samples // 2
    if modes is None:
        return top
    if isinstance(modes, bool) or not isinstance(modes, (int, np.integer)):
        raise PDEError(f"modes must be an integer in [1, {top}], got {modes!r}")
    if not 1 <= int(modes) <= top:
        raise PDEError(f"modes must be in [1, {top}] (M/2 for M = {samples} samples per curve), got {modes}")
    return int(modes)


_DEV_K = np.concatenate([[0.0], np.geomspace(1e-3, _K_SEARCH_MAX, 160)])
_DEV_LOG_STEP = float(np.log(_DEV_K[2] / _DEV_K[1]))


@lru_cache(maxsize=256)
def _deviation_table(knots: tuple[float, float, float, float]) -> np.ndarray:
    """``Delta(k) = max_s sum_j |L_j^k(s) - L_j^0(s)|`` on the grid ``_DEV_K``.

    How far the exponent-k interpolation of a harmonic can depart from the
    cubic (a = 0) one, per mm of the harmonic's amplitude at the curves; it
    grows like ``k^4`` for small k (constants and linear functions are not in
    the solution space of eq. 1 for n >= 1).
    """
    with np.errstate(all="ignore"):
        L = _cardinal(_DEV_K, knots, _LEBESGUE_S)
        dev = np.abs(L - L[:1]).sum(axis=2).max(axis=1)
    dev[~np.isfinite(dev)] = np.inf
    return np.maximum.accumulate(dev)                                       # monotone envelope


def _harmonic_amplitudes(spec: np.ndarray, t: int) -> np.ndarray:
    """Per patch and harmonic the largest amplitude (mm) over the patch's four curves, shape (t, H)."""
    amp = np.linalg.norm(np.abs(spec), axis=2)                              # (3t+1, H)
    return np.stack([amp[3 * k:3 * k + 4].max(axis=0) for k in range(t)])


def _deviation_limit(tables: np.ndarray, amp: np.ndarray, n_modes: int, tol: float,
                     upper: np.ndarray) -> np.ndarray:
    """Largest a <= upper per patch with ``sum_h amp_h Delta(a min(h, N+1)) <= tol``.

    The bound is monotone in a; it is evaluated at once on a geometric grid of 48
    values down to upper/1e4 and the crossing interpolated in log a (1 % accuracy).
    """
    upper = np.asarray(upper, float)
    h = np.minimum(np.arange(1, amp.shape[1]), n_modes + 1).astype(np.float64)
    rows_all = np.arange(len(upper))

    def bound(a: np.ndarray, rows: np.ndarray) -> np.ndarray:               # a: (r, G) -> (r, G)
        k = np.clip(a[:, :, None] * h[None, None, :], 0.0, _DEV_K[-1])     # (r, G, H-1)
        # _DEV_K is 0 then geometric: the bracketing index in closed form
        with np.errstate(divide="ignore"):
            j = np.floor(np.log(np.maximum(k, 1e-300) / _DEV_K[1]) / _DEV_LOG_STEP).astype(np.int64) + 1
        j = np.clip(j, 0, len(_DEV_K) - 2)
        f = np.clip((k - _DEV_K[j]) / (_DEV_K[j + 1] - _DEV_K[j]), 0.0, 1.0)
        r = np.arange(len(rows))[:, None, None]
        with np.errstate(invalid="ignore"):
            dev = tables[rows[r], j] * (1 - f) + tables[rows[r], j + 1] * f
        dev = np.where(np.isfinite(dev), dev, np.inf)
        return (amp[rows][:, None, 1:] * dev).sum(axis=2)

    at_upper = bound(upper[:, None], rows_all)[:, 0] <= tol
    if np.all(at_upper):
        return upper
    need = np.nonzero(~at_upper)[0]
    factors = np.concatenate([np.geomspace(1.0, 1e-4, 40), [0.0]])          # 1 ... 1e-4, 0
    a = upper[need, None] * factors[None, :]                                # (r, G)
    bound_grid = bound(a, need)                                             # (r, G), decreasing along G
    result = upper.copy()
    bound = bound_grid
    upper = upper[need]
    ok = bound <= tol
    first = np.argmax(ok, axis=1)                                           # largest a that is within tol
    out = a[np.arange(len(upper)), first]
    # interpolate between the failing grid point before it and the first good one (log a, log bound)
    inner = (first > 0) & (first < len(factors) - 1)
    i = np.nonzero(inner)[0]
    if i.size:
        a_bad, a_good = a[i, first[i] - 1], a[i, first[i]]
        b_bad, b_good = bound[i, first[i] - 1], np.maximum(bound[i, first[i]], 1e-300)
        frac = np.clip(np.log(tol / b_good) / np.log(b_bad / b_good), 0.0, 1.0)
        out[i] = a_good * (a_bad / a_good) ** (0.99 * frac)
    result[need] = np.where(ok.any(axis=1), out, 0.0)
    return result


def _bounds(bset: BoundarySet, n_modes: int, local: np.ndarray, spec: np.ndarray,
            want_default: bool = True, want_max: bool = True) -> tuple[np.ndarray | None, np.ndarray | None]:
    t = bset.patches
    keys = [tuple(float(x) for x in np.round(kn, 12)) for kn in local]
    tables = np.stack([_deviation_table(k) for k in keys])
    amp = _harmonic_amplitudes(spec, t)
    default = maximum = None
    if want_default:
        H, r = _patch_geometry(bset)
        with np.errstate(divide="ignore", invalid="ignore"):
            a_iso = np.where(r > 0, H / r, np.inf)
        stable_default = np.array([_stable_exponent(k, DEFAULT_LEBESGUE_GROWTH) for k in keys]) / (n_modes + 1)
        default = _deviation_limit(tables, amp, n_modes, DEFAULT_DEVIATION_MM, np.minimum(a_iso, stable_default))
    if want_max:
        stable_max = np.array([_stable_exponent(k, MAX_LEBESGUE_GROWTH) for k in keys]) / (n_modes + 1)
        maximum = _deviation_limit(tables, amp, n_modes, MAX_DEVIATION_MM, stable_max)
        if default is not None:
            maximum = np.maximum(maximum, default)
    return default, maximum


def smoothing_bounds(bset: BoundarySet, modes: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Default and maximum smoothing parameter a of each patch.

    Parameters
    ----------
    bset : BoundarySet
    modes : int, optional
        N of eq. 11 (default M//2).

    Returns
    -------
    default, maximum : ndarray, shape (t,)
        ``default`` is the largest a not above the isotropic ``H/r`` for which
        (1) the Lebesgue constant of the top exponent ``a (N+1)`` stays within
        ``DEFAULT_LEBESGUE_GROWTH`` of the cubic one and (2) the surface moves
        at most ``DEFAULT_DEVIATION_MM`` away from the a = 0 (cubic) solution
        (bound ``sum_h amp_h Delta(k_h)`` over the curves' harmonic amplitudes).
        ``maximum`` is the same with ``MAX_LEBESGUE_GROWTH`` and
        ``MAX_DEVIATION_MM``: every a in ``[0, maximum]`` gives a surface within
        ``MAX_DEVIATION_MM`` of the cubic one, larger values raise PDEError.
    """
    if not isinstance(bset, BoundarySet):
        raise PDEError(f"smoothing_bounds needs a BoundarySet, got {type(bset).__name__}")
    n = _check_modes(modes, bset.samples)
    spec, _ = curve_harmonics(bset.curves)
    return _bounds(bset, n, _local_knots(bset), spec)


# ----------------------------------------------------------------------------- the solved head


class PDEHead:
    """A solved PDE head: Bloor-Wilson spans along u, evaluable anywhere in (u, v, w).

    Do not construct directly; use :func:`solve_pde`.

    Attributes
    ----------
    bset : BoundarySet
        The boundary conditions solved for (not copied).
    continuity : {"c2", "paper"}
        ``"c2"``: one span between each pair of consecutive curves, position and
        derivative conditions, C2 across every curve (:mod:`.pde_spline`).
        ``"paper"``: t patches of four position curves each (eq. 3-6), C0 at the joints.
    smoothing : ndarray
        The smoothing parameter a of eq. 1: one per patch (``"paper"``, local u of the
        patch) or a single global value (``"c2"``, global u).
    modes : int
        N of eq. 11: harmonics with their own exponent ``a n``; the rest is R.
    span_edges : ndarray, shape (S + 1,)
        u where each span starts and ends (``k / t`` for the paper's patches; the
        curves' u and, with a dome, 1.0 for the vertex).
    curve_u : ndarray, shape (3t+1,)
        u of each boundary curve.
    knots : ndarray, shape (t, 4)
        Paper patches only: local knots ``(0, p1, p2, 1)`` of each patch.
    exponents : ndarray, shape (S, H)
        Exponent of every harmonic h = 0 .. M//2 on each span (in the span's local s).
    coefficients : ndarray of complex, shape (S, H, 4, 3)
        Basis coefficients: ``A_h(s) = basis(k_h, s) @ coefficients[i, h]`` and
        ``X(s, v) = Re sum_h A_h(s) e^{i h v}`` (so ``A_h - i B_h`` of eq. 9-10).
    condition : ndarray, shape (S,)
        Largest 1-norm condition number of the per-harmonic 4x4 systems.
    approximation_mm : float
        Smoothing length along u (``"c2"``; 0: the surface passes through every curve).
    vertex : ndarray or None
        The crown's pole (LPS mm) when the surface closes in a dome, else None.
    smoothing_is_default : bool
        True when ``smoothing`` was chosen by :func:`solve_pde` (stored as such by storage).
    remainder : bool
        False when the harmonics above ``modes`` were dropped (eq. 13's F, see :func:`solve_pde`).
    planar_z : bool
        Every curve lies in a plane z = const; then ``z(u, v, w) = A0_z(u)`` exactly.
    orientation : int
        +1 if the quads ``(u,v) -> (u,v+1) -> (u+1,v+1) -> (u+1,v)`` face outward, else -1.
    """

    def __init__(self, bset: BoundarySet, smoothing: np.ndarray, modes: int, knots: np.ndarray | None,
                 exponents: np.ndarray, coefficients: np.ndarray, condition: np.ndarray,
                 planar_z: bool, span_edges: np.ndarray | None = None, curve_u: np.ndarray | None = None,
                 continuity: str = "paper", approximation_mm: float = 0.0, vertex: np.ndarray | None = None):
        self.bset = bset
        self.smoothing = smoothing
        self.modes = modes
        self.knots = knots
        self.exponents = exponents
        self.coefficients = coefficients
        self.condition = condition
        self.planar_z = planar_z
        self.continuity = continuity
        self.approximation_mm = float(approximation_mm)
        self.vertex = vertex
        S = coefficients.shape[0]
        self.span_edges = np.linspace(0.0, 1.0, S + 1) if span_edges is None else np.asarray(span_edges, float)
        self.curve_u = np.asarray(bset.u_knots if curve_u is None else curve_u, float)
        self.smoothing_is_default = False
        self.remainder = True
        self._coef_real = np.ascontiguousarray(
            np.concatenate([coefficients.real, coefficients.imag], axis=-1))   # (S, H, 4, 6)
        self._uniform_spans = bool(np.allclose(self.span_edges, np.linspace(0.0, 1.0, S + 1), atol=1e-12))
        self._cubic_spans = ~np.any(exponents, axis=1)
        S_, H_ = coefficients.shape[:2]
        self._coef_flat = np.ascontiguousarray(self._coef_real.transpose(0, 2, 1, 3)).reshape(S_ * 4, H_ * 6)
        # the crown's dome (last span): which rotating part of the top ring's harmonic 1 is its ellipticity
        self._dome_minor = 0
        if vertex is not None and S > 0 and H_ > 1:
            a1 = basis(exponents[-1, 1], 0.0) @ coefficients[-1, 1]
            self._dome_minor = -1 if abs(a1[0] + 1j * a1[1]) >= abs(a1[0] - 1j * a1[1]) else 1
            self._cubic_spans[-1] = False                                      # evaluated with its fade
        self.orientation = 1
        self.orientation = self._measure_orientation()
        self._deviation = None

    # -- basic properties
    @property
    def lebesgue(self) -> np.ndarray:
        """Paper patches: the Lebesgue constant of each patch's largest exponent (overshoot factor)."""
        if self.knots is None:
            raise PDEError("the Lebesgue constant is defined for the paper's four-curve patches only")
        return lebesgue_constant(self.exponents.max(axis=1), self.knots)

    @property
    def patches(self) -> int:
        """t, the user's patch count (3t+1 curves), whatever the continuity."""
        return self.bset.patches

    @property
    def spans(self) -> int:
        """Number S of pieces along u (t paper patches, or the spans between curves)."""
        return self.coefficients.shape[0]

    @property
    def harmonics(self) -> int:
        """Number of harmonics h = 0 .. M//2 carried."""
        return self.coefficients.shape[1]

    @property
    def curve_deviation(self) -> float:
        """Largest distance (mm) between a boundary curve and the surface row at its u (0 when exact)."""
        if self._deviation is None:
            rows = self._grid(self.curve_u, self.bset.samples)
            self._deviation = float(np.linalg.norm(rows - self.bset.curves, axis=-1).max())
        return self._deviation

    def _patch_of(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Span index and local s in [0, 1] of each u."""
        u = np.asarray(u, dtype=np.float64)
        S = self.spans
        if self._uniform_spans:
            scaled = u * S
            patch = np.clip(np.floor(scaled).astype(np.int64), 0, S - 1)
            return patch, scaled - patch
        e = self.span_edges
        patch = np.clip(np.searchsorted(e, u, side="right") - 1, 0, S - 1)
        return patch, (u - e[patch]) / (e[patch + 1] - e[patch])

    @staticmethod
    def _check_u(u: np.ndarray) -> None:
        if not np.all(np.isfinite(u)) or np.any(u < -1e-12) or np.any(u > 1 + 1e-12):
            raise PDEError("u must lie in [0, 1]")

    # -- harmonic amplitudes
    def _amplitudes(self, u: np.ndarray, harmonics: int | None = None) -> np.ndarray:
        """Complex harmonic amplitudes ``A_h(u) - i B_h(u)`` (weighted), shape (len(u), H, 3).

        ``harmonics`` limits the computation to h < harmonics (1: the spine only); the
        arithmetic per harmonic is the same either way.
        """
        u = np.clip(np.asarray(u, dtype=np.float64).ravel(), 0.0, 1.0)
        patch, s = self._patch_of(u)
        H = self.harmonics if harmonics is None else int(harmonics)
        out = np.empty((u.size, H, 3), dtype=np.complex128)
        cubic = self._cubic_spans[patch]                                      # a = 0 there: one basis for all h
        if np.any(cubic):
            # one product: rows x (span, basis) weights (4 per row) times (span, basis) x (h, re/im xyz)
            rows = np.flatnonzero(cubic)
            g = basis(np.zeros(1), s[rows, None])[:, 0]                       # (n, 4)
            S = self.spans
            flat = self._coef_flat if H == self.harmonics else \
                np.ascontiguousarray(self._coef_flat.reshape(S * 4, -1, 6)[:, :H]).reshape(S * 4, H * 6)
            for start in range(0, rows.size, 512):
                sl = rows[start:start + 512]
                W = np.zeros((len(sl), S * 4))
                W[np.arange(len(sl))[:, None], 4 * patch[sl, None] + np.arange(4)] = g[start:start + 512]
                prod = small_matmul(W, flat).reshape(len(sl), H, 6)
                out[sl] = prod[..., :3] + 1j * prod[..., 3:]
        for k in np.unique(patch[~cubic]):
            sel = np.nonzero(patch == k)[0]
            g = basis_grid(self.exponents[k, :H], s[sel])                    # (n, H, 4)
            # batched over h: (H, n, 4) @ (H, 4, 6 = re xyz, im xyz)
            prod = np.einsum("hnb,hbc->nhc", g.transpose(1, 0, 2), self._coef_real[k, :H])
            amp = prod[..., :3] + 1j * prod[..., 3:]
            if self._dome_minor and k == self.spans - 1:                     # the crown's dome span
                amp = fade_dome_amplitudes(amp, s[sel], self.vertex, self._dome_minor)
            out[sel] = amp
        return out

    def spine(self, u: np.ndarray | float) -> np.ndarray:
        """The spine ``A_0(u)`` (eq. 8): the centre line, shape ``u.shape + (3,)``."""
        u = np.asarray(u, dtype=np.float64)
        self._check_u(u)
        return self._amplitudes(u.ravel(), harmonics=1)[:, 0].real.reshape(u.shape + (3,))

    # -- evaluation
    def evaluate(self, u: np.ndarray | float, v: np.ndarray | float, w: np.ndarray | float = 1.0,
                 chunk: int = 8192) -> np.ndarray:
        """Points ``X(u, v, w) = A0(u) + w (X(u, v) - A0(u))`` (eq. 11 and 23) in LPS mm.

        Parameters
        ----------
        u, v, w : array_like
            Broadcast together; ``u in [0, 1]``, v in radians (periodic), ``w`` usually in [0, 1].

        Returns
        -------
        ndarray, shape ``broadcast(u, v, w).shape + (3,)``
        """
        u, v, w = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float), np.asarray(w, float))
        self._check_u(u)
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(w))):
            raise PDEError("v and w must be finite")
        shape = u.shape
        uf, vf, wf = u.ravel(), v.ravel(), w.ravel()
        out = np.empty((uf.size, 3))
        h = np.arange(self.harmonics)
        for start in range(0, uf.size, chunk):
            sl = slice(start, start + chunk)
            amp = self._amplitudes(uf[sl])                                    # (n, H, 3)
            phase = np.exp(1j * np.outer(vf[sl], h))                          # (n, H)
            radial = np.einsum("nhc,nh->nc", amp[:, 1:], phase[:, 1:]).real
            out[sl] = amp[:, 0].real + wf[sl, None] * radial
        return out.reshape(shape + (3,))

    def _grid(self, u: np.ndarray, nv: int | None = None, v: np.ndarray | None = None) -> np.ndarray:
        """Surface points on the grid u x v: shape (len(u), nv, 3).

        With ``nv`` the columns are ``v_j = 2 pi j / nv`` and the synthesis is an
        inverse real FFT (harmonics above nv/2 are folded, which is exact at the
        sample points); with explicit ``v`` a direct cosine/sine sum.
        """
        H = self.harmonics
        if v is not None:
            amp = self._amplitudes(u)                                         # (nu, H, 3)
            phase = np.exp(1j * np.outer(np.arange(H), np.asarray(v, float)))   # (H, nv)
            a = amp.transpose(0, 2, 1).reshape(-1, H)                          # (nu*3, H)
            # contiguous real and imaginary parts: strided views would miss BLAS (~10x slower)
            pts = (np.ascontiguousarray(a.real) @ np.ascontiguousarray(phase.real)
                   - np.ascontiguousarray(a.imag) @ np.ascontiguousarray(phase.imag))
            return pts.reshape(len(u), 3, -1).transpose(0, 2, 1)
        u = np.clip(np.asarray(u, dtype=np.float64).ravel(), 0.0, 1.0)
        nb = nv // 2 + 1
        spec = np.empty((u.size, 3, nb), np.complex128)
        patch, s = self._patch_of(u)
        cubic = self._cubic_spans[patch]
        if np.any(cubic):                        # the harmonics folded once per nv, then one product
            rows = np.flatnonzero(cubic)
            g = basis(np.zeros(1), s[rows, None])[:, 0]
            W = np.zeros((rows.size, self.spans * 4))
            W[np.arange(rows.size)[:, None], 4 * patch[rows, None] + np.arange(4)] = g
            folded = small_matmul(W, self._folded(nv)).reshape(rows.size, nb, 6)
            spec[rows] = (folded[..., :3] + 1j * folded[..., 3:]).transpose(0, 2, 1)
        if not np.all(cubic):
            rows = np.flatnonzero(~cubic)
            spec[rows] = _fold(self._amplitudes(u[rows]).transpose(0, 2, 1), nv)
        return ring_points(spec, nv)

    def grid(self, u: np.ndarray, nv: int | None = None, v: np.ndarray | None = None) -> np.ndarray:
        """:meth:`_grid`, remembered per head for its last four samplings (read-only arrays).

        A live change rebuilds the surface and then the solid on the same (nu, nv) grid: the solid
        reads the surface's points instead of synthesising them again, and a w-range or nw change
        reuses them too. Rows do not depend on each other (``_grid(u)[:-1]`` is ``_grid(u[:-1])``
        bit for bit: ``tests/test_speed_identities.py``), so the dome's surface takes the first rows.
        """
        u = np.asarray(u, dtype=np.float64)
        key = (u.tobytes(), None if nv is not None else np.asarray(v, float).tobytes(), nv)
        entries = self.__dict__.setdefault("_grid_cache", {})
        pts = entries.get(key)
        if pts is None:
            pts = self._grid(u, nv) if nv is not None else self._grid(u, None, v=v)
            pts.flags.writeable = False
            if len(entries) >= 4:
                entries.pop(next(iter(entries)))
            entries[key] = pts
        return pts

    def _folded(self, nv: int) -> np.ndarray:
        """The (span, basis) x (bin, re/im xyz) coefficients with the harmonics folded onto the nv//2 + 1
        bins of an nv-point ring (cached per nv: the sliders rebuild at a few resolutions)."""
        cache = self.__dict__.setdefault("_folded_cache", {})
        if nv not in cache:
            H, nb = self.harmonics, nv // 2 + 1
            h = np.arange(H)
            m = h % nv
            conj = m > nv // 2
            b = np.where(conj, nv - m, m)
            F_re = np.zeros((H, nb))
            F_re[h, b] = 1.0
            F_im = F_re * np.where(conj, -1.0, 1.0)[:, None]                # conjugates flip the imaginary part
            c = self._coef_flat.reshape(-1, H, 6)
            k = c.shape[0]
            ct = np.ascontiguousarray(c.transpose(0, 2, 1))                    # (k, 6, H)
            re = small_matmul(ct[:, :3].reshape(-1, H), F_re).reshape(k, 3, nb)
            im = small_matmul(ct[:, 3:].reshape(-1, H), F_im).reshape(k, 3, nb)
            out = np.concatenate([re, im], axis=1).transpose(0, 2, 1)          # (k, nb, 6)
            if len(cache) > 8:
                cache.clear()
            cache[nv] = np.ascontiguousarray(out).reshape(k, nb * 6)
        return cache[nv]

    def _measure_orientation(self) -> int:
        """Sign of the volume enclosed by the polyhedral tube through the curves, default winding.

        The surface passes through (or, approximating, next to) the curves, so the
        coarse tube whose rings are the curves has the orientation of the surface.
        For curves stacked along z that all wind the same way (every set
        :func:`extract_boundaries` makes) that sign is the winding times the
        stacking direction, without building the tube.
        """
        c = self.bset.curves
        xy = c[..., :2]
        area = (xy[..., 0] * np.roll(xy[..., 1], -1, axis=1) - np.roll(xy[..., 0], -1, axis=1) * xy[..., 1]).sum(1)
        dz = np.diff(self.bset.heights)
        if (np.all(area > 0) or np.all(area < 0)) and (np.all(dz > 0) or np.all(dz < 0)):
            return 1 if area[0] * dz[0] > 0 else -1
        rings = c[:, ::max(1, self.bset.samples // 64)]
        mesh = _tube_mesh(rings, orientation=1, caps=_fan_caps(rings, rings[[0, -1]].mean(axis=1), fan_only=True))
        return 1 if signed_volume(mesh) >= 0 else -1

    def surface(self, nu: int, nv: int, caps: bool = False, uv: bool = True) -> Mesh:
        """The head surface as a tube of quads (paper Fig. 4, 5, 13).

        Parameters
        ----------
        nu : int
            Rows along u, including u = 0 and u = 1 (>= 2). With a dome the row
            u = 1 is the single vertex of the crown, joined by a triangle fan.
        nv : int
            Columns along v (>= 3), the seam stitched; ``v_j = 2 pi j / nv``, closer in v where an outline
            runs nearly radially (:meth:`v_columns`: no ring edge much longer than the curves' mean step).
        caps : bool
            Close the bottom (and, without a dome, the top) with triangles: a flat disc
            triangulated ring by ring (:class:`.surface_mesh.DiscCap`, no triangle much
            longer than the tube's edges) when the end curve is star-shaped around its
            spine point, else a triangulation of the ring; watertight for 3-D printing.
        uv : bool
            Per-corner UVs (:meth:`uv_layout`, computed once per boundary set: ~0.65 s CPU on a head).
            False for a mesh only measured (the slice selection's verification).

        Returns
        -------
        Mesh
            Quads wound outward; per-corner UVs in islands that are functions of (u, v)
            (:meth:`uv_layout`: the tube, the crown's dome and the cap, none mirrored),
            vertex attributes ``u`` and ``v`` (cap points: the end's u and their v).
        """
        nu, nv = _check_count(nu, "nu", 2), _check_count(nv, "nv", 3)
        u = np.linspace(0.0, 1.0, nu)
        ends = self.spine(np.array([0.0, 1.0]))
        density = self.v_density()
        if self.vertex is not None:
            nu = max(nu, 3)
            u = np.linspace(0.0, 1.0, nu)
            # the solid's grid too (it has the pole row; pde_solid takes the same columns)
            pts = (self.grid(u, nv) if density is None else self.grid(u, v=self.v_columns(nv)))[:-1]
            bottom = disc_caps(pts, ends, ends=(0,), reference=self.cap_reference(nu, nv))[0] if caps else None
            top = (np.asarray(self.vertex, float), _fan_indices(nv))
            return _tube_mesh(pts, self.orientation, [bottom, top], uv=uv, u=u[:-1], top_u=1.0,
                              uv_layout=self.uv_layout() if uv else None, v_density=density)
        pts = self.grid(u, nv) if density is None else self.grid(u, v=self.v_columns(nv))
        cap_tris = disc_caps(pts, ends, reference=self.cap_reference(nu, nv)) if caps else None
        return _tube_mesh(pts, self.orientation, cap_tris, uv=uv, u=u, uv_layout=self.uv_layout() if uv else None,
                          v_density=density)

    def v_density(self) -> np.ndarray | None:
        """How densely the surface's columns sample each of the curves' v steps
        (:func:`.surface_mesh.column_density` of the end curves the caps close: the bottom one, and the top
        one without a dome), None for equal steps. From the boundary curves alone: one per study.

        Only the capped ends: the same density from every curve also evened CThead's ears, but it moved
        faces into them and the UVs' area stretch there went from 3.81 to 4.61 (target 4), angle p95
        9.8 -> 11.6 deg; from the bottom curve it is 3.86 / 9.2 deg, GE's bottom ring 4.24 -> 2.90 mean
        edges (its middle rings keep edges up to ~4.3 mean edges)."""
        ends = [0] if self.vertex is not None else [0, -1]
        return _derived(self.bset, f"v_density{len(ends)}", lambda: column_density(self.bset.curves[ends]))

    def v_columns(self, nv: int) -> np.ndarray:
        """The v (radians) of the surface's nv columns (:func:`.surface_mesh.column_v`): ``2 pi j / nv``
        where the end curve's samples are about evenly spaced, closer where its outline runs nearly
        radially (issue 21: GE's neck ring had 8.4 mm edges, 4.2 x the tube's mean edge)."""
        return column_v(self.v_density(), int(nv))

    def cap_reference(self, nu: int, nv: int) -> dict:
        """What fixes the disc caps' vertex counts (:func:`.surface_mesh.disc_caps`): the tube's mean edge
        at (nu, nv) and the end curves' perimeters and largest radii, from the boundary curves alone, so
        the shape sliders rebuild the surface with the same topology."""
        def compute():
            c = self.bset.curves
            perimeter = np.linalg.norm(np.roll(c, -1, axis=1) - c, axis=2).sum(axis=1)
            radius = np.linalg.norm(c - c.mean(axis=1, keepdims=True), axis=2).max(axis=1)
            span = float(_curve_positions(self.bset)[-1])
            if self.vertex is not None:
                span += float(np.linalg.norm(c[-1] - c[-1].mean(axis=0), axis=1).mean())
            density = self.v_density()

            def arc_fraction(ring):
                """Cumulative length at the column fraction k / K, k = 0 .. K (with equal v steps: at
                v = 2 pi k / M), the abscissa of the cap's ring points (:class:`.surface_mesh.DiscCap`)."""
                closed = np.vstack([ring, ring[:1]])
                arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
                if density is None:
                    return arc / arc[-1]
                K = 4 * len(ring)
                v = column_v(density, K)
                return np.append(np.interp(v, TWO_PI * np.arange(len(ring) + 1) / len(ring), arc), arc[-1]) / arc[-1]
            return span, float(perimeter.mean()), ((perimeter[0], radius[0], arc_fraction(c[0])),
                                                   (perimeter[-1], radius[-1], arc_fraction(c[-1])))
        span, mean_perimeter, end_rings = _derived(self.bset, f"cap_ref{self.vertex is not None}", compute)
        edge = 0.5 * (span / max(nu - 1, 1) + mean_perimeter / nv)
        return {"edge": edge, "ends": end_rings}

    def uv_layout(self) -> dict:
        """The surface's UV islands (:func:`.surface_mesh.uv_islands`), from the boundary curves alone, so
        the UVs are one function of (u, v) for a study: nu, nv and the shape sliders do not move a
        painted texture. ``u_top``: where the dome starts in u; ``aspect``: the tube island's height over
        its width; ``tube_map``: :func:`.surface_mesh.uv_tube_map` of the curves (U, V in mm at the
        samples of :func:`.surface_mesh.uv_map_grid`, rows ``map_u``) and ``tube_box`` its extent; with a
        single curve ``shear`` (:func:`.surface_mesh.uv_shear`) instead."""
        from .surface_mesh import uv_map_grid, uv_shear, uv_tube_map

        def compute():
            c = self.bset.curves
            perimeter = np.linalg.norm(np.roll(c, -1, axis=1) - c, axis=2).sum(axis=1)
            steps = np.diff(_curve_positions(self.bset))
            length = float(steps.sum())
            tube = float((0.5 * (perimeter[1:] + perimeter[:-1]) * steps).sum())

            def flat_area(ring):
                d = ring - ring.mean(axis=0)
                return 0.5 * float(np.linalg.norm(np.cross(d, np.roll(d, -1, axis=0)).sum(axis=0)))
            # a spherical cap's area is pi times the squared chord from its pole to its rim
            r_top = float(np.linalg.norm(c[-1] - c[-1].mean(axis=0), axis=1).mean())
            h = dome_height(c, self.bset.heights, self.bset.meta.get("vertex_z"))
            top = np.pi * (r_top ** 2 + h ** 2) if self.vertex is not None else flat_area(c[-1])
            return (length / max(float(perimeter.mean()), 1e-9), top / max(tube, 1e-9),
                    flat_area(c[0]) / max(tube, 1e-9))
        aspect, dome_ratio, cap_ratio = _derived(self.bset, f"uv_areas{self.vertex is not None}", compute)
        u_top = float(self.curve_u[-1]) if self.vertex is not None else 1.0
        curve_u = np.asarray(self.curve_u, float)
        if len(curve_u) < 2:
            shear = _derived(self.bset, "uv_shear", lambda: uv_shear(self.bset.curves, curve_u))
            return {"u_top": u_top, "aspect": aspect, "curve_u": curve_u, "shear": shear,
                    "dome_ratio": dome_ratio, "cap_ratio": cap_ratio}

        # The map is a function of the curves' u up to scale (the spline through the curves and the
        # tangents' directions do not change when u is scaled), and the dome's tip rescales u at every
        # approximation or smoothing change: solved on u / u[-1] (rounded to 12 digits, so the key and
        # the result do not depend on the last bits of the scale), its rows scaled back to u.
        span = float(curve_u[-1] - curve_u[0])
        unit_u = np.round((curve_u - curve_u[0]) / span, 12) if span > 0 else curve_u

        density = self.v_density()

        def tube_map():                 # issue 21: near-conformal, even-scale UVs of the tube (mm)
            rings, map_u = uv_map_grid(self.bset.curves, unit_u, v_density=density)
            U, V, W = uv_tube_map(rings, map_u)
            box = (float(U.min()), float(max(U.max(), (U[:, 0] + W).max())), float(V.min()), float(V.max()))
            return (U, V, W), box, map_u
        # keyed by the curves' u too: the paper's patches and the C2 spline place the same curves at other u
        table, box, unit_map_u = _derived(self.bset, f"uv_tube_map{hash(unit_u.tobytes())}", tube_map)
        map_u = curve_u[0] + unit_map_u * span if span > 0 else unit_map_u
        return {"u_top": u_top, "aspect": (box[3] - box[2]) / (box[1] - box[0]), "curve_u": curve_u, "map_u": map_u,
                "shear": None, "tube_map": table, "tube_box": box, "dome_ratio": dome_ratio,
                "cap_ratio": cap_ratio, "v_density": density}

    def solid(self, nu: int, nv: int, nw: int, u_range: tuple[float, float] = (0.0, 1.0),
              v_range: tuple[float, float] = (0.0, TWO_PI), w_range: tuple[float, float] = (0.0, 1.0)) -> Mesh:
        """The boundary of the parametric box of the solid (eq. 23), see :func:`pde_solid.solid_mesh`."""
        from .pde_solid import solid_mesh
        return solid_mesh(self, nu, nv, nw, u_range, v_range, w_range)

    def w_field(self, grid, ct=None, progress=None):
        """The w-field and masked intensity on a voxel grid, see :func:`pde_solid.w_field`."""
        from .pde_solid import w_field
        return w_field(self, grid, ct, progress=progress)

    def __repr__(self) -> str:
        return (f"PDEHead(continuity={self.continuity!r}, patches={self.patches}, spans={self.spans}, "
                f"samples={self.bset.samples}, modes={self.modes}, "
                f"smoothing={np.round(self.smoothing, 4).tolist()}, approximation_mm={self.approximation_mm:g})")


def _fold(a: np.ndarray, nv: int) -> np.ndarray:
    """Complex harmonics (..., H) folded onto the nv//2 + 1 bins of an nv-point real signal (exact at the samples)."""
    H = a.shape[-1]
    nb = nv // 2 + 1
    spec = np.zeros(a.shape[:-1] + (nb,), np.complex128)
    if H <= (nv + 1) // 2:                                                     # no folding, no Nyquist clash
        spec[..., :H] = a
        return spec
    h = np.arange(H)
    m = h % nv
    conj = m > nv // 2
    b = np.where(conj, nv - m, m)
    np.add.at(spec, (Ellipsis, b[~conj]), a[..., ~conj])
    if np.any(conj):
        np.add.at(spec, (Ellipsis, b[conj]), np.conj(a[..., conj]))
    return spec


# ----------------------------------------------------------------------------- solver


def _as_smoothing(smoothing, t: int | None) -> np.ndarray | None:
    """Smoothing as t finite values >= 0 (any 1-D length when t is None)."""
    if smoothing is None:
        return None
    try:
        a = np.asarray(smoothing, dtype=np.float64)
    except (TypeError, ValueError):
        raise PDEError(f"smoothing must be a number or {t} numbers, got {smoothing!r}") from None
    if a.ndim == 0:
        a = np.full(t or 1, float(a))
    if t is None and a.ndim == 1 and a.size >= 1:
        t = a.size
    if a.shape != (t,):
        raise PDEError(f"smoothing must be a number or {t} numbers (one per patch), got shape {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise PDEError(f"smoothing a must be finite and >= 0, got {a.tolist()}")
    return a


def solve_pde(bset: BoundarySet, smoothing: float | Sequence[float] | None = None,
              modes: int | None = None, align: bool = False, continuity: str | None = None,
              approximation_mm: float | None = None, dome: bool = True, remainder: bool = True) -> PDEHead:
    """Solve the Bloor-Wilson PDE surface through the boundary curves (eq. 1-13).

    Parameters
    ----------
    bset : BoundarySet
        3t+1 closed curves, sample m at v = 2 pi m / M (sample 0 = the seam), as
        :func:`extract_boundaries` returns them.
    smoothing : float or sequence of floats, optional
        The smoothing parameter a of eq. 1. ``"c2"``: one value in global u, in
        ``[0, max]`` (:func:`smoothing_range`); default ``DEFAULT_C2_SMOOTHING``
        of the range. ``"paper"``: a number or t numbers (local u of each patch);
        default ``min(H/r, a_stable)`` per patch (module docstring). Values above
        the maximum raise :class:`PDEError`.
    modes : int, optional
        N of eq. 11, in ``[1, M//2]``; default ``M//2`` (R vanishes).
    align : bool
        First re-sample the curves with :func:`align_parameterisation` (same
        polylines, corresponding v); ``head.bset`` is then the aligned set.
    continuity : {"c2", "paper"}, optional
        ``"c2"`` (default): one span per pair of consecutive curves with shared
        u-derivatives, C2 across every curve (:mod:`.pde_spline`). ``"paper"``:
        t patches through four position curves each (eq. 3-6), C0 at the joints.
    approximation_mm : float, optional
        ``"c2"`` only: smoothing length along the head axis (mm) of the
        approximating mode; 0 interpolates every curve exactly. Default:
        :func:`default_approximation` (from the curves' spacing and the scan's
        slice thickness and tilt).
    dome : bool
        ``"c2"`` only: close the crown with a smooth dome through a vertex above
        the top curve (else the surface ends at the top curve).
    remainder : bool
        Keep the remainder R of eq. 11-12 (harmonics above ``modes`` with the
        shared exponent ``omega = a (N+1)``): the surface passes through the curves.
        False drops them: X is the truncated series F of eq. 13, a low-pass around
        every ring (fewer modes: a simpler, smoother head; ``head.curve_deviation``
        says how far it leaves the curves).

    Returns
    -------
    PDEHead

    Raises
    ------
    PDEError
        Bad input (not a BoundarySet, inconsistent knots, out-of-range settings).
    """
    if not isinstance(bset, BoundarySet):
        raise PDEError(f"solve_pde needs a BoundarySet, got {type(bset).__name__}")
    continuity = DEFAULT_CONTINUITY if continuity is None else continuity
    if continuity not in CONTINUITIES:
        raise PDEError(f"continuity must be one of {list(CONTINUITIES)}, got {continuity!r}")
    if align:
        bset = align_parameterisation(bset)                                  # no-op if already aligned
    n_modes = _check_modes(modes, bset.samples)
    keep = None if remainder else n_modes
    if continuity == "c2":
        head = _solve_c2(bset, smoothing, n_modes, approximation_mm, bool(dome), keep)
    else:
        if approximation_mm not in (None, 0, 0.0):
            raise PDEError("approximation_mm needs continuity='c2' (the paper's patches interpolate every curve)")
        head = _solve_paper(bset, smoothing, n_modes, keep)
    head.smoothing_is_default = smoothing is None
    head.remainder = bool(remainder)
    return head


def _curve_positions(bset: BoundarySet) -> np.ndarray:
    """Positions (mm) of the curves along the surface: cumulative mean distance between equal-v points
    of consecutive curves (chord length). The C2 spline's parameter: near the crown, where the
    rings shrink fast over little height, the spans are as long as the surface is, so neither the
    interpolation nor the approximating mode is stiffer there than on the sides of the head."""
    def compute():
        step = np.linalg.norm(np.diff(bset.curves, axis=0), axis=2).mean(axis=1)
        return np.concatenate([[0.0], np.cumsum(np.maximum(step, 1e-6))])
    return _derived(bset, "positions", compute)


def default_approximation(bset: BoundarySet) -> float:
    """Default smoothing length (mm) along u of the approximating mode.

    ``APPROXIMATION_PER_SLICE`` times the scan's axial slice step, but not more than
    ``APPROXIMATION_PER_GAP`` times the mean gap between the chosen curves (few
    curves: keep what they say). Thick or tilted slices step from plane to plane by
    more than the resampled grid's step: there at least ``APPROXIMATION_PER_THICKNESS``
    times the source slices' thickness along z (``thickness / cos(tilt)``), up to one
    gap. The length is measured along the surface (:func:`_curve_positions`).
    """
    meta = bset.meta
    spacing = meta.get("source_slice_step_mm") or (meta.get("spacing") or [0.0])[0]
    gaps = np.abs(np.diff(bset.heights))
    gap = float(gaps.mean()) if gaps.size else 0.0
    value = min(APPROXIMATION_PER_SLICE * float(spacing or 0.0), APPROXIMATION_PER_GAP * gap)
    thickness = float(meta.get("source_slice_thickness_mm") or 0.0)
    if thickness > 0:
        tilt = np.radians(float(meta.get("gantry_tilt_deg") or 0.0))
        value = max(value, min(APPROXIMATION_PER_THICKNESS * thickness / max(np.cos(tilt), 0.1), gap))
    return float(max(0.0, value))


def smoothing_range(bset: BoundarySet) -> tuple[float, float]:
    """``(default, maximum)`` of the C2 smoothing parameter a for this head.

    The isotropic value ``a_iso = Z / r`` (height Z of the head over its mean
    radius r: equal physical rates along u and v, the biharmonic in arc length) is
    the top of the range; the default is ``DEFAULT_C2_SMOOTHING * a_iso``. A
    normalised slider ``f in [0, 1]`` maps to ``a = f * maximum``.
    """
    c = bset.curves
    r = _derived(bset, "radius", lambda: float(np.linalg.norm(c - c.mean(axis=1, keepdims=True), axis=2).mean()))
    z = float(np.ptp(bset.heights)) or 1.0
    a_iso = z / r if r > 0 else 0.0
    return DEFAULT_C2_SMOOTHING * a_iso, a_iso


def _derived(bset: BoundarySet, name: str, compute):
    """A quantity derived from the curves alone, computed once per boundary set.

    The live sliders re-solve the same curves many times; their harmonics, positions and
    radius do not change. A BoundarySet's curves are not modified after it is made (every
    step returns a new set), and the cache sits on the object, so it goes with it.
    """
    cache = bset.__dict__.setdefault("_derived", {})
    key = (name, bset.curves.ctypes.data, bset.curves.shape)
    if key not in cache:
        cache[key] = compute()
    return cache[key]


def _harmonics(bset: BoundarySet, keep: int | None) -> tuple[np.ndarray, bool]:
    """The curves' harmonics (a fresh copy); with ``keep`` only h <= keep (eq. 13's truncated series, no R)."""
    spec, planar = _derived(bset, "harmonics", lambda: curve_harmonics(bset.curves))
    spec = spec.copy()
    if keep is not None:
        spec[:, keep + 1:] = 0.0
    return spec, planar


def control_ranges(bset: BoundarySet, continuity: str | None = None, modes: int | None = None) -> dict:
    """The study's valid ranges of the user controls, for normalised 0-1 sliders.

    Returns
    -------
    dict
        ``"smoothing"``: ``(default, maximum)`` of a (floats for ``"c2"``, per-patch
        arrays for ``"paper"``, from :func:`smoothing_bounds`); ``"approximation_mm"``:
        ``(default, maximum)`` of the approximation length (``"c2"``; ``(0, 0)`` for
        ``"paper"``). Every value in ``[0, maximum]`` solves (no refused values).
    """
    continuity = DEFAULT_CONTINUITY if continuity is None else continuity
    if continuity == "paper":
        return {"smoothing": smoothing_bounds(bset, modes), "approximation_mm": (0.0, 0.0)}
    gaps = np.abs(np.diff(bset.heights))
    return {"smoothing": smoothing_range(bset),
            "approximation_mm": (default_approximation(bset),
                                 APPROXIMATION_MAX_PER_GAP * float(gaps.mean() if gaps.size else 0.0))}


def solve_with_controls(bset: BoundarySet, continuity: str | None = None, smoothing: float | None = None,
                        approximation: float | None = None, modes: int | None = None,
                        dome: bool = True) -> PDEHead:
    """:func:`solve_pde` from normalised controls (what the add-on's sliders hold).

    Parameters
    ----------
    smoothing, approximation : float in [0, 1] or None
        Fractions of :func:`control_ranges`' maxima; None: the solver's defaults.
    modes : int or None
        None or 0: every harmonic (the curves are passed exactly); N > 0: the
        truncated series of eq. 13 with N modes (``remainder=False``), a visibly
        simpler head.
    """
    continuity = DEFAULT_CONTINUITY if continuity is None else continuity
    for name, f in (("smoothing", smoothing), ("approximation", approximation)):
        if f is not None and not (np.isfinite(f) and 0.0 <= f <= 1.0):
            raise PDEError(f"{name} must be a fraction in [0, 1], got {f!r}")
    n = None if not modes else int(modes)
    if n is not None:
        n = min(n, bset.samples // 2)
    ranges = control_ranges(bset, continuity, n)
    a = None if smoothing is None else np.asarray(ranges["smoothing"][1]) * float(smoothing)
    kwargs = dict(smoothing=a, modes=n, continuity=continuity, remainder=n is None)
    if continuity == "c2":
        kwargs.update(dome=dome, approximation_mm=None if approximation is None
                      else float(approximation) * ranges["approximation_mm"][1])
    return solve_pde(bset, **kwargs)


def _solve_c2(bset: BoundarySet, smoothing, n_modes: int, approximation_mm, dome: bool,
              keep: int | None = None) -> PDEHead:
    spec, planar = _harmonics(bset, keep)                                     # (m, H, 3)
    z = _curve_positions(bset)
    default_a, max_a = smoothing_range(bset)
    if smoothing is None:
        a = default_a
    else:
        arr = _as_smoothing(smoothing, None)
        if arr.size != 1 and np.ptp(arr) > 0:
            raise PDEError("continuity='c2' takes one smoothing value for the whole head, "
                           f"got {arr.size} different values")
        a = float(arr.ravel()[0])
        if a > max_a * (1 + 1e-9):
            raise PDEError(f"smoothing a={a:.4g} is above this head's maximum {max_a:.4g} (the isotropic "
                           "height/radius ratio); use a value in [0, that] or the normalised slider")
    L = default_approximation(bset) if approximation_mm is None else approximation_mm
    if not (np.isfinite(L) and L >= 0):
        raise PDEError(f"approximation_mm must be a length >= 0 (mm), got {approximation_mm!r}")
    if L > 0:
        exact_z = spec[:, 0, 2].copy()
        spec = smoothing_spline_values(z, spec, float(L))
        if planar:                                                            # z stays exact per curve
            spec[:, 0, 2] = exact_z
            spec[:, 1:, 2] = 0.0
    vertex = None
    top = z[-1]
    if dome:
        zt = float(bset.curves[-1, :, 2].mean())
        height = dome_height(bset.curves, bset.heights, bset.meta.get("vertex_z"))
        sign = 1.0 if bset.heights[-1] >= bset.heights[0] else -1.0
        vertex = np.array([spec[-1, 0, 0].real, spec[-1, 0, 1].real, zt + sign * height])
        top = z[-1] + float(np.linalg.norm(bset.curves[-1] - vertex, axis=1).mean())
    knots = np.concatenate([z, [top]]) if dome else z
    u = (knots - knots[0]) / (knots[-1] - knots[0])
    exponents, coefficients = c2_spans(spec, u, a, n_modes, pole=vertex)
    if not np.all(np.isfinite(coefficients)):
        raise PDEError("the PDE solution is not finite (degenerate boundary curves or knots?)")
    condition = np.ones(coefficients.shape[0])
    return PDEHead(bset, np.array([a]), n_modes, None, exponents, coefficients, condition, planar,
                   span_edges=u, curve_u=u[:len(z)], continuity="c2", approximation_mm=float(L), vertex=vertex)


def _solve_paper(bset: BoundarySet, smoothing, n_modes: int, keep: int | None = None) -> PDEHead:
    _require_3t_plus_1(bset)
    t = bset.patches
    local = _local_knots(bset)
    spec, planar = _harmonics(bset, keep)                                     # (3t+1, H, 3)
    a = _as_smoothing(smoothing, t)
    if a is None:
        a, _ = _bounds(bset, n_modes, local, spec, want_max=False)
    else:
        _, maximum = _bounds(bset, n_modes, local, spec, want_default=False)
        over = np.nonzero(a > maximum * (1 + 1e-9))[0]
        if over.size:
            k = int(over[0])
            raise PDEError(
                f"smoothing a={a[k]:.4g} is too large for patch {k} with N={n_modes} modes: the surface "
                f"would bulge between the curves (interpolation growth > {MAX_LEBESGUE_GROWTH:g}x the cubic "
                f"one or a departure > {MAX_DEVIATION_MM:g} mm from the a = 0 surface); the maximum there "
                f"is {maximum[k]:.4g}. Lower the smoothing or change the number of modes.")
    H = spec.shape[1]
    h = np.arange(H, dtype=np.float64)
    exponents = a[:, None] * np.minimum(h, n_modes + 1)[None, :]              # R: omega = a (N+1)
    # patches with the same knots and smoothing share their 4x4 systems (uniform slice selections)
    _, first, which = np.unique(np.round(np.column_stack([local, a]), 12), axis=0, return_index=True,
                                return_inverse=True)
    G = basis(exponents[first][:, :, None], local[first][:, None, :])       # (types, H, 4 nodes, 4 basis)
    G_inv = inverse_4x4(G)[which.ravel()]
    G = G[which.ravel()]
    # rhs: the node curves' harmonics, (t, H, 4 nodes, 3)
    rhs = np.stack([spec[3 * k:3 * k + 4] for k in range(t)]).transpose(0, 2, 1, 3)
    coefficients = np.matmul(G_inv, rhs.real) + 1j * np.matmul(G_inv, rhs.imag)
    norm1 = lambda m: np.abs(m).sum(axis=-2).max(axis=-1)                    # noqa: E731 (1-norm)
    condition = (norm1(G) * norm1(G_inv)).max(axis=1)
    if not (np.all(np.isfinite(coefficients)) and np.all(np.isfinite(condition))):
        raise PDEError("the PDE solution is not finite (degenerate boundary curves or knots?)")
    return PDEHead(bset, a, n_modes, local, exponents, coefficients, condition, planar,
                   span_edges=np.arange(t + 1) / t, curve_u=bset.u_knots, continuity="paper")


def ring_points(spec: np.ndarray, nv: int) -> np.ndarray:
    """The rings' points (rows, nv, 3) from their folded Fourier amplitudes ``spec`` (rows, 3, nv//2 + 1):
    ``x_j = a_0 + sum_b (a_b cos + b_b sin)``, as one inverse real FFT (``spec`` is scaled in place)."""
    # irfft weights: x_j = (1/nv)[Y_0 + 2 Re sum Y_b w^bj + Y_{nv/2} (-1)^j]
    spec *= nv / 2.0
    spec[..., 0] *= 2.0
    if nv % 2 == 0:
        spec[..., -1] *= 2.0
    return np.fft.irfft(spec, n=nv, axis=-1).transpose(0, 2, 1)
