"""Craniometric landmarks on the skull, depth-table markers, Frankfurt horizontal and the mid-sagittal mirror.

Everything is in patient LPS millimetres and Blender-free, so the Blender
operators (:mod:`operators.forensic`) and the tests share it:

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
* :func:`landmark_depths_on_ct`: the same rays, with the bone and skin points at the level
  crossings of the CT's interpolated intensities, and whether the profile along the ray supports
  the depth; :func:`measure_landmark_depths`: the one entry every depth output uses (the CT's when the
  study has one, else the meshes', with the method recorded);
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

from .errors import PDEHeadError
from .mesh_geometry import MeshDistance, closest_point_on_triangle, mesh_triangles
from .mesh import Mesh


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
    # landmarks of the depth tables (Caple & Stephan's codes) that the set above lacks (issue 22)
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
def snap_to_surface(points: np.ndarray, mesh: Mesh, chunk: int = 200_000) -> tuple[np.ndarray, np.ndarray]:
    """The nearest surface points of ``mesh`` to ``points`` and the unit outward normals there.

    Exact (every triangle is tested; meant for tens of landmarks). The normal is the
    normal of the triangle the nearest point lies on (winding outward).

    Returns
    -------
    (snapped, normals) : ndarray (n, 3) each
    """
    v, t = mesh_triangles(mesh)
    if len(t) == 0:
        raise PDEHeadError("cannot snap landmarks to a mesh without faces")
    pts = np.atleast_2d(np.asarray(points, np.float64))
    best_d = np.full(len(pts), np.inf)
    best_p = np.zeros_like(pts)
    best_t = np.zeros(len(pts), np.int64)
    for s in range(0, len(t), chunk):
        tt = t[s:s + chunk]
        a, b, c = v[tt[:, 0]], v[tt[:, 1]], v[tt[:, 2]]
        for i, p in enumerate(pts):
            q = closest_point_on_triangle(p, a, b, c)
            d = np.einsum("ij,ij->i", q - p, q - p)
            j = int(np.argmin(d))
            if d[j] < best_d[i]:
                best_d[i], best_p[i], best_t[i] = d[j], q[j], s + j
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
    from .tissue_depth import cast_rays

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
    base, normal, depth = _depth_rays(landmarks, skull, skin, max_depth_mm)
    return {n: (base[i], float(depth[i])) for i, n in enumerate(names)}


def _depth_rays(landmarks: dict[str, np.ndarray], skull: Mesh, skin: Mesh | None, max_depth_mm: float):
    """The depth rays of the landmarks (in their order): bone points (snapped onto ``skull``), the bone's
    exposed normals there, and the meshes' depth along them (NaN without ``skin``)."""
    from .tissue_depth import cast_rays

    base, nearest = snap_to_surface(np.array([landmarks[n] for n in landmarks]), skull)
    normal = exposed_normals(base, skull, nearest_normals=nearest)
    depth = cast_rays(base, normal, skin, max_depth_mm) if skin is not None else np.full(len(base), np.nan)
    return base, normal, depth


#: The bone point is refined along the ray to the bone level's crossing in the interpolated CT within this many
#: voxel sizes (the largest) of the mesh's point: the bone mesh of thin margins lies up to a slice off the bone.
DEPTH_SEARCH_VOXELS = 2.0
#: Step (mm) of the intensity profile sampled along each landmark's ray (trilinear interpolation).
DEPTH_PROFILE_STEP_MM = 0.05
#: Bone thicker than this (mm) met by the ray between the bone point and the skin makes the depth ``uncertain``.
DEPTH_BONE_IN_FRONT_MM = 0.5
#: The bone's plateau is looked for this far (mm) inside the bone point along the ray ...
DEPTH_PLATEAU_MM = 4.0
#: ... and reached when the peak there is at least this fraction of the way from the bone level to the bone mode.
DEPTH_PLATEAU_FRACTION = 0.8
#: A ray that runs within the slices (its slice index changes by less than this per slice spacing along it) is
#: checked between the two slices either side of it: their own crossings along its path may lie at most this many
#: slice spacings apart (1: the surface meets the ray at 45 deg or more between the slices) ...
DEPTH_SLICE_RUN = 0.5
DEPTH_SLICE_SHIFT = 1.0
#: ... where the nearer slice's weight is at least this (a ray on a slice measures that slice).
DEPTH_SLICE_WEIGHT = 0.1
#: A ray within this angle (deg) of the slices' normal crosses its bone and skin edges between two slices, sampled
#: a slice spacing apart: there the crossing is located with the blurred-step model of the slices
#: (:func:`step_crossing`) instead of the linear interpolation of the two slices.
DEPTH_STEP_MODEL_DEG = 30.0
#: The slices' edge spread (:func:`slice_edge_spread`) is measured on the skin where its slope against the slices
#: is at most this (deg), from at least DEPTH_SPREAD_MIN_COLUMNS columns (else no step model is used).
DEPTH_SPREAD_MAX_SLOPE_DEG = 45.0
DEPTH_SPREAD_MIN_COLUMNS = 100
#: Air (HU): the skin level is half way between it and soft tissue.
AIR_HU = -1000.0


@dataclass
class DepthOnCT:
    """A landmark's depth measured on the CT's intensities (:func:`landmark_depths_on_ct`).

    ``point``: the bone point (patient mm; the bone level's crossing along the ray); ``depth``: mm to the skin
    level's crossing along the bone's exposed normal (NaN when no skin is met); ``mesh_depth``: the depth from
    the meshes alone (:func:`landmark_depths`); ``direction``: the ray's unit direction (the bone's exposed
    normal); ``trusted``: False when the profile along the ray says the measurement cannot be trusted,
    ``evidence`` then says why (measured numbers); ``method``: ``"ct"``, or ``"mesh"`` when
    :func:`measure_landmark_depths` fell back to the meshes (no CT intensities)."""

    point: np.ndarray
    depth: float
    mesh_depth: float
    direction: np.ndarray
    trusted: bool
    evidence: str = ""
    method: str = "ct"          # "ct": on the CT's intensities; "mesh": on the meshes (no usable CT)


def slice_edge_spread(volume: np.ndarray, spacing, air: float, tissue: float,
                      max_slope_deg: float = DEPTH_SPREAD_MAX_SLOPE_DEG) -> tuple[float | None, int]:
    """The spread (mm, the standard deviation of an equivalent Gaussian edge) of the CT's edges across the slices,
    measured on the head's own skin: the slice profile (a thick slice's box, the scanner's blur) sets how far an
    edge between two slices shows in them.

    In every column of the slices (a fixed in-plane position, along the slice axis) the outermost crossing of the
    half-way level between ``air`` and ``tissue`` (the top of the head, and the other way the chin and the neck) is
    an air/skin edge; where its surface slopes at most ``max_slope_deg`` against the slices (the slope from the
    neighbouring columns' crossings), with tissue two slices inside and air two slices outside, the samples near it
    between 10 % and 90 % of the way from air to tissue are counted. An edge blurred by a Gaussian of s.d.
    ``sigma`` along its normal, at a random place between the slices of spacing ``h``, shows in 2 * 1.2816 *
    sigma / (h cos(slope)) such samples on average: ``sigma = h * mean(count * cos(slope)) / 2.563``. (A box of
    the slice spacing gives 0.8 per edge: 0.31 h, against its s.d. of 0.29 h.)

    Returns (sigma mm, number of columns); sigma is None with fewer than :data:`DEPTH_SPREAD_MIN_COLUMNS` columns.
    """
    from scipy.special import ndtri

    h, dy, dx = (float(v) for v in spacing[:3])
    f_all = (np.asarray(volume, np.float32) - np.float32(air)) / np.float32(tissue - air)
    counts, weights = [], []
    for f in (f_all, f_all[::-1]):             # the outermost edge from either end of the slice axis
        nz = f.shape[0]
        above = f >= 0.5
        has = above.any(0)
        top = nz - 1 - np.argmax(above[::-1], axis=0)
        t = np.clip(top, 2, nz - 3)

        def at(o):
            return np.take_along_axis(f, (t + o)[None], 0)[0]

        f0, f1 = at(0), at(1)
        zc = (t + (f0 - 0.5) / np.maximum(f0 - f1, 1e-6)) * h          # the edge's height, linearly
        gy, gx = np.gradient(zc, dy, dx)
        slope = np.hypot(gy, gx)
        ok = has & (top >= 2) & (top <= nz - 3) & (slope <= np.tan(np.radians(max_slope_deg)))
        ok &= (at(-2) > 0.9) & (at(2) < 0.1)
        n = sum(((at(o) > 0.1) & (at(o) < 0.9)).astype(np.float32) for o in (-1, 0, 1, 2))
        counts.append(n[ok])
        weights.append(1.0 / np.sqrt(1.0 + slope[ok] ** 2))
    count, cos = np.concatenate(counts), np.concatenate(weights)
    if len(count) < DEPTH_SPREAD_MIN_COLUMNS:
        return None, int(len(count))
    return float(h * np.mean(count * cos) / (2.0 * ndtri(0.9))), int(len(count))


def step_crossing(samples: np.ndarray, values: np.ndarray, level: float, inside: float, outside: float,
                  spread: float) -> float | None:
    """The crossing of ``level`` by an edge from ``inside`` to ``outside`` (values) seen in a few samples along a
    ray (``samples`` mm along it, outward), modelled as a blurred step ``outside + (inside - outside) *
    Phi((s_e - s) / spread)``: from the sample most nearly half way (its fraction f of the way strictly between
    2 % and 98 %), ``s_e = s + spread * Phi^-1(f)``, and the level's crossing ``s_e - spread * Phi^-1(f_level)``.
    None when no sample lies on the edge's slope (the edge is then no better located than by interpolation)."""
    from scipy.special import ndtri

    f = (np.asarray(values, float) - outside) / (inside - outside)
    on = (f > 0.02) & (f < 0.98)
    if not on.any() or not 0.0 < (level - outside) / (inside - outside) < 1.0:
        return None
    # the sample on the outer side of the edge: its fraction leans on the outside's level (air, soft tissue), which
    # is known, far less than on the inside's (a bone's own value, fat or muscle under the skin)
    i = np.flatnonzero(on)[np.argmin(f[on])]
    fl = (level - outside) / (inside - outside)
    return float(samples[i] + spread * (ndtri(f[i]) - ndtri(fl)))


def landmark_depths_on_ct(landmarks: dict[str, np.ndarray], skull: Mesh, skin: Mesh, volume: np.ndarray, ct,
                          bone_level: float, skin_level: float, bone_mode: float | None = None,
                          head_mask: np.ndarray | None = None, max_depth_mm: float = 60.0,
                          search_mm: float | None = None, slice_spread_mm: float | None = None) -> dict[str, DepthOnCT]:
    """Landmark depths with sub-voxel bone and skin points: the level crossings of the CT's trilinearly
    interpolated intensities along each landmark's ray, not the meshes' surfaces.

    The ray is the one :func:`landmark_depths` casts (from the landmark snapped onto the bone mesh, along the
    bone's exposed normal, :func:`exposed_normals`). Along it the intensities ``volume`` (the CT's grid,
    e.g. ``SkullSegmentation.hu``) are sampled every :data:`DEPTH_PROFILE_STEP_MM` by trilinear
    interpolation. The bone point is the outward crossing of ``bone_level`` nearest the mesh point within
    ``search_mm`` (default :data:`DEPTH_SEARCH_VOXELS` of the largest voxel size): on thick slices the
    smoothed mesh of a thin margin or an arch lies 1.5-3 mm off the bone, the iso-surface of the
    interpolated intensities does not (a level set between samples, not the binary mask's staircase). The
    skin point is the first outward crossing of ``skin_level`` beyond the bone point: the CT's own skin
    where the PDE skin smooths over a fold (the nasion's notch, the lips).

    A depth is not trusted (``trusted`` False, the measured reason in ``evidence``) when

    * no outward crossing of the bone level lies within ``search_mm`` of the mesh point;
    * the ray meets bone again (more than :data:`DEPTH_BONE_IN_FRONT_MM` of it) between the bone point and
      the skin: the landmark lies behind other bone along its normal, the depth would run through it;
    * the bone along the ray never reaches its plateau: its peak within :data:`DEPTH_PLATEAU_MM` inside the
      bone point is below :data:`DEPTH_PLATEAU_FRACTION` of the way from ``bone_level`` to ``bone_mode`` (a
      margin or a plate thinner than the blur of the slices: partial volume lowers it, and the level crossing
      of a bone that never reaches its own value lies off its surface);
    * no skin is met within ``max_depth_mm``;
    * the ray runs within the slices (it crosses less than :data:`DEPTH_SLICE_RUN` of a slice spacing per slice
      spacing along it) and the two slices either side of it disagree on a crossing: along the ray's path, each
      slice's own crossing of the level lies more than :data:`DEPTH_SLICE_SHIFT` slice spacings from the other's,
      or one slice has none within ``search_mm`` (an edge of bone or a lip that ends between the slices: the
      surface meets the ray at a grazing angle there, and the crossing interpolated between the two slices is
      the interpolation's, not the CT's). Checked where the farther slice weighs at least
      :data:`DEPTH_SLICE_WEIGHT`.

    Where the skin touches something outside the head (a pillow, a head holder: the skin level's crossing lies
    more than a voxel beyond the head mask's), the skin point is the PDE skin's (or the head mask's) instead.

    A ray within :data:`DEPTH_STEP_MODEL_DEG` of the slices' normal crosses each edge between two slices a slice
    spacing apart, and the linear crossing between them moves with where the edge lies between them (on the
    phantom's 4.3 mm slices by up to 0.6 mm per edge). Where the edge's own surface also faces the slices (the bone
    mesh's normal at the bone point, the skin mesh's at the skin point, within the same angle) the crossing is
    located instead with the blurred-step model of the slices (:func:`step_crossing`): the edge's spread across
    the slices is measured on the study's own skin (:func:`slice_edge_spread`, or ``slice_spread_mm``), divided by
    the cosine between the edge's normal and the ray; the plateaus are air and soft tissue (2 * skin_level + 1000)
    for the skin, soft tissue and the larger of ``bone_mode`` and the bone's peak along the ray for the bone.

    Parameters
    ----------
    landmarks : dict
        name -> patient mm.
    skull, skin : Mesh
        The bone mesh (:func:`~.skull.skull_mesh`) and the skin (the PDE skin): the ray's start and direction,
        and ``mesh_depth``.
    volume : ndarray (nz, ny, nx)
        Intensities on ``ct``'s grid in the units of the two levels.
    ct : CTVolume
        The grid's geometry (``patient_to_index``, ``spacing``).
    bone_level, skin_level : float
        The bone's iso-level (the one the bone mask was thresholded at) and the skin's (half way between air
        and soft tissue).
    bone_mode : float, optional
        The bone's own value (the histogram's bone mode); without it the plateau is not checked.
    head_mask : ndarray of bool, optional
        The head segmentation's mask on ``ct``'s grid (pillows and holders outside it).

    Returns
    -------
    dict name -> :class:`DepthOnCT`
    """
    from scipy import ndimage as ndi

    names = list(landmarks)
    if not names:
        return {}
    vol = np.asarray(volume)
    if vol.shape != tuple(ct.shape):
        raise PDEHeadError(f"landmark depths: the intensities' shape {vol.shape} is not the CT's {tuple(ct.shape)}")
    base, normal, mesh_depth = _depth_rays(landmarks, skull, skin, max_depth_mm)
    search = float(DEPTH_SEARCH_VOXELS * max(ct.spacing)) if search_mm is None else float(search_mm)
    step = DEPTH_PROFILE_STEP_MM
    s = np.arange(-search, max_depth_mm + search + step / 2, step)
    pts = base[:, None, :] + s[None, :, None] * normal[:, None, :]
    idx = ct.patient_to_index(pts.reshape(-1, 3)).T
    vol32 = vol.astype(np.float32, copy=False)
    prof = ndi.map_coordinates(vol32, idx, order=1, mode="nearest").reshape(len(names), -1)
    mask_prof = None
    if head_mask is not None:
        mask_prof = ndi.map_coordinates(np.asarray(head_mask, np.float32), idx, order=1, mode="constant",
                                        cval=0.0).reshape(len(names), -1)

    def crossings(v, level):
        """Sub-sample positions (mm along the ray) where the profile falls through ``level`` going outward."""
        i = np.flatnonzero((v[:-1] >= level) & (v[1:] < level))
        return s[i] + (v[i] - level) / (v[i] - v[i + 1]) * step

    slice_mm = float(ct.spacing[0])
    k_index = idx[0].reshape(len(names), -1)

    def between_slices(k, at, level, what):
        """Why the crossing at ``at`` (mm along ray ``k``) is not the CT's, when the ray runs between two slices
        that disagree on it (see the docstring); "" when they agree or the ray does not run within the slices."""
        near = np.abs(s - at) <= slice_mm
        kk = k_index[k][near]
        if not near.any() or np.ptp(kk) >= 2.0 * DEPTH_SLICE_RUN:
            return ""
        kc = float(np.interp(at, s, k_index[k]))
        k0 = int(np.floor(kc))
        f = kc - k0
        if min(f, 1.0 - f) < DEPTH_SLICE_WEIGHT or k0 < 0 or k0 + 1 >= vol.shape[0]:
            return ""
        window = np.abs(s - at) <= search
        sub = idx.reshape(3, len(names), -1)[:, k][:, window]
        found = []
        for kz in (k0, k0 + 1):
            plane = sub.copy()
            plane[0] = kz
            v = ndi.map_coordinates(vol32, plane, order=1, mode="nearest")
            sw = s[window]
            i = np.flatnonzero((v[:-1] >= level) & (v[1:] < level))
            c = sw[i] + (v[i] - level) / (v[i] - v[i + 1]) * step
            found.append(float(c[np.argmin(np.abs(c - at))]) if len(c) else float("nan"))
        a, b = found
        if np.isfinite(a) and np.isfinite(b) and abs(a - b) <= DEPTH_SLICE_SHIFT * slice_mm:
            return ""
        where = ", ".join(f"slice {kz}: " + (f"{c - at:+.1f} mm" if np.isfinite(c) else f"none within {search:.1f} mm")
                          for kz, c in zip((k0, k0 + 1), found))
        return (f"the ray runs between two slices {slice_mm:.1f} mm apart ({f:.2f} of the way) that disagree on "
                f"the {what}'s crossing along it ({where}): an edge between the slices, met at a grazing angle; "
                "the interpolated crossing is not measured")

    spread = slice_spread_mm
    if spread is None:
        spread = slice_edge_spread(vol, ct.spacing, AIR_HU, 2.0 * skin_level - AIR_HU)[0]
    tissue = 2.0 * skin_level - AIR_HU
    # the ray's slice index per mm along it: |dk/ds| * slice spacing is the cosine to the slices' normal
    dk = (k_index[:, -1] - k_index[:, 0]) / (s[-1] - s[0])
    bone_normal = snap_to_surface(base, skull)[1]
    steep = np.abs(dk) * slice_mm >= np.cos(np.radians(DEPTH_STEP_MODEL_DEG))

    # the slices' normal in patient mm (the slice index's gradient)
    axis = ct.patient_to_index(np.vstack([np.zeros(3), np.eye(3)]))[:, 0]
    slice_normal = (axis[1:] - axis[0]) / np.linalg.norm(axis[1:] - axis[0])
    across = np.cos(np.radians(DEPTH_STEP_MODEL_DEG))

    def on_slices(k, at, level, inside, outside, edge_normal):
        """The crossing near ``at`` on ray ``k`` by the blurred-step model from the two slices either side, where
        the edge (its surface's ``edge_normal``) also faces the slices; an edge oblique to the ray spreads along it
        by 1 / cos of the angle between them."""
        if abs(float(edge_normal @ slice_normal)) < across:
            return at
        cos = abs(float(edge_normal @ normal[k]))
        kc = float(np.interp(at, s, k_index[k]))
        si = at + (np.array([np.floor(kc), np.floor(kc) + 1.0]) - kc) / dk[k]
        got = step_crossing(si, np.interp(si, s, prof[k]), level, inside, outside, spread / cos)
        return at if got is None or abs(got - at) > slice_mm else got

    out: dict[str, DepthOnCT] = {}
    for k, name in enumerate(names):
        v = prof[k]
        mesh_d = float(mesh_depth[k])
        exits = crossings(v, bone_level)
        near = exits[np.abs(exits) <= search]
        if not len(near):
            out[name] = DepthOnCT(base[k], mesh_d, mesh_d, normal[k], False,
                                  f"no crossing of the bone level {bone_level:g} within {search:.1f} mm of the bone "
                                  f"mesh along the ray (the profile peaks at {v[np.abs(s) <= search].max():.0f}): "
                                  "bone thinner than the voxels, hidden by partial volume")
            continue
        sb = float(near[np.argmin(np.abs(near))])
        point = base[k] + sb * normal[k]
        skins = crossings(v, skin_level)
        skins = skins[skins > sb]
        if not len(skins) or skins[0] - sb > max_depth_mm:
            out[name] = DepthOnCT(point, float("nan"), mesh_d, normal[k], False,
                                  f"the ray meets no skin within {max_depth_mm:g} mm of the bone")
            continue
        ss = float(skins[0])
        holder = False
        if mask_prof is not None:
            edge = crossings(mask_prof[k], 0.5)
            edge = edge[edge > sb]
            voxel = float(max(ct.spacing))
            if len(edge) and ss > edge[0] + voxel:   # the skin level runs on into a pillow or a holder
                holder = True
                ss = sb + mesh_d if np.isfinite(mesh_d) and abs(sb + mesh_d - edge[0]) <= voxel else float(edge[0])
        inside = (s <= sb) & (s > sb - DEPTH_PLATEAU_MM)
        if bone_mode is not None and inside.any():
            peak = float(v[inside].max())
            need = bone_level + DEPTH_PLATEAU_FRACTION * (bone_mode - bone_level)
            if peak < need:
                out[name] = DepthOnCT(point, ss - sb, mesh_d, normal[k], False,
                                      f"the bone along the ray peaks at {peak:.0f} within {DEPTH_PLATEAU_MM:g} mm, "
                                      f"below {need:.0f} ({DEPTH_PLATEAU_FRACTION:.0%} of the way from the bone level "
                                      f"{bone_level:g} to the bone mode {bone_mode:g}): bone thinner than the slices' "
                                      "blur, partial volume moves its surface")
                continue
        between = (s > sb + step) & (s < ss)
        again = float(np.count_nonzero(v[between] >= bone_level) * step)
        if again > DEPTH_BONE_IN_FRONT_MM:
            first = float(s[between][np.argmax(v[between] >= bone_level)] - sb)
            out[name] = DepthOnCT(point, ss - sb, mesh_d, normal[k], False,
                                  f"the ray meets {again:.1f} mm of bone {first:.1f} mm in front of the bone point "
                                  "before the skin: the landmark lies behind other bone along its normal")
            continue
        why = between_slices(k, sb, bone_level, "bone") or ("" if holder else between_slices(k, ss, skin_level, "skin"))
        if spread and steep[k]:
            # across the slices: each edge lies between two slices a spacing apart, and the linear crossing moves
            # with the edge's place between them (up to 0.15 of a spacing for the slices' own spread): the
            # blurred-step model of the slices locates it
            if bone_mode is not None:
                sb = on_slices(k, sb, bone_level, max(float(bone_mode), float(v[inside].max()) if inside.any() else -np.inf),
                               tissue,
                               bone_normal[k])
                point = base[k] + sb * normal[k]
            if not holder:
                ss = on_slices(k, ss, skin_level, tissue, AIR_HU,
                               snap_to_surface(base[k] + ss * normal[k], skin)[1][0])
        out[name] = DepthOnCT(point, ss - sb, mesh_d, normal[k], not why, why)
    return out


def depth_levels(skull_seg) -> dict:
    """The levels of :func:`landmark_depths_on_ct` in the units of ``skull_seg.hu`` (a
    :class:`~.skull.SkullSegmentation`): the bone level the mask was made at, the bone mode (None when the
    histogram had none) and the skin level half way between air (-1000 HU) and the soft-tissue mode
    (``skull_seg.c2``)."""
    hist = skull_seg.meta.get("histogram") or {}
    mode = hist.get("bone_mode")
    return {"bone_level": float(skull_seg.bone_level), "bone_mode": None if mode is None else float(mode),
            "skin_level": 0.5 * (-1000.0 + float(skull_seg.c2))}


def measure_landmark_depths(landmarks: dict[str, np.ndarray], skull: Mesh, skin: Mesh | None, skull_seg=None,
                            head_mask: np.ndarray | None = None,
                            max_depth_mm: float = 60.0) -> dict[str, DepthOnCT]:
    """The landmark depths every output writes (the batch's landmarks.csv, the add-on's Export Landmark Depths
    and Export for Printing): on the CT's intensities (:func:`landmark_depths_on_ct`, levels from
    :func:`depth_levels`) when ``skull_seg`` carries them and the CT shows soft tissue; otherwise on the meshes
    (:func:`landmark_depths`), each result's ``method`` ``"mesh"`` and its ``evidence`` saying why.
    Without a skin the depths are NaN (the bone point is the landmark snapped onto ``skull``)."""
    names = list(landmarks)
    if not names:
        return {}
    why = ""
    if skin is None:
        why = "no skin: depths not measured"
    elif skull_seg is None or getattr(skull_seg, "hu", None) is None or getattr(skull_seg, "ct", None) is None:
        why = "no CT intensities: depths measured on the meshes"
    elif not skull_seg.meta.get("has_skin", True):
        why = "the CT shows no soft tissue: depths measured on the meshes"
    if not why:
        return landmark_depths_on_ct(landmarks, skull, skin, skull_seg.hu, skull_seg.ct, head_mask=head_mask,
                                     max_depth_mm=max_depth_mm, **depth_levels(skull_seg))
    base, normal, depth = _depth_rays(landmarks, skull, skin, max_depth_mm)
    return {n: DepthOnCT(base[i], float(depth[i]), float(depth[i]), normal[i], True, why, "mesh")
            for i, n in enumerate(names)}


def depth_flags(flags: dict[str, str], measured: dict[str, DepthOnCT]) -> dict[str, str]:
    """The landmarks' flags with every ``ok`` landmark whose depth the CT's profile does not support
    (``trusted`` False) turned ``uncertain``; landmarks without a flag count as ``ok``."""
    out = dict(flags)
    for name, m in measured.items():
        if not m.trusted and out.get(name, "ok") == "ok":
            out[name] = "uncertain"
    return out


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
    from scipy.spatial import cKDTree

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
