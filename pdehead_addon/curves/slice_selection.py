"""Slice selection: which slices give the boundary curves (paper sections 4.1 and 6).

Named strategies (:data:`SELECTION_STRATEGIES`, :func:`register_selection`): ``"uniform"``
(:func:`select_uniform`) and ``"shape-change"`` (:func:`select_shape_change`) choose among the
*usable* slices (:func:`usable_slices`), never a slice whose outline is the edge of the scan
(:func:`scan_edge_slices`). The automatic choice, ``"auto"`` (the curves whose PDE surface best
follows every slice), is :mod:`.auto_selection`.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
from scipy import ndimage

from ..core.errors import BoundaryError

#: Largest share of a slice's outline that may be the edge of the scanned slab (tilted series).
MAX_SCAN_EDGE_FRACTION = 0.1
#: Default fraction of the largest slice area below which a slice counts as degenerate.
MIN_AREA_FRACTION = 0.05

SelectionFunc = Callable[..., Sequence[int]]


# --------------------------------------------------------------------------- named strategies
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

    cross = ndimage.generate_binary_structure(2, 1)[None]  # in-plane neighbours only: eq. 22 per slice
    near_edge = ~ndimage.binary_erosion(np.asarray(coverage, bool), structure=cross, border_value=1)
    ring = mask & ~ndimage.binary_erosion(mask, structure=cross, border_value=0)
    ring_px = np.count_nonzero(ring, axis=(1, 2))
    at_edge = np.count_nonzero(ring & near_edge, axis=(1, 2))
    return at_edge > max_fraction * np.maximum(ring_px, 1)
