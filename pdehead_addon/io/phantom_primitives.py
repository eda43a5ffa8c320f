"""Signed-distance building blocks of the synthetic head (:mod:`.phantom`): mm, negative inside.

Evaluated on flat point sets (:class:`Points`) or on a regular grid (:class:`Grid`). Every primitive only
touches the points in its bounding box (grown by the blend width); elsewhere it is "far" and leaves the
field exactly unchanged, which is what makes the default grid fast. Grid and arbitrary points go through
the same code, so the truth at voxel centres is bit-identical to :meth:`~.phantom.Phantom.inside_head` there.
"""
from __future__ import annotations

import math

import numpy as np

EMPTY = "empty"  # selection of no point


class Points:
    """Flat patient LPS coordinates (mm) of arbitrary points; fields are 1-D arrays."""

    __slots__ = ("x", "y", "z", "ax")

    def __init__(self, x: np.ndarray, y: np.ndarray, z: np.ndarray):
        self.x, self.y, self.z = x, y, z
        self.ax = np.abs(x)

    @property
    def shape(self) -> tuple[int, ...]:
        return self.x.shape

    def take(self, selection) -> "Points":
        return self if selection is None else Points(self.x[selection], self.y[selection], self.z[selection])

    def select(self, box: tuple[np.ndarray, np.ndarray, bool]):
        """Indices of the points inside ``box = (lo, hi, mirror)`` (None: all, ``EMPTY``: none)."""
        lo, hi, mirror = box
        x = self.ax if mirror else self.x
        inside = (x >= lo[0]) & (x <= hi[0]) & (self.y >= lo[1]) & (self.y <= hi[1])
        inside &= (self.z >= lo[2]) & (self.z <= hi[2])
        if inside.all():
            return None
        return np.flatnonzero(inside) if inside.any() else EMPTY


class Grid:
    """The points of a rectilinear grid given by its axes; fields are ``(nz, ny, nx)`` arrays.

    Coordinates are broadcast views, so per-axis terms cost 1-D work, and a box
    selection is a sub-grid (slices, or an index array along x for mirrored
    boxes). The box test is the same predicate as :meth:`Points.select` on the
    same coordinates, and all arithmetic is element-wise, so a grid and a flat
    list of its points give bit-identical fields.
    """

    __slots__ = ("xs", "ys", "zs", "x", "y", "z", "ax")

    def __init__(self, xs: np.ndarray, ys: np.ndarray, zs: np.ndarray):
        self.xs, self.ys, self.zs = xs, ys, zs
        self.x, self.y, self.z = xs[None, None, :], ys[None, :, None], zs[:, None, None]
        self.ax = np.abs(self.x)

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.zs.size, self.ys.size, self.xs.size)

    def take(self, selection) -> "Grid":
        if selection is None:
            return self
        kz, jy, ix = selection
        return Grid(self.xs[ix], self.ys[jy], self.zs[kz])

    def select(self, box: tuple[np.ndarray, np.ndarray, bool]):
        lo, hi, mirror = box
        parts = []
        for values, low, high in ((self.zs, lo[2], hi[2]), (self.ys, lo[1], hi[1]),
                                  (np.abs(self.xs) if mirror else self.xs, lo[0], hi[0])):
            index = np.flatnonzero((values >= low) & (values <= high))
            if index.size == 0:
                return EMPTY
            if index.size == values.size:
                parts.append(slice(None))
            elif index[-1] - index[0] + 1 == index.size:  # contiguous: a view
                parts.append(slice(int(index[0]), int(index[-1]) + 1))
            else:  # |x| in [lo, hi] on both sides of x = 0 (only x can be split)
                parts.append(index)
        if all(isinstance(part, slice) and part == slice(None) for part in parts):
            return None
        return tuple(parts)


def ellipsoid_sd(u, v, w, r):
    """Approximate signed distance to the ellipsoid u^2/a^2 + v^2/b^2 + w^2/c^2 = 1.

    ``(k0 - 1) k0 / k1`` with k0 = |p/r|, k1 = |p/r^2| (Quilez): exact zero set,
    a good distance estimate near the surface, correct sign everywhere.
    """
    pu, pv, pw = u / r[0], v / r[1], w / r[2]
    k0 = np.sqrt(pu * pu + pv * pv + pw * pw)
    k1 = np.sqrt(pu * pu / (r[0] * r[0]) + pv * pv / (r[1] * r[1]) + pw * pw / (r[2] * r[2]))
    radius = np.divide(k0, k1, out=np.full(k0.shape, float(min(r))), where=k1 > 0)
    return (k0 - 1.0) * radius


def ellipse_sd(u, v, r):
    """2-D version of :func:`ellipsoid_sd` (an infinite elliptic cylinder)."""
    pu, pv = u / r[0], v / r[1]
    k0 = np.sqrt(pu * pu + pv * pv)
    k1 = np.sqrt(pu * pu / (r[0] * r[0]) + pv * pv / (r[1] * r[1]))
    radius = np.divide(k0, k1, out=np.full(k0.shape, float(min(r))), where=k1 > 0)
    return (k0 - 1.0) * radius


def smin(a, b, k):
    """Smooth union (polynomial smooth minimum, blend width k mm); exactly min(a, b) if |a-b| >= k."""
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - 0.25 * k * h * h


def smax(a, b, k):
    """Smooth intersection; ``smax(a, -b, k)`` is the smooth difference a minus b."""
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.maximum(a, b) + 0.25 * k * h * h


def rotation_ear(flare_deg: float, roll_deg: float) -> np.ndarray:
    """Rows: local axes (u, v, w) of the left ear plate: w (the front edge) tilted by ``roll_deg``
    about y so the top leans outwards, then v (backwards) turned by ``flare_deg`` towards +x."""
    cf, sf = math.cos(math.radians(flare_deg)), math.sin(math.radians(flare_deg))
    cr, sr = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
    return np.array([[cr * cf, -cr * sf, -sr], [sf, cf, 0.0], [sr * cf, -sr * sf, cr]])


def rotation_about_x(angle_deg: float) -> np.ndarray:
    """Rows: local axes (u, v, w) rotated by ``angle_deg`` about +x (u = x)."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


class Ellipsoid:
    """Ellipsoid, optionally rotated (semi-axes along the rows of ``axes``), mirrored in x
    (``|x|``) and cut in half (``half``: only the part with local v >= 0)."""

    def __init__(self, centre, radii, *, mirror: bool = False, axes: np.ndarray | None = None,
                 half: bool = False):
        self.centre, self.radii = np.asarray(centre, float), tuple(float(r) for r in radii)
        self.mirror, self.axes, self.half = mirror, axes, half

    def local(self, p):
        """The points in the primitive's local axes (u, v, w) about its centre (``|x|`` if mirrored)."""
        dx = (p.ax if self.mirror else p.x) - self.centre[0]
        dy, dz = p.y - self.centre[1], p.z - self.centre[2]
        if self.axes is not None:
            a = self.axes
            dx, dy, dz = (a[0, 0] * dx + a[0, 1] * dy + a[0, 2] * dz,
                          a[1, 0] * dx + a[1, 1] * dy + a[1, 2] * dz,
                          a[2, 0] * dx + a[2, 1] * dy + a[2, 2] * dz)
        return dx, dy, dz

    def sd(self, p) -> np.ndarray:
        dx, dy, dz = self.local(p)
        d = ellipsoid_sd(dx, dy, dz, self.radii)
        return np.maximum(d, -dy) if self.half else d  # half: keep local v >= 0 only

    def box(self, margin: float):
        reach = np.full(3, max(self.radii)) if self.axes is not None else np.asarray(self.radii)
        return self.centre - reach - margin, self.centre + reach + margin, self.mirror


class Plate(Ellipsoid):
    """Flat elliptic plate of uniform thickness ``2 * radii[0]`` (edges rounded by 1.5 mm):
    an ellipse of semi-axes ``radii[1:]`` in the local (v, w) plane. Unlike a thin ellipsoid
    its rim does not taper, so any sampling finer than its thickness keeps it connected."""

    def sd(self, p) -> np.ndarray:
        dx, dy, dz = self.local(p)
        d = smax(ellipse_sd(dy, dz, self.radii[1:]), np.abs(dx) - self.radii[0], 1.5)
        return np.maximum(d, -dy) if self.half else d


class Cylinder:
    """Elliptic cylinder along z between ``bottom`` and ``top`` (hard caps)."""

    def __init__(self, centre_xy, radii_xy, *, top: float = math.inf, bottom: float = -math.inf):
        self.centre, self.radii = np.asarray(centre_xy, float), tuple(float(r) for r in radii_xy)
        self.top, self.bottom = float(top), float(bottom)

    def sd(self, p) -> np.ndarray:
        d = ellipse_sd(p.x - self.centre[0], p.y - self.centre[1], self.radii)
        if math.isfinite(self.top):
            d = np.maximum(d, p.z - self.top)
        if math.isfinite(self.bottom):
            d = np.maximum(d, self.bottom - p.z)
        return d

    def box(self, margin: float):
        lo = np.array([*(self.centre - self.radii - margin), self.bottom - margin])
        hi = np.array([*(self.centre + self.radii + margin), self.top + margin])
        return lo, hi, False


class SmoothUnion:
    """Smooth union of primitives: ``first`` then ``(primitive, blend)`` pairs."""

    def __init__(self, first, *rest):
        self.first, self.rest = first, rest

    def sd(self, p) -> np.ndarray:
        d = self.first.sd(p)
        for prim, k in self.rest:
            d = smin(d, prim.sd(p), k)
        return d

    def box(self, margin: float):
        boxes = [self.first.box(margin)] + [prim.box(margin + k) for prim, k in self.rest]
        if len({b[2] for b in boxes}) != 1:
            raise ValueError("a smooth union must not mix mirrored and plain primitives")
        return (np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0), boxes[0][2])


def blend(field: np.ndarray, p, prim, k: float, carve: bool = False) -> None:
    """In place: smooth union (or smooth difference if ``carve``) of ``prim`` into ``field``.

    Only points within ``2k + 6`` mm of the primitive's bounding box are touched:
    beyond it the primitive is farther than the blend width from any surface of
    ``field`` that matters (the sign and the near field are unchanged).
    """
    selection = p.select(prim.box(2.0 * k + 6.0))
    if selection is EMPTY:
        return
    d = prim.sd(p.take(selection))
    old = field if selection is None else field[selection]
    new = smax(old, -d, k) if carve else smin(old, d, k)
    if selection is None:
        field[...] = new
    else:
        field[selection] = new
