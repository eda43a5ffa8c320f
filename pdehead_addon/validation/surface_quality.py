"""How smooth a PDE head looks, in numbers: creases, folds, notches and terracing.

These are the measures of the surface's smoothness, evaluated
on a ``(20 t + 1) x 360`` grid of :meth:`PDEHead.evaluate` by default:

* **crease** - at every interior boundary curve ``u_k``, the angle between the
  one-sided surface normals at ``u_k - 2e-4`` and ``u_k + 2e-4`` (u in [0, 1]).
  The paper's four-position patches (eq. 3-6) are only C0 at the patch joints;
  a C1 surface has no jump in the limit.
* **folds** - rings ``X(u, .)`` whose projection on the axial plane crosses itself.
* **notches** - share of grid points whose in-ring outward normal points toward
  the ring's (area) centroid (inlets, slits, holes: the ring is not star-shaped there).
* **terracing** - for consecutive curves ``j, j+1``: per v, the ring radius half
  way between them minus the mean of the radii at the two curves (one centre per
  pair: the mean of the three rings' centroids); RMS over v and over the pairs in
  the middle 80 % of the height. A smooth convex head gives about
  ``curvature * gap^2 / 8`` (0.08 mm for a 90 mm sphere and 7.5 mm gaps); steps
  from slice to slice give much more.
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import LinearNDInterpolator

TWO_PI = 2.0 * np.pi
#: Half step (in u) of the one-sided normals at a curve (the issue's 2e-4).
CREASE_OFFSET = 2e-4


def _normals(head, u: np.ndarray, v: np.ndarray, du: float) -> np.ndarray:
    """Unit normals ``X_v x X_u`` at (u, v) from central differences of width ``du`` in u."""
    dv = TWO_PI / 3600.0
    xu = (head.evaluate(u + du, v) - head.evaluate(u - du, v)) / (2 * du)
    xv = (head.evaluate(u, v + dv) - head.evaluate(u, v - dv)) / (2 * dv)
    n = np.cross(xv, xu)
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)


def crease_angles(head, nv: int = 360, offset: float = CREASE_OFFSET) -> np.ndarray:
    """Angle (degrees) between the one-sided normals at every interior curve, shape (n_interior, nv).

    The normals are taken at ``u_k -/+ offset`` with differences of width ``offset / 2``,
    so each one sees only its own side of the curve.
    """
    uk = np.asarray(head.curve_u, float)[1:-1]
    v = TWO_PI * np.arange(nv) / nv
    uu, vv = np.meshgrid(uk, v, indexing="ij")
    below = _normals(head, uu - offset, vv, offset / 2)
    above = _normals(head, uu + offset, vv, offset / 2)
    cos = np.clip(np.einsum("...i,...i", below, above), -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def _segments_cross(xy: np.ndarray) -> int:
    """Number of pairs of non-adjacent edges of a closed polygon (n, 2) that cross."""
    a, b = xy, np.roll(xy, -1, axis=0)
    n = len(xy)
    # orientation tests of every edge pair, vectorised
    def orient(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])
    A, B = a[:, None], b[:, None]
    C, D = a[None, :], b[None, :]
    o1, o2 = orient(A, B, C), orient(A, B, D)
    o3, o4 = orient(C, D, A), orient(C, D, B)
    cross = (o1 * o2 < 0) & (o3 * o4 < 0)
    i, j = np.triu_indices(n, 2)
    keep = (j - i) % n != n - 1                                   # first and last edge are adjacent
    return int(np.count_nonzero(cross[i[keep], j[keep]]))


def fold_count(head, nu: int | None = None, nv: int = 360) -> int:
    """Rings ``X(u, .)`` of the (nu x nv) grid whose axial projection crosses itself."""
    nu = 20 * head.patches + 1 if nu is None else nu
    rings = head.evaluate(*np.meshgrid(np.linspace(0, 1, nu), TWO_PI * np.arange(nv) / nv, indexing="ij"))
    return int(sum(_segments_cross(r[:, :2]) > 0 for r in rings))


def notch_fraction(head, nu: int | None = None, nv: int = 360) -> float:
    """Share of grid points whose in-ring outward normal points toward the ring's centroid."""
    nu = 20 * head.patches + 1 if nu is None else nu
    rings = head.evaluate(*np.meshgrid(np.linspace(0, 1, nu), TWO_PI * np.arange(nv) / nv, indexing="ij"))
    xy = rings[..., :2]
    tangent = np.roll(xy, -1, axis=1) - np.roll(xy, 1, axis=1)
    outward = np.stack([tangent[..., 1], -tangent[..., 0]], axis=-1)      # ccw ring: (dy, -dx) points out
    # orientation of each ring (a ring may be cw if the head was given so): flip per ring
    area = (xy[..., 0] * np.roll(xy[..., 1], -1, axis=1) - np.roll(xy[..., 0], -1, axis=1) * xy[..., 1]).sum(axis=1)
    outward *= np.where(area >= 0, 1.0, -1.0)[:, None, None]
    cross = xy[..., 0] * np.roll(xy[..., 1], -1, axis=1) - np.roll(xy[..., 0], -1, axis=1) * xy[..., 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        centroid = ((xy + np.roll(xy, -1, axis=1)) * cross[..., None]).sum(axis=1) / (3.0 * cross.sum(axis=1))[:, None]
    centroid = np.where(np.isfinite(centroid), centroid, xy.mean(axis=1))[:, None, :]
    radial = xy - centroid
    inward = np.einsum("...i,...i", outward, radial) < 0
    degenerate = np.linalg.norm(tangent, axis=-1) < 1e-9                   # a pole ring
    return float(np.count_nonzero(inward & ~degenerate) / max(1, np.count_nonzero(~degenerate)))


def terracing_rms(head, nv: int = 360, middle: float = 0.8) -> float:
    """RMS (mm) of ``r_mid - (r_j + r_{j+1}) / 2`` over v and the pairs in the middle of the height."""
    uk = np.asarray(head.curve_u, float)
    v = TWO_PI * np.arange(nv) / nv
    um = 0.5 * (uk[:-1] + uk[1:])
    rings_k = head.evaluate(uk[:, None], v[None, :])
    rings_m = head.evaluate(um[:, None], v[None, :])
    z = rings_k[..., 2].mean(axis=1)
    lo, hi = z.min(), z.max()
    margin = 0.5 * (1.0 - middle) * (hi - lo)
    zm = 0.5 * (z[:-1] + z[1:])
    keep = (zm >= lo + margin) & (zm <= hi - margin)
    if not np.any(keep):
        return 0.0
    a, b, m = rings_k[:-1][keep, :, :2], rings_k[1:][keep, :, :2], rings_m[keep, :, :2]
    centre = (a.mean(axis=1) + b.mean(axis=1) + m.mean(axis=1))[:, None, :] / 3.0
    ra, rb, rm = (np.linalg.norm(x - centre, axis=-1) for x in (a, b, m))
    d = rm - 0.5 * (ra + rb)
    return float(np.sqrt(np.mean(d * d)))


def surface_quality(head, nv: int = 360) -> dict[str, float]:
    """All four measures: crease p95/max (degrees), folds, notch fraction, terracing RMS (mm)."""
    crease = crease_angles(head, nv=nv)
    return {
        "crease_p95_deg": float(np.percentile(crease, 95)) if crease.size else 0.0,
        "crease_max_deg": float(crease.max()) if crease.size else 0.0,
        "folds": fold_count(head, nv=nv),
        "notch_fraction": notch_fraction(head, nv=nv),
        "terracing_rms_mm": terracing_rms(head, nv=nv),
    }


#: Rings of the crown's dome within this distance (mm) of the pole are measured by :func:`pole_ripple`.
POLE_RADIUS_MM = 10.0


def _pole_frame(head, u_near: float) -> tuple[np.ndarray, np.ndarray]:
    """The pole and its unit normal (pointing away from the head): the Newell normal of a ring close to it."""
    pole = np.asarray(head.vertex, float)
    ring = head.evaluate(np.full(720, u_near), TWO_PI * np.arange(720) / 720)
    d = ring - pole
    n = np.cross(d, np.roll(d, -1, axis=0)).sum(axis=0)
    n /= np.linalg.norm(n)
    if n @ (pole - head.spine(np.array([head.curve_u[-1]]))[0]) < 0:
        n = -n
    return pole, n


def pole_ripple(head, radius_mm: float = POLE_RADIUS_MM, rings: int = 160, nv: int = 720) -> dict[str, float]:
    """The star at the crown's pole, in numbers.

    On every ring ``X(u, .)`` of the dome whose mean distance from the pole is at most
    ``radius_mm``, the ring's radius about the pole in the pole's tangent plane,
    ``r(theta)`` (resampled at equal angles theta around the pole), is split into its
    harmonics ``A_n``; the RMS around the ring of the slope ripple of the harmonics
    ``n >= 3`` is ``sqrt(sum_{n>=3} (n A_n / r_mean)^2 / 2)`` (radians, reported in
    degrees). Harmonics that fade like ``r^n`` toward the pole (a smooth pole) give a
    ripple that vanishes there; harmonics that shrink only like ``r`` keep it constant,
    which shades as radial ridges.

    Returns
    -------
    dict
        ``worst_deg`` (the worst ring), ``mean_deg``, ``rings`` measured, the pole's
        unit normal ``normal`` and the dome's height above the top curve ``dome_height_mm``
        (0 and empty when the head has no dome).
    """
    if head.vertex is None:
        return {"worst_deg": 0.0, "mean_deg": 0.0, "rings": 0, "normal": [], "dome_height_mm": 0.0}
    u0 = float(head.curve_u[-1])
    u = u0 + (1.0 - u0) * (1.0 - np.geomspace(1.0, 1e-4, rings))[1:]          # denser toward the pole
    pole, n = _pole_frame(head, 1.0 - 1e-4 * (1.0 - u0))
    v = TWO_PI * np.arange(nv) / nv
    pts = head.evaluate(u[:, None], v[None, :]) - pole                        # (R, nv, 3)
    e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    x, y = pts @ e1, pts @ e2
    r = np.hypot(x, y)
    keep = (np.linalg.norm(pts, axis=-1).mean(axis=1) <= radius_mm) & (r.min(axis=1) > 0)
    theta = np.arctan2(y, x)
    grid = -np.pi + TWO_PI * np.arange(nv) / nv
    ripple = []
    for i in np.nonzero(keep)[0]:
        order = np.argsort(theta[i])
        th, rr = theta[i, order], r[i, order]
        ri = np.interp(grid, th, rr, period=TWO_PI)
        c = np.fft.rfft(ri) / nv
        amp = 2.0 * np.abs(c[1:])                                            # A_n, n = 1 ..
        nn = np.arange(1, len(c))
        hi = nn >= 3
        ripple.append(np.sqrt(np.sum((nn[hi] * amp[hi] / ri.mean()) ** 2) / 2.0))
    ripple = np.degrees(np.array(ripple)) if ripple else np.zeros(1)
    top = head.evaluate(np.full(nv, u0), v)
    return {"worst_deg": float(ripple.max()), "mean_deg": float(ripple.mean()), "rings": int(keep.sum()),
            "normal": n.tolist(), "dome_height_mm": float((pole - top.mean(axis=0)) @ n)}


#: Circles about the crown's pole where :func:`crown_ripple` compares a head with the smoothed mask.
CROWN_RADII_MM = (20.0, 25.0, 30.0, 35.0, 40.0)


def crown_ripple(vertices: np.ndarray, faces: np.ndarray, pole: np.ndarray, up: np.ndarray,
                 radii=CROWN_RADII_MM, angles: int = 360) -> dict[float, float]:
    """Radial ridges across the crown, in numbers: the slope ripple of the height on circles about the pole.

    On the circle of horizontal radius ``rho`` about ``pole`` (in the plane normal to ``up``), the
    surface's height along ``up`` at ``angles`` equal angles is split into its harmonics ``A_n``; the
    slope ripple is ``sqrt(sum_{n >= 3} (n A_n / rho)^2 / 2)`` (the RMS around the circle of the
    tangential slope of those harmonics), in degrees. ``n <= 2`` is the head's oval. A smooth crown's
    n-th height harmonic shrinks like ``rho^n`` toward its pole; ridges that run into the pole keep it.

    Parameters
    ----------
    vertices : ndarray, shape (N, 3)
        Any triangle mesh of the head (the PDE surface, marching cubes), patient mm.
    faces : ndarray of int, shape (F, 3)
        Its triangles, outward.
    pole : ndarray, shape (3,)
        The crown's pole (``head.vertex``).
    up : ndarray, shape (3,)
        The direction out of the crown (the slice axis, toward the vertex).
    radii : sequence of float
        The circles' radii, mm.

    Returns
    -------
    dict
        ``{rho: ripple in degrees}``; NaN where the circle leaves the crown.

    Notes
    -----
    The height is interpolated linearly over a Delaunay triangulation of the vertices of the faces
    facing ``up`` within the cylinder ``rho <= max(radii) + 5`` and less than ``max(radii)`` below the
    pole (the crown's top sheet, not the floor of a cavity inside it); on meshes as fine as 0.5 mm this
    is the mesh's own height within its chord error.
    """
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    d = np.asarray(vertices, dtype=np.float64) - np.asarray(pole, dtype=np.float64)
    x, y, h = d @ e1, d @ e2, d @ up
    faces = np.asarray(faces)
    tri = d[faces]
    facing = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) @ up > 0
    rmax = float(max(radii))
    keep = np.zeros(len(d), bool)
    keep[faces[facing].ravel()] = True
    keep &= (np.hypot(x, y) <= rmax + 5.0) & (h > -rmax)
    height = LinearNDInterpolator(np.c_[x[keep], y[keep]], h[keep])
    theta = TWO_PI * np.arange(angles) / angles
    n = np.arange(1, angles // 2 + 1)
    out = {}
    for rho in radii:
        z = height(rho * np.cos(theta), rho * np.sin(theta))
        amp = 2.0 * np.abs(np.fft.rfft(z)[1:] / angles)
        hi = n >= 3
        out[float(rho)] = float(np.degrees(np.sqrt(np.sum((n[hi] * amp[hi] / rho) ** 2) / 2.0)))
    return out


def edge_bends(mesh, skip_u: float | None = 0.0) -> np.ndarray:
    """The angle (degrees) between the normals of the two faces at every interior edge of a mesh.

    Parameters
    ----------
    mesh : Mesh
        Quads and triangles (:meth:`PDEHead.surface`).
    skip_u : float or None
        Edges with a vertex whose ``u`` attribute equals this (the bottom cap's boundary ring and the cap,
        where the tube meets its flat disc at the neck's own angle) count as 0; None measures every edge.

    Returns
    -------
    ndarray, shape (n_edges,)
        One angle per edge shared by two faces; a slit or a pinched fold shows as edges above 60-90 deg.
    """
    V = np.asarray(mesh.vertices, dtype=np.float64)
    polys = [np.asarray(mesh.quads, np.int64).reshape(-1, 4), np.asarray(mesh.triangles, np.int64).reshape(-1, 3)]
    normals, a, b, face = [], [], [], []
    offset = 0
    for f in polys:
        if not len(f):
            continue
        p = V[f]
        n = np.cross(p, np.roll(p, -1, axis=1)).sum(axis=1)         # Newell's normal of each polygon
        normals.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300))
        a.append(f.ravel())
        b.append(np.roll(f, -1, axis=1).ravel())
        face.append(np.repeat(np.arange(len(f)) + offset, f.shape[1]))
        offset += len(f)
    normals, a, b, face = np.concatenate(normals), np.concatenate(a), np.concatenate(b), np.concatenate(face)
    key = np.minimum(a, b) * len(V) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    key, face, lo = key[order], face[order], np.minimum(a, b)[order]
    pair = np.nonzero(key[1:] == key[:-1])[0]
    cos = np.einsum("ij,ij->i", normals[face[pair]], normals[face[pair + 1]])
    angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    if skip_u is not None and "u" in mesh.vertex_attributes:
        u = np.asarray(mesh.vertex_attributes["u"], dtype=np.float64)
        hi = key[pair] - lo[pair] * len(V)
        angle[(u[lo[pair]] == skip_u) | (u[hi] == skip_u)] = 0.0
    return angle


def _face_corners(mesh):
    """(faces as vertex-index lists, their per-corner UVs): quads then triangles."""
    faces = [f for f in (mesh.quads, mesh.triangles) if len(f)]
    uvs = [x for x, f in ((mesh.quad_uv, mesh.quads), (mesh.triangle_uv, mesh.triangles)) if len(f)]
    return faces, uvs


def uv_quality(mesh, middle: float = 0.8) -> dict[str, float]:
    """How paintable a mesh's UVs are: mirrored and empty faces, area stretch, angle distortion.

    * ``mirrored``: faces whose UV polygon winds against their 3-D winding (negative UV area);
      ``zero_area``: faces with UV area <= 1e-12 (neither can be painted);
    * ``stretch_p99_p1``: over the faces whose centre lies in the middle ``middle`` of the mesh's
      height (z), the ratio p99 / p1 of |UV area| / 3-D area (1 = the texel density is even);
    * ``angle_p95_deg``: over the same faces, p95 of |UV angle - 3-D angle| per corner.

    Quads are measured as quads (signed polygon area, their four corner angles).
    """
    faces, uvs = _face_corners(mesh)
    v = mesh.vertices
    mirrored = zero = total = 0
    stretch, angle = [], []
    z = v[:, 2]
    lo, hi = z.min(), z.max()
    margin = 0.5 * (1.0 - middle) * (hi - lo)
    for f, uv in zip(faces, uvs):
        uv = np.asarray(uv, float)
        p = v[f]
        x, y = uv[..., 0], uv[..., 1]
        a_uv = 0.5 * (x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y).sum(axis=1)
        c = p.mean(axis=1, keepdims=True)
        a_3d = 0.5 * np.linalg.norm(np.cross(p - c, np.roll(p, -1, axis=1) - c).sum(axis=1), axis=1)
        mirrored += int(np.count_nonzero(a_uv < -1e-12))
        zero += int(np.count_nonzero(np.abs(a_uv) <= 1e-12))
        total += len(f)
        mid = (c[:, 0, 2] >= lo + margin) & (c[:, 0, 2] <= hi - margin) & (a_3d > 0)
        stretch.append(np.abs(a_uv[mid]) / a_3d[mid])                      # mirrored faces count by size

        def corner_angles(q):
            e1 = np.roll(q, -1, axis=1) - q
            e0 = np.roll(q, 1, axis=1) - q
            cos = np.einsum("...i,...i", e0, e1) / np.maximum(
                np.linalg.norm(e0, axis=-1) * np.linalg.norm(e1, axis=-1), 1e-300)
            return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        angle.append(np.abs(corner_angles(uv[mid]) - corner_angles(p[mid])).ravel())
    stretch = np.concatenate(stretch)
    angle = np.concatenate(angle)
    ok = stretch > 0
    return {
        "faces": total,
        "mirrored": mirrored,
        "zero_area": zero,
        "stretch_p99_p1": float(np.percentile(stretch[ok], 99) / np.percentile(stretch[ok], 1))
        if ok.any()
        else float("inf"),
        "angle_p95_deg": float(np.percentile(angle, 95)) if angle.size else 0.0,
    }


def cap_edge_ratio(mesh) -> float:
    """Longest edge of the mesh's triangles (the caps and the pole's fan) over the mean edge of the whole mesh."""
    if not len(mesh.triangles):
        return 0.0
    e = mesh.edges()
    mean = np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1).mean()
    t = mesh.vertices[mesh.triangles]
    longest = np.linalg.norm(t - np.roll(t, -1, axis=1), axis=-1).max()
    return float(longest / mean)
