"""The 3-D Chan-Vese soft model (paper eq. 16-21) solved with Chambolle's dual projection.

:func:`chan_vese_soft` minimises eq. 16 on one grid; :func:`_solve_pyramid`
runs it coarse to fine.  :func:`~pdehead_addon.segmentation.segment_head`
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
        :class:`~pdehead_addon.errors.Cancelled` (the worker threads are stopped).

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
        c1, c2 = _region_means(float(q.sum(dtype=np.float64)), float(np.vdot(img.ravel(), q.ravel())),
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
            c1, c2 = _region_means(sums[0], sums[1], state.img_sum + float(outside[0]), count)
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
    reps = [int(f) // int(t) for f, t in zip(from_factors, to_factors)]
    if (all(int(f) % int(t) == 0 for f, t in zip(from_factors, to_factors))
            and all(n <= m * r for n, m, r in zip(shape, a.shape, reps))):
        # whole blocks: repeat along x on the small array, then strided writes in z and y
        # (3x less time than np.repeat axis by axis, which copies the growing array twice more)
        nz, ny, nx = (int(n) for n in shape)
        row = np.repeat(a, reps[2], axis=2)[:, :, :nx] if reps[2] > 1 else a[:, :, :nx]
        out = np.empty((nz, ny, nx), np.float32)
        if nz == a.shape[0] * reps[0] and ny == a.shape[1] * reps[1]:
            # the grid is whole blocks in z and y: one broadcast write (~35 % less time than the loop)
            out.reshape(a.shape[0], reps[0], a.shape[1], reps[1], nx)[...] = row[:, None, :, None, :]
            return out
        for k in range(reps[0]):
            for j in range(reps[1]):
                dst = out[k::reps[0], j::reps[1]]
                dst[...] = row[:dst.shape[0], :dst.shape[1]]
        return out
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
# Coarse to fine
# ----------------------------------------------------------------------------------------------

def _solve_pyramid(img: np.ndarray, spacing: Sequence[float], lam: float, theta: float, tau: float | None,
                   levels_mm: Sequence[float], level_iterations: Sequence[int], iterations: int, inner: int,
                   tolerance: float, threads: int, progress=None) -> tuple[dict, dict]:
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
    # progress: iterations run so far over the most that can run (a level may stop early)
    planned = max(1, sum(max(n, 0) for _, n in plan) + iterations)
    before = [0]

    def level_progress(done: int) -> None:
        if progress is not None:
            progress((before[0] + done) / planned, f"Chan-Vese iteration {before[0] + done} of at most {planned}")
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
                             q0=q, c0=c, sig0=sig, threads=threads, progress=level_progress)
        before[0] += n
        info["levels"].append(dict(factors=tuple(int(f) for f in fac), shape=tuple(level_img.shape),
                                   iterations=res["iterations"], change=res["change"]))
        q, c, sig, prev = res["q"], (res["c1"], res["c2"]), res["sig"], fac
        del res, level_img
    fine_tau = bound(spacing) if tau is None else tau
    if prev is not None and (FINE_BAND or img.size >= FINE_BAND_MIN_VOXELS) and not two_d and int(inner) == 1:
        # the full grid only in a band of coarse blocks around the coarse boundary
        res, band_info = _band_fine_solve(img, spacing, lam, theta, fine_tau, iterations, tolerance, q, sig, c,
                                          prev, progress=level_progress, threads=threads)
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
        q = _resample_nearest(q[coarse_box], prev, (1, 1, 1), shape)
        sig = tuple(_resample_nearest(sa[coarse_box] * np.float32(fp), prev, (1, 1, 1), shape)
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
#: (:func:`_band_fine_solve`) on every grid; False: only on grids of at least
#: :data:`FINE_BAND_MIN_VOXELS` (smaller ones solve the coarse head's box, :func:`_fine_crop`).
FINE_BAND = False
#: Grids of at least this many voxels run the full-resolution level in the band.  Smaller grids gain
#: nothing from it (CThead, 7.4 M voxels: 1.6-1.7 s CPU for segment_head either way, the band's index
#: building eats the saving) and keep the box solve, so their masks are unchanged (CThead, GE and the
#: phantom are the golden cases of the selection and the visible-face score).  On the 512 x 512 x 300
#: scan (78.6 M voxels) the solver takes 5.2-6.3 s CPU instead of 9.8-10.2 s (docs/benchmarks.md, issue 20).
FINE_BAND_MIN_VOXELS = 40_000_000
#: Coarse blocks are undecided when their membership lies in (UNDECIDED_Q, 1 - UNDECIDED_Q) or when
#: they touch the boundary of ``q > 0.5`` (either side, 26-neighbours); the band is those blocks grown
#: by FINE_BAND_MARGIN blocks.  Measured on the 512 x 512 x 300 scan (3 x 4 x 4 blocks): the undecided
#: blocks alone (1.0 M voxels) or grown by one block (6.9 M) break the mask (min per-slice Jaccard
#: 0.54 / 0.83); with the boundary's blocks on both sides (6.6 M voxels, 8.4 %) it is 0.9934.
UNDECIDED_Q = 0.02
FINE_BAND_MARGIN = 0
#: The band's sweep is split over the solver's threads in parts of at least this many voxels.
BAND_PART_VOXELS = 1_000_000


#: Also put in the band every block whose full-resolution intensities straddle the fine level's
#: boundary level (c1 + c2) / 2 (eq. 18: where the data term changes sign), so thin features the coarse
#: level smoothed away (nostrils, lips, ear rims) are solved at full resolution.  Measured against the
#: box solve: CThead 670 -> 66 voxels differ (per-slice Jaccard min 0.970 -> 0.997), the 512 x 512 x 300
#: scan 2,623 -> 1,110 (min 0.9923 -> 0.9931), the band 6.6 -> 7.3 M voxels.
FINE_BAND_STRADDLE = True


def _block_range(img: np.ndarray, factors: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """Minimum and maximum of ``img`` over blocks of ``factors`` voxels (the grid is whole blocks)."""
    fz, fy, fx = (int(f) for f in factors)
    lo = hi = None
    for dz in range(fz):
        for dy in range(fy):
            for dx in range(fx):
                view = img[dz::fz, dy::fy, dx::fx]
                if lo is None:
                    lo, hi = view.copy(), view.copy()
                else:
                    np.minimum(lo, view, out=lo)
                    np.maximum(hi, view, out=hi)
    return lo, hi


def _band_blocks(q_coarse: np.ndarray, margin: int, img: np.ndarray | None = None, factors=None,
                 level: float | None = None) -> np.ndarray:
    """Coarse blocks of the band: undecided or on the coarse boundary, grown by ``margin`` blocks (26-conn.).

    With ``img`` (the full grid, whole blocks of ``factors``) and ``level``, also the blocks whose
    intensities straddle ``level`` (:data:`FINE_BAND_STRADDLE`).
    """
    from scipy import ndimage
    lo = np.float32(UNDECIDED_Q)
    undecided = (q_coarse > lo) & (q_coarse < np.float32(1.0) - lo)
    if img is not None and level is not None:
        bmin, bmax = _block_range(img, factors)
        undecided |= (bmin < np.float32(level)) & (bmax > np.float32(level))
        del bmin, bmax
    inside = q_coarse > np.float32(0.5)
    cube = np.ones((3, 3, 3), bool)
    undecided |= ndimage.binary_dilation(inside, cube) & ~ndimage.binary_erosion(inside, cube, border_value=1)
    if margin > 0:
        undecided = ndimage.binary_dilation(undecided, cube, iterations=int(margin))
    return undecided


def _band_fine_solve(img: np.ndarray, spacing: Sequence[float], lam: float, theta: float, tau: float,
                     iterations: int, tolerance: float, q_coarse: np.ndarray, sig_coarse, c0, factors,
                     progress=None, margin: int | None = None, threads: int = 1) -> tuple[dict | None, dict]:
    """The full-resolution level of eq. 16-21 only in a band of coarse blocks around the coarse boundary.

    Outside the band the membership keeps the coarse level's value (nearest-neighbour upsampled; there
    the coarse q is within :data:`UNDECIDED_Q` of 0 or 1 and more than ``margin`` blocks from the
    coarse boundary).  Inside it the same iteration as :class:`_ChanVeseState` (eq. 20 and one eq. 21
    step per outer iteration, eq. 17 over the whole grid) runs on the band's blocks gathered into
    compact vectors, block after block; the q and s of a one-block ring around the band stay at their
    coarse values.  Narrow-band level sets (Adalsteinsson & Sethian 1995) make the same trade.
    Returns ``(None, {})`` when the grid is not whole blocks (the caller solves the box instead).
    """
    margin = FINE_BAND_MARGIN if margin is None else int(margin)
    shape = tuple(int(n) for n in img.shape)
    fac = tuple(int(f) for f in factors)
    cshape = tuple(int(n) for n in q_coarse.shape)
    if any(n != m * f for n, m, f in zip(shape, cshape, fac)):
        return None, {}
    if FINE_BAND_STRADDLE:
        band = _band_blocks(q_coarse, margin, img, fac, 0.5 * (float(c0[0]) + float(c0[1])))
    else:
        band = _band_blocks(q_coarse, margin)
    if not band.any():
        return None, {}
    from scipy import ndimage
    ring = ndimage.binary_dilation(band, np.ones((3, 3, 3), bool)) & ~band
    # the ring blocks whose t grad t on the band reads (forward face neighbours) come first
    face = np.zeros_like(band)
    face[1:] |= band[:-1]
    face[:, 1:] |= band[:, :-1]
    face[:, :, 1:] |= band[:, :, :-1]
    face &= ring
    order = [np.flatnonzero(band), np.flatnonzero(face), np.flatnonzero(ring & ~face)]
    del face, ring
    blocks = np.concatenate(order).astype(np.int32)
    n_band, n_t, n_all = order[0].size, order[0].size + order[1].size, blocks.size
    del order
    per = fac[0] * fac[1] * fac[2]
    nb, nt, ne = n_band * per, n_t * per, n_all * per
    block_lut = np.full(int(np.prod(cshape)), n_all, np.int32)       # n_all: no block (the zero slot)
    block_lut[blocks] = np.arange(n_all, dtype=np.int32)
    bz, rem = np.divmod(blocks, np.int32(cshape[1] * cshape[2]))
    by, bx = np.divmod(rem, np.int32(cshape[2]))
    del rem
    bcoords = (bz, by, bx)
    cstrides = (cshape[1] * cshape[2], cshape[2], 1)
    oz, oy, ox = (o.ravel().astype(np.int32) for o in
                  np.meshgrid(np.arange(fac[0]), np.arange(fac[1]), np.arange(fac[2]), indexing="ij"))
    ocoords = (oz, oy, ox)
    ostrides = (fac[1] * fac[2], fac[2], 1)
    local = np.arange(per, dtype=np.int32)

    def face_neighbours(count: int, axis: int, step: int) -> tuple[np.ndarray, np.ndarray]:
        """The entries of blocks ``:count`` on their face towards ``step`` along ``axis`` (compact
        indices) and each one's neighbour in the next block: the zero slot where there is no block
        (backward), the entry itself at the grid's end (forward: gradient 0)."""
        f = fac[axis]
        on_face = local[ocoords[axis] == (0 if step < 0 else f - 1)]
        across = on_face - np.int32(step * (f - 1) * ostrides[axis])
        bc = bcoords[axis][:count]
        inside_grid = (bc > 0) if step < 0 else (bc < cshape[axis] - 1)
        nblock = np.full(count, n_all, np.int32)
        nblock[inside_grid] = block_lut[blocks[:count][inside_grid] + np.int32(step * cstrides[axis])]
        pos = np.arange(count, dtype=np.int32)[:, None] * np.int32(per) + on_face[None, :]
        nbr = nblock[:, None] * np.int32(per) + across[None, :]
        if step < 0:
            nbr[nblock == n_all] = ne
        else:
            nbr[~inside_grid] = pos[~inside_grid]
        return pos.reshape(-1), nbr.reshape(-1)

    # inside a block the neighbour along an axis is ``ostrides[axis]`` entries on: the sweep shifts the
    # whole vector and corrects only the entries on the block's face (a third to a quarter of them),
    # whose neighbour lies in another block (or is the zero slot / itself at the grid's end)
    back_edge = [face_neighbours(n_t, ax, -1) for ax in range(3)]
    fwd_edge = [face_neighbours(n_band, ax, +1) for ax in range(3)]
    if any(int(nbr.max(initial=0)) >= ne for _, nbr in fwd_edge):
        raise AssertionError("band without its ring")  # cannot happen: the ring surrounds the band
    # warm start: the coarse q and s (s/h rescaled to the fine step; 0 at the grid's last index, eq. 21)
    neg_q = np.empty(ne + 1, np.float32)
    neg_q[:ne] = np.repeat(q_coarse.reshape(-1)[blocks], per)
    neg_q[ne] = 0.0
    q_init_band = neg_q[:nb].copy()
    neg_q *= np.float32(-1.0 / theta)
    sig = []
    for ax in range(3):
        sa = np.zeros(ne + 1, np.float32)
        view = sa[:ne].reshape(n_all, per)
        view[...] = (sig_coarse[ax].reshape(-1)[blocks] * np.float32(fac[ax]))[:, None]
        at_end = (bcoords[ax] == cshape[ax] - 1)[:, None] & (ocoords[ax] == fac[ax] - 1)[None, :]
        view[at_end] = 0.0
        sig.append(sa)
    img6 = img.reshape(cshape[0], fac[0], cshape[1], fac[1], cshape[2], fac[2])
    band_img = np.ascontiguousarray(img6[bz[:n_band], :, by[:n_band], :, bx[:n_band], :], np.float32).reshape(-1)
    # the whole grid's membership (coarse, upsampled) and eq. 17's sums of what stays frozen
    q_full = _resample_nearest(q_coarse, fac, (1, 1, 1), shape)
    total_i = float(np.sum(img, dtype=np.float64))
    frozen_q = float(np.sum(q_full, dtype=np.float64)) - float(np.sum(q_init_band, dtype=np.float64))
    frozen_iq = (float(np.vdot(img.reshape(-1), q_full.reshape(-1)))
                 - float(np.vdot(band_img, q_init_band)))
    count = img.size
    weights = tuple(np.float32(1.0 / float(h) ** 2) for h in spacing)
    tau32 = np.float32(tau)
    low = np.float32(-1.0 / theta)
    c1, c2 = c0
    used = (c1, c2)
    change = float("nan")
    done = 0
    t_pad = np.zeros(nt + per, np.float32)      # t and room for the shifted reads past the band's end
    t = t_pad[:nt]
    w = np.empty(nb, np.float32)
    n = np.empty(nb, np.float32)
    g = [np.empty(nb, np.float32) for _ in range(3)]
    # the sweep's element-wise phases run on ranges of the vectors, one per thread (numpy releases
    # the GIL); the sums of eq. 17 are taken on the whole vectors: the same numbers as one thread
    parts = max(1, min(int(threads), nb // BAND_PART_VOXELS or 1))
    t_cuts = np.linspace(0, nt, parts + 1).round().astype(np.int64)
    b_cuts = np.linspace(0, nb, parts + 1).round().astype(np.int64)
    back_cut = [np.searchsorted(pos, t_cuts) for pos, _ in back_edge]
    fwd_cut = [np.searchsorted(pos, b_cuts) for pos, _ in fwd_edge]
    pool = ThreadPoolExecutor(parts) if parts > 1 else None

    def run(phase, *args):
        if pool is None:
            phase(0, *args)
        else:
            list(pool.map(lambda k: phase(k, *args), range(parts)))

    def phase_t(k):
        """t = div s - q/theta on band and ring (div = -grad^T: s[i] - s[i - e_a]), entries of part k."""
        lo, hi = int(t_cuts[k]), int(t_cuts[k + 1])
        tr = t[lo:hi]
        np.add(neg_q[lo:hi], sig[0][lo:hi], out=tr)
        tr += sig[1][lo:hi]
        tr += sig[2][lo:hi]
        for ax in range(3):
            st = ostrides[ax]
            pos, nbr = back_edge[ax]
            a, b = int(back_cut[ax][k]), int(back_cut[ax][k + 1])
            pos, nbr = pos[a:b], nbr[a:b]
            kept = t[pos]
            s0 = max(lo, st)
            if hi > s0:
                t[s0:hi] -= sig[ax][s0 - st:hi - st]
            t[pos] = kept - sig[ax][nbr]

    def phase_q(k, lam_alpha, lam_beta):
        """eq. 20 on the band: neg_q = clip(t + lam r, -1/theta, 0) into w; n = w - the old neg_q."""
        lo, hi = int(b_cuts[k]), int(b_cuts[k + 1])
        wr, nr = w[lo:hi], n[lo:hi]
        np.multiply(band_img[lo:hi], np.float32(lam_alpha), out=wr)
        wr += t[lo:hi]
        wr += np.float32(lam_beta)
        np.clip(wr, low, np.float32(0.0), out=wr)
        np.subtract(wr, neg_q[lo:hi], out=nr)

    def phase_s(k):
        """neg_q = w, then eq. 21 on the band from t, entries of part k."""
        lo, hi = int(b_cuts[k]), int(b_cuts[k + 1])
        neg_q[lo:hi] = w[lo:hi]
        tb = t[lo:hi]
        wr, nr = w[lo:hi], n[lo:hi]
        gr = [ga[lo:hi] for ga in g]
        for ax in range(3):
            st = ostrides[ax]
            pos, nbr = fwd_edge[ax]
            a, b = int(fwd_cut[ax][k]), int(fwd_cut[ax][k + 1])
            pos, nbr = pos[a:b], nbr[a:b]
            np.subtract(t_pad[lo + st:hi + st], tb, out=gr[ax])
            g[ax][pos] = t[nbr] - t[pos]
        np.multiply(gr[0], gr[0], out=nr)
        nr *= weights[0]
        for ax in (1, 2):
            np.multiply(gr[ax], gr[ax], out=wr)
            wr *= weights[ax]
            nr += wr
        np.sqrt(nr, out=nr)
        nr *= tau32
        nr += np.float32(1.0)
        np.reciprocal(nr, out=nr)
        for ax in range(3):
            gr[ax] *= np.float32(tau * weights[ax])
            gr[ax] += sig[ax][lo:hi]
            np.multiply(gr[ax], nr, out=sig[ax][lo:hi])

    try:
        for it in range(int(iterations)):
            run(phase_t)
            lam_alpha, lam_beta = lam * 2.0 * (c2 - c1), lam * (c1 * c1 - c2 * c2)
            run(phase_q, lam_alpha, lam_beta)
            d = float(np.vdot(n, n))
            sum_q = -theta * float(w.sum(dtype=np.float64))
            sum_iq = -theta * float(np.vdot(band_img, w))
            run(phase_s)
            used = (c1, c2)
            c1, c2 = _region_means(frozen_q + sum_q, frozen_iq + sum_iq, total_i, count)
            change = math.sqrt(theta * theta * d / count)
            done = it + 1
            if progress is not None:
                progress(done)
            if change < tolerance:
                break
    finally:
        if pool is not None:
            pool.shutdown()
    q6 = q_full.reshape(img6.shape)
    q6[bz[:n_band], :, by[:n_band], :, bx[:n_band], :] = (neg_q[:nb] * np.float32(-theta)).reshape(n_band, *fac)
    res = dict(q=q_full, c1=used[0], c2=used[1], iterations=done, change=change, sig=None)
    return res, dict(band_voxels=int(nb), ring_voxels=int(ne - nb))
