"""Face from the skull (issue 23): a closed PDE face solved through the tissue-depth pegs.

The practitioner's end product in forensic facial approximation is a face; this module makes one from
the bone skull, its landmarks and a depth table, by the same C2 PDE engine as the skin
(:func:`.pde_surface.solve_pde`), fast enough to re-solve on every peg drag.

Method
------
Everything is expressed on a cylinder of directions about the vertical (patient z) axis through the
skull's centroid: a row every ``row_mm`` of height, a column every ``360 / columns`` degrees.

1. *The bone's outer profile* (:func:`bone_profile`): per (row, column) bin the outermost point of the
   bone skull; per row the 2-D convex hull of that ring (which bridges the orbits, the nasal aperture,
   the temporal fossae and the cheeks), a grey closing and a Gaussian smoothing along the height, and
   away from the pegs a stronger one (:func:`_smooth_far_from_pegs`: the rows' hulls step). Where a
   column meets no bone (below the skull base at the back, below the mandible) the neck rule of
   :func:`_neck_fill` continues the profile downward.
2. *The pegs*: each landmark of the depth table stands on the bone along the bone's outward normal,
   averaged over the bone around it (:func:`peg_normals`); its tip (base + depth x normal) is where the skin must pass.
   In the cylinder frame each tip is a site (z, angle) with a radial offset over the profile.
3. *The tissue-depth field* (:meth:`FaceModel._offset_field`): over the whole head, a wide
   normalised Gaussian average of the peg offsets (Shepard / partition of unity, radius
   ``spread_mm``) with the rule depth where no peg stands (:data:`RULE_DEPTH_MM`: the vault and the
   neck), plus a narrow Gaussian radial-basis correction (lightly regularised) that makes the field
   pass through every tip (to a few tenths of a mm), except a peg that disagrees with its neighbours by more
   than :data:`DAMP_FREE_MM` (:meth:`FaceModel._site_damping`); kept from overshooting between the pegs
   (:meth:`FaceModel._limited`). A peg's influence fades within about 2 ``spread_mm``.
4. *Prediction rules* for what a depth field cannot make (:mod:`.face_features`, each cited there): the nose
   from the nasal aperture and the nasal length, the closed eyes in the orbits, the mouth from the teeth and the
   canines, a default ear at each porion.
5. *The face*: profile + depth field + nose + lips + eyes + ears = radius per bin; each row is a closed boundary curve;
   the C2 PDE surface through them (:func:`.pde_surface.solve_pde`, dome over the vertex, a flat cap
   under the neck) is the face, a closed mesh in patient mm.

What does not depend on the depths is computed once in :meth:`FaceModel.prepare`; :meth:`FaceModel.solve`
evaluates the field, adds the features, solves the PDE and meshes it (tens of ms).

Every result carries :data:`APPROXIMATION_LABEL` and its provenance: it is an approximation, not an
identification.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .. import defaults as D
from ..core.boundary_set import BoundarySet, knots_from_heights
from ..core.errors import PDEHeadError
from .face_features import (EAR_LENGTH_MM, EAR_WIDTH_MM, FRONT_COS, check_skull, ear_shape, eye_shape, mouth_shape,
                            nose_bump, predict_eyes, predict_mouth, predict_nose)
from ..core.mesh import Mesh

APPROXIMATION_LABEL = D.FACE_LABEL

#: Depth (mm) where no peg stands: the vault and the back of the head. The T-Table 2023 grand means at vertex (5.0 mm)
#: and opisthocranion (6.0 mm) (Hona & Stephan 2024, Int J Legal Med 138(2):519-535, doi:10.1007/s00414-023-03087-x,
#: values as printed in esomjai/Forensic-Craniofacial-Approximation- Validation-Tool, "FSTT/Generating FSTT cylinders in
#: Slicer.md"), rounded to their mean.
RULE_DEPTH_MM = 5.5
#: Weight of the rule depth in the Shepard average (a peg at distance ``spread_mm`` weighs e^-1 = 0.37).
RULE_WEIGHT = 0.04
#: The neck below the skull: radius (mm) of the neck about its axis, which lies this far behind the skull's centroid
#: axis. Adult neck circumference ~ 36-40 cm (anthropometric surveys, e.g. Ben-Noun et al. 2001, Obesity Research
#: 9(8):470-477: men 38.0 cm, women 32.5 cm mean; cited from memory of that survey, not re-read) -> radius ~ 55-60 mm.
#: It shapes only the neck, outside the scored face.
NECK_RADIUS_MM = 57.0
NECK_BEHIND_MM = 12.0
#: How fast the neck recedes below the skull base (mm per mm of height: 0.8 ~ a 40 degree slope).
NECK_SLOPE = 0.8
#: The bone's radius map is made on at most this many columns (2 degrees) and interpolated to the face's grid (finer
#: bins meet no bone vertex on a coarse skull mesh: GE 29 % within +-2.5 mm on 360 columns, 35 % on 180).
PROFILE_COLUMNS = 180
#: Closing of the bone's radius map: how wide a gap (mm) the envelope bridges (the orbit is ~ 40 mm wide,
#: the nasal aperture ~ 25 mm).
CLOSING_MM = 15.0
#: Radius (mm) over which the bone's normal at a landmark is averaged (:func:`peg_normals`).
PEG_NORMAL_RADIUS_MM = 8.0
#: A peg follows the averaged bone normal unless it leans more than 45 degrees from the closed profile's
#: normal (then the profile's): e.g. subspinale on a mask whose thin maxilla is gone faces up, not forward.
PEG_NORMAL_MIN_COS = 0.7
#: Vertical Gaussian smoothing (mm) of the closed profile: each row's hull is made on its own, and rows a few mm
#: apart step (the teeth, the zygomatic arches' edges); a skin does not.
PROFILE_SMOOTH_MM = 4.0
#: ... and around the head (degrees; the Gaussian of the profile and of its normals): one column of the first,
#: 180-column grid, kept in degrees when the grid became 360 columns (issue 23's sixth session).
PROFILE_SMOOTH_DEG = 2.0
#: Away from the pegs the closed profile is smoothed more, in 2-D on the (angle, height) grid: a Gaussian of
#: :data:`PROFILE_SMOOTH_FAR_MM` of height and :data:`PROFILE_SMOOTH_FAR_ARC_MM` of arc (at the median radius): each
#: row's hull is made on its own, which leaves horizontal ridges across the lower face that no peg corrects. Within
#: about :data:`PROFILE_NEAR_MM` of a peg tip the lightly smoothed profile is kept (Gaussian blend). CThead (issue
#: 23b): 57.3 -> 57.5 % within +-2.5 mm; row-to-row second difference of the face's radius 0.48 -> 0.40 mm.
PROFILE_SMOOTH_FAR_MM = 8.0
PROFILE_SMOOTH_FAR_ARC_MM = 2.0
PROFILE_NEAR_MM = 10.0
#: Width of the exact correction's Gaussians, as a fraction of ``spread_mm``.
NARROW_FRACTION = 0.5
#: Regularisation of the exact peg interpolation (relative to the kernel's unit diagonal).
RBF_REGULARISATION = 0.05
#: A peg whose offset disagrees with what its neighbours give there (the wide field without it) by more than
#: :data:`DAMP_FREE_MM` is followed less closely by the exact correction: its regularisation grows by ((disagreement -
#: DAMP_FREE_MM) / DAMP_SCALE_MM)^2 (:meth:`FaceModel._site_damping`; the T-Table's 26 mm supra-M2 and 22 mm sub-M2
#: pegs beside 8-13 mm ones made the jaw's border lumpy). Fixed at the table's means from the skull and the table
#: alone; the mid-sagittal pegs (within :data:`DAMP_MIDLINE_DEG` of straight ahead) stay exact: the nose and the lips
#: stand on them. CThead (issue 23's fifth session): 60.1 -> 62.0 % within +-2.5 mm; GE unchanged.
DAMP_FREE_MM = 4.0
DAMP_SCALE_MM = 5.0
DAMP_MIDLINE_DEG = 10.0
#: No overshoot between the pegs (:meth:`FaceModel._limited`): the field stays between the lowest and the highest
#: blend base + k_i (target_i - base) of the wide field with each site's offset (k_i = exp(-(d / R)^4) along the
#: height times the same around, R = LIMIT_RADIUS_FRACTION x ``spread_mm``; a smooth min / max LIMIT_SOFT_MM wide).
#: The Gaussians' exact correction swings beyond two close sites of very different offsets (CThead, issue 23's 8th
#: session: subspinale 3.8 and mid-philtrum 14.8 mm, 3.4 mm apart: 19.7 mm above them, 16.6 over the incisors where
#: the pegs are 12-13). At a site the bound is its own offset: the field still passes through every tip.
LIMIT_RADIUS_FRACTION = 1.0
LIMIT_SOFT_MM = 1.0
#: A site's blend weight below which the limiter leaves it out (its term is then below 1e-12 x its offset).
LIMIT_WEIGHT_FLOOR = 1e-12


# ------------------------------------------------------------------------------------------ geometry
def _site_windows(rows_on: np.ndarray, cols_on: np.ndarray):
    """For each site i (the columns of ``rows_on`` (K, n) and ``cols_on`` (M, n)): ``(i, rows, cols)`` as
    basic slices (views) covering its rows and columns; a run of columns across the seam (column 0) gives
    two windows. Rows and columns of one site are one run each (the weights fall off with distance)."""
    M = len(cols_on)
    for i in range(rows_on.shape[1]):
        r, c = np.flatnonzero(rows_on[:, i]), np.flatnonzero(cols_on[:, i])
        if not r.size or not c.size:
            continue
        rows = slice(r[0], r[-1] + 1)
        if c[-1] - c[0] + 1 == c.size or c.size == M:
            yield i, rows, slice(c[0], c[-1] + 1)
        else:                                            # wraps: [gap end .. M) and [0 .. gap start)
            gap = int(np.flatnonzero(np.diff(c) > 1)[0])
            yield i, rows, slice(c[gap + 1], M)
            yield i, rows, slice(0, c[gap] + 1)


@dataclass
class FaceGrid:
    """The face's grid: rows at heights ``z`` and columns at angles ``theta`` around the vertical axis
    through ``centre`` (patient mm, radians)."""
    centre: np.ndarray          # (2,) x, y of the vertical axis
    z: np.ndarray               # (K,) row heights, ascending
    theta: np.ndarray           # (M,) column angles; 0 = posterior (+y), pi/2 = patient's left (+x)

    def polar(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d = np.asarray(p, float)[..., :2] - self.centre
        return np.asarray(p, float)[..., 2], np.mod(np.arctan2(d[..., 0], d[..., 1]), 2 * np.pi), np.hypot(d[..., 0], d[..., 1])

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
                 closing_mm: float = CLOSING_MM) -> tuple[np.ndarray, np.ndarray]:
    """The bone's outer radius per (row, column) bin and its closed envelope.

    1. per bin the outermost skull vertex (NaN where the ray meets no bone);
    2. gaps inside a column are interpolated along the height; below ``base_z`` (the skull base) the neck
       rule of :func:`_neck_fill`;
    3. per row the 2-D convex hull of the ring: the envelope a skin stretched over the bone would take
       across the orbits, the nasal aperture, the temporal fossae and the cheeks (between the zygoma and
       the mandible), where no depth is measured;
    4. a grey closing over ``closing_mm`` of height (the vertical gaps, e.g. the nasal aperture above the
       maxilla) and a Gaussian smoothing (:data:`PROFILE_SMOOTH_MM` of height, 1 column).

    Returns
    -------
    raw : (K, M) outermost bone radius per bin (NaN where the bin meets no bone)
    closed : (K, M) the closed, gap-filled, smoothed profile (no NaN)
    """
    M_face = len(grid.theta)
    if M_face > PROFILE_COLUMNS:                 # the bone's map on the coarser grid, then interpolated (see there)
        coarse = FaceGrid(grid.centre, grid.z, np.arange(PROFILE_COLUMNS) * 2 * np.pi / PROFILE_COLUMNS)
        raw_c, sm_c = bone_profile(skull, coarse, base_z, closing_mm)
        return _resample_columns(raw_c, M_face), _resample_columns(sm_c, M_face)
    z, th, r = grid.polar(skull.vertices)
    dz = grid.z[1] - grid.z[0]
    K, M = len(grid.z), len(grid.theta)
    k = np.round((z - grid.z[0]) / dz).astype(int)
    j = np.round(th / (2 * np.pi) * M).astype(int) % M
    ok = (k >= 0) & (k < K)
    raw = np.full(K * M, -np.inf)
    np.maximum.at(raw, k[ok] * M + j[ok], r[ok])
    raw = raw.reshape(K, M)
    raw[~np.isfinite(raw)] = np.nan
    filled = _neck_fill(raw, grid, base_z)
    hull = _row_hulls(filled, grid.theta)
    kz = max(1, int(round(closing_mm / dz)))
    pad = kz
    padded = np.pad(hull, ((pad, pad), (0, 0)), mode="edge")
    closed = ndimage.grey_closing(padded, size=(kz, 1), mode="wrap")[pad:-pad]
    closed = np.maximum(closed, hull)
    sm = ndimage.gaussian_filter(np.pad(closed, ((pad, pad), (0, 0)), mode="edge"),
                                 sigma=(PROFILE_SMOOTH_MM / dz, _columns(PROFILE_SMOOTH_DEG, grid)),
                                 mode="wrap")[pad:-pad]
    return raw, sm


def _smooth_far_from_pegs(profile: np.ndarray, grid: FaceGrid, sites: np.ndarray) -> np.ndarray:
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


def _row_hulls(radius: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Per row, the radius along each column's ray of the 2-D convex hull of the row's ring."""
    from scipy.spatial import ConvexHull

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


def _neck_fill(raw: np.ndarray, grid: FaceGrid, base_z: float | None = None) -> np.ndarray:
    """Fill bins that meet no bone, and shape the neck below the skull base.

    Gaps inside a column are interpolated along the height; above the skull's top row the top is
    repeated. Below ``base_z`` (the skull base) the rays meet the mandible, the mastoids and what is
    left of the upper cervical spine, none of which is the neck's outline: there each column keeps its
    bone where the bone lies further out, and otherwise recedes from the row above by at most
    :data:`NECK_SLOPE` mm per mm of height (the occiput's curve into the nape, the chin's into the
    throat) down to the neck, a circle of :data:`NECK_RADIUS_MM` about an axis :data:`NECK_BEHIND_MM`
    behind the skull's axis. A rule, not a measurement of this head.
    """
    K, M = raw.shape
    out = raw.copy()
    good = np.isfinite(out)
    rows = np.arange(K)
    for j in np.nonzero(good.sum(0) >= 2)[0]:                 # gaps inside a column (per column: 180 at most)
        gi = np.nonzero(good[:, j])[0]
        inside = (rows >= gi[0]) & (rows <= gi[-1])
        out[inside, j] = np.interp(rows[inside], gi, out[gi, j])
    th = grid.theta
    b = NECK_BEHIND_MM
    neck = b * np.cos(th) + np.sqrt(np.maximum(NECK_RADIUS_MM ** 2 - (b * np.sin(th)) ** 2, 1.0))
    dz = grid.z[1] - grid.z[0]
    top = int(np.nonzero(np.isfinite(out).any(1))[0].max()) if np.isfinite(out).any() else K - 1
    kb = top if base_z is None else int(np.clip(np.floor((base_z - grid.z[0]) / dz), 0, top))
    for k in range(kb - 1, -1, -1):                           # downward from the skull base
        above = out[k + 1]
        bone = np.where(np.isfinite(out[k]), out[k], -np.inf)
        out[k] = np.maximum(bone, np.maximum(np.minimum(above, neck), above - NECK_SLOPE * dz))
    for k in range(1, K):                                     # above the top: repeat
        miss = ~np.isfinite(out[k]) & np.isfinite(out[k - 1])
        out[k, miss] = out[k - 1, miss]
    for k in range(K - 2, -1, -1):
        miss = ~np.isfinite(out[k]) & np.isfinite(out[k + 1])
        out[k, miss] = out[k + 1, miss]
    if not np.all(np.isfinite(out)):
        out[~np.isfinite(out)] = NECK_RADIUS_MM
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
    e.g. the maxilla at the bone level, points anywhere); where that still points more than 45 degrees
    away from the closed profile's outward normal (:data:`PEG_NORMAL_MIN_COS`), the profile's normal (not above
    the profile's last row, where its normal means nothing: the vertex keeps the bone's).
    The T-Table's convention is a depth measured along the bone normal at the landmark."""
    from scipy.spatial import cKDTree

    v, t = skull.vertices, skull.triangles
    if len(skull.quads):
        t = np.concatenate([t, skull.quads[:, [0, 1, 2]], skull.quads[:, [0, 2, 3]]])
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    fn = np.cross(b - a, c - a)                                    # area-weighted (|fn| = 2 area)
    tree = cKDTree((a + b + c) / 3.0)
    env = envelope_normals(grid, profile, bases)
    out = np.empty_like(bases)
    for i, p in enumerate(bases):
        idx = tree.query_ball_point(p, radius_mm)
        n = fn[idx].sum(axis=0) if idx else env[i]
        norm = np.linalg.norm(n)
        n = n / norm if norm > 0 else env[i]
        # above the last row (vertex) the profile's normal is meaningless (the rows' radius near the axis): the bone's
        out[i] = n if float(n @ env[i]) >= PEG_NORMAL_MIN_COS or p[2] > grid.z[-1] else env[i]
    return out


# ------------------------------------------------------------------------------------------ the model
@dataclass
class FaceResult:
    """One solved face: the closed mesh (patient mm, the CT's frame) and where it came from."""

    mesh: Mesh
    provenance: dict
    timings: dict
    tips: np.ndarray | None = None
    depths: np.ndarray | None = None
    head: object = None


def peg_kernel(a: np.ndarray, b: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian kernel exp(-|a_i - b_j|^2 / sigma^2), (len(a), len(b)), float32-free but allocation-light."""
    d2 = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * (a @ b.T)
    np.maximum(d2, 0.0, out=d2)
    d2 *= -1.0 / (sigma * sigma)
    return np.exp(d2, out=d2)


@dataclass
class FaceModel:
    """A face-from-skull model: everything that does not depend on the peg depths, prepared once.

    Build it with :meth:`prepare`; :meth:`solve` makes a face for any depths or peg tips.
    The model is re-created from (skull mesh, landmarks, table, options) alone: nothing in it needs
    pickling.
    """

    peg_names: list
    peg_bases: np.ndarray
    peg_normals: np.ndarray
    default_depths: np.ndarray
    depth_sd: np.ndarray
    grid: FaceGrid
    raw: np.ndarray
    profile: np.ndarray
    rule_sites: list
    nose: dict | None
    mouth: dict | None
    options: dict
    provenance: dict
    flags: dict = field(default_factory=dict)
    prepare_seconds: float = 0.0

    # -------------------------------------------------------------------- prepare
    @classmethod
    def prepare(cls, skull: Mesh, landmarks: dict, table, *, sex=None, flags: dict | None = None,
                row_mm: float | None = None, columns: int | None = None, spread_mm: float | None = None,
                nu: int | None = None, nv: int | None = None, neck_mm: float = 40.0) -> "FaceModel":
        """Prepare the face model of a skull.

        ``skull``: the bone skull (:func:`.skull.skull_mesh` or a ``--skull-mesh``), patient LPS mm; ``landmarks``: on
        the bone (patient mm), those the table has become pegs, the others feed the prediction rules; ``table``: a
        DepthTable or dict (mean depth per landmark; SDs from ``table.sd``); ``sex`` (kept in the provenance; the
        T-Table 2023 is pooled) and ``flags`` (``ok`` / ``uncertain`` / ``not_found``, for the provenance).
        """
        from .landmarks import marker_pegs

        t0 = time.perf_counter()
        if skull is None or len(skull.vertices) < 100:
            raise PDEHeadError("the skull mesh is empty: no face can be approximated")
        ext = np.ptp(skull.vertices, axis=0)
        if np.any(ext < 60.0) or np.any(ext > 400.0):
            raise PDEHeadError(f"the skull mesh is {ext[0]:.0f} x {ext[1]:.0f} x {ext[2]:.0f} mm: not a skull "
                               "in mm (a skull is ~ 140 x 190 x 130 mm or more)")
        row_mm = D.FACE_ROW_MM.default if row_mm is None else float(row_mm)
        columns = int(D.FACE_COLUMNS.default if columns is None else columns)
        spread = D.FACE_SPREAD_MM.default if spread_mm is None else float(spread_mm)
        lm = {k: np.asarray(v, float) for k, v in landmarks.items() if v is not None}
        check_skull(lm, flags)
        pegs = marker_pegs(lm, skull, table, measured_direction=False)     # the face sets its own normals
        if len(pegs) < 4:
            raise PDEHeadError(f"only {len(pegs)} landmarks have a depth in the table: at least 4 are needed "
                               "for a face (run Find Landmarks)")
        names = [p[0] for p in pegs]
        bases = np.array([p[1] for p in pegs])
        depths = np.array([p[3] for p in pegs], float)
        sd_of = getattr(table, "sd", None)
        sds = np.array([(sd_of(n) if sd_of else None) or np.nan for n in names], float)
        # the axis: the bone's centroid (area-weighted vertices are close enough: a dense uniform mesh)
        centre = skull.vertices[:, :2].mean(axis=0)
        zlo = float(skull.vertices[:, 2].min()) - neck_mm
        zhi = float(skull.vertices[:, 2].max()) - 4.0
        K = max(8, int(np.ceil((zhi - zlo) / row_mm)) + 1)
        grid = FaceGrid(centre, np.linspace(zlo, zhi, K), np.arange(columns) * 2 * np.pi / columns)
        base_z = None
        po = [lm[n] for n in ("Porion L", "Porion R") if n in lm]
        if po:
            base_z = float(np.mean([p[2] for p in po])) - 15.0   # the skull base, ~15 mm below the ear canals
        raw, profile = bone_profile(skull, grid, base_z)
        normals = peg_normals(skull, bases, grid, profile)
        hull_profile = profile
        profile = _smooth_far_from_pegs(profile, grid, bases + depths[:, None] * normals)
        rule_sites = [(n, p, w) for n, p, w in predict_eyes(lm)]
        nose = predict_nose(lm, skull)
        mouth = predict_mouth(lm)
        from ..core.provenance import provenance
        prov_table = table.provenance_record() if hasattr(table, "provenance_record") else {"table": "imported table"}
        prov = provenance(label=APPROXIMATION_LABEL, method="face from skull: PDE surface through tissue-depth "
                          "pegs (pdehead_addon.forensic.face_from_skull)", sex=sex, **prov_table)
        if flags:
            prov["landmark_flags"] = {n: flags.get(n, "ok") for n in sorted(lm)}
        options = dict(row_mm=row_mm, columns=columns, spread_mm=spread, nu=nu or D.FACE_NU.default,
                       nv=nv or D.FACE_NV.default, neck_mm=neck_mm, sex=sex)
        model = cls(names, bases, normals, depths, sds, grid, raw, profile, rule_sites, nose, mouth, options,
                    prov, dict(flags or {}))
        model.vertex_z = float(skull.vertices[:, 2].max())
        model._in_rows = grid.polar(model.tips_for(depths))[0] <= grid.z[-1]
        model.landmarks_used = lm
        model.hull_profile = hull_profile                    # the peer (constant_depth) keeps the bone's own profile
        model._grid_xyz = model._cyl(np.repeat(grid.z, columns), np.tile(grid.theta, K))
        model._damping = model._site_damping()
        model.prepare_seconds = time.perf_counter() - t0
        return model

    # -------------------------------------------------------------------- the field
    def _cyl(self, z, theta) -> np.ndarray:
        """Sites on a cylinder of the mean radius: distances between them ~ distances over the head."""
        rho = 85.0
        return np.stack([rho * np.sin(theta), rho * np.cos(theta), np.asarray(z, float)], axis=-1)

    def tips_for(self, depths: np.ndarray) -> np.ndarray:
        return self.peg_bases + np.asarray(depths, float)[:, None] * self.peg_normals

    def field_sites(self, tips: np.ndarray) -> np.ndarray:
        """The points (n, 3) the tissue-depth field passes through: the peg tips within the profile's rows
        and the rule sites (vault, temples, neck)."""
        # a tip above the last row (vertex) is left to the dome over the vault: near the axis its radial offset
        # to the top row's radius is meaningless (-21 mm on CThead)
        in_rows = getattr(self, "_in_rows", None)
        sites = [np.asarray(tips, float)[in_rows if in_rows is not None else slice(None)]]
        sites += [np.array([p for _, p, _ in self.rule_sites])] if self.rule_sites else []
        return np.concatenate(sites)

    def _offset_field(self, tips: np.ndarray) -> np.ndarray:
        """(K, M) radial offset over the profile that passes through every tip (and rule site)."""
        g = self.grid
        z, th, r = g.polar(self.field_sites(tips))
        target = r - g.sample(self.profile, z, th)                    # offset each site needs
        xs = self._cyl(z, th)
        sigma = self.options["spread_mm"]
        # wide Shepard average with the rule depth
        Wg = peg_kernel(self._grid_xyz, xs, sigma)                        # (G, n)
        Ws = peg_kernel(xs, xs, sigma)
        base_g = (Wg @ target + RULE_WEIGHT * RULE_DEPTH_MM) / (Wg.sum(1) + RULE_WEIGHT)
        base_s = (Ws @ target + RULE_WEIGHT * RULE_DEPTH_MM) / (Ws.sum(1) + RULE_WEIGHT)
        # narrow exact correction
        s2 = NARROW_FRACTION * sigma
        w = self._correction_weights(xs, target - base_s)
        corr = peg_kernel(self._grid_xyz, xs, s2) @ w
        shape = self.profile.shape
        return self._limited((base_g + corr).reshape(shape), base_g.reshape(shape), xs, target)

    def _limited(self, field: np.ndarray, base: np.ndarray, xs: np.ndarray, target: np.ndarray) -> np.ndarray:
        """The field (K, M) kept within the blends of ``base`` with the sites' ``target`` (:data:`LIMIT_RADIUS_FRACTION`);
        one place for :meth:`_offset_field` and the live path (sites ``xs`` on the model's cylinder)."""
        if LIMIT_RADIUS_FRACTION <= 0 or not len(target):
            return field
        g, R = self.grid, LIMIT_RADIUS_FRACTION * float(self.options["spread_mm"])
        ring = self._cyl(np.zeros(len(g.theta)), g.theta)[:, :2]
        kz = np.exp(-((g.z[:, None] - xs[None, :, 2]) / R) ** 4)                                   # (K, n)
        kt = np.exp(-(((ring[:, None, :] - xs[None, :, :2]) ** 2).sum(-1) / (R * R)) ** 2)       # (M, n)
        target = np.asarray(target, float)
        # max / min over the sites of kz kt (target - base), each site on the rows and columns where its weight
        # exceeds LIMIT_WEIGHT_FLOOR (about 2 R around it: a few % of the grid): the dense (K, M, n) product
        # cost 13 ms of the live face's ~100 ms; elsewhere a site's term is 0 to within 1e-12 x its offset
        hi, lo = np.zeros_like(base), np.zeros_like(base)
        for i, rows, cols in _site_windows(kz > LIMIT_WEIGHT_FLOOR, kt > LIMIT_WEIGHT_FLOOR):
            dev = np.multiply.outer(kz[rows, i], kt[cols, i])
            dev *= target[i] - base[rows, cols]
            np.maximum(hi[rows, cols], dev, out=hi[rows, cols])
            np.minimum(lo[rows, cols], dev, out=lo[rows, cols])
        hi += base
        lo += base
        k = LIMIT_SOFT_MM
        h = np.clip(0.5 + 0.5 * (hi - field) / k, 0.0, 1.0)                 # smooth min(field, hi)
        out = hi + (field - hi) * h - k * h * (1.0 - h)
        h = np.clip(0.5 + 0.5 * (out - lo) / k, 0.0, 1.0)                   # smooth max(out, lo)
        return lo + (out - lo) * h + k * h * (1.0 - h)

    def _correction_weights(self, xs: np.ndarray, residual: np.ndarray) -> np.ndarray:
        """Weights of the narrow Gaussians of the exact correction at the field sites ``xs`` for the
        ``residual`` (offset minus the wide field at each site), regularised per site
        (:meth:`_site_damping`). One place for :meth:`_offset_field` and the live path."""
        Phi = peg_kernel(xs, xs, NARROW_FRACTION * self.options["spread_mm"])
        lam = self.__dict__.get("_damping")
        lam = RBF_REGULARISATION * np.ones(len(xs)) if lam is None or len(lam) != len(xs) else lam
        Phi[np.diag_indices_from(Phi)] += lam
        return np.linalg.solve(Phi, residual)

    def _site_damping(self) -> np.ndarray:
        """Per field site, the exact correction's regularisation: :data:`RBF_REGULARISATION`, plus
        ((|disagreement| - :data:`DAMP_FREE_MM`) / :data:`DAMP_SCALE_MM`)^2 where a site's offset at the table's
        means disagrees with the wide field of the other sites (leave-one-out Shepard average) by more than
        :data:`DAMP_FREE_MM`; the mid-sagittal pegs are not damped. A robust-interpolation rule (an outlying
        peg pulls the face less than its neighbours agree on), fixed by the skull and the table."""
        g = self.grid
        z, th, r = g.polar(self.field_sites(self.tips_for(self.default_depths)))
        target = r - g.sample(self.profile, z, th)
        xs = self._cyl(z, th)
        W = peg_kernel(xs, xs, self.options["spread_mm"])
        np.fill_diagonal(W, 0.0)
        others = (W @ target + RULE_WEIGHT * RULE_DEPTH_MM) / (W.sum(1) + RULE_WEIGHT)
        off = np.abs(target - others)
        midline = np.abs(np.angle(np.exp(1j * (th - np.pi)))) < np.radians(DAMP_MIDLINE_DEG)
        excess = np.where(midline, 0.0, np.maximum(off - DAMP_FREE_MM, 0.0))
        return RBF_REGULARISATION + (excess / DAMP_SCALE_MM) ** 2

    def _mouth_shape(self, base: np.ndarray, grid: FaceGrid | None = None) -> np.ndarray | None:
        """The lips over the face ``base`` (:func:`.face_features.mouth_shape`; on ``grid``, default the model's)."""
        return mouth_shape(grid or self.grid, self.mouth, base)

    def _eye_shape(self, base: np.ndarray, grid: FaceGrid | None = None) -> np.ndarray | None:
        """The closed eyes over the face ``base`` (:func:`.face_features.eye_shape`)."""
        return eye_shape(grid or self.grid, getattr(self, "landmarks_used", None) or {}, base)

    def _ear_shape(self) -> np.ndarray | None:
        """The default ears at the porions (:func:`.face_features.ear_shape`). Fixed by the skull: computed once."""
        if "_ears" not in self.__dict__:
            self.__dict__["_ears"] = ear_shape(self.grid, getattr(self, "landmarks_used", {}) or {})
        return self.__dict__["_ears"]

    def _peg_tip(self, tips: np.ndarray, *names) -> np.ndarray | None:
        for n in names:
            if n in self.peg_names:
                return tips[self.peg_names.index(n)]
        return None

    def _nose_bump(self, base: np.ndarray, tips: np.ndarray, grid: FaceGrid | None = None) -> np.ndarray | None:
        """The nose over the face ``base`` on the current peg ``tips`` (:func:`.face_features.nose_bump`)."""
        return nose_bump(grid or self.grid, self.nose, base, lambda *names: self._peg_tip(tips, *names))

    def _front(self) -> tuple[slice, FaceGrid]:
        """The columns the nose, the lips and the eyes can touch (``cos theta < -0.2``: all three are zero
        elsewhere) as a slice, and the grid of those columns: the features are made there alone (live speed)."""
        if "_front_grid" not in self.__dict__:
            g = self.grid
            j = np.flatnonzero(np.cos(g.theta) < FRONT_COS)
            if j.size and j[-1] - j[0] + 1 == j.size:
                cols = slice(int(j[0]), int(j[-1]) + 1)
            else:                                     # never for theta = 0 behind the head; all columns then
                cols = slice(0, len(g.theta))
            self.__dict__["_front_grid"] = (cols, FaceGrid(g.centre, g.z, g.theta[cols]))
        return self.__dict__["_front_grid"]

    def _surface(self, radius: np.ndarray, nu=None, nv=None, top_z: float | None = None):
        from ..pde.pde_head import derived_once
        from ..pde.pde_surface import solve_pde

        g = self.grid
        curves = g.point(g.z[:, None], g.theta[None, :], radius)
        top = self.vertex_z + RULE_DEPTH_MM if top_z is None else float(top_z)
        bset = BoundarySet(curves, np.full(len(g.z), -1), g.z, knots_from_heights(g.z),
                           meta={"vertex_z": top, "parameterisation": "aligned"})
        # The C2 spline's parameter (chord-length positions of the curves) and its smoothing (from the mean
        # radius) are fixed by the first face solved, so a peg moved at the chin does not re-parameterise
        # (slide) or re-smooth the whole head: only the curves near the peg change.
        fixed = self.__dict__.setdefault("_pde_fixed", {})
        if fixed:
            derived_once(bset, "positions", lambda: fixed["positions"])
            derived_once(bset, "radius", lambda: fixed["radius"])
        head = solve_pde(bset, approximation_mm=0.0)
        if not fixed:
            from ..pde.pde_surface import curve_positions, smoothing_range
            smoothing_range(bset)                                # computes and caches the mean radius
            fixed["positions"] = curve_positions(bset)
            fixed["radius"] = derived_once(bset, "radius", lambda: None)   # the value smoothing_range cached
        return head

    def _mesh(self, head, nu=None, nv=None) -> Mesh:
        """The closed mesh of a solved face. The neck cap's vertex counts are fixed by the first face solved
        at these (nu, nv), so every later solve (a dragged peg) gives the same topology: the Blender layer can
        rewrite the positions in place."""
        nu, nv = int(nu or self.options["nu"]), int(nv or self.options["nv"])
        refs = self.__dict__.setdefault("_cap_refs", {})
        if (nu, nv) not in refs:
            refs[(nu, nv)] = head.cap_reference(nu, nv)
        head.cap_reference = lambda _nu, _nv, _ref=refs[(nu, nv)]: _ref
        # the columns' v steps (issue 21: closer where an outline runs radially) too, for the same reason
        density = self.__dict__.setdefault("_v_density", [head.v_density()])[0]
        head.v_density = lambda _d=density: _d
        # the UV layout too (issue 21's tube map costs ~0.65 s per new set of curves): fixed by the first
        # face, so a dragged peg neither waits for it nor moves a painted texture
        layout = self.__dict__.get("_uv_layout")
        if layout is None:
            layout = self._uv_layout = head.uv_layout()
        head.uv_layout = lambda _layout=layout: _layout
        return head.surface(nu, nv, caps=True)

    def sd_faces(self, k: float = 1.0) -> tuple[FaceResult, FaceResult]:
        """The faces at mean - k SD and mean + k SD at every peg (the range to show; depths never below 0;
        a peg without an SD keeps its mean)."""
        sd = np.nan_to_num(self.depth_sd, nan=0.0)
        lo = self.solve(depths=np.maximum(self.default_depths - k * sd, 0.0))
        hi = self.solve(depths=self.default_depths + k * sd)
        for res, sign in ((lo, "-"), (hi, "+")):
            res.provenance["depths"] = f"table mean {sign} {k:g} SD at every peg"
        return lo, hi

    def constant_depth(self, depth_mm: float) -> FaceResult:
        """The peer: the bone's closed outer profile pushed out by one depth everywhere (no pegs, no nose)."""
        head = self._surface(getattr(self, "hull_profile", self.profile) + float(depth_mm))
        mesh = head.surface(int(self.options["nu"]), int(self.options["nv"]), caps=True)   # not live: own caps
        prov = dict(self.provenance, method=f"constant depth {depth_mm:g} mm over the bone's closed profile")
        return FaceResult(mesh, prov, {}, head=head)

    def solve(self, *, depths: np.ndarray | None = None, tips: np.ndarray | None = None,
              nu: int | None = None, nv: int | None = None) -> FaceResult:
        """The face through the pegs at ``depths`` (mm, one per peg; default the table's means) or at
        explicit peg-tip positions ``tips`` (patient mm, shape (n, 3): a dragged peg), which win."""
        t0 = time.perf_counter()
        if tips is None:
            d = self.default_depths if depths is None else np.asarray(depths, float).reshape(-1)
            if d.shape != self.default_depths.shape or not np.all(np.isfinite(d)):
                raise PDEHeadError(f"depths: need {len(self.default_depths)} finite values, got {d.shape}")
            tips = self.tips_for(d)
        else:
            tips = np.asarray(tips, float).reshape(-1, 3)
            if tips.shape != self.peg_bases.shape or not np.all(np.isfinite(tips)):
                raise PDEHeadError(f"tips: need {len(self.peg_bases)} finite points, got {tips.shape}")
            d = np.einsum("ij,ij->i", tips - self.peg_bases, self.peg_normals)
        radius = self.shaped_radius(self._offset_field(tips), tips)
        t1 = time.perf_counter()
        head = self._surface(radius, top_z=self.top_z_for(tips))
        t2 = time.perf_counter()
        mesh = self._mesh(head, nu, nv)
        t3 = time.perf_counter()
        return FaceResult(mesh, self.provenance_for(d),
                          {"field": t1 - t0, "pde": t2 - t1, "mesh": t3 - t2, "total": t3 - t0},
                          tips=tips, depths=d, head=head)

    def shaped_radius(self, offset: np.ndarray, tips: np.ndarray) -> np.ndarray:
        """The face's radius (K, M) over the profile: the tissue-depth ``offset`` field, then what a depth
        field cannot make (the nose, the lips, the ears). One place for :meth:`solve` and the live path."""
        radius = self.profile + offset
        cols, front = self._front()
        face = radius[:, cols]
        bump = self._nose_bump(face, tips, front)
        if bump is not None:
            face = face + bump
        lips = self._mouth_shape(face, front)
        if lips is not None:
            face = face + lips
        eyes = self._eye_shape(face, front)
        if eyes is not None:
            face = face + eyes
        radius[:, cols] = face
        ears = self._ear_shape()
        if ears is not None:
            radius = radius + ears
        return radius

    def top_z_for(self, tips: np.ndarray) -> float | None:
        """The dome's top: the vertex peg's tip height (above the rows, not in the radial field), if any."""
        vertex = self._peg_tip(tips, "Vertex")
        return float(vertex[2]) if vertex is not None else None

    def provenance_for(self, depths: np.ndarray) -> dict:
        """The provenance of a face solved with the pegs at ``depths`` (mm)."""
        prov = dict(self.provenance)
        if self.mouth is not None:
            prov["predicted_mouth_width_mm"] = round(float(self.mouth["width_mm"]), 1)
            if self.mouth.get("stomion_z") is not None:
                prov["predicted_stomion_z_mm"] = round(float(self.mouth["stomion_z"]), 1)
        if self._ear_shape() is not None:
            prov["ears"] = f"default ear ({EAR_LENGTH_MM:g} x {EAR_WIDTH_MM:g} mm, Farkas 1994 norms) at each porion"
        prov["peg_depths_mm"] = {n: round(float(x), 2) for n, x in zip(self.peg_names, depths)}
        return prov


def face_from_skull(skull: Mesh, landmarks: dict, table, **kw) -> FaceResult:
    """Prepare and solve at the table's means: the face of a skull in one call (see :class:`FaceModel`)."""
    solve_kw = {k: kw.pop(k) for k in ("depths", "tips") if k in kw}
    model = FaceModel.prepare(skull, landmarks, table, **kw)
    res = model.solve(**solve_kw)
    res.timings["prepare"] = model.prepare_seconds
    return res
