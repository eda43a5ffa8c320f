"""The 3-D Chan-Vese soft model (paper eq. 16-21) coarse to fine.

:func:`solve_pyramid` runs :func:`.chan_vese.chan_vese_soft` on block-mean levels of the image, then
on the full grid: on the coarse head's box (:func:`_fine_crop`) or, on large grids, only in a band of
coarse blocks around the coarse boundary (:func:`~.chan_vese_band.band_fine_solve`).
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .chan_vese import chan_vese_soft, tau_bound
from .chan_vese_band import band_fine_solve
from .coarse_blocks import block_mean, resample_nearest


def _coarse_factors(spacing: Sequence[float], coarse_mm: float) -> tuple[int, int, int]:
    """Integer block sizes that bring each axis close to ``coarse_mm`` (never below 1)."""
    return tuple(max(1, int(round(coarse_mm / float(h)))) for h in spacing)


# ----------------------------------------------------------------------------------------------
# Coarse to fine
# ----------------------------------------------------------------------------------------------

def _level_plan(shape, spacing, levels_mm, level_iterations, two_d: bool):
    """The coarse levels, coarsest first: [(block factors (z, y, x), iterations)], and the iterations left
    over for the full grid (those of levels that do not exist because the grid is already that coarse)."""
    plan: list[tuple[tuple[int, int, int], int]] = []
    carry = 0
    counts = list(level_iterations) + [0] * max(0, len(levels_mm) - len(level_iterations))
    for mm, n in sorted(zip((float(m) for m in levels_mm), counts), reverse=True):
        carry += int(n)
        fac = tuple(min(fi, ni) for fi, ni in zip(_coarse_factors(spacing, mm), shape))
        if two_d:
            fac = (1,) + fac[1:]
        if max(fac) == 1:
            continue  # the grid is already this coarse: these iterations go to a finer level
        if plan and fac == plan[-1][0]:
            plan[-1] = (fac, plan[-1][1] + carry)
        else:
            plan.append((fac, carry))
        carry = 0
    return plan, carry


def solve_pyramid(img: np.ndarray, spacing: Sequence[float], lam: float, theta: float, tau: float | None,
                   levels_mm: Sequence[float], level_iterations: Sequence[int], iterations: int, inner: int,
                   tolerance: float, threads: int, progress=None, own_img: bool = False) -> tuple[dict, dict]:
    """Eq. 16-21 coarse to fine: block-mean levels of ~``levels_mm`` voxels, then the full grid.

    Each level starts from the previous one's membership q, means (c1, c2) and
    dual s (nearest-neighbour upsampled; s is dimensionless, |s| <= 1, so the
    stored s/h is rescaled by h_coarse/h_fine).  Iterations of a level that
    does not exist (the grid is already that coarse) move to the next level.
    ``own_img``: ``img`` may be overwritten (the band's q is written into it).
    """
    two_d = img.shape[0] == 1
    def bound(h):
        return tau_bound(h[1:] if two_d else h)
    plan, carry = _level_plan(img.shape, spacing, levels_mm, level_iterations, two_d)
    iterations = int(iterations) + carry
    info: dict[str, Any] = {"levels": [], "tau": None}
    # progress: iterations run so far over the most that can run (a level may stop early)
    planned = max(1, sum(max(n, 0) for _, n in plan) + iterations)
    before = [0]

    def level_progress(done: int, message: str | None = None) -> None:
        if progress is not None:
            progress((before[0] + done) / planned,
                     message or f"Chan-Vese iteration {before[0] + done} of at most {planned}")
    q = c = sig = None
    prev = None
    for fac, n in plan:
        if n <= 0:
            continue
        level_img = block_mean(img, fac, threads)
        level_spacing = tuple(h * f for h, f in zip(spacing, fac))
        if prev is not None:
            q = resample_nearest(q, prev, fac, level_img.shape)
            sig = tuple(resample_nearest(sa * np.float32(fp / ff), prev, fac, level_img.shape)
                        for sa, fp, ff in zip(sig, prev, fac))
        level_tau = bound(level_spacing) if tau is None else tau * min(f * f for f in fac)
        res = chan_vese_soft(level_img, level_spacing, lam, theta, level_tau, n, inner, tolerance,
                             q0=q, c0=c, sig0=sig, threads=threads, progress=level_progress)
        before[0] += n
        info["levels"].append(dict(factors=tuple(int(f) for f in fac), shape=tuple(level_img.shape),
                                   iterations=res["iterations"], change=res["change"]))
        q, c, sig, prev = res["q"], (res["c1"], res["c2"]), res["sig"], fac
        del res
    fine_tau = bound(spacing) if tau is None else tau
    if prev is not None and (FINE_BAND or img.size >= FINE_BAND_MIN_VOXELS) and not two_d and int(inner) == 1:
        # the full grid only in a band of coarse blocks around the coarse boundary
        res, band_info = band_fine_solve(img, spacing, lam, theta, fine_tau, iterations, tolerance, q, sig, c,
                                          prev, progress=level_progress, threads=threads, coarse_img=level_img,
                                          own_img=own_img)
        if res is not None:
            info.update(tau=fine_tau, fine_iterations=res["iterations"], fine_change=res["change"],
                        fine_box=None, fine_band=band_info)
            return res, info
    crop = None
    if prev is not None:
        # the full grid only where the coarse head is (q > FINE_CROP_Q grown by FINE_CROP_MARGIN blocks):
        # elsewhere q is 0 and stays 0; the region means (eq. 17) still count that air (``outside``)
        crop = _fine_crop(q, prev, img.shape)
        coarse_box = tuple(slice(b.start // f, -(-b.stop // f)) for b, f in zip(crop, prev))
        shape = tuple(b.stop - b.start for b in crop)
        q = resample_nearest(q[coarse_box], prev, (1, 1, 1), shape)
        sig = tuple(resample_nearest(sa[coarse_box] * np.float32(fp), prev, (1, 1, 1), shape)
                    for sa, fp in zip(sig, prev))
    if crop is not None and any(b.stop - b.start < n for b, n in zip(crop, img.shape)):
        fine_img = img[crop]
        outside = (float(np.sum(img, dtype=np.float64)) - float(np.sum(fine_img, dtype=np.float64)),
                   img.size - fine_img.size)
        # a view, not a copy (one volume of memory less at the peak); the sweep reads it slab by slab
    else:
        crop, fine_img, outside = None, img, (0.0, 0)
    res = chan_vese_soft(fine_img, spacing, lam, theta, fine_tau, iterations, inner, tolerance,
                         q0=q, c0=c, sig0=sig, threads=threads, progress=level_progress, outside=outside)
    if crop is not None:
        # the dual (three volumes of the box) goes before the whole grid's q is made: this was the
        # segmentation's peak of memory
        q = sig = None
        res["sig"] = None  # on the crop only
        full = np.zeros(img.shape, np.float32)
        full[crop] = res["q"]
        res["q"] = full
    info.update(tau=fine_tau, fine_iterations=res["iterations"], fine_change=res["change"],
                fine_box=None if crop is None else tuple((b.start, b.stop) for b in crop))
    return res, info


#: The full-resolution level runs on the box where the coarse membership exceeds this ...
FINE_CROP_Q = 1e-3
#: ... grown by this many coarse blocks on every side.
FINE_CROP_MARGIN = 2


def _fine_crop(q_coarse: np.ndarray, factors: Sequence[int], shape: Sequence[int]) -> tuple[slice, ...]:
    """The full grid's box (aligned to the coarse blocks) of the coarse head grown by a margin."""
    head = q_coarse > np.float32(FINE_CROP_Q)
    box = []
    for axis in range(3):
        other = tuple(a for a in range(3) if a != axis)
        idx = np.flatnonzero(head.any(axis=other))
        f, n = int(factors[axis]), int(shape[axis])
        if idx.size == 0:
            return tuple(slice(0, int(m)) for m in shape)
        lo = max(0, int(idx[0]) - FINE_CROP_MARGIN) * f
        hi = min(n, (int(idx[-1]) + 1 + FINE_CROP_MARGIN) * f)
        box.append(slice(lo, hi))
    return tuple(box)


# ----------------------------------------------------------------------------------------------
# The full-resolution level in a narrow band around the coarse boundary
# ----------------------------------------------------------------------------------------------

#: Run the full-resolution level only in a band of coarse blocks around the coarse boundary
#: (:func:`~.chan_vese_band.band_fine_solve`) on every grid; False: only on grids of at least
#: :data:`FINE_BAND_MIN_VOXELS` (smaller ones solve the coarse head's box, :func:`_fine_crop`).
FINE_BAND = False
#: Grids of at least this many voxels run the full-resolution level in the band.  Smaller grids gain
#: nothing from it (the band's index building eats the saving) and keep the box solve, so their masks are
#: unchanged (the test data sets are the golden cases of the selection and the visible-face score).  On a
#: 512 x 512 x 300 scan the band takes about half the solver's CPU time off (docs/benchmarks.md).
FINE_BAND_MIN_VOXELS = 40_000_000
