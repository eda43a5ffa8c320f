"""In-slice disk morphology with radii in mm, the largest component and hole filling (numpy and scipy only).

The clean-up of the segmentation (:mod:`.mask_cleanup`) opens, closes, erodes and dilates each axial slice
with a disk of a radius in millimetres (anisotropic pixels give an elliptic disk in voxels), built from
shifted copies on rows packed 64 voxels to a word (:mod:`.binary_morphology`).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import ndimage as ndi

from ..core.threads import THREADS, in_slabs
from . import run_labels
from .binary_morphology import PARALLEL_VOXELS, run_steps as _run_steps

__all__ = ["erode_disk", "dilate_disk", "open_disk", "close_disk", "box_opening", "bounding_box",
           "largest_component", "fill_holes_per_slice", "fill_cavities"]


def _shifted_combine(mask: np.ndarray, offsets: Sequence[tuple[int, ...]], erode: bool) -> np.ndarray:
    """AND (erosion) or OR (dilation) of shifted copies of a boolean volume.

    ``offsets`` are (dy, dx) in-slice or (dz, dy, dx); ``out[p] = op(mask[p + o])``.
    Outside the volume counts as True for erosion and False for dilation, so
    neither an opening nor a closing creates or removes anything at the border.
    (The reference of :class:`_Packed`, which does the same on 64 voxels per word.)
    """
    out = mask.copy()
    for offset in offsets:
        offset = (0,) * (3 - len(offset)) + tuple(offset)
        if not any(offset):
            continue
        dst = tuple(slice(max(0, -o), n - max(0, o)) for o, n in zip(offset, mask.shape))
        src = tuple(slice(max(0, o), n - max(0, -o)) for o, n in zip(offset, mask.shape))
        if erode:
            out[dst] &= mask[src]
        else:
            out[dst] |= mask[src]
    return out


def box_opening(mask: np.ndarray, size: Sequence[int]) -> np.ndarray:
    """Opening with a (nz, ny, nx) box (outside is background): the union of all boxes inside ``mask``.

    Erosion by [0, n-1] windows then dilation by [-(n-1), 0] windows, axis by axis.
    """
    pad = [(0, max(0, n - 1)) for n in size]
    padded = np.pad(mask, pad)
    plan = []
    for erode, sign in ((True, 1), (False, -1)):
        for axis, n in enumerate(size):
            unit = tuple(sign if a == axis else 0 for a in range(3))
            plan += [([unit], erode)] * (n - 1)
    out = _run_steps(padded, plan)
    return out[tuple(slice(0, n) for n in mask.shape)]


def _disk_steps(spacing_yx: Sequence[float], radius_mm: float) -> list[list[tuple[int, int]]]:
    """A disk of ``radius_mm`` as a chain of small in-slice footprints (a Minkowski sum).

    An octagon = square (half-widths ay, ax) + diamond (b crosses); the regular
    octagon touching the circle on the axes and the diagonals has a = 0.414 r
    and b = 0.586 r.  Every footprint has at most 5 pixels, so erosion and
    dilation are a few boolean ANDs/ORs of shifted views.
    """
    hy, hx = (float(h) for h in spacing_yx)
    ry, rx = radius_mm / hy, radius_mm / hx
    b = int(round(0.586 * min(ry, rx)))
    ay = max(0, int(round(ry)) - b)
    ax = max(0, int(round(rx)) - b)
    return ([[(-1, 0), (0, 0), (1, 0)]] * ay + [[(0, -1), (0, 0), (0, 1)]] * ax
            + [[(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)]] * b)


def erode_disk(mask: np.ndarray, spacing_yx: Sequence[float], radius_mm: float) -> np.ndarray:
    """In-slice erosion by an (octagonal) disk of ``radius_mm``; AND of shifted packed words."""
    return _run_steps(mask, [(step, True) for step in _disk_steps(spacing_yx, radius_mm)])


def dilate_disk(mask: np.ndarray, spacing_yx: Sequence[float], radius_mm: float) -> np.ndarray:
    """In-slice dilation by an (octagonal) disk of ``radius_mm``; OR of shifted packed words."""
    return _run_steps(mask, [(step, False) for step in _disk_steps(spacing_yx, radius_mm)])


def open_disk(mask: np.ndarray, spacing_yx: Sequence[float], radius_mm: float) -> np.ndarray:
    """In-slice opening: removes what a disk of ``radius_mm`` does not fit in."""
    steps = _disk_steps(spacing_yx, radius_mm)
    return _run_steps(mask, [(step, True) for step in steps] + [(step, False) for step in steps])


def close_disk(mask: np.ndarray, spacing_yx: Sequence[float], radius_mm: float) -> np.ndarray:
    """In-slice closing: bridges gaps narrower than the disk of ``radius_mm``."""
    steps = _disk_steps(spacing_yx, radius_mm)
    return _run_steps(mask, [(step, False) for step in steps] + [(step, True) for step in steps])


def _crop_box(mask: np.ndarray) -> tuple[slice, ...] | None:
    """Bounding box of a 3-D ``mask`` grown by one voxel in y and x (None: empty); the whole array otherwise."""
    if mask.ndim != 3:
        return tuple(slice(0, n) for n in mask.shape)
    return bounding_box(mask, (0, 1, 1))


def largest_component(mask: np.ndarray, structure: np.ndarray | None = None) -> np.ndarray:
    """The largest connected component of a boolean volume (6-connectivity by default).

    6-connectivity (the default) is found on the runs along x (:func:`.run_labels.largest_component`,
    the same voxels as ``ndi.label``'s largest component for a fraction of its time); any other
    ``structure`` is labelled with ``ndi.label``.
    """
    box = _crop_box(mask)
    if box is None:
        return np.zeros(mask.shape, dtype=bool)
    if any(b.stop - b.start < n for b, n in zip(box, mask.shape)):
        out = np.zeros(mask.shape, dtype=bool)  # labels on the mask's bounding box only (same result)
        out[box] = largest_component(np.ascontiguousarray(mask[box]), structure)
        return out
    if structure is None and mask.ndim == 3:
        return run_labels.largest_component(mask)
    labels, n = ndi.label(mask, structure=structure)
    if n == 0:
        return np.zeros(mask.shape, dtype=bool)
    if n == 1:
        return labels == 1
    counts = np.bincount(labels[mask], minlength=n + 1)
    counts[0] = 0
    return labels == np.argmax(counts)


def fill_holes_per_slice(mask: np.ndarray) -> np.ndarray:
    """Fill every background region that does not reach the border of its axial slice.

    This is a superset of the 3-D hole filling (a 3-D cavity never reaches a slice
    border), and also closes the nasal cavity, mouth and ear canals in the slices
    where they are enclosed although they open to the outside in 3-D.
    The background's runs along x are linked within each slice
    (:func:`.run_labels.fill_holes_per_slice`; the same as labelling each slice's background).
    """
    if mask.ndim == 2:
        return fill_holes_per_slice(mask[None])[0]
    nz = mask.shape[0]
    if mask.size < PARALLEL_VOXELS or THREADS < 2 or nz < 2:
        return run_labels.fill_holes_per_slice(mask)
    # large volumes: two slabs of slices in threads (the slices are independent: the same result)
    out = np.empty(mask.shape, dtype=bool)

    def slab(a: int, b: int) -> None:
        out[a:b] = run_labels.fill_holes_per_slice(mask[a:b])

    in_slabs(nz, slab)
    return out


def fill_cavities(mask: np.ndarray, spacing_yx: Sequence[float], radius_mm: float = 4.0) -> np.ndarray:
    """The filled outer envelope: holes and cavities whose opening is narrower than ~2 ``radius_mm``.

    Per axial slice: a closing with a ``radius_mm`` disk seals narrow openings
    (nostrils, a parted mouth, ear canals, metal-streak gaps); the regions it
    encloses are added together with the closing's bridges that seal them,
    while what the closing adds elsewhere (in concave bends of the outline) is
    not, so the skin outline itself is kept.  Finally every hole is filled per
    slice (a superset of the 3-D holes).
    """
    closed = close_disk(mask, spacing_yx, radius_mm)
    cavities = fill_holes_per_slice(closed)
    np.greater(cavities, closed, out=cavities)                   # filled & ~closed (in place: fewer passes)
    seals = dilate_disk(cavities, spacing_yx, radius_mm)
    np.greater(closed, mask, out=closed)                         # closed & ~mask
    seals &= closed
    del closed
    seals |= cavities
    seals |= mask
    return fill_holes_per_slice(seals)


def bounding_box(mask: np.ndarray, margin: Sequence[int]) -> tuple[slice, ...] | None:
    """Slices of the bounding box of ``mask`` grown by ``margin`` voxels per axis."""
    box = []
    for axis in range(mask.ndim):
        other = tuple(a for a in range(mask.ndim) if a != axis)
        nonzero = np.flatnonzero(mask.any(axis=other))
        if nonzero.size == 0:
            return None
        lo = max(0, int(nonzero[0]) - margin[axis])
        hi = min(mask.shape[axis], int(nonzero[-1]) + 1 + margin[axis])
        box.append(slice(lo, hi))
    return tuple(box)
