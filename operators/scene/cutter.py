"""An interactive cutter: a box empty the user moves, rotates and scales; the solid is cut away where it is.

The solid of a study is one parametric box of eq. 23 (u, v and w ranges, Fig. 14), so a cutter
maps to ranges: the surface and two inner shells are sampled on a (u, v) grid and every (u, v)
column with a sample inside the cutter box is *hit*. Two cuts remove all hit columns:

- a **wedge** in v (Fig. 14b): the solid keeps the longest run of un-hit v columns (all u);
- a **slab** in u (the top or the bottom off, Fig. 14a): it keeps the longest run of un-hit u rows.

The one that keeps more of the head is applied (w is left as the user set it). A box at the side
of the head therefore cuts a wedge, a box over the crown takes the top off, and a box away from
the head restores the whole solid. A ``depsgraph_update_post`` handler applies the cutter whenever
its transform changes (moving it in the viewport, from Python, or during playback), and only then,
so an unchanged scene costs one comparison per study.
"""
from __future__ import annotations

import math

import bpy
import numpy as np
from mathutils import Matrix

from ...pdehead_addon import PDEHeadError, surface_grid_cached
from .. import state
from ..state import suspended_updates
from . import render

CUTTER_KIND = "cutter"
SAMPLES_U, SAMPLES_V = 64, 128
SHELLS = (1.0, 0.85)  # w of the sampled shells (near the spine every v is close: inner shells would over-cut)
TWO_PI = 2.0 * math.pi


def _longest_run(free: np.ndarray, circular: bool) -> tuple[int, int] | None:
    """(first, last) index of the longest run of True (wrapping around when `circular`), or None."""
    n = len(free)
    if not free.any():
        return None
    if free.all():
        return (0, n - 1)
    x = np.concatenate([free, free]) if circular else free
    best, start = (0, 0, 0), None
    for i, f in enumerate(x):  # <= 256 entries: one pass over the sample columns, not over voxels
        if f and start is None:
            start = i
        if (not f or i == len(x) - 1) and start is not None:
            end = i if f else i - 1
            length = min(end - start + 1, n)
            if length > best[0]:
                best = (length, start, start + length - 1)
            start = None
    return best[1], best[2]


def cutter_ranges(head, inverse_matrix_mm: np.ndarray, size: float):
    """The (u_range, v_range) that cut away what a box cutter covers (see the module docstring).

    Parameters
    ----------
    head : PDEHead
    inverse_matrix_mm : (4, 4)
        Patient LPS mm -> the cutter's local coordinates (the cube empty spans +-`size`).
    size : float
        Half edge of the cutter box in its local units (``empty_display_size``).

    Returns
    -------
    (u_range, v_range, kept_fraction, kind) with kind "none", "wedge" or "slab".
    """
    u = np.linspace(0.0, 1.0, SAMPLES_U)
    v = TWO_PI * np.arange(SAMPLES_V) / SAMPLES_V
    if hasattr(head, "_grid"):  # the solid's cached grid synthesis (inverse FFT): same points, ~50x faster
        surface = surface_grid_cached(head, u, v, SAMPLES_V)              # (nu, nv, 3)
    else:
        surface = head.evaluate(u[:, None], v[None, :], 1.0)
    spine = head.spine(u)[:, None, :]
    hit = np.zeros((SAMPLES_U, SAMPLES_V), bool)
    for w in SHELLS:
        pts = spine + w * (surface - spine)
        local = pts.reshape(-1, 3) @ inverse_matrix_mm[:3, :3].T + inverse_matrix_mm[:3, 3]
        hit |= np.all(np.abs(local) <= size, axis=1).reshape(SAMPLES_U, SAMPLES_V)
    if not hit.any():
        return (0.0, 1.0), (0.0, TWO_PI), 1.0, "none"
    wedge = _longest_run(~hit.any(axis=0), circular=True)
    slab = _longest_run(~hit.any(axis=1), circular=False)
    # a kept range needs two samples at least (start < end)
    kept_wedge = 0.0 if wedge is None or wedge[1] <= wedge[0] else (wedge[1] - wedge[0] + 1) / SAMPLES_V
    kept_slab = 0.0 if slab is None or slab[1] <= slab[0] else (slab[1] - slab[0] + 1) / SAMPLES_U
    if max(kept_wedge, kept_slab) == 0.0:
        raise PDEHeadError("the cutter covers the whole head: nothing would be left of the solid")
    if kept_wedge >= kept_slab:
        j0, j1 = wedge
        return (0.0, 1.0), (float(v[0] + TWO_PI * j0 / SAMPLES_V), float(TWO_PI * j1 / SAMPLES_V)), \
            kept_wedge, "wedge"
    i0, i1 = slab
    return (float(u[i0]), float(u[i1])), (0.0, TWO_PI), kept_slab, "slab"


def cutter_of(coll):
    for obj in coll.objects:
        if obj.get("pdehead_kind") == CUTTER_KIND:
            return obj
    return None


def signature(obj, matrix=None) -> tuple:
    """The cutter's transform (``matrix``, default its own) and size: the handlers re-apply the cutter
    when it changes."""
    matrix = obj.matrix_world if matrix is None else matrix
    return tuple(round(float(x), 7) for row in matrix for x in row) + (float(obj.empty_display_size),)


def add_cutter(context, coll):
    """A box empty at the front-left quarter of the head (a Fig. 14b wedge), through its whole height."""
    s = state.settings(coll)
    shown = next((o for o in (s.solid_object, s.surface_object) if o is not None), None)
    if shown is None:
        raise PDEHeadError(f"study '{coll.name}' has no solid yet: build it first")
    cutter = cutter_of(coll)
    if cutter is None:
        cutter = bpy.data.objects.new(f"{coll.name} Cutter", None)
        cutter["pdehead_kind"] = CUTTER_KIND
        cutter.empty_display_type = "CUBE"
        cutter.show_in_front = True
        cutter.hide_render = True
        coll.objects.link(cutter)
    lo, hi = render.world_bounds([shown])
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    # the patient's left (+x) and the face (-y): the quarter a Fig. 14b cutaway opens
    box_centre = centre + np.array([0.6 * half[0], -0.6 * half[1], 0.0])
    box_half = np.array([0.5 * half[0], 0.5 * half[1], 1.1 * half[2]])
    cutter.empty_display_size = 1.0
    cutter.matrix_world = Matrix.Translation(box_centre) @ Matrix.Diagonal((*box_half, 1.0))
    with suspended_updates():
        s.use_cutter = True
    context.view_layer.update()
    return cutter
