"""The 3-D Chan-Vese soft model (paper eq. 16-21) solved with Chambolle's dual projection.

:func:`chan_vese_soft` minimises eq. 16 on one grid;
:func:`.chan_vese_pyramid.solve_pyramid` runs it coarse to fine.
:func:`~pdehead_addon.segment.segmentation.segment_head`
windows the intensities, calls the pyramid and cleans up the thresholded
membership (:mod:`.mask_cleanup`).

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
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Sequence

import numpy as np

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


def region_means(sum_q: float, sum_iq: float, sum_i: float, count: int) -> tuple[float, float]:
    """Eq. 17 from the sums of q, I q and I."""
    eps = 1e-12
    c1 = sum_iq / max(sum_q, eps)
    c2 = (sum_i - sum_iq) / max(count - sum_q, eps)
    return float(c1), float(c2)


def chan_vese_soft(img: np.ndarray, spacing: Sequence[float], lam: float, theta: float,
                   tau: float | None = None, iterations: int = 30, inner: int = 1,
                   tolerance: float = 0.0, q0: np.ndarray | None = None,
                   c0: tuple[float, float] | None = None, sig0=None, threads: int = 1,
                   slab: int | None = None, progress=None, outside: tuple[float, int] = (0.0, 0)) -> dict[str, Any]:
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
    outside : (sum of I, voxel count)
        A region beyond ``img`` where q = 0 (the air around a cropped grid): its
        intensities count in c2 of eq. 17 and its voxels in the RMS change.
    progress : callable, optional
        ``progress(iterations_done)`` after every outer iteration; it may raise
        :class:`~pdehead_addon.core.errors.Cancelled` (the worker threads are stopped).

    Returns
    -------
    dict with ``q`` (membership in [0, 1], float32), ``c1``, ``c2`` (the means
    used in the last q step), ``iterations`` run, ``change`` (last mean |dq|)
    (last RMS change of q) and ``sig`` (the scaled dual, for warm starts).
    """
    if tau is None:
        tau = tau_bound(spacing)
    q = img if q0 is None else q0  # a given q0 is taken over (modified in place)
    count = img.size + int(outside[1])
    if c0 is None:
        c1, c2 = region_means(float(q.sum(dtype=np.float64)), float(np.vdot(img.ravel(), q.ravel())),
                               float(img.sum(dtype=np.float64)) + float(outside[0]), count)
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
            c1, c2 = region_means(sums[0], sums[1], state.img_sum + float(outside[0]), count)
            change = math.sqrt(sums[2] / count)
            done = it + 1
            if progress is not None:
                progress(done)
            if change < tolerance:
                break
        return dict(q=state.membership(release=True), c1=used[0], c2=used[1], iterations=done, change=change,
                    sig=state.sig)
    finally:
        state.close()
