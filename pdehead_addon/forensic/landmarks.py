"""Craniometric landmarks on the skull, depth-table markers, Frankfurt horizontal and the mid-sagittal mirror.

Everything is in patient LPS millimetres and Blender-free, so the Blender
operators (:mod:`operators.ui.forensic_ops`) and the tests share it:

* :data:`STANDARD_LANDMARKS`: the midline and bilateral landmarks of the
  soft-tissue depth tables (the set of Stephan & Simpson 2008 / Taylor 2001,
  as used in craniofacial identification) plus porion and orbitale for the
  Frankfurt horizontal;
* :func:`snap_to_surface`: a clicked point onto the nearest point of the skull
  mesh, with the outward surface normal there;
* :func:`marker_pegs`: a depth table (:mod:`.depth_table`) to pegs standing on
  the skull along its normal with those lengths;
* :func:`landmark_depths`: the measured depth (skull to skin along the skull
  normal) at each placed landmark (written by :func:`.depth_table.write_landmark_csv`);
  (the same rays measured on the CT's intensities: :mod:`.depth_on_ct`);
* :func:`frankfurt_transform`: the rigid transform that makes the Frankfurt
  plane (porions and orbitales) horizontal with the face toward -y;
* :func:`midsagittal_plane` / :func:`mirror_matrix`: the plane fitted to
  bilateral landmark pairs and the reflection across it;
  :func:`symmetry_plane`: the skull's own plane of reflective symmetry, for
  when no bilateral landmarks are placed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..core.errors import PDEHeadError
from ..core.mesh import Mesh
from ..core.mesh_geometry import MeshDistance, closest_point_on_triangle, mesh_triangles
from .tissue_depth import cast_rays


@dataclass(frozen=True)
class LandmarkDef:
    key: str
    name: str
    bilateral: bool
    description: str


_DEFS = [
    ("g", "Glabella", False, "most prominent midline point between the supraorbital ridges"),
    ("n", "Nasion", False, "midline point of the frontonasal suture"),
    ("rhi", "Rhinion", False, "lowest midline point of the internasal suture (end of the nasal bones)"),
    ("mp", "Mid-philtrum", False, "midline point of the maxilla under the mid-philtrum (A point)"),
    ("sd", "Supradentale", False, "midline point of the upper alveolar crest between the incisors"),
    ("id", "Infradentale", False, "midline point of the lower alveolar crest between the incisors"),
    ("sm", "Supramentale", False, "deepest midline point of the mandible's anterior concavity (B point)"),
    ("pog", "Pogonion", False, "most anterior midline point of the chin (mental eminence)"),
    ("me", "Menton", False, "lowest midline point of the mandibular symphysis"),
    ("v", "Vertex", False, "highest point of the cranial vault"),
    ("op", "Opisthocranion", False, "most posterior midline point of the vault"),
    ("fe", "Frontal eminence", True, "most prominent point of the frontal eminence"),
    ("so", "Supraorbital", True, "above the orbit, at the middle of the supraorbital margin"),
    ("sbo", "Suborbital", True, "below the orbit, at the middle of the infraorbital margin"),
    ("im", "Inferior malar", True, "lower edge of the zygomatic bone"),
    ("lo", "Lateral orbit", True, "lateral orbital margin at the level of the frontozygomatic suture"),
    ("za", "Zygomatic arch", True, "most lateral point of the zygomatic arch (zygion)"),
    ("sg", "Supraglenoid", True, "above the glenoid fossa, on the root of the zygomatic arch"),
    ("go", "Gonion", True, "most lateral point of the mandibular angle"),
    ("supm2", "Supra M2", True, "alveolar bone above the upper second molar"),
    ("ocl", "Occlusal line", True, "on the mandibular ramus at the occlusal plane"),
    ("subm2", "Sub M2", True, "mandibular body below the lower second molar"),
    ("po", "Porion", True, "highest point of the external acoustic meatus (Frankfurt horizontal)"),
    ("or", "Orbitale", True, "lowest point of the infraorbital margin (Frankfurt horizontal)"),
    # landmarks of the depth tables (Caple & Stephan's codes) that the set above lacks, so that every
    # tabulated depth has a landmark to stand on
    ("mn", "Mid-nasal", False, "midline point of the nasal bones half way from nasion to rhinion"),
    ("ss", "Subspinale", False, "deepest midline point of the maxilla between the nasal spine and prosthion"),
    ("gn", "Gnathion", False, "midline point of the chin between pogonion and menton (most anterior-inferior)"),
    ("ac", "Alare curvature", True, "bony proxy: the widest point of the nasal aperture's margin"),
    ("sc", "Supra canine", True, "maxillary alveolar bone over the upper canine root"),
    ("ic", "Infra canine", True, "mandibular alveolar bone over the lower canine root"),
    ("mr", "Mid-ramus", True, "centre of the lateral surface of the mandibular ramus"),
    ("mmb", "Mid-mandibular border", True, "lower border of the mandible half way from menton to gonion"),
]

#: The standard set: midline landmarks once, bilateral ones as "<Name> L" and "<Name> R" (patient sides).
STANDARD_LANDMARKS: list[LandmarkDef] = []
for _key, _name, _bi, _desc in _DEFS:
    if _bi:
        STANDARD_LANDMARKS.append(LandmarkDef(f"{_key}_l", f"{_name} L", True, _desc + " (patient left)"))
        STANDARD_LANDMARKS.append(LandmarkDef(f"{_key}_r", f"{_name} R", True, _desc + " (patient right)"))
    else:
        STANDARD_LANDMARKS.append(LandmarkDef(_key, _name, False, _desc))
LANDMARK_NAMES = [d.name for d in STANDARD_LANDMARKS]
_BY_NAME = {d.name.lower(): d for d in STANDARD_LANDMARKS}
_BY_NAME.update({d.key.lower(): d for d in STANDARD_LANDMARKS})


def landmark(name: str) -> LandmarkDef:
    """The standard landmark of a name or key (case-insensitive), or a PDEHeadError listing the set."""
    d = _BY_NAME.get(str(name).strip().lower())
    if d is None:
        raise PDEHeadError(f"unknown landmark {name!r}; the standard set is: {', '.join(LANDMARK_NAMES)}")
    return d


def bilateral_pairs(names) -> list[tuple[str, str]]:
    """(left, right) name pairs present in ``names``."""
    have = set(names)
    return [(n, n[:-1] + "R") for n in names if n.endswith(" L") and n[:-1] + "R" in have]


# --------------------------------------------------------------------------- snapping
def snap_to_surface(points: np.ndarray, mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """The nearest surface points of ``mesh`` to ``points`` and the unit outward normals there.

    Exact (every triangle that can hold the nearest point is tested; meant for tens of landmarks). The normal is
    the normal of the triangle the nearest point lies on (winding outward); of triangles equally near, the
    first.

    Returns
    -------
    (snapped, normals) : ndarray (n, 3) each
    """
    v, t = mesh_triangles(mesh)
    if len(t) == 0:
        raise PDEHeadError("cannot snap landmarks to a mesh without faces")
    pts = np.atleast_2d(np.asarray(points, np.float64))
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    centre = (a + b + c) / 3.0
    radius = np.sqrt(np.max([np.einsum("ij,ij->i", q - centre, q - centre) for q in (a, b, c)], axis=0))
    corners = v[np.unique(t)]
    best_p = np.zeros_like(pts)
    best_t = np.zeros(len(pts), np.int64)
    for i, p in enumerate(pts):
        # The nearest corner bounds the nearest surface point's distance; a triangle whose bounding sphere lies
        # beyond that bound cannot hold it. Only the rest go through the exact test (a few of 365k on a skull).
        bound = np.sqrt(np.min(np.einsum("ij,ij->i", corners - p, corners - p)))
        cand = np.flatnonzero(np.linalg.norm(centre - p, axis=1) - radius <= bound * (1 + 1e-9) + 1e-9)
        if len(cand) == 0:                  # a point that is not finite: every triangle, as the exact test had it
            cand = np.arange(len(t))
        q = closest_point_on_triangle(p, a[cand], b[cand], c[cand])
        d = np.einsum("ij,ij->i", q - p, q - p)
        j = int(np.argmin(d))
        best_p[i], best_t[i] = q[j], cand[j]
    tri = t[best_t]
    n = np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return best_p, n


# --------------------------------------------------------------------------- depth tables and pegs
def marker_pegs(landmarks: dict[str, np.ndarray], skull: Mesh, table: dict[str, float],
                measured_direction: bool = True) -> list[tuple[str, np.ndarray, np.ndarray, float]]:
    """Pegs for the landmarks that the table has: (name, base on the skull, outward unit direction, length mm).

    A peg stands along the direction :func:`landmark_depths` measures the depth along (the bone's exposed
    normal, :func:`exposed_normals`), so that at the rim of an opening it stands perpendicular to the bone
    beside the opening, as the measured depth does, rather than leaning into the opening along the
    nearest triangle's normal. ``measured_direction=False`` gives the nearest triangle's normal instead,
    for a caller that sets its own directions (the face from the skull): the exposed normals cast rays
    over the bone (~6 s for 34 pegs on CThead's 365k-triangle skull)."""
    names = [n for n in landmarks if n in table]
    if not names:
        return []
    base, nearest = snap_to_surface(np.array([landmarks[n] for n in names]), skull)
    normal = exposed_normals(base, skull, nearest_normals=nearest) if measured_direction else nearest
    return [(n, base[i], normal[i], float(table[n])) for i, n in enumerate(names)]


#: Radius (mm) of the bone surface around a landmark whose exposed normals give its measurement direction.
DEPTH_NORMAL_RADIUS_MM = 6.0
#: A triangle of that neighbourhood is exposed when a ray along its normal meets no bone within this (mm):
#: the walls of an orbit, the nasal aperture or the ear canal face other bone across the opening.
DEPTH_EXPOSURE_MM = 60.0


def exposed_normals(points: np.ndarray, skull: Mesh, radius_mm: float = DEPTH_NORMAL_RADIUS_MM,
                    exposure_mm: float = DEPTH_EXPOSURE_MM, max_triangles: int = 160,
                    nearest_normals: np.ndarray | None = None) -> np.ndarray:
    """The measurement direction of a tissue depth at bone surface points: the bone's outward normal
    averaged (area-weighted) over the triangles within ``radius_mm`` that face the outside.

    At the rim of an opening (nasion, orbitale, the orbit margins, porion) the normal of the nearest
    triangle is no direction: the surface turns into the opening there, and a ray along it runs into
    the orbit or the ear canal and meets the skin far away, or not at all. The walls of an opening face
    other bone across it, so a triangle counts only when a ray along its own normal meets no bone within
    ``exposure_mm`` (the outer face of the skull around the opening does); their mean normal is the normal
    of the bone's outer face with the opening bridged -- the way a caliper or a peg is set perpendicular
    to the bone beside an opening. On smooth bone it is the local normal averaged over the radius. Where no
    triangle qualifies, the nearest triangle's normal is kept.

    Parameters
    ----------
    points : ndarray (n, 3)
        Points on (or snapped to) the skull surface, mm.
    skull : Mesh
        Closed outward-wound bone surface.
    nearest_normals : ndarray (n, 3), optional
        The nearest triangles' normals (from :func:`snap_to_surface`), kept where no triangle is exposed.

    Returns
    -------
    ndarray (n, 3)
        Unit outward directions.
    """
    v, t = mesh_triangles(skull)
    pts = np.atleast_2d(np.asarray(points, np.float64))
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    cross = np.cross(b - a, c - a)
    area2 = np.linalg.norm(cross, axis=1)
    tn = cross / np.maximum(area2, 1e-12)[:, None]
    cen = (a + b + c) / 3.0
    nearest = snap_to_surface(pts, skull)[1] if nearest_normals is None else np.asarray(nearest_normals, float)
    groups, origins, dirs = [], [], []
    for p in pts:
        idx = np.flatnonzero(np.einsum("ij,ij->i", cen - p, cen - p) <= radius_mm ** 2)
        if len(idx) > max_triangles:                     # an even subset: the mean, not every triangle
            idx = idx[np.linspace(0, len(idx) - 1, max_triangles).round().astype(int)]
        groups.append(idx)
        origins.append(cen[idx] + 0.3 * tn[idx])
        dirs.append(tn[idx])
    if not any(len(g) for g in groups):
        return nearest
    hit = cast_rays(np.concatenate(origins), np.concatenate(dirs), skull, exposure_mm,
                    distance=MeshDistance(v, t))
    out = nearest.copy()
    k = 0
    for i, idx in enumerate(groups):
        free = ~np.isfinite(hit[k:k + len(idx)])
        k += len(idx)
        if free.any():
            m = (tn[idx[free]] * area2[idx[free], None]).sum(0)
            if np.linalg.norm(m) > 1e-9:
                out[i] = m / np.linalg.norm(m)
    return out


def landmark_depths(landmarks: dict[str, np.ndarray], skull: Mesh, skin: Mesh,
                    max_depth_mm: float = 60.0) -> dict[str, tuple[np.ndarray, float]]:
    """Measured tissue depth at each landmark: skull point, and distance to the skin along the skull's
    outward normal there (mm, NaN if the skin is not met within ``max_depth_mm``). The normal is the
    bone's outer face's (:func:`exposed_normals`), so that at the rim of an opening the depth is taken
    perpendicular to the bone beside the opening, not into it."""
    names = list(landmarks)
    if not names:
        return {}
    base, normal, depth = depth_rays(landmarks, skull, skin, max_depth_mm)
    return {n: (base[i], float(depth[i])) for i, n in enumerate(names)}


def depth_rays(landmarks: dict[str, np.ndarray], skull: Mesh, skin: Mesh | None, max_depth_mm: float):
    """The depth rays of the landmarks (in their order): bone points (snapped onto ``skull``), the bone's
    exposed normals there, and the meshes' depth along them (NaN without ``skin``)."""
    base, nearest = snap_to_surface(np.array([landmarks[n] for n in landmarks]), skull)
    normal = exposed_normals(base, skull, nearest_normals=nearest)
    depth = cast_rays(base, normal, skin, max_depth_mm) if skin is not None else np.full(len(base), np.nan)
    return base, normal, depth


# --------------------------------------------------------------------------- orientation
def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v)
    if not n > 1e-9:
        raise PDEHeadError("degenerate landmarks: points coincide")
    return v / n


def frankfurt_transform(porion_l, porion_r, orbitale_l, orbitale_r) -> np.ndarray:
    """4x4 rigid transform (patient mm -> aligned mm) that puts the head in the Frankfurt horizontal.

    The Frankfurt plane is the least-squares plane of the two porions and the two
    orbitales. In the aligned frame it is horizontal (its normal is +z, superior), the
    porion-to-porion line is the x axis (patient right -> left, +x), the face looks
    toward -y, and the mid-porion point stays where it was (rotation about it).
    """
    pts = np.array([porion_l, porion_r, orbitale_l, orbitale_r], np.float64)
    if pts.shape != (4, 3) or not np.all(np.isfinite(pts)):
        raise PDEHeadError("the Frankfurt horizontal needs porion L/R and orbitale L/R as 3-D points")
    centre = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centre)
    up = vt[2]
    if up[2] < 0:
        up = -up
    x = pts[0] - pts[1]                                    # right porion -> left porion
    x = _unit(x - up * (x @ up))
    y = np.cross(up, x)                                    # z x x = y: with x to the left, y posterior
    front = 0.5 * (pts[2] + pts[3]) - 0.5 * (pts[0] + pts[1])
    if front @ y > 0:                                      # orbitales must be anterior (-y)
        raise PDEHeadError("the orbitales lie behind the porions: check the left/right and landmark names")
    rot = np.stack([x, y, up])                             # rows: new axes in patient coordinates
    pivot = 0.5 * (pts[0] + pts[1])
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = pivot - rot @ pivot
    return m


def midsagittal_plane(pairs: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Plane (point, unit normal toward patient left) best fitting the bisectors of bilateral pairs.

    The normal is the dominant direction of the left-minus-right vectors (the sign kept
    toward +x); the point is the mean of the pair midpoints.
    """
    if len(pairs) < 1:
        raise PDEHeadError("the mid-sagittal plane needs at least one bilateral landmark pair")
    left = np.array([p[0] for p in pairs], np.float64)
    right = np.array([p[1] for p in pairs], np.float64)
    return _bisector_plane(left, right)


def _bisector_plane(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    diff = left - right
    if len(diff) == 1:
        n = _unit(diff[0])
    else:
        _, _, vt = np.linalg.svd(diff, full_matrices=False)
        n = vt[0]
        if n @ diff.sum(axis=0) < 0:
            n = -n
    return 0.5 * (left + right).mean(axis=0), n


def mirror_matrix(point: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """4x4 reflection across the plane through ``point`` with unit ``normal``."""
    n = _unit(np.asarray(normal, np.float64))
    m = np.eye(4)
    m[:3, :3] -= 2.0 * np.outer(n, n)
    m[:3, 3] = 2.0 * (n @ np.asarray(point, np.float64)) * n
    return m


def _kabsch(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation minimising ``|rot @ source + shift - target|`` (Kabsch)."""
    ms, mt = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((source - ms).T @ (target - mt))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rot, mt - rot @ ms


#: Mirror-ICP settings of :func:`symmetry_plane`.
SYMMETRY_POINTS = 20_000      # points used (a fixed random subset of a larger mesh)
SYMMETRY_TRIM = 0.7           # fraction of closest correspondences kept (asymmetric parts drop out)
SYMMETRY_ITERATIONS = 150     # per stage (outliers rejected, then trimmed)
SYMMETRY_REJECT = 3.0         # first stage: pairs within this many times the median distance
SYMMETRY_FAN_DEG = 12.0       # starting planes tried: +-12 deg about two axes ...
SYMMETRY_FAN_STEP_DEG = 3.0   # ... in 3 deg steps
SYMMETRY_FAN_POINTS = 1_000   # scored (and the best starts refined) on this many points
SYMMETRY_STARTS = 3           # starts refined
SYMMETRY_FAN_MM = 20.0        # and offsets +-20 mm ...
SYMMETRY_FAN_STEP_MM = 4.0    # ... in 4 mm steps


def symmetry_plane(points: np.ndarray, normal: np.ndarray = (1.0, 0.0, 0.0), point: np.ndarray | None = None,
                   trim: float = SYMMETRY_TRIM, iterations: int = SYMMETRY_ITERATIONS,
                   max_points: int = SYMMETRY_POINTS) -> tuple[np.ndarray, np.ndarray, dict]:
    """The plane of reflective symmetry of a point set (the skull's mid-sagittal plane).

    Mirror ICP: reflect the points across the current plane, register the
    mirrored copy to the original by rigid ICP steps (nearest-point pairs, the
    ``trim`` fraction of closest pairs kept so that asymmetric parts -- a head
    holder, a displaced mandible, streaks -- do not pull; Kabsch rotation and
    translation), and take the plane of the composed reflection, until it
    stops moving. For a symmetric object, registration then reflection is a
    reflection across its symmetry plane. Converges to the nearest symmetry
    plane, so the start (default: the patient's left-right axis through the
    centroid) must be within a few tens of degrees -- true for a head scan in
    patient coordinates.

    Parameters
    ----------
    points : (n, 3) array
        Patient mm (e.g. the skull mesh's vertices).
    normal, point : array_like
        Starting plane; ``point`` defaults to the centroid.
    trim : float
        Fraction in (0, 1] of the pairs kept each iteration.
    iterations : int
        Upper bound on the iterations of each stage.
    max_points : int
        Larger sets are subsampled (deterministically) to this many points.

    Returns
    -------
    point, normal : (3,) arrays
        A point on the plane and the unit normal toward patient left (+x).
    info : dict
        ``residual_mm``: median distance of the kept reflected points to their
        partners; ``start_residual_mm`` the same for the starting plane;
        ``iterations``; ``converged``.

    See also :func:`midsagittal_plane` (the plane from placed bilateral landmarks).
    """
    pts = np.asarray(points, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 10 or not np.isfinite(pts).all():
        raise PDEHeadError(f"the symmetry plane needs at least 10 finite 3-D points, got shape {pts.shape}")
    if not 0.0 < trim <= 1.0:
        raise PDEHeadError(f"trim must be in (0, 1], got {trim!r}")
    pts = pts[np.random.default_rng(0).permutation(len(pts))[:max_points]]   # random order: pts[:k] is a subset
    tree = cKDTree(pts)
    n = _unit(np.asarray(normal, np.float64))
    c = pts.mean(axis=0) if point is None else np.asarray(point, np.float64)

    def residual(c, n, keep, sub=pts):
        dist, idx = tree.query(sub - 2.0 * ((sub - c) @ n)[:, None] * n)
        best = np.argpartition(dist, keep - 1)[:keep] if keep < len(sub) else np.arange(len(sub))
        return float(np.median(dist[best])), best, idx

    start = residual(c, n, len(pts))[0]
    # ICP only finds the nearest optimum and slides slowly: start from the best of a coarse fan of planes
    fan = np.radians(np.arange(-SYMMETRY_FAN_DEG, SYMMETRY_FAN_DEG + 1e-9, SYMMETRY_FAN_STEP_DEG))
    e1 = _unit(np.cross(n, [0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.cross(n, [0.0, 1.0, 0.0]))
    e2 = np.cross(n, e1)
    candidates = [_unit(n + np.tan(a) * e1 + np.tan(b) * e2) for a in fan for b in fan]
    coarse = pts[:SYMMETRY_FAN_POINTS]
    shifts = np.arange(-SYMMETRY_FAN_MM, SYMMETRY_FAN_MM + 1e-9, SYMMETRY_FAN_STEP_MM)
    starts = []
    for m in candidates:  # every orientation with every offset (the centroid is off where one side has more)
        base = coarse - 2.0 * ((coarse - c) @ m)[:, None] * m
        dist, _ = tree.query((base[None] + (2.0 * shifts)[:, None, None] * m).reshape(-1, 3))
        score = np.median(dist.reshape(len(shifts), -1), axis=1)
        k = int(np.argmin(score))
        starts.append((score[k], c + shifts[k] * m, m))
    starts.sort(key=lambda t: t[0])
    # the fan is coarser than the basin of the true plane: refine the best few on the subset, keep the best
    refined = [_mirror_icp(tree, coarse, c0, n0, trim, iterations) for _, c0, n0 in starts[:SYMMETRY_STARTS]]
    _, c, n, _, _ = min(refined, key=lambda r: r[0])
    _, c, n, it, converged = _mirror_icp(tree, pts, c, n, trim, iterations)
    if n[0] < 0:
        n = -n
    return c, n, dict(residual_mm=residual(c, n, max(3, int(round(trim * len(pts)))))[0], start_residual_mm=start,
                      iterations=it, converged=bool(converged))


def _mirror_icp(tree, pts: np.ndarray, c: np.ndarray, n: np.ndarray, trim: float, iterations: int):
    """Mirror ICP from the plane (c, n) on ``pts`` (``tree`` holds the reference points): returns
    (trimmed median residual, c, n, iterations, converged)."""
    converged, it = False, 0
    keep = max(3, int(round(trim * len(pts))))
    # Pairs farther than a few times the median are rejected first (a fixed trimmed fraction from the
    # start locks the plane where it is; keeping all pairs lets a one-sided part pull it), then the
    # closest ``trim`` fraction refines.
    for stage in ("reject", "trim"):
        for _ in range(int(iterations)):
            it += 1
            dist, idx = tree.query(pts - 2.0 * ((pts - c) @ n)[:, None] * n)
            if stage == "reject":
                best = np.flatnonzero(dist <= SYMMETRY_REJECT * max(np.median(dist), 0.1))
            else:
                best = np.argpartition(dist, keep - 1)[:keep]
            mirrored = pts[best] - 2.0 * ((pts[best] - c) @ n)[:, None] * n
            rot, shift = _kabsch(mirrored, tree.data[idx[best]])
            # the composed map x -> rot @ (reflection of x) + shift, projected onto the nearest reflection
            a = rot @ (np.eye(3) - 2.0 * np.outer(n, n))
            b = rot @ (2.0 * (n @ c) * n) + shift
            _, vecs = np.linalg.eigh(0.5 * (a + a.T))
            n_new = vecs[:, 0] * (1.0 if vecs[:, 0] @ n >= 0 else -1.0)
            c_new = c - ((c @ n_new) - 0.5 * (b @ n_new)) * n_new      # the point of the new plane nearest c
            moved = np.degrees(np.arccos(np.clip(n_new @ n, -1, 1))), abs((c_new - c) @ n_new)
            c, n = c_new, n_new
            converged = moved[0] < 1e-3 and moved[1] < 1e-3
            if converged:
                break
    dist, _ = tree.query(pts - 2.0 * ((pts - c) @ n)[:, None] * n)
    return float(np.median(np.partition(dist, keep - 1)[:keep])), c, n, it, converged
