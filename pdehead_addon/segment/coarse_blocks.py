"""Blocks of a coarse grid: block means, block reductions on slabs of block rows, nearest resampling.

The coarse levels of the Chan-Vese pyramid (:mod:`.chan_vese_pyramid`) and its band solve
(:mod:`.chan_vese_band`) read the image in blocks of whole voxels; these are their shared grid operations.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..core.threads import in_slabs

__all__ = ["PARALLEL_VOXELS", "by_block_slabs", "block_mean", "resample_nearest"]


#: Block reductions (:func:`block_mean`, :func:`_block_straddles`) of grids of at least this many
#: voxels run on slabs of block rows in the solver's threads (the same numbers: each block is summed
#: alone, in the same order).
PARALLEL_VOXELS = 4_000_000


def by_block_slabs(reduce, img: np.ndarray, factors: Sequence[int], threads: int, *args) -> np.ndarray:
    """``reduce(img, factors, *args)`` (a per-block reduction of a grid of whole blocks in z) on
    slabs of block rows, one per thread, stacked."""
    fz = int(factors[0])
    cz = img.shape[0] // fz
    if img.size < PARALLEL_VOXELS or threads < 2 or cz < 2:
        return reduce(img, factors, *args)
    pieces = {}

    def slab(a: int, b: int) -> None:
        pieces[a] = reduce(img[a * fz:b * fz], factors, *args)

    in_slabs(cz, slab, threads)
    return np.concatenate([pieces[a] for a in sorted(pieces)], axis=0)


def block_mean(img: np.ndarray, factors: Sequence[int], threads: int = 1) -> np.ndarray:
    """Mean over blocks of ``factors`` voxels (edge-padded to whole blocks), float32."""
    fz, fy, fx = factors
    nz, ny, nx = img.shape
    pz, py, px = (-nz) % fz, (-ny) % fy, (-nx) % fx
    if pz or py or px:
        img = np.pad(img, ((0, pz), (0, py), (0, px)), mode="edge")
    if threads > 1:
        return by_block_slabs(block_mean, img, factors, threads)
    out = None
    for dz in range(fz):  # sum of strided views: much faster than a reshaped mean
        for dy in range(fy):
            for dx in range(fx):
                view = img[dz::fz, dy::fy, dx::fx]
                out = view.astype(np.float32, copy=True) if out is None else np.add(out, view, out=out)
    out *= np.float32(1.0 / (fz * fy * fx))
    return out


def resample_nearest(a: np.ndarray, from_factors: Sequence[int], to_factors: Sequence[int],
                      shape: Sequence[int], out: np.ndarray | None = None) -> np.ndarray:
    """Nearest-neighbour map between two block grids of the same volume (blocks of ``*_factors`` voxels).

    ``out``: a float32 C-contiguous array of ``shape`` to write into (used when the grid is whole blocks)."""
    reps = [int(f) // int(t) for f, t in zip(from_factors, to_factors)]
    if (all(int(f) % int(t) == 0 for f, t in zip(from_factors, to_factors))
            and all(n <= m * r for n, m, r in zip(shape, a.shape, reps))):
        # whole blocks: repeat along x on the small array, then strided writes in z and y
        # (3x less time than np.repeat axis by axis, which copies the growing array twice more)
        nz, ny, nx = (int(n) for n in shape)
        row = np.repeat(a, reps[2], axis=2)[:, :, :nx] if reps[2] > 1 else a[:, :, :nx]
        if out is None or out.shape != (nz, ny, nx) or out.dtype != np.float32 or not out.flags.c_contiguous:
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
