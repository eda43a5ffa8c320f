"""Step 2: head segmentation with the 3D Chan-Vese soft model (paper eq. 16-21) and clean-up.

The model (eq. 16) is solved on the windowed intensities ``I`` in [0, 1] by
alternating the region means (eq. 17), the closed-form q step (eq. 20) and
Chambolle's dual projection (eq. 21), in 3-D with the voxel spacing in mm.
The soft membership is then thresholded and cleaned up the way the paper
describes (largest connected component, holes filled), plus the removal of
what touches the head but is not head (cushions, cloth, head holders).

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
is measured in mm^2 of surface and ``lam`` is in 1/mm for ``I`` in [0, 1]:
a structure is kept when ``lam * |r|`` exceeds its mean curvature, roughly when
it is thicker than ``2 / lam`` mm.
"""
from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy import ndimage as ndi

from .ct_volume import CTVolume
from .errors import SegmentationError


@dataclass
class Segmentation:
    """Result of :func:`segment_head`.

    Attributes
    ----------
    mask : ndarray of bool, shape (nz, ny, nx)
        The cleaned head mask.
    probability : ndarray of float32, shape (nz, ny, nx)
        The soft membership p of eq. 16 before clean-up.
    c1, c2 : float
        Mean windowed intensity inside (head) and outside (air), eq. 17.
    iterations : int
        Outer iterations run.
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

def auto_window(data: np.ndarray, max_samples: int = 2_000_000, bins: int = 512) -> tuple[float, float]:
    """Air and soft-tissue levels of a head scan, from its histogram.

    Otsu's threshold splits the histogram into a dark (air, cloth) and a bright
    (tissue, bone) class; the window is (mode of the dark class, mode of the
    bright class).  In CT the bright mode is the soft-tissue/brain peak (bone is
    spread thinly over a long tail), so the window maps air to 0 and soft tissue
    to 1 whatever the units (HU, uncalibrated raw, 8-bit), and the Chan-Vese
    boundary lands near the middle of the air/skin edge.

    Parameters
    ----------
    data : ndarray
        The volume.
    max_samples : int
        The histogram is taken on a regular subsample of at most this many voxels.
    bins : int
        Histogram bins between the 0.1 and 99.9 percentiles.

    Returns
    -------
    (low, high) : tuple of float
        Intensity mapped to 0 and to 1.
    """
    flat = np.asarray(data).reshape(-1)
    step = max(1, flat.size // max_samples)
    sample = flat[::step].astype(np.float32, copy=False)
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
                 slab: int = 2, threads: int = 1):
        self.img = img
        self.shape = img.shape
        self.spacing = tuple(float(h) for h in spacing)
        self.theta = float(theta)
        self.tau = float(tau)
        self.neg_q = (q * np.float32(-1.0 / theta)).astype(np.float32)
        if sig is None:
            sig = tuple(np.zeros(self.shape, np.float32) for _ in range(3))
        else:
            for axis, s in enumerate(sig):  # re-impose the invariant
                idx = [slice(None)] * 3
                idx[axis] = -1
                s[tuple(idx)] = 0.0
        self.sig = sig
        self.weights = tuple(np.float32(1.0 / h ** 2) for h in self.spacing)
        nz = self.shape[0]
        self.slab = max(1, int(slab))
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

    def membership(self) -> np.ndarray:
        """q = -theta * neg_q, the constrained soft membership in [0, 1]."""
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
                   slab: int = 2) -> dict[str, Any]:
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
        Warm start: membership, (c1, c2) and scaled dual ``s_a / h_a``.

    Returns
    -------
    dict with ``q`` (membership in [0, 1], float32), ``c1``, ``c2`` (the means
    used in the last q step), ``iterations`` run, ``change`` (last mean |dq|)
    (last RMS change of q) and ``sig`` (the scaled dual, for warm starts).
    """
    if tau is None:
        tau = tau_bound(spacing)
    q = img if q0 is None else q0
    count = img.size
    state = _ChanVeseState(img, q, spacing, theta, tau, sig=sig0, slab=slab, threads=threads)
    try:
        if c0 is None:
            c1, c2 = _region_means(float(q.sum(dtype=np.float64)),
                                   float(np.vdot(img.ravel(), q.ravel())), state.img_sum, count)
        else:
            c1, c2 = c0
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
        return dict(q=state.membership(), c1=used[0], c2=used[1], iterations=done, change=change,
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
    mz, my, mx = img.shape[0] // fz, img.shape[1] // fy, img.shape[2] // fx
    out = img.reshape(mz, fz, my, fy, mx, fx).mean(axis=(1, 3, 5), dtype=np.float32)
    return out.astype(np.float32, copy=False)


def _upsample_repeat(a: np.ndarray, factors: Sequence[int], shape: Sequence[int]) -> np.ndarray:
    """Nearest-neighbour inverse of :func:`_block_mean` cropped to ``shape``."""
    out = a
    for axis, f in enumerate(factors):
        if f > 1:
            out = np.repeat(out, f, axis=axis)
    return np.ascontiguousarray(out[: shape[0], : shape[1], : shape[2]])


def _upsample_linear(a: np.ndarray, factors: Sequence[int], shape: Sequence[int]) -> np.ndarray:
    """Linear interpolation of block-mean data back to the fine grid (block centres aligned)."""
    coords = []
    for n_fine, f, n_coarse in zip(shape, factors, a.shape):
        x = (np.arange(n_fine, dtype=np.float32) + 0.5) / f - 0.5
        coords.append(np.clip(x, 0, n_coarse - 1))
    out = a
    for axis, x in enumerate(coords):
        if factors[axis] == 1:
            continue
        i0 = np.floor(x).astype(np.intp)
        i1 = np.minimum(i0 + 1, a.shape[axis] - 1)
        w = (x - i0).astype(np.float32)
        shape_w = [1, 1, 1]
        shape_w[axis] = -1
        w = w.reshape(shape_w)
        lo = np.take(out, i0, axis=axis)
        hi = np.take(out, i1, axis=axis)
        hi -= lo
        hi *= w
        lo += hi
        out = lo
    return np.ascontiguousarray(out, dtype=np.float32)


# ----------------------------------------------------------------------------------------------
# Clean-up: what the paper does after eq. 21 (largest component, holes) plus what touches the
# head but is not head (cushions, cloth, head holders, streaks)
# ----------------------------------------------------------------------------------------------

#: 4-connectivity inside each axial slice, no links between slices (per-slice 2-D labelling).
_IN_SLICE = np.zeros((3, 3, 3), dtype=bool)
_IN_SLICE[1] = ndi.generate_binary_structure(2, 1)


def _disk(spacing_yx: Sequence[float], radius_mm: float) -> np.ndarray:
    """In-slice disk of ``radius_mm`` as a (1, h, w) structuring element (anisotropic pixels)."""
    hy, hx = (float(h) for h in spacing_yx)
    ry, rx = int(radius_mm / hy), int(radius_mm / hx)
    y, x = np.mgrid[-ry:ry + 1, -rx:rx + 1]
    disk = (y * hy) ** 2 + (x * hx) ** 2 <= radius_mm ** 2 + 1e-9
    return disk[None]


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

    An octagon = square (half-widths ay, ax) + diamond (b crosses); a regular
    octagon touching the circle on the axes and diagonals has a = 0.414 r and
    b = 0.586 r.  Lines are split in unit steps, so every footprint has <= 3 pixels.
    """
    hy, hx = (float(h) for h in spacing_yx)
    ry, rx = radius_mm / hy, radius_mm / hx
    b = int(round(0.586 * min(ry, rx)))
    ay = max(0, int(round(ry)) - b)
    ax = max(0, int(round(rx)) - b)
    steps: list[list[tuple[int, int]]] = []
    steps += [[(-1, 0), (0, 0), (1, 0)]] * (ay // 2) + ([[(0, 0), (1, 0)], [(-1, 0), (0, 0)]] if ay % 2 else [])
    steps += [[(0, -1), (0, 0), (0, 1)]] * (ax // 2) + ([[(0, 0), (0, 1)], [(0, -1), (0, 0)]] if ax % 2 else [])
    steps += [[(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)]] * b
    return steps


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
        counts = np.bincount(labels.reshape(-1), minlength=n + 1)
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


def estimate_noise(img: np.ndarray, max_samples: int = 4_000_000) -> float:
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
    noise std is multiplied by ``(2 sqrt(pi) s)^(-d/2)``; at least 0.5 voxel.
    """
    if noise <= target:
        return 0.5
    return max(0.5, (noise / target) ** (2.0 / ndim) / (2.0 * math.sqrt(math.pi)))


def _component_extents(labels: np.ndarray, n: int, spacing_yx: Sequence[float]) -> np.ndarray:
    """In-slice bounding-box diagonal (mm) of every label 1..n (index 0 unused)."""
    dy, dx = spacing_yx
    extent = np.zeros(n + 1)
    for index, sl in enumerate(ndi.find_objects(labels), start=1):
        if sl is not None:
            extent[index] = math.hypot((sl[1].stop - sl[1].start) * dy, (sl[2].stop - sl[2].start) * dx)
    return extent


def find_apparatus(mask: np.ndarray, smooth: np.ndarray, spacing: Sequence[float], bright_level: float = 1.1,
                   shell_mm: float = 3.0, min_extent_mm: float = 60.0, exposed_fraction: float = 0.5) -> np.ndarray:
    """Long thin high-density shells lying in the air: head holders, table tops, metal streaks.

    Bone is the only dense tissue of the head and it is covered by skin,
    whereas a plastic/carbon head holder or a table top is a dense shell a few
    mm thick and a hand wide or more, with air (or pillow) on both sides.
    Dense voxels (``smooth`` above ``bright_level`` in window units, about
    +100 HU for CT) that an in-slice opening with a ``shell_mm`` disk removes
    are thin dense structures; an in-slice piece of them is apparatus when it
    spans more than ``min_extent_mm`` and more than ``exposed_fraction`` of its
    pixels are within ``shell_mm`` of the outside air of that slice (thin bone
    such as the frontal sinus wall is covered by the scalp or borders enclosed
    air only).  The shells are
    grown by one pixel inside ``mask`` to take their partial-volume rim along.
    """
    dz, dy, dx = (float(h) for h in spacing)
    bright = mask & (smooth > np.float32(bright_level))
    if not bright.any():
        return bright
    thin = bright & ~open_disk(bright, (dy, dx), shell_mm)
    labels, n = ndi.label(thin, structure=_IN_SLICE)
    if n == 0:
        return thin
    candidate = _component_extents(labels, n, (dy, dx)) > min_extent_mm
    candidate[0] = False
    if not candidate.any():
        return np.zeros(mask.shape, dtype=bool)
    near_air = dilate_disk(~fill_holes_per_slice(mask), (dy, dx), shell_mm)
    size = np.bincount(labels.reshape(-1), minlength=n + 1)
    exposed = np.bincount(labels[near_air & thin], minlength=n + 1)
    apparatus = candidate & (exposed > exposed_fraction * np.maximum(size, 1))
    return _shifted_combine(apparatus[labels], [(-1, 0), (1, 0), (0, -1), (0, 1)], erode=False) & mask


def tissue_envelope(head: np.ndarray, smooth: np.ndarray, spacing_yx: Sequence[float], level: float = 0.85,
                    close_mm: float = 3.0) -> np.ndarray:
    """Filled per-slice envelope of the tissue (``smooth >= level``) of ``head``, closed with a ``close_mm`` disk."""
    return fill_holes_per_slice(close_disk(head & (smooth >= np.float32(level)), spacing_yx, close_mm))


def find_cushion(mask: np.ndarray, smooth: np.ndarray, spacing: Sequence[float], level: float = 0.85,
                 thickness_mm: float = 2.0, low: float = 0.4, envelope: np.ndarray | None = None) -> np.ndarray:
    """Voxels of ``mask`` that belong to a pillow or foam layer pressed against the head.

    A pillow or cloth pressed against the head is denser than air but clearly
    less dense than skin, fat and muscle; where it is compressed enough to pass
    the air/skin decision it forms a layer of intermediate intensity several mm
    thick *outside* the skin.  The partial-volume rim of a real skin surface is
    as dark but only about a point-spread width thick.  So the cushion is the
    intermediate part of the mask (smoothed windowed intensity between ``low``
    and ``level``) that (a) contains a box spanning at least ``thickness_mm``
    along each axis (a morphological opening; a skin band of normal thickness
    t only holds such a box when t > thickness_mm / sqrt(2), whatever its
    orientation) and (b) lies outside ``envelope``, the envelope of the tissue
    (default :func:`tissue_envelope` of ``mask``), so that intermediate regions
    inside the skin (metal-streak shadows, sinus walls) are never cushion.  Darker voxels inside the mask are narrow gaps
    the TV term bridged (between an ear and the scalp): they are not cushion.

    Returns the boolean cushion mask (a subset of ``mask``).
    """
    tissue = smooth >= np.float32(level)
    band = mask & ~tissue & (smooth > np.float32(low))
    dz, dy, dx = (float(h) for h in spacing)
    size = tuple(min(n, max(2, 1 + math.ceil(thickness_mm / h))) for n, h in zip(mask.shape, (dz, dy, dx)))
    thick = _box_opening(band, size)
    if not thick.any():
        return thick
    if envelope is None:
        envelope = tissue_envelope(mask, smooth, (dy, dx), level)
    return thick & ~envelope


def clean_head_mask(mask: np.ndarray, data: np.ndarray, window: tuple[float, float], spacing: Sequence[float],
                    opening_mm: float = 2.5, bright_level: float | None = 1.1, shell_mm: float = 3.0,
                    cushion_level: float | None = 0.85, cushion_mm: float = 2.0,
                    max_thin_extent_mm: float = 50.0, close_mm: float = 2.0,
                    noise: float | None = None) -> tuple[np.ndarray, dict]:
    """The paper's clean-up of the thresholded soft membership, extended to real scans.

    0. A lightly smoothed windowed copy of the data (unclipped; sigma from the
       noise level, :func:`smoothing_sigma`) is used by steps 1-2.
    1. Apparatus: thin dense shells (head holders, table tops, metal streaks)
       are removed (:func:`find_apparatus`).
    2. Cushions: thick intermediate-density layers outside the skin are removed
       (:func:`find_cushion`).
    3. Thin attachments: a per-slice opening with a disk of ``opening_mm``
       separates what hangs on the head by a thin bridge; the largest 3-D
       component of the opened mask is the head core (the paper's "largest
       connected component").  What the opening took away is given back
       component by component when the component is compact (in-slice extent
       at most ``max_thin_extent_mm``: ear rims, nose tip, lips) or lies mostly
       inside the tissue envelope of the core (nasal septum, sinus walls); long
       thin structures outside the head (cloth, tables, streaks) are dropped.
    4. Holes: a per-slice closing with a ``close_mm`` disk bridges narrow
       openings (nostrils, streak shadows), then every hole is filled per
       axial slice (which includes the 3-D holes), so the head mask is the
       filled outer skin envelope.

    Parameters
    ----------
    mask : ndarray of bool
        Thresholded membership.
    data, window :
        The CT intensities and the window mapping air to 0 and soft tissue to 1.
    spacing : (dz, dy, dx) mm

    Returns
    -------
    (mask, stats)
    """
    stats: dict[str, Any] = {}
    dz, dy, dx = (float(h) for h in spacing)
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
    smooth = ndi.gaussian_filter(smooth, sigma=sigma, mode="nearest", truncate=3.0)
    stats.update(noise=noise, smoothing_sigma=sigma)
    if bright_level is not None:
        apparatus = find_apparatus(work, smooth, spacing, bright_level, shell_mm)
        stats["apparatus_voxels"] = int(apparatus.sum())
        work = work & ~apparatus
    # at least a 3x3-pixel square, or coarse grids keep 2-pixel shells
    opening_mm = max(opening_mm, 1.5 * max(dy, dx))
    opened = open_disk(work, (dy, dx), opening_mm)
    core = largest_component(opened)
    if not core.any():
        raise SegmentationError(f"no part of the head is thicker than the {2 * opening_mm:g} mm opening")
    # the envelope comes from the core, which no longer holds a holder that would enclose the pillow
    envelope = tissue_envelope(core, smooth, (dy, dx), 0.85 if cushion_level is None else cushion_level)
    if cushion_level is not None:
        cushion = find_cushion(work, smooth, spacing, cushion_level, cushion_mm, envelope=envelope)
        stats["cushion_voxels"] = int(cushion.sum())
        work &= ~cushion
        core &= ~cushion
    del smooth
    thin = work & ~opened
    labels, n = ndi.label(thin)
    head = core
    if n:
        total = np.bincount(labels.reshape(-1), minlength=n + 1)
        inside = np.bincount(labels[envelope], minlength=n + 1)
        keep = (_component_extents(labels, n, (dy, dx)) <= max_thin_extent_mm) | (2 * inside > total)
        keep[0] = False
        stats["thin_kept_voxels"] = int(total[keep].sum())
        stats["thin_dropped_voxels"] = int(total[1:][~keep[1:]].sum())
        head = core | keep[labels]
    head = largest_component(head)
    if close_mm > 0:
        head = close_disk(head, (dy, dx), close_mm)
    head = fill_holes_per_slice(head)
    out = np.zeros(mask.shape, dtype=bool)
    out[box] = head
    stats["head_voxels"] = int(head.sum())
    return out, stats


# ----------------------------------------------------------------------------------------------
# The whole step
# ----------------------------------------------------------------------------------------------

def _solve_coarse_to_fine(img, spacing, lam, theta, tau, coarse_mm, coarse_iterations, iterations,
                          inner, tolerance, threads):
    """Eq. 16-21 on a ~``coarse_mm`` grid, then warm-started on the full grid."""
    factors = _coarse_factors(spacing, coarse_mm) if coarse_mm else (1, 1, 1)
    if img.shape[0] == 1:
        factors = (1,) + tuple(factors[1:])
    tau_spacing = spacing if img.shape[0] > 1 else spacing[1:]
    info: dict[str, Any] = {"coarse_factors": tuple(int(f) for f in factors)}
    q0 = c0 = sig0 = None
    if max(factors) > 1 and coarse_iterations > 0:
        coarse_img = _block_mean(img, factors)
        coarse_spacing = tuple(h * f for h, f in zip(spacing, factors))
        coarse_tau = tau_bound(coarse_spacing if img.shape[0] > 1 else coarse_spacing[1:]) if tau is None \
            else tau * min(f * f for f in factors)
        res = chan_vese_soft(coarse_img, coarse_spacing, lam, theta, coarse_tau, coarse_iterations, inner,
                             tolerance, threads=threads)
        info.update(coarse_iterations=res["iterations"], coarse_change=res["change"])
        q0 = _upsample_linear(res["q"], factors, img.shape)
        c0 = (res["c1"], res["c2"])
        # s is dimensionless (|s| <= 1), so the scaled dual s/h is rescaled by h_coarse/h_fine
        sig0 = tuple(_upsample_repeat(s * np.float32(f), factors, img.shape) for s, f in zip(res["sig"], factors))
        del res
    fine_tau = tau_bound(tau_spacing) if tau is None else tau
    res = chan_vese_soft(img, spacing, lam, theta, fine_tau, iterations, inner, tolerance,
                         q0=q0, c0=c0, sig0=sig0, threads=threads)
    info.update(fine_iterations=res["iterations"], fine_change=res["change"], tau=fine_tau)
    return res, info


def segment_head(ct: CTVolume, *, lam: float = 1.0, theta: float = 0.1, tau: float | None = None,
                 iterations: int = 8, coarse_iterations: int = 40, inner: int = 1,
                 tolerance: float = 1e-4, window: tuple[float, float] | None = None,
                 coarse_mm: float = 2.0, threshold: float = 0.5, cleanup: bool = True,
                 opening_mm: float = 2.5, bright_level: float | None = 1.1,
                 cushion_level: float | None = 0.85, cushion_mm: float = 2.0,
                 slices: Sequence[int] | None = None, threads: int | None = None) -> Segmentation:
    """Segment the head with the 3-D Chan-Vese soft model (eq. 16-21) and clean it up.

    Parameters
    ----------
    ct : CTVolume
    lam : float
        lambda of eq. 16 in 1/mm for intensities windowed to [0, 1].
    theta : float
        Coupling of eq. 19-21 (mm); the paper's theta of eq. 20 is ``theta * lam``.
    tau : float, optional
        Dual step of eq. 21 (mm^2). Default :func:`tau_bound` of the grid.
    iterations, coarse_iterations : int
        Outer iterations (eq. 17, 20, 21) on the full grid and on the ~``coarse_mm`` grid.
    inner : int
        Chambolle steps (eq. 21) per outer iteration.
    tolerance : float
        Stop a level early when the RMS change of q per iteration falls below it.
    window : (low, high), optional
        Intensities mapped to 0 and 1. Default :func:`auto_window` (air and soft-tissue modes).
    coarse_mm : float
        Voxel size of the coarse level (0 for a single level).
    threshold : float
        Level of the soft membership taken as the head.
    cleanup : bool
        Apply :func:`clean_head_mask` (otherwise the mask is the thresholded membership).
    opening_mm, bright_level, cushion_level, cushion_mm :
        Clean-up parameters (see :func:`clean_head_mask`); ``None`` levels disable that removal.
    slices : sequence of int, optional
        The paper's mode: segment only these axial slices, each as a 2-D problem
        (eq. 16-21 with the in-plane gradient). The returned mask and membership
        are zero on every other slice; ``iterations`` is the largest count run.
    threads : int, optional
        Worker threads of the solver (default: up to 2).

    Returns
    -------
    Segmentation
    """
    if not isinstance(ct, CTVolume):
        raise SegmentationError(f"segment_head needs a CTVolume, got {type(ct).__name__}")
    data = ct.data
    if data.ndim != 3 or min(data.shape) < 1 or data.size < 8:
        raise SegmentationError(f"cannot segment a volume of shape {data.shape}")
    if not (lam > 0 and theta > 0 and (tau is None or tau > 0)):
        raise SegmentationError(f"lam, theta and tau must be positive (lam={lam}, theta={theta}, tau={tau})")
    if threads is None:
        threads = min(2, os.cpu_count() or 1)
    spacing = tuple(float(h) for h in ct.spacing)
    if window is None:
        window = auto_window(data)
    window = (float(window[0]), float(window[1]))
    params = dict(lam=lam, theta=theta, tau=tau, iterations=iterations, coarse_iterations=coarse_iterations,
                  inner=inner, tolerance=tolerance, window=window, coarse_mm=coarse_mm, threshold=threshold,
                  cleanup=cleanup, opening_mm=opening_mm, bright_level=bright_level, cushion_level=cushion_level,
                  cushion_mm=cushion_mm,
                  slices=None if slices is None else [int(k) for k in slices])
    img = window_intensities(data, window)
    if slices is not None:
        return _segment_slices(ct, img, spacing, params, threads)
    res, info = _solve_coarse_to_fine(img, spacing, lam, theta, tau, coarse_mm, coarse_iterations, iterations,
                                      inner, tolerance, threads)
    q = res["q"]
    raw = q > np.float32(threshold)
    stats: dict[str, Any] = {}
    if cleanup:
        mask, stats = clean_head_mask(raw, data, window, spacing, opening_mm=opening_mm, bright_level=bright_level,
                                      cushion_level=cushion_level, cushion_mm=cushion_mm)
    else:
        mask = raw
    meta = dict(params=params, solver=info, cleanup=stats, mode="volume")
    return Segmentation(mask=mask, probability=q, c1=res["c1"], c2=res["c2"],
                        iterations=int(info["fine_iterations"]), ct=ct, meta=meta)


def _segment_slices(ct, img, spacing, params, threads) -> Segmentation:
    raise NotImplementedError
