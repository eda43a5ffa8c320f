"""Step 2: head segmentation with the 3D Chan-Vese soft model (paper eq. 16-21) and clean-up.

The model (eq. 16) is solved on the windowed intensities ``I`` in [0, 1] (air
-> 0, soft tissue -> 1, :func:`auto_window`) by alternating the region means
(eq. 17), the closed-form q step (eq. 20) and Chambolle's dual projection
(eq. 21), in 3-D with the voxel spacing in mm.  The soft membership is then
thresholded and cleaned up the way the paper describes (largest connected
component, holes filled), plus the removal of what touches the head but is not
head (pillows, cloth, table tops, head holders, metal streaks), giving the
filled outer skin envelope (:func:`clean_head_mask`).

Notation and units
------------------
With ``r = (I - c1)^2 - (I - c2)^2`` eq. 16 becomes eq. 18,
``min_p TV(p) + lam * <r, p>``, relaxed (eq. 19) with the coupling
``1/(2 theta) ||p - q||^2``.  Then (Bresson et al. 2007, the scheme the paper
follows)::

    q = clip(p - theta * lam * r, 0, 1)                          (eq. 20)
    p = q - theta * div(s)
    s <- (s + tau grad(div s - q/theta)) / (1 + tau |grad(div s - q/theta)|)   (eq. 21)

The paper writes eq. 20 as ``clip(p - theta' r)`` with ``theta' = lam/mu`` and
``mu`` the coupling weight of eq. 19; here ``mu = 1/theta`` so the paper's
``theta'`` is ``theta * lam``.  (The paper's eq. 21 writes ``q/lam`` where the
ROF step of its own eq. 19 needs ``q/theta``; we use the consistent form.)
Gradients are forward differences in mm and ``div = -grad^T`` exactly, so TV
is measured in mm^2 of surface, ``lam`` is in 1/mm for ``I`` in [0, 1] (a
structure is kept when ``lam * |r|`` exceeds its mean curvature, roughly when
it is thicker than ``2 / lam`` mm) and the step bound is
``tau <= 1 / (4 sum_a 1/h_a^2)`` (:func:`tau_bound`).

Implementation
--------------
numpy only, float32.  One outer iteration (eq. 20 + one eq. 21 step + the sums
of eq. 17) is a single fused sweep over slabs of a few slices that stay in
cache (:class:`_ChanVeseState`), split over two threads on large slices.  The
problem is solved coarse to fine: block means of ~2 mm first, then a few
iterations on the full grid warm-started from the coarse q, (c1, c2) and dual s.
"""
from __future__ import annotations

import math
import os
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy import ndimage as ndi

from . import input_checks
from .ct_volume import CTVolume
from .errors import SegmentationError

#: Smallest slice (pixels per side) that can hold a head outline with its clean-up openings.
MIN_SLICE_PIXELS = 16
#: Peak memory of segment_head per voxel beyond the CT itself: 5.33 GB measured on 512 x 512 x 800
#: (scripts/bench_large_scan.py, docs/benchmarks.md), rounded up.
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
        nz, ny, nx = (n - n % 2 for n in data.shape)
        block = data[:nz, :ny, :nx]
        sample = (block[0::2, 0::2, 0::2].astype(np.float32) + block[1::2, 0::2, 0::2] + block[0::2, 1::2, 0::2]
                  + block[0::2, 0::2, 1::2] + block[1::2, 1::2, 0::2] + block[1::2, 0::2, 1::2]
                  + block[0::2, 1::2, 1::2] + block[1::2, 1::2, 1::2]) * np.float32(0.125)
    else:
        sample = data.astype(np.float32)
    sample = sample.reshape(-1)
    sample = sample[:: max(1, sample.size // max_samples)]
    sample = sample[np.isfinite(sample)]
    if sample.size == 0:
        raise SegmentationError("the volume has no finite intensities")
    lo, hi = np.percentile(sample, [0.1, 99.9])
    if not hi > lo:
        raise SegmentationError(f"the volume is constant ({lo:g}); there is no head to segment")
    hist, edges = np.histogram(sample, bins=bins, range=(lo, hi))
    centres = 0.5 * (edges[:-1] + edges[1:])
    from skimage.filters import threshold_otsu
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
    """Map ``window = (low, high)`` linearly to [0, 1] and clip (float32)."""
    low, high = float(window[0]), float(window[1])
    if not high > low:
        raise SegmentationError(f"window must be (low, high) with high > low, got {window}")
    out = np.subtract(data, np.float32(low), out=out, dtype=np.float32)
    out *= np.float32(1.0 / (high - low))
    np.clip(out, 0.0, 1.0, out=out)
    return out


# ----------------------------------------------------------------------------------------------
# Discrete gradient and divergence (mm), div = -grad^T
# ----------------------------------------------------------------------------------------------

def gradient(u: np.ndarray, spacing: Sequence[float]) -> tuple[np.ndarray, ...]:
    """Forward-difference gradient in physical units, zero on the last index (Neumann).

    Parameters
    ----------
    u : ndarray, shape (n0, n1, ..., )
    spacing : sequence of float
        Grid step of each axis (mm).

    Returns
    -------
    tuple of ndarray
        ``g[a][..., i, ...] = (u[i+1] - u[i]) / h_a`` for ``i < n_a - 1`` and 0 for the last index.
    """
    u = np.asarray(u)
    out = []
    for axis, h in enumerate(spacing):
        g = np.zeros(u.shape, dtype=np.result_type(u.dtype, np.float32))
        hi = [slice(None)] * u.ndim
        lo = [slice(None)] * u.ndim
        hi[axis] = slice(1, None)
        lo[axis] = slice(None, -1)
        np.subtract(u[tuple(hi)], u[tuple(lo)], out=g[tuple(lo)])
        g /= g.dtype.type(h)
        out.append(g)
    return tuple(out)


def divergence(field_components: Sequence[np.ndarray], spacing: Sequence[float]) -> np.ndarray:
    """Divergence that is exactly the negative adjoint of :func:`gradient`.

    ``<gradient(u), s> = -<u, divergence(s)>`` for every ``u`` and every ``s``
    (the last index of each component, where the gradient is 0, is ignored):
    ``div_a[i] = (s[i] [i < n-1] - s[i-1] [i > 0]) / h_a``.
    """
    comps = [np.asarray(c) for c in field_components]
    shape = comps[0].shape
    div = np.zeros(shape, dtype=np.result_type(comps[0].dtype, np.float32))
    for axis, (s, h) in enumerate(zip(comps, spacing)):
        head = [slice(None)] * s.ndim
        tail = [slice(None)] * s.ndim
        head[axis] = slice(None, -1)
        tail[axis] = slice(1, None)
        scale = div.dtype.type(1.0 / h)
        div[tuple(head)] += s[tuple(head)] * scale
        div[tuple(tail)] -= s[tuple(head)] * scale
    return div


def tau_bound(spacing: Sequence[float]) -> float:
    """Largest step of Chambolle's projection (eq. 21) with a convergence guarantee.

    Chambolle (2004, Thm. 3.1) converges for ``tau <= 1 / ||div||^2``.  With
    forward differences each 1-D operator ``D_a/h_a`` has norm below ``2/h_a``
    and the axes are orthogonal blocks of ``grad``, so
    ``||div||^2 = ||grad||^2 <= sum_a 4/h_a^2`` and
    ``tau <= 1 / (4 * sum_a 1/h_a^2)`` (mm^2): 1/8 in 2-D and 1/12 in 3-D for
    unit spacing, as in Chambolle's paper.
    """
    return 1.0 / (4.0 * sum(1.0 / float(h) ** 2 for h in spacing))


# ----------------------------------------------------------------------------------------------
# The fused Chan-Vese / Chambolle sweep
# ----------------------------------------------------------------------------------------------

class _ChanVeseState:
    """Arrays of the eq. 16-21 iteration on one grid, swept slab by slab.

    Stored: the windowed image ``img``, the scaled dual ``sig_a = s_a / h_a``
    (so that ``div s = sum_a D_a^T sig_a`` needs no division) and
    ``neg_q = -q / theta`` (so that ``t = div s - q/theta = div s + neg_q``).
    One sweep does, per slab of planes and in cache: ``t``; ``p = -theta t``;
    the q step (eq. 20) from ``p`` with the current ``c1, c2``; one dual step
    (eq. 21) from ``t``; and the sums for eq. 17.  The invariant
    ``sig_a[last index along a] == 0`` holds throughout (the gradient is 0
    there), which makes the backward difference of the divergence exact.
    """

    def __init__(self, img: np.ndarray, q: np.ndarray, spacing, theta: float, tau: float,
                 sig: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                 slab: int | None = None, threads: int = 1, own_q: bool = False):
        self.img = img
        self.shape = img.shape
        self.spacing = tuple(float(h) for h in spacing)
        self.theta = float(theta)
        self.tau = float(tau)
        if own_q and q.dtype == np.float32 and q.flags.c_contiguous:
            self.neg_q = q  # take the caller's buffer over (saves a volume of memory)
            self.neg_q *= np.float32(-1.0 / theta)
        else:
            self.neg_q = np.multiply(q, np.float32(-1.0 / theta), dtype=np.float32)
        if sig is None:
            sig = tuple(np.zeros(self.shape, np.float32) for _ in range(3))
        else:
            for axis, s in enumerate(sig):  # re-impose the invariant
                idx = [slice(None)] * 3
                idx[axis] = -1
                s[tuple(idx)] = 0.0
        self.sig = sig
        self.weights = tuple(np.float32(1.0 / h ** 2) for h in self.spacing)
        nz, ny, nx = self.shape
        # ~128k voxels per slab keeps a slab's working set in cache and the per-call overhead small
        self.slab = max(1, min(16, 131072 // (ny * nx))) if slab is None else max(1, int(slab))
        # threads pay off only on large planes (numpy's per-call overhead and the GIL dominate small ones)
        if ny * nx < 65536:
            threads = 1
        threads = max(1, min(int(threads), nz // (2 * self.slab) or 1))
        bounds = np.linspace(0, nz, threads + 1).round().astype(int)
        self.chunks = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
        self.buffers = [self._make_buffers() for _ in self.chunks]
        self.pool = ThreadPoolExecutor(len(self.chunks)) if len(self.chunks) > 1 else None
        self.img_sum = float(np.sum(img, dtype=np.float64))

    def close(self):
        if self.pool is not None:
            self.pool.shutdown()
            self.pool = None

    def _make_buffers(self):
        _, ny, nx = self.shape
        b = self.slab
        plane = (b, ny, nx)
        return dict(t=np.empty((b + 1, ny, nx), np.float32),
                    dz=np.zeros(plane, np.float32), dy=np.zeros(plane, np.float32),
                    dx=np.zeros(plane, np.float32), n=np.empty(plane, np.float32),
                    w=np.empty(plane, np.float32),
                    # constant arrays: numpy's maximum/minimum/vdot are much faster with
                    # an array operand than with a broadcast scalar
                    zero=np.zeros(plane, np.float32),
                    low=np.full(plane, -1.0 / self.theta, np.float32),
                    ones=np.ones(b * ny * nx, np.float32))

    def _t_planes(self, z0: int, z1: int, out: np.ndarray) -> None:
        """``t = div s + neg_q`` on planes z0..z1-1 into out[:z1-z0] (reads the old s)."""
        sx, sy, sz = self.sig[2], self.sig[1], self.sig[0]
        o = out[: z1 - z0]
        np.add(sx[z0:z1], sy[z0:z1], out=o)
        # x: flat backward difference; the term wrapping to the previous row is
        # sig_x[row-1, nx-1] == 0 by the invariant, so it is exact (and contiguous, fast)
        o.reshape(-1)[1:] -= sx[z0:z1].reshape(-1)[:-1]
        o[:, 1:, :] -= sy[z0:z1, :-1, :]
        o += sz[z0:z1]
        if z0 > 0:
            o -= sz[z0 - 1:z1 - 1]
        elif z1 > 1:
            o[1:] -= sz[0:z1 - 1]
        o += self.neg_q[z0:z1]

    def _sweep_chunk(self, ci: int, first_t: np.ndarray | None, after_t: np.ndarray | None,
                     q_coeffs: tuple[float, float] | None) -> tuple[float, float, float]:
        a_chunk, b_chunk = self.chunks[ci]
        buf = self.buffers[ci]
        t, dz, dy, dx, n, w = buf["t"], buf["dz"], buf["dy"], buf["dx"], buf["n"], buf["w"]
        nz = self.shape[0]
        wz, wy, wx = self.weights
        tau = np.float32(self.tau)
        sz, sy, sx = self.sig
        sum_q = 0.0
        sum_iq = 0.0
        change = 0.0
        carry = first_t
        for a in range(a_chunk, b_chunk, self.slab):
            b = min(a + self.slab, b_chunk)
            m = b - a
            # t on planes a..b (b is the extra plane for the z difference)
            if carry is None:
                self._t_planes(a, b, t)
            else:
                t[0] = carry
                if m > 1:
                    self._t_planes(a + 1, b, t[1:])
            has_next = b < nz
            if has_next:
                if b == b_chunk:
                    t[m] = after_t
                else:
                    self._t_planes(b, b + 1, t[m:])
                carry = t[m].copy() if b < b_chunk else None
            tm = t[:m]
            nn, ww = n[:m], w[:m]
            # q step (eq. 20) from p = -theta t, written as neg_q = clip(t + lam r, -1/theta, 0)
            if q_coeffs is not None:
                lam_alpha, lam_beta = q_coeffs
                nq = self.neg_q[a:b]
                np.multiply(self.img[a:b], np.float32(lam_alpha), out=ww)
                ww += tm
                ww += np.float32(lam_beta)
                np.maximum(ww, buf["low"][:m], out=ww)
                np.minimum(ww, buf["zero"][:m], out=ww)
                np.subtract(ww, nq, out=nn)
                flat = nn.reshape(-1)
                change += float(np.vdot(flat, flat))
                nq[...] = ww
                wflat = ww.reshape(-1)
                sum_q += float(np.vdot(wflat, buf["ones"][: wflat.size]))
                sum_iq += float(np.vdot(self.img[a:b].reshape(-1), wflat))
            # dual step (eq. 21) from t: d_a = D_a t, |grad t|^2 = sum w_a d_a^2
            gz, gy, gx = dz[:m], dy[:m], dx[:m]
            if has_next:
                np.subtract(t[1:m + 1], tm, out=gz)
            else:
                if m > 1:
                    np.subtract(t[1:m], t[:m - 1], out=gz[:m - 1])
                gz[m - 1] = 0.0
            np.subtract(tm[:, 1:], tm[:, :-1], out=gy[:, :-1])  # gy[:, -1] stays 0
            tflat = tm.reshape(-1)
            np.subtract(tflat[1:], tflat[:-1], out=gx.reshape(-1)[:-1])
            gx[:, :, -1] = 0.0  # the flat difference wrapped across rows there
            np.multiply(gz, gz, out=nn)
            if wz != 1:
                nn *= wz
            for g, wa in ((gy, wy), (gx, wx)):
                np.multiply(g, g, out=ww)
                if wa != 1:
                    ww *= wa
                nn += ww
            np.sqrt(nn, out=nn)
            nn *= tau
            nn += np.float32(1.0)
            np.reciprocal(nn, out=nn)
            for s, g, wa in ((sz, gz, wz), (sy, gy, wy), (sx, gx, wx)):
                g *= np.float32(tau * wa)
                g += s[a:b]
                np.multiply(g, nn, out=s[a:b])
        theta = self.theta
        return -theta * sum_q, -theta * sum_iq, theta * theta * change

    def sweep(self, q_coeffs: tuple[float, float] | None):
        """One dual step of eq. 21 (and, with ``q_coeffs``, the q step of eq. 20).

        Returns ``(sum q, sum I q, sum (q_new - q_old)^2)`` (zeros without a q step).
        """
        nz = self.shape[0]
        jobs = []
        # t on the planes shared by two chunks is computed before any chunk writes
        boundary_t = {}
        for a, _ in self.chunks[1:]:
            buf = np.empty((1,) + self.shape[1:], np.float32)
            self._t_planes(a, a + 1, buf)
            boundary_t[a] = buf[0]
        for ci, (a, b) in enumerate(self.chunks):
            first_t = boundary_t.get(a)
            after_t = boundary_t.get(b) if b < nz else None
            jobs.append((ci, first_t, after_t, q_coeffs))
        if self.pool is None:
            results = [self._sweep_chunk(*job) for job in jobs]
        else:
            results = list(self.pool.map(lambda job: self._sweep_chunk(*job), jobs))
        return tuple(sum(r[i] for r in results) for i in range(3))

    def membership(self, release: bool = False) -> np.ndarray:
        """q = -theta * neg_q, the constrained soft membership in [0, 1] (``release``: in place, state unusable)."""
        if release:
            q, self.neg_q = self.neg_q, None
            q *= np.float32(-self.theta)
            return q
        return self.neg_q * np.float32(-self.theta)


def _region_means(sum_q: float, sum_iq: float, sum_i: float, count: int) -> tuple[float, float]:
    """Eq. 17 from the sums of q, I q and I."""
    eps = 1e-12
    c1 = sum_iq / max(sum_q, eps)
    c2 = (sum_i - sum_iq) / max(count - sum_q, eps)
    return float(c1), float(c2)


def chan_vese_soft(img: np.ndarray, spacing: Sequence[float], lam: float, theta: float,
                   tau: float | None = None, iterations: int = 30, inner: int = 1,
                   tolerance: float = 0.0, q0: np.ndarray | None = None,
                   c0: tuple[float, float] | None = None, sig0=None, threads: int = 1,
                   slab: int | None = None) -> dict[str, Any]:
    """Minimise eq. 16 on one grid by alternating eq. 17, eq. 20 and eq. 21.

    Parameters
    ----------
    img : ndarray float32, shape (nz, ny, nx)
        Windowed intensities in [0, 1].
    spacing : (dz, dy, dx)
        Voxel size in mm.
    lam, theta, tau : float
        Data weight (1/mm), coupling (mm) and dual step (mm^2, default :func:`tau_bound`).
    iterations : int
        Outer iterations (eq. 17 + eq. 20 + ``inner`` steps of eq. 21).
    inner : int
        Dual steps of eq. 21 per outer iteration.
    tolerance : float
        Stop when the root-mean-square change of q in an outer iteration falls below it.
    q0, c0, sig0 :
        Warm start: membership, (c1, c2) and scaled dual ``s_a / h_a``.  The
        arrays are taken over and modified in place (memory).

    Returns
    -------
    dict with ``q`` (membership in [0, 1], float32), ``c1``, ``c2`` (the means
    used in the last q step), ``iterations`` run, ``change`` (last mean |dq|)
    (last RMS change of q) and ``sig`` (the scaled dual, for warm starts).
    """
    if tau is None:
        tau = tau_bound(spacing)
    q = img if q0 is None else q0  # a given q0 is taken over (modified in place)
    count = img.size
    if c0 is None:
        c1, c2 = _region_means(float(q.sum(dtype=np.float64)), float(np.vdot(img.ravel(), q.ravel())),
                               float(img.sum(dtype=np.float64)), count)
    else:
        c1, c2 = c0
    state = _ChanVeseState(img, q, spacing, theta, tau, sig=sig0, slab=slab, threads=threads,
                           own_q=q0 is not None)
    del q, q0
    try:
        change = float("nan")
        done = 0
        used = (c1, c2)
        for it in range(iterations):
            for k in range(inner):
                last = k == inner - 1
                coeffs = (lam * 2.0 * (c2 - c1), lam * (c1 * c1 - c2 * c2)) if last else None
                sums = state.sweep(coeffs)
            used = (c1, c2)
            c1, c2 = _region_means(sums[0], sums[1], state.img_sum, count)
            change = math.sqrt(sums[2] / count)
            done = it + 1
            if change < tolerance:
                break
        return dict(q=state.membership(release=True), c1=used[0], c2=used[1], iterations=done, change=change,
                    sig=state.sig)
    finally:
        state.close()


def _coarse_factors(spacing: Sequence[float], coarse_mm: float) -> tuple[int, int, int]:
    """Integer block sizes that bring each axis close to ``coarse_mm`` (never below 1)."""
    return tuple(max(1, int(round(coarse_mm / float(h)))) for h in spacing)


def _block_mean(img: np.ndarray, factors: Sequence[int]) -> np.ndarray:
    """Mean over blocks of ``factors`` voxels (edge-padded to whole blocks), float32."""
    fz, fy, fx = factors
    nz, ny, nx = img.shape
    pz, py, px = (-nz) % fz, (-ny) % fy, (-nx) % fx
    if pz or py or px:
        img = np.pad(img, ((0, pz), (0, py), (0, px)), mode="edge")
    out = None
    for dz in range(fz):  # sum of strided views: much faster than a reshaped mean
        for dy in range(fy):
            for dx in range(fx):
                view = img[dz::fz, dy::fy, dx::fx]
                out = view.astype(np.float32, copy=True) if out is None else np.add(out, view, out=out)
    out *= np.float32(1.0 / (fz * fy * fx))
    return out


def _resample_nearest(a: np.ndarray, from_factors: Sequence[int], to_factors: Sequence[int],
                      shape: Sequence[int]) -> np.ndarray:
    """Nearest-neighbour map between two block grids of the same volume (blocks of ``*_factors`` voxels)."""
    out = a
    for axis in range(3):
        f_from, f_to = int(from_factors[axis]), int(to_factors[axis])
        if f_from == f_to and out.shape[axis] == shape[axis]:
            continue
        if f_from % f_to == 0 and shape[axis] <= out.shape[axis] * (f_from // f_to):
            out = np.repeat(out, f_from // f_to, axis=axis)
            if out.shape[axis] != shape[axis]:
                out = np.take(out, np.arange(shape[axis]), axis=axis)
        else:
            index = np.minimum((np.arange(shape[axis]) * f_to) // f_from, out.shape[axis] - 1)
            out = np.take(out, index, axis=axis)
    return np.ascontiguousarray(out, dtype=np.float32)


# ----------------------------------------------------------------------------------------------
# Clean-up: what the paper does after eq. 21 (largest component, holes) plus what touches the
# head but is not head (cushions, cloth, head holders, streaks)
# ----------------------------------------------------------------------------------------------

#: 4-connectivity inside each axial slice, no links between slices (per-slice 2-D labelling).
_IN_SLICE = np.zeros((3, 3, 3), dtype=bool)
_IN_SLICE[1] = ndi.generate_binary_structure(2, 1)


def _shifted_combine(mask: np.ndarray, offsets: Sequence[tuple[int, ...]], erode: bool) -> np.ndarray:
    """AND (erosion) or OR (dilation) of shifted copies of a boolean volume.

    ``offsets`` are (dy, dx) in-slice or (dz, dy, dx); ``out[p] = op(mask[p + o])``.
    Outside the volume counts as True for erosion and False for dilation, so
    neither an opening nor a closing creates or removes anything at the border.
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


def _box_opening(mask: np.ndarray, size: Sequence[int]) -> np.ndarray:
    """Opening with a (nz, ny, nx) box (outside is background): the union of all boxes inside ``mask``.

    Erosion by [0, n-1] windows then dilation by [-(n-1), 0] windows, axis by axis.
    """
    pad = [(0, max(0, n - 1)) for n in size]
    out = np.pad(mask, pad)
    for axis, n in enumerate(size):
        unit = tuple(1 if a == axis else 0 for a in range(3))
        for _ in range(n - 1):
            out = _shifted_combine(out, [unit], erode=True)
    for axis, n in enumerate(size):
        unit = tuple(-1 if a == axis else 0 for a in range(3))
        for _ in range(n - 1):
            out = _shifted_combine(out, [unit], erode=False)
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
    """In-slice erosion by an (octagonal) disk of ``radius_mm``; fast AND of shifted views."""
    out = mask
    for step in _disk_steps(spacing_yx, radius_mm):
        out = _shifted_combine(out, step, erode=True)
    return out if out is not mask else mask.copy()


def dilate_disk(mask: np.ndarray, spacing_yx: Sequence[float], radius_mm: float) -> np.ndarray:
    """In-slice dilation by an (octagonal) disk of ``radius_mm``; fast OR of shifted views."""
    out = mask
    for step in _disk_steps(spacing_yx, radius_mm):
        out = _shifted_combine(out, step, erode=False)
    return out if out is not mask else mask.copy()


def open_disk(mask: np.ndarray, spacing_yx: Sequence[float], radius_mm: float) -> np.ndarray:
    """In-slice opening: removes what a disk of ``radius_mm`` does not fit in."""
    return dilate_disk(erode_disk(mask, spacing_yx, radius_mm), spacing_yx, radius_mm)


def close_disk(mask: np.ndarray, spacing_yx: Sequence[float], radius_mm: float) -> np.ndarray:
    """In-slice closing: bridges gaps narrower than the disk of ``radius_mm``."""
    return erode_disk(dilate_disk(mask, spacing_yx, radius_mm), spacing_yx, radius_mm)


def largest_component(mask: np.ndarray, structure: np.ndarray | None = None) -> np.ndarray:
    """The largest connected component of a boolean volume (6-connectivity by default)."""
    labels, n = ndi.label(mask, structure=structure)
    if n == 0:
        return np.zeros(mask.shape, dtype=bool)
    if n == 1:
        return labels == 1
    # count on a subsample first (bincount of a big label volume is slow); exact when close
    sample = labels[::2, ::2, ::2].reshape(-1)
    counts = np.bincount(sample, minlength=n + 1)
    counts[0] = 0
    order = np.argsort(counts)
    if counts[order[-2]] * 1.5 > counts[order[-1]]:
        counts = np.bincount(labels[mask], minlength=n + 1)
        counts[0] = 0
    return labels == np.argmax(counts)


def fill_holes_per_slice(mask: np.ndarray) -> np.ndarray:
    """Fill every background region that does not reach the border of its axial slice.

    This is a superset of the 3-D hole filling (a 3-D cavity never reaches a slice
    border), and also closes the nasal cavity, mouth and ear canals in the slices
    where they are enclosed although they open to the outside in 3-D.
    """
    labels, n = ndi.label(~mask, structure=_IN_SLICE)
    if n == 0:
        return mask.copy()
    border = np.concatenate([labels[:, 0, :].ravel(), labels[:, -1, :].ravel(),
                             labels[:, :, 0].ravel(), labels[:, :, -1].ravel()])
    outside = np.zeros(n + 1, dtype=bool)
    outside[border] = True
    outside[0] = False
    return ~outside[labels]


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
    cavities = fill_holes_per_slice(closed) & ~closed
    seals = closed & ~mask & dilate_disk(cavities, spacing_yx, radius_mm)
    return fill_holes_per_slice(mask | cavities | seals)


def _bounding_box(mask: np.ndarray, margin: Sequence[int]) -> tuple[slice, ...] | None:
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


def estimate_noise(img: np.ndarray, max_samples: int = 1_000_000) -> float:
    """Standard deviation of white noise in ``img`` from neighbour differences (robust MAD).

    Most pairs of x-neighbours lie in flat regions (air, brain), where their
    difference is noise with standard deviation ``sqrt(2) * sigma``; the median
    absolute difference ignores the edges.
    """
    step = max(1, img.shape[0] * img.shape[1] // max(1, max_samples // max(1, img.shape[2])))
    rows = img.reshape(-1, img.shape[2])[::step]
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


def _component_extents(labels: np.ndarray, n: int, spacing_yx: Sequence[float]) -> np.ndarray:
    """In-slice bounding-box diagonal (mm) of every label 1..n (index 0 unused)."""
    dy, dx = spacing_yx
    extent = np.zeros(n + 1)
    for index, sl in enumerate(ndi.find_objects(labels), start=1):
        if sl is not None:
            extent[index] = math.hypot((sl[1].stop - sl[1].start) * dy, (sl[2].stop - sl[2].start) * dx)
    return extent


def head_envelope(tissue: np.ndarray, spacing_yx: Sequence[float], opening_mm: float = 2.5,
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
                 level: float = 0.85, thickness_mm: float = 2.0, low: float = 0.4) -> np.ndarray:
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
        (:func:`head_envelope` of the voxels ``>= level``), so intermediate
        regions enclosed by skin (metal-streak shadows, sinus walls) are never
        cushion.

    Darker voxels in the mask are narrow gaps the TV term bridged (between an
    ear and the scalp), not cushion either.  Returns a subset of ``mask``.
    """
    band = mask & (smooth < np.float32(level)) & (smooth > np.float32(low)) & ~envelope
    dz, dy, dx = (float(h) for h in spacing)
    size = tuple(min(n, max(2, 1 + math.ceil(thickness_mm / h))) for n, h in zip(mask.shape, (dz, dy, dx)))
    return _box_opening(band, size)


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
                      alignment: float = 0.85, elongation: float = 2.0) -> np.ndarray:
    """Which labelled thin components (1..n) are metal streaks: long and pointing at the metal.

    A streak is a ray from a dense insert: a component in a slice with metal whose in-plane
    principal axis (of its pixel positions in mm) is at least ``elongation`` times longer than
    its width and makes ``|cos| >= alignment`` with the direction from the nearest metal pixel
    to the component's centroid. Lips and ear rims run along the skin, across such rays.
    Returns a bool array of length n + 1 (index 0 False).
    """
    out = np.zeros(n + 1, dtype=bool)
    if not n or not metal.any():
        return out
    dy, dx = (float(h) for h in spacing_yx)
    with_metal = np.flatnonzero(metal.any(axis=(1, 2)))
    for index, sl in enumerate(ndi.find_objects(labels), start=1):
        if sl is None:
            continue
        ks = np.arange(sl[0].start, sl[0].stop)
        ks = ks[np.isin(ks, with_metal)]
        if ks.size == 0:
            continue
        kk, jj, ii = np.nonzero(labels[sl] == index)
        if kk.size < 3:
            continue
        pts = np.stack([(jj + sl[1].start) * dy, (ii + sl[2].start) * dx], axis=1)
        centre = pts.mean(axis=0)
        cov = np.cov((pts - centre).T)
        evals, evecs = np.linalg.eigh(cov)
        if evals[0] > 0 and math.sqrt(evals[1] / evals[0]) < elongation:
            continue                                   # not elongated (a straight line has evals[0] = 0)
        mj, mi = np.nonzero(metal[ks].any(axis=0))
        mpts = np.stack([mj * dy, mi * dx], axis=1)
        nearest = mpts[np.argmin(((mpts - centre) ** 2).sum(axis=1))]
        radial = centre - nearest
        norm = float(np.hypot(*radial))
        if norm > 0 and abs(float(evecs[:, 1] @ radial)) / norm >= alignment:
            out[index] = True
    return out


def clean_head_mask(mask: np.ndarray, data: np.ndarray, window: tuple[float, float], spacing: Sequence[float],
                    opening_mm: float = 2.5, cushion_level: float | None = 0.85, cushion_mm: float = 2.0,
                    max_thin_extent_mm: float = 50.0, close_mm: float = 6.0, envelope_mm: float = 3.0,
                    noise: float | None = None, metal_level: float | None = 3.0,
                    streak_close_mm: float = 3.0, streak_reach_mm: float = 40.0) -> tuple[np.ndarray, dict]:
    """The paper's clean-up of the thresholded soft membership, extended to real scans.

    1. Envelope: the filled outline of the head's own tissue (windowed
       intensity ``>= cushion_level``; :func:`head_envelope`).
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
    box = _bounding_box(mask, margin)
    if box is None:
        raise SegmentationError("nothing in the volume is brighter than air: no head found")
    work = mask[box]
    low, high = window
    smooth = np.subtract(data[box], np.float32(low), dtype=np.float32)
    smooth *= np.float32(1.0 / (high - low))
    if noise is None:
        noise = estimate_noise(smooth)
    sigma = smoothing_sigma(noise)
    if sigma > 0:
        smooth = ndi.gaussian_filter(smooth, sigma=sigma, mode="nearest", truncate=3.0)
    stats.update(noise=noise, smoothing_sigma=sigma)
    level = 0.85 if cushion_level is None else float(cushion_level)
    envelope = head_envelope(work & (smooth >= np.float32(level)), yx, opening_mm, envelope_mm)
    if cushion_level is not None:
        # heavier smoothing widens the skin's own intermediate rim: demand a correspondingly thicker layer
        thickness = cushion_mm + 2.0 * max(0.0, sigma - 0.5) * max(dz, dy, dx)
        cushion = find_cushion(work, smooth, spacing, envelope, level, thickness)
        stats["cushion_voxels"] = int(np.count_nonzero(cushion))
        work &= ~cushion
    del smooth
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
    labels, n = ndi.label(thin)
    head = core
    if n:
        total = np.bincount(labels[thin], minlength=n + 1)
        inside = np.bincount(labels[envelope & thin], minlength=n + 1)
        keep = (_component_extents(labels, n, yx) <= max_thin_extent_mm) | (2 * inside > total)
        if metal is not None:
            streak = streak_components(labels, n, metal, yx) & ~(2 * inside > total)
            stats["streak_voxels"] = int(total[streak & keep].sum())
            keep &= ~streak
        keep[0] = False
        stats["thin_kept_voxels"] = int(total[keep].sum())
        stats["thin_dropped_voxels"] = int(total[1:].sum() - total[keep].sum())
        head = largest_component(core | keep[labels])
    del labels, thin
    head = fill_cavities(head, yx, close_mm) if close_mm > 0 else fill_holes_per_slice(head)
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
    ears, lies 90-130 mm below the vertex; the shoulders 200 mm or more). Going down from it the cross-section shrinks to the neck; the
    trunk starts at the first slice whose area exceeds ``area_jump`` times the
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


# ----------------------------------------------------------------------------------------------
# The whole step
# ----------------------------------------------------------------------------------------------

def _solve_pyramid(img: np.ndarray, spacing: Sequence[float], lam: float, theta: float, tau: float | None,
                   levels_mm: Sequence[float], level_iterations: Sequence[int], iterations: int, inner: int,
                   tolerance: float, threads: int) -> tuple[dict, dict]:
    """Eq. 16-21 coarse to fine: block-mean levels of ~``levels_mm`` voxels, then the full grid.

    Each level starts from the previous one's membership q, means (c1, c2) and
    dual s (nearest-neighbour upsampled; s is dimensionless, |s| <= 1, so the
    stored s/h is rescaled by h_coarse/h_fine).  Iterations of a level that
    does not exist (the grid is already that coarse) move to the next level.
    """
    two_d = img.shape[0] == 1
    def bound(h):
        return tau_bound(h[1:] if two_d else h)
    plan: list[tuple[tuple[int, int, int], int]] = []
    carry = 0
    counts = list(level_iterations) + [0] * max(0, len(levels_mm) - len(level_iterations))
    for mm, n in sorted(zip((float(m) for m in levels_mm), counts), reverse=True):
        carry += int(n)
        fac = tuple(min(fi, ni) for fi, ni in zip(_coarse_factors(spacing, mm), img.shape))
        if two_d:
            fac = (1,) + fac[1:]
        if max(fac) == 1:
            continue  # the grid is already this coarse: these iterations go to a finer level
        if plan and fac == plan[-1][0]:
            plan[-1] = (fac, plan[-1][1] + carry)
        else:
            plan.append((fac, carry))
        carry = 0
    iterations = int(iterations) + carry
    info: dict[str, Any] = {"levels": [], "tau": None}
    q = c = sig = None
    prev = None
    for fac, n in plan:
        if n <= 0:
            continue
        level_img = _block_mean(img, fac)
        level_spacing = tuple(h * f for h, f in zip(spacing, fac))
        if prev is not None:
            q = _resample_nearest(q, prev, fac, level_img.shape)
            sig = tuple(_resample_nearest(sa * np.float32(fp / ff), prev, fac, level_img.shape)
                        for sa, fp, ff in zip(sig, prev, fac))
        level_tau = bound(level_spacing) if tau is None else tau * min(f * f for f in fac)
        res = chan_vese_soft(level_img, level_spacing, lam, theta, level_tau, n, inner, tolerance,
                             q0=q, c0=c, sig0=sig, threads=threads)
        info["levels"].append(dict(factors=tuple(int(f) for f in fac), shape=tuple(level_img.shape),
                                   iterations=res["iterations"], change=res["change"]))
        q, c, sig, prev = res["q"], (res["c1"], res["c2"]), res["sig"], fac
        del res, level_img
    if prev is not None:
        q = _resample_nearest(q, prev, (1, 1, 1), img.shape)
        sig = tuple(_resample_nearest(sa * np.float32(fp), prev, (1, 1, 1), img.shape) for sa, fp in zip(sig, prev))
    fine_tau = bound(spacing) if tau is None else tau
    res = chan_vese_soft(img, spacing, lam, theta, fine_tau, iterations, inner, tolerance,
                         q0=q, c0=c, sig0=sig, threads=threads)
    info.update(tau=fine_tau, fine_iterations=res["iterations"], fine_change=res["change"])
    return res, info


def segment_head(ct: CTVolume, *, lam: float = 3.0, theta: float = 0.1, tau: float | None = None,
                 iterations: int = 6, levels_mm: Sequence[float] = (2.0,),
                 level_iterations: Sequence[int] = (20,), inner: int = 1, tolerance: float = 1e-4,
                 window: tuple[float, float] | None = None, threshold: float = 0.5, cleanup: bool = True,
                 opening_mm: float = 2.5, cushion_level: float | None = 0.85, cushion_mm: float = 2.0,
                 close_mm: float = 6.0, slices: Sequence[int] | None = None, threads: int | None = None,
                 max_memory_gb: float | None = MEMORY_BUDGET_GB) -> Segmentation:
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

    Returns
    -------
    Segmentation
        ``mask`` (bool), ``probability`` (q of eq. 20, float32 in [0, 1]),
        ``c1``/``c2`` (eq. 17, windowed units), ``iterations`` (outer
        iterations of all levels), ``ct`` and ``meta`` (window, parameters,
        solver levels, clean-up statistics).
    """
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
    if threads is None:
        threads = min(2, os.cpu_count() or 1)
    spacing = tuple(float(h) for h in ct.spacing)
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
                f"{max_memory_gb:g} GB budget; downsample the scan on import by {factor} (load_ct(..., "
                f"downsample={factor}), CLI --downsample {factor}, import dialog 'Downsample') for about "
                f"{need / factor ** 3:.3g} GB, or pass max_memory_gb=None")
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
    img = window_intensities(data, window)
    if slices is not None:
        seg = _segment_slices(ct, img, spacing, params, clean_kw, [int(k) for k in slices], threads)
        return _check_result(seg, spacing, seg_warnings)
    res, info = _solve_pyramid(img, spacing, lam, theta, tau, levels_mm, level_iterations, iterations, inner,
                               tolerance, threads)
    del img
    q = res.pop("q")
    stats: dict[str, Any] = {}
    mask = q > np.float32(threshold)
    if cleanup:
        mask, stats = clean_head_mask(mask, data, window, spacing, **clean_kw)
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
    return _check_result(seg, spacing, seg_warnings)


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
        res, info = _solve_pyramid(img[k:k + 1], spacing, params["lam"], params["theta"], params["tau"],
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
