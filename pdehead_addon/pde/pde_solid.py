"""Step 5: the PDE solid (paper eq. 23), its w-field on a voxel grid and eq. 24 opacity.

The solid is ``X(u, v, w) = A0(u) + w (X(u, v) - A0(u))`` (eq. 23 with the
remainder R of eq. 11 scaled by w as well, so that w = 1 is exactly the
surface and w = 0 the spine A0). :func:`solid_mesh` meshes the boundary of a
parametric box of it (the cut-aways of Fig. 14); :func:`w_field` tabulates w
on a voxel grid together with the CT intensity masked by the solid (the 3-D
texture of section 4.3.1); :func:`alpha_from_w` is eq. 24. The CT on a (u, v, w) grid of the
solid, for live cut-aways, is :mod:`.solid_ct_table`'s.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.ndimage import map_coordinates

from ..core.ct_volume import CTVolume
from ..core.errors import PDEError, report_progress
from ..core.mesh import Mesh
from ..core.threads import map_in_order
from .surface_mesh import check_count

#: Value of the w-field at voxels outside the solid (any value > 1 means outside).
OUTSIDE_W = 2.0
TWO_PI = 2.0 * np.pi


# ----------------------------------------------------------------------------- eq. 24


def alpha_from_w(w: np.ndarray, low: float = 0.1, high: float = 0.9) -> np.ndarray:
    """Opacity of eq. 24: ``alpha = (l_alpha - h_alpha) w + h_alpha`` inside, 0 outside.

    Parameters
    ----------
    w : array_like
        w-field values; ``w <= 1`` is inside the solid, ``w > 1`` (e.g.
        :data:`OUTSIDE_W`) outside.
    low, high : float
        ``l_alpha`` (at the surface, w = 1) and ``h_alpha`` (at the spine,
        w = 0); the paper's section 5.3 uses 0.1 and 0.9.

    Returns
    -------
    ndarray of float32, same shape as ``w``
    """
    if not (0.0 <= low <= 1.0 and 0.0 <= high <= 1.0 and np.isfinite(low) and np.isfinite(high)):
        raise PDEError(f"alpha bounds must lie in [0, 1], got low={low!r}, high={high!r}")
    w = np.asarray(w, dtype=np.float32)
    inside = w <= 1.0
    alpha = (np.float32(low) - np.float32(high)) * np.clip(w, 0.0, 1.0) + np.float32(high)
    return np.where(inside, alpha, np.float32(0.0)).astype(np.float32)


# ----------------------------------------------------------------------------- solid mesh


def _range(r, name: str, lo: float, hi: float) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in r)
    except (TypeError, ValueError):
        raise PDEError(f"{name} must be a pair of numbers, got {r!r}") from None
    if not (np.isfinite(a) and np.isfinite(b) and lo - 1e-12 <= a < b <= hi + 1e-12):
        raise PDEError(f"{name} must satisfy {lo:g} <= start < end <= {hi:g}, got ({a:g}, {b:g})")
    return max(a, lo), min(b, hi)


def _collapse(faces: np.ndarray, corner_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Split quads after vertex merging: keep 4-distinct as quads, 3-distinct as triangles, drop the rest."""
    same = faces == np.roll(faces, -1, axis=1)                              # corner k == corner k+1
    n_same = same.sum(axis=1)
    quads = faces[n_same == 0]
    quad_uv = corner_uv[n_same == 0]
    tri_rows = np.nonzero(n_same == 1)[0]
    keep = ~same[tri_rows]                                                   # drop the repeated corner
    tris = faces[tri_rows][keep].reshape(-1, 3)
    tri_uv = corner_uv[tri_rows][keep].reshape(-1, 3, 2)
    # a quad whose opposite corners coincide (n_same == 0 but 3 distinct) cannot occur on this grid
    return quads, quad_uv, tris, tri_uv


def solid_mesh(head, nu: int, nv: int, nw: int, u_range: tuple[float, float] = (0.0, 1.0),
               v_range: tuple[float, float] = (0.0, TWO_PI),
               w_range: tuple[float, float] = (0.0, 1.0)) -> Mesh:
    """The faces bounding the parametric box of the solid (eq. 23, Fig. 7 and 14).

    Parameters
    ----------
    head : PDEHead
    nu, nv, nw : int
        Samples along u, v and w (Fig. 14 uses 40, 60, 5). For the full v range
        the nv columns are ``v0 + 2 pi j / nv`` and the seam is stitched; for a
        partial range they include both ends.
    u_range, v_range, w_range : (float, float)
        The parametric box, e.g. ``v_range=(pi/2, 2 pi)`` or ``w_range=(0.8, 1)`` for
        the cut-aways of Fig. 14.

    Returns
    -------
    Mesh
        The w = w_max (outer) and w = w_min (inner) faces, the u = u_min and
        u = u_max faces and, for a partial v range, the two v cut faces; all
        wound outward. Vertex attributes ``u``, ``v``, ``w``; per-corner UVs
        ``(u, v / 2 pi)`` (1.0 on the seam). With ``w_min = 0`` the inner face
        collapses onto the spine: its vertices are merged into one spine vertex
        per u, its quads (zero area) are dropped and the u-end quads touching
        the spine become triangles, so the mesh stays a valid closed 2-manifold
        without zero-area faces.
    """
    nu, nw = check_count(nu, "nu", 2), check_count(nw, "nw", 2)
    u0, u1 = _range(u_range, "u_range", 0.0, 1.0)
    v0, v1 = _range(v_range, "v_range", -TWO_PI, 2 * TWO_PI)
    w0, w1 = _range(w_range, "w_range", 0.0, 1.0)
    if v1 - v0 > TWO_PI + 1e-9:
        raise PDEError(f"v_range spans more than 2 pi: ({v0:g}, {v1:g})")
    full = v1 - v0 >= TWO_PI - 1e-9
    nv = check_count(nv, "nv", 3 if full else 2)
    u = np.linspace(u0, u1, nu)
    w = np.linspace(w0, w1, nw)
    v = v0 + TWO_PI * np.arange(nv) / nv if full else np.linspace(v0, v1, nv)
    uniform = nv if (full and v0 == 0.0) else None
    density = head.v_density() if uniform is not None and hasattr(head, "v_density") else None
    if density is not None:             # the surface's columns (PDEHead.v_columns): its skin, its grid
        v, uniform = head.v_columns(nv), None
    surf = surface_grid_cached(head, u, v, uniform)
    spine = head.spine(u)                                                    # (nu, 3)
    crown = getattr(head, "vertex", None) is not None and u1 == 1.0
    quads, tris, quad_c, tri_c, iu, iv, iw = _solid_topology(nu, nv, nw, full, w0 == 0.0, head.orientation > 0,
                                                             crown)
    # corner UVs (u, v / 2 pi); for the full range the seam corner (unwrapped column nv) gets v0/2pi + 1
    def corner_uv(c):
        cv = v0 / TWO_PI + c[..., 1] / nv if full else v[c[..., 1]] / TWO_PI
        return np.stack([u[c[..., 0]], cv], axis=-1)
    pos = spine[iu] + w[iw][:, None] * (surf[iu, iv] - spine[iu])
    return Mesh(pos, quads, tris, corner_uv(quad_c), corner_uv(tri_c),
                {"u": u[iu], "v": v[iv], "w": w[iw]})


def surface_grid_cached(head, u: np.ndarray, v: np.ndarray, nv_uniform: int | None) -> np.ndarray:
    """The surface grid X(u_i, v_j): the head's cached :meth:`~.pde_head.PDEHead.grid` (shared with
    its surface mesh) when it has one, else its :meth:`.PDEHead.surface_points`."""
    if hasattr(head, "grid"):
        return head.grid(u, nv_uniform) if nv_uniform is not None else head.grid(u, v=v)
    return head.surface_points(u, nv_uniform) if nv_uniform is not None else head.surface_points(u, None, v=v)


_TOPOLOGY_CACHE: dict = {}


def _solid_topology(nu: int, nv: int, nw: int, full: bool, on_spine: bool, flip: bool, crown: bool = False):
    """Faces of the parametric box's boundary for a grid of nu x nv x nw samples (cached: pure integers).

    ``on_spine``: the inner face w = 0 collapses onto the spine (one vertex per u); ``crown``: the
    last u row is the crown's pole (a dome head), one vertex for every (v, w) there.

    Returns quads, triangles (indices into the used vertices), their corner (iu, iv unwrapped)
    index pairs, and the (iu, iv, iw) grid index of each used vertex.
    """
    key = (nu, nv, nw, full, on_spine, flip, crown)
    hit = _TOPOLOGY_CACHE.get(key)
    if hit is not None:
        return hit

    def vid(iu, iv, iw):
        return (iu * nv + (iv % nv if full else iv)) * nw + iw

    faces, corners = [], []                                                  # corner (iu, iv unwrapped)
    ncol = nv if full else nv - 1

    def add(iu, iv, iw):
        # iu, iv, iw: (..., 4) corner index arrays
        faces.append(vid(iu, iv, iw).reshape(-1, 4))
        corners.append(np.stack([np.broadcast_to(iu, iv.shape), iv], axis=-1).reshape(-1, 4, 2))

    U, V = np.meshgrid(np.arange(nu - 1), np.arange(ncol), indexing="ij")
    cu = np.stack([U, U + 1, U + 1, U], axis=-1)
    cv = np.stack([V, V, V + 1, V + 1], axis=-1)
    add(cu, cv, np.full(cu.shape, nw - 1))                                  # outer w = w1: +w
    add(cu[..., ::-1], cv[..., ::-1], np.zeros(cu.shape, int))              # inner w = w0: -w
    V, W = np.meshgrid(np.arange(ncol), np.arange(nw - 1), indexing="ij")
    cv = np.stack([V, V + 1, V + 1, V], axis=-1)
    cw = np.stack([W, W, W + 1, W + 1], axis=-1)
    add(np.full(cv.shape, nu - 1), cv, cw)                                  # u = u1: +u
    add(np.zeros(cv.shape, int), cv[..., ::-1], cw[..., ::-1])              # u = u0: -u
    if not full:
        W, U = np.meshgrid(np.arange(nw - 1), np.arange(nu - 1), indexing="ij")
        cw = np.stack([W, W + 1, W + 1, W], axis=-1)
        cu = np.stack([U, U, U + 1, U + 1], axis=-1)
        add(cu, np.full(cu.shape, nv - 1), cw)                              # v = v1: +v
        add(cu[..., ::-1], np.zeros(cu.shape, int), cw[..., ::-1])          # v = v0: -v
    faces = np.concatenate(faces)
    corners = np.concatenate(corners)
    # parametric outward (u, v, w right-handed) is physically inward when the surface
    # quads (u,v)->(u,v+1)->(u+1,v+1)->(u+1,v) face outward (orientation +1)
    if flip:
        faces = faces[:, ::-1]
        corners = corners[:, ::-1]
    iw_of = faces % nw
    iu_of = faces // (nv * nw)
    if on_spine:  # inner face on the spine: one vertex per u
        faces = np.where(iw_of == 0, iu_of * nv * nw, faces)
    if crown:
        # the crown's pole: every (v, w) of the last row is the same point (kept as its w = w1 vertex)
        faces = np.where(iu_of == nu - 1, (nu - 1) * nv * nw + nw - 1, faces)
    quads, quad_c, tris, tri_c = _collapse(faces, corners)
    # the used grid vertices in index order and each one's new index: np.unique by counting
    # (ids are bounded by nu * nv * nw), linear time instead of a sort
    ids = np.concatenate([quads.ravel(), tris.ravel()])
    present = np.bincount(ids, minlength=nu * nv * nw) > 0
    used = np.flatnonzero(present)
    new_index = np.cumsum(present) - 1
    inverse = new_index[ids]
    quads = inverse[:quads.size].reshape(-1, 4)
    tris = inverse[quads.size:].reshape(-1, 3)
    out = (quads, tris, quad_c, tri_c, used // (nv * nw), (used // nw) % nv, used % nw)
    for a in out:
        a.setflags(write=False)  # shared between calls
    if len(_TOPOLOGY_CACHE) >= 16:
        _TOPOLOGY_CACHE.pop(next(iter(_TOPOLOGY_CACHE)))
    _TOPOLOGY_CACHE[key] = out
    return out


# ----------------------------------------------------------------------------- w-field


@dataclass
class WField:
    """The solid's w on a voxel grid and the CT intensity masked by it (section 4.3.1).

    Attributes
    ----------
    w : ndarray of float32, shape (nz, ny, nx)
        w in [0, 1] inside the solid (0 on the spine, 1 on the surface),
        :data:`OUTSIDE_W` outside.
    intensity : ndarray of float32, shape (nz, ny, nx)
        CT intensity (raw units, e.g. HU) inside the solid, 0 outside.
    spacing, origin, direction
        Grid geometry, same meaning as in :class:`CTVolume`.
    meta : dict
        How it was computed (method, directions per plane, ...).
    """

    w: np.ndarray
    intensity: np.ndarray
    spacing: tuple[float, float, float]
    origin: np.ndarray
    direction: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def inside(self) -> np.ndarray:
        return self.w <= 1.0

    def to_ctvolume(self, which: str = "w", low: float = 0.1, high: float = 0.9) -> CTVolume:
        """One channel as a :class:`CTVolume`: ``"w"``, ``"intensity"`` or ``"alpha"`` (eq. 24)."""
        if which == "w":
            data = self.w
        elif which == "intensity":
            data = self.intensity
        elif which == "alpha":
            data = alpha_from_w(self.w, low, high)
        else:
            raise PDEError(f"unknown w-field channel {which!r}; use 'w', 'intensity' or 'alpha'")
        return CTVolume(data, self.spacing, self.origin.copy(), self.direction.copy(),
                        {"source": "pde w_field", "channel": which, **self.meta})


def axial_grid(spacing, origin, direction) -> tuple[np.ndarray, np.ndarray, float, float]:
    """In-plane affine of an axial grid: (2x2 matrix index(i,j)->xy, xy origin, z0, dz per k)."""
    D = np.asarray(direction, float)
    dz, dy, dx = spacing
    if abs(abs(D[2, 2]) - 1.0) > 1e-6 or np.any(np.abs(D[2, :2]) > 1e-6) or np.any(np.abs(D[:2, 2]) > 1e-6):
        raise PDEError("w_field needs a grid whose slices are axial (k axis along patient z, i and j "
                       "axes horizontal); resample the volume to an axial grid first")
    A = D[:2, :2] * np.array([dx, dy])
    return A, np.asarray(origin, float)[:2], float(origin[2]), float(D[2, 2] * dz)


def _plane_u(head, z: np.ndarray) -> np.ndarray:
    """u of each height z by inverting the spine's z (monotone); NaN outside the head."""
    t = head.patches
    uu = np.linspace(0.0, 1.0, 64 * t + 1)
    zz = head.spine(uu)[:, 2]
    dz = np.diff(zz)
    if not (np.all(dz > 0) or np.all(dz < 0)):
        raise PDEError("the spine is not monotone in z; w_field needs curves stacked along z")
    if dz[0] < 0:
        uu, zz = uu[::-1], zz[::-1]
    # planes within rounding of the end curves belong to them (the spine's end z may be off by an ulp)
    tol = 1e-9 * max(1.0, float(np.abs(zz).max()))
    z = np.where(np.abs(z - zz[0]) <= tol, zz[0], np.where(np.abs(z - zz[-1]) <= tol, zz[-1], z))
    u = np.interp(z, zz, uu, left=np.nan, right=np.nan)
    ok = np.isfinite(u)
    for _ in range(3):  # secant refinement (the spine is exactly linear per patch for height knots)
        if not np.any(ok):
            break
        uo = u[ok]
        h = 1e-6
        z1 = head.spine(np.clip(uo, 0, 1))[:, 2]
        z2 = head.spine(np.clip(uo + np.where(uo < 1 - h, h, -h), 0, 1))[:, 2]
        slope = (z2 - z1) / np.where(uo < 1 - h, h, -h)
        flat = np.abs(slope) < 1e-9                   # the dome's pole: z'(u) = 0, keep the interpolated u
        step = np.where(flat, 0.0, (z1 - z[ok]) / np.where(flat, 1.0, slope))
        u[ok] = np.clip(uo - step, 0.0, 1.0)
    return u


def _inside_scanline(poly: np.ndarray, ni: int, nj: int) -> np.ndarray:
    """Even-odd inside test of pixel centres (i, j) for closed polygons in index coordinates.

    poly : (P, n, 2) columns (i, j). Returns bool (P, nj, ni). Vectorised over
    all edges: every edge crossing of a row j at x adds a toggle for the
    pixels i < x; the cumulative sum's parity is the even-odd rule.
    """
    P, n, _ = poly.shape
    a = poly
    b = np.roll(poly, -1, axis=1)
    y0, y1 = a[..., 1], b[..., 1]
    lo = np.minimum(y0, y1)
    hi = np.maximum(y0, y1)
    r0 = np.clip(np.ceil(lo), 0, nj)                 # rows j with lo <= j < hi
    r1 = np.clip(np.ceil(hi), 0, nj)
    cnt = (r1 - r0).astype(np.int64).ravel()
    edge = np.repeat(np.arange(P * n), cnt)
    offs = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    rows = (r0.ravel()[edge] + offs).astype(np.int64)
    ax, ay = a[..., 0].ravel()[edge], a[..., 1].ravel()[edge]
    bx, by = b[..., 0].ravel()[edge], b[..., 1].ravel()[edge]
    x = ax + (rows - ay) * (bx - ax) / (by - ay)
    col = np.clip(np.ceil(x), 0, ni).astype(np.int64)   # pixels i < x  <=>  i <= ceil(x) - 1
    plane = edge // n
    toggles = np.zeros((P, nj, ni + 1), np.int32)
    np.add.at(toggles, (plane, rows, col), 1)
    # count of crossings with x > i = sum over col > i
    parity = np.cumsum(toggles[..., ::-1], axis=2)[..., ::-1][..., 1:] & 1
    return parity.astype(bool)


def _farthest_crossing(poly: np.ndarray, centre: np.ndarray, bins: int) -> np.ndarray:
    """Distance from centre to the farthest polygon crossing along each of ``bins`` directions.

    poly : (P, n, 2), centre : (P, 2). Returns (P, bins); 0 where a direction meets no edge.
    Direction k has angle ``-pi + (k + 1/2) 2 pi / bins``.
    """
    P, n, _ = poly.shape
    A = poly - centre[:, None, :]
    B = np.roll(A, -1, axis=1)
    pa = np.arctan2(A[..., 1], A[..., 0])
    pb = np.arctan2(B[..., 1], B[..., 0])
    dphi = np.mod(pb - pa + np.pi, TWO_PI) - np.pi
    width = TWO_PI / bins
    start = np.minimum(pa, pa + dphi)
    stop = np.maximum(pa, pa + dphi)
    k0 = np.ceil((start + np.pi) / width - 0.5)
    k1 = np.floor((stop + np.pi) / width - 0.5)
    cnt = np.maximum(k1 - k0 + 1, 0).astype(np.int64).ravel()
    edge = np.repeat(np.arange(P * n), cnt)
    offs = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    k = (k0.ravel()[edge] + offs).astype(np.int64)
    theta = -np.pi + (k + 0.5) * width
    dx, dy = np.cos(theta), np.sin(theta)
    Af = A.reshape(-1, 2)[edge]
    E = (B - A).reshape(-1, 2)[edge]
    denom = dx * E[:, 1] - dy * E[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (Af[:, 0] * E[:, 1] - Af[:, 1] * E[:, 0]) / denom
    s = np.where(np.isfinite(s) & (s > 0), s, 0.0)
    out = np.zeros(P * bins)
    np.maximum.at(out, (edge // n) * bins + np.mod(k, bins), s)
    return out.reshape(P, bins)


def _w_planes(head, ks, u, n_sec: int, oxy, A_inv, ni: int, nj: int, directions: int):
    """w (eq. 23) of the voxels inside the cross-sections of the planes ``ks`` (at u ``u``): their (k, j, i)
    in ``np.nonzero``'s order and w as float32 (see :func:`w_field`)."""
    sec = head.surface_points(u, n_sec)[..., :2]                                  # (P, n, 2) xy
    S = head.spine(u)[:, :2]
    poly = (sec - oxy) @ A_inv.T                                         # -> (i, j) index coordinates
    Sidx = (S - oxy) @ A_inv.T
    inside = _inside_scanline(poly, ni, nj)                              # (P, nj, ni)
    smax = _farthest_crossing(poly, Sidx, directions)                   # (P, bins)
    p_idx, j_idx, i_idx = np.nonzero(inside)
    rx = i_idx - Sidx[p_idx, 0]
    ry = j_idx - Sidx[p_idx, 1]
    r = np.hypot(rx, ry)
    f = (np.arctan2(ry, rx) + np.pi) / (TWO_PI / directions) - 0.5
    k0 = np.floor(f).astype(np.int64)
    frac = f - k0
    s0 = smax[p_idx, np.mod(k0, directions)]
    s1 = smax[p_idx, np.mod(k0 + 1, directions)]
    s = np.where((s0 > 0) & (s1 > 0), s0 * (1 - frac) + s1 * frac, np.maximum(s0, s1))
    with np.errstate(divide="ignore", invalid="ignore"):
        wv = np.where(s > 0, np.minimum(r / s, 1.0), 1.0)
    return ks[p_idx], j_idx, i_idx, wv.astype(np.float32)


def _axis_lerp(coord: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lower index, fraction and in-range flag (``0 <= coord <= n - 1``, map_coordinates' "constant") along
    one axis of n >= 2 samples."""
    ok = (coord >= 0) & (coord <= n - 1)
    c = np.clip(coord, 0, n - 1)
    lo = np.minimum(np.floor(c).astype(np.int64), n - 2)
    return lo, (c - lo).astype(np.float32), ok


def _ct_on_grid(ct: CTVolume, found, grid: CTVolume, w_out: np.ndarray, intensity: np.ndarray) -> None:
    """The CT, trilinear (``map_coordinates(order=1, mode="constant")``, the CT's lowest value outside), at
    the voxels of ``grid`` that ``found`` lists ((k, j, i) per chunk of planes), into ``intensity``.

    An axis-aligned grid (each CT index a function of one grid index: both axial, as Run Pipeline's) is
    interpolated plane by plane, separably: the two CT slices around the plane, then its rows, then its
    columns (several times faster than the general path, the same values to float32 rounding). Any other grid goes
    through the voxels' CT indices and ``map_coordinates``.
    """
    cval = float(ct.data.min())
    # grid index -> CT index is affine: its origin and the images of the unit steps
    steps = ct.patient_to_index(grid.index_to_patient(np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float64)))
    base, unit = steps[0], steps[1:] - steps[0]
    if np.count_nonzero(unit - np.diag(np.diag(unit))) == 0 and min(ct.shape) >= 2 and found:
        tables = [np.arange(n) * unit[c, c] + base[c] for c, n in enumerate(w_out.shape)]
        (j0, tj, okj), (i0, ti, oki) = (_axis_lerp(t, n) for t, n in zip(tables[1:], ct.shape[1:]))
        nz = ct.shape[0]
        inside_all = w_out <= 1.0
        for k in np.flatnonzero(inside_all.any(axis=(1, 2))):
            z = float(tables[0][k])
            if not 0.0 <= z <= nz - 1:
                np.copyto(intensity[k], np.float32(cval), where=inside_all[k])
                continue
            k0 = min(int(np.floor(z)), nz - 2)
            tz = np.float32(z - k0)
            lower, upper = ct.data[k0][j0], ct.data[k0 + 1][j0]                     # rows j0 of both slices
            rows = lower + tz * (upper - lower)
            lower, upper = ct.data[k0][j0 + 1], ct.data[k0 + 1][j0 + 1]
            rows += tj[:, None] * ((lower + tz * (upper - lower)) - rows)           # (grid rows, CT columns)
            vals = rows[:, i0]
            vals += ti * (rows[:, i0 + 1] - vals)
            vals[~okj] = cval
            vals[:, ~oki] = cval
            np.copyto(intensity[k], vals, where=inside_all[k])
        return
    # the planes in increasing k, each in (j, i) order: np.nonzero(inside_all) without a pass over the grid
    kk, jj2, ii2 = (np.concatenate(a) if found else np.zeros(0, np.int64) for a in zip(*found))
    idx = np.empty((3, kk.size))
    for c in range(3):                       # the three index coordinates, not a loop over voxels
        row = idx[c]
        np.multiply(kk, unit[0, c], out=row)
        row += jj2 * unit[1, c]
        row += ii2 * unit[2, c]
        row += base[c]
    vals = map_coordinates(ct.data, idx, order=1, mode="constant", cval=cval)
    intensity[kk, jj2, ii2] = vals.astype(np.float32)


def w_field(head, grid, ct: CTVolume | None = None, directions: int = 4096,
            planes_per_chunk: int = 16, progress=None) -> WField:
    """Tabulate w (eq. 23) and the masked CT intensity on a voxel grid (the 3-D texture, section 4.3.1).

    Parameters
    ----------
    head : PDEHead
        Solved from axial-planar curves (z constant per curve), so that
        ``z(u, v, w) = A0_z(u)`` and every axial voxel plane is one u.
    grid : CTVolume or float
        A CTVolume whose grid is used (its slices must be axial; ``ct`` defaults
        to it), or a voxel size in mm: then the grid is the solid's bounding
        box at that isotropic spacing (identity direction).
    ct : CTVolume, optional
        Intensity source; sampled trilinearly when its grid differs from ``grid``.
    directions : int
        Angular resolution of the farthest-crossing table per plane.
    planes_per_chunk : int
        Planes processed together (bounds peak memory).
    progress : callable, optional
        ``progress(fraction, message)`` after every chunk of planes; it may raise
        :class:`~pdehead_addon.core.errors.Cancelled` (nothing is returned).

    Returns
    -------
    WField

    Notes
    -----
    For each voxel plane at height z: u from the spine's z, the cross-section
    polygon ``C(v) = X(u, v, 1)`` (sampled finer than half a voxel) and the
    spine point ``S = A0(u)``. A voxel centre is inside when it is inside C by
    the even-odd rule (scanline rasterisation of C at the exact voxel centres,
    so non-star-shaped sections - ears, nose - have no holes). Its w is
    ``|p - S| / s_max`` where ``s_max`` is the distance from S to the FARTHEST
    crossing of C along the ray from S through p (tabulated at ``directions``
    angles and interpolated linearly, clamped to 1): for a section that is
    star-shaped around S this is exactly the parametric w of eq. 23 (the ray
    from S meets C once, at ``X(u, v, 1)``); otherwise it is the natural
    extension that keeps ``w <= 1`` everywhere inside and w increasing along
    every ray from the spine. The affine voxel-index map keeps ratios along
    lines, so the whole computation runs in voxel index coordinates.
    """
    if not head.planar_z:
        raise PDEError("w_field needs boundary curves that each lie in an axial plane (constant z); "
                       "these curves are not axial-planar")
    if isinstance(grid, CTVolume):
        spacing, origin, direction, shape = grid.spacing, grid.origin, grid.direction, grid.shape
        if ct is None:
            ct = grid
    else:
        try:
            size = float(grid)
        except (TypeError, ValueError):
            raise PDEError(f"grid must be a CTVolume or a voxel size in mm, got {type(grid).__name__}") from None
        if not (np.isfinite(size) and size > 0):
            raise PDEError(f"voxel size must be a positive number of mm, got {grid!r}")
        pts = head.surface_points(np.linspace(0.0, 1.0, 16 * head.patches + 1), 512)
        lo, hi = pts.reshape(-1, 3).min(axis=0) - size, pts.reshape(-1, 3).max(axis=0) + size
        shape = tuple(int(np.ceil((hi[d] - lo[d]) / size)) + 1 for d in (2, 1, 0))
        if np.prod(shape) > 1024 ** 3:
            raise PDEError(f"voxel size {size:g} mm gives a grid of {shape} voxels; choose a larger size")
        spacing, origin, direction = (size, size, size), lo, np.eye(3)
    if ct is not None and not isinstance(ct, CTVolume):
        raise PDEError(f"ct must be a CTVolume, got {type(ct).__name__}")
    A, oxy, z0, dzk = axial_grid(spacing, origin, direction)
    A_inv = np.linalg.inv(A)
    nz, nj, ni = shape
    w_out = np.full(shape, OUTSIDE_W, np.float32)

    z = z0 + dzk * np.arange(nz)
    u_of = _plane_u(head, z)
    planes = np.nonzero(np.isfinite(u_of))[0]
    # polygon resolution: edges shorter than half the smallest in-plane voxel
    perim = float(np.max(np.linalg.norm(np.diff(head.bset.curves, axis=1, append=head.bset.curves[:, :1]),
                                        axis=2).sum(axis=1)))
    n_sec = int(2 ** np.ceil(np.log2(max(256, 2.0 * perim / min(spacing[1], spacing[2])))))
    n_sec = min(n_sec, 16384)
    found = []                                   # (k, j, i) of the voxels inside, plane by plane: nonzero's order
    chunks = [planes[start:start + planes_per_chunk] for start in range(0, len(planes), planes_per_chunk)]

    def chunk_w(ks):
        return _w_planes(head, ks, u_of[ks], n_sec, oxy, A_inv, ni, nj, directions)
    # the chunks' planes are independent and numpy releases the GIL in their large loops: two threads on
    # two cores; the results are placed in plane order, as one thread would
    def place(n, result):
        kidx, j_idx, i_idx, wv = result
        report_progress(progress, 0.9 * (n + 1) * planes_per_chunk / max(len(planes), 1),
                        f"w-field plane {min((n + 1) * planes_per_chunk, len(planes))} of {len(planes)}")
        w_out[kidx, j_idx, i_idx] = wv
        found.append((kidx, j_idx, i_idx))
    map_in_order(chunk_w, chunks, place)
    inside_all = w_out <= 1.0
    intensity = np.zeros(shape, np.float32)
    if ct is not None:
        same = (ct.shape == tuple(shape) and np.allclose(ct.spacing, spacing) and
                np.allclose(ct.origin, origin) and np.allclose(ct.direction, direction))
        if same:
            intensity[inside_all] = ct.data[inside_all]
        else:
            _ct_on_grid(ct, found, CTVolume(np.zeros((1, 1, 1), np.float32), spacing, origin, direction),
                        w_out, intensity)
    meta = {"method": "scanline inside test + farthest crossing from the spine", "directions": int(directions),
            "section_samples": int(n_sec), "outside_w": OUTSIDE_W}
    return WField(w_out, intensity, tuple(float(s) for s in spacing), np.asarray(origin, float).copy(),
                  np.asarray(direction, float).copy(), meta)
