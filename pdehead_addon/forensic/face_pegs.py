"""The pegs of a solved face: how far each tip is from the face, why, and what is implausible.

A face from the skull (:class:`.face_from_skull.FaceModel`) passes through most peg tips to a few tenths of a mm,
but not through all: a peg whose offset disagrees with its neighbours' is damped
(:meth:`~.face_from_skull.FaceModel.site_damping`), the field is kept from overshooting
(:meth:`~.face_from_skull.FaceModel.limited_field`) and the nose, lips and cheeks are shape rules over the field. This
module says so, per peg, cheaply enough for every live re-solve (:func:`peg_report`): the tip's distance to the
face (exact point-to-triangle distances near the nearest face vertex), whether the peg is damped and by how much,
how far the limiter moved the field there, whether the practitioner holds it, and the warnings of a peg pushed
into the bone or dragged implausibly far (thresholds in :mod:`..defaults`). And where the pegs stand: the automatic
landmarks that miss their definition moved to it (:func:`alar_pegs_by_definition`, :func:`mid_ramus_by_definition`)
and the cheek band whose least tissue is the smallest of its pegs' means (:func:`cheek_bands`, :func:`cheek_depth`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import defaults as D
from ..core.mesh import Mesh
from ..core.mesh_geometry import point_triangle_distance, triangulate
from .face_features import aperture_margins, point_of

#: A peg whose field the limiter moved by more than this (mm) at its tip is reported as limited.
LIMITED_MM = 0.5
#: Half-width (in rows and columns of the face's grid) of the window of triangles searched around a tip's nearest
#: face vertex: the closest point of a smooth surface lies in the triangles next to its nearest vertex; 2 leaves a
#: margin for a coarse mesh or a sliver.
SEARCH_HALF_WIDTH = 2
#: The nearest face vertex is searched on every COARSE_STEP-th row and column first, then around that one.
COARSE_STEP = 4


@dataclass
class PegReport:
    """Per peg of a solved face (arrays in the model's peg order).

    Attributes
    ----------
    names : list of str
        The pegs' landmarks.
    tip_to_face_mm : ndarray
        Distance from each tip to the face mesh (mm).
    depth_mm : ndarray
        Each tip's depth along its peg's axis (the bone normal at its landmark), mm.
    drift_mm : ndarray
        Each tip's distance from its peg's axis (a peg moved off its landmark), mm.
    disagreement_mm : ndarray
        How far the peg's offset at the table's means disagrees with its neighbours' (NaN: above the rows).
    damping : ndarray
        The extra regularisation of the peg in the exact correction (0: followed exactly; held pegs 0).
    limited_mm : ndarray
        How far the limiter moved the field at the tip (mm, signed).
    held : ndarray of bool
        The pegs the practitioner holds (followed exactly whatever the automatic rule says).
    warnings : list of dict
        ``{"peg", "kind" ("into_bone" / "far"), "text"}``, one per implausible peg and cause.
    sd_mm : ndarray or None
        The table's SD at each peg's landmark: an automatic peg's tip is met as closely as it allows
        (:meth:`.face_field.DepthField.tip_slack`).
    """

    names: list
    tip_to_face_mm: np.ndarray
    depth_mm: np.ndarray
    drift_mm: np.ndarray
    disagreement_mm: np.ndarray
    damping: np.ndarray
    limited_mm: np.ndarray
    held: np.ndarray
    warnings: list = field(default_factory=list)
    sd_mm: np.ndarray | None = None

    def why(self, i: int) -> str:
        """Why peg ``i``'s tip is off the face, in words."""
        if self.held[i]:
            return f"held: the face keeps at least {D.FACE_MIN_TISSUE_MM.default:g} mm over the bone"
        if self.damping[i] > 0:
            return f"damped: disagrees with its neighbours by {self.disagreement_mm[i]:.1f} mm"
        if abs(self.limited_mm[i]) > LIMITED_MM:
            return f"limited: the field kept {abs(self.limited_mm[i]):.1f} mm from overshooting"
        sd = np.nan if self.sd_mm is None else float(self.sd_mm[i])
        if np.isfinite(sd) and self.tip_to_face_mm[i] <= sd:
            return f"smoothed: within the table's SD ({sd:.1f} mm) of its mean; hold it to meet the tip"
        if not np.isfinite(self.disagreement_mm[i]):
            return "above the rows: the dome over the vault"
        return "shaped: the nose, lips, cheeks or the surface between the rows"

    def off_face(self, limit_mm: float = D.FACE_PEG_OFF_MM) -> list[dict]:
        """The pegs whose tip is farther than ``limit_mm`` from the face, farthest first:
        ``{"peg", "tip_to_face_mm", "why", "held"}``."""
        rows = np.flatnonzero(self.tip_to_face_mm > limit_mm)
        rows = rows[np.argsort(-self.tip_to_face_mm[rows])]
        return [{"peg": self.names[i], "tip_to_face_mm": round(float(self.tip_to_face_mm[i]), 1),
                 "why": self.why(i), "held": bool(self.held[i])} for i in rows]

    def record(self) -> dict:
        """What the face's provenance keeps: the pegs off the face, the held pegs and the warnings."""
        return {"pegs_off_face": self.off_face(),
                "pegs_held": [n for n, h in zip(self.names, self.held) if h],
                "peg_warnings": list(self.warnings)}

    def summary(self) -> str | None:
        """One line naming the pegs off the face with their distances (None when there are none)."""
        off = self.off_face()
        if not off:
            return None
        listed = ", ".join(f"{o['peg']} {o['tip_to_face_mm']:.1f} mm" for o in off)
        return (f"{len(off)} of {len(self.names)} peg tips are more than {D.FACE_PEG_OFF_MM:g} mm from the face: "
                f"{listed}")


def held_mask(names: list, held) -> np.ndarray:
    """``held`` (landmark names, or a bool array in ``names``' order, or None) as a bool array over ``names``."""
    if held is None:
        return np.zeros(len(names), bool)
    if isinstance(held, np.ndarray) and held.dtype == bool:
        if held.shape != (len(names),):
            raise ValueError(f"held: need {len(names)} flags, got {held.shape}")
        return held.copy()
    wanted = set(held)
    return np.array([n in wanted for n in names], bool)


class TipDistance:
    """Distance from points to the face's tube and dome (its vertices as :class:`.face_live.LiveFace` and
    :meth:`.FaceModel.solve` lay them out: ``rows`` x ``columns`` tube vertices row by row, the neck cap's, then
    the dome's apex last). The neck cap is left out: no peg stands under the jaw's rows.

    Per point: its nearest tube vertex (one matrix product), then the exact distance to the triangles within
    :data:`SEARCH_HALF_WIDTH` rows and columns of it (and to the dome's fan there).
    """

    def __init__(self, rows: int, columns: int):
        self.rows, self.columns = int(rows), int(columns)
        h = SEARCH_HALF_WIDTH
        dr, dc = np.meshgrid(np.arange(-h, h), np.arange(-h, h), indexing="ij")
        self._dr, self._dc = dr.ravel(), dc.ravel()                 # the quads' lower-left corners around a vertex
        self._fan = np.arange(-h, h)

    def nearest_vertex(self, p: np.ndarray, tube: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) of each point's nearest vertex of the ``tube`` (rows, columns, 3): the nearest of every
        :data:`COARSE_STEP`-th row and column first, then the nearest within a coarse step of it (a smooth face: all
        51 000 vertices against 34 tips cost 18 ms of a ~100 ms live solve, this ~2 ms)."""
        rows, cols, step = self.rows, self.columns, COARSE_STEP
        coarse = tube[::step, ::step]
        flat = coarse.reshape(-1, 3)
        d2 = (flat * flat).sum(1)[None, :] - 2.0 * (p @ flat.T)          # |p|^2 left out: the same for each row
        rc, cc = np.divmod(np.argmin(d2, axis=1), coarse.shape[1])
        k = np.arange(-step, step + 1)
        r = np.clip(rc[:, None, None] * step + k[None, :, None], 0, rows - 1)          # (n, w, 1)
        c = (cc[:, None, None] * step + k[None, None, :]) % cols                      # (n, 1, w)
        r, c = np.broadcast_arrays(r, c)
        d = ((tube[r, c] - p[:, None, None, :]) ** 2).sum(-1).reshape(len(p), -1)
        best = np.argmin(d, axis=1)
        n = np.arange(len(p))
        return r.reshape(len(p), -1)[n, best], c.reshape(len(p), -1)[n, best]

    def __call__(self, points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
        rows, cols = self.rows, self.columns
        p = np.asarray(points, float).reshape(-1, 3)
        v = np.asarray(vertices, float)
        r0, c0 = self.nearest_vertex(p, v[:rows * cols].reshape(rows, cols, 3))
        r = np.clip(r0[:, None] + self._dr[None, :], 0, rows - 2)             # (n, q) quads' rows
        c = (c0[:, None] + self._dc[None, :]) % cols
        a, b = r * cols + c, r * cols + (c + 1) % cols
        quads = np.stack([a + cols, b + cols, b, a], axis=-1)    # (n, q, 4): the mesh's own corner order and diagonal
        tris = triangulate(quads.reshape(-1, 4)).reshape(2, len(p), -1, 3).transpose(1, 0, 2, 3).reshape(len(p), -1, 3)
        top = (rows - 1) * cols + (c0[:, None] + self._fan[None, :]) % cols       # the dome's fan at the top row
        apex = np.full_like(top, len(v) - 1)
        fan = np.stack([top, (top - (rows - 1) * cols + 1) % cols + (rows - 1) * cols, apex], axis=-1)
        tris = np.concatenate([tris, fan], axis=1)
        d = point_triangle_distance(p[:, None, :], v[tris[..., 0]], v[tris[..., 1]], v[tris[..., 2]])
        return d.min(axis=1)


def _tip_distance(model, nu: int, nv: int) -> TipDistance:
    cache = model.__dict__.setdefault("_tip_distance", {})
    key = (max(int(nu), 3), int(nv))
    if key not in cache:
        cache[key] = TipDistance(key[0] - 1, key[1])
    return cache[key]


def peg_report(model, tips: np.ndarray, vertices: np.ndarray, held=None, nu: int | None = None,
               nv: int | None = None) -> PegReport:
    """The :class:`PegReport` of the face ``vertices`` (patient mm, the model's layout at ``nu`` x ``nv``, default
    the model's) solved by ``model`` through ``tips`` with the pegs ``held`` (names or a bool array; None: none).
    Reads what the model's last solve left (the limiter's shift): call it right after that solve."""
    names = list(model.peg_names)
    tips = np.asarray(tips, float).reshape(-1, 3)
    held = held_mask(names, held)
    nu = int(nu or model.options["nu"])
    nv = int(nv or model.options["nv"])
    dist = _tip_distance(model, nu, nv)(tips, vertices)
    rel = tips - model.peg_bases
    depth = np.einsum("ij,ij->i", rel, model.peg_normals)
    drift = np.linalg.norm(rel - depth[:, None] * model.peg_normals, axis=1)
    n_in = int(np.count_nonzero(model.in_rows))
    disagreement = np.full(len(names), np.nan)
    damping = np.zeros(len(names))
    disagreement[model.in_rows] = model.site_disagreement()[:n_in]
    damping[model.in_rows] = model.site_extra_damping()[:n_in]
    damping[held] = 0.0
    limited = np.zeros(len(names))
    shift = model.__dict__.get("_last_limit_shift")
    if shift is not None:
        g = model.grid
        z, th, _ = g.polar(model.to_frame(tips))
        limited = np.where(model.in_rows, g.sample(shift, np.clip(z, g.z[0], g.z[-1]), th), 0.0)
    warnings = peg_warnings(names, depth, drift, model.default_depths, model.depth_sd)
    warned = {w["peg"] for w in warnings}
    for i in np.flatnonzero(held & (dist > D.FACE_PEG_OFF_MM)):
        if names[i] not in warned:                  # a held peg the face cannot reach: say so (the tester's thin ala)
            warnings.append({"peg": names[i], "kind": "held_off_face",
                             "text": f"{names[i]}: held, but the face stays {dist[i]:.1f} mm from its tip (the face "
                                     f"keeps at least {D.FACE_MIN_TISSUE_MM.default:g} mm over the bone)"})
    return PegReport(names, dist, depth, drift, disagreement, damping, limited, held, warnings,
                     np.asarray(model.depth_sd, float))


def peg_warnings(names: list, depth: np.ndarray, drift: np.ndarray, mean: np.ndarray, sd: np.ndarray) -> list[dict]:
    """The implausible pegs, as data: ``{"peg", "kind", "text"}`` for a tip in the bone (depth below
    :data:`~..defaults.FACE_PEG_MIN_DEPTH_MM`), moved off its landmark (drift beyond
    :data:`~..defaults.FACE_PEG_MAX_DRIFT_MM`) or deeper than the table's mean +
    :data:`~..defaults.FACE_PEG_MAX_DEPTH_SD` SD."""
    out = []
    limit = np.asarray(mean, float) + D.FACE_PEG_MAX_DEPTH_SD * np.asarray(sd, float)      # NaN without an SD
    for i in np.flatnonzero(depth < D.FACE_PEG_MIN_DEPTH_MM):
        out.append({"peg": names[i], "kind": "into_bone",
                    "text": f"{names[i]}: its tip is {-depth[i]:.1f} mm inside the bone (depth along its axis "
                            f"{depth[i]:.1f} mm)"})
    for i in np.flatnonzero(drift > D.FACE_PEG_MAX_DRIFT_MM):
        out.append({"peg": names[i], "kind": "far",
                    "text": f"{names[i]}: its tip is {drift[i]:.0f} mm off its landmark's axis (more than "
                            f"{D.FACE_PEG_MAX_DRIFT_MM:g} mm: moved off the landmark)"})
    for i in np.flatnonzero(np.nan_to_num(depth - limit, nan=-1.0) > 0):
        out.append({"peg": names[i], "kind": "far",
                    "text": f"{names[i]}: depth {depth[i]:.1f} mm, beyond the table's mean + "
                            f"{D.FACE_PEG_MAX_DEPTH_SD:g} SD ({limit[i]:.1f} mm)"})
    return out


# ------------------------------------------------------------------------------------------ pegs by definition
#: An automatic alare curvature landmark flagged ``uncertain`` that lies farther than this (mm) from the point its
#: definition gives on the skull (:func:`.face_features.aperture_margins`) is moved there for the face: two voxels
#: and a half of a 0.96 mm scan; the automatic one is a guess (``uncertain``) and the peg's depth belongs beside the
#: aperture.
ALAR_DEFINITION_TOLERANCE_MM = 5.0


def alar_pegs_by_definition(landmarks: dict, flags: dict | None, skull: Mesh) -> tuple[dict, dict]:
    """``landmarks`` with each alare curvature flagged ``uncertain`` (the automatic search's guess) moved
    to the aperture's lateral margin (:func:`.face_features.aperture_margins`) when farther than
    :data:`ALAR_DEFINITION_TOLERANCE_MM` from it, and ``{name: (old, new)}`` of those moved. A landmark with no flag
    (placed by hand or read from a file) is kept as it is."""
    if not flags:
        return landmarks, {}
    n, ss = point_of(landmarks, "Nasion", "Glabella"), point_of(landmarks, "Subspinale", "Mid-philtrum")
    if n is None or ss is None:
        return landmarks, {}
    names = [k for k in ("Alare curvature L", "Alare curvature R")
             if k in landmarks and flags.get(k, "ok") == "uncertain"]
    if not names:
        return landmarks, {}
    want = aperture_margins(skull, ss, 0.5 * (n[0] + ss[0]))
    out, moved = dict(landmarks), {}
    for k in names:
        if k in want and float(np.linalg.norm(want[k] - landmarks[k])) > ALAR_DEFINITION_TOLERANCE_MM:
            out[k] = want[k]
            moved[k] = (landmarks[k], want[k])
    return out, moved


#: Mid-ramus by its definition (the outermost ramus point half way up from gonion to the condyle's top; the condyle's
#: top taken at the porion's height, the condyle sitting in the glenoid fossa in front of the ear canal): an automatic
#: mid-ramus whose height lies outside this fraction of the gonion-porion height on its side is taken as misplaced and
#: replaced by the other side's, mirrored across the mid-sagittal plane, when that one is within it.
MID_RAMUS_FRACTION = (0.3, 0.7)
#: The landmarks on the mid-sagittal plane that fix it (:func:`midsagittal_plane`).
MIDLINE_LANDMARKS = ("Glabella", "Nasion", "Subspinale", "Supradentale", "Infradentale", "Pogonion", "Menton",
                     "Gnathion", "Vertex", "Opisthocranion", "Mid-philtrum", "Supramentale")


def midsagittal_plane(landmarks: dict) -> tuple[np.ndarray, float] | None:
    """The mid-sagittal plane (unit normal toward the patient's left, offset) fitted to the midline landmarks
    (x = a + b y + c z by least squares), or None with fewer than 3 of them."""
    pts = np.array([landmarks[n] for n in MIDLINE_LANDMARKS if n in landmarks], float)
    if len(pts) < 3:
        return None
    A = np.column_stack([np.ones(len(pts)), pts[:, 1], pts[:, 2]])
    (a, b, c), *_ = np.linalg.lstsq(A, pts[:, 0], rcond=None)
    n = np.array([1.0, -b, -c])
    norm = float(np.linalg.norm(n))
    return n / norm, float(a / norm)


def mirrored(point: np.ndarray, plane: tuple[np.ndarray, float]) -> np.ndarray:
    n, d = plane
    return point - 2.0 * (float(point @ n) - d) * n


def mid_ramus_by_definition(landmarks: dict, flags: dict | None, skull: Mesh) -> tuple[dict, dict]:
    """``landmarks`` with an automatic mid-ramus outside :data:`MID_RAMUS_FRACTION` of the gonion-porion height on its
    side replaced by the other side's mirrored across the mid-sagittal plane (:func:`midsagittal_plane`) and put on
    the nearest skull vertex, when the other side's is within it; ``{name: (old, new)}`` of those moved. Landmarks
    without flags (placed by hand or read from a file) are kept."""
    if not flags:
        return landmarks, {}
    plane = midsagittal_plane(landmarks)

    def fraction(side):
        mr, go, po = (landmarks.get(f"{n} {side}") for n in ("Mid-ramus", "Gonion", "Porion"))
        if mr is None or go is None or po is None or po[2] - go[2] < 20.0:
            return None
        return float((mr[2] - go[2]) / (po[2] - go[2]))

    lo, hi = MID_RAMUS_FRACTION
    out, moved = dict(landmarks), {}
    for side, other in (("L", "R"), ("R", "L")):
        name = f"Mid-ramus {side}"
        f, g = fraction(side), fraction(other)
        if plane is None or f is None or g is None or flags.get(name) in (None, "not_found") or lo <= f <= hi:
            continue
        if not lo <= g <= hi:
            continue
        target = mirrored(np.asarray(landmarks[f"Mid-ramus {other}"], float), plane)
        near = skull.vertices[np.argmin(np.linalg.norm(skull.vertices - target, axis=1))]
        out[name] = near.copy()
        moved[name] = (landmarks[name], out[name])
    return out, moved


def mirrored_normals(names: list, normals: np.ndarray, moved: dict,
                     plane: tuple[np.ndarray, float] | None) -> np.ndarray:
    """``normals`` (one per peg of ``names``) with each landmark ``moved`` by :func:`mid_ramus_by_definition` standing
    in the mirror of its other side's direction: it was put there as the other side's mirror image, on the nearest
    skull vertex, whose own bone normal says little (CThead at 1600 and at its automatic level: the mirrored Mid-ramus
    L's averaged normal pointed 53 degrees down, (0.50, -0.33, -0.80), its peg into the neck, while Mid-ramus R's
    stood sideways, (-0.95, -0.26, -0.16); the face's cheek then depended on the strip level by 6 points). Without
    the mid-sagittal ``plane`` or the other side's peg, unchanged."""
    out = np.array(normals, float)
    if plane is None:
        return out
    unit = np.asarray(plane[0], float)
    for name in moved:
        other = name[:-1] + ("R" if name.endswith("L") else "L")
        if name in names and other in names:
            v = out[names.index(other)]
            out[names.index(name)] = v - 2.0 * float(v @ unit) * unit
    return out


#: The cheek (:func:`cheek_bands`): between the infraorbital margin (Suborbital, or Orbitale), the zygion (Zygomatic
#: arch) and the jaw pegs present (JAW_PEGS: the lowest sets the band's floor; without any, the cheek runs down
#: CHEEK_DOWN_MM, a cheek's height from the orbit's floor to the occlusal plane, about 40 mm in adults: Farkas 1994's
#: orbitale to stomion ~ 45 mm, cited from the literature, not re-read).
CHEEK_PEGS = ("Suborbital", "Orbitale", "Zygomatic arch")
JAW_PEGS = ("Supra M2", "Occlusal line", "Sub M2", "Mid-ramus", "Gonion", "Mid-mandibular border", "Supra canine",
            "Infra canine")
CHEEK_DOWN_MM = 40.0


def cheek_bands(landmarks: dict, grid) -> list[tuple[float, float, float, float]]:
    """Per side with an infraorbital margin and a zygion: (z_low, z_high, theta_medial, theta_lateral) of the cheek,
    from the infraorbital margin's height down to the lowest jaw landmark present on that side (or
    :data:`CHEEK_DOWN_MM`), between the infraorbital margin's and the zygion's angles about the face's axis."""
    out = []
    for side in ("L", "R"):
        io = point_of(landmarks, f"Suborbital {side}", f"Orbitale {side}")
        zy = point_of(landmarks, f"Zygomatic arch {side}")
        if io is None or zy is None:
            continue
        jaw = [landmarks[f"{n} {side}"][2] for n in JAW_PEGS if f"{n} {side}" in landmarks]
        z_high = float(io[2])
        z_low = float(min(jaw)) if jaw else z_high - CHEEK_DOWN_MM
        if z_low >= z_high - 5.0:
            continue
        _, ta, _ = grid.polar(io[None])
        _, tb, _ = grid.polar(zy[None])
        out.append((z_low, z_high, float(ta[0]), float(tb[0])))
    return out


def cheek_depth(names: list, depths: np.ndarray) -> float | None:
    """The smallest table mean of the cheek's pegs present (:data:`CHEEK_PEGS` and :data:`JAW_PEGS`), or None."""
    keys = CHEEK_PEGS + JAW_PEGS
    got = [float(d) for n, d in zip(names, depths) if n.rsplit(" ", 1)[0] in keys]
    return min(got) if got else None
