"""Clean-up of the thresholded membership: what the paper does after eq. 21, and more.

The paper keeps the largest connected component and fills its holes; real
scans also need what touches the head but is not head removed (pillows, cloth,
table tops, head holders, metal streaks) and the neck cut when the scan reaches
the shoulders.  The in-slice disk morphology with radii in mm is :mod:`.disk_morphology`.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from scipy import ndimage as ndi

from ..core.errors import SegmentationError, report_progress
from ..core.threads import THREADS, in_slabs
from . import run_labels
from .binary_morphology import PARALLEL_VOXELS
from .disk_morphology import (
    bounding_box,
    box_opening,
    close_disk,
    fill_cavities,
    fill_holes_per_slice,
    largest_component,
    open_disk,
)

#: 4-connectivity inside each axial slice, no links between slices (per-slice 2-D labelling).
_IN_SLICE = np.zeros((3, 3, 3), dtype=bool)
_IN_SLICE[1] = ndi.generate_binary_structure(2, 1)


#: :func:`find_cushion`'s lower bound of a cushion's windowed intensity (darker: a gap, not a pillow).
CUSHION_LOW = 0.4


def estimate_noise(img: np.ndarray, max_samples: int = 1_000_000) -> float:
    """Standard deviation of white noise in ``img`` from neighbour differences (robust MAD).

    Most pairs of x-neighbours lie in flat regions (air, brain), where their
    difference is noise with standard deviation ``sqrt(2) * sigma``; the median
    absolute difference ignores the edges.
    """
    step = _noise_row_step(img.shape, max_samples)
    return _noise_of_rows(img.reshape(-1, img.shape[2])[::step])


def _noise_row_step(shape: Sequence[int], max_samples: int = 1_000_000) -> int:
    """:func:`estimate_noise` reads every this many x-rows of a (z, y, x) volume."""
    return max(1, shape[0] * shape[1] // max(1, max_samples // max(1, shape[2])))


def _noise_of_rows(rows: np.ndarray) -> float:
    """:func:`estimate_noise` of the sampled x-rows (2-D)."""
    diff = np.abs(np.diff(rows, axis=1)).ravel()
    diff = diff[diff > 0] if np.count_nonzero(diff) > diff.size // 2 else diff
    return float(np.median(diff) / (0.6745 * math.sqrt(2.0))) if diff.size else 0.0


def smoothing_sigma(noise: float, target: float = 0.03, ndim: int = 3) -> float:
    """Gaussian sigma (voxels) bringing white noise of std ``noise`` down to about ``target``.

    For a normalised Gaussian of standard deviation s voxels in d dimensions the
    noise std is multiplied by ``(2 sqrt(pi) s)^(-d/2)``; 0 (no smoothing) when
    the noise is already below ``target``, else at least 0.5 voxel.
    """
    if noise <= target:
        return 0.0
    return max(0.5, (noise / target) ** (2.0 / ndim) / (2.0 * math.sqrt(math.pi)))


def _component_extents(labels: np.ndarray, n: int, spacing_yx: Sequence[float],
                       objects: list | None = None) -> np.ndarray:
    """In-slice bounding-box diagonal (mm) of every label 1..n (index 0 unused); ``objects``:
    ``ndi.find_objects(labels)`` when the caller has it already."""
    dy, dx = spacing_yx
    extent = np.zeros(n + 1)
    for index, sl in enumerate(ndi.find_objects(labels) if objects is None else objects, start=1):
        if sl is not None:
            extent[index] = math.hypot((sl[1].stop - sl[1].start) * dy, (sl[2].stop - sl[2].start) * dx)
    return extent


def tissue_envelope(tissue: np.ndarray, spacing_yx: Sequence[float], opening_mm: float = 2.5,
                  close_mm: float = 3.0) -> np.ndarray:
    """Filled per-slice envelope of the head's own tissue.

    The largest 3-D component of ``tissue`` after an in-slice opening with an
    ``opening_mm`` disk (which drops table tops, holder arcs and cloth), closed
    with a ``close_mm`` disk (bridging nostrils and metal-streak gaps) and with
    every hole filled per slice.
    """
    core = largest_component(open_disk(tissue, spacing_yx, opening_mm))
    return fill_holes_per_slice(close_disk(core, spacing_yx, close_mm))


def find_cushion(mask: np.ndarray, smooth: np.ndarray, spacing: Sequence[float], envelope: np.ndarray,
                 level: float = 0.85, thickness_mm: float = 2.0, low: float = CUSHION_LOW) -> np.ndarray:
    """Voxels of ``mask`` that belong to a pillow or foam layer pressed against the head.

    A pillow or cloth pressed against the head is denser than air but clearly
    less dense than skin, fat and muscle; where it is compressed enough to pass
    the air/skin decision it forms a layer of intermediate intensity several mm
    thick *outside* the skin.  The partial-volume rim of a real skin surface is
    as dark but only about a point-spread width thick.  So the cushion is the
    intermediate part of the mask (windowed intensity ``smooth`` between
    ``low`` and ``level``) that

    (a) contains a box spanning at least ``thickness_mm`` along each axis (a
        morphological opening; a skin band of normal thickness t only holds
        such a box when t > thickness_mm / sqrt(2), whatever its orientation,
        so the grazing cut of the vertex is spared), and
    (b) lies outside ``envelope``, the envelope of the head's tissue
        (:func:`tissue_envelope` of the voxels ``>= level``), so intermediate
        regions enclosed by skin (metal-streak shadows, sinus walls) are never
        cushion.

    Darker voxels in the mask are narrow gaps the TV term bridged (between an
    ear and the scalp), not cushion either.  Returns a subset of ``mask``.
    """
    band = mask & (smooth < np.float32(level)) & (smooth > np.float32(low)) & ~envelope
    return _cushion_of_band(band, spacing, thickness_mm)


def _cushion_of_band(band: np.ndarray, spacing: Sequence[float], thickness_mm: float) -> np.ndarray:
    """:func:`find_cushion`'s opening of its candidate ``band`` (intermediate, in the mask, outside the envelope)."""
    dz, dy, dx = (float(h) for h in spacing)
    size = tuple(min(n, max(2, 1 + math.ceil(thickness_mm / h))) for n, h in zip(band.shape, (dz, dy, dx)))
    return box_opening(band, size)


def _windowed(values: np.ndarray, window: tuple[float, float]) -> np.ndarray:
    """The clean-up's windowed intensity ``(values - low) * (1 / (high - low))`` in float32."""
    low, high = window
    out = np.subtract(values, np.float32(low), dtype=np.float32)
    out *= np.float32(1.0 / (high - low))
    return out


def _first_passing(dtype: np.dtype, window: tuple[float, float], level: float, strict: bool):
    """The smallest value v of ``dtype`` whose windowed intensity is >= ``level`` (> when ``strict``);
    None when no value passes. The windowing is monotone (float32 rounding is), so the values that
    pass are exactly those >= v: found among the 8/16-bit integers by tabulating them all, among the
    float32 values by bisection on their order."""
    level = np.float32(level)

    def passes(v):
        w = _windowed(np.asarray(v, dtype=dtype), window)
        return (w > level) if strict else (w >= level)

    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        ok = np.flatnonzero(passes(np.arange(info.min, info.max + 1, dtype=np.int64).astype(dtype)))
        return None if ok.size == 0 else dtype.type(info.min + int(ok[0]))
    # float32: the finite values in order are the int32 keys k -> bits (k >= 0) or ~bits of -v (k < 0)
    def value(k: int) -> np.float32:
        bits = np.array(k if k >= 0 else -k, dtype=np.int32).view(np.float32)
        return np.float32(bits if k >= 0 else -bits)

    big = int(np.array(np.finfo(np.float32).max, dtype=np.float32).view(np.int32))
    lo, hi = -big, big
    if not passes(value(hi)):
        return np.float32(np.inf) if passes(np.float32(np.inf)) else None
    if passes(value(lo)):
        return value(lo)
    while hi - lo > 1:                                   # passes(value(hi)) and not passes(value(lo))
        mid = (lo + hi) // 2
        if passes(value(mid)):
            hi = mid
        else:
            lo = mid
    return value(hi)


def _windowed_range(raw: np.ndarray, window: tuple[float, float], above: tuple[float, bool] | None,
                    below: float | None) -> np.ndarray | None:
    """``windowed >= above[0]`` (``>`` when ``above[1]``) and ``windowed < below`` without the float volume.

    ``windowed`` is :func:`_windowed` of ``raw``, as the clean-up computes it; since the windowing is
    monotone each bound is one comparison of the raw values with the first value that passes
    (:func:`_first_passing`): voxel for voxel what the float volume gives, without its 4 bytes per
    voxel and the time to fill them. For 8/16-bit integers and float32; None for other data types.
    """
    dtype = raw.dtype
    if not ((dtype.kind in "iu" and dtype.itemsize <= 2) or dtype == np.float32):
        return None
    if raw.ndim == 3 and raw.size >= PARALLEL_VOXELS and THREADS > 1 and raw.shape[0] >= THREADS:
        # large volumes: slabs of slices in threads (element-wise: the same result)
        out = np.empty(raw.shape, dtype=bool)

        def slab(a: int, b: int) -> None:
            out[a:b] = _windowed_range_serial(raw[a:b], window, above, below)

        in_slabs(raw.shape[0], slab)
        return out
    return _windowed_range_serial(raw, window, above, below)


def _windowed_range_serial(raw: np.ndarray, window: tuple[float, float], above: tuple[float, bool] | None,
                           below: float | None) -> np.ndarray:
    """:func:`_windowed_range` in the calling thread (``raw`` of a supported data type)."""
    dtype = raw.dtype
    out = None
    if above is not None:
        first = _first_passing(dtype, window, above[0], above[1])
        if first is None:
            return np.zeros(raw.shape, dtype=bool)
        out = raw >= first
    if below is not None:
        first = _first_passing(dtype, window, below, False)  # the values below it are < below
        if first is not None:
            if out is None:
                out = raw < first
            else:
                out &= raw < first
        elif out is None:
            out = ~np.isnan(raw) if dtype.kind == "f" else np.ones(raw.shape, dtype=bool)
    return out


def metal_slices(data: np.ndarray, window: tuple[float, float], level: float = 3.0,
                 min_pixels: int = 3) -> np.ndarray:
    """Per-slice metal masks: windowed intensity above ``level`` (bool, same shape as ``data``).

    With air at 0 and soft tissue at 1, bone lies at about 1.5-2.5 (1100-1900 HU) and dental metal
    saturates the scanner's range (3071 HU = 3.9; CThead's fillings 3.1). Slices with fewer than
    ``min_pixels`` such pixels count as metal-free (all False).
    """
    low, high = window
    metal = data > np.float32(low + level * (high - low))
    few = np.count_nonzero(metal, axis=(1, 2)) < min_pixels
    metal[few] = False
    return metal


def streak_components(labels: np.ndarray, n: int, metal: np.ndarray, spacing_yx: Sequence[float],
                      alignment: float = 0.85, elongation: float = 2.0, objects: list | None = None,
                      sizes: np.ndarray | None = None) -> np.ndarray:
    """Which labelled thin components (1..n) are metal streaks: long and pointing at the metal.

    A streak is a ray from a dense insert: a component in a slice with metal whose in-plane
    principal axis (of its pixel positions in mm) is at least ``elongation`` times longer than
    its width and makes ``|cos| >= alignment`` with the direction from the nearest metal pixel
    to the component's centroid. Lips and ear rims run along the skin, across such rays.
    Returns a bool array of length n + 1 (index 0 False). ``objects`` (``ndi.find_objects(labels)``)
    and ``sizes`` (voxels per label, index >= 1) may be passed when the caller has them already.
    """
    out = np.zeros(n + 1, dtype=bool)
    if not n or not metal.any():
        return out
    dy, dx = (float(h) for h in spacing_yx)
    has_metal = metal.any(axis=(1, 2))
    if sizes is None:
        sizes = np.bincount(labels.reshape(-1), minlength=n + 1)
    metal_points: dict[tuple[int, int], np.ndarray] = {}
    for index, sl in enumerate(ndi.find_objects(labels) if objects is None else objects, start=1):
        if sl is None or sizes[index] < 3:
            continue
        ks = np.flatnonzero(has_metal[sl[0]]) + sl[0].start
        if ks.size == 0:
            continue
        kk, jj, ii = np.nonzero(labels[sl] == index)
        pts = np.stack([(jj + sl[1].start) * dy, (ii + sl[2].start) * dx], axis=1)
        centre = pts.mean(axis=0)
        cov = np.cov((pts - centre).T)
        evals, evecs = np.linalg.eigh(cov)
        if evals[0] > 0 and math.sqrt(evals[1] / evals[0]) < elongation:
            continue                                   # not elongated (a straight line has evals[0] = 0)
        key = (sl[0].start, sl[0].stop)
        if key not in metal_points:     # the metal of these slices (shared by the components spanning them)
            mj, mi = np.nonzero(metal[ks].any(axis=0))
            metal_points[key] = np.stack([mj * dy, mi * dx], axis=1)
        mpts = metal_points[key]
        nearest = mpts[np.argmin(((mpts - centre) ** 2).sum(axis=1))]
        radial = centre - nearest
        norm = float(np.hypot(*radial))
        if norm > 0 and abs(float(evecs[:, 1] @ radial)) / norm >= alignment:
            out[index] = True
    return out


def _core_with_kept(core: np.ndarray, labels: np.ndarray, keep: np.ndarray, thin_at: np.ndarray,
                    thin_labels: np.ndarray, total: np.ndarray) -> np.ndarray:
    """``largest_component(core | keep[labels])`` without labelling the head again.

    ``core`` is one 6-connected component and the thin components (``labels``, 6-connected, sizes
    ``total``) touch each other only through it, so the component holding the core is the core with
    the kept thin components 6-adjacent to it, and every other kept component stands alone. When one
    of those comes within 1.5 x of the core's component (where :func:`largest_component` counts
    exactly), the volume is labelled as before.
    """
    shape = core.shape
    flat_core = core.reshape(-1)
    coords = np.unravel_index(thin_at, shape)
    touches = np.zeros(thin_at.size, dtype=bool)
    stride = 1
    for axis in (2, 1, 0):
        c = coords[axis]
        for step in (-1, 1):
            ok = (c > 0) if step < 0 else (c < shape[axis] - 1)
            touches[ok] |= flat_core[thin_at[ok] + step * stride]
        stride *= shape[axis]
    joined = np.zeros(keep.size, dtype=bool)
    joined[thin_labels[touches]] = True
    joined &= keep
    size = int(np.count_nonzero(core)) + int(total[joined].sum())
    alone = keep & ~joined
    if alone.any() and 1.5 * int(total[alone].max()) >= size:
        return largest_component(core | keep[labels])
    head = core.copy()
    head.reshape(-1)[thin_at[joined[thin_labels]]] = True
    return head


def clean_head_mask(mask: np.ndarray, data: np.ndarray, window: tuple[float, float], spacing: Sequence[float],
                    opening_mm: float = 2.5, cushion_level: float | None = 0.85, cushion_mm: float = 2.0,
                    max_thin_extent_mm: float = 50.0, close_mm: float = 6.0, envelope_mm: float = 3.0,
                    noise: float | None = None, metal_level: float | None = 3.0,
                    streak_close_mm: float = 3.0, streak_reach_mm: float = 40.0,
                    progress=None) -> tuple[np.ndarray, dict]:
    """The paper's clean-up of the thresholded soft membership, extended to real scans.

    1. Envelope: the filled outline of the head's own tissue (windowed
       intensity ``>= cushion_level``; :func:`tissue_envelope`).
    2. Cushions: thick intermediate-density layers outside that envelope are
       removed (:func:`find_cushion`).  The intensities are smoothed first only
       when the noise (:func:`estimate_noise`) calls for it (:func:`smoothing_sigma`).
    3. Thin attachments: a per-slice opening with a disk of ``opening_mm``
       separates what hangs on the head by a thin bridge (head-holder arcs,
       table tops, cloth, streaks); the largest 3-D component of the opened
       mask is the head core (the paper's "largest connected component").
       What the opening took away is given back component by component when
       the component is compact (in-slice extent at most
       ``max_thin_extent_mm``: ear rims, nose tip, lips) or lies mostly inside
       the envelope (nasal septum, sinus walls); long thin structures outside
       the head are dropped, and so are metal streaks: in slices with metal
       (windowed intensity above ``metal_level``, :func:`metal_slices`) a thin
       piece outside the envelope that is elongated along the ray from the metal
       (:func:`streak_components`) is a bright streak, not a lip.
    4. Holes and cavities: every hole is filled per axial slice (a superset of
       the 3-D holes), and so are cavities whose opening a ``close_mm`` disk
       closes (nostrils, mouth, ear canals, streak gaps; :func:`fill_cavities`),
       so the head mask is the filled outer skin envelope.
    5. Streak bumps and notches: in the slices with metal, within
       ``streak_reach_mm`` of it, the outline is opened and closed with a
       ``streak_close_mm`` disk, which removes the bumps bright streaks raise
       on the lips and fills the notches dark streaks cut into them.

    Parameters
    ----------
    mask : ndarray of bool
        Thresholded membership ``q > 0.5``.
    data, window :
        The CT intensities and the window mapping air to 0 and soft tissue to 1.
    spacing : (dz, dy, dx) mm
    opening_mm, cushion_level, cushion_mm, max_thin_extent_mm, close_mm, envelope_mm :
        See above; ``cushion_level=None`` skips step 2 (the envelope then uses 0.85).
    metal_level, streak_close_mm, streak_reach_mm :
        Metal-streak handling (steps 3 and 5); ``metal_level=None`` disables it.
    noise : float, optional
        Noise std in window units (default estimated).
    progress : callable, optional
        ``progress(fraction, message)`` after each step above (seconds apart on a clinical scan); it may
        raise :class:`~pdehead_addon.Cancelled`.

    Returns
    -------
    (mask, stats)
    """
    stats: dict[str, Any] = {}
    dz, dy, dx = (float(h) for h in spacing)
    yx = (dy, dx)
    # at least a 3x3-pixel square, or coarse grids keep 2-pixel shells
    opening_mm = max(opening_mm, 1.5 * max(dy, dx))
    margin = (2, int(math.ceil(2 * opening_mm / dy)) + 2, int(math.ceil(2 * opening_mm / dx)) + 2)
    box = bounding_box(mask, margin)
    if box is None:
        raise SegmentationError("nothing in the volume is brighter than air: no head found")
    work = mask[box]
    low, high = window
    raw = data[box]
    scale = np.float32(1.0 / (high - low))
    level = 0.85 if cushion_level is None else float(cushion_level)
    smooth = None
    if noise is None:
        nz, ny, nx = raw.shape
        step = _noise_row_step(raw.shape)
        rows = np.arange(0, nz * ny, step)
        sample = np.subtract(raw[rows // ny, rows % ny], np.float32(low), dtype=np.float32)
        sample *= scale                                  # estimate_noise of the windowed volume, on its rows
        noise = _noise_of_rows(sample)
    sigma = smoothing_sigma(noise)
    stats.update(noise=noise, smoothing_sigma=sigma)
    tissue = None if sigma > 0 else _windowed_range(raw, window, (level, False), None)
    if tissue is None:                                   # smoothed, or another data type: the float volume
        smooth = np.subtract(raw, np.float32(low), dtype=np.float32)
        smooth *= scale
        if sigma > 0:
            smooth = ndi.gaussian_filter(smooth, sigma=sigma, mode="nearest", truncate=3.0)
        tissue = smooth >= np.float32(level)
    tissue &= work
    report_progress(progress, 0.1, "the head's tissue envelope")
    envelope = tissue_envelope(tissue, yx, opening_mm, envelope_mm)
    del tissue
    report_progress(progress, 0.25, "cushions outside the head")
    if cushion_level is not None:
        # heavier smoothing widens the skin's own intermediate rim: demand a correspondingly thicker layer
        thickness = cushion_mm + 2.0 * max(0.0, sigma - 0.5) * max(dz, dy, dx)
        band = None if smooth is not None else _windowed_range(raw, window, (CUSHION_LOW, True), level)
        if band is None:
            if smooth is None:
                smooth = np.subtract(raw, np.float32(low), dtype=np.float32)
                smooth *= scale
            cushion = find_cushion(work, smooth, spacing, envelope, level, thickness)
        else:                                            # find_cushion's band, on the integers
            band &= work
            band &= ~envelope
            cushion = _cushion_of_band(band, spacing, thickness)
            del band
        stats["cushion_voxels"] = int(np.count_nonzero(cushion))
        work &= ~cushion
    del smooth
    report_progress(progress, 0.4, "thin attachments")
    metal = metal_slices(data[box], window, metal_level) if metal_level is not None else None
    if metal is not None and not metal.any():
        metal = None
    stats["metal_slices"] = [] if metal is None else [int(k) + box[0].start
                                                       for k in np.flatnonzero(metal.any(axis=(1, 2)))]
    opened = open_disk(work, yx, opening_mm)
    core = largest_component(opened)
    if not core.any():
        raise SegmentationError(f"no part of the head is thicker than the {2 * opening_mm:g} mm opening")
    thin = work & ~opened
    del opened
    report_progress(progress, 0.55, "thin attachments: what to give back")
    labels, n, runs, thin_run_labels = run_labels.label(thin)    # ndi.label(thin), on its runs
    head = core
    if n:
        thin_at = runs.voxels()                          # the thin voxels (flat indices) and their labels
        thin_labels = np.repeat(thin_run_labels, runs.length)
        total = np.bincount(thin_labels, minlength=n + 1)
        inside = np.bincount(thin_labels[envelope.reshape(-1)[thin_at]], minlength=n + 1)
        objects = runs.objects(thin_run_labels, n)       # ndi.find_objects(labels)
        keep = (_component_extents(labels, n, yx, objects) <= max_thin_extent_mm) | (2 * inside > total)
        if metal is not None:
            streak = streak_components(labels, n, metal, yx, objects=objects, sizes=total) & ~(2 * inside > total)
            stats["streak_voxels"] = int(total[streak & keep].sum())
            keep &= ~streak
        keep[0] = False
        stats["thin_kept_voxels"] = int(total[keep].sum())
        stats["thin_dropped_voxels"] = int(total[1:].sum() - total[keep].sum())
        head = _core_with_kept(core, labels, keep, thin_at, thin_labels, total)
    del labels, thin, runs
    report_progress(progress, 0.7, "holes and cavities")
    head = fill_cavities(head, yx, close_mm) if close_mm > 0 else fill_holes_per_slice(head)
    report_progress(progress, 0.9, "metal streaks")
    if metal is not None and streak_close_mm > 0:
        # near the metal only: open away the bumps of bright streaks, close the notches of dark ones
        ks = np.flatnonzero(metal.any(axis=(1, 2)))
        near = np.stack([ndi.distance_transform_edt(~metal[k], sampling=yx) <= streak_reach_mm for k in ks])
        part = head[ks]
        smoothed = fill_holes_per_slice(close_disk(open_disk(part, yx, streak_close_mm), yx, streak_close_mm))
        changed = (smoothed != part) & near
        stats["streak_smoothed_voxels"] = int(np.count_nonzero(changed))
        part[changed] = smoothed[changed]
        head[ks] = largest_component(part) if part.any() else part
    out = np.zeros(mask.shape, dtype=bool)
    out[box] = head
    stats["head_voxels"] = int(np.count_nonzero(head))
    return out, stats


def cut_at_neck(mask: np.ndarray, spacing: Sequence[float], head_height_mm: float = 160.0,
                area_jump: float = 2.0, neck_margin: float = 1.1) -> tuple[np.ndarray, dict | None]:
    """Stop the head mask at the neck when the scan goes on into the shoulders.

    A head-and-neck scan reaches the shoulders, which join the neck in the mask; the
    PDE head (and its boundary curves) must end at the neck. The head's widest slice
    is looked for in the top ``head_height_mm`` of the mask (the widest level, at the
    ears, lies 90-130 mm below the vertex; the shoulders 200 mm or more). Going down
    from it the cross-section shrinks to the neck; the trunk starts at the first slice
    whose area exceeds ``area_jump`` times the
    smallest area above it and which is wider than the head. The mask is cut below
    the neck: the lowest slice between the head's widest slice and the trunk whose
    area is within ``neck_margin`` of that smallest area. Scans without shoulders are
    returned unchanged (``None`` info).

    Returns
    -------
    (mask, info) with info = dict(neck_slice, trunk_slice, removed_voxels) or None.
    """
    dz, dy, dx = (float(h) for h in spacing)
    cols = mask.any(axis=1)
    nz = mask.shape[0]
    width = np.zeros(nz)
    for k in np.flatnonzero(cols.any(axis=1)):
        c = np.flatnonzero(cols[k])
        width[k] = (c[-1] - c[0] + 1) * dx
    present = np.flatnonzero(width > 0)
    if present.size < 3:
        return mask, None
    area = np.count_nonzero(mask, axis=(1, 2)).astype(np.float64) * dy * dx
    top = present[-1]
    head = [k for k in present if k >= top - head_height_mm / dz]
    widest = max(head, key=lambda k: width[k])
    smallest, trunk = math.inf, None
    for k in range(widest, present[0] - 1, -1):        # k decreases toward inferior
        if area[k] > area_jump * smallest and width[k] > width[widest]:
            trunk = k
            break
        smallest = min(smallest, area[k]) if area[k] > 0 else smallest
    if trunk is None:
        return mask, None
    span = np.arange(trunk + 1, widest + 1)
    neck = int(span[np.flatnonzero(area[span] <= neck_margin * smallest)[0]])
    removed = int(np.count_nonzero(mask[:neck]))
    out = mask.copy()
    out[:neck] = False
    return out, dict(neck_slice=neck, trunk_slice=int(trunk), removed_voxels=removed)
