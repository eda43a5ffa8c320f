"""Face from the skull: a closed PDE face solved through the tissue-depth pegs.

The practitioner's end product in forensic facial approximation is a face; this module makes one from
the bone skull, its landmarks and a depth table, by the same C2 PDE engine as the skin
(:func:`.pde_surface.solve_pde`), fast enough to re-solve on every peg drag.

Method
------
Everything is expressed on a cylinder of directions about the vertical (patient z) axis through the
skull's centroid: a row every ``row_mm`` of height, a column every ``360 / columns`` degrees.

1. *The bone's outer profile* (:func:`.face_profile.bone_profile`): per (row, column) bin the outermost point of the
   bone skull; per row the 2-D convex hull of that ring (which bridges the orbits, the nasal aperture,
   the temporal fossae and the cheeks), a grey closing and a smoothing over the surface by a length in mm
   (:func:`.face_profile.surface_smooth`: the rows' hulls step). Where a
   column meets no bone (below the skull base at the back, below the mandible) a neck rule
   (:mod:`.face_profile`) continues the profile downward.
2. *The pegs*: each landmark of the depth table stands on the bone along the bone's outward normal,
   averaged over the bone around it (:func:`.face_profile.peg_normals`); its tip (base + depth x normal) is where
   the skin must pass.
   In the cylinder frame each tip is a site (z, angle) with a radial offset over the profile.
3. *The tissue-depth field* (:meth:`FaceModel._offset_field`): over the whole head, a wide
   normalised Gaussian average of the peg offsets (Shepard / partition of unity, radius
   ``spread_mm``) with the rule depth where no peg stands (:data:`RULE_DEPTH_MM`: the vault and the
   neck), plus a narrow Gaussian radial-basis correction (lightly regularised) that makes the field
   pass through every tip (to a few tenths of a mm), except a peg that disagrees with its neighbours by more
   than :data:`DAMP_FREE_MM` (:meth:`FaceModel.site_damping`); kept from overshooting between the pegs
   (:meth:`FaceModel.limited_field`). A peg's influence fades within about 2 ``spread_mm``.
4. *Prediction rules* for what a depth field cannot make (:mod:`.face_features`, each cited there): the nose
   from the nasal aperture and the nasal length, the closed eyes in the orbits, the mouth from the teeth and the
   canines, a default ear at each porion.
5. *The skin smoothed* (:mod:`.face_skin`): profile + depth field, smoothed over the surface below the brows
   (a twiced Gaussian): neither the profile's row steps nor the field's swings between neighbouring pegs are a skin's.
6. *The face*: that + nose + lips + eyes + ears = radius per bin, never below the bone floor
   (:func:`.face_profile.bone_floor`: the outermost bone plus :data:`.defaults.FACE_MIN_TISSUE_MM`, so no bone comes
   through the face), the pegs the practitioner holds put back on it (:meth:`FaceModel._held_on_face`); each row
   is a closed boundary curve (a skull without a mandible: the rows tilted to end along the scan's cut,
   :func:`.face_profile.tilted_rows`); the C2 PDE surface through them (:func:`.pde_surface.solve_pde`, dome over
   the vertex, a flat cap under the neck or on the cut) is the face, a closed mesh in patient mm.

What does not depend on the depths is computed once in :meth:`FaceModel.prepare`; :meth:`FaceModel.solve`
evaluates the field, adds the features, solves the PDE and meshes it (tens of ms).

Every result carries :data:`APPROXIMATION_LABEL` and its provenance: it is an approximation, not an
identification.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .. import defaults as D
from ..core.boundary_set import BoundarySet, knots_from_heights
from ..core.errors import PDEHeadError
from ..core.mesh import Mesh
from ..core.provenance import provenance
from ..pde.pde_head import derived_once
from ..pde.pde_surface import curve_positions, smoothing_range, solve_pde
from .face_eyes import predict_eyes
from .face_features import EAR_LENGTH_MM, EAR_WIDTH_MM, check_skull, predict_ears, predict_mouth, predict_nose
from .face_field import (  # noqa: F401  (re-exported: face_live and the tests read them here)
    DAMP_FREE_MM,
    DAMP_MIDLINE_DEG,
    DAMP_SCALE_MM,
    HELD_REGULARISATION,
    LIMIT_RADIUS_FRACTION,
    LIMIT_SOFT_MM,
    LIMIT_WEIGHT_FLOOR,
    NARROW_FRACTION,
    RBF_REGULARISATION,
    RULE_DEPTH_MM,
    RULE_WEIGHT,
    DepthField,
    peg_kernel,
)
from .face_frame import (
    HeadFrameFeatures,
    frame_refusal,
    head_yaw,
    into_frankfurt_frame,
    landmarks_in_head_frame,
    to_head_frame,
)
from .face_pegs import (
    alar_pegs_by_definition,
    cheek_bands,
    cheek_depth,
    held_mask,
    mid_ramus_by_definition,
    midsagittal_plane,
    mirrored_normals,
    peg_report,
)
from .face_profile import (
    PROFILE_SMOOTH_MM,
    FaceGrid,
    bone_floor,
    bone_profile,
    cheek_floor,
    convex_rows,
    peg_normals,
    round_floor,
    scan_cut_plane,
    smooth_far_from_pegs,
    smooth_floor_near_cut,
    smooth_max,
    surface_smooth,
    tilted_rows,
)
from .face_skin import brow_weight, lift_onto_floor, smooth_skin
from .landmarks import marker_pegs

APPROXIMATION_LABEL = D.FACE_LABEL
#: Fewer vertices than this cannot trace the bone's outer profile (a bone skull has 10^5).
MIN_SKULL_VERTICES = 100

#: ... and after the shape rules (the nose, the lips, the eyes, the ears: :meth:`FaceModel._held_on_face`) the face
#: is put back through a held peg's tip by a Gaussian bump this wide (mm, sigma on the field's cylinder): about the
#: ala's or the philtrum's width, so a held peg reshapes the face around it and not the whole nose or mouth.
HELD_SHAPE_MM = 5.0
#: The radius (mm) of the cylinder the field's sites lie on (:meth:`FaceModel.cylinder_points`, the held pegs'
#: bumps): about the head's mean radius, so distances on it are about distances over the head.
FIELD_RADIUS_MM = 85.0
#: The cheeks: between the oral fissure (the mouth's stomion) and the orbit's floor (the
#: orbitales) each row of the face (profile + depth field, before the nose, lips and eyes) is lifted to its convex
#: envelope in horizontal section over the front columns (:func:`.face_profile.convex_rows`: chords up to
#: CHEEK_SPAN_DEG apart), faded in and out over CHEEK_RAMP_MM at the band's ends. Why: there the bone recedes from
#: the canine eminence into the canine fossa and along the dental arch to the molars under the zygoma, and the closed
#: profile's chords lie 15-20 mm inside the eminence (CThead, 20-30 mm below pronasale, 25-30 degrees off the midline);
#: no T-Table landmark stands between supra canine, mid-infraorbital and supra M2 (damped), so the field there dipped
#: into a horizontal hollow. A cheek's skin does not follow the bone into those hollows (the buccal and malar fat and
#: the buccinator fill them): a shape rule with no published number; the band's ends are landmarks and the span a
#: choice (about the arc from the canine eminence to the zygoma), nothing fitted, though the band itself was found on
#: the scored head's error map. CThead 63.0 -> 63.2 % within +-2.5 mm (mean 2.52 -> 2.48 mm); GE unchanged.
CHEEK_SPAN_DEG = 30.0
#: The cheeks' lift (made row by row) is smoothed over the surface by this length (mm): the closed profile's
#: (:data:`.face_profile.PROFILE_SMOOTH_MM`), so the lift does not bring back the rows' steps the profile's smoothing
#: took out.
CHEEK_SMOOTH_MM = PROFILE_SMOOTH_MM
CHEEK_PASSES = 2
CHEEK_RAMP_MM = 5.0
#: The landmarks on the mandible's chin (:meth:`FaceModel.prepare`): with none of them the skull has no mandible
#: (the scan stopped above the chin) and the face no neck: it ends along the scan's cut.
MANDIBLE_LANDMARKS = ("Menton", "Gnathion", "Pogonion")


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
    pegs: object = None          # .face_pegs.PegReport: each tip's distance to the face, damping, warnings


@dataclass
class FaceModel(DepthField, HeadFrameFeatures):
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
                nu: int | None = None, nv: int | None = None, neck_mm: float | None = None) -> "FaceModel":
        """Prepare the face model of a skull.

        ``skull``: the bone skull (:func:`.skull.skull_mesh` or a ``--skull-mesh``), patient LPS mm; ``landmarks``: on
        the bone (patient mm), those the table has become pegs, the others feed the prediction rules; ``table``: a
        DepthTable or dict (mean depth per landmark; SDs from ``table.sd``); ``sex`` (kept in the provenance; the
        T-Table 2023 is pooled) and ``flags`` (``ok`` / ``uncertain`` / ``not_found``, for the provenance).
        ``neck_mm``: how far below the skull's lowest bone the face ends (its neck cap); default
        :data:`.defaults.FACE_NECK_MM` with a chin (a mandible landmark). Without one the scan stopped above the
        chin: the face ends along the scan's cut (:func:`.face_profile.scan_cut_plane`, found from the skull alone;
        GE: its 18.5-degree slab) ``neck_mm`` beyond it (default :data:`.defaults.FACE_CUT_MARGIN_MM`), on a flat
        tilted cap (:func:`.face_profile.tilted_rows`), or where no cut is found ``neck_mm`` under the lowest bone.
        """
        t0 = time.perf_counter()
        if skull is None or len(skull.vertices) == 0 or skull.face_count == 0:
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
        lm, moved = alar_pegs_by_definition(lm, flags, skull)
        lm, moved_ramus = mid_ramus_by_definition(lm, flags, skull)
        if len(skull.vertices) < MIN_SKULL_VERTICES:    # a skull's landmarks on a handful of vertices: no profile
            raise PDEHeadError(f"the skull mesh has only {len(skull.vertices)} vertices: a closed mesh, but too coarse "
                               f"to be a bone skull (at least {MIN_SKULL_VERTICES} are needed for its outer profile)")
        chin = any(n in lm for n in MANDIBLE_LANDMARKS)
        # without a chin the face ends along the scan's cut (its rows tilted to it, :meth:`_surface`), neck_mm
        # under it, or where no cut is found, neck_mm under the lowest bone. The cut is the scan's: found in its axes
        scan_cut = None if chin else scan_cut_plane(skull)
        # the model is made in the head's Frankfurt frame (:mod:`.face_frame`): its rows level with the head, not
        # with the scanner; the pegs are handed back in patient mm
        skull, lm, cut_plane, frame = into_frankfurt_frame(skull, lm, scan_cut)
        refused = {} if frame is not None else frame_refusal(lm)     # why not, when it says (unturned)
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
        if neck_mm is None:
            neck_mm = (D.FACE_NECK_MM if chin else D.FACE_CUT_MARGIN_MM).default
        neck_mm = float(neck_mm)
        # the rows of a head with the whole neck, those more than neck_mm under the lowest bone left out: a shorter
        # neck keeps the other rows where they were (the bone's profile is binned on them; GE moved by a row phase
        # scored 40.9 % within 2.5 mm at a 7 mm cut, 41.7 % at 8.25 mm, 42.2 % with the neck); a tilted cut keeps
        # them all (the cut's back end lies below the lowest bone)
        zmin = float(skull.vertices[:, 2].min())
        zlo = zmin - max(neck_mm, D.FACE_NECK_MM.default)
        zhi = float(skull.vertices[:, 2].max()) - 4.0
        K = max(8, int(np.ceil((zhi - zlo) / row_mm)) + 1)
        rows = np.linspace(zlo, zhi, K)
        kept = rows if cut_plane is not None else rows[rows >= zmin - neck_mm - 1e-9]
        grid = FaceGrid(centre, kept, np.arange(columns) * 2 * np.pi / columns)
        K = len(grid.z)
        base_z = None
        po = [lm[n] for n in ("Porion L", "Porion R") if n in lm]
        if po:
            base_z = float(np.mean([p[2] for p in po])) - 15.0   # the skull base, ~15 mm below the ear canals
        raw, profile = bone_profile(skull, grid, base_z)
        # up to whole hundredths of a mm here (never lower), so the model kept as text in hundredths
        # (:func:`.face_live.model_state`, 2 bytes a bin) is this one to the bit
        floor = bone_floor(skull, grid, D.FACE_MIN_TISSUE_MM.default)
        least = cheek_depth(names, depths)
        cheeks = None if least is None else cheek_floor(skull, grid, cheek_bands(lm, grid), least,
                                                        D.FACE_MIN_TISSUE_MM.default)
        if cheeks is not None:              # the cheeks' least tissue: the smallest of their pegs' table means
            floor = np.maximum(floor, cheeks)
        if cut_plane is not None:                             # the cut bone's ragged edge, rounded
            floor = smooth_floor_near_cut(floor, grid, cut_plane, profile)
        else:                           # a skin over a bone bump is a rounded mound (a cut skull: rounded at the cut)
            floor = round_floor(floor, grid, profile)
        floor = np.ceil(floor * 100.0) / 100.0
        normals = peg_normals(skull, bases, grid, profile)
        normals = mirrored_normals(names, normals, moved_ramus, midsagittal_plane(lm))
        hull_profile = profile
        profile = smooth_far_from_pegs(profile, grid, bases + depths[:, None] * normals)
        # the nose, the mouth and the eyes predicted facing the head's front (:mod:`.face_frame`)
        yaw = head_yaw(lm)
        lm_head = landmarks_in_head_frame(lm, grid.centre, yaw)
        rule_sites = [(n, to_head_frame(p, grid.centre, yaw, back=True), w) for n, p, w in predict_eyes(lm_head)]
        nose = predict_nose(lm_head, skull if yaw == 0.0 else
                            Mesh(to_head_frame(skull.vertices, grid.centre, yaw), skull.quads, skull.triangles))
        mouth = predict_mouth(lm_head)
        prov_table = table.provenance_record() if hasattr(table, "provenance_record") else {"table": "imported table"}
        prov = provenance(label=APPROXIMATION_LABEL, method="face from skull: PDE surface through tissue-depth "
                          "pegs (pdehead_addon.forensic.face_from_skull)", sex=sex, **prov_table)
        if flags:
            prov["landmark_flags"] = {n: flags.get(n, "ok") for n in sorted(lm)}
        for key, what in (("alare_curvature_by_definition", moved), ("mid_ramus_by_definition", moved_ramus)):
            if what:
                prov[key] = {n: {"from": [round(float(x), 2) for x in a], "to": [round(float(x), 2) for x in b]}
                             for n, (a, b) in what.items()}
        if yaw != 0.0:
            prov["head_yaw_deg"] = round(float(np.degrees(yaw)), 1)
        prov.update(refused)
        if scan_cut is not None:                                 # in the scan's axes (patient mm)
            prov["scan_cut"] = {"tilt_deg": round(float(np.degrees(np.arccos(-scan_cut[0][2]))), 1),
                                "normal": [round(float(x), 4) for x in scan_cut[0]],
                                "offset_mm": round(float(scan_cut[1]), 2), "face_beyond_mm": neck_mm,
                                "why": "no mandible: the face ends along the scan's cut of the skull"}
        options = dict(row_mm=row_mm, columns=columns, spread_mm=spread, nu=nu or D.FACE_NU.default,
                       nv=nv or D.FACE_NV.default, neck_mm=neck_mm, sex=sex)
        model = cls(names, bases, normals, depths, sds, grid, raw, profile, rule_sites, nose, mouth, options,
                    prov, dict(flags or {}))
        model.keep_frame(frame)                             # the pegs handed back in patient mm
        model.face_yaw = yaw
        model.vertex_z = float(skull.vertices[:, 2].max())
        model.cut_plane = None if cut_plane is None else np.append(cut_plane[0], cut_plane[1])
        model._in_rows = grid.polar(model.to_frame(model.tips_for(depths)))[0] <= grid.z[-1]
        model.landmarks_used = lm                            # in the model's frame
        model.hull_profile = hull_profile                    # the peer (constant_depth) keeps the bone's own profile
        model.bone_floor = floor                             # no row of the face inside it (:meth:`shaped_radius`)
        model._grid_xyz = model.cylinder_points(np.repeat(grid.z, columns), np.tile(grid.theta, K))
        model._damping = model.site_damping()
        model.prepare_seconds = time.perf_counter() - t0
        return model

    @property
    def in_rows(self) -> np.ndarray | None:
        """Which pegs' tips lie within the profile's rows (the rest, e.g. the vertex, are the dome's), or
        None before :meth:`prepare`. Kept under its stored name ``_in_rows`` (files saved with a face)."""
        return self.__dict__.get("_in_rows")

    # -------------------------------------------------------------------- the field
    def cylinder_points(self, z, theta) -> np.ndarray:
        """Sites on a cylinder of the mean radius: distances between them ~ distances over the head."""
        rho = FIELD_RADIUS_MM
        return np.stack([rho * np.sin(theta), rho * np.cos(theta), np.asarray(z, float)], axis=-1)

    def tips_for(self, depths: np.ndarray) -> np.ndarray:
        return self.peg_bases + np.asarray(depths, float)[:, None] * self.peg_normals

    def field_sites(self, tips: np.ndarray) -> np.ndarray:
        """The points (n, 3) the tissue-depth field passes through: the peg tips within the profile's rows
        and the rule sites (vault, temples, neck)."""
        # a tip above the last row (vertex) is left to the dome over the vault: near the axis its radial offset
        # to the top row's radius is meaningless (-21 mm on CThead)
        in_rows = self.in_rows
        sites = [self.to_frame(tips)[in_rows if in_rows is not None else slice(None)]]
        sites += [np.array([p for _, p, _ in self.rule_sites])] if self.rule_sites else []
        return np.concatenate(sites)

    def held_sites(self, held) -> np.ndarray | None:
        """The field sites (:meth:`field_sites`) of the pegs ``held`` (names, or a bool array in the pegs' order;
        None: none) as a bool array, or None when none is held."""
        if held is None:
            return None
        mask = held_mask(self.peg_names, held)
        if not mask.any():
            return None
        in_rows = self.in_rows
        mask = mask[in_rows] if in_rows is not None else mask
        return np.concatenate([mask, np.zeros(len(self.rule_sites or ()), bool)])

    def surface_head(self, radius: np.ndarray, nu=None, nv=None, top_z: float | None = None):
        g = self.grid
        plane = self.__dict__.get("cut_plane")
        if plane is None:
            z = np.broadcast_to(g.z[:, None], radius.shape)
        else:                                   # a skull cut by its scan: the face ends along the cut
            z, radius = tilted_rows(g, radius, (plane[:3], plane[3]), self.options["neck_mm"])
        top = self.vertex_z + RULE_DEPTH_MM if top_z is None else float(top_z)
        # made in the model's frame, solved in patient mm (the PDE is the same in any frame, eq. 1-13: the head, its
        # mesh and the live positions need no turning back)
        curves = self.from_frame(g.point(z, g.theta[None, :], radius))
        heights = curves[..., 2].mean(axis=1)
        top = float(self.from_frame(np.array([g.centre[0], g.centre[1], top]))[2])
        bset = BoundarySet(curves, np.full(len(g.z), -1), heights, knots_from_heights(heights),
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
        # the columns' v steps (closer where an outline runs radially) too, for the same reason
        density = self.__dict__.setdefault("_v_density", [head.v_density()])[0]
        head.v_density = lambda _d=density: _d
        # the UV layout too (the tube map costs ~0.65 s per new set of curves): fixed by the first
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
        head = self.surface_head(getattr(self, "hull_profile", self.profile) + float(depth_mm))
        mesh = head.surface(int(self.options["nu"]), int(self.options["nv"]), caps=True)   # not live: own caps
        prov = dict(self.provenance, method=f"constant depth {depth_mm:g} mm over the bone's closed profile")
        return FaceResult(mesh, prov, {}, head=head)

    def solve(self, *, depths: np.ndarray | None = None, tips: np.ndarray | None = None,
              nu: int | None = None, nv: int | None = None, held=None) -> FaceResult:
        """The face through the pegs at ``depths`` (mm, one per peg; default the table's means) or at
        explicit peg-tip positions ``tips`` (patient mm, shape (n, 3): a dragged peg), which win. ``held``: the
        pegs the practitioner holds (landmark names, or a bool array in the pegs' order): never damped, the face
        passes through their tips. The result's ``pegs`` (:class:`.face_pegs.PegReport`) says how far each tip is
        from the face and why; its provenance lists the pegs off the face and the warnings."""
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
        radius = self.shaped_radius(self._offset_field(tips, held), tips, held)
        t1 = time.perf_counter()
        head = self.surface_head(radius, top_z=self.top_z_for(tips))
        t2 = time.perf_counter()
        mesh = self._mesh(head, nu, nv)
        t3 = time.perf_counter()
        report = peg_report(self, tips, mesh.vertices, held, nu, nv)
        t4 = time.perf_counter()
        return FaceResult(mesh, self.provenance_for(d, report),
                          {"field": t1 - t0, "pde": t2 - t1, "mesh": t3 - t2, "pegs": t4 - t3, "total": t4 - t0},
                          tips=tips, depths=d, head=head, pegs=report)

    def shaped_radius(self, offset: np.ndarray, tips: np.ndarray, held=None) -> np.ndarray:
        """The face's radius (K, M) over the profile: the tissue-depth ``offset`` field, then what a depth
        field cannot make (the nose, the lips, the ears), then the pegs ``held`` put back on the face
        (:meth:`_held_on_face`). One place for :meth:`solve` and the live path."""
        radius = self._smooth_face(self.profile + offset, tips, held)
        cols, front = self._front()
        face = self._cheeks(radius[:, cols], front)
        bump = self._nose_bump(face, tips, front, anchor=(self.profile + offset)[:, cols])
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
        floor = self.__dict__.get("bone_floor")
        if floor is not None:             # the floor's lift spread over its crests' edges; the held pegs put back on it
            radius = lift_onto_floor(radius, floor, self.grid, self.__dict__["_smooth_w"][1])
        radius = self._held_on_face(radius, tips, held)
        if floor is not None:                       # last: nothing after it may bring the bone through the face
            radius = smooth_max(radius, floor, LIMIT_SOFT_MM)
        return radius

    def _smooth_face(self, radius: np.ndarray, tips: np.ndarray, held=None) -> np.ndarray:
        """``radius`` (the profile plus the depth field) smoothed below the brows (:func:`.face_skin.smooth_skin`),
        then put back through the peg tips as the field passes through them (:meth:`through_sites`), each as closely
        as the table's SD at it allows (:meth:`tip_slack`)."""
        if "_smooth_w" not in self.__dict__:      # fixed by the skull: computed once (the rows' weights and radii)
            self.__dict__["_smooth_w"] = (brow_weight(self.grid.z, getattr(self, "landmarks_used", None) or {}),
                                          np.median(self.profile, axis=1))
        weight, rho = self.__dict__["_smooth_w"]

        def smoothed(r):
            return smooth_skin(r, self.grid, weight, self.__dict__.get("bone_floor"), rho=rho)
        smooth = smoothed(radius)
        return radius if smooth is radius else self.through_sites(smooth, tips, held, self.tip_slack(smoothed))

    def _held_on_face(self, radius: np.ndarray, tips: np.ndarray, held) -> np.ndarray:
        """``radius`` with the held pegs' tips put back on it: the shape rules (the nose, the lips, the eyes, the
        ears) are added over the depth field and moved a held peg's tip off the face (CThead: alare curvature R
        4.4 mm, subspinale 2.1 mm), so the hand's peg wins there too: Gaussian bumps
        (:data:`HELD_SHAPE_MM` wide on the cylinder of the field) whose sum is the residual at every held tip in
        the rows. Not the bone floor, which comes after: a held peg dragged into the bone stays outside it."""
        if held is None:
            return radius
        mask = held_mask(self.peg_names, held)
        in_rows = self.in_rows
        if in_rows is not None:                     # a tip above the rows (vertex) is the dome's
            mask &= in_rows
        if not mask.any():
            return radius
        g = self.grid
        z, th, r = g.polar(self.to_frame(tips)[mask])
        residual = r - g.sample(radius, z, th)
        s2 = 2.0 * HELD_SHAPE_MM ** 2

        def bumps(zs, ths):
            """The bumps' height and arc factors at heights ``zs`` and angles ``ths`` (one kernel for the tips'
            system and the grid: the face passes through each held tip)."""
            dz2 = (np.asarray(zs, float)[:, None] - z[None, :]) ** 2
            arc = FIELD_RADIUS_MM * np.angle(np.exp(1j * (np.asarray(ths, float)[:, None] - th[None, :])))
            return np.exp(-dz2 / s2), np.exp(-arc ** 2 / s2)

        at_tips = np.multiply(*bumps(z, th))
        coef = np.linalg.solve(at_tips + 1e-9 * np.eye(len(z)), residual)
        height, around = bumps(g.z, g.theta)                                      # (K, n), (M, n)
        return radius + np.einsum("kn,mn->km", height * coef, around)

    def _cheek_weight(self) -> np.ndarray | None:
        """Per row, the weight (0-1) of the convex cheeks (:data:`CHEEK_SPAN_DEG`): 1 from the stomion to the
        orbitales' height, faded over :data:`CHEEK_RAMP_MM`; None without a mouth or an orbitale."""
        lm = getattr(self, "landmarks_used", None) or {}
        orb = [lm[n][2] for n in ("Orbitale L", "Orbitale R") if n in lm]
        sto = (self.mouth or {}).get("stomion_z")
        if CHEEK_SPAN_DEG <= 0 or not orb or sto is None:
            return None
        z = self.grid.z
        ramp = max(CHEEK_RAMP_MM, 1e-6)
        w = np.clip((z - float(sto)) / ramp + 0.5, 0, 1) * np.clip((float(np.mean(orb)) - z) / ramp + 0.5, 0, 1)
        return w if np.any(w > 0) else None

    def _cheeks(self, face: np.ndarray, grid: FaceGrid) -> np.ndarray:
        """The front columns ``face`` (rows x columns of ``grid``) with the cheek band's rows made convex
        (:data:`CHEEK_SPAN_DEG`). One place for :meth:`solve` and the live path."""
        w = self._cheek_weight()
        if w is None:
            return face
        rows = np.flatnonzero(w > 0)
        dth = float(grid.theta[1] - grid.theta[0])
        span = int(round(np.radians(CHEEK_SPAN_DEG) / dth))
        band = face[rows]
        lift = convex_rows(band, dth, span, CHEEK_PASSES) - band
        out = face.copy()
        out[rows] = band + w[rows, None] * lift
        if CHEEK_SMOOTH_MM > 0:         # the lift is made row by row: smoothed over the surface, it does not step
            lifted = np.zeros_like(face)
            lifted[rows] = w[rows, None] * lift
            out = face + surface_smooth(lifted, grid, CHEEK_SMOOTH_MM, rho=FIELD_RADIUS_MM, periodic=False)
        return out

    def top_z_for(self, tips: np.ndarray) -> float | None:
        """The dome's top: the vertex peg's tip height (above the rows, not in the radial field), if any."""
        vertex = self._peg_tip(tips, "Vertex")
        return float(self.to_frame(vertex)[2]) if vertex is not None else None

    def provenance_for(self, depths: np.ndarray, report=None) -> dict:
        """The provenance of a face solved with the pegs at ``depths`` (mm); with its pegs' ``report``
        (:class:`.face_pegs.PegReport`): the pegs off the face (and why), the held pegs and the warnings."""
        prov = dict(self.provenance)
        if self.mouth is not None:
            prov["predicted_mouth_width_mm"] = round(float(self.mouth["width_mm"]), 1)
            if self.mouth.get("stomion_z") is not None:
                at = [self.mouth["mid_x"], self.mouth["centre"][1], self.mouth["stomion_z"]]   # the head's frame
                prov["predicted_stomion_z_mm"] = round(float(self._patient(at)[2]), 1)
        if self._ear_shape() is not None:
            sides = [f"Porion {ear['side']}" for ear in predict_ears(getattr(self, "landmarks_used", {}) or {})]
            prov["ears"] = (f"default ear ({EAR_LENGTH_MM:g} x {EAR_WIDTH_MM:g} mm, Farkas 1994 norms) at "
                            f"{' and '.join(sides)}: one shape for everyone, not this person's ears")
        prov["peg_depths_mm"] = {n: round(float(x), 2) for n, x in zip(self.peg_names, depths)}
        if report is not None:
            prov.update(report.record())
        return prov


def face_from_skull(skull: Mesh, landmarks: dict, table, **kw) -> FaceResult:
    """Prepare and solve at the table's means: the face of a skull in one call (see :class:`FaceModel`)."""
    solve_kw = {k: kw.pop(k) for k in ("depths", "tips") if k in kw}
    model = FaceModel.prepare(skull, landmarks, table, **kw)
    res = model.solve(**solve_kw)
    res.timings["prepare"] = model.prepare_seconds
    return res
