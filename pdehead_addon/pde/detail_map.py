"""The CT detail map: the scan's fine relief (closed eyelids, lips, nose wings) as a height map in the
surface's UV layout, for bump shading of the smooth PDE surface.

Why shading, not geometry: the upper eyelid's edge is a one-slice feature of a 2 mm scan, and every
geometry route measured that shows it breaks the visible-face p95 target (the docstring of
:mod:`..curves.slice_selection`). The surface and its exports stay the smooth PDE surface; the map holds,
per texel, how far the CT's skin lies from it along its normal, which a renderer uses as a bump map.

Method
------
1. **Texels to the surface.** The surface is meshed by its own evaluator
   (:meth:`.pde_head.PDEHead.surface`, the UVs of :meth:`~.pde_head.PDEHead.uv_layout`, a function of
   (u, v) only) at about one quad per texel, and its triangles are rasterised in UV space
   (:func:`rasterise_triangles`): every texel centre inside a triangle gets the point and the
   (area-weighted vertex) normal interpolated barycentrically. The triangles are far below a millimetre,
   so the interpolation's error (curvature x edge^2 / 8) is ~0.01 mm. Texels of the tube and the crown's
   dome are filled; the bottom cap (the neck's cut, not skin) and the texels outside every island are 0.
2. **The skin.** The head mask is smoothed by a Gaussian of ``sigma_mm`` per axis (mm, converted to voxels
   per axis; the slice axis at least ``SLICE_SIGMA`` of a slice step, so a 2 mm scan's outline steps do not
   shade as horizontal bands) and its 0.5 level is the skin: the same level marching cubes of the smoothed
   mask shows. Where the PDE surface is upright (its normal across the slice axis) a slice step hardly moves
   the skin along the normal, so there the skin is taken from a mask smoothed by only
   ``UPRIGHT_SLICE_SIGMA`` of a step along the slices, which keeps one-slice creases (a closed eye's lid
   line), blended into the first by the normal's slice-axis component (``UPRIGHT_NZ``).
3. **The offset.** Along the outward normal the smoothed mask is sampled (``scipy.ndimage.map_coordinates``,
   order 1) at offsets ``-max_mm .. +max_mm`` every ``step_mm``; the crossing of 0.5 from inside (> 0.5) to
   outside nearest the surface, placed linearly between its two samples, is the texel's height (mm,
   positive: the skin lies outside the PDE surface). A texel with no such crossing within ``max_mm`` gets 0.
   Where the surface faces up along the slice axis the height fades to 0 (``UP_FADE``): the slices cut the
   skin there at a glancing angle and their steps would band the crown.
4. **Gutters.** The map is softened by a Gaussian of ``SOFTEN_TEXELS`` over the islands (normalised), and the
   texels just outside the islands take the value of the nearest filled texel
   (``PAD_TEXELS``), so linear filtering at an island's edge and the v = 0 seam does not blend in zeros.

All of it is vectorised (the rasteriser loops over window offsets, the sampler over chunks of texels).

References
----------
J. F. Blinn, "Simulation of wrinkled surfaces", Computer Graphics (SIGGRAPH '78) 12(3), 286-292 (1978):
bump mapping, the normal perturbed by a height field's gradient.
W. E. Lorensen, H. E. Cline, "Marching cubes", SIGGRAPH '87: the 0.5 level of the mask as its surface.
(Both cited from the literature, not re-read here.)
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import distance_transform_edt, gaussian_filter, map_coordinates

from .. import defaults as D
from ..core.errors import report_progress
from .surface_uv_map import uv_islands

__all__ = ["ct_detail_map", "detail_map_stages", "DetailMap", "texel_surface", "rasterise_triangles", "smooth_mask",
           "offset_to_level", "SLICE_SIGMA", "PAD_TEXELS"]

#: The Gaussian along the slice axis is at least this share of the slice step (mm): a stack of 2 mm
#: slices smoothed by 1.2 mm keeps a faint step per slice, which a bump map shows as horizontal bands.
#: Looked at on CThead (Cycles, front and three-quarter): 0.6 banded the cheeks, 1.0 lost most of the
#: closed upper eyelid's line; 0.8 (1.6 mm) shows the lid line without bands on the face.
SLICE_SIGMA = 0.8

#: Where the PDE surface is upright (its normal across the slice axis) the slices cut the skin square on, so a
#: slice step moves the skin along the normal by ~|n_z| x the step and hardly at all where |n_z| is small;
#: there the mask is smoothed along the slice axis by only ``UPRIGHT_SLICE_SIGMA`` of a step (at least
#: ``sigma_mm``), which keeps one-slice creases such as a closed eye's lid line. The two masks' offsets are
#: blended by the surface normal's |n_z|: the thin one alone below ``UPRIGHT_NZ[0]``, the
#: :data:`SLICE_SIGMA` one alone above ``UPRIGHT_NZ[1]``.
UPRIGHT_SLICE_SIGMA = 0.3
UPRIGHT_NZ = (0.15, 0.35)

#: Fade of the map where the surface faces up (the normal's patient z, the slice axis: from 1 at
#: ``UP_FADE[0]`` to 0 at ``UP_FADE[1]``): there the slices cut the skin at a glancing angle and a 2 mm step
#: becomes a terrace many mm wide, banding the crown in rings that no Gaussian short of a slice step removes
#: (CThead: the tube's top 35 mm, looked at); the face's features face forward or down.
UP_FADE = (0.5, 0.8)

#: Texels around each island that take the nearest island texel's value (linear filtering, mip maps).
PAD_TEXELS = 4

#: A Gaussian (texels) over the map: where the nearest crossing jumps from one sheet of skin to another
#: (the nostrils' rims, the mouth's corners) the map steps, and a step shades as a jagged edge.
SOFTEN_TEXELS = 1.0

#: Surface mesh quads per texel along each UV axis, before the rasteriser measures its triangles.
MESH_PER_TEXEL = 1.0

#: Triangles rasterised at once (:func:`texel_surface`).
RASTER_CHUNK = 131072


@dataclass
class DetailMap:
    """A CT detail map (:func:`ct_detail_map`).

    Attributes
    ----------
    height : ndarray of float32, shape (resolution, resolution)
        Offset (mm) along the surface's outward normal from the PDE surface to the CT's skin; row 0 is
        UV v = 0 (Blender's pixel order), column 0 is UV u = 0.
    covered : ndarray of bool, same shape
        Texels of the tube and dome islands (before the gutters are padded).
    found : ndarray of bool, same shape
        Covered texels where the skin was found within ``max_mm``.
    meta : dict
        The parameters used and a few numbers (texels covered / found, seconds per step).
    """

    height: np.ndarray
    covered: np.ndarray
    found: np.ndarray
    meta: dict = field(default_factory=dict)


def smooth_mask(mask: np.ndarray, spacing, sigma_mm: float, slice_sigma: float = SLICE_SIGMA,
                slice_sigma_mm: float | None = None) -> np.ndarray:
    """The head mask as float32 smoothed by a Gaussian of ``sigma_mm`` per axis (``spacing``: (dz, dy, dx)
    mm), the slice axis (0) at least ``slice_sigma`` of its step; or, given ``slice_sigma_mm``, by
    exactly that along the slice axis."""
    dz, dy, dx = (float(s) for s in spacing)
    along = max(sigma_mm, slice_sigma * dz) if slice_sigma_mm is None else float(slice_sigma_mm)
    sigma = np.array([along, sigma_mm, sigma_mm]) / np.array([dz, dy, dx])
    return gaussian_filter(np.asarray(mask, np.float32), sigma=sigma, mode="constant", cval=0.0, truncate=3.0)


def rasterise_triangles(uv: np.ndarray, resolution: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The texel centres inside each UV triangle.

    Parameters
    ----------
    uv : ndarray, shape (n, 3, 2)
        Triangle corners in UV ([0, 1]^2).
    resolution : int
        Texels along each axis; texel (r, c) has its centre at UV ((c + 0.5) / res, (r + 0.5) / res).

    Returns
    -------
    texel : ndarray of int64, shape (m,)
        Flat texel index ``r * resolution + c`` (a texel on a shared edge may appear twice).
    triangle : ndarray of int64, shape (m,)
        The triangle it lies in.
    bary : ndarray, shape (m, 3)
        Its barycentric coordinates in that triangle.
    """
    p = np.asarray(uv, float) * resolution - 0.5                     # texel-centre coordinates
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    # the corners' min and max by pairs: a reduction over the middle axis of (n, 3, 2) is ~10x slower
    lo = np.ceil(np.minimum(np.minimum(a, b), c) - 1e-9).astype(np.int64)   # (n, 2): the box's first centre
    extent = (np.floor(np.maximum(np.maximum(a, b), c) + 1e-9).astype(np.int64) - lo + 1).clip(0)
    e1, e2 = b - a, c - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ok = np.abs(det) > 1e-14
    out_t, out_tri, out_b = [], [], []
    # one pass per offset inside the largest box; each pass is vectorised over the triangles that need it
    for dy in range(int(extent[:, 1].max(initial=0))):
        rows = ok & (extent[:, 1] > dy)
        for dx in range(int(extent[:, 0].max(initial=0))):
            sel = np.flatnonzero(rows & (extent[:, 0] > dx))
            if sel.size == 0:
                continue
            x, y = lo[sel, 0] + dx, lo[sel, 1] + dy
            qx, qy = x - a[sel, 0], y - a[sel, 1]
            s = (qx * e2[sel, 1] - qy * e2[sel, 0]) / det[sel]
            t = (e1[sel, 0] * qy - e1[sel, 1] * qx) / det[sel]
            inside = (s >= -1e-9) & (t >= -1e-9) & (s + t <= 1 + 1e-9) & (x >= 0) & (y >= 0) \
                & (x < resolution) & (y < resolution)
            out_t.append((y * resolution + x)[inside])
            out_tri.append(sel[inside])
            out_b.append(np.stack([1.0 - s - t, s, t], axis=1)[inside])
    if not out_t:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    return np.concatenate(out_t), np.concatenate(out_tri), np.concatenate(out_b)


def area_vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals of outward-wound triangles."""
    v = vertices
    e1, e2 = v[triangles[:, 1]] - v[triangles[:, 0]], v[triangles[:, 2]] - v[triangles[:, 0]]
    n = np.stack([e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1], e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2],
                  e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]], axis=1)         # np.cross, without its copies
    # the face normals summed at their corners (bincount: np.add.at is ~10x slower on a million faces)
    corner = triangles.ravel()
    out = np.stack([np.bincount(corner, np.repeat(n[:, c], 3), minlength=len(v)) for c in range(3)], axis=1)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)


def texel_surface(head, resolution: int, mesh_per_texel: float = MESH_PER_TEXEL):
    """The PDE surface at every texel of the tube and dome islands of its UV layout.

    The surface is meshed by :meth:`.pde_head.PDEHead.surface` (its own evaluator and UVs) at about
    ``mesh_per_texel`` quads per texel and rasterised (:func:`rasterise_triangles`).

    Returns
    -------
    texel : ndarray of int64, shape (m,)
        Flat texel indices (row-major, row 0 at v = 0), each once.
    points, normals : ndarray, shape (m, 3)
        The surface point (LPS mm) and its unit outward normal at each texel.
    """
    layout = head.uv_layout()
    isl = uv_islands(float(layout["aspect"]), layout.get("dome_ratio"), layout.get("cap_ratio"))
    _, _, width, height = isl["tube"]
    nv = int(np.clip(np.ceil(mesh_per_texel * width * resolution), 16, 8192))
    nu = int(np.clip(np.ceil(mesh_per_texel * height * resolution), 8, 8192))
    mesh = head.surface(nu, nv, caps=False)                 # the tube, and the dome's pole fan
    tris = np.concatenate([mesh.quads[:, [0, 1, 2]], mesh.quads[:, [0, 2, 3]], mesh.triangles])
    quad_uv = np.asarray(mesh.quad_uv, float)
    tri_uv = np.concatenate([quad_uv[:, [0, 1, 2]], quad_uv[:, [0, 2, 3]]]
                            + ([np.asarray(mesh.triangle_uv, float)] if len(mesh.triangles) else []))
    normals = area_vertex_normals(mesh.vertices, tris)
    del quad_uv
    # the triangles in chunks: the rasteriser's temporaries for a million triangles at once were the
    # map's peak memory (CThead at 1024 px: the call's traced peak 404 MB at once, 287 MB in chunks)
    starts = range(0, len(tri_uv), RASTER_CHUNK)
    parts = [rasterise_triangles(tri_uv[s:s + RASTER_CHUNK], resolution) for s in starts]
    texel = np.concatenate([p[0] for p in parts])
    tri = np.concatenate([p[1] + s for p, s in zip(parts, starts)])
    bary = np.concatenate([p[2] for p in parts])
    del parts, tri_uv
    texel, first = np.unique(texel, return_index=True)      # a texel on a shared edge: one of its triangles
    corners = tris[tri[first]]
    w = bary[first]

    def interpolate(at_vertices):
        # corner by corner: a sum over the middle axis of (m, 3, 3) is several times slower
        return sum(at_vertices[corners[:, k]] * w[:, k, None] for k in range(3))
    points = interpolate(mesh.vertices)
    nrm = interpolate(normals)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    return texel, points, nrm


#: The sampler's first pass along the normal takes every ``COARSE_STEPS``-th of the ``step_mm`` samples; only
#: the coarse intervals where it crosses the level, and those nearer the surface than that crossing (a gap
#: or sliver under a coarse step can hide a crossing between two coarse samples), are then sampled at
#: ``step_mm``: the same samples, the same linear placement and so the same offsets as sampling every
#: ``step_mm`` throughout, at ~12 samples a texel instead of 25 (CThead at the defaults).
COARSE_STEPS = 4


def _level_crossings(f: np.ndarray, t: np.ndarray, step_mm: float):
    """Per row of ``f`` (the field minus the level at offsets ``t``, ``step_mm`` apart): the crossing from
    inside (> 0) to outside (<= 0) nearest offset 0, placed linearly between its two samples (offset 0
    where there is none), whether there is one, and the index of its interval."""
    cross = (f[:, :-1] > 0) & (f[:, 1:] <= 0)                            # inside -> outside going outward
    frac = f[:, :-1] / np.where(cross, f[:, :-1] - f[:, 1:], 1.0)
    at = t[..., :-1] + step_mm * frac
    best = np.argmin(np.where(cross, np.abs(at), np.inf), axis=1)
    rows = np.arange(len(f))
    hit = cross[rows, best]
    return np.where(hit, at[rows, best], 0.0), hit, best


def offset_to_level(field3d: np.ndarray, to_index: np.ndarray, points: np.ndarray, normals: np.ndarray,
                    max_mm: float, step_mm: float, level: float = 0.5, chunk: int = 65536,
                    coarse_steps: int = COARSE_STEPS) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (mm) along each normal to the nearest crossing of ``level`` from above to below.

    Parameters
    ----------
    field3d : ndarray, shape (nz, ny, nx)
        E.g. the smoothed mask (1 inside).
    to_index : ndarray, shape (4, 4)
        Patient LPS mm (homogeneous) to voxel index (k, j, i) (homogeneous).
    points, normals : ndarray, shape (m, 3)
        Where to start and the (unit) direction of positive offsets.
    max_mm, step_mm : float
        Samples at ``-max_mm .. max_mm`` every ``step_mm``.
    coarse_steps : int
        Search every ``coarse_steps``-th sample first, then refine the interval of the nearest crossing
        (:data:`COARSE_STEPS`; 1: every sample at once).

    Returns
    -------
    offset : ndarray of float32, shape (m,)
        The crossing's offset, 0 where there is none.
    found : ndarray of bool, shape (m,)
    """
    k = max(1, int(round(max_mm / step_mm)))
    # the coarse samples are a subset of the fine ones: the coarse step divides the whole span
    coarse = next(c for c in range(max(1, int(coarse_steps)), 0, -1) if (2 * k) % c == 0)
    t = np.linspace(-k * step_mm, k * step_mm, 2 * k + 1)
    t_coarse = t[::coarse]
    inner = np.arange(1, coarse) * step_mm                                 # the fine samples inside an interval
    A, b = to_index[:3, :3], to_index[:3, 3]
    m = len(points)
    offset = np.zeros(m, np.float32)
    found = np.zeros(m, bool)
    vol = np.asarray(field3d, np.float32)

    def sample(p0, d, offsets):
        """The field minus ``level`` at ``p0 + offsets d`` (offsets: (K,) or (c, K))."""
        offsets = np.broadcast_to(offsets, (len(p0), np.shape(offsets)[-1]))
        coords = p0.T[:, :, None] + offsets[None] * d.T[:, :, None]        # (3, c, K): contiguous per axis
        f = map_coordinates(vol, coords.reshape(3, -1), order=1, mode="constant", cval=0.0)
        return f.reshape(offsets.shape) - level

    def refine(f, p0, d, row, i):
        """The nearest crossing inside coarse interval ``i`` of texel ``row`` at every fine sample (pairs)."""
        lo = t_coarse[i]
        fine = np.concatenate([f[row, i][:, None], sample(p0[row], d[row], lo[:, None] + inner),
                               f[row, i + 1][:, None]], axis=1)
        at, hit, _ = _level_crossings(fine, lo[:, None] + np.arange(coarse + 1) * step_mm, step_mm)
        return np.where(hit, at, np.nan)

    # how near offset 0 each coarse interval comes
    reach = np.where((t_coarse[:-1] < 0) & (t_coarse[1:] > 0), 0.0,
                     np.minimum(np.abs(t_coarse[:-1]), np.abs(t_coarse[1:])))
    for start in range(0, m, chunk):
        sl = slice(start, start + chunk)
        p0 = points[sl] @ A.T + b                                        # (c, 3) voxel index
        d = normals[sl] @ A.T                                            # index per mm along the normal
        f = sample(p0, d, t_coarse)
        at, hit, _ = _level_crossings(f, t_coarse, coarse * step_mm)
        if coarse > 1:
            # 1. every coarse interval that crosses, at every fine sample
            row, i = np.nonzero((f[:, :-1] > 0) & (f[:, 1:] <= 0))
            got = refine(f, p0, d, row, i)
            nearest = np.full(len(f), np.inf)
            np.minimum.at(nearest, row, np.abs(got))
            # 2. the intervals nearer the surface than that crossing (all of them without one): a gap or a
            # sliver under a coarse step can hide a crossing from the coarse samples
            row2, i2 = np.nonzero((reach[None, :] < nearest[:, None])
                                  & ~((f[:, :-1] > 0) & (f[:, 1:] <= 0)))
            row, got = np.concatenate([row, row2]), np.concatenate([got, refine(f, p0, d, row2, i2)])
            keep = ~np.isnan(got)
            row, got = row[keep], got[keep]
            order = np.lexsort((np.abs(got), row))                       # by texel, the nearest first
            first = order[np.unique(row[order], return_index=True)[1]]
            at, hit = np.zeros(len(f)), np.zeros(len(f), bool)
            at[row[first]], hit[row[first]] = got[first], True
        offset[sl] = at
        found[sl] = hit
    return offset, found


def _soften(height: np.ndarray, covered: np.ndarray, sigma_texels: float) -> np.ndarray:
    """A Gaussian of ``sigma_texels`` over the covered texels only (normalised: the islands' edges and the
    gutters do not pull the values toward 0)."""
    if sigma_texels <= 0:
        return height
    w = covered.astype(np.float32)
    num = gaussian_filter(height * w, sigma_texels, mode="constant")
    den = gaussian_filter(w, sigma_texels, mode="constant")
    return np.where(covered, num / np.maximum(den, 1e-6), 0.0).astype(np.float32)


def _pad_gutters(height: np.ndarray, covered: np.ndarray, pad: int) -> np.ndarray:
    """Texels within ``pad`` of an island take the nearest island texel's value."""
    if not covered.any() or covered.all() or pad <= 0:
        return height
    dist, (iy, ix) = distance_transform_edt(~covered, return_indices=True)
    near = (dist > 0) & (dist <= pad)
    out = height.copy()
    out[near] = height[iy[near], ix[near]]
    return out


def _slice_axis(ct) -> np.ndarray:
    """The unit LPS direction of the CT's slice axis (k), pointing superior."""
    axis = np.asarray(ct.direction, float)[:, 2]
    axis = axis / max(float(np.linalg.norm(axis)), 1e-12)
    return axis if axis[2] >= 0 else -axis


def ct_detail_map(head, mask: np.ndarray, ct, resolution: int = D.DETAIL_RESOLUTION.default,
                  sigma_mm: float = D.DETAIL_SIGMA.default, max_mm: float = D.DETAIL_MAX_OFFSET.default,
                  step_mm: float = 0.25, coarse_steps: int = COARSE_STEPS, progress=None) -> DetailMap:
    """The CT detail map of a PDE head: per texel of its UV layout, the offset (mm) along the surface's
    outward normal from the PDE surface to the 0.5 level of the smoothed head mask (module docstring).

    Parameters
    ----------
    head : PDEHead
        The solved surface (its UV layout is the map's).
    mask : ndarray of bool, shape (nz, ny, nx)
        The head mask (:class:`~..segment.segmentation.Segmentation` ``.mask``).
    ct : CTVolume
        The volume the mask lies on (its ``spacing`` and ``affine``; the intensities are not read).
    resolution : int
        Texels along each side of the square map.
    sigma_mm : float
        The Gaussian applied to the mask (mm; along the slice axis at least :data:`SLICE_SIGMA` of a step).
    max_mm : float
        How far along the normal the skin is looked for (either side); the map's values lie within it.
    step_mm : float
        The sampling step along the normal (the crossing is placed linearly between two samples).
    coarse_steps : int
        The sampler's first pass takes every ``coarse_steps``-th sample (:data:`COARSE_STEPS`; 1: every
        sample, as before: the same map).
    progress : callable, optional
        ``progress(fraction, message)`` between the stages and the sampler's chunks; it may raise
        :class:`~..core.errors.Cancelled` (nothing is returned or kept).

    Returns
    -------
    DetailMap

    Notes
    -----
    Cost on CThead (256 x 256 x 113 voxels, t = 15) at 1024 x 1024 (~530k texels covered), 2 shared cores
    (docs/method.md, "The closed eyes: a CT detail map"): ~2.6 s of CPU (the branch's first version 3.2 s): the
    mask's Gaussian ~0.2 s, the texels (the surface meshed at ~1M vertices and rasterised) ~1.2 s,
    sampling ~1 s (13 samples a texel where sampling every 0.25 mm took 25), softening and gutters
    0.1 s; ~0.3 GB at its peak (the texel mesh and its rasterised triangles, in chunks). The upright
    texels' thin-smoothed mask (:data:`UPRIGHT_SLICE_SIGMA`) adds a second Gaussian (~0.2 s) and their
    second search (~0.6 s on a loaded machine: sampling 1.7 -> 2.3 s).
    """
    stages = detail_map_stages(head, mask, ct, resolution, sigma_mm, max_mm, step_mm, coarse_steps)
    while True:
        try:
            fraction, message = next(stages)
        except StopIteration as done:
            return done.value
        report_progress(progress, fraction, message)


def detail_map_stages(head, mask: np.ndarray, ct, resolution: int = D.DETAIL_RESOLUTION.default,
                      sigma_mm: float = D.DETAIL_SIGMA.default, max_mm: float = D.DETAIL_MAX_OFFSET.default,
                      step_mm: float = 0.25, coarse_steps: int = COARSE_STEPS, chunk: int = 65536):
    """:func:`ct_detail_map` one stage at a time, for a caller that keeps a UI responsive between them (a
    Blender modal operator: Esc between two stages stops it with nothing kept).

    A generator: yields ``(fraction, message)`` after each stage (the mask's Gaussian, the texels, each
    ``chunk`` of texels sampled; none takes more than ~1.5 s on CThead at 1024 px) and returns the
    :class:`DetailMap` (``StopIteration.value``). Parameters as :func:`ct_detail_map`.
    """
    res = int(D.DETAIL_RESOLUTION.check(int(resolution), "resolution"))
    clock = {}
    t0 = time.perf_counter()
    smoothed = smooth_mask(mask, ct.spacing, float(sigma_mm))
    upright = smooth_mask(mask, ct.spacing, float(sigma_mm), slice_sigma_mm=UPRIGHT_SLICE_SIGMA * float(ct.spacing[0]))
    clock["smooth_s"] = time.perf_counter() - t0
    yield 0.1, "the texels of the surface's UV map"
    t1 = time.perf_counter()
    texel, points, normals = texel_surface(head, res)
    clock["texels_s"] = time.perf_counter() - t1
    yield 0.4, "sampling the skin along the normals"
    to_index = np.linalg.inv(ct.affine)[[2, 1, 0, 3]]                    # LPS -> (k, j, i)
    offset = np.zeros(len(texel), np.float32)
    hit = np.zeros(len(texel), bool)
    clock["sample_s"] = 0.0
    nz = np.abs(normals @ _slice_axis(ct))
    thin = np.clip((UPRIGHT_NZ[1] - nz) / (UPRIGHT_NZ[1] - UPRIGHT_NZ[0]), 0.0, 1.0).astype(np.float32)
    for start in range(0, len(texel), chunk):
        t2 = time.perf_counter()
        sl = slice(start, start + chunk)
        offset[sl], hit[sl] = offset_to_level(smoothed, to_index, points[sl], normals[sl], float(max_mm),
                                              float(step_mm), chunk=chunk, coarse_steps=coarse_steps)
        near = np.flatnonzero(thin[sl] > 0) + start             # upright texels: the thin mask's offset too
        if near.size:
            o2, h2 = offset_to_level(upright, to_index, points[near], normals[near], float(max_mm), float(step_mm),
                                     chunk=chunk, coarse_steps=coarse_steps)
            w = thin[near]
            both = hit[near] & h2
            offset[near] = np.where(both, w * o2 + (1 - w) * offset[near], np.where(h2 & (w >= 0.5), o2, offset[near]))
            hit[near] |= h2 & (w >= 0.5)
        clock["sample_s"] += time.perf_counter() - t2
        yield 0.4 + 0.55 * min(start + chunk, len(texel)) / len(texel), "sampling the skin along the normals"
    t3 = time.perf_counter()
    offset *= np.clip((UP_FADE[1] - normals @ _slice_axis(ct)) / (UP_FADE[1] - UP_FADE[0]), 0.0, 1.0).astype(np.float32)
    del smoothed, upright
    height = np.zeros(res * res, np.float32)
    covered = np.zeros(res * res, bool)
    found = np.zeros(res * res, bool)
    height[texel], covered[texel], found[texel] = offset, True, hit
    height, covered, found = (a.reshape(res, res) for a in (height, covered, found))
    height = _pad_gutters(_soften(height, covered, SOFTEN_TEXELS), covered, PAD_TEXELS).astype(np.float32)
    clock["pad_s"] = time.perf_counter() - t3
    meta = {"resolution": res, "sigma_mm": float(sigma_mm), "max_mm": float(max_mm), "step_mm": float(step_mm),
            "covered": int(covered.sum()), "found": int(found.sum()), **clock}
    return DetailMap(height, covered, found, meta)
