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
   than :data:`DAMP_FREE_MM` at the table's means, which it follows less closely (:meth:`FaceModel._site_damping`).
   It is linear in the depths; a peg's influence fades within about 2 ``spread_mm``.
4. *Prediction rules* for what a depth field cannot make: the nose (:func:`predict_nose`: its width from
   the nasal aperture, its base from the aperture's floor, its tip from the nasal length;
   :meth:`FaceModel._nose_bump` builds it from a dorsum, a rounded tip lobule, a columella and two alae),
   the eyes (:func:`predict_eyes`: the corneal apex; :meth:`FaceModel._eye_shape`: the closed lids between
   canthi placed from the lateral orbital margin), the mouth (:func:`predict_mouth`: the oral fissure at the
   occlusal midpoint of the incisors' crests, the width from the canines; :meth:`FaceModel._mouth_shape` draws
   the fissure, the vermilion outlines with a cupid's bow, the philtrum and the mentolabial sulcus) and a
   default ear at each porion (:func:`predict_ears`, :meth:`FaceModel._ear_shape`), each cited in its docstring.
5. *The face*: profile + depth field + nose + lips + eyes + ears = radius per bin; each row is a closed boundary curve;
   the C2 PDE surface through them (:func:`.pde_surface.solve_pde`, dome over the vertex, a flat cap
   under the neck) is the face, a closed mesh in patient mm.

Everything that does not depend on the depths (the profile, the grid, the kernels between the rule
sites) is computed once in :meth:`FaceModel.prepare`; :meth:`FaceModel.solve` evaluates the linear
field, adds the nose, solves the PDE and meshes it (tens of ms).

Every result carries :data:`APPROXIMATION_LABEL` and its provenance: it is an approximation, not an
identification.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from . import defaults as D
from .boundary_set import BoundarySet, knots_from_heights
from .errors import PDEHeadError
from .mesh import Mesh
from .provenance import SOFTWARE_VERSION

APPROXIMATION_LABEL = D.FACE_LABEL

#: Depth (mm) where no peg stands: the vault and the back of the head. The T-Table 2023 grand means at
#: vertex (5.0 mm) and opisthocranion (6.0 mm) (Hona & Stephan 2024, Int J Legal Med 138(2):519-535,
#: doi:10.1007/s00414-023-03087-x, values as printed in esomjai/Forensic-Craniofacial-Approximation-
#: Validation-Tool, "FSTT/Generating FSTT cylinders in Slicer.md"), rounded to their mean.
RULE_DEPTH_MM = 5.5
#: Weight of the rule depth in the Shepard average (a peg at distance ``spread_mm`` weighs e^-1 = 0.37).
RULE_WEIGHT = 0.04
#: The neck below the skull: radius (mm) of the neck about its axis, which lies this far behind the
#: skull's centroid axis. Adult neck circumference ~ 36-40 cm (anthropometric surveys, e.g. Ben-Noun et al.
#: 2001, Obesity Research 9(8):470-477: men 38.0 cm, women 32.5 cm mean; cited from memory of that survey,
#: not re-read) -> radius ~ 55-60 mm. It shapes only the neck, outside the scored face.
NECK_RADIUS_MM = 57.0
NECK_BEHIND_MM = 12.0
#: How fast the neck recedes below the skull base (mm per mm of height: 0.8 ~ a 40 degree slope).
NECK_SLOPE = 0.8
#: The bone's radius map is made on at most this many columns (2 degrees) and interpolated to the face's grid:
#: a finer bin meets no bone vertex on a coarse skull mesh (GE: 29 % within +-2.5 mm on a 360-column map against
#: 35 % on this one; CThead unchanged), and the bone's outline needs no more; the face's grid is finer for the nose,
#: the lips and the eyes (:data:`.defaults.FACE_COLUMNS`).
PROFILE_COLUMNS = 180
#: Closing of the bone's radius map: how wide a gap (mm) the envelope bridges (the orbit is ~ 40 mm wide,
#: the nasal aperture ~ 25 mm).
CLOSING_MM = 15.0
#: Radius (mm) over which the bone's normal at a landmark is averaged (:func:`peg_normals`).
PEG_NORMAL_RADIUS_MM = 8.0
#: A peg follows the averaged bone normal unless it leans more than 45 degrees from the closed profile's
#: normal (then the profile's): e.g. subspinale on a mask whose thin maxilla is gone faces up, not forward.
PEG_NORMAL_MIN_COS = 0.7
#: A skull must give at least this many ``ok`` landmarks (:func:`_check_skull`).
MIN_OK_LANDMARKS = 8
#: Vertical Gaussian smoothing (mm) of the closed profile: each row's hull is made on its own, and rows a few mm
#: apart step (the teeth, the zygomatic arches' edges); a skin does not.
PROFILE_SMOOTH_MM = 4.0
#: ... and around the head (degrees; the Gaussian of the profile and of its normals): one column of the first,
#: 180-column grid, kept in degrees when the grid became 360 columns (issue 23's sixth session).
PROFILE_SMOOTH_DEG = 2.0
#: Away from the pegs the closed profile is smoothed more, in 2-D on the (angle, height) grid: a Gaussian of
#: :data:`PROFILE_SMOOTH_FAR_MM` of height and :data:`PROFILE_SMOOTH_FAR_ARC_MM` of arc (at the median radius).
#: Each row's hull is made on its own, which leaves horizontal ridges across the lower face (the teeth, the
#: mandible's rows, the cheeks' bridges) that no peg corrects; smoothing around the head instead costs
#: accuracy (the profile's shape across the face is information), so the smoothing is mostly along the height.
#: Within about :data:`PROFILE_NEAR_MM` of a peg tip the lightly smoothed profile is kept (Gaussian blend).
#: CThead (bench_face, issue 23b): 57.3 % / mean 2.86 / p95 7.99 mm before, 57.5 % / 2.80 / 7.78 after;
#: row-to-row second difference of the face's radius over the scored region 0.48 -> 0.40 mm.
PROFILE_SMOOTH_FAR_MM = 8.0
PROFILE_SMOOTH_FAR_ARC_MM = 2.0
PROFILE_NEAR_MM = 10.0
#: Width of the exact correction's Gaussians, as a fraction of ``spread_mm``.
NARROW_FRACTION = 0.5
#: Regularisation of the exact peg interpolation (relative to the kernel's unit diagonal).
RBF_REGULARISATION = 0.05
#: A peg whose offset disagrees with what its neighbours give there (the wide field without it) by more than
#: :data:`DAMP_FREE_MM` is followed less closely by the exact correction: its regularisation grows by
#: ((disagreement - DAMP_FREE_MM) / DAMP_SCALE_MM)^2 (:meth:`FaceModel._site_damping`). The T-Table's 26 mm
#: supra-M2 and 22 mm sub-M2 pegs stand 10-15 mm off their 8-13 mm neighbours at the jaw's border: a field
#: through all of them exactly is lumpy there. Computed once, at the table's means, from the skull and the table
#: alone (nothing of the scored skin); the pegs on the mid-sagittal profile (within
#: :data:`DAMP_MIDLINE_DEG` of straight ahead) stay exact: the nose and the lips stand on them. CThead
#: (bench_face, issue 23's fifth session): 60.1 % / mean 2.66 / p95 7.47 mm before, 62.0 % / 2.56 / 7.38 after;
#: mean second difference of the face's radius over the front of the lower face 0.49 -> 0.38 mm along the
#: height, 0.38 -> 0.25 mm around the head; GE unchanged (34.2 %).
DAMP_FREE_MM = 4.0
DAMP_SCALE_MM = 5.0
DAMP_MIDLINE_DEG = 10.0


# ------------------------------------------------------------------------------------------ geometry
@dataclass
class _Grid:
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


def _columns(degrees: float, grid: "_Grid") -> float:
    """An angle in columns of the grid."""
    return float(np.radians(degrees) / (grid.theta[1] - grid.theta[0]))


def _resample_columns(table: np.ndarray, columns: int) -> np.ndarray:
    """A (K, M) map periodic in its columns, linearly interpolated to ``columns`` columns (NaN stays NaN)."""
    K, M = table.shape
    f = np.arange(columns) * (M / columns)
    j0 = np.floor(f).astype(int) % M
    a = f - np.floor(f)
    return (1 - a) * table[:, j0] + a * table[:, (j0 + 1) % M]


def bone_profile(skull: Mesh, grid: _Grid, base_z: float | None = None,
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
        coarse = _Grid(grid.centre, grid.z, np.arange(PROFILE_COLUMNS) * 2 * np.pi / PROFILE_COLUMNS)
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


def _smooth_far_from_pegs(profile: np.ndarray, grid: _Grid, sites: np.ndarray) -> np.ndarray:
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


def _neck_fill(raw: np.ndarray, grid: _Grid, base_z: float | None = None) -> np.ndarray:
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


def envelope_normals(grid: _Grid, profile: np.ndarray, points: np.ndarray, smooth_mm: float = 6.0) -> np.ndarray:
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


def peg_normals(skull: Mesh, bases: np.ndarray, grid: _Grid, profile: np.ndarray,
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


def _check_skull(landmarks: dict, flags: dict | None) -> None:
    """Refuse what is not a skull: the face is built around the orbits, so both orbits must have been found
    (Orbitale or Supraorbital, left and right), and at least :data:`MIN_OK_LANDMARKS` landmarks must be ``ok``
    (an ellipsoid or a box gives a few ``uncertain`` guesses and nothing ``ok``)."""
    have = set(landmarks) if flags is None else {n for n in landmarks if flags.get(n, "ok") != "not_found"}
    orbits = all(f"Orbitale {s}" in have or f"Supraorbital {s}" in have for s in "LR")
    ok = len(have) if flags is None else sum(1 for n in have if flags.get(n, "ok") == "ok")
    if not orbits or ok < MIN_OK_LANDMARKS:
        raise PDEHeadError(f"this does not look like a skull: {'no orbits were found' if not orbits else ''}"
                           f"{' and ' if not orbits and ok < MIN_OK_LANDMARKS else ''}"
                           f"{f'only {ok} landmarks were found with confidence' if ok < MIN_OK_LANDMARKS else ''}"
                           " (a face is approximated only on a skull with its orbits; place the landmarks by hand "
                           "if the automatic ones failed)")


# ------------------------------------------------------------------------------------------ prediction rules
def _pt(landmarks: dict, *names):
    for n in names:
        if n in landmarks and landmarks[n] is not None:
            return np.asarray(landmarks[n], float)
    return None


#: The closed eye (:meth:`FaceModel._eye_shape`). The palpebral fissure runs from the exocanthion, EYE_EX_INSET_MM
#: medial of the lateral orbital margin, EYE_FISSURE_MM toward the midline to the endocanthion: adult norms
#: ex-en ~ 30 mm (Farkas LG (1994) Anthropometry of the Head and Face, 2nd ed.) and the exocanthion ~ 4-5 mm inside
#: the lateral orbital rim (Stephan CN, Davidson PL (2008) "The placement of the human eyeball and canthi in
#: craniofacial identification", J Forensic Sci 53(3):612-619); both cited from the forensic literature, not
#: re-read for this module. The fissure's height is the orbit's mid-height (Supraorbital and Suborbital/Orbitale).
EYE_EX_INSET_MM = 5.0
EYE_FISSURE_MM = 30.0
#: Shape (mm): the globe's convexity under the lids, the fissure's groove (the upper lid's margin over the lower),
#: the upper lid's arc above the canthi's line, and the supratarsal crease above it. Shape choices.
EYE_GLOBE_MM = 2.0
EYE_FISSURE_GROOVE_MM = 1.2
EYE_LID_ARC_MM = 2.5
EYE_CREASE_MM = 0.8
EYE_CREASE_ABOVE_MM = 8.0


def predict_eyes(landmarks: dict) -> list[tuple[str, np.ndarray, float]]:
    """Eye sites: the corneal apex of each eye.

    Method: the cornea's apex lies on the line from the mid-supraorbital to the mid-infraorbital margin
    (the "tangent" guideline: Wilkinson CM, Mautner SA (2003) "Measurement of eyeball protrusion and its
    application in facial reconstruction", J Forensic Sci 48(1):12-16; Stephan CN (2002) "Facial
    approximation: globe projection guideline falsified by exophthalmometry literature", J Forensic Sci
    47(4):730-735, which replaced the older 16 mm-from-lateral-orbit guideline). Both are cited from the
    forensic literature, not re-read for this module. The apex is put on the midpoint of the
    ``Supraorbital`` and ``Suborbital`` (or ``Orbitale``) landmarks, 1 mm in front of it for the lid.
    Guyomarc'h P, Dutailly B, Couture C, Coqueugniot H (2012), "Anatomical placement of the human eyeball
    in the orbit - validation using CT scans of living adults and prediction for facial approximation",
    J Forensic Sci 57(5):1271-1275, place the globe from the orbit's breadth and height. The version read
    was esomjai/Forensic-Craniofacial-Approximation-Validation-Tool, "Eye predictions/Guyomarc'h GUI.md",
    where the corneal apex sits 0.513 x the orbit height in front of the deepest lateral orbital margin.
    That method needs ectoconchion and dacryon, which the landmark set lacks, so it is not used here.

    Returns
    -------
    list of (name, point patient mm, weight): the apex of each eye found.
    """
    out = []
    for side in ("L", "R"):
        so, sb = _pt(landmarks, f"Supraorbital {side}"), _pt(landmarks, f"Suborbital {side}", f"Orbitale {side}")
        if so is None or sb is None:
            continue
        mid = 0.5 * (so + sb)
        mid[1] -= 1.0                                  # the closed lid, ~1 mm over the cornea (anterior = -y)
        out.append((f"Eye {side}", mid, 1.0))
    return out


#: Nasal tip protrusion (subnasale to pronasale, mm) and alar width (mm) of adults, both sexes pooled:
#: Farkas LG (1994) Anthropometry of the Head and Face, 2nd ed., New York: Raven Press (North American
#: Caucasian norms: sn-prn about 20 mm in men and 19 mm in women; al-al about 35 and 31 mm), as quoted in
#: the forensic literature on nose prediction (e.g. Rynn, Wilkinson & Peters 2010, below). Cited from that
#: literature, not re-read for this module: check the values against Farkas before casework.
NOSE_PROTRUSION_MM = 19.5
NOSE_ALAR_WIDTH_MM = 33.0
#: Krogman's rule: the alae lie about 5 mm lateral of the nasal aperture's widest point on each side
#: (Krogman WM, Iscan MY (1986) The Human Skeleton in Forensic Medicine, 2nd ed., Springfield: Thomas;
#: cited from the forensic literature, not re-read for this module).
ALAR_MARGIN_MM = 5.0
#: Nasal length (soft nasion to pronasale, mm) from the bony nasion-subspinale distance Z:
#: NL = NASAL_LENGTH_SLOPE x Z + NASAL_LENGTH_INTERCEPT_MM, Rynn C, Wilkinson CM, Peters HL (2010) "Prediction of
#: nasal morphology from the skull", Forensic Sci Med Pathol 6(1):20-34, their European-ancestry equation for
#: both sexes. Read in esomjai/Forensic-Craniofacial-Approximation-Validation-Tool, the guide "Rynn et al.
#: 2010's technique", table "Nasal length" ("pred Rynn EA NL = 0.74 x Z + 3.5", Z the nasion-subspinale line);
#: not re-read in the paper.
NASAL_LENGTH_SLOPE = 0.74
NASAL_LENGTH_INTERCEPT_MM = 3.5
#: The nasal aperture's lower border is looked for in a band this wide (mm, half width) about the midline, at
#: most this far (mm) behind the upper jaw's front (:func:`aperture_floor`).
APERTURE_BAND_MM = 4.0
APERTURE_DEPTH_MM = 25.0
#: Half the nose's breadth at its root (mm): the nasal root between the eyes (Farkas' intercanthal width
#: en-en ~ 32 mm; the root ~ 2/3 of it), where the dorsum leaves the soft nasion.
NOSE_ROOT_HALF_MM = 10.0
#: The nose's parts (:meth:`FaceModel._nose_bump`). Half widths (mm): the dorsum at the tip's height (at the root it
#: is :data:`NOSE_ROOT_HALF_MM`), the tip lobule (across the domes) and the columella (~ 7 mm wide). The lobule
#: reaches :data:`NOSE_TIP_UP_MM` up the dorsum (the supratip) and :data:`NOSE_TIP_DOWN_FRACTION` of the way down
#: to subnasale. Shape choices of an average adult nose (no bone predicts them), not measurements.
NOSE_DORSUM_HALF_MM = 8.0
NOSE_TIP_HALF_MM = 11.0
NOSE_TIP_UP_MM = 11.0
NOSE_TIP_DOWN_FRACTION = 0.8
#: The lobule's bluntness across: its depth falls as (1 - (dx / half width)^2)^NOSE_TIP_BLUNT (0.5: an ellipse,
#: pointed when it is deeper than it is wide; smaller: a fuller tip with steeper sides); along the height it
#: is an ellipse (a rounded tip in profile). A shape choice.
NOSE_TIP_BLUNT = 0.45
#: In profile the lobule is an ellipse this deep (mm) about pronasale (its radius of curvature ~ up^2 / depth), not
#: the whole way to the face: a rounded tip rather than a point. A shape choice.
NOSE_TIP_DEPTH_MM = 9.0
NOSE_COLUMELLA_HALF_MM = 3.5
#: The alae: each :data:`NOSE_ALA_HALF_MM` half wide and :data:`NOSE_ALA_HEIGHT_MM` high, standing
#: :data:`NOSE_ALA_FRACTION` of the tip's protrusion (subnasale to pronasale) off the face, a groove
#: :data:`NOSE_ALAR_GROOVE_MM` deep round them. Their outer edges are at half the alar width (:func:`predict_nose`,
#: from the aperture). Shape choices, not measurements.
NOSE_ALA_HALF_MM = 9.0
NOSE_ALA_HEIGHT_MM = 16.0
NOSE_ALA_FRACTION = 0.33
NOSE_ALAR_GROOVE_MM = 0.6
#: The smooth maximum that joins the parts (:func:`_smooth_max`): how close (mm) two parts must be to be blended.
NOSE_BLEND_MM = 2.0
#: Pegs that stand on the nasal dorsum: the nose's ridge runs through their tips.
NOSE_DORSUM_PEGS = ("Rhinion", "Mid-nasal")


def aperture_width(skull: Mesh, subspinale: np.ndarray, mid_x: float) -> float | None:
    """Widest breadth (mm) of the nasal aperture: at heights 6-20 mm above subspinale, the widest gap around
    the midline between the front bone (within 25 mm behind subspinale) on the two sides. None if not seen."""
    v = skull.vertices
    best = None
    for dz in np.arange(6.0, 21.0, 2.0):
        m = (np.abs(v[:, 2] - (subspinale[2] + dz)) < 1.0) & (v[:, 1] < subspinale[1] + 25.0)
        x = v[m, 0]
        left, right = x[x > mid_x + 2.0], x[x < mid_x - 2.0]
        if left.size and right.size:
            w = float(left.min() - right.max())
            if 12.0 < w < 45.0 and (best is None or w > best):
                best = w
    return best


def aperture_floor(skull: Mesh, subspinale: np.ndarray, nasion: np.ndarray, mid_x: float) -> float | None:
    """Height (patient z, mm) of the nasal aperture's lower border at the midline: the lowest 1 mm row above
    subspinale where the mid-sagittal band (|x - mid_x| < :data:`APERTURE_BAND_MM`) has no bone within
    :data:`APERTURE_DEPTH_MM` behind subspinale, on a run of at least 5 such rows (the aperture, not a hole in a
    thin maxilla). A property of the whole aperture's outline, not of the anterior nasal spine's tip (a thin
    bone a bone mask rarely keeps). None when no such run lies between subspinale and 10 mm below nasion."""
    v = skull.vertices
    band = (np.abs(v[:, 0] - mid_x) < APERTURE_BAND_MM) & (v[:, 1] < subspinale[1] + APERTURE_DEPTH_MM)
    z0, z1 = float(subspinale[2]), float(nasion[2]) - 10.0
    if z1 - z0 < 10.0:
        return None
    rows = np.arange(z0, z1, 1.0)
    k = np.floor(v[band, 2] - z0).astype(int)
    bone = np.zeros(rows.size, bool)
    bone[k[(k >= 0) & (k < rows.size)]] = True
    gap = ~bone
    # runs of empty rows: the first run of 5 or more from below
    run = np.convolve(gap.astype(int), np.ones(5, int), mode="valid") == 5
    starts = np.nonzero(run)[0]
    return float(rows[starts[0]]) if starts.size else None


def _smooth_max(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """max(a, b) with its crease rounded where the two are within ``k`` of each other (the polynomial smooth
    maximum: + k h^2 / 4, h = max(k - |a - b|, 0) / k), faded out where both are 0 (nothing is added there)."""
    m = np.maximum(a, b)
    h = np.clip(k - np.abs(a - b), 0.0, None) / k
    return m + 0.25 * k * h * h * np.clip(m / k, 0.0, 1.0)


def _circle_meet(a: np.ndarray, ra: float, b: np.ndarray, rb: float) -> np.ndarray:
    """The anterior (smaller y) meeting point in the (y, z) plane of the circles about ``a`` (radius ``ra``) and
    ``b`` (radius ``rb``); where they do not meet, the point on the line a-b that splits the gap."""
    d_vec = b - a
    d = float(np.hypot(*d_vec))
    u = d_vec / max(d, 1e-9)
    along = (d * d + ra * ra - rb * rb) / (2 * max(d, 1e-9))
    h = np.sqrt(max(ra * ra - along * along, 0.0))
    perp = np.array([-u[1], u[0]])
    if perp[0] > 0:                                           # anterior is -y
        perp = -perp
    return a + along * u + h * perp


def predict_nose(landmarks: dict, skull: Mesh | None = None) -> dict | None:
    """The nose: what of it the bone predicts (its width, its base), the rest from population norms.

    * *Width*: the alar width is the nasal aperture's greatest breadth plus ``2 x ALAR_MARGIN_MM``
      (Krogman & Iscan 1986: the alae lie ~5 mm lateral of the aperture on each side); where the aperture
      is not seen, ``NOSE_ALAR_WIDTH_MM`` (Farkas 1994). Rynn C, Wilkinson CM, Peters HL (2010),
      "Prediction of nasal morphology from the skull", Forensic Sci Med Pathol 6(1):20-34, found the
      aperture's width the best bony predictor of the alar width.
    * *Base*: soft subnasale at the height of the nasal aperture's lower border (:func:`aperture_floor`,
      the outline of the whole aperture, not the anterior nasal spine's tip or subspinale's depth), on the face
      the depth field makes there (the pegs around it, not one peg's tip); where the aperture's border is not
      found, 4 mm above subspinale. Soft nasion at the nasion peg's tip.
    * *Pronasale*: where two distances from the skull meet, in the mid-sagittal plane, in front: the nasal
      length from soft nasion, NL = 0.74 x Z + 3.5 mm (Z = bony nasion to subspinale; Rynn, Wilkinson & Peters
      2010, European-ancestry equation, :data:`NASAL_LENGTH_SLOPE`), and the tip's protrusion from subnasale,
      ``NOSE_PROTRUSION_MM`` (Farkas 1994). Z is a long, mostly vertical distance: a few mm of error in
      subspinale's depth (a thin bone on the bone mask's outline) moves it by a fraction of a mm.

    The threefold-ANS rule (Gerasimov 1955; Prokopec M, Ubelaker DH (2002) "Reconstructing the shape of
    the nose according to the skull", Forensic Sci Commun 4(1); implemented in esomjai/Forensic-
    Craniofacial-Approximation-Validation-Tool, "Nose predictions/Threefold ANS GUI.md": pronasale = the
    soft mid-philtrum + 3 x the spine's length along the spine) needs the anterior nasal spine, a thin
    bone that a binary mask at the bone level rarely keeps (on CThead it is not in the mask); it is not
    used.

    Returns the constant parts (``width_mm``, ``mid_x``); :meth:`FaceModel._nose_bump` places the nose on
    the current peg tips.
    """
    n = _pt(landmarks, "Nasion", "Glabella")
    ss = _pt(landmarks, "Subspinale", "Mid-philtrum")
    if n is None or ss is None:
        return None
    mid_x = 0.5 * (n[0] + ss[0])
    width, source = NOSE_ALAR_WIDTH_MM, "Farkas 1994 mean alar width"
    if skull is not None:
        ap = aperture_width(skull, ss, mid_x)
        if ap is not None:
            width, source = ap + 2 * ALAR_MARGIN_MM, f"aperture {ap:.1f} mm + 2 x {ALAR_MARGIN_MM:g} mm (Krogman)"
    floor = aperture_floor(skull, ss, n, mid_x) if skull is not None else None
    z_len = float(np.hypot(n[1] - ss[1], n[2] - ss[2]))
    return dict(width_mm=float(width), width_source=source, mid_x=float(mid_x),
                protrusion_mm=NOSE_PROTRUSION_MM, subnasale_z=floor,
                length_mm=NASAL_LENGTH_SLOPE * z_len + NASAL_LENGTH_INTERCEPT_MM)


#: The lips' shape about the oral fissure (stomion), over the face the depth field makes (whose depths at mid-philtrum,
#: supradentale, infradentale and supramentale set how far forward the lips stand). Heights from the fissure:
#: the upper vermilion LIP_UPPER_MM high (labrale superius at its border), the lower LIP_LOWER_MM, and the
#: mentolabial sulcus (sublabiale) LIP_SULCUS_MM below the fissure: adult norms, sto-ls ~ 8 mm, sto-li ~ 9-10 mm,
#: sto-sl ~ 17-19 mm (Farkas LG (1994) Anthropometry of the Head and Face, 2nd ed., Raven Press; cited from the
#: anthropometric literature, not re-read for this module).
LIP_UPPER_MM = 8.0
LIP_LOWER_MM = 9.5
LIP_SULCUS_MM = 18.0
#: Depths (mm): the oral fissure's groove at the midline (tapering to the corners), the vermilion rolls' forward
#: bulge, and the sulcus' and the philtrum's hollows. Shape choices (a closed, relaxed mouth), not measurements.
LIP_GROOVE_MM = 3.0
LIP_GROOVE_HALF_MM = 1.5
LIP_ROLL_MM = 1.5
LIP_SULCUS_DEPTH_MM = 3.0
LIP_PHILTRUM_MM = 1.0
#: The cupid's bow: the upper vermilion's border dips this much (mm) at the midline between two peaks
#: LIP_BOW_PEAK_MM either side (the philtral columns' feet). A shape choice.
LIP_BOW_DIP_MM = 1.5
LIP_BOW_PEAK_MM = 5.0


def predict_mouth(landmarks: dict) -> dict | None:
    """The mouth: its width from the canines and its line (the oral fissure, stomion) from the teeth.

    * *Width*: the inter-canine width is about 75 % of the mouth's width (cheilion to cheilion): Stephan CN,
      Henneberg M (2003) "Predicting mouth width from inter-canine width - a 75 % rule", J Forensic Sci
      48(4):725-727 (abstract read at the ASME digital collection's page of the article; the rule is in
      its title). The canines are ``Supra canine L/R`` (the maxillary canine eminences).
    * *Line*: the oral fissure lies at the occlusal plane, where the upper and lower incisors meet; its
      height is taken half way between the alveolar crests, supradentale and infradentale (the incisors'
      crowns are of similar height). Wilkinson CM, Motwani M, Chiang E (2003) "The relationship between
      the soft tissues and the skeletal detail of the mouth", J Forensic Sci 48(4):728-732, relate the
      lips' thickness to the teeth's height (abstract read at ojp.gov, NCJ 201544); without the teeth's
      crowns in a bone mask their regression is not used: the lips' thickness is the depth pegs'
      (mid-philtrum, supradentale, infradentale) and the vermilion rolls are a shape choice
      (:data:`LIP_ROLL_MM`).

    Returns ``width_mm``, ``centre`` (the canines' midpoint), ``mid_x`` and ``stomion_z`` (None where the
    incisors' crests are not found), or None without both canines.
    """
    c = [_pt(landmarks, f"Supra canine {s}") for s in "LR"]
    if c[0] is None or c[1] is None:
        return None
    icw = float(np.linalg.norm(c[0][:2] - c[1][:2]))
    centre = 0.5 * (c[0] + c[1])
    sd, idn = _pt(landmarks, "Supradentale"), _pt(landmarks, "Infradentale")
    stomion_z = float(0.5 * (sd[2] + idn[2])) if sd is not None and idn is not None and sd[2] > idn[2] else None
    mid = [p for p in (sd, idn, _pt(landmarks, "Subspinale")) if p is not None]
    mid_x = float(np.mean([p[0] for p in mid])) if mid else float(centre[0])
    return dict(width_mm=icw / 0.75, centre=centre, mid_x=mid_x, stomion_z=stomion_z)


#: The external ear (Farkas LG (1994) Anthropometry of the Head and Face, 2nd ed., Raven Press: adult ear
#: length sa-sba ~ 62 mm in men and 59 mm in women, width pra-pa ~ 35 and 32 mm; cited from the
#: anthropometric literature, not re-read for this module): a default ear, the same for every skull, since no
#: bone predicts the ear's shape (Wilkinson 2010, J Anat 216(2):235-250: the ears are among what "needs
#: artistic interpretation").
EAR_LENGTH_MM = 60.0
EAR_WIDTH_MM = 33.0
#: How far the auricle's rim stands off the head (mm) and the concha's hollow (mm): a shape choice for the
#: radial representation (it cannot fold the helix over), not a measurement.
EAR_PROTRUSION_MM = 12.0
EAR_CONCHA_MM = 6.0
#: The auricle's centre relative to porion (the ear canal's top): up (mm), back (mm), and the long axis' tilt
#: backward from vertical (degrees; the ear's usual inclination, a shape choice).
EAR_UP_MM = 8.0
EAR_BACK_MM = 10.0
EAR_TILT_DEG = 15.0


def predict_ears(landmarks: dict) -> list[dict]:
    """The ears at the porions: a default auricle (:data:`EAR_LENGTH_MM` x :data:`EAR_WIDTH_MM`, its centre
    :data:`EAR_UP_MM` above and :data:`EAR_BACK_MM` behind porion, the ear canal at its front lower part),
    one per porion found. Returns dicts with ``side`` and ``centre`` (patient mm)."""
    out = []
    for side in "LR":
        po = _pt(landmarks, f"Porion {side}")
        if po is None:
            continue
        out.append(dict(side=side, porion=po, centre=po + np.array([0.0, EAR_BACK_MM, EAR_UP_MM])))
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


def _kernel(a: np.ndarray, b: np.ndarray, sigma: float) -> np.ndarray:
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
    grid: _Grid
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

        Parameters
        ----------
        skull : Mesh
            The bone skull (:func:`.skull.skull_mesh` or a ``--skull-mesh``), patient LPS mm.
        landmarks : dict of str to (3,) array
            Landmarks on the bone (patient mm); those the table has become pegs, the others feed the
            prediction rules (nose, eyes, mouth).
        table : DepthTable or dict
            The depth table (mean depth per landmark name; SDs from ``table.sd`` where it has them).
        sex : str, optional
            Kept in the provenance; the shipped T-Table 2023 is pooled (no sex split).
        flags : dict, optional
            The landmarks' flags (``ok`` / ``uncertain`` / ``not_found``), for the provenance.
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
        _check_skull(lm, flags)
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
        grid = _Grid(centre, np.linspace(zlo, zhi, K), np.arange(columns) * 2 * np.pi / columns)
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
        from .provenance import provenance
        prov_table = table.provenance_record() if hasattr(table, "provenance_record") else {"table": "imported table"}
        prov = provenance(label=APPROXIMATION_LABEL, method="face from skull: PDE surface through tissue-depth "
                          "pegs (pdehead_addon.face_from_skull)", sex=sex, **prov_table)
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
        Wg = _kernel(self._grid_xyz, xs, sigma)                        # (G, n)
        Ws = _kernel(xs, xs, sigma)
        base_g = (Wg @ target + RULE_WEIGHT * RULE_DEPTH_MM) / (Wg.sum(1) + RULE_WEIGHT)
        base_s = (Ws @ target + RULE_WEIGHT * RULE_DEPTH_MM) / (Ws.sum(1) + RULE_WEIGHT)
        # narrow exact correction
        s2 = NARROW_FRACTION * sigma
        w = self._correction_weights(xs, target - base_s)
        corr = _kernel(self._grid_xyz, xs, s2) @ w
        return (base_g + corr).reshape(self.profile.shape)

    def _correction_weights(self, xs: np.ndarray, residual: np.ndarray) -> np.ndarray:
        """Weights of the narrow Gaussians of the exact correction at the field sites ``xs`` for the
        ``residual`` (offset minus the wide field at each site), regularised per site
        (:meth:`_site_damping`). One place for :meth:`_offset_field` and the live path."""
        Phi = _kernel(xs, xs, NARROW_FRACTION * self.options["spread_mm"])
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
        W = _kernel(xs, xs, self.options["spread_mm"])
        np.fill_diagonal(W, 0.0)
        others = (W @ target + RULE_WEIGHT * RULE_DEPTH_MM) / (W.sum(1) + RULE_WEIGHT)
        off = np.abs(target - others)
        midline = np.abs(np.angle(np.exp(1j * (th - np.pi)))) < np.radians(DAMP_MIDLINE_DEG)
        excess = np.where(midline, 0.0, np.maximum(off - DAMP_FREE_MM, 0.0))
        return RBF_REGULARISATION + (excess / DAMP_SCALE_MM) ** 2

    def _mouth_shape(self, base: np.ndarray) -> np.ndarray | None:
        """Radial change (K, M) of the lips over the face ``base``: the oral fissure at the stomion's height
        (:func:`predict_mouth`), a groove :data:`LIP_GROOVE_MM` deep at the midline running out to the mouth's
        corners (its width from the canines); the upper and the lower vermilion as rolls whose outlines narrow
        to the corners (heights :data:`LIP_UPPER_MM`, :data:`LIP_LOWER_MM`; the upper border with a cupid's
        bow); the philtrum's shallow hollow above the upper lip; the mentolabial sulcus
        (:data:`LIP_SULCUS_MM` below the fissure) between the lower lip and the chin."""
        mouth = self.mouth
        if mouth is None or mouth.get("stomion_z") is None:
            return None
        g = self.grid
        cx = g.centre[0]
        s, c = np.sin(g.theta), np.cos(g.theta)
        front = (c < -0.2)[None, :]
        x = cx + base * s[None, :]                                  # where each ray meets the face
        dx = x - mouth["mid_x"]
        u = np.abs(dx) / (0.5 * mouth["width_mm"])                  # 0 at the midline, 1 at the corners
        inside = np.clip(1.0 - u * u, 0.0, 1.0)
        dz = g.z[:, None] - mouth["stomion_z"]
        # the fissure: to the corners and a little beyond (the commissures)
        groove = -LIP_GROOVE_MM * np.exp(-0.5 * (dz / LIP_GROOVE_HALF_MM) ** 2) * np.clip(1.15 - u * u, 0.0, 1.0) ** 0.5
        # the vermilion outlines: heights narrow to nothing at the corners; the upper border's cupid's bow
        bow = LIP_BOW_DIP_MM * np.exp(-0.5 * (dx / (0.6 * LIP_BOW_PEAK_MM)) ** 2)
        h_up = np.maximum(LIP_UPPER_MM * np.sqrt(inside) - bow, 0.5)
        h_lo = np.maximum(LIP_LOWER_MM * np.sqrt(inside), 0.5)
        t_up = np.clip(dz / h_up, 0.0, None)
        t_lo = np.clip(-dz / h_lo, 0.0, None)
        roll_up = LIP_ROLL_MM * np.sin(np.pi * np.clip(t_up, 0.0, 1.0)) ** 0.7 * (t_up <= 1.0) * (dz > 0)
        roll_lo = LIP_ROLL_MM * np.sin(np.pi * np.clip(t_lo, 0.0, 1.0)) ** 0.7 * (t_lo <= 1.0) * (dz < 0)
        rolls = (roll_up + roll_lo) * np.sqrt(inside)
        # the philtrum (between the upper lip's border and subnasale) and the mentolabial sulcus
        philtrum = -LIP_PHILTRUM_MM * np.exp(-0.5 * ((dz - LIP_UPPER_MM - 6.0) / 4.0) ** 2) * np.exp(-0.5 * (dx / 5.0) ** 2)
        sulcus = -LIP_SULCUS_DEPTH_MM * np.exp(-0.5 * ((dz + LIP_SULCUS_MM) / 4.0) ** 2) * np.clip(1.0 - (u / 0.9) ** 2, 0.0, 1.0)
        return (groove + rolls + philtrum + sulcus) * front

    def _eye_shape(self, base: np.ndarray) -> np.ndarray | None:
        """Radial change (K, M) of the closed eyes over the face ``base``: per orbit with its lateral margin and
        its mid-height found, the globe's convexity between the canthi (an ellipse of the fissure's length and
        half as high), the fissure as a groove along the upper lid's margin (an arc :data:`EYE_LID_ARC_MM` above
        the line of the canthi at its middle) and the supratarsal crease :data:`EYE_CREASE_ABOVE_MM` above it."""
        lm = getattr(self, "landmarks_used", None) or {}
        g = self.grid
        cx = g.centre[0]
        s, c = np.sin(g.theta), np.cos(g.theta)
        front = (c < -0.2)[None, :]
        x = cx + base * s[None, :]
        zz = g.z[:, None]
        out = None
        for side, sign in (("L", 1.0), ("R", -1.0)):
            so = _pt(lm, f"Supraorbital {side}")
            sb = _pt(lm, f"Suborbital {side}", f"Orbitale {side}")
            lat = _pt(lm, f"Lateral orbit {side}")
            if so is None or sb is None or lat is None:
                continue
            ze = 0.5 * (so[2] + sb[2])
            ex = lat[0] - sign * EYE_EX_INSET_MM
            en = ex - sign * EYE_FISSURE_MM
            t = np.clip((x - en) / (ex - en), -0.3, 1.3)             # 0 at the endocanthion, 1 at the exocanthion
            xm, half = 0.5 * (en + ex), 0.5 * EYE_FISSURE_MM
            q2 = ((x - xm) / half) ** 2 + ((zz - ze) / (0.5 * half)) ** 2
            globe = EYE_GLOBE_MM * np.clip(1.0 - q2, 0.0, None)
            inside = np.clip(np.sin(np.pi * np.clip(t, 0.0, 1.0)), 0.0, None) ** 0.5
            lid = ze + EYE_LID_ARC_MM * np.sin(np.pi * np.clip(t, 0.0, 1.0)) ** 1.5
            fissure = -EYE_FISSURE_GROOVE_MM * np.exp(-0.5 * ((zz - lid) / 1.0) ** 2) * inside
            crease = -EYE_CREASE_MM * np.exp(-0.5 * ((zz - lid - EYE_CREASE_ABOVE_MM) / 1.5) ** 2) * inside
            eye = (globe + fissure + crease) * front
            out = eye if out is None else out + eye
        return out

    def _ear_shape(self) -> np.ndarray | None:
        """Radial ear bumps (K, M) at the porions (:func:`predict_ears`): a raised rim (the helix and the
        lobule, :data:`EAR_PROTRUSION_MM`) around a hollow concha, on an ellipse of the ear's length and
        width tilted :data:`EAR_TILT_DEG` back. Fixed by the skull: computed once."""
        cached = self.__dict__.get("_ears")
        if cached is not None or "_ears" in self.__dict__:
            return cached
        ears = predict_ears(getattr(self, "landmarks_used", {}) or {})
        if not ears:
            self.__dict__["_ears"] = None
            return None
        g = self.grid
        out = np.zeros((len(g.z), len(g.theta)))
        for ear in ears:
            z0, th0, r0 = g.polar(ear["centre"][None])
            z0, th0, r0 = float(z0[0]), float(th0[0]), float(r0[0])
            arc = np.angle(np.exp(1j * (g.theta[None, :] - th0))) * r0   # mm along the head, + toward +theta
            dz = g.z[:, None] - z0
            # theta = 0 is posterior: on the left (theta ~ pi/2) the back is toward smaller theta, on the right
            # (theta ~ 3 pi/2) toward larger; post > 0 behind the ear's centre
            post = -arc if ear["side"] == "L" else arc
            t = np.radians(EAR_TILT_DEG)
            a = dz * np.cos(t) + post * np.sin(t)                       # along the ear's long axis
            b = -dz * np.sin(t) + post * np.cos(t)
            q = np.sqrt((a / (0.5 * EAR_LENGTH_MM)) ** 2 + (b / (0.5 * EAR_WIDTH_MM)) ** 2)
            plate = np.clip(1.0 - q ** 6, 0.0, None)                     # flat top, steep edge
            concha = np.exp(-0.5 * (((a + 0.1 * EAR_LENGTH_MM) / (0.17 * EAR_LENGTH_MM)) ** 2
                                    + ((b + 0.1 * EAR_WIDTH_MM) / (0.2 * EAR_WIDTH_MM)) ** 2))
            out = np.maximum(out, EAR_PROTRUSION_MM * plate - EAR_CONCHA_MM * concha * (plate > 0.2))
        out = ndimage.gaussian_filter(out, sigma=(0.7, 0.7), mode=("nearest", "wrap"))
        self.__dict__["_ears"] = out
        return out

    def _peg_tip(self, tips: np.ndarray, *names) -> np.ndarray | None:
        for n in names:
            if n in self.peg_names:
                return tips[self.peg_names.index(n)]
        return None

    def _nose_bump(self, base: np.ndarray, tips: np.ndarray) -> np.ndarray | None:
        """Radial nose over the face ``base`` (K, M), made of four parts (:func:`predict_nose` gives where):

        * the *dorsum*: a rounded ridge from the soft nasion (the nasion peg's tip) straight to pronasale,
          through the pegs on the dorsum, :data:`NOSE_ROOT_HALF_MM` half wide at the root and
          :data:`NOSE_DORSUM_HALF_MM` at the tip;
        * the *tip lobule*: half an ellipsoid about pronasale, :data:`NOSE_TIP_HALF_MM` half wide (the
          domes), reaching up over :data:`NOSE_TIP_UP_MM` of the dorsum and down over
          :data:`NOSE_TIP_DOWN_FRACTION` of the way to subnasale, so the tip is rounded in both views;
        * the *columella*: a narrow (:data:`NOSE_COLUMELLA_HALF_MM`) ridge from the lobule back to subnasale
          (soft subnasale on the face ``base`` at the aperture's lower border), with a finite slope;
        * the *alae*: one half-ellipsoid each side, their outer edges at half the alar width
          (:func:`predict_nose`), :data:`NOSE_ALA_HALF_MM` half wide, from the alar base at subnasale's height
          up :data:`NOSE_ALA_HEIGHT_MM`, standing :data:`NOSE_ALA_FRACTION` of the tip's protrusion off the face,
          with a shallow alar-facial groove round them (:data:`NOSE_ALAR_GROOVE_MM`).

        The parts are in front of the face along -y and joined by a smooth maximum (a p-norm,
        :data:`NOSE_BLEND_P`); between the columella and the alae, under the lobule, the nostrils are the
        hollows the parts leave. Shapes are choices where no bone predicts them (cited constants say which)."""
        nose = self.nose
        n = self._peg_tip(tips, "Nasion", "Glabella")
        ss = self._peg_tip(tips, "Subspinale", "Mid-philtrum")
        if nose is None or n is None or ss is None:
            return None
        g = self.grid
        cx, cy = g.centre
        s, c = np.sin(g.theta), np.cos(g.theta)
        front = c < -0.2
        zn = float(n[2])
        zs = nose.get("subnasale_z")
        zs = float(ss[2]) + 4.0 if zs is None else float(zs)
        if zn - zs < 20.0:
            return None
        # subnasale on the face the depth field makes at its height (the midline ray of that row)
        ks = int(np.clip(np.round((zs - g.z[0]) / (g.z[1] - g.z[0])), 0, len(g.z) - 1))
        xs_row = cx + base[ks] * s
        js = int(np.argmin(np.where(front, np.abs(xs_row - nose["mid_x"]), np.inf)))
        ys = float(cy + base[ks, js] * c[js])
        yn = float(n[1])
        length = nose.get("length_mm")
        if length is None:                                   # a model kept before the nasal-length rule
            zp, yp = zs + 0.3 * (zn - zs), ys - nose["protrusion_mm"]
        else:
            yp, zp = _circle_meet(np.array([yn, zn]), float(length), np.array([ys, zs]), nose["protrusion_mm"])
            zp = float(np.clip(zp, zs + 2.0, zn - 5.0))
        Z = g.z
        # the dorsum's line: straight, through the pegs on it (rhinion, mid-nasal)
        on = [self._peg_tip(tips, nm) for nm in NOSE_DORSUM_PEGS]
        on = sorted([(float(p[2]), float(p[1])) for p in on if p is not None and zp + 2.0 < p[2] < zn - 2.0])
        zc = np.array([zp] + [a for a, _ in on] + [zn])
        yc = np.array([yp] + [b for _, b in on] + [yn])
        mid_x = nose["mid_x"]
        x = cx + base * s[None, :]                                  # where each ray meets the face
        y = cy + base * c[None, :]
        dx = np.where(front[None, :], x - mid_x, np.inf)
        zz = Z[:, None]
        # the dorsum (rows between pronasale and nasion)
        t = np.clip((zz - zp) / (zn - zp), 0.0, 1.0)
        half = NOSE_DORSUM_HALF_MM + (NOSE_ROOT_HALF_MM - NOSE_DORSUM_HALF_MM) * t
        ridge_y = np.interp(Z, zc, yc)[:, None]
        u = np.clip(np.abs(dx) / half, 0.0, 1.0)
        dorsum = np.clip(y - ridge_y, 0.0, None) * (1.0 - u * u) ** 0.75 * ((zz >= zp) & (zz <= zn))
        # the tip lobule: half an ellipsoid about pronasale (its depth to the face behind it)
        down = NOSE_TIP_DOWN_FRACTION * (zp - zs)
        qz = np.where(zz >= zp, (zz - zp) / NOSE_TIP_UP_MM, (zp - zz) / max(down, 1.0))
        ux = np.clip(np.abs(dx) / NOSE_TIP_HALF_MM, 0.0, 1.0)
        # beyond the ellipse (qz > 1) the lobule falls back steeply but continuously (a row crossing it as a peg
        # moves must not jump)
        qc = np.minimum(qz, 1.0)
        lobule_y = yp + NOSE_TIP_DEPTH_MM * (1.0 - np.sqrt(1.0 - qc * qc) + 4.0 * np.maximum(qz - 1.0, 0.0))
        lobule = np.clip(y - lobule_y, 0.0, None) * (1.0 - ux * ux) ** NOSE_TIP_BLUNT
        # the columella: subnasale -> the lobule's underside, (1 - w^2) from the tip's line
        w = np.clip((zp - zz) / (zp - zs), 0.0, 1.0)
        col_y = ys + (yp - ys) * np.sqrt(np.clip(1.0 - w ** 2, 0.0, 1.0))
        uc = np.clip(np.abs(dx) / NOSE_COLUMELLA_HALF_MM, 0.0, 1.0)
        columella = np.clip(y - col_y, 0.0, None) * (1.0 - uc * uc) ** 0.5 * ((zz >= zs) & (zz <= zp))
        # the alae: their outer edge at half the alar width, from the alar base (subnasale's height) up
        a_half = 0.5 * nose["width_mm"] - NOSE_ALA_HALF_MM
        a_z = zs + 0.5 * NOSE_ALA_HEIGHT_MM
        ala_h = NOSE_ALA_FRACTION * max(ys - yp, 0.0)
        alae = np.zeros_like(base)
        groove = np.zeros_like(base)
        for side in (-1.0, 1.0):
            qa2 = ((dx - side * a_half) / NOSE_ALA_HALF_MM) ** 2 + ((zz - a_z) / (0.5 * NOSE_ALA_HEIGHT_MM)) ** 2
            alae = np.maximum(alae, ala_h * np.clip(1.0 - qa2, 0.0, None) ** 0.5)
            qa = np.sqrt(qa2)
            # the alar-facial groove: outside the ala, on its lateral and lower sides (not toward the tip)
            outside = (side * (dx - side * a_half) > 0) | (zz < a_z)
            groove = np.minimum(groove, -NOSE_ALAR_GROOVE_MM * np.exp(-0.5 * ((qa - 1.08) / 0.1) ** 2) * outside)
        bump = dorsum
        for part in (lobule, columella, alae):
            bump = _smooth_max(bump, part, NOSE_BLEND_MM)
        bump = bump + groove * np.clip(1.0 - bump / 0.5, 0.0, 1.0)
        bump = np.nan_to_num(bump) / np.maximum(-c[None, :], 0.2)   # along -y -> along the ray
        return bump * front[None, :]

    # -------------------------------------------------------------------- solve
    def _surface(self, radius: np.ndarray, nu=None, nv=None, top_z: float | None = None):
        from .pde_surface import solve_pde

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
            cache = bset.__dict__.setdefault("_derived", {})
            key = lambda name: (name, bset.curves.ctypes.data, bset.curves.shape)   # noqa: E731 (pde_surface's key)
            cache[key("positions")] = fixed["positions"]
            cache[key("radius")] = fixed["radius"]
        head = solve_pde(bset, approximation_mm=0.0)
        if not fixed:
            from .pde_surface import curve_positions, smoothing_range
            smoothing_range(bset)                                # computes and caches the mean radius
            fixed["positions"] = curve_positions(bset)
            fixed["radius"] = bset.__dict__["_derived"][("radius", bset.curves.ctypes.data, bset.curves.shape)]
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
        bump = self._nose_bump(radius, tips)
        if bump is not None:
            radius = radius + bump
        lips = self._mouth_shape(radius)
        if lips is not None:
            radius = radius + lips
        eyes = self._eye_shape(radius)
        if eyes is not None:
            radius = radius + eyes
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
