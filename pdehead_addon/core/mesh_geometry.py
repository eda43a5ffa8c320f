"""Triangle-mesh geometry shared by the pipeline, the forensic tools and the measures: one copy of each routine.

* :func:`triangulate`, :func:`mesh_triangles`: the triangles of a :class:`~.mesh.Mesh` (quads split along
  their 0-2 diagonal);
* :func:`sample_surface`: points uniform by area on a triangle surface;
* :func:`closest_point_on_triangle`, :func:`point_triangle_distance`: exact, vectorised (Ericson,
  *Real-Time Collision Detection* 5.1.5);
* :class:`MeshDistance`, :func:`point_surface_distance`: the distance from many points to a mesh, exact
  point-to-triangle distances to candidate triangles found with a KD-tree (see :class:`MeshDistance`);
* :func:`edge_neighbours`: the triangle across each edge;
* :func:`signed_volume`: the enclosed volume by the divergence theorem;
* :func:`points_inside`: which points a closed mesh encloses (ray parity).

Numpy and scipy only (no bpy), patient millimetres in and out.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .errors import PDEHeadError

__all__ = ["triangulate", "mesh_triangles", "sample_surface", "closest_point_on_triangle",
           "point_triangle_distance", "edge_neighbours", "MeshDistance", "point_surface_distance", "signed_volume",
           "points_inside"]


def triangulate(faces: np.ndarray) -> np.ndarray:
    """Triangles of a face array: (m, 3) as is, (m, 4) quads split along the 0-2 diagonal."""
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] not in (3, 4):
        raise PDEHeadError(f"faces must have shape (m, 3) or (m, 4), got {f.shape}")
    if f.shape[1] == 3:
        return f
    return np.concatenate([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])


def mesh_triangles(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and all triangles (quads split) of a :class:`~pdehead_addon.core.mesh.Mesh`."""
    tris = [mesh.triangles]
    if len(mesh.quads):
        tris.insert(0, triangulate(mesh.quads))
    return mesh.vertices, np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)


def sample_surface(vertices: np.ndarray, triangles: np.ndarray, count: int,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points uniform by area on the triangles, and the triangle index of each."""
    v = np.asarray(vertices, dtype=np.float64)
    a, b, c = v[triangles[:, 0]], v[triangles[:, 1]], v[triangles[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    total = area.sum()
    if not np.isfinite(total) or total <= 0:
        raise PDEHeadError("surface has no area to sample")
    tri = rng.choice(len(triangles), size=count, p=area / total)
    r1 = np.sqrt(rng.random(count))
    r2 = rng.random(count)
    pts = (1 - r1)[:, None] * a[tri] + (r1 * (1 - r2))[:, None] * b[tri] + (r1 * r2)[:, None] * c[tri]
    return pts, tri


def _closest_on_segment(p: np.ndarray, s0: np.ndarray, s1: np.ndarray) -> np.ndarray:
    d = s1 - s0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip(np.nan_to_num(np.einsum("...i,...i", p - s0, d) / np.einsum("...i,...i", d, d)), 0, 1)
    return s0 + t[..., None] * d


def closest_point_on_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The closest points of triangles (a, b, c) to points p, all (..., 3) (broadcast), vectorised.

    Region classification of Ericson, *Real-Time Collision Detection* 5.1.5; a degenerate triangle (no
    area) gives the nearest point of its three edges.
    """
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("...i,...i", ab, ap)
    d2 = np.einsum("...i,...i", ac, ap)
    bp = p - b
    d3 = np.einsum("...i,...i", ab, bp)
    d4 = np.einsum("...i,...i", ac, bp)
    cp = p - c
    d5 = np.einsum("...i,...i", ab, cp)
    d6 = np.einsum("...i,...i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in = vb / denom
        w_in = vc / denom
        closest = a + v_in[..., None] * ab + w_in[..., None] * ac              # interior
        # edges
        t_ab = np.clip(d1 / (d1 - d3), 0, 1)
        t_ac = np.clip(d2 / (d2 - d6), 0, 1)
        t_bc = np.clip((d4 - d3) / ((d4 - d3) + (d5 - d6)), 0, 1)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    on_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    closest = np.where(on_bc[..., None], b + np.nan_to_num(t_bc)[..., None] * (c - b), closest)
    closest = np.where(on_ac[..., None], a + np.nan_to_num(t_ac)[..., None] * ac, closest)
    closest = np.where(on_ab[..., None], a + np.nan_to_num(t_ab)[..., None] * ab, closest)
    closest = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c, closest)
    closest = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b, closest)
    closest = np.where(((d1 <= 0) & (d2 <= 0))[..., None], a, closest)
    bad = ~np.all(np.isfinite(closest), axis=-1)
    if np.any(bad):  # degenerate triangle: the nearest point of its three edges
        p, a, b, c = np.broadcast_arrays(p, a, b, c)
        q = p[bad]
        edges = [_closest_on_segment(q, s0[bad], s1[bad]) for s0, s1 in ((a, b), (b, c), (a, c))]
        dist = np.stack([np.linalg.norm(q - e, axis=-1) for e in edges])
        closest = np.array(np.broadcast_to(closest, p.shape))
        closest[bad] = np.stack(edges)[np.argmin(dist, axis=0), np.arange(len(q))]
    return closest


def point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact Euclidean distance from points p to triangles (a, b, c), all (..., 3) (broadcast), vectorised:
    the distance to :func:`closest_point_on_triangle`."""
    return np.linalg.norm(p - closest_point_on_triangle(p, a, b, c), axis=-1)


def edge_neighbours(triangles: np.ndarray) -> np.ndarray:
    """(m, 3): the triangle across each edge of each triangle (itself on a boundary edge)."""
    m = len(triangles)
    e = np.stack([triangles, np.roll(triangles, -1, axis=1)], axis=-1).reshape(-1, 2)
    key = np.sort(e, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    ks = key[order]
    same = np.all(ks[1:] == ks[:-1], axis=1)
    out = np.repeat(np.arange(m), 3)                     # default: itself
    a, b = order[:-1][same], order[1:][same]             # the two half-edges of a shared edge
    out[a] = b // 3
    out[b] = a // 3
    return out.reshape(m, 3)


class MeshDistance:
    """Distance from points to a triangle mesh, built once and queried many times.

    Points are sampled uniformly by area on the mesh (``dense`` of them, ``seed``) and, with the mesh's
    vertices, put in a KD-tree; a query point's distance is the exact point-to-triangle distance to the
    best of its candidate triangles: those owning its ``candidates`` nearest samples and, with
    ``neighbours`` (the default), their edge neighbours too. The result is never larger than the plain
    nearest-sample distance and never smaller than the true distance; it equals the true distance unless
    the nearest triangle is among no candidates, which needs a sliver triangle much larger than the sample
    spacing. The neighbours make that rarer still: near a crease of a coarse mesh the nearest triangle can
    own none of the nearest samples (seen on the PDE skull), and a sphere tracer whose distance is too large
    steps through the surface (:func:`~.tissue_depth.cast_rays`).
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, dense: int = 400_000, candidates: int = 6,
                 seed: int = 0, neighbours: bool = True):
        self.v = np.asarray(vertices, np.float64)
        self.t = np.asarray(triangles, np.int64)
        rng = np.random.default_rng(seed)
        pts, tri = sample_surface(self.v, self.t, dense, rng)
        # the vertices themselves are exact surface points too (owned by any incident triangle)
        owner = np.empty(len(self.v), np.int64)
        owner[self.t.ravel()] = np.repeat(np.arange(len(self.t)), 3)
        used = np.unique(self.t.ravel())
        self.tree = cKDTree(np.concatenate([pts, self.v[used]]))
        self.owner = np.concatenate([tri, owner[used]])
        self.neighbours = edge_neighbours(self.t) if neighbours else None
        self.k = max(1, int(candidates))

    def __call__(self, points: np.ndarray, chunk: int = 16384) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64)
        out = np.empty(len(p))
        for s in range(0, len(p), chunk):
            q = p[s:s + chunk]
            _, idx = self.tree.query(q, k=self.k)
            cand = self.owner[idx.reshape(len(q), self.k)]
            if self.neighbours is not None:
                cand = np.concatenate([cand, self.neighbours[cand].reshape(len(q), -1)], axis=1)
            tri = self.t[cand]                                                 # (n, candidates, 3)
            d = point_triangle_distance(q[:, None, :], self.v[tri[..., 0]], self.v[tri[..., 1]], self.v[tri[..., 2]])
            out[s:s + chunk] = d.min(axis=1)
        return out


def point_surface_distance(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray,
                           dense: int = 400_000, candidates: int = 8, seed: int = 0,
                           chunk: int = 65536) -> np.ndarray:
    """Distance of each point to the triangle surface: a one-off :class:`MeshDistance` with ``candidates``
    nearest samples and no edge neighbours."""
    return MeshDistance(vertices, triangles, dense=dense, candidates=candidates, seed=seed,
                        neighbours=False)(points, chunk=chunk)


def signed_volume(mesh) -> float:
    """Signed enclosed volume (mm^3) of a :class:`~.mesh.Mesh` by the divergence theorem; > 0 for outward
    normals."""
    v = mesh.vertices
    tris = [mesh.triangles]
    if len(mesh.quads):
        q = mesh.quads
        tris += [q[:, [0, 1, 2]], q[:, [0, 2, 3]]]
    t = np.concatenate(tris)
    if not len(t):
        return 0.0
    return float(np.einsum("ij,ij->i", v[t[:, 0]], np.cross(v[t[:, 1]], v[t[:, 2]])).sum() / 6.0)


def points_inside(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, cell_mm: float = 2.0) -> np.ndarray:
    """Whether each point lies inside a closed triangle mesh (even-odd rule, ray along +z).

    The triangles are binned by their (x, y) bounding boxes on a grid of ``cell_mm``; a point's vertical ray
    is tested only against the triangles of its cell (barycentric coordinates in x, y). The points are nudged
    by an irrational fraction of a micrometre so no ray runs exactly through an edge or a vertex.
    """
    v = np.asarray(vertices, np.float64)
    t = np.asarray(triangles, np.int64)
    p = np.asarray(points, np.float64).reshape(-1, 3)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    origin = v[:, :2].min(0) - cell_mm
    lo = np.floor((np.minimum(np.minimum(a, b), c)[:, :2] - origin) / cell_mm).astype(np.int64)
    hi = np.floor((np.maximum(np.maximum(a, b), c)[:, :2] - origin) / cell_mm).astype(np.int64)
    nx = int(hi[:, 0].max()) + 2
    width = hi - lo + 1
    count = width[:, 0] * width[:, 1]
    tri = np.repeat(np.arange(len(t)), count)
    local = np.arange(tri.size) - np.repeat(np.cumsum(count) - count, count)
    key = (lo[tri, 1] + local // width[tri, 0]) * nx + lo[tri, 0] + local % width[tri, 0]
    order = np.argsort(key, kind="stable")
    key, tri = key[order], tri[order]
    cell = np.floor((p[:, :2] - origin) / cell_mm).astype(np.int64)
    on_grid = (cell >= 0).all(1) & (cell[:, 0] < nx)
    pkey = np.where(on_grid, cell[:, 1] * nx + cell[:, 0], -1)
    start, stop = np.searchsorted(key, pkey, "left"), np.searchsorted(key, pkey, "right")
    n = np.where(on_grid, stop - start, 0)
    pi = np.repeat(np.arange(len(p)), n)
    ti = tri[np.repeat(start, n) + np.arange(pi.size) - np.repeat(np.cumsum(n) - n, n)]
    px, py = p[pi, 0] + 1e-7 * np.sqrt(2.0), p[pi, 1] + 1e-7 * np.sqrt(3.0)
    A, B, C = a[ti], b[ti], c[ti]
    det = (B[:, 0] - A[:, 0]) * (C[:, 1] - A[:, 1]) - (C[:, 0] - A[:, 0]) * (B[:, 1] - A[:, 1])
    ok = np.abs(det) > 1e-14
    det = np.where(ok, det, 1.0)
    l1 = ((B[:, 0] - px) * (C[:, 1] - py) - (C[:, 0] - px) * (B[:, 1] - py)) / det
    l2 = ((C[:, 0] - px) * (A[:, 1] - py) - (A[:, 0] - px) * (C[:, 1] - py)) / det
    l3 = 1.0 - l1 - l2
    z = l1 * A[:, 2] + l2 * B[:, 2] + l3 * C[:, 2]
    crossing = ok & (l1 >= 0) & (l2 >= 0) & (l3 >= 0) & (z > p[pi, 2])
    return (np.bincount(pi[crossing], minlength=len(p)) & 1).astype(bool)
