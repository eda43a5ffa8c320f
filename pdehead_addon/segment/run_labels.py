"""Connected components of boolean volumes on runs along x (numpy + scipy.sparse only).

A volume (z, y, x) is read as its runs of True voxels along x (one flat ``nonzero`` of the
row differences); two runs are face-connected when they lie in neighbouring rows (y +- 1 in
the same slice, or z +- 1 at the same y) and share an x. Those links, found with two
``searchsorted`` over the sorted run ends, and ``scipy.sparse.csgraph.connected_components``
give the components of a head mask for a fraction of ``scipy.ndimage.label``'s time (it visits
every voxel; there are ~100 x fewer runs than voxels). The labels are numbered as
``ndi.label`` numbers them (by their first voxel in raster order), so every result here is
exactly that of the labelling it replaces (``tests/segment/test_speed_identities.py``).
"""
from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix

#: Rows of a volume are scanned for runs in chunks of about this many bytes.
_CHUNK_BYTES = 1 << 20


class Runs:
    """The runs of True along the last axis of a bool volume (z, y, x).

    ``row`` (z * ny + y), ``x0`` and ``x1`` (first and one past the last voxel) of every run, in
    raster order; ``start`` / ``end`` are ``row * (nx + 1) + x0`` / ``x1`` (sorted keys).
    """

    def __init__(self, mask: np.ndarray):
        mask = np.asarray(mask, dtype=bool)
        if mask.ndim == 2:
            mask = mask[None]
        self.shape = mask.shape
        nx = mask.shape[-1]
        rows = mask.reshape(-1, nx)
        # per row: start, end, start, end, ... (where a row padded with False changes); in chunks of rows
        # whose two buffers are reused (a temporary of the whole volume costs more in fresh pages)
        chunk = max(1, min(rows.shape[0], _CHUNK_BYTES // (nx + 2)))
        pad = np.zeros((chunk, nx + 2), dtype=bool)
        change = np.empty((chunk, nx + 1), dtype=bool)
        parts = []
        for r0 in range(0, rows.shape[0], chunk):
            n = min(chunk, rows.shape[0] - r0)
            pad[:n, 1:-1] = rows[r0:r0 + n]
            np.not_equal(pad[:n, 1:], pad[:n, :-1], out=change[:n])
            parts.append(np.flatnonzero(change[:n]) + r0 * (nx + 1))
        edges = np.concatenate(parts)
        del pad, change
        self.start, self.end = edges[0::2], edges[1::2]
        self.row = self.start // (nx + 1)
        self.x0 = self.start - self.row * (nx + 1)
        self.x1 = self.end - self.row * (nx + 1)

    @property
    def length(self) -> np.ndarray:
        return self.x1 - self.x0

    def voxels(self, which: np.ndarray | None = None) -> np.ndarray:
        """Flat indices (C order, ascending) of the voxels of the runs (all, or those ``which`` selects)."""
        row, x0, x1 = (self.row, self.x0, self.x1) if which is None else (self.row[which], self.x0[which],
                                                                           self.x1[which])
        length = x1 - x0
        total = int(length.sum())
        if total == 0:
            return np.zeros(0, dtype=np.int64)
        offset = np.cumsum(length) - length
        return np.arange(total, dtype=np.int64) + np.repeat(row * self.shape[-1] + x0 - offset, length)

    def paint(self, which: np.ndarray | None = None) -> np.ndarray:
        """A bool volume of ``shape``, True on the runs (all, or those ``which`` selects)."""
        nz, ny, nx = self.shape
        start, end = (self.start, self.end) if which is None else (self.start[which], self.end[which])
        count = int((end - start).sum())
        if 10 * count < nz * ny * nx:                      # few voxels: scatter their indices
            out = np.zeros(nz * ny * nx, dtype=bool)
            out[self.voxels(which)] = True
            return out.reshape(self.shape)
        steps = np.zeros(nz * ny * (nx + 1) + 1, dtype=np.int8)   # +1 at a run's start, -1 past its end
        steps[start] = 1
        steps[end] = -1
        np.cumsum(steps, dtype=np.int8, out=steps)
        return np.ascontiguousarray(steps[:-1].reshape(nz * ny, nx + 1)[:, :nx]).view(bool).reshape(self.shape)

    def links(self, in_slice: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Pairs (a, b) of face-connected runs: b in the next row (y + 1) or, unless ``in_slice``, the
        next slice (z + 1), sharing at least one x."""
        nz, ny, nx = self.shape
        width = nx + 1
        firsts, seconds = [], []
        for step in ((1,) if in_slice else (1, ny)):
            ok = (self.row % ny != ny - 1) if step == 1 else (self.row < (nz - 1) * ny)
            a = np.flatnonzero(ok)
            target = (self.row[a] + step) * width
            lo = np.searchsorted(self.end, target + self.x0[a], side="right")    # first run ending after x0
            hi = np.searchsorted(self.start, target + self.x1[a], side="left")   # runs starting before x1
            count = hi - lo
            some = count > 0
            a, lo, count = a[some], lo[some], count[some]
            if a.size == 0:
                continue
            offset = np.cumsum(count) - count
            firsts.append(np.repeat(a, count))
            seconds.append(np.arange(int(count.sum()), dtype=np.int64) + np.repeat(lo - offset, count))
        if not firsts:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        return np.concatenate(firsts), np.concatenate(seconds)

    def label(self, in_slice: bool = False) -> tuple[np.ndarray, int]:
        """The component (1..n) of every run and n; numbered by first voxel in raster order, as
        ``ndi.label`` numbers them (6-connectivity, or 4-connectivity in each slice)."""
        count = self.start.size
        if count == 0:
            return np.zeros(0, dtype=np.int32), 0
        from scipy.sparse.csgraph import connected_components  # deferred: ~8 ms at `import pdehead_addon`
        a, b = self.links(in_slice)
        graph = csr_matrix((np.ones(a.size, dtype=np.int8), (a, b)), shape=(count, count))
        n, comp = connected_components(graph, directed=False)
        _, first = np.unique(comp, return_index=True)          # each component's first run (raster order)
        rank = np.empty(n, dtype=np.int32)
        rank[np.argsort(first)] = np.arange(1, n + 1, dtype=np.int32)
        return rank[comp], int(n)

    def objects(self, labels: np.ndarray, n: int) -> list:
        """``ndi.find_objects`` of the labelled volume, from the runs (labels 1..n all present)."""
        ny = self.shape[1]
        order = np.argsort(labels, kind="stable")
        starts = np.searchsorted(labels[order], np.arange(1, n + 1))
        z, y = self.row[order] // ny, self.row[order] % ny
        box = [np.minimum.reduceat(z, starts), np.maximum.reduceat(z, starts) + 1,
               np.minimum.reduceat(y, starts), np.maximum.reduceat(y, starts) + 1,
               np.minimum.reduceat(self.x0[order], starts), np.maximum.reduceat(self.x1[order], starts)]
        z0, z1, y0, y1, x0, x1 = (v.tolist() for v in box)
        return [(slice(a, b), slice(c, d), slice(e, f)) for a, b, c, d, e, f in zip(z0, z1, y0, y1, x0, x1)]


def label(mask: np.ndarray, in_slice: bool = False) -> tuple[np.ndarray, int, Runs, np.ndarray]:
    """``ndi.label(mask)`` (6-connectivity; ``in_slice``: 4-connectivity in each axial slice, no links
    between slices): the int32 label volume, n, the runs and their labels."""
    runs = Runs(mask)
    run_labels, n = runs.label(in_slice)
    out = np.zeros(int(np.prod(runs.shape)), dtype=np.int32)
    out[runs.voxels()] = np.repeat(run_labels, runs.length)
    return out.reshape(np.shape(mask)), n, runs, run_labels


def largest_component(mask: np.ndarray) -> np.ndarray:
    """The largest 6-connected component of a bool volume; of equal sizes the first in raster order
    (``np.argmax`` of ``ndi.label``'s counts)."""
    runs = Runs(mask)
    run_labels, n = runs.label()
    if n <= 1:
        return np.array(mask, dtype=bool, copy=True)
    length = runs.length
    sizes = np.bincount(run_labels, weights=length, minlength=n + 1)
    sizes[0] = -1
    best = int(np.argmax(sizes))
    lose = run_labels != best
    if int(length[lose].sum()) <= sizes[best]:
        out = np.array(mask, dtype=bool, copy=True)
        out.reshape(-1)[runs.voxels(lose)] = False
        return out
    return runs.paint(~lose).reshape(np.shape(mask))


def fill_holes_per_slice(mask: np.ndarray) -> np.ndarray:
    """Every background region of an axial slice that does not reach the slice's border, filled
    (4-connectivity in the slice; ``mask`` 2-D or 3-D)."""
    runs = Runs(~np.asarray(mask, dtype=bool))
    run_labels, n = runs.label(in_slice=True)
    out = np.array(mask, dtype=bool, copy=True)
    if n == 0:
        return out
    nz, ny, nx = runs.shape
    y = runs.row % ny
    border = (runs.x0 == 0) | (runs.x1 == nx) | (y == 0) | (y == ny - 1)
    outside = np.zeros(n + 1, dtype=bool)
    outside[run_labels[border]] = True
    hole = ~outside[run_labels]
    if hole.any():
        out.reshape(-1)[runs.voxels(hole)] = True
    return out
