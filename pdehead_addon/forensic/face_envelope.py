"""The skull's closed outer envelope in 3-D, read as a radius on the face's grid.

The bone's outer profile on which the face stands (:func:`.face_profile.bone_profile`) must be a smooth surface on any
skull: one that bridges the orbits, the nasal aperture and the gaps between the zygoma and the mandible, as a skin
stretched over the bone would, and that does not step where a horizontal row meets or leaves a bone feature (the
zygomatic arch, the teeth, the mandible's angle). Made in 3-D rather than row by row, it is smooth by construction:

1. the skull mesh is voxelised (:data:`ENVELOPE_VOXEL_MM`): every voxel a triangle passes through;
2. a morphological closing with a ball (:data:`.face_profile.ENVELOPE_CLOSING_MM`) by two Euclidean distance transforms
   (dilation, then erosion: its cost does not grow with the ball), the cavities filled (in 3-D, then per axial
   section for a skull open at the foramen magnum or at the scan's cut);
3. the signed distance to the closed solid, smoothed by a Gaussian of :data:`ENVELOPE_SMOOTH_MM` (a smooth level
   set: its zero level has no corner finer than that);
4. per (row, column) bin of the grid the outermost zero crossing along the horizontal ray from the cylinder's axis
   (:func:`scipy.ndimage.map_coordinates`, all rays at once).

References
----------
.. [1] Serra J. Image Analysis and Mathematical Morphology. Academic Press, 1982 (closing by a ball).
.. [2] Maurer CR, Qi R, Raghavan V. A linear time algorithm for computing exact Euclidean distance transforms of binary
       images in arbitrary dimensions. IEEE TPAMI 25(2):265-270, 2003 (scipy's ``distance_transform_edt``).
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..core.mesh import Mesh

#: The voxel (mm) on which the skull's envelope is made. Its zero level is smoothed over
#: :data:`ENVELOPE_SMOOTH_MM`, larger than this voxel, so the voxel's steps do not show; CThead's skull in a box padded
#: by the closing is ~ 4 M voxels at 1.5 mm (~ 0.3 GB at the peak, four float64 distance maps).
ENVELOPE_VOXEL_MM = 1.5
#: The Gaussian (mm) on the closed solid's signed distance: the envelope's smallest rounding. A skin does not follow
#: the bone's edges finer than the soft tissue over them (the T-Table's depths over the face, ~ 5-10 mm); chosen on GE
#: and the phantom among 3 / 5 / 8 mm.
ENVELOPE_SMOOTH_MM = 5.0
#: Rays are sampled every this fraction of a voxel.
RAY_STEP_FRACTION = 0.5
#: Rows of rays sampled at once (peak memory: rows x columns x samples x 3 coordinates).
RAY_ROWS_PER_CHUNK = 16


def surface_points(mesh: Mesh, spacing_mm: float) -> np.ndarray:
    """Points on every triangle (and quad) of ``mesh`` no farther than ``spacing_mm`` apart: its vertices and a
    barycentric lattice on each face, the triangles grouped by how fine a lattice they need (a few groups, no loop over
    the faces)."""
    v = mesh.vertices
    t = mesh.triangles
    if len(mesh.quads):
        t = np.concatenate([t, mesh.quads[:, [0, 1, 2]], mesh.quads[:, [0, 2, 3]]])
    if not len(t):
        return v
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    longest = np.max([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1), np.linalg.norm(a - c, axis=1)],
                     axis=0)
    n_sub = np.maximum(1, np.ceil(longest / spacing_mm)).astype(int)
    out = [v]
    for n in np.unique(n_sub):
        if n < 2:
            continue
        sel = n_sub == n
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = (i + j) <= n
        u, w = i[keep] / n, j[keep] / n                         # barycentric lattice (n+1)(n+2)/2 points
        pa, pb, pc = a[sel], b[sel], c[sel]
        pts = pa[:, None, :] + u[None, :, None] * (pb - pa)[:, None, :] + w[None, :, None] * (pc - pa)[:, None, :]
        out.append(pts.reshape(-1, 3))
    return np.concatenate(out)


def closed_envelope_sdf(mesh: Mesh, closing_mm: float, smooth_mm: float | None = None,
                        voxel_mm: float | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """The smoothed signed distance (mm, negative inside) to the skull's closed solid, on a voxel box.

    Returns
    -------
    sdf : (X, Y, Z) float32, the Gaussian-smoothed signed distance
    origin : (3,) patient mm of voxel (0, 0, 0)
    voxel_mm : the voxel's size
    """
    smooth_mm = ENVELOPE_SMOOTH_MM if smooth_mm is None else float(smooth_mm)
    h = ENVELOPE_VOXEL_MM if voxel_mm is None else float(voxel_mm)
    pts = surface_points(mesh, 0.5 * h)
    pad = float(closing_mm) + 4.0 * float(smooth_mm) + 3.0 * h
    origin = pts.min(axis=0) - pad
    shape = tuple(np.ceil((pts.max(axis=0) + pad - origin) / h).astype(int) + 1)
    idx = np.round((pts - origin) / h).astype(np.intp)
    solid = np.zeros(shape, bool)
    solid[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    del pts, idx
    if closing_mm > 0:                                    # closing by a ball: dilate, then erode, by distance
        dilated = ndimage.distance_transform_edt(~solid, sampling=h) <= closing_mm
        solid |= ndimage.distance_transform_edt(dilated) * h > closing_mm
        del dilated
    solid = ndimage.binary_fill_holes(solid)
    axial = np.zeros((3, 3, 3), bool)
    axial[:, :, 1] = ndimage.generate_binary_structure(2, 1)  # each axial section on its own
    solid = ndimage.binary_fill_holes(solid, structure=axial)
    sdf = ndimage.distance_transform_edt(~solid, sampling=h).astype(np.float32)
    sdf -= ndimage.distance_transform_edt(solid, sampling=h).astype(np.float32)
    sdf += np.float32(0.5 * h)       # the zero level from the boundary voxels' outer faces to their centres (the bone)
    del solid
    if smooth_mm > 0:
        ndimage.gaussian_filter(sdf, sigma=float(smooth_mm) / h, output=sdf, mode="nearest")
    return sdf, origin, h


def envelope_radius(mesh: Mesh, grid, closing_mm: float, smooth_mm: float | None = None,
                    voxel_mm: float | None = None) -> np.ndarray:
    """(K, M) per bin of ``grid`` (:class:`.face_profile.FaceGrid`) the radius of the skull's closed, smoothed outer
    envelope (:func:`closed_envelope_sdf`): the outermost zero crossing of its signed distance along the horizontal ray
    from the grid's axis at the row's height and the column's angle; NaN where the ray meets no envelope (rows above or
    below the skull)."""
    sdf, origin, h = closed_envelope_sdf(mesh, closing_mm, smooth_mm, voxel_mm)
    step = RAY_STEP_FRACTION * h
    far = origin + (np.array(sdf.shape) - 1) * h
    corners = np.array([[x, y] for x in (origin[0], far[0]) for y in (origin[1], far[1])])
    r_max = float(np.max(np.hypot(*(corners - grid.centre).T)))
    r = np.arange(0.0, r_max + step, step)
    s, c = np.sin(grid.theta), np.cos(grid.theta)
    K, M = len(grid.z), len(grid.theta)
    out = np.full((K, M), np.nan)
    big = np.float32(1e3)                                 # outside the box: outside the skull
    for k0 in range(0, K, RAY_ROWS_PER_CHUNK):
        zs = grid.z[k0:k0 + RAY_ROWS_PER_CHUNK]
        shape = (len(zs), M, len(r))
        coords = np.empty((3,) + shape, np.float32)
        coords[0] = (grid.centre[0] + r[None, None, :] * s[None, :, None] - origin[0]) / h
        coords[1] = (grid.centre[1] + r[None, None, :] * c[None, :, None] - origin[1]) / h
        coords[2] = ((zs - origin[2]) / h)[:, None, None]
        f = ndimage.map_coordinates(sdf, coords.reshape(3, -1), order=1, mode="constant", cval=big).reshape(shape)
        inside = f < 0
        hit = inside.any(axis=2)
        last = len(r) - 1 - np.argmax(inside[..., ::-1], axis=2)          # the outermost inside sample
        nxt = np.minimum(last + 1, len(r) - 1)
        fa = np.take_along_axis(f, last[..., None], 2)[..., 0]
        fb = np.take_along_axis(f, nxt[..., None], 2)[..., 0]
        frac = np.where(fb > fa, fa / np.where(fb > fa, fa - fb, 1.0), 0.0)
        out[k0:k0 + len(zs)] = np.where(hit, r[last] + np.clip(frac, 0.0, 1.0) * step, np.nan)
    return out
