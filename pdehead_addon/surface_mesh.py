"""Tube meshes of a sampled surface grid: quads stitched along the v seam, caps, UVs, signed volume.

The PDE head (eq. 1-13) is evaluated on a grid u x v (:meth:`.pde_surface.PDEHead.surface`);
this module turns such a (nu, nv, 3) grid into a :class:`~.mesh.Mesh`: the quads
of the tube with the last column joined to the first (the v seam), per-corner
UVs ``(u, v / 2 pi)`` with 1.0 on the seam side, the end rings closed by a fan
to the spine point when the ring is star-shaped around it or else by a
triangulation of the ring polygon (Delaunay, ear clipping), and the signed
enclosed volume that fixes the outward winding.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from .errors import PDEError
from .mesh import Mesh

__all__ = ["signed_volume"]


def _check_count(n, name: str, minimum: int) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or int(n) < minimum:
        raise PDEError(f"{name} must be an integer >= {minimum}, got {n!r}")
    return int(n)


def signed_volume(mesh: Mesh) -> float:
    """Signed enclosed volume (mm^3) by the divergence theorem; > 0 for outward normals."""
    v = mesh.vertices
    tris = [mesh.triangles]
    if len(mesh.quads):
        q = mesh.quads
        tris += [q[:, [0, 1, 2]], q[:, [0, 2, 3]]]
    t = np.concatenate(tris)
    if not len(t):
        return 0.0
    return float(np.einsum("ij,ij->i", v[t[:, 0]], np.cross(v[t[:, 1]], v[t[:, 2]])).sum() / 6.0)


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


def _star_shaped(ring: np.ndarray, centre: np.ndarray) -> tuple[bool, np.ndarray, np.ndarray]:
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
    from scipy.spatial import Delaunay
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


def _fan_caps(pts: np.ndarray, spine_ends: np.ndarray, fan_only: bool = False, ends: tuple[int, ...] = (0, 1)
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
        star, p, _ = (True, None, None) if fan_only else _star_shaped(ring, centre)
        if star:
            caps.append((centre, _fan_indices(n)))
            continue
        ccw = (p[:, 0] * np.roll(p[:, 1], -1) - p[:, 1] * np.roll(p[:, 0], -1)).sum() > 0
        tri = _polygon_triangles(p if ccw else p[::-1])
        if not ccw:
            tri = (n - 1 - tri)[:, ::-1]
        caps.append((None, tri))
    return caps


def _fan_indices(n: int) -> np.ndarray:
    """A fan from a centre (index -1) to a ring of n points, counter-clockwise like the ring."""
    j = np.arange(n)
    return np.stack([np.full(n, -1), j, (j + 1) % n], axis=1)


def _tube_mesh(pts: np.ndarray, orientation: int, caps=None, uv: bool = False,
               u: np.ndarray | None = None, top_u: float = 1.0) -> Mesh:
    """Tube mesh from a (nu, nv, 3) grid, stitched along v; optional caps from :func:`_fan_caps`.

    ``caps`` is a (bottom, top) pair, either of which may be None (left open). With
    ``u`` (the rows' parameters) the vertex attributes ``u`` and ``v`` are set (cap
    centres get v = 0, the top centre u = ``top_u``).
    """
    nu, nv = pts.shape[:2]
    verts = [pts.reshape(-1, 3)]
    extra_u = []
    quads, quad_uv = _tube_topology(nu, nv, orientation)
    tris = []
    tri_uv = []
    if caps is not None:
        nvert = nu * nv
        for end, cap in enumerate(caps):
            if cap is None:
                continue
            centre, tri = cap
            row = 0 if end == 0 else nu - 1
            base = row * nv
            t = tri.copy()
            if centre is not None:
                verts.append(centre[None])
                extra_u.append(0.0 if end == 0 else top_u)
                t = np.where(t < 0, nvert, t + base)
                nvert += 1
            else:
                t = t + base
            # ring order j -> j+1 is counter-clockwise around +u when the tube quads face
            # outward with orientation +1 (checked by the signed volume); the bottom cap faces -u
            if (end == 0) == (orientation > 0):
                t = t[:, ::-1]
            tris.append(t)
            if uv:
                u_end = 0.0 if end == 0 else 1.0
                local = np.where(t >= nu * nv, -1, (t - base) % nv)
                vv = np.where(local < 0, 0.5, local / nv)
                tri_uv.append(np.stack([np.full(vv.shape, u_end), vv], axis=-1))
    mesh = Mesh(np.concatenate(verts), quads,
                np.concatenate(tris) if tris else np.zeros((0, 3), np.int64))
    if uv:
        mesh.quad_uv = quad_uv
        mesh.triangle_uv = np.concatenate(tri_uv) if tri_uv else None
    if u is not None:
        mesh.vertex_attributes["u"] = np.concatenate([np.repeat(u, nv), extra_u])
        mesh.vertex_attributes["v"] = np.concatenate([np.tile(np.arange(nv) * (2.0 * np.pi / nv), nu),
                                                      np.zeros(len(extra_u))])
    return mesh
