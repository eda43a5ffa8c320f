"""Distances between two surfaces given as vertices and faces (fidelity of the PDE head, section 5.2).

Points are sampled uniformly by area on each surface; the distance of a point to
the other surface is :func:`~.mesh_geometry.point_surface_distance`: the exact
point-to-triangle distance to the best of a few candidate triangles, the
candidates being the triangles that own the nearest points of a dense
area-uniform sampling of the other surface (KD-tree). The result is therefore
never larger than the plain nearest-sample distance and never smaller than the
true point-to-surface distance; it equals the true distance unless the nearest
triangle owns none of the ``candidates`` nearest samples, which needs a sliver
triangle much larger than the sample spacing.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ..core.errors import PDEHeadError

# the mesh primitives live in .mesh_geometry (shipped code imports them from there); these names stay importable
# from here for the measures' callers (scripts, tests, slice_selection)
from ..core.mesh_geometry import (  # noqa: F401
    mesh_triangles,
    point_surface_distance,
    point_triangle_distance,
    sample_surface,
    triangulate,
)


def _summary(d: np.ndarray) -> dict[str, float]:
    return {"mean": float(d.mean()), "p95": float(np.percentile(d, 95)), "max": float(d.max()),
            "rms": float(np.sqrt(np.mean(d * d)))}


def symmetric_surface_distance(verts_a: np.ndarray, faces_a: np.ndarray, verts_b: np.ndarray,
                               faces_b: np.ndarray, samples: int = 100_000, dense: int = 400_000,
                               candidates: int = 8, seed: int = 0) -> dict[str, Any]:
    """Symmetric surface distance between surfaces A and B (mm).

    Parameters
    ----------
    verts_a, verts_b : ndarray, shape (n, 3)
    faces_a, faces_b : ndarray of int, shape (m, 3) or (m, 4)
        Triangles or quads (quads are split).
    samples : int
        Points sampled uniformly by area on each surface.
    dense : int
        Size of the area-uniform sampling of the other surface used to pick candidate triangles.
    candidates : int
        Candidate triangles per point for the exact point-triangle distance.
    seed : int
        Random seed (the result is deterministic for a given seed).

    Returns
    -------
    dict
        ``mean``, ``p95``, ``max`` (Hausdorff), ``rms`` over the distances of both
        directions pooled, and ``a_to_b`` / ``b_to_a``: the same statistics per direction.
    """
    ta, tb = triangulate(faces_a), triangulate(faces_b)
    rng = np.random.default_rng(seed)
    pa, _ = sample_surface(verts_a, ta, samples, rng)
    pb, _ = sample_surface(verts_b, tb, samples, rng)
    d_ab = point_surface_distance(pa, verts_b, tb, dense=dense, candidates=candidates, seed=seed + 1)
    d_ba = point_surface_distance(pb, verts_a, ta, dense=dense, candidates=candidates, seed=seed + 2)
    both = np.concatenate([d_ab, d_ba])
    out: dict[str, Any] = _summary(both)
    out["a_to_b"] = _summary(d_ab)
    out["b_to_a"] = _summary(d_ba)
    return out


# ----------------------------------------------------------------------------- the visible face

#: The visible-face measure's settings (shared with the face-from-skull benchmark).
FACE_BIN_MM = 1.0            # height of a bin (patient z)
FACE_BIN_DEG = 1.0           # angle of a bin around the vertical axis through the mask's centroid
FACE_DEPTH_MM = 3.0          # kept: within this of the outermost point of its bin
FACE_HALF_ANGLE_DEG = 60.0   # +- this of straight ahead (-y)
FACE_BELOW_MM = 70.0         # the band below ...
FACE_ABOVE_MM = 60.0         # ... and above the pronasale
FACE_MIDLINE_MM = 20.0       # the pronasale: most anterior kept point this close to the mid-sagittal line


def _face_polar(points: np.ndarray, centre_xy) -> tuple[np.ndarray, np.ndarray]:
    """Angle (degrees, 0 = straight ahead = -y, + toward the patient's left +x) and distance from the
    vertical axis through ``centre_xy``."""
    d = np.asarray(points, float)[:, :2] - np.asarray(centre_xy, float)[None, :2]
    return np.degrees(np.arctan2(d[:, 0], -d[:, 1])), np.hypot(d[:, 0], d[:, 1])


def visible_face_points(points: np.ndarray, centre_xy, bin_mm: float = FACE_BIN_MM,
                        bin_deg: float = FACE_BIN_DEG, depth_mm: float = FACE_DEPTH_MM) -> np.ndarray:
    """Which points lie on the visible outside of the head: within ``depth_mm`` of the outermost point of
    their bin (``bin_mm`` of height x ``bin_deg`` around the vertical axis through ``centre_xy``).

    Drops what a marching-cubes surface of the head mask also holds inside: the nasal cavity, the
    airway, the mouth's interior.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    p = np.asarray(points, float)
    angle, radius = _face_polar(p, centre_xy)
    zb = np.floor(p[:, 2] / bin_mm).astype(np.int64)
    ab = np.floor((angle + 180.0) / bin_deg).astype(np.int64)
    key = (zb - zb.min()) * (int(np.ceil(360.0 / bin_deg)) + 1) + ab
    _, inverse = np.unique(key, return_inverse=True)
    outer = np.full(inverse.max() + 1, -np.inf)
    np.maximum.at(outer, inverse, radius)
    return radius >= outer[inverse] - depth_mm


def face_window(points: np.ndarray, centre_xy, pronasale: np.ndarray, half_angle_deg: float = FACE_HALF_ANGLE_DEG,
                below_mm: float = FACE_BELOW_MM, above_mm: float = FACE_ABOVE_MM) -> np.ndarray:
    """Points within +- ``half_angle_deg`` of straight ahead and from ``below_mm`` under to ``above_mm``
    over the pronasale's height (bool, shape (n,))."""
    p = np.asarray(points, float)
    angle, _ = _face_polar(p, centre_xy)
    z0 = float(pronasale[2])
    return (np.abs(angle) <= half_angle_deg) & (p[:, 2] >= z0 - below_mm) & (p[:, 2] <= z0 + above_mm)


def pronasale(points: np.ndarray, centre_xy, midline_mm: float = FACE_MIDLINE_MM) -> np.ndarray:
    """The most anterior (smallest y) of ``points`` within ``midline_mm`` of the mid-sagittal line
    (the line through ``centre_xy`` along y)."""
    p = np.asarray(points, float)
    near = np.abs(p[:, 0] - float(centre_xy[0])) <= midline_mm
    if not np.any(near):
        raise PDEHeadError("no point near the mid-sagittal line: cannot find the pronasale")
    return p[near][np.argmin(p[near, 1])]


def _area_samples(vertices, triangles, density: float, rng) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, float)
    t = triangulate(triangles)
    area = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1).sum()
    return sample_surface(v, t, max(1000, int(np.ceil(area * density))), rng)


def visible_face_distance(surface_vertices: np.ndarray, surface_faces: np.ndarray, mask_vertices: np.ndarray,
                          mask_faces: np.ndarray, centre_xy, density: float = 1.0, seed: int = 0) -> dict[str, Any]:
    """How closely a surface follows the visible face of a head mask (in mm).

    Parameters
    ----------
    surface_vertices, surface_faces
        The surface measured (e.g. the exported ``skin.stl``), patient mm; triangles or quads.
    mask_vertices, mask_faces
        Marching cubes of the segmentation mask, patient mm.
    centre_xy : (2,)
        The mask's centroid (x, y): the vertical axis of the bins and the angle.
    density : float
        Points per mm^2 sampled on each surface (at least 1 for the issue's measure).

    Returns
    -------
    dict
        ``score_mean``: the mean of the two directed mean distances; ``score_p95``: the larger of
        the two directed p95; ``surface_to_mask`` / ``mask_to_surface``: mean and p95 each;
        ``pronasale`` (mm) and the point counts.

    Notes
    -----
    The mask's triangles are kept where their centroid lies within ``FACE_DEPTH_MM`` of the
    outermost point of its 1 mm x 1 deg bin (:func:`visible_face_points`): the nasal cavity,
    airway and mouth interior drop out. Both sides are sampled uniformly by area; both point
    sets are restricted to :func:`face_window` around the pronasale (:func:`pronasale` of the
    kept mask triangles' centroids). The surface's samples are kept by the same two rules (a closed
    skin loses nothing; a marching-cubes surface, e.g. the floor of a smoothed mask, loses its
    interior like the mask). Distances are exact point-to-triangle distances to the
    other side (the kept mask triangles, or all of the surface's triangles).
    """
    rng = np.random.default_rng(seed)
    mv = np.asarray(mask_vertices, float)
    mt = triangulate(mask_faces)
    centroids = mv[mt].mean(axis=1)
    kept = visible_face_points(centroids, centre_xy)
    tip = pronasale(centroids[kept], centre_xy)
    mask_win = kept & face_window(centroids, centre_xy, tip)
    mt_face = mt[mask_win]
    mp, _ = _area_samples(mv, mt_face, density, rng)
    sv = np.asarray(surface_vertices, float)
    st = triangulate(surface_faces)
    sp, _ = _area_samples(sv, st, density, rng)
    sp = sp[face_window(sp, centre_xy, tip) & visible_face_points(sp, centre_xy)]
    d_sm = point_surface_distance(sp, mv, mt_face, seed=seed + 1)
    d_ms = point_surface_distance(mp, sv, st, seed=seed + 2)
    out: dict[str, Any] = {
        "surface_to_mask": {"mean": float(d_sm.mean()), "p95": float(np.percentile(d_sm, 95))},
        "mask_to_surface": {"mean": float(d_ms.mean()), "p95": float(np.percentile(d_ms, 95))},
        "pronasale": tip.tolist(), "surface_points": int(len(sp)), "mask_points": int(len(mp))}
    out["score_mean"] = 0.5 * (out["surface_to_mask"]["mean"] + out["mask_to_surface"]["mean"])
    out["score_p95"] = max(out["surface_to_mask"]["p95"], out["mask_to_surface"]["p95"])
    return out


def face_banding(vertices: np.ndarray, faces: np.ndarray, centre_xy, pronasale_point: np.ndarray,
                 density: float = 4.0, dz: float = 0.5, sigma_mm: float = 3.0, seed: int = 0) -> float:
    """Slice banding on the face: the RMS (mm) of the face's outermost radius minus its Gaussian of
    ``sigma_mm`` along z.

    Points sampled by area (``density`` per mm^2) inside :func:`face_window` are binned by their angle
    about ``centre_xy`` (1 degree, from -60 to 60 straight ahead) and their height (``dz`` mm, from 70 mm
    under the pronasale); per bin the largest horizontal radius is the face's outline. Its Gaussian along z
    (normalised over the bins that hold points) is the face's large-scale shape; the RMS of the difference,
    over the bins whose Gaussian sees >= 95 % filled bins, counts slice steps and the face's own small
    features (nose, lips, lids) alike, so it is compared with a reference (e.g. marching cubes of the
    smoothed mask), not with 0.
    """
    v, t = np.asarray(vertices, float), triangulate(faces)
    area = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1).sum()
    pts, _ = sample_surface(v, t, int(area * density), np.random.default_rng(seed))
    pts = pts[face_window(pts, centre_xy, pronasale_point)]
    d = pts[:, :2] - np.asarray(centre_xy, float)[None]
    angle, radius = np.degrees(np.arctan2(d[:, 0], -d[:, 1])), np.hypot(d[:, 0], d[:, 1])
    a = np.floor(angle + 60.0).astype(int)
    z0 = float(pronasale_point[2]) - 70.0
    k = np.floor((pts[:, 2] - z0) / dz).astype(int)
    na, nz = 121, int(np.ceil(130.0 / dz)) + 1
    keep = (a >= 0) & (a < na) & (k >= 0) & (k < nz)
    r = np.full(na * nz, -np.inf)
    np.maximum.at(r, a[keep] * nz + k[keep], radius[keep])
    r = r.reshape(na, nz)
    have = np.isfinite(r)
    w = have.astype(float)
    s = sigma_mm / dz
    cover = gaussian_filter1d(w, s, axis=1, mode="constant")
    smooth = gaussian_filter1d(np.where(have, r, 0.0), s, axis=1, mode="constant") / np.maximum(cover, 1e-9)
    inner = have & (cover > 0.95)                                   # away from holes and ends
    return float(np.sqrt(np.mean((r - smooth)[inner] ** 2)))
