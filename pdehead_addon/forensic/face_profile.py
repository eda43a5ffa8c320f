"""The face's grid and the bone's closed outer profile on it: where the face from the skull starts.

The face is made on a cylinder of directions about the vertical (patient z) axis through the skull's centroid
(:class:`FaceGrid`: a row every ``row_mm`` of height, a column every ``360 / columns`` degrees). On it:
:func:`bone_profile` is the bone's outermost radius per bin, closed per row by its 2-D convex hull (which
bridges the orbits, the nasal aperture, the temporal fossae and the cheeks), a grey closing and a Gaussian
over the surface (:func:`surface_smooth`, a length in mm both ways), continued below the skull by a neck rule;
:func:`smooth_far_from_pegs` can smooth it more away from the pegs (off by default); :func:`peg_normals` gives
each landmark's outward direction (the bone's averaged normal, or the closed profile's where the bone's leans too
far). :mod:`.face_from_skull` stands the pegs and the depth field on this profile.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, cKDTree

from ..core.mesh import Mesh
from .face_envelope import envelope_radius
from .face_neck import neck_fill, neck_slope

#: The bone's radius map is made on at most this many columns (2 degrees) and interpolated to the face's grid (finer
#: bins meet no bone vertex on a coarse skull mesh: GE 29 % within +-2.5 mm on 360 columns, 35 % on 180).
PROFILE_COLUMNS = 180
#: Closing of the bone's radius map: how wide a gap (mm) the envelope bridges (the orbit is ~ 40 mm wide,
#: the nasal aperture ~ 25 mm).
CLOSING_MM = 15.0
#: The closed profile made in 3-D (:func:`.face_envelope.envelope_radius`: the skull voxelised, closed by a ball of
#: :data:`ENVELOPE_CLOSING_MM`, its signed distance smoothed, read along the grid's rays) instead of row by row (each
#: row's 2-D convex hull, a grey closing over :data:`CLOSING_MM` of height). Smooth by construction (no row steps),
#: and better on GE, the phantom unchanged, but off: on CThead stripped at 1500 and at 1600 its faces land far apart,
#: which the robustness suite requires within 3 points. The cause is in the skull, not here: at 1500 CThead's skull
#: keeps the dental fillings' metal streaks in the cheeks' soft tissue, and the ball bridges them into the envelope
#: over the upper lip and cheeks (a size rule cannot tell them from GE's thin maxilla); see docs/benchmarks.md.
PROFILE_3D = False
#: The ball (mm, radius) closing the skull in 3-D (:data:`PROFILE_3D`): wide enough to bridge the orbit's opening
#: (~ 40 x 35 mm) and the nasal aperture (~ 25 mm); chosen on GE and the phantom (a 15 mm ball leaves the orbits open).
ENVELOPE_CLOSING_MM = 30.0
#: Radius (mm) over which the bone's normal at a landmark is averaged (:func:`peg_normals`).
PEG_NORMAL_RADIUS_MM = 8.0
#: A peg follows the averaged bone normal while it lies within the first angle (degrees) of the closed profile's
#: normal and the profile's beyond the second (e.g. subspinale on a mask whose thin maxilla is gone faces up, not
#: forward), blended between. A blend, not a switch at 45 degrees: a switch turned GE's pegs by 15-50 degrees for bases
#: moved by ~1 mm when it was stripped at 250 HU (its tips by up to 7 mm); 45 +- 10 so that a turn of the bone normal by
#: a few degrees moves a tip by a fraction of a millimetre; measured on every suite row (docs/benchmarks.md).
PEG_NORMAL_BLEND_DEG = (35.0, 55.0)


def plate_coherence(thickness_mm: float, radius_mm: float = PEG_NORMAL_RADIUS_MM) -> float:
    """The coherence (the sum's length over the lengths' sum) of the area-weighted normals within ``radius_mm`` of a
    point on one face of a flat plate ``thickness_mm`` thick: the near face's disc (pi r^2) against the far face's
    (pi (r^2 - t^2)), t^2 / (2 r^2 - t^2); 1 for a plate at least as thick as the radius."""
    t, r = min(float(thickness_mm), float(radius_mm)), float(radius_mm)
    return t * t / (2.0 * r * r - t * t)


#: ... and the profile's where the bone's normals within the radius cancel: both faces of a thin bone lie in the
#: radius, and their sum is the small difference of two opposite sums, whose direction is noise (the rims, the holes,
#: the level). Given as the thickness of a flat plate with that coherence (:func:`plate_coherence`): the profile's
#: normal on a plate up to the first thickness (mm), the bone's from the second, blended between. At 1.6-2.5 mm (was:
#: coherence 0.02-0.05; the phantom's nasal bones, 0.00, turned its mid-nasal peg by 44 degrees under a 15-degree pitch)
#: CThead's rami (coherence 0.09-0.16) kept the bone's: Mid-ramus L's normal turned by 31 degrees between the strips at
#: 1500 and at its automatic level and pointed 48 degrees below the horizontal into the neck at 1600, and the two
#: strips' faces lay 7.0 points apart. Chosen on CThead's strip levels' agreement (a check, not its score, which the
#: change lowers), checked on GE and the phantom (docs/benchmarks.md).
PEG_NORMAL_PLATE_MM = (4.0, 5.0)
PEG_NORMAL_COHERENCE = tuple(plate_coherence(t) for t in PEG_NORMAL_PLATE_MM)
#: Smoothing of the closed profile over the surface (:func:`surface_smooth`): a Gaussian of PROFILE_SMOOTH_MM along the
#: height and PROFILE_SMOOTH_ARC_MM of arc around the head (mm both, not rows or degrees). Each row's hull is made on
#: its own, and rows a few mm apart step (the teeth, the zygomatic arches' edges); a skin does not. Chosen on GE and the
#: phantom, checked on CThead: GE 48.8 / 49.9 / 51.1 / 48.7 / 41.8 % within +-2.5 mm at 4 / 6 / 8 / 10 / 15 mm, the
#: phantom 42.0-43.4 % throughout; 6 and not GE's best 8 because at 8 mm CThead stripped at 1500 and at 1600 scored
#: 10 points apart (48.0 / 57.8 %; at 6 mm 51.8 / 54.5 %), which the robustness suite requires within 3 points.
PROFILE_SMOOTH_MM = 6.0
PROFILE_SMOOTH_ARC_MM = PROFILE_SMOOTH_MM
#: The closed profile's normals (:func:`envelope_normals`) are smoothed this much around the head (degrees).
PROFILE_SMOOTH_DEG = 2.0
#: Away from the pegs the closed profile could be smoothed more (:func:`smooth_far_from_pegs`: a Gaussian of
#: :data:`PROFILE_SMOOTH_FAR_MM` of height and :data:`PROFILE_SMOOTH_FAR_ARC_MM` of arc, blended into the profile within
#: about :data:`PROFILE_NEAR_MM` of the peg tips). Off (0): its 8 mm had been chosen on CThead's score, and the
#: profile's smoothing over the surface (:data:`PROFILE_SMOOTH_MM`) does its work on any head.
PROFILE_SMOOTH_FAR_MM = 0.0
PROFILE_SMOOTH_FAR_ARC_MM = 2.0
PROFILE_NEAR_MM = 10.0
#: The bone floor (:func:`round_floor`) is rounded over the bone's bumps: a grey dilation of +- FLOOR_ROUND_MM (height
#: and arc), then a Gaussian of half that: the floor is never lower than the bone plus the least tissue, but it no
#: longer steps from row to row with the bone's edges (the maxilla beside the nasal aperture, the zygomas, the teeth),
#: which printed boxes and steps on the face wherever the floor held it up. The length is that of the cut's rounding
#: (:data:`CUT_FLOOR_SMOOTH_MM`, chosen on GE).
FLOOR_ROUND_MM = 3.0
#: The bone floor's recession under the bone (:func:`bone_floor`) is smoothed over this much height and angle: on
#: GE each column's maxilla ends at its own height, and the recession made vertical ridges 5-10 degrees apart.
FLOOR_SMOOTH_MM = 3.0
FLOOR_SMOOTH_DEG = 4.0


#: The scan's cut (:func:`scan_cut_plane`): a skull without a mandible is taken as cut by its scan along the
#: largest group of its convex hull's downward facets that tilt at most :data:`CUT_MAX_TILT_DEG` from horizontal
#: and lie within :data:`CUT_COPLANAR_DEG` of one another, when that group holds :data:`CUT_MIN_AREA_FRACTION` of the
#: hull's downward area. GE: 12,451 of 21,604 mm^2 (0.58), tilt 18.6 degrees (the series' gantry tilt: 18.5).
CUT_MAX_TILT_DEG = 35.0
CUT_COPLANAR_DEG = 5.0
CUT_MIN_AREA_FRACTION = 0.3
#: Where the scan cut the bone the bone floor is rounded (:func:`smooth_floor_near_cut`): up to CUT_BAND_MM above
#: the cut, faded out over CUT_BAND_FADE_MM more, by a grey dilation of +- CUT_FLOOR_SMOOTH_MM.
CUT_BAND_MM = 8.0
CUT_BAND_FADE_MM = 4.0
CUT_FLOOR_SMOOTH_MM = 3.0


@dataclass
class FaceGrid:
    """The face's grid: rows at heights ``z`` and columns at angles ``theta`` around the vertical axis
    through ``centre`` (patient mm, radians)."""
    centre: np.ndarray          # (2,) x, y of the vertical axis
    z: np.ndarray               # (K,) row heights, ascending
    theta: np.ndarray           # (M,) column angles; 0 = posterior (+y), pi/2 = patient's left (+x)

    def polar(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d = np.asarray(p, float)[..., :2] - self.centre
        theta = np.mod(np.arctan2(d[..., 0], d[..., 1]), 2 * np.pi)
        return np.asarray(p, float)[..., 2], theta, np.hypot(d[..., 0], d[..., 1])

    def point(self, z, theta, r) -> np.ndarray:
        z, theta, r = np.broadcast_arrays(np.asarray(z, float), np.asarray(theta, float), np.asarray(r, float))
        return np.stack([self.centre[0] + r * np.sin(theta), self.centre[1] + r * np.cos(theta), z], axis=-1)

    def sample(self, table: np.ndarray, z: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Bilinear value of a (K, M) map at heights ``z`` and angles ``theta`` (periodic in the angle)."""
        K, M = table.shape
        fz = np.clip((np.asarray(z, float) - self.z[0]) / (self.z[1] - self.z[0]), 0, K - 1 - 1e-9)
        ft = np.mod(np.asarray(theta, float), 2 * np.pi) / (2 * np.pi) * M
        k0, j0 = np.floor(fz).astype(int), np.floor(ft).astype(int) % M
        a, b = fz - k0, ft - np.floor(ft)
        j1 = (j0 + 1) % M
        k1 = np.minimum(k0 + 1, K - 1)
        return ((1 - a) * (1 - b) * table[k0, j0] + (1 - a) * b * table[k0, j1]
                + a * (1 - b) * table[k1, j0] + a * b * table[k1, j1])


def _columns(degrees: float, grid: "FaceGrid") -> float:
    """An angle in columns of the grid."""
    return float(np.radians(degrees) / (grid.theta[1] - grid.theta[0]))


def _resample_columns(table: np.ndarray, columns: int) -> np.ndarray:
    """A (K, M) map periodic in its columns, linearly interpolated to ``columns`` columns (NaN stays NaN)."""
    K, M = table.shape
    f = np.arange(columns) * (M / columns)
    j0 = np.floor(f).astype(int) % M
    a = f - np.floor(f)
    return (1 - a) * table[:, j0] + a * table[:, (j0 + 1) % M]


def bone_profile(skull: Mesh, grid: FaceGrid, base_z: float | None = None,
                 closing_mm: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The bone's outer radius per (row, column) bin and its closed envelope.

    1. per bin the outermost skull vertex (NaN where the ray meets no bone);
    2. gaps inside a column are interpolated along the height; below ``base_z`` (the skull base) the neck
       rule of :func:`.face_neck.neck_fill`;
    3. per row the 2-D convex hull of the ring: the envelope a skin stretched over the bone would take
       across the orbits, the nasal aperture, the temporal fossae and the cheeks (between the zygoma and
       the mandible), where no depth is measured;
    4. a grey closing over ``closing_mm`` of height (the vertical gaps, e.g. the nasal aperture above the
       maxilla) and a smoothing over the surface (:func:`surface_smooth`: :data:`PROFILE_SMOOTH_MM` of height and
       :data:`PROFILE_SMOOTH_ARC_MM` of arc).

    With :data:`PROFILE_3D` steps 2-4 are made on the skull's closed envelope in 3-D instead
    (:func:`.face_envelope.envelope_radius`, a ball of :data:`ENVELOPE_CLOSING_MM`), continued below the skull base by
    the same neck rule and smoothed over the surface the same way.

    Returns
    -------
    raw : (K, M) outermost bone radius per bin (NaN where the bin meets no bone)
    closed : (K, M) the closed, gap-filled, smoothed profile (no NaN)
    """
    closing_mm = CLOSING_MM if closing_mm is None else float(closing_mm)
    M_face = len(grid.theta)
    if M_face > PROFILE_COLUMNS:                 # the bone's map on the coarser grid, then interpolated (see there)
        coarse = FaceGrid(grid.centre, grid.z, np.arange(PROFILE_COLUMNS) * 2 * np.pi / PROFILE_COLUMNS)
        raw_c, sm_c = bone_profile(skull, coarse, base_z, closing_mm)
        return _resample_columns(raw_c, M_face), _resample_columns(sm_c, M_face)
    dz = grid.z[1] - grid.z[0]
    raw = outermost_bone(skull, grid)
    raw[~np.isfinite(raw)] = np.nan
    if PROFILE_3D:
        closed = neck_fill(envelope_radius(skull, grid, ENVELOPE_CLOSING_MM), grid, base_z)
    else:
        filled = neck_fill(raw, grid, base_z)
        hull = _row_hulls(filled, grid.theta)
        kz = max(1, int(round(closing_mm / dz)))
        pad = kz
        padded = np.pad(hull, ((pad, pad), (0, 0)), mode="edge")
        closed = ndimage.grey_closing(padded, size=(kz, 1), mode="wrap")[pad:-pad]
        closed = np.maximum(closed, hull)
    sm = surface_smooth(closed, grid, PROFILE_SMOOTH_MM, arc_mm=PROFILE_SMOOTH_ARC_MM)
    return raw, sm


def surface_smooth(radius: np.ndarray, grid: FaceGrid, length_mm: float, rho: np.ndarray | float | None = None,
                   periodic: bool = True, arc_mm: float | None = None) -> np.ndarray:
    """A (K, M) map on ``grid`` smoothed over the surface it describes: a Gaussian of ``length_mm`` along the height and
    the same around the head, in arc at each row's radius ``rho`` (per row or one value; default each row's median of
    ``radius``, the map being a radius), so millimetres and not degrees or rows set it; the rows beyond the map's
    ends continued by its edge rows; ``periodic``: the columns go round the head (else an open run of columns).

    Why a length over the surface: each row of the bone's profile (its convex hull in horizontal section) is made on
    its own, so the rows step where a row meets or leaves a bone feature (a zygomatic arch, the teeth, the mandible's
    angle), and a smoothing along the rows' height alone in rows, or around in degrees, leaves a coarser wave in the
    other direction: the face took horizontal waves across the cheeks."""
    radius = np.asarray(radius, float)
    if length_mm <= 0:
        return radius
    dz = float(grid.z[1] - grid.z[0])
    dth = float(grid.theta[1] - grid.theta[0])
    pad = max(1, int(np.ceil(4.0 * length_mm / dz)))
    padded = np.pad(radius, ((pad, pad), (0, 0)), mode="edge")
    out = ndimage.gaussian_filter1d(padded, length_mm / dz, axis=0, mode="nearest")[pad:-pad]
    if rho is None:
        rho = np.median(out, axis=1)
    rho = np.broadcast_to(np.maximum(np.asarray(rho, float), 5.0), (radius.shape[0],))
    sig_cols = (length_mm if arc_mm is None else arc_mm) / (rho * dth)
    # rows grouped by their width in columns (to 5 %): the filter runs a few times, not once per row
    keys = np.round(np.log(sig_cols) / np.log(1.05)).astype(int)
    res = np.empty_like(out)
    for key in np.unique(keys):
        rows = keys == key
        res[rows] = ndimage.gaussian_filter1d(out[rows], float(1.05 ** key), axis=1,
                                              mode="wrap" if periodic else "nearest")
    return res


def outermost_bone(skull: Mesh, grid: FaceGrid) -> np.ndarray:
    """(K, M) per bin of ``grid`` (each skull vertex in the row and the column nearest to it) the radius of the
    outermost skull vertex; -inf where no vertex falls (and for the vertices above the top row or below the
    bottom one, which no row holds)."""
    z, th, r = grid.polar(skull.vertices)
    dz = grid.z[1] - grid.z[0]
    K, M = len(grid.z), len(grid.theta)
    k = np.round((z - grid.z[0]) / dz).astype(int)
    j = np.round(th / (2 * np.pi) * M).astype(int) % M
    ok = (k >= 0) & (k < K)
    raw = np.full(K * M, -np.inf)
    np.maximum.at(raw, k[ok] * M + j[ok], r[ok])
    return raw.reshape(K, M)


def bone_floor(skull: Mesh, grid: FaceGrid, min_tissue_mm: float) -> np.ndarray:
    """(K, M) the least radius the face may have in each bin of ``grid``: the outermost skull vertex in the bin
    and the columns on either side (:func:`outermost_bone`), plus ``min_tissue_mm``; below the bone, receding
    no faster than the neck (:func:`.face_neck.neck_slope` mm per mm of height); 0 where no bone is above.

    Why: the closed profile's smoothing lowers the bone's peaks (the maxilla's front, the zygomas) and the depth
    field may go below zero between the pegs, so without a floor the face cut through the bone (GE's maxilla:
    495-509 skull vertices outside the face, by up to 3.5 mm). The columns on either side: a vertex between two
    columns lies under the face between them. Not the rows above and below: on the crown, where the radius
    falls steeply with the height, the row below's bone pushed the face out by up to 6 mm (GE); a vertex
    between two rows is covered by ``min_tissue_mm`` (GE, CThead and the phantom: no vertex outside). The
    recession under the bone: where the bone ends (GE's maxilla cut by the scan) the face would step in by
    the whole floor within one row, a ragged shelf along the bone's cut edge.
    """
    near = ndimage.maximum_filter(outermost_bone(skull, grid), size=(1, 3), mode=("nearest", "wrap"))
    floor = np.where(np.isfinite(near), near + float(min_tissue_mm), 0.0)
    dz = float(grid.z[1] - grid.z[0])
    receding = floor.copy()
    recede = neck_slope(grid.theta) * dz
    for k in range(len(grid.z) - 2, -1, -1):                 # downward: per row, vectorised over the columns
        np.maximum(receding[k], receding[k + 1] - recede, out=receding[k])
    # the recession smoothed (each column's bone ends at its own height: unsmoothed, vertical ridges); only
    # the cosmetic recession is smoothed, the bone's own floor is kept as it is (the guarantee)
    receding = ndimage.gaussian_filter(receding, sigma=(FLOOR_SMOOTH_MM / dz, _columns(FLOOR_SMOOTH_DEG, grid)),
                                       mode=("nearest", "wrap"))
    return np.maximum(floor, receding)


#: The cheeks' least tissue (:func:`cheek_floor`) is faded in over this much height (mm) and angle (degrees) at the
#: band's edges, so the floor does not step: the skin's own smoothing length (:data:`.face_skin.FACE_SMOOTH_MM`, 11
#: mm; 7 degrees is 11 mm of arc at a face's ~90 mm radius). At 5 mm / 5 degrees the band's top edge, on the
#: infraorbital margin, stood as a bar under each eye (CThead 1500: the face's curvature down the cheek under the
#: eyes, 95th percentile, 0.133 -> 0.106 per mm at 11 mm; scores within 0.3 points, docs/benchmarks.md).
CHEEK_FLOOR_RAMP_MM = 11.0
CHEEK_FLOOR_RAMP_DEG = 7.0


def cheek_floor(skull: Mesh, grid: FaceGrid, bands: list[tuple[float, float, float, float]], depth_mm: float,
                min_tissue_mm: float) -> np.ndarray | None:
    """(K, M) the least radius of the cheeks: the outermost bone (as :func:`bone_floor`) plus ``depth_mm`` inside each
    band ``(z_low, z_high, theta_a, theta_b)`` (heights in mm, the angles of its two sides in radians, the shorter
    arc between them), ``min_tissue_mm`` outside, the change faded over :data:`CHEEK_FLOOR_RAMP_MM` /
    :data:`CHEEK_FLOOR_RAMP_DEG`; None without a band.

    Why: between the infraorbital margin, the zygion and the jaw, where the T-Table stands few pegs, the depth field
    may dip toward the closed bone profile (the canine fossa, the maxilla cut by a scan ending at the teeth), while
    every published depth there (infraorbital, zygomatic, the jaw's) is larger: the skin over the cheek stands at
    least the smallest of the pegs' means around it."""
    if not bands:
        return None
    near = ndimage.maximum_filter(outermost_bone(skull, grid), size=(1, 3), mode=("nearest", "wrap"))
    w = np.zeros(near.shape)
    rz, rt = max(CHEEK_FLOOR_RAMP_MM, 1e-6), np.radians(max(CHEEK_FLOOR_RAMP_DEG, 1e-6))
    for z0, z1, ta, tb in bands:
        wz = np.clip((grid.z - z0) / rz + 0.5, 0, 1) * np.clip((z1 - grid.z) / rz + 0.5, 0, 1)
        mid = np.angle(np.exp(1j * 0.5 * (ta + tb))) if abs(np.angle(np.exp(1j * (tb - ta)))) < np.pi else ta
        half = 0.5 * abs(np.angle(np.exp(1j * (tb - ta))))
        off = np.abs(np.angle(np.exp(1j * (grid.theta - mid))))
        wt = np.clip((half - off) / rt + 0.5, 0, 1)
        w = np.maximum(w, np.outer(wz, wt))
    extra = w * max(float(depth_mm) - float(min_tissue_mm), 0.0)
    return np.where(np.isfinite(near), near + float(min_tissue_mm) + extra, 0.0)


def scan_cut_plane(skull: Mesh, max_tilt_deg: float = CUT_MAX_TILT_DEG) -> tuple[np.ndarray, float] | None:
    """The plane along which the scan's lower edge cut a skull without a mandible, or None.

    A CT slab that stops above the chin cuts the skull along its lowest slice: GE's gantry-tilted slab
    (18.5 degrees) cuts it from the skull base at the back to the orbits' floor at the front. The cut is the
    skull's lowest support plane: the largest group of downward-facing, coplanar (within
    :data:`CUT_COPLANAR_DEG`) facets of the skull's convex hull; a skull without a mandible that no scan cut
    (a dry skull) gives the plane it stands on (its teeth, its occipital condyles and its mastoids).

    Returns
    -------
    (normal, offset) : the plane ``normal . p = offset`` (patient mm), the unit normal pointing down and
        out of the skull, ``offset`` the largest ``normal . v`` of the skull's vertices (every vertex on or
        above the plane); None when no such group covers :data:`CUT_MIN_AREA_FRACTION` of the hull's
        downward area or it tilts more than ``max_tilt_deg`` from horizontal.
    """
    v = np.asarray(skull.vertices, float)
    try:
        hull = ConvexHull(v)
    except Exception:                                           # degenerate (flat) vertex set: no plane
        return None
    n = hull.equations[:, :3]
    tri = v[hull.simplices]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    down = n[:, 2] < -np.cos(np.radians(max_tilt_deg))
    if not down.any():
        return None
    seed = int(np.argmax(np.where(down, area, 0.0)))
    group = down & (n @ n[seed] > np.cos(np.radians(CUT_COPLANAR_DEG)))
    if area[group].sum() < CUT_MIN_AREA_FRACTION * area[n[:, 2] < 0].sum():
        return None
    normal = (n[group] * area[group, None]).sum(axis=0)
    normal /= np.linalg.norm(normal)
    if -normal[2] < np.cos(np.radians(max_tilt_deg)):
        return None
    return normal, float((v @ normal).max())


def height_above_plane(grid: FaceGrid, radius: np.ndarray, plane: tuple[np.ndarray, float]) -> np.ndarray:
    """(K, M) how far each bin of ``grid`` at ``radius`` lies above ``plane`` (``normal . p = offset``, the normal
    pointing down: :func:`scan_cut_plane`), measured along the height."""
    normal, offset = plane
    x = grid.centre[0] + radius * np.sin(grid.theta)
    y = grid.centre[1] + radius * np.cos(grid.theta)
    return grid.z[:, None] - (float(offset) - normal[0] * x - normal[1] * y) / normal[2]


def round_floor(floor: np.ndarray, grid: FaceGrid, radius: np.ndarray, length_mm: float = FLOOR_ROUND_MM) -> np.ndarray:
    """The bone floor rounded over ``length_mm``: its grey dilation over +- ``length_mm`` of height and of arc (at the
    median ``radius``), Gaussian-smoothed by half that, never below ``floor`` (the guarantee that no bone comes
    through the face is kept: where the rounded mound would dip below the floor the floor wins).

    Why: the floor is the outermost bone per bin plus the least tissue, so it steps wherever a row meets a bone edge
    (the maxilla beside the nasal aperture, the zygomas, the teeth), and the face held up by it took those steps
    (boxes beside the nose, ridges across the cheeks). A skin over a bone bump is a rounded mound."""
    if length_mm <= 0:
        return floor
    dz, per_col = row_and_column_mm(grid, radius)
    hz = max(1, round(length_mm / dz))
    ht = max(1, round(length_mm / per_col))
    return np.maximum(floor, _mound(floor, (hz, ht), (0.5 * length_mm / dz, 0.5 * length_mm / per_col)))


def row_and_column_mm(grid: FaceGrid, radius: np.ndarray) -> tuple[float, float]:
    """The grid's row step and its column step in arc at the median ``radius`` (mm)."""
    return float(grid.z[1] - grid.z[0]), float(np.median(radius)) * float(grid.theta[1] - grid.theta[0])


def _mound(floor: np.ndarray, half_sizes: tuple[int, int], sigmas: tuple[float, float]) -> np.ndarray:
    """``floor``'s grey dilation over +- ``half_sizes`` (rows, columns), then a Gaussian of ``sigmas``: every bone
    peak covered by a rounded mound (rows continued at the ends, columns round the head)."""
    hz, ht = half_sizes
    dilated = ndimage.grey_dilation(floor, size=(2 * hz + 1, 2 * ht + 1), mode=("nearest", "wrap"))
    return ndimage.gaussian_filter(dilated, sigma=sigmas, mode=("nearest", "wrap"))


def smooth_floor_near_cut(floor: np.ndarray, grid: FaceGrid, plane: tuple[np.ndarray, float],
                          radius: np.ndarray) -> np.ndarray:
    """The bone floor (:func:`bone_floor`) rounded where the scan cut the bone: within :data:`CUT_BAND_MM` above
    the cut (faded out over :data:`CUT_BAND_FADE_MM`) and below it, the floor's grey dilation over
    +- :data:`CUT_FLOOR_SMOOTH_MM` (height and arc), Gaussian-smoothed by half that; never below the floor.

    Why: a cut bone's edge is ragged (the maxilla's and the zygomas' walls and the sinuses opened by the cut),
    the face's rows there stand on it (the closed profile recedes where the rows run out of bone), and the
    face took its lumps (GE: 57 % of the front bins within 5 mm above the cut held up by the floor, by up to
    12 mm). Dilation, then a Gaussian of half its width, covers every bone peak (the max with the floor keeps
    the guarantee where it would not) with a rounded mound.
    """
    dz, per_col = row_and_column_mm(grid, radius)
    hz = max(1, int(round(CUT_FLOOR_SMOOTH_MM / dz)))
    ht = max(1, int(round(CUT_FLOOR_SMOOTH_MM / per_col)))
    rounded = _mound(floor, (hz, ht), (0.5 * hz, 0.5 * ht))
    above = height_above_plane(grid, radius, plane)
    w = np.clip((CUT_BAND_MM + CUT_BAND_FADE_MM - above) / CUT_BAND_FADE_MM, 0.0, 1.0)
    return np.maximum(floor, floor + w * (rounded - floor))


def tilted_rows(grid: FaceGrid, radius: np.ndarray, plane: tuple[np.ndarray, float],
                margin_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The face's rows re-spaced per column so that the lowest one lies on the scan's cut (:func:`scan_cut_plane`)
    lowered by ``margin_mm`` along its normal; the top row stays where it is.

    Each column's rows are spread evenly (linearly in the height) from the height where the column's own
    profile ``radius`` meets the lowered plane up to the top row; their radius is the column's, interpolated
    (Catmull-Rom) at those heights. Why: a skull cut obliquely by its scan (GE) ends 30-50 mm higher at the
    front than at the back, and a face ending on one horizontal row hung a flat apron below the maxilla with
    no bone behind it; this one ends along the scan's own cut, as the scanned skin does.

    Returns
    -------
    z : (K, M) the rows' heights per column; r : (K, M) the face's radius there.
    """
    z0, dz = float(grid.z[0]), float(grid.z[1] - grid.z[0])
    K = len(grid.z)
    # per bin the height above the lowered plane; the cut is where a column crosses it, the lowest crossing
    # from below (vectorised over the whole map)
    f = height_above_plane(grid, radius, (plane[0], float(plane[1]) + float(margin_mm)))
    above = f >= 0
    first = np.where(above.any(axis=0), np.argmax(above, axis=0), 0)
    k1 = np.maximum(first, 1)
    cols = np.arange(len(grid.theta))
    fa, fb = f[k1 - 1, cols], f[k1, cols]
    t = np.where(first > 0, np.clip(fa / np.where(fa != fb, fa - fb, 1.0), 0.0, 1.0), 0.0)
    cut = np.where(first > 0, grid.z[k1 - 1] + t * dz, z0)
    top = float(grid.z[-1])
    frac = (grid.z[:, None] - z0) / (top - z0)
    z = cut[None, :] + frac * (top - cut[None, :])
    # Catmull-Rom along each column at the fractional rows
    fk = np.clip((z - z0) / dz, 0.0, K - 1.0)
    k = np.clip(np.floor(fk).astype(int), 0, K - 2)
    u = fk - k
    rows = [np.clip(k + d, 0, K - 1) for d in (-1, 0, 1, 2)]
    p0, p1, p2, p3 = (radius[r, cols[None, :]] for r in rows)
    r = 0.5 * ((2 * p1) + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u ** 2
               + (-p0 + 3 * p1 - 3 * p2 + p3) * u ** 3)
    return z, r


def smooth_max(a: np.ndarray, b: np.ndarray, width: float) -> np.ndarray:
    """max(a, b) with its corner rounded over ``width`` (a quadratic blend); never below max(a, b)."""
    h = np.clip(0.5 + 0.5 * (a - b) / width, 0.0, 1.0)
    return b + (a - b) * h + width * h * (1.0 - h)


def smooth_min(a: np.ndarray, b: np.ndarray, width: float) -> np.ndarray:
    """min(a, b) with its corner rounded over ``width``; never above min(a, b)."""
    return -smooth_max(-np.asarray(a), -np.asarray(b), width)


def smooth_far_from_pegs(profile: np.ndarray, grid: FaceGrid, sites: np.ndarray) -> np.ndarray:
    """The closed profile smoothed in 2-D (:data:`PROFILE_SMOOTH_FAR_MM` of height,
    :data:`PROFILE_SMOOTH_FAR_ARC_MM` of arc) where no peg stands, blended into the lightly smoothed one
    within ~ :data:`PROFILE_NEAR_MM` of the peg tips (weight: the largest Gaussian of the distance on the
    cylinder of the median radius). Computed once in :meth:`FaceModel.prepare` (at the table's depths), so
    solve() is unchanged."""
    if PROFILE_SMOOTH_FAR_MM <= 0:
        return profile
    dz = float(grid.z[1] - grid.z[0])
    dth = float(grid.theta[1] - grid.theta[0])
    rho = float(np.median(profile))
    sig = (PROFILE_SMOOTH_FAR_MM / dz, PROFILE_SMOOTH_FAR_ARC_MM / (rho * dth))
    strong = ndimage.gaussian_filter(profile, sigma=sig, mode=("nearest", "wrap"))
    z, th, _ = grid.polar(sites)
    dzs = grid.z[:, None, None] - z[None, None, :]
    dts = np.angle(np.exp(1j * (grid.theta[None, :, None] - th[None, None, :]))) * rho
    near = np.exp(-(dzs ** 2 + dts ** 2) / (2 * PROFILE_NEAR_MM ** 2)).max(axis=2)
    return near * profile + (1 - near) * strong


def convex_rows(radius: np.ndarray, dtheta: float, span: int, passes: int = 2) -> np.ndarray:
    """Each row of ``radius`` (rows x columns, columns ``dtheta`` radians apart, an open run of columns) lifted to
    the chords between its columns up to ``span`` columns apart: the chord between the columns j - s and j + s meets
    the ray j at 2 r_a r_b cos(s dtheta) / (r_a + r_b). ``passes`` sweeps over s = 1 .. span approximate the rows'
    convex envelope within that span (vectorised: a few ms where a 2-D hull per row costs ~10 ms a row). The
    ``span`` columns at each end of the run are kept (they have no chord on one side)."""
    r = np.array(radius, float, copy=True)
    n = r.shape[1]
    if span < 1 or n <= 2 * span:
        return r
    mid = r[:, span:n - span]                                  # a view: updated in place
    for _ in range(passes):
        for s in range(1, span + 1):
            a, b = r[:, span - s:n - span - s], r[:, span + s:n - span + s]
            np.maximum(mid, 2.0 * np.cos(s * dtheta) * a * b / (a + b), out=mid)
    return r


def _row_hulls(radius: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Per row, the radius along each column's ray of the 2-D convex hull of the row's ring."""
    out = radius.copy()
    s, c = np.sin(theta), np.cos(theta)
    for k in range(radius.shape[0]):
        xy = np.column_stack([radius[k] * s, radius[k] * c])
        try:
            idx = ConvexHull(xy).vertices
        except Exception:                                     # degenerate row: keep it
            continue
        idx = np.sort(idx)                                    # hull vertices in angle order (rays are ordered)
        # between consecutive hull vertices a and b, a ray at angle t meets the chord a-b
        nxt = np.roll(idx, -1)
        for a, b in zip(idx, nxt):
            span = (np.arange(a, b + (len(theta) if b <= a else 0) + 1)) % len(theta)
            pa, pb = xy[a], xy[b]
            d = np.column_stack([s[span], c[span]])
            e = pb - pa
            # solve t * d = pa + u * e  ->  t = cross(pa, e) / cross(d, e)
            den = d[:, 0] * e[1] - d[:, 1] * e[0]
            num = pa[0] * e[1] - pa[1] * e[0]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(np.abs(den) > 1e-12, num / den, radius[k, span])
            out[k, span] = np.maximum(radius[k, span], np.where(np.isfinite(t) & (t > 0), t, radius[k, span]))
    return out


def envelope_normals(grid: FaceGrid, profile: np.ndarray, points: np.ndarray, smooth_mm: float = 6.0) -> np.ndarray:
    """Outward unit normals of the closed profile (the surface r = profile(z, angle)) at the points' bins."""
    dz = grid.z[1] - grid.z[0]
    R = ndimage.gaussian_filter(profile, sigma=(smooth_mm / dz, _columns(PROFILE_SMOOTH_DEG, grid)),
                                mode=("nearest", "wrap"))
    Rz = np.gradient(R, dz, axis=0)
    dth = grid.theta[1] - grid.theta[0]
    Rt = (np.roll(R, -1, axis=1) - np.roll(R, 1, axis=1)) / (2 * dth)
    z, th, _ = grid.polar(points)
    r, rz, rt = grid.sample(R, z, th), grid.sample(Rz, z, th), grid.sample(Rt, z, th)
    s, c = np.sin(th), np.cos(th)
    d_th = np.stack([rt * s + r * c, rt * c - r * s, np.zeros_like(r)], -1)
    d_z = np.stack([rz * s, rz * c, np.ones_like(r)], -1)
    n = np.cross(d_th, d_z)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    radial = np.stack([s, c, np.zeros_like(s)], -1)
    return np.where((np.einsum("ij,ij->i", n, radial) < 0)[:, None], -n, n)


def peg_normals(skull: Mesh, bases: np.ndarray, grid: FaceGrid, profile: np.ndarray,
                radius_mm: float = PEG_NORMAL_RADIUS_MM) -> np.ndarray:
    """The direction each peg stands in: the bone's outward normal at the landmark, averaged over the bone
    surface within ``radius_mm`` (area-weighted; a single triangle's normal on a thin or fragmentary bone,
    e.g. the maxilla at the bone level, points anywhere); where that still leans away from the closed profile's
    outward normal, turned towards the profile's: the bone's within the first angle of
    :data:`PEG_NORMAL_BLEND_DEG`, the profile's beyond the second, blended linearly in the angle between (not above
    the profile's last row, where its normal means nothing: the vertex keeps the bone's).
    The T-Table's convention is a depth measured along the bone normal at the landmark."""
    v, t = skull.vertices, skull.triangles
    if len(skull.quads):
        t = np.concatenate([t, skull.quads[:, [0, 1, 2]], skull.quads[:, [0, 2, 3]]])
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    fn = np.cross(b - a, c - a)                                    # area-weighted (|fn| = 2 area)
    tree = cKDTree((a + b + c) / 3.0)
    env = envelope_normals(grid, profile, bases)
    bone = np.empty_like(bases)
    coherence = np.zeros(len(bases))
    for i, idx in enumerate(tree.query_ball_point(bases, radius_mm)):   # a few dozen pegs, not vertices
        n = fn[idx].sum(axis=0) if idx else env[i]
        norm = np.linalg.norm(n)
        bone[i] = n / norm if norm > 0 else env[i]
        coherence[i] = norm / max(float(np.linalg.norm(fn[idx], axis=1).sum()), 1e-12) if idx else 0.0
    lean = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", bone, env), -1.0, 1.0)))
    lo, hi = PEG_NORMAL_BLEND_DEG
    c_lo, c_hi = PEG_NORMAL_COHERENCE
    w = np.maximum(np.clip((lean - lo) / (hi - lo), 0.0, 1.0),            # 0: the bone's, 1: the profile's
                   np.clip((c_hi - coherence) / (c_hi - c_lo), 0.0, 1.0))[:, None]
    # above the last row (vertex) the profile's normal is meaningless (the rows' radius near the axis): the bone's
    w[bases[:, 2] > grid.z[-1]] = 0.0
    out = (1.0 - w) * bone + w * env
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.where(norm > 1e-9, out / np.maximum(norm, 1e-9), env)
