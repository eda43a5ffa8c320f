"""Where the v columns of the head's tube sit: closer in v where an outline runs radially.

:func:`column_density` (a function of the boundary curves alone, one per study) warps the columns' v so
that no step of v carries a capped end curve much further than its mean sample step; :func:`column_v`
gives the nv columns' v, :func:`column_fraction` and :func:`column_fraction_inverse` map between v and the
columns' fraction. Used by the surface mesh (:mod:`.surface_mesh`), its UV map (:mod:`.surface_uv_map`) and
the solved head (:mod:`.pde_head`).
"""
from __future__ import annotations

import numpy as np

__all__ = ["column_density", "column_v", "column_fraction", "column_fraction_inverse", "V_STEP_LIMIT"]

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
