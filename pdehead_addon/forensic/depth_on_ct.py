"""Landmark tissue depths measured on the CT's intensities: the bone and skin points at the level crossings of the
interpolated CT along each landmark's ray (:func:`landmark_depths_on_ct`), whether the profile along the ray supports
the depth, and :func:`measure_landmark_depths`, the one entry every depth output uses (the CT's when the study has
one, else the meshes' of :func:`~pdehead_addon.forensic.landmarks.landmark_depths`, with the method recorded).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi
from scipy.special import ndtri

from ..core.errors import PDEHeadError
from ..core.mesh import Mesh
from .landmarks import depth_rays, snap_to_surface

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
#: A depth is plausible only where the ray meets the skin within this many times the distance from the bone point
#: to the nearest skin (a ray that runs along the face, past a nose or a cheek, measures the face, not the depth);
DEPTH_NEAREST_SKIN_FACTOR = 1.5
#: ... not within this many voxels of the scan's edge (the first or last slice, the field of view, a tilted slab's
#: border: the skin there is where the scan stops) ...
DEPTH_EDGE_VOXELS = 2
#: ... and within the table's mean +- this many SD (:func:`measure_landmark_depths` with a table).
DEPTH_TABLE_SD = 3.0


@dataclass
class DepthOnCT:
    """A landmark's depth measured on the CT's intensities (:func:`landmark_depths_on_ct`).

    ``point``: the bone point (patient mm; the bone level's crossing along the ray); ``depth``: mm to the skin
    level's crossing along the bone's exposed normal (NaN when no skin is met); ``mesh_depth``: the depth from
    the meshes alone (:func:`~.landmarks.landmark_depths`); ``direction``: the ray's unit direction (the bone's exposed
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
    h, dy, dx = (float(v) for v in spacing[:3])
    f_all = (np.asarray(volume, np.float32) - np.float32(air)) / np.float32(tissue - air)
    counts, weights = [], []
    for f in (f_all, f_all[::-1]):             # the outermost edge from either end of the slice axis
        nz = f.shape[0]
        above = f >= 0.5
        has = above.any(0)
        top = nz - 1 - np.argmax(above[::-1], axis=0)
        t = np.clip(top, 2, nz - 3)
        at = {o: np.take_along_axis(f, (t + o)[None], 0)[0] for o in range(-2, 3)}   # f at t + o
        f0, f1 = at[0], at[1]
        zc = (t + (f0 - 0.5) / np.maximum(f0 - f1, 1e-6)) * h          # the edge's height, linearly
        gy, gx = np.gradient(zc, dy, dx)
        slope = np.hypot(gy, gx)
        ok = has & (top >= 2) & (top <= nz - 3) & (slope <= np.tan(np.radians(max_slope_deg)))
        ok &= (at[-2] > 0.9) & (at[2] < 0.1)
        n = sum(((at[o] > 0.1) & (at[o] < 0.9)).astype(np.float32) for o in (-1, 0, 1, 2))
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

    The ray is the one :func:`~.landmarks.landmark_depths` casts (from the landmark snapped onto the bone mesh, along
    the bone's exposed normal, :func:`~.landmarks.exposed_normals`). Along it the intensities ``volume`` (the CT's grid,
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
    names = list(landmarks)
    if not names:
        return {}
    vol = np.asarray(volume)
    if vol.shape != tuple(ct.shape):
        raise PDEHeadError(f"landmark depths: the intensities' shape {vol.shape} is not the CT's {tuple(ct.shape)}")
    base, normal, mesh_depth = depth_rays(landmarks, skull, skin, max_depth_mm)
    search = float(DEPTH_SEARCH_VOXELS * max(ct.spacing)) if search_mm is None else float(search_mm)
    rays = _Rays(base, normal, vol, ct, search, max_depth_mm, head_mask)
    spread = slice_spread_mm
    if spread is None:
        spread = slice_edge_spread(vol, ct.spacing, AIR_HU, 2.0 * skin_level - AIR_HU)[0]
    rays.spread = spread
    rays.bone_normal = snap_to_surface(base, skull)[1]
    levels = (bone_level, skin_level, bone_mode)
    return {name: rays.measure(k, float(mesh_depth[k]), levels, skin) for k, name in enumerate(names)}


class _Rays:
    """The intensity profiles along the landmarks' rays (:func:`landmark_depths_on_ct`) and the measures on them."""

    def __init__(self, base, normal, vol, ct, search: float, max_depth_mm: float, head_mask):
        self.base, self.normal, self.vol, self.search, self.max_depth_mm = base, normal, vol, search, max_depth_mm
        self.voxel = float(max(ct.spacing))
        self.step = step = DEPTH_PROFILE_STEP_MM
        self.s = s = np.arange(-search, max_depth_mm + search + step / 2, step)
        n = len(base)
        pts = base[:, None, :] + s[None, :, None] * normal[:, None, :]
        self.idx = idx = ct.patient_to_index(pts.reshape(-1, 3)).T
        self.vol32 = vol.astype(np.float32, copy=False)
        self.prof = ndi.map_coordinates(self.vol32, idx, order=1, mode="nearest").reshape(n, -1)
        self.mask_prof = None
        if head_mask is not None:
            self.mask_prof = ndi.map_coordinates(np.asarray(head_mask, np.float32), idx, order=1, mode="constant",
                                                 cval=0.0).reshape(n, -1)
        self.slice_mm = slice_mm = float(ct.spacing[0])
        self.k_index = idx[0].reshape(n, -1)
        # the ray's slice index per mm along it: |dk/ds| * slice spacing is the cosine to the slices' normal
        self.dk = (self.k_index[:, -1] - self.k_index[:, 0]) / (s[-1] - s[0])
        self.steep = np.abs(self.dk) * slice_mm >= np.cos(np.radians(DEPTH_STEP_MODEL_DEG))
        # the slices' normal in patient mm (the slice index's gradient)
        axis = ct.patient_to_index(np.vstack([np.zeros(3), np.eye(3)]))[:, 0]
        self.slice_normal = (axis[1:] - axis[0]) / np.linalg.norm(axis[1:] - axis[0])
        self.across = np.cos(np.radians(DEPTH_STEP_MODEL_DEG))
        self.spread = None
        self.bone_normal = None
        self.shape = np.asarray(vol.shape)
        self.coverage = getattr(ct, "coverage", None)
        self.ct, self.head_mask = ct, head_mask

    def crossings(self, v, level):
        """Sub-sample positions (mm along the ray) where the profile falls through ``level`` going outward."""
        i = np.flatnonzero((v[:-1] >= level) & (v[1:] < level))
        return self.s[i] + (v[i] - level) / (v[i] - v[i + 1]) * self.step

    def between_slices(self, k, at, level, what):
        """Why the crossing at ``at`` (mm along ray ``k``) is not the CT's, when the ray runs between two slices
        that disagree on it (see :func:`landmark_depths_on_ct`); "" when they agree or the ray does not run within
        the slices."""
        s, slice_mm, search = self.s, self.slice_mm, self.search
        near = np.abs(s - at) <= slice_mm
        kk = self.k_index[k][near]
        if not near.any() or np.ptp(kk) >= 2.0 * DEPTH_SLICE_RUN:
            return ""
        kc = float(np.interp(at, s, self.k_index[k]))
        k0 = int(np.floor(kc))
        f = kc - k0
        if min(f, 1.0 - f) < DEPTH_SLICE_WEIGHT or k0 < 0 or k0 + 1 >= self.vol.shape[0]:
            return ""
        window = np.abs(s - at) <= search
        sub = self.idx.reshape(3, len(self.base), -1)[:, k][:, window]
        found = []
        for kz in (k0, k0 + 1):
            plane = sub.copy()
            plane[0] = kz
            v = ndi.map_coordinates(self.vol32, plane, order=1, mode="nearest")
            sw = s[window]
            i = np.flatnonzero((v[:-1] >= level) & (v[1:] < level))
            c = sw[i] + (v[i] - level) / (v[i] - v[i + 1]) * self.step
            found.append(float(c[np.argmin(np.abs(c - at))]) if len(c) else float("nan"))
        a, b = found
        if np.isfinite(a) and np.isfinite(b) and abs(a - b) <= DEPTH_SLICE_SHIFT * slice_mm:
            return ""
        where = ", ".join(f"slice {kz}: " + (f"{c - at:+.1f} mm" if np.isfinite(c) else f"none within {search:.1f} mm")
                          for kz, c in zip((k0, k0 + 1), found))
        return (f"the ray runs between two slices {slice_mm:.1f} mm apart ({f:.2f} of the way) that disagree on "
                f"the {what}'s crossing along it ({where}): an edge between the slices, met at a grazing angle; "
                "the interpolated crossing is not measured")

    def on_slices(self, k, at, level, inside, outside, edge_normal):
        """The crossing near ``at`` on ray ``k`` by the blurred-step model from the two slices either side, where
        the edge (its surface's ``edge_normal``) also faces the slices; an edge oblique to the ray spreads along it
        by 1 / cos of the angle between them."""
        if abs(float(edge_normal @ self.slice_normal)) < self.across:
            return at
        s = self.s
        cos = abs(float(edge_normal @ self.normal[k]))
        kc = float(np.interp(at, s, self.k_index[k]))
        si = at + (np.array([np.floor(kc), np.floor(kc) + 1.0]) - kc) / self.dk[k]
        got = step_crossing(si, np.interp(si, s, self.prof[k]), level, inside, outside, self.spread / cos)
        return at if got is None or abs(got - at) > self.slice_mm else got

    def measure(self, k: int, mesh_d: float, levels, skin) -> DepthOnCT:
        """The depth on ray ``k`` (rules in :func:`landmark_depths_on_ct`)."""
        bone_level, skin_level, bone_mode = levels
        s, search, normal = self.s, self.search, self.normal
        v = self.prof[k]
        exits = self.crossings(v, bone_level)
        near = exits[np.abs(exits) <= search]
        if not len(near):
            return DepthOnCT(self.base[k], mesh_d, mesh_d, normal[k], False,
                             f"no crossing of the bone level {bone_level:g} within {search:.1f} mm of the bone "
                             f"mesh along the ray (the profile peaks at {v[np.abs(s) <= search].max():.0f}): "
                             "bone thinner than the voxels, hidden by partial volume")
        sb = float(near[np.argmin(np.abs(near))])
        point = self.base[k] + sb * normal[k]
        skins = self.crossings(v, skin_level)
        skins = skins[skins > sb]
        if not len(skins) or skins[0] - sb > self.max_depth_mm:
            return DepthOnCT(point, float("nan"), mesh_d, normal[k], False,
                             f"the ray meets no skin within {self.max_depth_mm:g} mm of the bone")
        ss, holder = self._skin_point(k, sb, float(skins[0]), mesh_d)
        inside = (s <= sb) & (s > sb - DEPTH_PLATEAU_MM)
        why = self._untrusted(v, sb, ss, inside, bone_level, bone_mode)
        if why:
            return DepthOnCT(point, ss - sb, mesh_d, normal[k], False, why)
        why = self.between_slices(k, sb, bone_level, "bone") or \
            ("" if holder else self.between_slices(k, ss, skin_level, "skin"))
        if self.spread and self.steep[k]:
            # across the slices: each edge lies between two slices a spacing apart, and the linear crossing moves
            # with the edge's place between them (up to 0.15 of a spacing for the slices' own spread): the
            # blurred-step model of the slices locates it
            tissue = 2.0 * skin_level - AIR_HU
            if bone_mode is not None:
                sb = self.on_slices(k, sb, bone_level,
                                    max(float(bone_mode), float(v[inside].max()) if inside.any() else -np.inf),
                                    tissue, self.bone_normal[k])
                point = self.base[k] + sb * normal[k]
            if not holder:
                ss = self.on_slices(k, ss, skin_level, tissue, AIR_HU,
                                    snap_to_surface(self.base[k] + ss * normal[k], skin)[1][0])
        why = why or self.implausible(k, sb, ss, point, skin)
        return DepthOnCT(point, ss - sb, mesh_d, normal[k], not why, why)

    def nearest_skin(self, point: np.ndarray, within: float, skin) -> float:
        """The distance (mm) from ``point`` to the nearest skin, looked for up to ``within`` mm (a larger distance
        is returned as ``within`` + a voxel): the nearest centre of a voxel outside the head mask (the scan's own
        skin; the scan's cut, where the mask meets the volume's border, is not skin; the skin lies up to a voxel
        nearer, so thin tissue is not demoted for the voxels' size); without a mask the nearest point of the
        ``skin`` mesh."""
        if self.head_mask is None:
            return float(np.linalg.norm(snap_to_surface(point[None], skin)[0][0] - point))
        spacing = np.asarray(self.ct.spacing, float)
        centre = self.ct.patient_to_index(point[None])[0]
        reach = np.ceil(within / spacing).astype(int) + 2
        lo = np.maximum(np.floor(centre).astype(int) - reach, 0)
        hi = np.minimum(np.floor(centre).astype(int) + reach + 1, self.shape)
        if np.any(hi <= lo):
            return within + float(spacing.max())
        box = ~np.asarray(self.head_mask[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]], bool)
        out = np.argwhere(box)
        if not len(out):
            return within + float(spacing.max())
        pts = self.ct.index_to_patient((out + lo).astype(float))
        return float(np.sqrt(((pts - point) ** 2).sum(1)).min())

    def implausible(self, k: int, sb: float, ss: float, point: np.ndarray, skin) -> str:
        """Why the depth from ``sb`` to ``ss`` (mm along ray ``k``) is not plausible: the ray meets the skin farther
        than :data:`DEPTH_NEAREST_SKIN_FACTOR` times the nearest skin (:meth:`nearest_skin`) from the bone point, or
        runs within :data:`DEPTH_EDGE_VOXELS` voxels of the scan's edge ("" when neither)."""
        depth = ss - sb
        nearest = self.nearest_skin(point, depth / DEPTH_NEAREST_SKIN_FACTOR, skin)
        if depth > DEPTH_NEAREST_SKIN_FACTOR * max(nearest, self.step):
            return (f"the ray meets the skin {depth:.1f} mm from the bone, more than {DEPTH_NEAREST_SKIN_FACTOR:g} x "
                    f"the nearest skin's {nearest:.1f} mm: it runs along the face, not through the soft tissue")
        on = (self.s >= sb) & (self.s <= ss)
        idx = self.idx.reshape(3, len(self.base), -1)[:, k][:, on]
        if idx.size:
            margin = float(DEPTH_EDGE_VOXELS)
            low = idx.min(axis=1)
            high = (self.shape - 1) - idx.max(axis=1)
            axis = int(np.argmin(np.minimum(low, high)))
            if min(low[axis], high[axis]) < margin:
                return (f"the ray runs within {DEPTH_EDGE_VOXELS} voxels of the scan's edge (axis "
                        f"{'kji'[axis]}, {min(low[axis], high[axis]):.1f} voxels): the skin there may be where the "
                        "scan stops")
            if self.coverage is not None:
                for a in range(3):
                    for d in (-margin, margin):
                        at = np.rint(idx).astype(np.int64)
                        at[a] = np.rint(idx[a] + d).astype(np.int64)
                        at = np.clip(at, 0, (self.shape - 1)[:, None])
                        if not self.coverage[tuple(at)].all():
                            return (f"the ray runs within {DEPTH_EDGE_VOXELS} voxels of the scan's edge (the "
                                    "scanned slab's border): the skin there may be where the scan stops")
        return ""

    def _skin_point(self, k, sb, ss, mesh_d):
        """Where the skin touches something outside the head (a pillow, a holder: the skin level runs on beyond
        the head mask's edge), the PDE skin's (or the head mask's) point instead; (skin mm along the ray, holder)."""
        if self.mask_prof is None:
            return ss, False
        edge = self.crossings(self.mask_prof[k], 0.5)
        edge = edge[edge > sb]
        voxel = self.voxel
        if len(edge) and ss > edge[0] + voxel:   # the skin level runs on into a pillow or a holder
            ss = sb + mesh_d if np.isfinite(mesh_d) and abs(sb + mesh_d - edge[0]) <= voxel else float(edge[0])
            return ss, True
        return ss, False

    def _untrusted(self, v, sb, ss, inside, bone_level, bone_mode) -> str:
        """Why the profile does not support the depth: the bone never reaches its plateau, or the ray meets bone
        again before the skin ("" when neither)."""
        s, step = self.s, self.step
        if bone_mode is not None and inside.any():
            peak = float(v[inside].max())
            need = bone_level + DEPTH_PLATEAU_FRACTION * (bone_mode - bone_level)
            if peak < need:
                return (f"the bone along the ray peaks at {peak:.0f} within {DEPTH_PLATEAU_MM:g} mm, "
                        f"below {need:.0f} ({DEPTH_PLATEAU_FRACTION:.0%} of the way from the bone level "
                        f"{bone_level:g} to the bone mode {bone_mode:g}): bone thinner than the slices' "
                        "blur, partial volume moves its surface")
        between = (s > sb + step) & (s < ss)
        again = float(np.count_nonzero(v[between] >= bone_level) * step)
        if again > DEPTH_BONE_IN_FRONT_MM:
            first = float(s[between][np.argmax(v[between] >= bone_level)] - sb)
            return (f"the ray meets {again:.1f} mm of bone {first:.1f} mm in front of the bone point "
                    "before the skin: the landmark lies behind other bone along its normal")
        return ""


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
                            max_depth_mm: float = 60.0, table=None) -> dict[str, DepthOnCT]:
    """The landmark depths every output writes (the batch's landmarks.csv, the add-on's Export Landmark Depths
    and Export for Printing): on the CT's intensities (:func:`landmark_depths_on_ct`, levels from
    :func:`depth_levels`) when ``skull_seg`` carries them and the CT shows soft tissue; otherwise on the meshes
    (:func:`~.landmarks.landmark_depths`), each result's ``method`` ``"mesh"`` and its ``evidence`` saying why.
    Without a skin the depths are NaN (the bone point is the landmark snapped onto ``skull``).

    A depth is plausible (``trusted``) only where, besides the profile's checks of :func:`landmark_depths_on_ct`,
    the ray meets the skin within :data:`DEPTH_NEAREST_SKIN_FACTOR` times the distance to the nearest skin, not
    within :data:`DEPTH_EDGE_VOXELS` voxels of the scan's edge, and, with a ``table``
    (:class:`~.depth_table.DepthTable`), within its mean +- :data:`DEPTH_TABLE_SD` SD for the landmark (landmarks
    the table lacks, or gives no SD for, are not checked against it); ``evidence`` says which check failed."""
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
        out = landmark_depths_on_ct(landmarks, skull, skin, skull_seg.hu, skull_seg.ct, head_mask=head_mask,
                                    max_depth_mm=max_depth_mm, **depth_levels(skull_seg))
    else:
        base, normal, depth = depth_rays(landmarks, skull, skin, max_depth_mm)
        out = {n: DepthOnCT(base[i], float(depth[i]), float(depth[i]), normal[i], True, why, "mesh")
               for i, n in enumerate(names)}
    return within_table(out, table) if table is not None else out


def within_table(measured: dict[str, DepthOnCT], table, k: float = DEPTH_TABLE_SD) -> dict[str, DepthOnCT]:
    """``measured`` with every trusted depth outside ``table``'s mean +- ``k`` SD for its landmark turned
    untrusted (its ``evidence`` the depth and the range); landmarks without an SD in the table are kept as they
    are."""
    entries = getattr(table, "entries", {})
    for name, m in measured.items():
        entry = entries.get(name)
        if entry is None or entry.sd_mm is None or not m.trusted or not np.isfinite(m.depth):
            continue
        low, high = entry.mean_mm - k * entry.sd_mm, entry.mean_mm + k * entry.sd_mm
        if not low <= m.depth <= high:
            m.trusted = False
            m.evidence = (f"the depth {m.depth:.1f} mm lies outside the table's mean +- {k:g} SD for the landmark "
                          f"({entry.mean_mm:g} +- {k:g} x {entry.sd_mm:g}: {max(low, 0.0):.1f}-{high:.1f} mm)")
    return measured


def depth_flags(flags: dict[str, str], measured: dict[str, DepthOnCT]) -> dict[str, str]:
    """The landmarks' flags with every ``ok`` landmark whose depth the CT's profile does not support
    (``trusted`` False) turned ``uncertain``; landmarks without a flag count as ``ok``."""
    out = dict(flags)
    for name, m in measured.items():
        if not m.trusted and out.get(name, "ok") == "ok":
            out[name] = "uncertain"
    return out
