"""Step 2: head segmentation with the 3D Chan-Vese soft model (paper eq. 16-21) and clean-up.

The model (eq. 16) is solved on the windowed intensities ``I`` in [0, 1] (air
-> 0, soft tissue -> 1, :func:`auto_window`) by alternating the region means
(eq. 17), the closed-form q step (eq. 20) and Chambolle's dual projection
(eq. 21), in 3-D with the voxel spacing in mm.  The soft membership is then
thresholded and cleaned up the way the paper describes (largest connected
component, holes filled), plus the removal of what touches the head but is not
head (pillows, cloth, table tops, head holders, metal streaks), giving the
filled outer skin envelope (:func:`clean_head_mask`).

The solver is :mod:`.chan_vese` (eq. 16-21; coarse to fine: :mod:`.chan_vese_pyramid`), the clean-up
:mod:`.mask_cleanup`; this module windows the intensities, runs both and
checks the result (:func:`segment_head`).  Their public names are re-exported
here.
"""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy import ndimage as ndi
from skimage.filters import threshold_otsu

from ..core.ct_volume import CTVolume, apply_window
from ..core.errors import SegmentationError, report_progress, scaled_progress
from ..core.threads import THREADS, in_slabs
from ..io import input_checks
from .binary_morphology import PARALLEL_VOXELS
from .chan_vese import chan_vese_soft, divergence, gradient, tau_bound
from .chan_vese_pyramid import solve_pyramid
from .disk_morphology import dilate_disk, erode_disk
from .mask_cleanup import (
    clean_head_mask,
    close_disk,
    cut_at_neck,
    estimate_noise,
    fill_cavities,
    fill_holes_per_slice,
    find_cushion,
    largest_component,
    metal_slices,
    open_disk,
    smoothing_sigma,
    streak_components,
    tissue_envelope,
)

__all__ = [
    "Segmentation", "segment_head", "auto_window", "window_intensities", "MIN_SLICE_PIXELS",
    "SEGMENT_BYTES_PER_VOXEL", "MEMORY_BUDGET_GB",
    # eq. 16-21 (.chan_vese)
    "chan_vese_soft", "gradient", "divergence", "tau_bound",
    # clean-up (.mask_cleanup)
    "clean_head_mask", "cut_at_neck", "tissue_envelope", "find_cushion", "metal_slices", "streak_components",
    "erode_disk", "dilate_disk", "open_disk", "close_disk", "largest_component", "fill_holes_per_slice",
    "fill_cavities", "estimate_noise", "smoothing_sigma",
]

#: Smallest slice (pixels per side) that can hold a head outline with its clean-up openings.
MIN_SLICE_PIXELS = 16
#: Peak memory of segment_head per voxel beyond the CT itself: 5.33 GB measured on 512 x 512 x 800
#: (scripts/bench/bench_large_scan.py, docs/benchmarks.md), rounded up.
SEGMENT_BYTES_PER_VOXEL = 26
#: Default memory budget of segment_head (GB): larger scans are refused with the downsample advice.
MEMORY_BUDGET_GB = 8.0


@dataclass
class Segmentation:
    """Result of :func:`segment_head`.

    Attributes
    ----------
    mask : ndarray of bool, shape (nz, ny, nx)
        The cleaned head mask.
    probability : ndarray of float32, shape (nz, ny, nx)
        The soft membership of eq. 16 before clean-up: q of eq. 20 (in [0, 1]
        by construction; p = q - theta div s differs from it by O(theta)).
    c1, c2 : float
        Mean windowed intensity inside (head) and outside (air), eq. 17.
    iterations : int
        Outer iterations run (all levels of the coarse-to-fine solve).
    ct : CTVolume
        The volume segmented (for its geometry and intensities); not copied.
    meta : dict
        Parameters used and clean-up statistics.
    """

    mask: np.ndarray
    probability: np.ndarray
    c1: float
    c2: float
    iterations: int
    ct: CTVolume
    meta: dict[str, Any] = field(default_factory=dict)


# ----------------------------------------------------------------------------------------------
# Intensity window
# ----------------------------------------------------------------------------------------------

def auto_window(data: np.ndarray, max_samples: int = 1_000_000, bins: int = 256) -> tuple[float, float]:
    """Air and soft-tissue levels of a head scan, from its histogram.

    The histogram is taken on 2x2x2 block means (noise / 2.8, so that the modes
    survive heavy noise).  Otsu's threshold splits it into a dark (air, cloth,
    pillow) and a bright (tissue, bone) class; the window is (mode of the dark
    class, mode of the bright class).  In CT the bright mode is the
    soft-tissue/brain peak (bone is spread thinly over a long tail), so the
    window maps air to 0 and soft tissue to 1 whatever the units (HU,
    uncalibrated raw, 8-bit), and the Chan-Vese boundary, half-way between the
    region means, lands half-way between air and skin (the 50 % partial-volume
    level of the surface).

    Parameters
    ----------
    data : ndarray
        The volume.
    max_samples : int
        The histogram uses at most about this many (block-mean) samples.
    bins : int
        Histogram bins between the 0.1 and 99.9 percentiles.

    Returns
    -------
    (low, high) : tuple of float
        Intensity mapped to 0 and to 1.
    """
    data = np.asarray(data)
    if data.ndim == 3 and min(data.shape) >= 2:
        # every step-th block mean (flat order), computed for those blocks only: the same numbers as
        # taking every step-th of all the block means, for a fraction of the time on large scans
        blocks = tuple(n // 2 for n in data.shape)
        size = blocks[0] * blocks[1] * blocks[2]
        z, y, x = (2 * c for c in np.unravel_index(np.arange(0, size, max(1, size // max_samples)), blocks))
        flat = np.ascontiguousarray(data).reshape(-1)
        at = np.ravel_multi_index((z, y, x), data.shape)            # the block's first voxel, then its 7 others
        sz, sy = data.shape[1] * data.shape[2], data.shape[2]

        def voxel(offset: int) -> np.ndarray:
            return np.take(flat, at + offset if offset else at)
        sample = (voxel(0).astype(np.float32) + voxel(sz) + voxel(sy) + voxel(1) + voxel(sz + sy)
                  + voxel(sz + 1) + voxel(sy + 1) + voxel(sz + sy + 1)) * np.float32(0.125)
    else:
        sample = data.astype(np.float32).reshape(-1)
        sample = sample[:: max(1, sample.size // max_samples)]
    sample = sample[np.isfinite(sample)]
    if sample.size == 0:
        raise SegmentationError("the volume has no finite intensities")
    lo, hi = np.percentile(sample, [0.1, 99.9])
    if not hi > lo:
        raise SegmentationError(f"the volume is constant ({lo:g}); there is no head to segment")
    hist, edges = np.histogram(sample, bins=bins, range=(lo, hi))
    centres = 0.5 * (edges[:-1] + edges[1:])
    split = float(threshold_otsu(hist=(hist, centres)))
    smooth = ndi.gaussian_filter1d(hist.astype(np.float64), 2.0)
    dark = centres < split
    if dark.all() or not dark.any():
        raise SegmentationError("the intensity histogram has no air/tissue contrast")
    low = float(centres[dark][np.argmax(smooth[dark])])
    high = float(centres[~dark][np.argmax(smooth[~dark])])
    if not high > low:
        raise SegmentationError(f"no air/tissue contrast found (air {low:g}, tissue {high:g})")
    return low, high


def window_intensities(data: np.ndarray, window: tuple[float, float], out: np.ndarray | None = None) -> np.ndarray:
    """Map ``window = (low, high)`` linearly to [0, 1] and clip (float32): :func:`.ct_volume.apply_window`."""
    low, high = float(window[0]), float(window[1])
    if not high > low:
        raise SegmentationError(f"window must be (low, high) with high > low, got {window}")
    data = np.asarray(data)
    if out is not None or data.ndim != 3 or data.size < PARALLEL_VOXELS or THREADS < 2:
        return apply_window(data, (low, high), out=out, finite=False)
    # large volumes: slabs of about a megabyte (the three passes stay in cache), two threads
    out = np.empty(data.shape, np.float32)
    step = max(1, 262144 // max(1, data.shape[1] * data.shape[2]))

    def slab(a: int, b: int) -> None:
        for k in range(a, b, step):
            apply_window(data[k:min(k + step, b)], (low, high), out=out[k:min(k + step, b)], finite=False)

    in_slabs(data.shape[0], slab)
    return out


def segment_head(ct: CTVolume, *, lam: float = 3.0, theta: float = 0.1, tau: float | None = None,
                 iterations: int = 6, levels_mm: Sequence[float] = (2.0,),
                 level_iterations: Sequence[int] = (20,), inner: int = 1, tolerance: float = 1e-4,
                 window: tuple[float, float] | None = None, threshold: float = 0.5, cleanup: bool = True,
                 opening_mm: float = 2.5, cushion_level: float | None = 0.85, cushion_mm: float = 2.0,
                 close_mm: float = 6.0, slices: Sequence[int] | None = None, threads: int | None = None,
                 max_memory_gb: float | None = MEMORY_BUDGET_GB, progress=None) -> Segmentation:
    """Segment the head with the 3-D Chan-Vese soft model (eq. 16-21) and clean it up.

    The intensities are first windowed to [0, 1] (air -> 0, soft tissue -> 1,
    clipped; :func:`auto_window`), so ``lam`` means the same on every scanner
    and unit.  Eq. 16 is then minimised coarse to fine (block means of about
    ``levels_mm``, then the full grid) by alternating eq. 17, 20 and 21
    (:func:`chan_vese_soft`); ``q > threshold`` is cleaned up by
    :func:`clean_head_mask` into the filled outer skin envelope.

    Parameters
    ----------
    ct : CTVolume
    lam : float
        lambda of eq. 16 in 1/mm (intensities in [0, 1]); structures thinner
        than about ``2 / lam`` mm with a contrast of 1 are smoothed away.  The
        default 3 keeps ear rims and the nasal septum yet beats a threshold
        clearly at heavy noise (300-400 HU); 1 is smoother and more robust.
    theta : float
        Coupling of eq. 19-21 in mm; the paper's theta of eq. 20 is ``theta * lam``.
    tau : float, optional
        Dual step of eq. 21 in mm^2; default :func:`tau_bound` of each grid.
    iterations : int
        Outer iterations (eq. 17 + 20 + 21) on the full grid (after the coarse levels).
    levels_mm, level_iterations :
        Voxel sizes (mm) of the coarse levels and their outer iterations; a
        level as fine as the grid passes its iterations on.  ``levels_mm=()``
        solves on the full grid only.
    inner : int
        Chambolle steps (eq. 21) per outer iteration.
    tolerance : float
        A level stops early when the RMS change of q per iteration is below it.
    window : (low, high), optional
        Intensities mapped to 0 and 1 (default :func:`auto_window`).
    threshold : float
        Level of the soft membership taken as the head.
    cleanup : bool
        Apply :func:`clean_head_mask`; otherwise the mask is ``q > threshold``.
    opening_mm, cushion_level, cushion_mm, close_mm :
        Clean-up parameters (:func:`clean_head_mask`); ``cushion_level=None``
        disables the pillow removal (it is off for ``ct.meta["modality"]`` "MR").
    slices : sequence of int, optional
        The paper's own mode: segment only these axial slices (indices of
        ``ct.data``), each as an independent 2-D problem (eq. 16-21 with the
        in-slice gradient) with a 2-D clean-up.  The returned ``mask`` and
        ``probability`` are zero on every other slice; ``c1``/``c2`` are the
        means over the selected slices (per slice in ``meta["slices"]``) and
        ``iterations`` is the largest count run on one slice.
    threads : int, optional
        Worker threads of the solver (default: min(2, CPUs)).
    max_memory_gb : float or None
        Refuse (before any work) a volume whose segmentation would need more than
        this, with the advice to downsample (``load_ct(..., downsample=2)``, CLI
        ``--downsample 2``, import dialog "Downsample"); None: no limit.
    progress : callable, optional
        ``progress(fraction, message)`` after every solver iteration and clean-up stage; it
        may raise :class:`~pdehead_addon.core.errors.Cancelled`, which stops the segmentation
        (worker threads included) and propagates; nothing is returned or kept.

    Returns
    -------
    Segmentation
        ``mask`` (bool), ``probability`` (q of eq. 20, float32 in [0, 1]),
        ``c1``/``c2`` (eq. 17, windowed units), ``iterations`` (outer
        iterations of all levels), ``ct`` and ``meta`` (window, parameters,
        solver levels, clean-up statistics).
    """
    _check_arguments(ct, lam, theta, tau, iterations, inner, threshold, max_memory_gb)
    data = ct.data
    if threads is None:
        threads = min(2, os.cpu_count() or 1)
    spacing = tuple(float(h) for h in ct.spacing)
    if window is None:
        window = auto_window(data)
    window = (float(window[0]), float(window[1]))
    seg_warnings: list[str] = []
    # early: a quick look at the head's size before the solve (the spacing may be metres or microns)
    quick, quick_sp = input_checks.object_mask(data, spacing, 0.5 * (window[0] + window[1]))
    extent = input_checks.mask_extent_mm(quick, quick_sp)
    if extent is None:
        raise SegmentationError("nothing in the volume is brighter than air: no head found")
    refusal, _ = input_checks.check_head_extent(extent, spacing)
    if refusal:
        raise SegmentationError(refusal)
    params = dict(lam=lam, theta=theta, tau=tau, iterations=int(iterations), levels_mm=tuple(levels_mm),
                  level_iterations=tuple(int(n) for n in level_iterations), inner=int(inner), tolerance=tolerance,
                  window=window, threshold=threshold, cleanup=cleanup, opening_mm=opening_mm,
                  cushion_level=cushion_level, cushion_mm=cushion_mm, close_mm=close_mm)
    if str(ct.meta.get("modality", "")).upper() in ("MR", "MRI"):
        # pillows are recognised by CT densities; in MRI the skull and scalp look like one
        cushion_level = None
    clean_kw = dict(opening_mm=opening_mm, cushion_level=cushion_level, cushion_mm=cushion_mm, close_mm=close_mm)
    report_progress(progress, 0.0, "windowing the intensities")
    img = window_intensities(data, window)
    if slices is not None:
        seg = _segment_slices(ct, img, spacing, params, clean_kw, [int(k) for k in slices], threads)
        return _check_result(seg, spacing, seg_warnings)
    res, info = solve_pyramid(img, spacing, lam, theta, tau, levels_mm, level_iterations, iterations, inner,
                               tolerance, threads, progress=scaled_progress(progress, 0.02, 0.8), own_img=True)
    del img  # q may live in its buffer now (own_img)
    q = res.pop("q")
    res.pop("sig", None)  # the dual of an uncropped fine level: three volumes not needed in the clean-up
    stats: dict[str, Any] = {}
    mask = q > np.float32(threshold)
    if cleanup:
        report_progress(progress, 0.8, "cleaning up the head mask")
        mask, stats = clean_head_mask(mask, data, window, spacing, **clean_kw,
                                      progress=scaled_progress(progress, 0.8, 0.95))
        report_progress(progress, 0.95, "finding the neck")
        mask, neck = cut_at_neck(mask, spacing)
        stats["neck_cut"] = neck
        if neck is not None:
            z = ct.index_to_patient(np.array([neck["neck_slice"], 0, 0]))[2]
            seg_warnings.append(f"the scan goes on below the neck into the shoulders (from slice "
                                f"{neck['trunk_slice']} down): the head mask stops at the neck, slice "
                                f"{neck['neck_slice']} (z = {z:.0f} mm); {neck['removed_voxels']} voxels below "
                                "it are left out")
    meta = dict(mode="volume", window=window, params=params, solver=info, cleanup=stats)
    total = int(info["fine_iterations"]) + sum(int(level["iterations"]) for level in info["levels"])
    seg = Segmentation(mask=mask, probability=q, c1=res["c1"], c2=res["c2"], iterations=total, ct=ct, meta=meta)
    report_progress(progress, 1.0, "segmentation done")
    return _check_result(seg, spacing, seg_warnings)


def _check_arguments(ct, lam, theta, tau, iterations, inner, threshold, max_memory_gb) -> None:
    """:func:`segment_head`'s refusals before any work (SegmentationError with the reason)."""
    if not isinstance(ct, CTVolume):
        raise SegmentationError(f"segment_head needs a CTVolume, got {type(ct).__name__}")
    data = ct.data
    if data.ndim != 3 or data.shape[1] < 3 or data.shape[2] < 3:
        raise SegmentationError(f"cannot segment a volume of shape {data.shape}: need [z, y, x] slices of >= 3x3")
    bad = input_checks.count_non_finite(data)
    if bad:
        raise SegmentationError(f"{bad} voxel(s) are NaN or infinite; load the volume with load_ct (which fills "
                                "them as air with a warning) or replace them first")
    for name, value in (("lam", lam), ("theta", theta)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise SegmentationError(f"{name} must be a positive number, got {value!r}")
    if tau is not None and not (math.isfinite(tau) and tau > 0):
        raise SegmentationError(f"tau must be a positive number, got {tau!r}")
    if int(iterations) < 1 or int(inner) < 1:
        raise SegmentationError(f"iterations and inner must be >= 1, got {iterations} and {inner}")
    if not 0.0 < threshold < 1.0:
        raise SegmentationError(f"threshold must lie in (0, 1), got {threshold}")
    lo, hi = float(data.min()), float(data.max())
    if not hi > lo:
        raise SegmentationError(f"the volume is constant ({lo:g}); there is no head to segment")
    if min(data.shape[1:]) < MIN_SLICE_PIXELS:
        nz, ny, nx = data.shape
        raise SegmentationError(f"the volume of {nz} x {ny} x {nx} voxels (z, y, x) is too small to segment a "
                                f"head: slices need at least {MIN_SLICE_PIXELS} x {MIN_SLICE_PIXELS} pixels")
    if max_memory_gb is not None:
        need = (SEGMENT_BYTES_PER_VOXEL + data.itemsize) * data.size / 1e9
        if need > max_memory_gb:
            factor = max(2, math.ceil((need / max_memory_gb) ** (1.0 / 3.0)))
            nz, ny, nx = data.shape
            raise SegmentationError(
                f"segmenting {nx} x {ny} x {nz} voxels (x, y, z) needs about {need:.3g} GB, more than the "
                f"{max_memory_gb:g} GB budget; import the scan again with downsample={factor} for about "
                f"{need / factor ** 3:.3g} GB (segment_head: max_memory_gb=None lifts the budget)")


def _check_result(seg: Segmentation, spacing, seg_warnings: list[str]) -> Segmentation:
    """The head mask's size against human ranges: ``meta["warnings"]`` and a HeadSizeWarning."""
    extent = input_checks.mask_extent_mm(seg.mask, spacing)
    seg.meta["head_extent_mm"] = extent
    if extent is not None:
        refusal, warning = input_checks.check_head_extent(extent, spacing, "head mask")
        message = refusal or warning
        if message:
            seg_warnings.append(message)
    seg.meta["warnings"] = list(seg_warnings)
    for message in seg_warnings:
        warnings.warn(message, input_checks.HeadSizeWarning, stacklevel=3)
    return seg


def _segment_slices(ct: CTVolume, img: np.ndarray, spacing, params: dict, clean_kw: dict,
                    slices: list[int], threads: int) -> Segmentation:
    """The paper's per-slice mode: independent 2-D problems on the selected slices only."""
    nz = img.shape[0]
    bad = [k for k in slices if not -nz <= k < nz]
    if bad:
        raise SegmentationError(f"slice indices {bad} are outside the volume's {nz} slices")
    slices = sorted({k % nz for k in slices})
    if not slices:
        raise SegmentationError("no slices selected")
    mask = np.zeros(img.shape, dtype=bool)
    prob = np.zeros(img.shape, dtype=np.float32)
    per_slice = []
    most = 0
    for k in slices:
        res, info = solve_pyramid(img[k:k + 1], spacing, params["lam"], params["theta"], params["tau"],
                                   params["levels_mm"], params["level_iterations"], params["iterations"],
                                   params["inner"], params["tolerance"], 1)
        prob[k] = res["q"][0]
        m = res["q"] > np.float32(params["threshold"])
        stats: dict[str, Any] = {}
        if params["cleanup"]:
            try:
                m, stats = clean_head_mask(m, ct.data[k:k + 1], params["window"], spacing, **clean_kw)
            except SegmentationError:
                m = np.zeros_like(m)  # nothing head-like in this slice (above the vertex, below the neck)
        mask[k] = m[0]
        most = max(most, int(info["fine_iterations"]) + sum(int(lv["iterations"]) for lv in info["levels"]))
        per_slice.append(dict(slice=k, c1=res["c1"], c2=res["c2"], solver=info, cleanup=stats))
    meta = dict(mode="slices", slices=per_slice, window=params["window"], params=params)
    c1 = float(np.mean([d["c1"] for d in per_slice]))
    c2 = float(np.mean([d["c2"] for d in per_slice]))
    return Segmentation(mask=mask, probability=prob, c1=c1, c2=c2, iterations=most, ct=ct, meta=meta)
