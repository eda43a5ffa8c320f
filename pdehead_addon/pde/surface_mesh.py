"""Tube meshes of a sampled surface grid: quads stitched along the v seam, caps, UVs, signed volume.

The PDE head (eq. 1-13) is evaluated on a grid u x v (:meth:`.pde_head.PDEHead.surface`);
this module turns such a (nu, nv, 3) grid into a :class:`~.mesh.Mesh`: the quads
of the tube with the last column joined to the first (the v seam), per-corner
UVs, the end rings closed by a flat disc triangulated ring by ring when the ring
is star-shaped around its spine point (:class:`DiscCap`; a fan to that point for
the crown's pole and the orientation test) or else by a triangulation of the ring
polygon (Delaunay, ear clipping), and the signed enclosed volume that fixes the
outward winding.

UVs (the map and the islands are :mod:`.surface_uv_map`'s, the columns' v :mod:`.surface_columns`'):
the tube is one island (v across, u up: a least-squares map of the boundary curves that keeps the cells'
angles and texel size), the crown's dome and each cap a disc; every island is a function of (u, v) fixed
per study (from the boundary curves), none is mirrored, and each keeps ``UV_MARGIN``
from the texture's border and the seam. This module gives each face corner its UV. Without a layout the UVs are the old
``(u, v / 2 pi)`` (used by the orientation test and the benchmarks' "before").
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.spatial import Delaunay

from ..core.errors import PDEError
from ..core.mesh import Mesh
from ..core.mesh_geometry import signed_volume
from .surface_columns import column_fraction, column_fraction_inverse, column_v
from .surface_uv_map import uv_islands

#: signed_volume is .mesh_geometry's, imported from here by pde_surface, the scripts and the tests
__all__ = ["signed_volume"]

TWO_PI = 2.0 * np.pi


def check_count(n, name: str, minimum: int) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or int(n) < minimum:
        raise PDEError(f"{name} must be an integer >= {minimum}, got {n!r}")
    return int(n)


@lru_cache(maxsize=8)
def _tube_topology(nu: int, nv: int, orientation: int) -> tuple[np.ndarray, np.ndarray]:
    """Quads and per-corner UVs of an (nu, nv) tube, cached and read-only (shared between meshes)."""
    quads, uv = _tube_quads(nu, nv, orientation), _tube_uv(nu, nv, orientation)
    quads.flags.writeable = False
    uv.flags.writeable = False
    return quads, uv


def _tube_quads(nu: int, nv: int, orientation: int) -> np.ndarray:
    i = np.arange(nu - 1)[:, None]
    j = np.arange(nv)[None, :]
    j1 = (j + 1) % nv
    q = np.stack([i * nv + j, i * nv + j1, (i + 1) * nv + j1, (i + 1) * nv + j], axis=-1).reshape(-1, 4)
    return q if orientation > 0 else np.ascontiguousarray(q[:, ::-1])


def _tube_uv(nu: int, nv: int, orientation: int) -> np.ndarray:
    u = np.linspace(0.0, 1.0, nu)
    j = np.arange(nv) / nv
    uv = np.empty((nu - 1, nv, 4, 2))
    uv[:, :, 0, 0] = uv[:, :, 1, 0] = u[:-1, None]
    uv[:, :, 2, 0] = uv[:, :, 3, 0] = u[1:, None]
    uv[:, :, 0, 1] = uv[:, :, 3, 1] = j[None, :]
    uv[:, :, 1, 1] = uv[:, :, 2, 1] = j[None, :] + 1.0 / nv          # the seam corner gets 1.0
    uv = uv.reshape(-1, 4, 2)
    return uv if orientation > 0 else np.ascontiguousarray(uv[:, ::-1])


def star_shaped_ring(ring: np.ndarray, centre: np.ndarray) -> tuple[bool, np.ndarray, np.ndarray]:
    """Whether a closed ring winds once monotonically around centre (in its own plane)."""
    d = ring - centre
    normal = np.cross(d, np.roll(d, -1, axis=0)).sum(axis=0)                 # Newell normal * 2
    norm = np.linalg.norm(normal)
    if norm == 0:
        return False, np.zeros((len(ring), 2)), normal
    normal = normal / norm
    e1 = d[np.argmax(np.linalg.norm(d, axis=1))]
    e1 = e1 - normal * (e1 @ normal)
    e1 /= np.linalg.norm(e1) or 1.0
    e2 = np.cross(normal, e1)
    p = np.stack([d @ e1, d @ e2], axis=1)
    cross = p[:, 0] * np.roll(p[:, 1], -1) - p[:, 1] * np.roll(p[:, 0], -1)
    return bool(np.all(cross > 0)), p, normal


def _ear_clip(p: np.ndarray) -> np.ndarray:
    """Triangulate a simple counter-clockwise polygon (n, 2) by ear clipping: (n-2, 3) indices."""
    idx = list(range(len(p)))
    tris = []
    guard = 0
    while len(idx) > 3 and guard < 4 * len(p) * len(p):
        guard += 1
        n = len(idx)
        arr = np.array(idx)
        a, b, c = p[np.roll(arr, 1)], p[arr], p[np.roll(arr, -1)]
        convex = ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])) > 0
        clipped = False
        for m in np.nonzero(convex)[0]:
            ia, ib, ic = idx[m - 1], idx[m], idx[(m + 1) % n]
            others = np.array([x for x in idx if x not in (ia, ib, ic)])
            if others.size:
                q = p[others]
                A, B, C = p[ia], p[ib], p[ic]
                d1 = (B[0] - A[0]) * (q[:, 1] - A[1]) - (B[1] - A[1]) * (q[:, 0] - A[0])
                d2 = (C[0] - B[0]) * (q[:, 1] - B[1]) - (C[1] - B[1]) * (q[:, 0] - B[0])
                d3 = (A[0] - C[0]) * (q[:, 1] - C[1]) - (A[1] - C[1]) * (q[:, 0] - C[0])
                if np.any((d1 >= 0) & (d2 >= 0) & (d3 >= 0)):
                    continue
            tris.append((ia, ib, ic))
            idx.pop(m)
            clipped = True
            break
        if not clipped:  # numerically degenerate remainder: close with a fan
            break
    for m in range(1, len(idx) - 1):
        tris.append((idx[0], idx[m], idx[m + 1]))
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


def _points_in_polygon(q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd test of points q (n, 2) against a closed polygon (m, 2), vectorised."""
    a, b = poly, np.roll(poly, -1, axis=0)
    inside = np.zeros(len(q), bool)
    for start in range(0, len(a), 256):
        pa, pb = a[start:start + 256], b[start:start + 256]
        cond = (pa[None, :, 1] > q[:, None, 1]) != (pb[None, :, 1] > q[:, None, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = pa[None, :, 0] + (q[:, None, 1] - pa[None, :, 1]) * (pb[None, :, 0] - pa[None, :, 0]) / (
                pb[None, :, 1] - pa[None, :, 1])
        inside ^= (np.count_nonzero(cond & (q[:, None, 0] < xc), axis=1) % 2).astype(bool)
    return inside


def _polygon_triangles(p: np.ndarray) -> np.ndarray:
    """Triangulation of a simple counter-clockwise polygon (n, 2) without new vertices.

    Delaunay triangles inside the polygon when they recover every boundary edge
    (the usual case for densely sampled curves), else ear clipping.
    """
    n = len(p)
    try:
        tri = Delaunay(p).simplices
        cen = p[tri].mean(axis=1)
        tri = tri[_points_in_polygon(cen, p)]
        a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
        cw = ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])) < 0
        tri[cw] = tri[cw][:, ::-1]
        if len(tri) == n - 2:
            e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
            boundary = (e[:, 1] - e[:, 0]) % n == 1
            if np.count_nonzero(boundary) == n and len(np.unique(e[boundary, 0])) == n:
                return tri
    except Exception:  # qhull failure on degenerate input: fall through to ear clipping
        pass
    return _ear_clip(p)


def fan_caps(pts: np.ndarray, spine_ends: np.ndarray, fan_only: bool = False, ends: tuple[int, ...] = (0, 1)
              ) -> list[tuple[np.ndarray | None, np.ndarray]]:
    """Cap triangulations of the first and last ring: (centre or None, triangles in ring indices).

    A fan to the spine point when the ring is star-shaped around it (or when
    ``fan_only``: enough for signed volumes), else a triangulation of the ring
    polygon in its plane. Triangles run counter-clockwise like the ring; the
    caller orients them.
    """
    caps = []
    for end in ends:
        ring, centre = (pts[0], spine_ends[0]) if end == 0 else (pts[-1], spine_ends[1])
        n = len(ring)
        star, p, _ = (True, None, None) if fan_only else star_shaped_ring(ring, centre)
        if star:
            caps.append((centre, fan_indices(n)))
            continue
        ccw = (p[:, 0] * np.roll(p[:, 1], -1) - p[:, 1] * np.roll(p[:, 0], -1)).sum() > 0
        tri = _polygon_triangles(p if ccw else p[::-1])
        if not ccw:
            tri = (n - 1 - tri)[:, ::-1]
        caps.append((None, tri))
    return caps


def fan_indices(n: int) -> np.ndarray:
    """A fan from a centre (index -1) to a ring of n points, counter-clockwise like the ring."""
    j = np.arange(n)
    return np.stack([np.full(n, -1), j, (j + 1) % n], axis=1)


def _zipper(keys: list[np.ndarray], offsets: np.ndarray) -> np.ndarray:
    """Triangles between each closed ring k and ring k+1 inside it, joined in the order of their positions.

    ``keys[k]``: increasing position (a fraction of the turn, from the same start) of the middle of each
    edge i -> i+1 of ring k; ``offsets[k]``: the index of ring k's first point. Every triangle has one edge
    on a ring, so none spans more than a step of either; counter-clockwise like the rings. All ring
    pairs at once (one sort).
    """
    sizes = np.array([len(k) for k in keys])
    pairs = len(keys) - 1
    a_sizes, b_sizes = sizes[:-1], sizes[1:]
    key = np.concatenate(keys[:-1] + keys[1:])
    pair = np.concatenate([np.repeat(np.arange(pairs), a_sizes), np.repeat(np.arange(pairs), b_sizes)])
    kind = np.concatenate([np.zeros(a_sizes.sum(), bool), np.ones(b_sizes.sum(), bool)])
    order = np.lexsort((kind, key, pair))
    pair, kind = pair[order], kind[order]
    start = np.concatenate([[0], np.cumsum(a_sizes + b_sizes)[:-1]])        # first event of each pair
    ca, cb = np.cumsum(~kind), np.cumsum(kind)
    before_a = np.concatenate([[0], ca])[start]
    before_b = np.concatenate([[0], cb])[start]
    ia = ca - (~kind) - before_a[pair]
    ib = cb - kind - before_b[pair]
    na, nb = a_sizes[pair], b_sizes[pair]
    oa, ob = np.asarray(offsets)[:-1][pair], np.asarray(offsets)[1:][pair]
    a0, a1 = oa + ia % na, oa + (ia + 1) % na
    b0, b1 = ob + ib % nb, ob + (ib + 1) % nb
    return np.where(kind[:, None], np.stack([a0, b1, b0], axis=1), np.stack([a0, a1, b0], axis=1))


def ring_in_plane(ring: np.ndarray, centre: np.ndarray):
    """A closed ring's coordinates in its own plane through ``centre``, counter-clockwise.

    The plane's normal is the ring's area vector about ``centre``. Returns ``flat`` (the ring's offsets
    from ``centre`` projected into the plane, (n, 3)), the in-plane axes ``e1`` (towards the first point)
    and ``e2``, the 2-D points ``p2`` ((n, 2)) and their unwrapped angle ``theta`` (0 at the first point,
    increasing).
    """
    d = ring - centre
    normal = np.cross(d, np.roll(d, -1, axis=0)).sum(axis=0)
    normal /= np.linalg.norm(normal) or 1.0
    flat = d - np.outer(d @ normal, normal)
    e1 = flat[0] / (np.linalg.norm(flat[0]) or 1.0)
    e2 = np.cross(normal, e1)
    p2 = np.stack([flat @ e1, flat @ e2], axis=1)
    theta = np.unwrap(np.arctan2(p2[:, 1], p2[:, 0]))
    theta -= theta[0]
    if theta[-1] < 0:                                   # clockwise in this frame
        p2[:, 1] *= -1
        e2 = -e2
        theta = -theta
    return flat, e1, e2, p2, theta


class DiscCap:
    """A flat cap triangulated ring by ring (the neck closed without a fan of long triangles).

    Rings of the end curve scaled toward its centre in the curve's plane, radial steps of at most ``edge`` mm (at
    the ring's farthest point), each with about one point per ``edge`` mm placed at even fractions of the end
    curve's samples (its v), joined in the order of those fractions (:func:`_zipper`); the last ring is joined to
    the centre. With ``plan`` (a reference perimeter and radius) the counts, hence the connectivity, do not depend
    on the ring of the moment. Attributes: ``vertices`` (the new points), ``triangles`` (ring indices 0 .. n-1, new
    points from n), counter-clockwise like the ring, ``radius`` (fraction of the end curve, 0 at the centre) and
    ``angle`` (the v of the end curve in the same direction, radians) of every new point.
    """

    def __init__(self, ring: np.ndarray, centre: np.ndarray, edge: float, plan: tuple | None = None):
        n = len(ring)
        flat, e1, e2, p2, theta = ring_in_plane(ring, centre)
        edge = max(float(edge), 1e-9)
        # plan: (perimeter, largest radius) of a reference ring that fixes the counts, so the topology
        # does not change while the shape sliders move the ring a little (in-place rebuilds)
        closed = np.vstack([p2, p2[:1]])
        own_arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
        if plan is None:
            p_ref, r_ref, arc_fraction = None, float(np.linalg.norm(flat, axis=1).max()), own_arc / own_arc[-1]
        else:
            p_ref, r_ref, arc_fraction = plan                 # arc_fraction: at v = 2 pi k / K, k = 0 .. K
        rings = max(1, int(np.ceil(r_ref / edge)))
        f = 1.0 - np.arange(1, rings) / rings                                  # the inner rings' scale
        perimeter = float(np.linalg.norm(np.roll(p2, -1, axis=0) - p2, axis=1).sum()) if p_ref is None else p_ref
        m = np.maximum(6, np.ceil(f * perimeter / edge).astype(np.int64))
        ring_of = np.repeat(np.arange(len(f)), m)
        first = np.concatenate([[0], np.cumsum(m)[:-1]])
        j = np.arange(m.sum()) - first[ring_of]
        # each inner ring evenly along the (reference) end curve's length, at fixed fractions of its
        # samples (its v): the connectivity depends on the counts only, a shape slider rebuilds in place
        v_frac = np.interp(j / m[ring_of], arc_fraction, np.linspace(0.0, 1.0, len(arc_fraction)))
        idx = v_frac * n
        lo = np.floor(idx).astype(np.int64)
        w = (idx - lo)[:, None]
        q = p2[lo % n] * (1 - w) + p2[(lo + 1) % n] * w
        fr = f[ring_of]
        mid = np.where(np.arange(m.sum()) + 1 < (first + m)[ring_of], 0.5 * (v_frac + np.roll(v_frac, -1)),
                       0.5 * (v_frac + 1.0))
        keys = [(np.arange(n) + 0.5) / n] + np.split(mid, first[1:])
        offsets = np.concatenate([[0], n + first, [n + m.sum()]])
        tris = [_zipper(keys, offsets[:-1])] if len(f) else []
        centre_index = n + int(m.sum())
        last_off, last_n = (offsets[-2], int(m[-1])) if len(f) else (0, n)
        j = np.arange(last_n)
        tris.append(np.stack([np.full(last_n, centre_index), last_off + j, last_off + (j + 1) % last_n], axis=1))
        self.vertices = np.concatenate([centre + fr[:, None] * (q[:, :1] * e1 + q[:, 1:] * e2),
                                        np.asarray(centre, float)[None]])
        self.triangles = np.concatenate(tris)
        self.radius = np.concatenate([fr, [0.0]])
        self.angle = np.concatenate([TWO_PI * idx / n, [0.0]])



#: The disc caps' step (radially and along each ring) in mean edges of the tube: a flat disc needs no
#: finer triangles, and the mesh should have none longer than 3 mean edges. 1.2, not 1.5: where the outline
#: runs radially a ring's step and the step to the next ring lie along one line, so a zipper triangle
#: there spans both (the longest edge is under 3 mean edges at 1.2, not at 1.5, on GE). The caps' triangle count
#: grows by ~1.5x (figures in docs/benchmarks.md).
CAP_EDGE = 1.2


def disc_caps(pts: np.ndarray, spine_ends: np.ndarray, ends: tuple[int, ...] = (0, 1),
              reference: dict | None = None) -> list:
    """Caps of the first / last ring: a :class:`DiscCap` where the ring is star-shaped around its spine
    point, else the polygon triangulation of :func:`fan_caps`. The step is :data:`CAP_EDGE` tube edges.

    ``reference`` (:meth:`.pde_head.PDEHead.cap_reference`): the tube's edge and each end ring's
    perimeter and radius from the boundary curves, so the caps' vertex counts depend on nu and nv only.
    """
    if reference is not None:
        edge = CAP_EDGE * float(reference["edge"])
    else:
        du = np.linalg.norm(np.diff(pts, axis=0), axis=-1).mean() if len(pts) > 1 else 0.0
        dv = np.linalg.norm(np.roll(pts, -1, axis=1) - pts, axis=-1).mean()
        edge = CAP_EDGE * (0.5 * (du + dv) if du > 0 else dv)
    out = []
    for end in ends:
        ring, centre = (pts[0], spine_ends[0]) if end == 0 else (pts[-1], spine_ends[1])
        star, _, _ = star_shaped_ring(ring, centre)
        plan = None if reference is None else reference["ends"][end]
        out.append(DiscCap(ring, centre, edge, plan) if star else fan_caps(pts, spine_ends, ends=(end,))[0])
    return out



def _table_at(layout: dict, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """U and V of :func:`uv_tube_map` at rows u (k,) and angles v (m,) (v = 2 pi is the seam's far side,
    U + W there), linear in u between curves and around v."""
    U, V, W = layout["tube_map"]
    cu = np.asarray(layout.get("map_u", layout["curve_u"]), float)
    M = U.shape[1]
    j = np.clip(np.searchsorted(cu, u, side="right") - 1, 0, len(cu) - 2)
    w = np.clip((u - cu[j]) / np.maximum(cu[j + 1] - cu[j], 1e-12), 0.0, 1.0)[:, None]
    density = layout.get("v_density")
    if density is None:
        x = np.asarray(v, float) * (M / TWO_PI)
    else:                                            # the table's samples lie at column_v(density, M)
        v = np.asarray(v, float)
        turns = np.floor_divide(v, TWO_PI)
        x = (column_fraction(density, v - TWO_PI * turns) + turns) * M
    lo = np.floor(x).astype(np.int64)
    f = x - lo
    turns_lo, turns_hi = np.floor_divide(lo, M), np.floor_divide(lo + 1, M)
    out = []
    for T, wrap in ((U, W), (V, 0.0)):
        rows = T[j] * (1 - w) + T[j + 1] * w
        out.append(rows[:, lo % M] * (1 - f) + rows[:, (lo + 1) % M] * f
                   + wrap * (turns_lo * (1 - f) + turns_hi * f))
    return out[0], out[1]


def _shear_at(layout: dict, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """phi of :func:`uv_shear` at rows u (k,) and angles v (m,), linear in u between curves and around v."""
    shear = layout.get("shear")
    if shear is None:
        return np.zeros((len(u), len(v)))
    cu = np.asarray(layout["curve_u"], float)
    M = shear.shape[1]
    j = np.clip(np.searchsorted(cu, u, side="right") - 1, 0, len(cu) - 2)
    w = np.clip((u - cu[j]) / np.maximum(cu[j + 1] - cu[j], 1e-12), 0.0, 1.0)[:, None]
    rows = shear[j] * (1 - w) + shear[j + 1] * w                               # (k, M)
    x = np.mod(v, TWO_PI) * (M / TWO_PI)
    lo = np.floor(x).astype(np.int64) % M
    f = x - np.floor(x)
    return rows[:, lo] * (1 - f) + rows[:, (lo + 1) % M] * f


def _signed_uv_area(uv: np.ndarray) -> np.ndarray:
    """Signed area of each UV polygon (..., k, 2), > 0 counter-clockwise."""
    x, y = uv[..., 0], uv[..., 1]
    return 0.5 * (x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y).sum(axis=-1)


def _disc_uv(centre, radius: float, rho: np.ndarray, angle: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Polar UVs ``centre + radius * rho * (cos, sin)(+-angle)`` of the vertices (rho, angle), per corner
    of ``faces`` (indices into them), turned so the faces are not mirrored."""
    r = np.clip(rho, 0.0, 1.0 / 0.9) * (0.9 * radius)
    uv = np.stack([centre[0] + r * np.cos(angle), centre[1] + r * np.sin(angle)], axis=-1)[faces]
    if np.sum(_signed_uv_area(uv)) < 0:                                      # mirrored: turn the other way
        uv[..., 1] = 2.0 * centre[1] - uv[..., 1]
    return uv


@lru_cache(maxsize=8)
def _corner_grid_index(nu: int, nv: int, orientation: int) -> np.ndarray:
    """Per quad corner, the index into an (nu, nv + 1) grid of (row, column) with the seam column nv."""
    i = np.arange(nu - 1)[:, None, None] + np.array([0, 0, 1, 1])[None, None, :]
    j = np.arange(nv)[None, :, None] + np.array([0, 1, 1, 0])[None, None, :]
    idx = (i * (nv + 1) + j).reshape(-1, 4)
    idx = idx if orientation > 0 else np.ascontiguousarray(idx[:, ::-1])
    idx.flags.writeable = False
    return idx


def tube_mesh(pts: np.ndarray, orientation: int, caps=None, uv: bool = False,
               u: np.ndarray | None = None, top_u: float = 1.0, uv_layout: dict | None = None,
               v_density: np.ndarray | None = None) -> Mesh:
    """Tube mesh from a (nu, nv, 3) grid, stitched along v; optional caps (:func:`disc_caps`, :func:`fan_caps`).

    ``caps`` is a (bottom, top) pair, either of which may be None (left open). With
    ``u`` (the rows' parameters) the vertex attributes ``u`` and ``v`` are set (cap
    centres get v = 0, the top centre u = ``top_u``). ``uv_layout`` (with ``u``):
    ``{"u_top": u where the dome starts (1 without), "aspect": tube length / circumference}``
    gives the UV islands of :func:`uv_islands`; else per-corner ``(u, v / 2 pi)``. ``v_density``
    (:func:`column_density`): the columns lie at :func:`column_v` (the attribute ``v`` and the tube's UVs
    follow it; the discs' polar angle is the column fraction, a function of v too).
    """
    nu, nv = pts.shape[:2]
    verts = [pts.reshape(-1, 3)]
    extra_u, extra_v = [], []
    quads, quad_uv = _tube_topology(nu, nv, orientation)
    tris = []
    cap_faces = []                                   # (end, triangles, polar radius / angle per vertex or None)
    if caps is not None:
        nvert = nu * nv
        for end, cap in enumerate(caps):
            if cap is None:
                continue
            row = 0 if end == 0 else nu - 1
            base = row * nv
            end_u = 0.0 if end == 0 else top_u
            if isinstance(cap, DiscCap):
                t = cap.triangles.copy()
                new = t >= nv
                t = np.where(new, t - nv + nvert, t + base)
                verts.append(cap.vertices)
                extra_u.append(np.full(len(cap.vertices), end_u))
                extra_v.append(TWO_PI * column_fraction_inverse(v_density, cap.angle / TWO_PI))
                polar = (np.concatenate([np.ones(nv), cap.radius]),
                         np.concatenate([TWO_PI * np.arange(nv) / nv, cap.angle]), base, nvert)
                nvert += len(cap.vertices)
            else:
                centre, t = cap
                t = t.copy()
                if centre is not None:
                    verts.append(centre[None])
                    extra_u.append(np.array([end_u]))
                    extra_v.append(np.zeros(1))
                    polar = (np.concatenate([np.ones(nv), [0.0]]),
                             np.concatenate([TWO_PI * np.arange(nv) / nv, [0.0]]), base, nvert)
                    t = np.where(t < 0, nvert, t + base)
                    nvert += 1
                else:
                    polar = None
                    t = t + base
            # ring order j -> j+1 is counter-clockwise around +u when the tube quads face
            # outward with orientation +1 (checked by the signed volume); the bottom cap faces -u
            if (end == 0) == (orientation > 0):
                t = t[:, ::-1]
            tris.append(t)
            cap_faces.append((end, t, polar))
    all_verts = np.concatenate(verts)
    mesh = Mesh(all_verts, quads, np.concatenate(tris) if tris else np.zeros((0, 3), np.int64))
    if uv and uv_layout is not None and u is not None:
        mesh.quad_uv, mesh.triangle_uv = _island_uv(all_verts, quads, cap_faces, nu, nv, np.asarray(u, float),
                                                    orientation, uv_layout, v_density)
    elif uv:
        tri_uv = []
        for end, t, _ in cap_faces:
            base = (0 if end == 0 else nu - 1) * nv
            u_end = 0.0 if end == 0 else 1.0
            local = np.where(t >= nu * nv, -1, (t - base) % nv)
            vv = np.where(local < 0, 0.5, local / nv)
            tri_uv.append(np.stack([np.full(vv.shape, u_end), vv], axis=-1))
        mesh.quad_uv = quad_uv
        mesh.triangle_uv = np.concatenate(tri_uv) if tri_uv else None
    if u is not None:
        mesh.vertex_attributes["u"] = np.concatenate([np.repeat(u, nv)] + extra_u)
        mesh.vertex_attributes["v"] = np.concatenate([np.tile(column_v(v_density, nv), nu)] + extra_v)
    return mesh


#: The tube's and dome's quad UVs depend on (nu, nv) and the study's layout only: the shape sliders reuse them.
_QUAD_UV_CACHE: dict = {}


def _tube_and_dome_uv(quads, nu: int, nv: int, u: np.ndarray, orientation: int, layout: dict, isl: dict,
                      v_density: np.ndarray | None = None):
    """Per-corner UVs of the tube's quads: the tube island, and the dome's disc above ``u_top``."""
    x0, y0, width, height = isl["tube"]
    u_top = float(layout["u_top"])
    v_cols = np.append(column_v(v_density, nv), TWO_PI)                      # the seam column gets 2 pi
    grid = np.empty((nu, nv + 1, 2))
    if layout.get("tube_map") is not None:
        # the near-conformal, even-scale map of the curves (uv_tube_map), one scale for U and V
        # (the angles are kept) so the island fits the tube's rectangle; rows above the top curve (the
        # dome) take it at the top curve and are overwritten by the dome's disc below
        U, V = _table_at(layout, np.minimum(u, u_top), v_cols)
        box = layout["tube_box"]                                             # (U min, U max, V min, V max)
        scale = min(width / (box[1] - box[0]), height / (box[3] - box[2]))
        frac = (U - box[0]) * scale / width
        grid[..., 1] = y0 + (V - box[2]) * scale
    else:
        phi = _shear_at(layout, u, v_cols)                                      # (nu, nv + 1)
        seam = _shear_at(layout, np.asarray(layout.get("curve_u", [0.0, 1.0]), float), np.zeros(1))[:, 0]
        span = TWO_PI + seam.max() - seam.min()                              # the island's wavy left/right edges
        frac = (v_cols[None, :] - phi + seam.max()) / span
        grid[..., 1] = (y0 + height * u / u_top)[:, None]
    frac = frac if orientation > 0 else 1.0 - frac
    grid[..., 0] = x0 + width * frac
    quad_uv = grid.reshape(-1, 2)[_corner_grid_index(nu, nv, orientation)]
    if u_top < 1.0:
        dome_rows = (0.5 * (u[:-1] + u[1:]) > u_top)
        if np.any(dome_rows):
            r0 = int(np.argmax(dome_rows))
            sel = np.repeat(dome_rows, nv)
            q = quads[sel] - r0 * nv
            rho_v = np.repeat((1.0 - u[r0:]) / (1.0 - u_top), nv)
            ang_v = np.tile(TWO_PI * np.arange(nv) / nv, nu - r0)
            quad_uv[sel] = _disc_uv(isl["dome"], isl["dome_radius"], rho_v, ang_v, q)
    return quad_uv


def _island_uv(verts, quads, cap_faces, nu: int, nv: int, u: np.ndarray, orientation: int, layout: dict,
               v_density: np.ndarray | None = None):
    """Per-corner UVs of the tube, dome and cap islands (:func:`uv_islands`), each a function of (u, v).

    Tube: ``U = left + width * v / 2 pi`` (mirrored for the other winding), ``V = bottom + height *
    u / u_top``. Dome (quads whose centre lies above ``u_top``, and the pole's fan): polar, radius
    ``(1 - u) / (1 - u_top)``, angle v. Caps: polar, radius the cap ring's fraction of the end curve.
    No island is mirrored (the winding of each is checked).
    """
    isl = uv_islands(float(layout["aspect"]), layout.get("dome_ratio"), layout.get("cap_ratio"))
    u_top = float(layout["u_top"])
    shear = layout.get("shear")
    tube_map = layout.get("tube_map")
    key = (nu, nv, orientation, u_top, float(layout["aspect"]), isl["dome_radius"], hash(u.tobytes()),
           None if shear is None else (shear.ctypes.data, shear.shape, float(shear.sum())),
           None if tube_map is None else (tube_map[0].ctypes.data, tube_map[0].shape, float(tube_map[0].sum())),
           None if v_density is None else hash(np.asarray(v_density, float).tobytes()))
    quad_uv = _QUAD_UV_CACHE.get(key)
    if quad_uv is None:
        quad_uv = _tube_and_dome_uv(quads, nu, nv, u, orientation, layout, isl, v_density)
        quad_uv.flags.writeable = False
        if len(_QUAD_UV_CACHE) >= 8:
            _QUAD_UV_CACHE.pop(next(iter(_QUAD_UV_CACHE)))
        _QUAD_UV_CACHE[key] = quad_uv
    tri_uv = []
    for end, t, polar in cap_faces:
        dome_fan = end == 1 and u_top < 1.0
        centre = isl["dome"] if end == 1 else isl["cap"]           # without a dome the top cap takes its place
        if polar is not None:
            rho, ang, base, first_new = polar
            rho = rho.copy()
            if dome_fan:                                                         # the pole fan: dome polar
                rho[:nv] = (1.0 - u[-1]) / (1.0 - u_top)
            local = np.where(t >= first_new, t - first_new + nv, t - base)
            tri_uv.append(_disc_uv(centre, isl["dome_radius" if end == 1 else "cap_radius"], rho, ang, local))
        else:                                                                    # polygon cap: planar projection
            ring = verts[t]
            c = verts[np.unique(t)].mean(axis=0)
            d = verts[np.unique(t)] - c
            _, _, vt = np.linalg.svd(d, full_matrices=False)
            p = (ring - c) @ vt[:2].T
            p /= np.abs(p).max() or 1.0
            rho, ang = np.hypot(p[..., 0], p[..., 1]), np.arctan2(p[..., 1], p[..., 0])
            flat = np.arange(t.size).reshape(t.shape)
            tri_uv.append(_disc_uv(centre, isl["dome_radius" if end == 1 else "cap_radius"], rho.ravel(), ang.ravel(),
                                   flat))
    return quad_uv, (np.concatenate(tri_uv) if tri_uv else None)
