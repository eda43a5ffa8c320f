"""Face from the skull (issue 23): a closed PDE face solved through the tissue-depth pegs.

The practitioner's end product in forensic facial approximation is a face; this module makes one from
the bone skull, its landmarks and a depth table, by the same C2 PDE engine as the skin
(:func:`.pde_surface.solve_pde`), fast enough to re-solve on every peg drag.

Method
------
Everything is expressed on a cylinder of directions about the vertical (patient z) axis through the
skull's centroid: a row every ``row_mm`` of height, a column every ``360 / columns`` degrees.

1. *The bone's outer profile* (:func:`bone_profile`): per (row, column) bin the outermost point of the
   bone skull; a grey-level closing of that radius map closes the orbits, the nasal aperture, the
   foramina and the gaps between the zygomatic arches and the temporal bone (a closed envelope of the
   bone), then a light Gaussian smoothing. Where a column meets no bone (below the skull base at the
   back, below the mandible) the neck rule of :func:`_neck_fill` continues the profile downward.
2. *The pegs*: each landmark of the depth table stands on the bone along the bone's outward normal
   (:func:`.landmarks.marker_pegs`); its tip (base + depth x normal) is where the skin must pass.
   In the cylinder frame each tip is a site (z, angle) with a radial offset over the profile.
3. *The tissue-depth field* (:meth:`FaceModel._offset_field`): over the whole head, a wide
   normalised Gaussian average of the peg offsets (Shepard / partition of unity, radius
   ``spread_mm``) with the rule depth where no peg stands (:data:`RULE_DEPTH_MM`: the vault and the
   neck), plus a narrow Gaussian radial-basis correction that makes the field pass through every
   tip exactly. It is linear in the depths; a peg's influence fades within about 2 ``spread_mm``.
4. *Prediction rules* for what a depth field cannot make: the nose (:func:`predict_nose`), the eyes
   (:func:`predict_eyes`) and the mouth (:func:`predict_mouth`), each cited in its docstring.
5. *The face*: profile + depth field + nose = radius per bin; each row is a closed boundary curve;
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
#: 2001, Obesity Research 9(8):470-477: men 38.0 cm, women 32.5 cm mean) -> radius ~ 55-60 mm.
NECK_RADIUS_MM = 57.0
NECK_BEHIND_MM = 12.0
#: Closing of the bone's radius map: how wide a gap (mm) the envelope bridges (the orbit is ~ 40 mm wide,
#: the nasal aperture ~ 25 mm).
CLOSING_MM = 36.0
#: Regularisation of the exact peg interpolation (relative to the kernel's unit diagonal).
RBF_REGULARISATION = 1e-3


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


def bone_profile(skull: Mesh, grid: _Grid, closing_mm: float = CLOSING_MM) -> tuple[np.ndarray, np.ndarray]:
    """The bone's outer radius per (row, column) bin and its closed envelope.

    Returns
    -------
    raw : (K, M) outermost bone radius per bin (NaN where the bin meets no bone)
    closed : (K, M) the closed, gap-filled, smoothed profile (no NaN)
    """
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
    filled = _neck_fill(raw, grid)
    mean_r = float(np.nanmean(raw))
    kz = max(1, int(round(closing_mm / dz)))
    kt = max(1, int(round(closing_mm / (mean_r * 2 * np.pi / M))))
    # close in (row, angle): periodic in the angle, edge rows repeated
    pad = kz
    padded = np.pad(filled, ((pad, pad), (0, 0)), mode="edge")
    closed = ndimage.grey_closing(padded, size=(kz, kt), mode="wrap")[pad:-pad]
    # the closing must not reach below the bone (it only fills dips): max with the filled map
    closed = np.maximum(closed, filled)
    sm = ndimage.gaussian_filter(np.pad(closed, ((pad, pad), (0, 0)), mode="edge"),
                                 sigma=(1.5 / dz * 1.0, 1.0), mode="wrap")[pad:-pad]
    return raw, sm


def _neck_fill(raw: np.ndarray, grid: _Grid) -> np.ndarray:
    """Fill bins that meet no bone.

    Above the skull's top row the top is repeated. Below the bone (the neck behind the mandible,
    under the chin) each column continues from the lowest bone above it toward the neck, a circle of
    :data:`NECK_RADIUS_MM` about an axis :data:`NECK_BEHIND_MM` behind the skull's axis, receding by at
    most 1 mm per mm of height (a 45 degree submental slope): a rule, not a measurement of this head.
    """
    K, M = raw.shape
    out = raw.copy()
    # columns empty in the middle (rays through gaps above bone): interpolate along z per column first
    for j in range(M):
        col = out[:, j]
        good = np.isfinite(col)
        if good.sum() >= 2:
            lo, hi = np.nonzero(good)[0][[0, -1]]
            idx = np.arange(lo, hi + 1)
            col[lo:hi + 1] = np.interp(idx, np.nonzero(good)[0], col[good])
    # neck radius per column: distance from the skull axis to the neck circle along the ray
    th = grid.theta
    b = NECK_BEHIND_MM
    # ray from the axis centre c in direction (sin th, cos th); neck centre at c + (0, b)
    proj = b * np.cos(th)
    neck = proj + np.sqrt(np.maximum(NECK_RADIUS_MM ** 2 - (b * np.sin(th)) ** 2, 1.0))
    dz = grid.z[1] - grid.z[0]
    top = np.nanmax(np.where(np.isfinite(out), np.arange(K)[:, None], -1), axis=0)
    for k in range(K - 2, -1, -1):                    # downward: from the row above
        miss = ~np.isfinite(out[k]) & np.isfinite(out[k + 1])
        if np.any(miss):
            above = out[k + 1, miss]
            out[k, miss] = np.maximum(np.minimum(above, neck[miss]), above - dz)
    for k in range(1, K):                             # upward (above the top): repeat
        miss = ~np.isfinite(out[k]) & np.isfinite(out[k - 1])
        out[k, miss] = out[k - 1, miss]
    if not np.all(np.isfinite(out)):                  # whole rows missing: the mean of the map
        out[~np.isfinite(out)] = float(np.nanmean(out)) if np.isfinite(np.nanmean(out)) else NECK_RADIUS_MM
    del top
    return out


# ------------------------------------------------------------------------------------------ prediction rules
def _pt(landmarks: dict, *names):
    for n in names:
        if n in landmarks and landmarks[n] is not None:
            return np.asarray(landmarks[n], float)
    return None


def predict_eyes(landmarks: dict) -> list[tuple[str, np.ndarray, float]]:
    """Eye sites: the corneal apex of each eye, where the closed lids lie.

    Method: Stephan CN, Huang T. "Eyeball protrusion": the cornea's apex lies close to the line from the
    mid-supraorbital to the mid-infraorbital margin, on average about 1-2 mm behind it in adults
    (Stephan CN, Huang T, Orbit-based prediction of eyeball protrusion, reviewed in Stephan CN (2002)
    "Facial approximation: globe projection guideline falsified by exophthalmometry literature",
    J Forensic Sci 47(4):730-735, which replaced the older 16 mm-from-lateral-orbit guideline); here the
    apex is put on the mid-point of the supraorbital and suborbital landmarks (with the closed lid's
    ~1 mm over it). Guyomarc'h P, Dutailly B, Couture C, Coqueugniot H (2012), "Anatomical placement of
    the human eyeball in the orbit - validation using CT scans of living adults and prediction for facial
    approximation", J Forensic Sci 57(5):1271-1275, place the globe from orbital breadth and height (read
    in esomjai/Forensic-Craniofacial-Approximation-Validation-Tool, "Eye predictions/Guyomarc'h GUI.md":
    corneal apex 0.513 x orbit height in front of the deepest lateral orbital margin); that needs
    ectoconchion and dacryon, which our landmark set lacks.

    Returns
    -------
    list of (name, point patient mm, weight): the apex of each eye found (lid surface).
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


def predict_nose(landmarks: dict, skull: Mesh | None = None) -> dict | None:
    """The nose: pronasale and the nasal profile from the nasal aperture and the anterior nasal spine.

    Method (the "threefold ANS" rule): the nose projects from the face about three times the length of
    the anterior nasal spine - Prokopec M, Ubelaker DH (2002), "Reconstructing the shape of the nose
    according to the skull", Forensic Science Communications 4(1), after Gerasimov MM (1955) - as
    implemented in esomjai/Forensic-Craniofacial-Approximation-Validation-Tool, "Nose predictions/
    Threefold ANS GUI.md". The nose's width at the alae is the aperture's width plus ~ 10 mm on each
    side... here: the aperture width (alare curvature L-R) x 1.5, after Rynn C, Wilkinson CM, Peters HL
    (2010), "Prediction of nasal morphology from the skull", Forensic Sci Med Pathol 6(1):20-34 (alar
    width ~ 1.5 x... aperture width, their fig. / table of regressions) - a rounded rule, not their
    regression.

    The spine length is taken as the horizontal distance from subspinale to the most anterior bone
    point of the midline between subspinale and 15 mm above it (the spine's tip, acanthion).
    """
    n = _pt(landmarks, "Nasion", "Glabella")
    ss = _pt(landmarks, "Subspinale")
    if n is None or ss is None:
        return None
    tip = ss.copy()
    if skull is not None:
        v = skull.vertices
        near = (np.abs(v[:, 0] - ss[0]) < 3.0) & (v[:, 2] > ss[2]) & (v[:, 2] < ss[2] + 15.0)
        if np.any(near):
            tip = v[near][np.argmin(v[near, 1])]
    spine = max(float(ss[1] - tip[1]), 0.0)
    spine = float(np.clip(spine, 3.0, 12.0))            # a broken or unseen spine: within the adult range
    width = 34.0
    ac = [_pt(landmarks, f"Alare curvature {s}") for s in "LR"]
    if ac[0] is not None and ac[1] is not None:
        aw = abs(ac[0][0] - ac[1][0])
        if 15.0 < aw < 40.0:
            width = 1.5 * aw
    return dict(acanthion=tip, spine_mm=spine, projection_mm=3.0 * spine, nasion=n, subspinale=ss,
                alar_width_mm=width)


def predict_mouth(landmarks: dict) -> dict | None:
    """The mouth: the stomion at the occlusal plane, mouth width from the canines.

    Method: mouth width ~ the distance between the canines' distal borders x ~1.3 (inter-canine width
    predicts mouth width: Stephan CN, Henneberg M (2003), "Predicting mouth width from inter-canine width
    - a 75 % rule", J Forensic Sci 48(4):725-727: the inter-canine width is ~75 % of the mouth width).
    """
    c = [_pt(landmarks, f"Supra canine {s}") for s in "LR"]
    if c[0] is None or c[1] is None:
        return None
    icw = float(np.linalg.norm(c[0][:2] - c[1][:2]))
    return dict(width_mm=icw / 0.75, centre=0.5 * (c[0] + c[1]))


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
    d2 = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
    return np.exp(-d2 / (sigma * sigma))


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
                row_mm: float | None = None, columns: int = 180, spread_mm: float | None = None,
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
        spread = D.FACE_SPREAD_MM.default if spread_mm is None else float(spread_mm)
        lm = {k: np.asarray(v, float) for k, v in landmarks.items() if v is not None}
        pegs = marker_pegs(lm, skull, table)
        if len(pegs) < 4:
            raise PDEHeadError(f"only {len(pegs)} landmarks have a depth in the table: at least 4 are needed "
                               "for a face (run Find Landmarks)")
        names = [p[0] for p in pegs]
        bases = np.array([p[1] for p in pegs])
        normals = np.array([p[2] for p in pegs])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        depths = np.array([p[3] for p in pegs], float)
        sd_of = getattr(table, "sd", None)
        sds = np.array([(sd_of(n) if sd_of else None) or np.nan for n in names], float)
        # the axis: the bone's centroid (area-weighted vertices are close enough: a dense uniform mesh)
        centre = skull.vertices[:, :2].mean(axis=0)
        zlo = float(skull.vertices[:, 2].min()) - neck_mm
        zhi = float(skull.vertices[:, 2].max()) - 4.0
        K = max(8, int(np.ceil((zhi - zlo) / row_mm)) + 1)
        grid = _Grid(centre, np.linspace(zlo, zhi, K), np.arange(columns) * 2 * np.pi / columns)
        raw, profile = bone_profile(skull, grid)
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
        model._grid_xyz = model._cyl(np.repeat(grid.z, columns), np.tile(grid.theta, K))
        model.prepare_seconds = time.perf_counter() - t0
        return model

    # -------------------------------------------------------------------- the field
    def _cyl(self, z, theta) -> np.ndarray:
        """Sites on a cylinder of the mean radius: distances between them ~ distances over the head."""
        rho = 85.0
        return np.stack([rho * np.sin(theta), rho * np.cos(theta), np.asarray(z, float)], axis=-1)

    def tips_for(self, depths: np.ndarray) -> np.ndarray:
        return self.peg_bases + np.asarray(depths, float)[:, None] * self.peg_normals

    def _offset_field(self, tips: np.ndarray) -> np.ndarray:
        """(K, M) radial offset over the profile that passes through every tip (and rule site)."""
        g = self.grid
        sites = [np.asarray(tips, float)] + ([np.array([p for _, p, _ in self.rule_sites])] if self.rule_sites else [])
        pts = np.concatenate(sites)
        z, th, r = g.polar(pts)
        target = r - g.sample(self.profile, z, th)                    # offset each site needs
        xs = self._cyl(z, th)
        sigma = self.options["spread_mm"]
        # wide Shepard average with the rule depth
        Wg = _kernel(self._grid_xyz, xs, sigma)                        # (G, n)
        Ws = _kernel(xs, xs, sigma)
        base_g = (Wg @ target + RULE_WEIGHT * RULE_DEPTH_MM) / (Wg.sum(1) + RULE_WEIGHT)
        base_s = (Ws @ target + RULE_WEIGHT * RULE_DEPTH_MM) / (Ws.sum(1) + RULE_WEIGHT)
        # narrow exact correction
        s2 = 0.5 * sigma
        Phi = _kernel(xs, xs, s2)
        w = np.linalg.solve(Phi + RBF_REGULARISATION * np.eye(len(xs)), target - base_s)
        corr = _kernel(self._grid_xyz, xs, s2) @ w
        return (base_g + corr).reshape(self.profile.shape)

    def _nose_bump(self) -> np.ndarray | None:
        """Radial nose added to the face (K, M): pronasale projection from :func:`predict_nose`."""
        nose = self.nose
        if nose is None:
            return None
        g = self.grid
        n, ss, ac = nose["nasion"], nose["subspinale"], nose["acanthion"]
        z_top, z_bot = n[2] - 8.0, ac[2] - 4.0                       # the nose from below nasion to subnasale
        z_prn = z_bot + 0.25 * (z_top - z_bot)                         # pronasale about 1/4 up from subnasale
        zc, thc, _ = g.polar(0.5 * (n + ss))
        Z = g.z[:, None]
        arc = np.angle(np.exp(1j * (g.theta[None, :] - thc))) * 70.0  # mm across the face at ~70 mm radius
        proj = nose["projection_mm"]
        # profile: rises linearly from the top to the pronasale, falls steeply to the subnasale
        up = np.clip((z_top - Z) / max(z_top - z_prn, 1.0), 0.0, 1.0)
        down = np.clip((Z - z_bot) / max(z_prn - z_bot, 1.0), 0.0, 1.0)
        height = proj * np.where(Z >= z_prn, up, np.sqrt(down)) * ((Z <= z_top) & (Z >= z_bot - 2.0))
        half = 0.5 * nose["alar_width_mm"] * np.where(Z >= z_prn, 0.45 + 0.55 * (1 - up), 1.0)
        across = np.exp(-(arc / np.maximum(half, 1.0)) ** 4 * 1.5) * (1 - (arc / (half * 1.6)) ** 2).clip(0)
        return height * across

    # -------------------------------------------------------------------- solve
    def solve(self, *, depths: np.ndarray | None = None, tips: np.ndarray | None = None,
              nu: int | None = None, nv: int | None = None) -> FaceResult:
        """The face through the pegs at ``depths`` (mm, one per peg; default the table's means) or at
        explicit peg-tip positions ``tips`` (patient mm, shape (n, 3): a dragged peg), which win."""
        from .pde_surface import solve_pde

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
        offset = self._offset_field(tips)
        radius = self.profile + offset
        bump = self._nose_bump()
        if bump is not None:
            radius = radius + bump
        t1 = time.perf_counter()
        g = self.grid
        curves = g.point(g.z[:, None], g.theta[None, :], radius)
        bset = BoundarySet(curves, np.full(len(g.z), -1), g.z, knots_from_heights(g.z),
                           meta={"vertex_z": self.vertex_z + RULE_DEPTH_MM, "parameterisation": "aligned"})
        head = solve_pde(bset, approximation_mm=0.0)
        t2 = time.perf_counter()
        mesh = head.surface(int(nu or self.options["nu"]), int(nv or self.options["nv"]), caps=True)
        t3 = time.perf_counter()
        prov = dict(self.provenance)
        prov["peg_depths_mm"] = {n: round(float(x), 2) for n, x in zip(self.peg_names, d)}
        return FaceResult(mesh, prov, {"field": t1 - t0, "pde": t2 - t1, "mesh": t3 - t2, "total": t3 - t0},
                          tips=tips, depths=d, head=head)


def face_from_skull(skull: Mesh, landmarks: dict, table, **kw) -> FaceResult:
    """Prepare and solve at the table's means: the face of a skull in one call (see :class:`FaceModel`)."""
    solve_kw = {k: kw.pop(k) for k in ("depths", "tips") if k in kw}
    model = FaceModel.prepare(skull, landmarks, table, **kw)
    res = model.solve(**solve_kw)
    res.timings["prepare"] = model.prepare_seconds
    return res
