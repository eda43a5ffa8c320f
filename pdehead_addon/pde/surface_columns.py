"""Where the v columns (and the u rows) of the head's tube sit: closer where an outline runs radially or
the surface bends tightly.

:func:`column_density` (a function of the boundary curves alone, one per study) warps the columns' v so
that no step of v carries a capped end curve much further than its mean sample step; :func:`column_v`
gives the nv columns' v, :func:`column_fraction` and :func:`column_fraction_inverse` map between v and the
columns' fraction. :func:`normal_turning`, :func:`bend_rows` and :func:`bend_column_density` place a mesh's
rows and columns where the surface's normal turns fastest (under the ears, at the jaw), so a coarse mesh
has no edge creased far beyond the smooth surface's own bend. Used by the surface mesh
(:mod:`.surface_mesh`), its UV map (:mod:`.surface_uv_map`) and the solved head (:mod:`.pde_head`).
"""
from __future__ import annotations

import numpy as np

__all__ = ["column_density", "column_v", "column_fraction", "column_fraction_inverse", "V_STEP_LIMIT",
           "normal_turning", "surface_turning", "bend_rows", "bend_column_density", "BEND_ROW_SHARE",
           "BEND_COLUMN_SHARE"]

TWO_PI = 2.0 * np.pi


#: The surface's columns: no step of v may carry the capped end curve further than this many times its
#: mean sample step. Where an outline runs nearly radially (a wide neck) equal steps of the angular
#: parameter v are long on the surface (several mean edges of the tube), and so is every cap triangle on
#: them; there the columns are placed closer in v (:func:`column_density`). 1.5 shortens those edges most
#: while the UVs' angle distortion stays within its limit (tighter values cost angle; the measures:
#: docs/benchmarks.md, the face up close).
V_STEP_LIMIT = 1.5


def column_density(curves: np.ndarray, limit: float = V_STEP_LIMIT) -> np.ndarray | None:
    """How densely the surface's columns sample each step ``v_k -> v_k+1`` of the curves' M samples, shape
    (M,): ``max(1, longest step of any curve there / (limit * the curves' mean step))``; None when that is 1
    everywhere (equal steps of v). A function of the boundary curves alone (one per study): nu, nv and the
    shape sliders keep it, so the columns' v and hence the UVs stay put."""
    c = np.asarray(curves, float)
    e = np.linalg.norm(np.roll(c, -1, axis=1) - c, axis=-1)                 # (n, M): step k -> k + 1
    d = np.maximum(1.0, e.max(axis=0) / (float(limit) * max(float(e.mean()), 1e-12)))
    return None if np.all(d <= 1.0) else d


def column_v(density: np.ndarray | None, nv: int) -> np.ndarray:
    """The v of nv columns spaced by ``density`` (:func:`column_density`): column j at the fraction j / nv of
    the density's integral over the turn (piecewise linear), so v_0 = 0 and the columns increase."""
    return TWO_PI * column_fraction_inverse(density, np.arange(nv) / nv)


def column_fraction_inverse(density: np.ndarray | None, s: np.ndarray) -> np.ndarray:
    """v / 2 pi at the column fraction s (:func:`column_v` at any s in [0, 1])."""
    s = np.asarray(s, float)
    if density is None:
        return s
    M = len(density)
    G = np.concatenate([[0.0], np.cumsum(density)])
    return np.interp(s, G / G[-1], np.arange(M + 1) / M)


def column_fraction(density: np.ndarray | None, v: np.ndarray) -> np.ndarray:
    """The inverse of :func:`column_v`: the column fraction s in [0, 1] at v (radians, in [0, 2 pi])."""
    v = np.asarray(v, float)
    if density is None:
        return v / TWO_PI
    M = len(density)
    G = np.concatenate([[0.0], np.cumsum(density)])
    return np.interp(v, TWO_PI * np.arange(M + 1) / M, G / G[-1])


#: The share of a bend-fitted mesh's rows (:func:`bend_rows`) and columns (:func:`bend_column_density`)
#: placed by the surface's normal turning; the rest stay evenly spaced (in u; in v, the head's own column
#: density), so a head without tight bends keeps about its even mesh. Chosen on CThead and GE at the
#: viewport's 120 x 240: the smallest of the shares tried (0.2-1.0) with no edge bending by more than 60 deg
#: off the bottom ring on either (docs/benchmarks.md, the face up close, "Slits").
BEND_ROW_SHARE = 0.65
BEND_COLUMN_SHARE = 0.7


def normal_turning(points: np.ndarray, u: np.ndarray, skip_first_row: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """How far the surface's unit normal turns between neighbouring samples of a grid of its points.

    Parameters
    ----------
    points : ndarray, shape (K, M, 3)
        Surface points on rows ``u`` (increasing) and M evenly spaced, periodic columns.
    u : ndarray, shape (K,)
        The rows' parameter.
    skip_first_row : bool
        Leave the first row (the capped bottom ring, where the tube meets its disc) out of the columns'
        measure.

    Returns
    -------
    turn_u : ndarray, shape (K - 1,)
        The largest turning (degrees) over the columns between rows k and k + 1.
    turn_v : ndarray, shape (M,)
        The largest turning (degrees) over the rows between columns j and j + 1 (mod M).

    Rows whose ring has collapsed (a dome's pole: mean radius about its centre under 5 % of the median)
    have no normal and count 0. The normal is the cross product of central differences (in u:
    ``numpy.gradient``; in v: the neighbouring columns).
    """
    P = np.asarray(points, float)
    u = np.asarray(u, float)
    tu = np.gradient(P, u, axis=0)
    tv = np.roll(P, -1, axis=1) - np.roll(P, 1, axis=1)
    n = np.cross(tu, tv)
    n /= np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-300)
    radius = np.linalg.norm(P - P.mean(axis=1, keepdims=True), axis=2).mean(axis=1)
    flat = radius < 0.05 * np.median(radius)
    along_u = np.degrees(np.arccos(np.clip((n[1:] * n[:-1]).sum(axis=2), -1.0, 1.0)))
    along_u[flat[1:] | flat[:-1]] = 0.0
    along_v = np.degrees(np.arccos(np.clip((np.roll(n, -1, axis=1) * n).sum(axis=2), -1.0, 1.0)))
    along_v[flat] = 0.0
    if skip_first_row:
        along_v[0] = 0.0
    return along_u.max(axis=1), along_v.max(axis=0)


def surface_turning(head, rows: int = 961, column_rows: int = 481, oversample: int = 4):
    """(fine rows u, the normal's turning along u between them, its turning along v between ``oversample
    x samples`` fine columns): :func:`normal_turning` of ``head``'s surface (``surface_points``) on ``rows`` x
    ``samples`` points for u and ``column_rows`` x ``oversample x samples`` for v, ``samples`` being its
    curves' count of samples."""
    M = int(head.bset.curves.shape[1])
    fine_u = np.linspace(0.0, 1.0, int(rows))
    turn_u = normal_turning(head.surface_points(fine_u, M), fine_u)[0]
    coarse_u = np.linspace(0.0, 1.0, int(column_rows))
    return fine_u, turn_u, normal_turning(head.surface_points(coarse_u, int(oversample) * M), coarse_u)[1]


def bend_rows(turn_u: np.ndarray, u: np.ndarray, nu: int, share: float = BEND_ROW_SHARE) -> np.ndarray:
    """The u of ``nu`` rows (0 and 1 included, increasing) that equidistribute ``(1 - share)`` x even
    spacing plus ``share`` x the normal's turning ``turn_u`` between the fine rows ``u``
    (:func:`normal_turning`): rows close together where the surface bends tightly along u.

    This is de Boor's equidistribution of a monitor function along a curve (C. de Boor, "Good
    approximation by splines with variable knots II", Lecture Notes in Mathematics 363, Springer 1974,
    pp. 12-20), the monitor being the blend above.
    """
    u = np.asarray(u, float)
    turn = np.asarray(turn_u, float)
    even = np.diff(u) / (u[-1] - u[0])
    total = float(turn.sum())
    weight = even if total <= 0.0 else (1.0 - share) * even + share * turn / total
    cdf = np.concatenate([[0.0], np.cumsum(weight)])
    rows = np.interp(np.linspace(0.0, 1.0, int(nu)), cdf / cdf[-1], u)
    rows[0], rows[-1] = u[0], u[-1]
    return rows


def bend_column_density(turn_v: np.ndarray, density: np.ndarray | None,
                        share: float = BEND_COLUMN_SHARE) -> np.ndarray | None:
    """A column density (:func:`column_v`) over the ``len(turn_v)`` equal steps of v: ``(1 - share)`` x the
    head's own ``density`` (:func:`column_density`, None = even) plus ``share`` x the normal's turning
    ``turn_v`` (:func:`normal_turning`), each as a fraction of its turn; mean 1. None when the surface
    does not turn and the density is None. ``len(turn_v)`` must be a multiple of ``len(density)``."""
    turn = np.asarray(turn_v, float)
    F = len(turn)
    base = np.ones(F) if density is None else np.repeat(np.asarray(density, float), F // len(density))
    if len(base) != F:
        raise ValueError(f"{F} steps of v are not a multiple of the density's {len(density)}")
    total = float(turn.sum())
    if total <= 0.0:
        return None if density is None else base / base.mean()
    d = (1.0 - share) * base / base.sum() + share * turn / total
    return d / d.mean()
