"""The smoothing parameter a of the paper's PDE patches (eq. 1): how large it may be, per patch.

Used by the paper's four-curve patches (``solve_pde(continuity="paper")``, :mod:`.pde_surface`): the
default a of each patch and the largest value accepted (:func:`smoothing_bounds`), from the Lebesgue
constant of the patch's 4x4 interpolation (:func:`lebesgue_constant`) and the surface's departure
from the a = 0 (cubic) solution.

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
"""
from __future__ import annotations

from functools import lru_cache
from typing import Sequence

import numpy as np

from ..core.boundary_set import BoundarySet
from ..core.errors import PDEError
from .pde_basis import basis, curve_harmonics

__all__ = ["lebesgue_constant", "smoothing_bounds", "smoothing_limits", "check_modes", "local_knots",
           "require_3t_plus_1", "DEFAULT_LEBESGUE_GROWTH", "MAX_LEBESGUE_GROWTH", "DEFAULT_DEVIATION_MM",
           "MAX_DEVIATION_MM"]

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


def require_3t_plus_1(bset: BoundarySet) -> None:
    if not bset.is_3t_plus_1:
        raise PDEError(f"continuity='paper' needs 3t+1 curves (four per patch, shared ends), got "
                       f"{bset.curves.shape[0]}; use the default continuity='c2' for any count")


def local_knots(bset: BoundarySet) -> np.ndarray:
    """Per-patch knots ``(0, p1, p2, 1)`` in local s, shape (t, 4); validates ``bset.u_knots``."""
    require_3t_plus_1(bset)
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


def check_modes(modes: int | None, samples: int) -> int:
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


def smoothing_limits(bset: BoundarySet, n_modes: int, local: np.ndarray, spec: np.ndarray,
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
    n = check_modes(modes, bset.samples)
    spec, _ = curve_harmonics(bset.curves)
    return smoothing_limits(bset, n, local_knots(bset), spec)
