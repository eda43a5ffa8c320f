"""Segmentation accuracy: the Jaccard measure of the paper (section 6) and an independent reference.

The paper evaluates its segmentation with the Jaccard (JC) measure against
manual ground truth (Figure 10: 0.9815 on average over the CThead slices).
There is no manual ground truth for the real scans here, so
:func:`reference_head_mask` builds an *independent* reference by another,
deliberately simple method: a plain threshold at the air/skin level given in
each data set's README, the largest 3-D component, holes filled, and the
apparatus removed with rules that differ from the variational pipeline's
clean-up (a second, higher "tissue" threshold instead of the cushion layer
test; exposed high-density shells instead of an opening for head holders).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import ndimage as ndi

from .ct_volume import CTVolume


def jaccard(a: np.ndarray, b: np.ndarray) -> float:
    """|a & b| / |a | b| of two boolean arrays (1.0 when both are empty)."""
    a = np.asarray(a, dtype=bool)
    b = np.asarray(b, dtype=bool)
    if a.shape != b.shape:
        raise ValueError(f"jaccard: shapes differ {a.shape} vs {b.shape}")
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union


def per_slice_jaccard(a: np.ndarray, b: np.ndarray, axis: int = 0) -> np.ndarray:
    """Jaccard of every slice along ``axis`` where ``a`` or ``b`` is non-empty (float64 array)."""
    a = np.moveaxis(np.asarray(a, dtype=bool), axis, 0)
    b = np.moveaxis(np.asarray(b, dtype=bool), axis, 0)
    if a.shape != b.shape:
        raise ValueError(f"per_slice_jaccard: shapes differ {a.shape} vs {b.shape}")
    inter = np.count_nonzero(a & b, axis=(1, 2)) if a.ndim == 3 else np.count_nonzero(a & b, axis=tuple(range(1, a.ndim)))
    union = np.count_nonzero(a | b, axis=tuple(range(1, a.ndim)))
    keep = union > 0
    return inter[keep] / union[keep]


def head_slices(reference: np.ndarray, min_fraction: float = 0.01, axis: int = 0) -> np.ndarray:
    """Indices of "the head's slices": reference area >= ``min_fraction`` of its largest slice area."""
    ref = np.moveaxis(np.asarray(reference, dtype=bool), axis, 0)
    area = np.count_nonzero(ref.reshape(ref.shape[0], -1), axis=1)
    if area.max() == 0:
        return np.zeros(0, dtype=int)
    return np.flatnonzero(area >= min_fraction * area.max())


def slice_jaccard_on_head(mask: np.ndarray, reference: np.ndarray, min_fraction: float = 0.01) -> np.ndarray:
    """Per-axial-slice Jaccard of ``mask`` against ``reference`` over :func:`head_slices` of the reference."""
    ks = head_slices(reference, min_fraction)
    m = np.asarray(mask, dtype=bool)[ks]
    r = np.asarray(reference, dtype=bool)[ks]
    inter = np.count_nonzero(m & r, axis=(1, 2))
    union = np.count_nonzero(m | r, axis=(1, 2))
    return inter / np.maximum(union, 1)


# ----------------------------------------------------------------------------------------------
# The independent reference
# ----------------------------------------------------------------------------------------------

_IN_SLICE = np.zeros((3, 3, 3), dtype=bool)
_IN_SLICE[1] = ndi.generate_binary_structure(2, 1)


def _disk(spacing_yx: Sequence[float], radius_mm: float) -> np.ndarray:
    hy, hx = (float(h) for h in spacing_yx)
    ry, rx = int(radius_mm / hy), int(radius_mm / hx)
    y, x = np.mgrid[-ry:ry + 1, -rx:rx + 1]
    return ((y * hy) ** 2 + (x * hx) ** 2 <= radius_mm ** 2 + 1e-9)[None]


def _largest(mask: np.ndarray) -> np.ndarray:
    labels, n = ndi.label(mask)
    if n == 0:
        return np.zeros(mask.shape, dtype=bool)
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    return labels == np.argmax(counts)


def _fill_2d(mask: np.ndarray) -> np.ndarray:
    """Per-slice hole filling (holes = background not reaching the slice border)."""
    out = np.empty_like(mask)
    for k in range(mask.shape[0]):
        out[k] = ndi.binary_fill_holes(mask[k])
    return out


def reference_head_mask(ct: CTVolume, threshold: float, *, tissue_threshold: float | None = None,
                        bright_threshold: float | None = None, shell_mm: float = 2.0, rim_mm: float = 1.0,
                        reach_mm: float = 1.5, close_mm: float = 6.0) -> np.ndarray:
    """A simple threshold-based head mask, independent of :func:`segment_head`.

    1. ``T = data > threshold`` (the README air/skin level, in the data's units).
    2. Tissue core ``C = data > tissue_threshold`` (default ``threshold``). With
       ``bright_threshold``, high-density voxels of ``C`` within ``shell_mm``
       (in-slice) of air are "exposed shells", i.e. head holders, tables or
       metal streaks (bone is always covered by skin), and are removed with a
       ``rim_mm`` partial-volume rim and from the exposed voxels of the slices
       just above and below (where a resampled thin shell may be blurred below
       ``bright_threshold``).
    3. The largest 3-D component of ``C`` is the head core.
    4. ``T`` is kept within ``reach_mm`` in-slice (and one slice up or down) of
       the core: a pillow whose density lies between the two thresholds is cut
       at that distance, while the soft in-slice ramp of the skin at the vertex,
       cut at a grazing angle, lies over the neighbouring slice's core.
    5. Largest 3-D component; the cavities that a per-slice closing with a
       ``close_mm`` disk encloses (nostrils, mouth, ear canals, metal-streak
       gaps) are filled together with the closing's seal; every hole is filled
       per slice (which includes the 3-D holes).

    Returns
    -------
    ndarray of bool, the shape of ``ct.data``.
    """
    data = ct.data
    _, hy, hx = ct.spacing
    above = data > threshold
    core = data > (threshold if tissue_threshold is None else tissue_threshold)
    core &= above
    if bright_threshold is not None:
        air_distance = np.empty(data.shape, dtype=np.float32)
        for k in range(data.shape[0]):
            air_distance[k] = ndi.distance_transform_edt(above[k], sampling=(hy, hx))
        near_air = above & (air_distance <= shell_mm)
        shell = near_air & (data > bright_threshold)
        shell = ndi.binary_dilation(shell, structure=_disk((hy, hx), rim_mm))
        # also one slice up and down: interpolated (resampled, tilted) slices blur a thin shell below the level
        shell[1:] |= shell[:-1].copy()
        shell[:-1] |= shell[1:].copy()
        shell &= near_air
        core &= ~shell
    core = _largest(core)
    # reach: in-slice disk and one slice up/down; at the vertex the skin is cut at a grazing angle,
    # so its soft in-slice ramp lies over/under the core of the neighbouring slice (a pillow does not)
    reach = _disk((hy, hx), reach_mm)
    reach = np.concatenate([reach, reach, reach], axis=0) if data.shape[0] > 1 else reach
    head = above & ndi.binary_dilation(core, structure=reach)
    head = _largest(head)
    if close_mm > 0:
        # cavities sealed by a close_mm closing are filled with their seal, the rest of the outline is kept
        disk = _disk((hy, hx), close_mm)
        pad = disk.shape[1] // 2 + disk.shape[2] // 2 + 2
        padded = np.pad(head, ((0, 0), (pad, pad), (pad, pad)))
        closed = ndi.binary_closing(padded, structure=disk)[:, pad:-pad, pad:-pad]
        cavities = _fill_2d(closed) & ~closed
        seals = closed & ~head & ndi.binary_dilation(cavities, structure=disk)
        head = head | cavities | seals
    return _fill_2d(head)
