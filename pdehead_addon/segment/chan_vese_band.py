"""The full-resolution level of the Chan-Vese pyramid in a narrow band of coarse blocks around the coarse
boundary (paper eq. 16-21 solved where the head's boundary can still move).

:func:`band_fine_solve` is what :func:`~.chan_vese_pyramid.solve_pyramid` runs on large grids instead of the
coarse head's box.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from typing import Sequence

import numpy as np
from scipy import ndimage

from .chan_vese import region_means
from .coarse_blocks import by_block_slabs, resample_nearest

__all__ = ["band_fine_solve", "UNDECIDED_Q", "FINE_BAND_MARGIN", "BAND_PART_VOXELS", "BAND_CHUNK_BLOCKS",
           "FINE_BAND_STRADDLE"]


#: Coarse blocks are undecided when their membership lies in (UNDECIDED_Q, 1 - UNDECIDED_Q) or when
#: they touch the boundary of ``q > 0.5`` (either side, 26-neighbours); the band is those blocks grown
#: by FINE_BAND_MARGIN blocks.  Measured on the 512 x 512 x 300 scan (3 x 4 x 4 blocks): the undecided
#: blocks alone (1.0 M voxels) or grown by one block (6.9 M) break the mask (min per-slice Jaccard
#: 0.54 / 0.83); with the boundary's blocks on both sides (6.6 M voxels, 8.4 %) it is 0.9934.
UNDECIDED_Q = 0.02
FINE_BAND_MARGIN = 0
#: The band's sweep is split over the solver's threads in parts of at least this many voxels.
BAND_PART_VOXELS = 1_000_000
#: Blocks per chunk of the band's sweep (:class:`_BandSweep`): 1024 blocks of 48 voxels keep a chunk's
#: arrays (about 2 MB) in cache.
BAND_CHUNK_BLOCKS = 1024


#: Also put in the band every block whose full-resolution intensities straddle the fine level's
#: boundary level (c1 + c2) / 2 (eq. 18: where the data term changes sign), so thin features the coarse
#: level smoothed away (nostrils, lips, ear rims) are solved at full resolution: the band's mask then
#: differs from the box solve's in far fewer voxels, for a slightly larger band.
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


def _block_straddles(img: np.ndarray, factors: Sequence[int], level: float, threads: int = 1) -> np.ndarray:
    """Blocks of ``factors`` voxels holding a voxel below ``level`` and one above: ``(min < level) &
    (max > level)`` of :func:`_block_range`, from two comparisons and an OR over each block (on the
    comparisons' bytes read 2, 4 or 8 at a time along x), about a third of its time."""
    if threads > 1:
        return by_block_slabs(_block_straddles, img, factors, threads, level)
    fz, fy, fx = (int(f) for f in factors)
    nz, ny, nx = img.shape
    if fx not in (1, 2, 4, 8) or not img.flags.c_contiguous:
        lo, hi = _block_range(img, factors)
        return (lo < np.float32(level)) & (hi > np.float32(level))
    out = None
    for compare in (np.less, np.greater):
        hit = compare(img, np.float32(level))
        rows = hit.view(np.dtype(f"u{fx}")) != 0 if fx > 1 else hit     # (nz, ny, nx // fx): any along x
        del hit
        rows = rows.reshape(nz // fz, fz, ny // fy, fy, nx // fx)
        found = rows[:, 0, :, 0].copy()
        for dz in range(fz):
            for dy in range(fy):
                if dz or dy:
                    found |= rows[:, dz, :, dy]
        out = found if out is None else out & found
    return out


def _band_blocks(q_coarse: np.ndarray, margin: int, img: np.ndarray | None = None, factors=None,
                 level: float | None = None, threads: int = 1) -> np.ndarray:
    """Coarse blocks of the band: undecided or on the coarse boundary, grown by ``margin`` blocks (26-conn.).

    With ``img`` (the full grid, whole blocks of ``factors``) and ``level``, also the blocks whose
    intensities straddle ``level`` (:data:`FINE_BAND_STRADDLE`).
    """
    lo = np.float32(UNDECIDED_Q)
    undecided = (q_coarse > lo) & (q_coarse < np.float32(1.0) - lo)
    if img is not None and level is not None:
        undecided |= _block_straddles(img, factors, level, threads)
    inside = q_coarse > np.float32(0.5)
    cube = np.ones((3, 3, 3), bool)
    undecided |= ndimage.binary_dilation(inside, cube) & ~ndimage.binary_erosion(inside, cube, border_value=1)
    if margin > 0:
        undecided = ndimage.binary_dilation(undecided, cube, iterations=int(margin))
    return undecided


def band_fine_solve(img: np.ndarray, spacing: Sequence[float], lam: float, theta: float, tau: float,
                     iterations: int, tolerance: float, q_coarse: np.ndarray, sig_coarse, c0, factors,
                     progress=None, margin: int | None = None, threads: int = 1, coarse_img=None,
                     own_img: bool = False) -> tuple[dict | None, dict]:
    """The full-resolution level of eq. 16-21 only in a band of coarse blocks around the coarse boundary.

    Outside the band the membership keeps the coarse level's value (nearest-neighbour upsampled; there
    the coarse q is within :data:`UNDECIDED_Q` of 0 or 1 and more than ``margin`` blocks from the
    coarse boundary).  Inside it the same iteration as :class:`.chan_vese._ChanVeseState` (eq. 20 and
    one eq. 21 step per outer iteration, eq. 17 over the whole grid) runs on the band's blocks gathered
    into compact vectors, block after block (:class:`_BandSweep`); the q and s of a one-block ring
    around the band stay at their coarse values.  Narrow-band level sets (Adalsteinsson & Sethian 1995)
    make the same trade.  Returns ``(None, {})`` when the grid is not whole blocks (the caller solves
    the box instead).

    ``coarse_img``: the block means of ``img`` over ``factors`` (the coarse level's image), from which
    eq. 17's sums over the frozen blocks are taken (instead of three passes over the whole grid).
    ``own_img``: ``img`` may be overwritten; the returned q is then written into its buffer.
    """
    margin = FINE_BAND_MARGIN if margin is None else int(margin)
    shape = tuple(int(n) for n in img.shape)
    fac = tuple(int(f) for f in factors)
    cshape = tuple(int(n) for n in q_coarse.shape)
    if any(n != m * f for n, m, f in zip(shape, cshape, fac)):
        return None, {}
    # its set-up takes seconds on a clinical scan: reported stage by stage, so a cancel is heard within it
    preparing = (lambda: progress(0, "preparing the full-resolution band")) if progress is not None else (lambda: None)
    preparing()
    if FINE_BAND_STRADDLE:
        band = _band_blocks(q_coarse, margin, img, fac, 0.5 * (float(c0[0]) + float(c0[1])), threads)
    else:
        band = _band_blocks(q_coarse, margin)
    if not band.any():
        return None, {}
    preparing()
    lay = _BandLayout(band, fac)
    preparing()
    sweep = _BandSweep(lay, img, q_coarse, sig_coarse, spacing, theta, tau, threads)
    try:
        preparing()
    except BaseException:
        sweep.close()  # its worker pool; from here on the loop's finally closes it
        raise
    # eq. 17's sums of what stays frozen (the coarse q outside the band) and the whole grid's membership
    if coarse_img is not None and tuple(coarse_img.shape) == cshape:
        per = float(lay.per)
        frozen = ~band.reshape(-1)
        qc = q_coarse.reshape(-1)[frozen].astype(np.float64)
        total_i = per * float(np.sum(coarse_img, dtype=np.float64))
        frozen_q = per * float(qc.sum())
        frozen_iq = per * float(np.dot(qc, coarse_img.reshape(-1)[frozen]))
        del qc, frozen
        q_full = resample_nearest(q_coarse, fac, (1, 1, 1), shape, out=img if own_img else None)
    else:
        q_full = resample_nearest(q_coarse, fac, (1, 1, 1), shape)
        total_i = float(np.sum(img, dtype=np.float64))
        frozen_q = float(np.sum(q_full, dtype=np.float64)) - float(np.sum(sweep.q_init_band, dtype=np.float64))
        frozen_iq = (float(np.vdot(img.reshape(-1), q_full.reshape(-1)))
                     - float(np.vdot(sweep.band_img, sweep.q_init_band)))
    sweep.q_init_band = None
    del band
    count = img.size
    c1, c2 = c0
    used = (c1, c2)
    change = float("nan")
    done = 0
    try:
        for it in range(int(iterations)):
            d, sum_q, sum_iq = sweep.step(lam, c1, c2)
            used = (c1, c2)
            c1, c2 = region_means(frozen_q + sum_q, frozen_iq + sum_iq, total_i, count)
            change = math.sqrt(theta * theta * d / count)
            done = it + 1
            if progress is not None:
                progress(done)
            if change < tolerance:
                break
    finally:
        sweep.close()
    bz, by, bx = (c[:lay.n_band] for c in lay.bcoords)
    q6 = q_full.reshape(cshape[0], fac[0], cshape[1], fac[1], cshape[2], fac[2])
    q6[bz, :, by, :, bx, :] = (sweep.neg_q[:lay.nb] * np.float32(-theta)).reshape(lay.n_band, *fac)
    res = dict(q=q_full, c1=used[0], c2=used[1], iterations=done, change=change, sig=None)
    return res, dict(band_voxels=int(lay.nb), ring_voxels=int(lay.ne - lay.nb))


class _BandLayout:
    """The band's blocks, its ring and their entries in the compact vectors of :class:`_BandSweep`.

    The band's blocks come first, then the ring blocks that the band's forward differences read (face
    neighbours), then the rest of the one-block ring (26-neighbours); entry ``e`` of block ``i`` of the
    vectors is voxel ``e`` (z, y, x order) of that block, and entry ``ne`` is a zero slot.  Inside a
    block the neighbour along an axis is ``ostrides[axis]`` entries on: the sweep shifts the whole
    vector and corrects only the entries on the block's face (a third to a quarter of them), whose
    neighbour lies in another block (or is the zero slot / itself at the grid's end): ``back_nbr`` and
    ``fwd_nbr`` per axis, the neighbours of the face entries in the order of :meth:`face` (block after
    block, each block's face entries in order).
    """

    def __init__(self, band: np.ndarray, fac: tuple[int, int, int]):
        cshape = tuple(int(n) for n in band.shape)
        ring = ndimage.binary_dilation(band, np.ones((3, 3, 3), bool)) & ~band
        # the ring blocks whose t grad t on the band reads (forward face neighbours) come first
        face = np.zeros_like(band)
        face[1:] |= band[:-1]
        face[:, 1:] |= band[:, :-1]
        face[:, :, 1:] |= band[:, :, :-1]
        face &= ring
        order = [np.flatnonzero(band), np.flatnonzero(face), np.flatnonzero(ring & ~face)]
        del face, ring
        self.blocks = np.concatenate(order).astype(np.int32)
        self.n_band, self.n_t, self.n_all = order[0].size, order[0].size + order[1].size, self.blocks.size
        del order
        self.fac, self.cshape = fac, cshape
        self.per = per = fac[0] * fac[1] * fac[2]
        self.nb, self.nt, self.ne = self.n_band * per, self.n_t * per, self.n_all * per
        self.block_lut = np.full(int(np.prod(cshape)), self.n_all, np.int32)   # n_all: no block (the zero slot)
        self.block_lut[self.blocks] = np.arange(self.n_all, dtype=np.int32)
        bz, rem = np.divmod(self.blocks, np.int32(cshape[1] * cshape[2]))
        by, bx = np.divmod(rem, np.int32(cshape[2]))
        self.bcoords = (bz, by, bx)
        self.cstrides = (cshape[1] * cshape[2], cshape[2], 1)
        self.ocoords = tuple(o.ravel().astype(np.int32) for o in
                             np.meshgrid(np.arange(fac[0]), np.arange(fac[1]), np.arange(fac[2]), indexing="ij"))
        self.ostrides = (fac[1] * fac[2], fac[2], 1)
        # np.intp: numpy's fancy indexing converts other index types on every call
        self.back_nbr = [self.face_neighbours(self.n_t, ax, -1)[1].astype(np.intp) for ax in range(3)]
        self.fwd_nbr = [self.face_neighbours(self.n_band, ax, +1)[1].astype(np.intp) for ax in range(3)]
        if any(int(nbr.max(initial=0)) >= self.ne for nbr in self.fwd_nbr):
            raise AssertionError("band without its ring")  # cannot happen: the ring surrounds the band

    def face(self, vector: np.ndarray, axis: int, step: int) -> np.ndarray:
        """The entries of whole blocks ``vector`` on their face towards ``step`` along ``axis``, a view
        (blocks, ...) in the order of ``face_neighbours``' entries."""
        blocks = vector.reshape((-1,) + self.fac)
        index = [slice(None)] * 4
        index[1 + axis] = 0 if step < 0 else self.fac[axis] - 1
        return blocks[tuple(index)]

    def face_neighbours(self, count: int, axis: int, step: int) -> tuple[np.ndarray, np.ndarray]:
        """The entries of blocks ``:count`` on their face towards ``step`` along ``axis`` (compact
        indices) and each one's neighbour in the next block: the zero slot where there is no block
        (backward), the entry itself at the grid's end (forward: gradient 0)."""
        f, per, n_all = self.fac[axis], self.per, self.n_all
        local = np.arange(per, dtype=np.int32)
        on_face = local[self.ocoords[axis] == (0 if step < 0 else f - 1)]
        across = on_face - np.int32(step * (f - 1) * self.ostrides[axis])
        bc = self.bcoords[axis][:count]
        inside_grid = (bc > 0) if step < 0 else (bc < self.cshape[axis] - 1)
        nblock = np.full(count, n_all, np.int32)
        nblock[inside_grid] = self.block_lut[self.blocks[:count][inside_grid] + np.int32(step * self.cstrides[axis])]
        pos = np.arange(count, dtype=np.int32)[:, None] * np.int32(per) + on_face[None, :]
        nbr = nblock[:, None] * np.int32(per) + across[None, :]
        if step < 0:
            nbr[nblock == n_all] = self.ne
        else:
            nbr[~inside_grid] = pos[~inside_grid]
        return pos.reshape(-1), nbr.reshape(-1)


class _BandSweep:
    """One outer iteration of eq. 20-21 on the band's compact vectors (:class:`_BandLayout`).

    Warm-started from the coarse q and s (s/h rescaled to the fine step; 0 at the grid's last index,
    eq. 21).  The vectors are swept in chunks of :data:`BAND_CHUNK_BLOCKS` blocks, small enough that
    a chunk's dozen arrays stay in cache through the chain of element-wise operations: first t on
    every chunk, then per chunk the q step, its sums for eq. 17 (float64) and the dual step.  The
    chunks are split over the threads (numpy releases the GIL); the sums are added chunk by chunk in
    order, so the numbers do not depend on the thread count.
    """

    def __init__(self, lay: _BandLayout, img: np.ndarray, q_coarse: np.ndarray, sig_coarse, spacing,
                 theta: float, tau: float, threads: int):
        self.lay = lay
        fac, cshape, per = lay.fac, lay.cshape, lay.per
        nb, nt, ne, n_all = lay.nb, lay.nt, lay.ne, lay.n_all
        self.theta, self.tau = float(theta), float(tau)
        neg_q = np.empty(ne + 1, np.float32)
        neg_q[:ne] = np.repeat(q_coarse.reshape(-1)[lay.blocks], per)
        neg_q[ne] = 0.0
        self.q_init_band = neg_q[:nb].copy()
        neg_q *= np.float32(-1.0 / theta)
        self.neg_q = neg_q
        self.sig = []
        for ax in range(3):
            sa = np.zeros(ne + 1, np.float32)
            view = sa[:ne].reshape(n_all, per)
            view[...] = (sig_coarse[ax].reshape(-1)[lay.blocks] * np.float32(fac[ax]))[:, None]
            at_end = (lay.bcoords[ax] == cshape[ax] - 1)[:, None] & (lay.ocoords[ax] == fac[ax] - 1)[None, :]
            view[at_end] = 0.0
            self.sig.append(sa)
        bz, by, bx = (c[:lay.n_band] for c in lay.bcoords)
        img6 = img.reshape(cshape[0], fac[0], cshape[1], fac[1], cshape[2], fac[2])
        self.band_img = np.ascontiguousarray(img6[bz, :, by, :, bx, :], np.float32).reshape(-1)
        self.weights = tuple(np.float32(1.0 / float(h) ** 2) for h in spacing)
        self.t_pad = np.zeros(nt + per, np.float32)      # t and room for the shifted reads past the band's end
        self.t = self.t_pad[:nt]
        self.chunk = max(1, int(BAND_CHUNK_BLOCKS))
        self.parts = parts = max(1, min(int(threads), nb // BAND_PART_VOXELS or 1))
        size = self.chunk * per
        self.scratch = [dict(w=np.empty(size, np.float32), n=np.empty(size, np.float32),
                             g=[np.empty(size, np.float32) for _ in range(3)]) for _ in range(parts)]
        self.pool = ThreadPoolExecutor(parts) if parts > 1 else None

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()
            self.pool = None

    def run(self, phase, n_blocks: int, *args) -> None:
        """``phase(part, b0, b1, chunk index, *args)`` on every chunk of blocks ``:n_blocks``, the
        chunks split in whole runs over the threads."""
        chunks = -(-int(n_blocks) // self.chunk)
        cuts = np.linspace(0, chunks, self.parts + 1).round().astype(int)

        def part(k: int) -> None:
            for c in range(int(cuts[k]), int(cuts[k + 1])):
                phase(k, c * self.chunk, min((c + 1) * self.chunk, int(n_blocks)), c, *args)
        if self.pool is None:
            part(0)
        else:
            list(self.pool.map(part, range(self.parts)))

    def step(self, lam: float, c1: float, c2: float) -> tuple[float, float, float]:
        """eq. 20 with (c1, c2) and one eq. 21 step: ``(sum (dq theta)^2 / theta^2, sum q, sum I q)`` of the band."""
        self.run(self.phase_t, self.lay.n_t)
        sums = np.zeros((-(-self.lay.n_band // self.chunk), 3))
        self.run(self.phase_qs, self.lay.n_band, lam * 2.0 * (c2 - c1), lam * (c1 * c1 - c2 * c2), sums)
        d, sum_w, sum_iw = (math.fsum(col) for col in sums.T)
        return d, -self.theta * sum_w, -self.theta * sum_iw

    def phase_t(self, k: int, b0: int, b1: int, c: int) -> None:
        """t = div s - q/theta on band and ring (div = -grad^T: s[i] - s[i - e_a]), blocks b0..b1."""
        t, sig, lay = self.t, self.sig, self.lay
        lo, hi = b0 * lay.per, b1 * lay.per
        tr = t[lo:hi]
        np.add(self.neg_q[lo:hi], sig[0][lo:hi], out=tr)
        tr += sig[1][lo:hi]
        tr += sig[2][lo:hi]
        for ax in range(3):
            st = lay.ostrides[ax]
            m = lay.per // lay.fac[ax]                       # face entries per block
            face = lay.face(tr, ax, -1)
            kept = face.copy()
            s0 = max(lo, st)
            if hi > s0:
                t[s0:hi] -= sig[ax][s0 - st:hi - st]
            kept -= sig[ax][lay.back_nbr[ax][b0 * m:b1 * m]].reshape(kept.shape)
            face[...] = kept

    def phase_qs(self, k: int, b0: int, b1: int, c: int, lam_alpha: float, lam_beta: float,
                 sums: np.ndarray) -> None:
        """Blocks b0..b1 of the band: eq. 20 (neg_q = clip(t + lam r, -1/theta, 0)), the chunk's sums
        of (dq)^2, q and I q (``sums[c]``, float64, in units of neg_q), then eq. 21 from t."""
        t, sig, weights, lay = self.t, self.sig, self.weights, self.lay
        lo, hi = b0 * lay.per, b1 * lay.per
        size = hi - lo
        buf = self.scratch[k]
        wr, nr = buf["w"][:size], buf["n"][:size]
        gr = [ga[:size] for ga in buf["g"]]
        tb, nq, im = t[lo:hi], self.neg_q[lo:hi], self.band_img[lo:hi]
        np.multiply(im, np.float32(lam_alpha), out=wr)
        wr += tb
        wr += np.float32(lam_beta)
        np.clip(wr, np.float32(-1.0 / self.theta), np.float32(0.0), out=wr)
        np.subtract(wr, nq, out=nr)
        np.multiply(nr, nr, out=nr)
        sums[c, 0] = nr.sum(dtype=np.float64)
        sums[c, 1] = wr.sum(dtype=np.float64)
        np.multiply(im, wr, out=nr)
        sums[c, 2] = nr.sum(dtype=np.float64)
        nq[...] = wr
        for ax in range(3):
            st = lay.ostrides[ax]
            m = lay.per // lay.fac[ax]
            np.subtract(self.t_pad[lo + st:hi + st], tb, out=gr[ax])
            face = lay.face(gr[ax], ax, +1)
            np.subtract(t[lay.fwd_nbr[ax][b0 * m:b1 * m]].reshape(face.shape), lay.face(tb, ax, +1), out=face)
        np.multiply(gr[0], gr[0], out=nr)
        nr *= weights[0]
        for ax in (1, 2):
            np.multiply(gr[ax], gr[ax], out=wr)
            wr *= weights[ax]
            nr += wr
        np.sqrt(nr, out=nr)
        nr *= np.float32(self.tau)
        nr += np.float32(1.0)
        np.reciprocal(nr, out=nr)
        for ax in range(3):
            gr[ax] *= np.float32(self.tau * weights[ax])
            gr[ax] += sig[ax][lo:hi]
            np.multiply(gr[ax], nr, out=sig[ax][lo:hi])
