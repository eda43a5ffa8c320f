"""Soft-tissue depth between the skin and the skull, per skin vertex (forensic facial reconstruction).

Two distances per skin vertex, in mm:

* ``depth``: along the inward skin normal to the first crossing of the skull
  surface (what a depth marker measures when it stands perpendicular to the
  skin; CloudCompare's and MeshLab's "distance along normals");
* ``nearest``: the distance to the nearest point of the skull surface (the
  shortest way to bone; never larger than ``depth``).

The ray is cast by sphere tracing on the exact point-to-mesh distance
(:class:`~.mesh_geometry.MeshDistance`: :func:`~.mesh_geometry.point_triangle_distance` on KD-tree
candidate triangles): each step advances by the distance to the nearest skull point,
which can never cross the surface, so the first crossing is found, not some
later one; a ray stops when it is within ``tolerance`` of the skull.

No value (NaN) is stored, with the reason in ``reason``, where

* ``NO_BONE``: the ray meets no skull within ``max_depth_mm`` (neck, ears, the
  open orbit of a bone mesh);
* ``ENVELOPE``: the ray meets the skull *envelope* where there is no bone
  within ``bone_tolerance_mm`` (the PDE skull closes over the orbits, the nasal
  aperture and the temporal fossae; see :mod:`.skull`);
* ``INSIDE``: the skin vertex lies inside the skull envelope (a fold of the
  smooth surfaces where the tissue is very thin).
"""
from __future__ import annotations

import csv
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage as ndi

from ..core.errors import PDEHeadError
from ..core.mesh import Mesh
from ..core.mesh_geometry import MeshDistance, mesh_triangles
from ..core.provenance import provenance_lines

MEASURED, NO_BONE, ENVELOPE, INSIDE = 0, 1, 2, 3
#: Longest depth searched (mm); deeper rays end in the airway, the orbit or the other side of the head.
MAX_DEPTH_MM = 40.0
#: A sphere-traced ray whose distance grows again after falling below this (mm) has crossed the surface.
CROSSING_MM = 0.1


@dataclass
class TissueDepth:
    """Per-vertex soft-tissue depth of a skin mesh.

    Attributes
    ----------
    points : ndarray (n, 3)
        The skin vertices (patient LPS mm).
    normals : ndarray (n, 3)
        Unit inward normals used for the rays.
    depth : ndarray (n,)
        Distance along the inward normal to the skull (mm), NaN where ``reason != MEASURED``.
    nearest : ndarray (n,)
        Distance to the nearest skull point (mm), NaN where ``reason != MEASURED``.
    hits : ndarray (n, 3)
        The skull point each ray met (NaN where none).
    reason : ndarray of uint8 (n,)
        :data:`MEASURED`, :data:`NO_BONE`, :data:`ENVELOPE` or :data:`INSIDE`.
    meta : dict
        Parameters and :meth:`statistics`.
    """

    points: np.ndarray
    normals: np.ndarray
    depth: np.ndarray
    nearest: np.ndarray
    hits: np.ndarray
    reason: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def statistics(self, mask: np.ndarray | None = None) -> dict[str, float]:
        """Count, share measured and min/median/mean/p95/max of ``depth`` (over ``mask``, default all)."""
        sel = np.ones(len(self.depth), bool) if mask is None else np.asarray(mask, bool)
        d = self.depth[sel]
        ok = np.isfinite(d)
        out: dict[str, float] = {"vertices": int(sel.sum()), "measured": int(ok.sum()),
                                 "measured_fraction": float(ok.mean()) if d.size else 0.0}
        for code, name in ((NO_BONE, "no_bone"), (ENVELOPE, "envelope"), (INSIDE, "inside")):
            out[name] = int(np.count_nonzero(self.reason[sel] == code))
        if ok.any():
            v = d[ok]
            out.update(min=float(v.min()), median=float(np.median(v)), mean=float(v.mean()),
                       p95=float(np.percentile(v, 95)), max=float(v.max()))
        return out


def vertex_normals(mesh: Mesh) -> np.ndarray:
    """Unit outward vertex normals: area-weighted sum of the normals of the triangles around each vertex."""
    v, tris = mesh_triangles(mesh)
    fn = np.cross(v[tris[:, 1]] - v[tris[:, 0]], v[tris[:, 2]] - v[tris[:, 0]])   # |fn| = 2 * area
    out = np.zeros_like(v)
    for c in range(3):
        np.add.at(out, tris[:, c], fn)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, norm, out=np.zeros_like(out), where=norm > 0)


def cast_rays(origins: np.ndarray, directions: np.ndarray, mesh: Mesh, max_distance: float,
              tolerance: float = 0.01, max_steps: int = 400, distance: MeshDistance | None = None) -> np.ndarray:
    """Distance along each ray to the first crossing of a closed mesh (sphere tracing), NaN if none.

    Parameters
    ----------
    origins, directions : ndarray (n, 3)
        Ray starts and unit directions.
    mesh : Mesh
    max_distance : float
        Rays farther than this are misses.
    tolerance : float
        A ray has hit when it is this close to the surface (mm).
    max_steps : int
        Steps per ray (grazing rays that have not converged by then are misses).

    Notes
    -----
    A ray also counts as a hit when its distance grows again right after falling below
    :data:`CROSSING_MM` (it crossed the surface within the last step, or grazed it that closely).
    """
    dist = distance or MeshDistance(*mesh_triangles(mesh))
    o = np.asarray(origins, np.float64)
    d = np.asarray(directions, np.float64)
    t = np.zeros(len(o))
    last = np.full(len(o), np.inf)
    result = np.full(len(o), np.nan)
    active = np.arange(len(o))
    for _ in range(int(max_steps)):
        if active.size == 0:
            break
        r = dist(o[active] + t[active, None] * d[active])
        hit = r <= tolerance
        result[active[hit]] = t[active[hit]] + r[hit]
        # the distance grows again right after it was tiny: the ray crossed the surface in the last
        # step (the candidate distance can be slightly too large next to fans of sliver triangles)
        crossed = ~hit & (r > last[active]) & (last[active] < CROSSING_MM)
        result[active[crossed]] = t[active[crossed]]
        last[active] = r
        t[active] += r
        alive = ~hit & ~crossed & (t[active] <= max_distance)
        active = active[alive]
    missed = np.flatnonzero(~np.isfinite(result))
    if 0 < missed.size <= EXACT_RAY_LIMIT:
        # the candidate distance can be too large at the apex of a fan (the crown's pole), so a traced
        # ray may step over the surface there: the few misses are checked exactly against every triangle
        v, tri = mesh_triangles(mesh)
        exact = ray_mesh_exact(o[missed], d[missed], v, tri)
        result[missed] = np.where(exact <= max_distance, exact, np.nan)
    return result


#: Missed rays up to this count are re-checked exactly (landmarks, pegs); a whole depth map is not.
EXACT_RAY_LIMIT = 256


def ray_mesh_exact(origins: np.ndarray, directions: np.ndarray, vertices: np.ndarray,
                   triangles: np.ndarray) -> np.ndarray:
    """Distance to the first triangle each ray meets (Moeller-Trumbore against all triangles), inf if none."""
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    e1, e2 = b - a, c - a
    out = np.full(len(origins), np.inf)
    for i, (o, d) in enumerate(zip(origins, directions)):
        pvec = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, pvec)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tvec = o - a
        uu = np.einsum("ij,ij->i", tvec, pvec) * inv
        qvec = np.cross(tvec, e1)
        vv = (qvec @ d) * inv
        tt = np.einsum("ij,ij->i", e2, qvec) * inv
        hit = ok & (uu >= -1e-9) & (vv >= -1e-9) & (uu + vv <= 1 + 1e-9) & (tt >= 0)
        if hit.any():
            out[i] = tt[hit].min()
    return out


def tissue_depth(skin: Mesh, skull: Mesh, *, envelope=None, max_depth_mm: float = MAX_DEPTH_MM,
                 bone_tolerance_mm: float | None = None, tolerance_mm: float = 0.01,
                 normals: np.ndarray | None = None) -> TissueDepth:
    """Soft-tissue depth of every skin vertex: along the inward skin normal and to the nearest skull point.

    Parameters
    ----------
    skin, skull : Mesh
        Closed surfaces in patient LPS mm with outward winding (the PDE skin, the PDE skull or the
        marching-cubes bone mesh of :func:`~.skull.skull_mesh`).
    envelope : SkullSegmentation, optional
        The skull segmentation the skull surface came from. With it, a hit farther than
        ``bone_tolerance_mm`` from its bone is :data:`ENVELOPE` and a skin vertex inside its envelope
        is :data:`INSIDE`; without it every hit counts.
    max_depth_mm : float
        Longest depth searched; beyond it :data:`NO_BONE`.
    bone_tolerance_mm : float, optional
        Default: 2 mm plus half the largest voxel size of the CT.
    tolerance_mm : float
        Sphere-tracing hit tolerance.
    normals : ndarray (n, 3), optional
        Outward skin normals; default :func:`vertex_normals`.

    Returns
    -------
    TissueDepth
    """
    if not isinstance(skin, Mesh) or not isinstance(skull, Mesh):
        raise PDEHeadError("tissue_depth needs two Mesh objects (skin, skull)")
    if len(skin.vertices) == 0 or skull.face_count == 0:
        raise PDEHeadError("tissue_depth: the skin has no vertices or the skull no faces")
    if not (np.isfinite(max_depth_mm) and max_depth_mm > 0):
        raise PDEHeadError(f"max_depth_mm must be > 0, got {max_depth_mm!r}")
    pts = np.asarray(skin.vertices, np.float64)
    n_out = vertex_normals(skin) if normals is None else np.asarray(normals, np.float64)
    inward = -n_out
    sv, st = mesh_triangles(skull)
    dist = MeshDistance(sv, st)
    along = cast_rays(pts, inward, skull, max_depth_mm, tolerance=tolerance_mm, distance=dist)
    nearest = dist(pts)
    reason = np.where(np.isfinite(along), MEASURED, NO_BONE).astype(np.uint8)
    reason[~np.isfinite(n_out).all(axis=1) | (np.linalg.norm(n_out, axis=1) == 0)] = NO_BONE
    hits = pts + np.where(np.isfinite(along), along, np.nan)[:, None] * inward
    meta: dict[str, Any] = dict(max_depth_mm=float(max_depth_mm), tolerance_mm=float(tolerance_mm))
    if envelope is not None:
        ct = envelope.ct
        tol = (2.0 + 0.5 * max(ct.spacing)) if bone_tolerance_mm is None else float(bone_tolerance_mm)
        bone_dist = _distance_to_bone(envelope.bone, ct.spacing)
        ok = reason == MEASURED
        at_hit = _sample_nearest(bone_dist, ct.patient_to_index(hits[ok]), fill=np.inf)
        env_only = np.zeros(len(pts), bool)
        env_only[np.flatnonzero(ok)[at_hit > tol]] = True
        reason[env_only] = ENVELOPE
        # a start inside the envelope (eroded by a voxel: the voxel grid is coarser than the surfaces)
        # would trace the skull's wall from the inside
        core = ndi.binary_erosion(envelope.mask, structure=ndi.generate_binary_structure(3, 1))
        inside = _sample_nearest(core.astype(np.float32), ct.patient_to_index(pts), fill=0.0) > 0.5
        reason[inside] = INSIDE
        meta.update(bone_tolerance_mm=tol)
    bad = reason != MEASURED
    depth = np.where(bad, np.nan, along)
    nearest = np.where(bad, np.nan, nearest)
    hits[bad] = np.nan
    out = TissueDepth(points=pts, normals=inward, depth=depth, nearest=nearest, hits=hits, reason=reason, meta=meta)
    out.meta["statistics"] = out.statistics()
    return out


def _distance_to_bone(bone: np.ndarray, spacing) -> np.ndarray:
    """Distance (mm, float32) of every voxel centre to the nearest bone voxel centre."""
    return ndi.distance_transform_edt(~bone, sampling=spacing).astype(np.float32)


def _sample_nearest(volume: np.ndarray, kji: np.ndarray, fill: float) -> np.ndarray:
    """Value of the nearest voxel at fractional indices (``fill`` outside the volume)."""
    idx = np.rint(np.asarray(kji)).astype(np.int64)
    inside = np.all((idx >= 0) & (idx < np.array(volume.shape)), axis=1)
    out = np.full(len(idx), fill, dtype=np.float64)
    k, j, i = idx[inside].T
    out[inside] = volume[k, j, i]
    return out


def write_depth_csv(result: TissueDepth, path: str | os.PathLike, provenance: dict | None = None) -> int:
    """Write one row per skin vertex: ``x,y,z`` (patient LPS mm), ``depth_mm`` (empty where no bone), the
    nearest-point distance and the reason; returns the number of rows. ``provenance`` (software, bone
    level, ...) goes first as ``# key: value`` lines."""
    path = os.fspath(path)
    pts = result.points
    with open(path, "w", newline="") as fh:
        fh.write("".join(line + "\n" for line in provenance_lines(provenance)))
        w = csv.writer(fh)
        w.writerow(["x_mm", "y_mm", "z_mm", "depth_mm", "nearest_mm", "reason"])
        fmt = np.vectorize(lambda x: "" if not np.isfinite(x) else f"{x:.3f}", otypes=[object])
        depth = fmt(result.depth)
        near = fmt(result.nearest)
        names = np.array(["measured", "no_bone", "envelope", "inside"], dtype=object)[result.reason]
        rows = zip(*(np.char.mod("%.3f", pts[:, c]) for c in range(3)), depth, near, names)
        w.writerows(rows)
    return len(pts)
