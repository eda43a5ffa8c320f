"""Levels read off a CT's values: where the bone's surface lies (the half-maximum level of the bone's own
histogram, :func:`half_maximum_level`) and where metal begins (:func:`metal_level`).

A CT blurs the edge of a bone over a voxel or two; the level that crosses the edge half way between the
surrounding soft tissue and the bone (the half-maximum height, Spoor et al. 1993) is where the physical surface
lies. A lower level stands the surface out by a share of the blur and joins what partial volume bridges (a
closed bite, the jaw joints): CThead in HU, resliced to 1.5 mm, stripped at and run with 250 HU put its bone
surface 0.6 mm (median) further out than at its half-maximum level (558 HU) and its face 7 points lower.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi

__all__ = ["bone_mode", "smoothed_histogram", "half_maximum_level", "metal_level", "METAL_HU", "SATURATION_MIN_HU"]

#: Above this (HU) a voxel is metal, not bone (enamel and cortical bone stay below ~2500 HU).
METAL_HU = 3000.0
#: A calibrated scan's saturation spike under METAL_HU is metal only above this (HU): the bone's mode is looked for
#: up to 2000 HU (:func:`~.skull.bone_level_rule`); a spike lower down is not a filling.
SATURATION_MIN_HU = 2000.0


def half_maximum_level(values: np.ndarray, tissue_hu: float, level_range: tuple[float, float],
                       bins_hu: float = 10.0) -> tuple[float, float] | None:
    """The half-maximum level of bone: half way between soft tissue and the mode of the bone's values.

    Parameters
    ----------
    values : ndarray
        The bone's voxels' values in HU (a calibrated scan; those of a skull segmented at a lower level).
    tissue_hu : float
        Soft tissue's value (HU) on the other side of the edge.
    level_range : (float, float)
        The result is kept in this range (HU).
    bins_hu : float
        Histogram bin width (HU).

    Returns
    -------
    (level, bone_mode) or None
        None when the values have no mode of their own (:func:`bone_mode`, as in :func:`~.skull.bone_level_rule`).

    References
    ----------
    .. [1] Spoor, C. F., Zonneveld, F. W., & Macho, G. A. (1993). Linear measurements of cortical bone and dental
       enamel by computed tomography: applications and problems. American Journal of Physical Anthropology,
       91(4), 469-484 (the half-maximum-height edge of a structure in CT).
    """
    values = np.asarray(values, dtype=np.float32).reshape(-1)
    values = values[:: max(1, values.size // 8_000_000)]
    if values.size == 0:
        return None
    # from the lowest value given (a stripped scan's level): the empty bins below it are not a valley
    edges = np.arange(max(tissue_hu + 150.0, float(np.floor(values.min()))), 2600.0 + bins_hu, bins_hu)
    mode = bone_mode(*smoothed_histogram(values, edges), tissue_hu)
    if mode is None:
        return None
    lo, hi = level_range
    return float(min(max(0.5 * (tissue_hu + mode), lo), hi)), mode


def smoothed_histogram(values: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bins' centres and the histogram of ``values`` over ``edges`` smoothed by a Gaussian of 3 bins."""
    hist, _ = np.histogram(values, bins=edges)
    return 0.5 * (edges[:-1] + edges[1:]), ndi.gaussian_filter1d(hist.astype(np.float64), 3.0)


def bone_mode(centres: np.ndarray, smooth: np.ndarray, tissue_hu: float) -> float | None:
    """The bone's own mode (HU) in a smoothed histogram of CT values, or None when the bone has none.

    The mode is the histogram's maximum between ``tissue_hu + 400`` and 2000 HU when that maximum is interior to
    the range and more than 1.3 times the histogram's lowest point between ``tissue_hu + 150`` HU and it (a valley
    towards soft tissue). A bone blurred through thick slices (GE's 4 mm) thins out towards the top without a mode
    of its own.

    Parameters
    ----------
    centres, smooth : ndarray
        The histogram's bin centres (HU, or pseudo-HU) and counts (:func:`smoothed_histogram`).
    tissue_hu : float
        Soft tissue's value (HU).

    Returns
    -------
    float or None
    """
    idx = np.flatnonzero((centres >= tissue_hu + 400.0) & (centres <= 2000.0))
    if idx.size < 3:
        return None
    peak = int(idx[np.argmax(smooth[idx])])
    valley = float(smooth[np.flatnonzero((centres > tissue_hu + 150.0) & (centres <= centres[peak]))].min())
    if not (idx[0] < peak < idx[-1]) or smooth[peak] <= 1.3 * valley or smooth[peak] <= 0:
        return None
    return float(centres[peak])


def metal_level(data: np.ndarray, calibrated: bool) -> float:
    """Metal level in stored units: METAL_HU, or the scanner's saturation spike at the top of the values.

    Uncalibrated: the top 0.5 % of the value range when at least 1e-5 of the voxels lie in it. Calibrated: the
    same, when it lies under METAL_HU but above :data:`SATURATION_MIN_HU` and is a spike (more voxels in it than in
    the 1.5 % of the range below it; a bone's or an enamel's tail thins out towards the top): a scanner or an export
    that clips its values below METAL_HU (CThead in HU: its fillings at 2,248 HU, 1,979 voxels in the top band and
    105 below it; GE's brightest bone: 1 and 4). Computed from the top of the value range only, so removing
    everything below the bone level does not change it."""
    top = float(data.max())
    span = top - float(data.min())
    cut = top - 0.005 * span
    near_top = int(np.count_nonzero(data >= np.float32(cut)))
    if not calibrated:
        return float(cut) if near_top > 1e-5 * data.size else np.inf
    if top < METAL_HU and cut >= SATURATION_MIN_HU and near_top > 1e-5 * data.size:
        below = int(np.count_nonzero((data >= np.float32(top - 0.02 * span)) & (data < np.float32(cut))))
        if near_top > below:
            return float(cut)
    return METAL_HU
