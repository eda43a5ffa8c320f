"""Automatic craniometric landmarks on the bone, each by a written rule, with a confidence flag.

The input is the binary bone mask (the CT thresholded at a bone level and cleaned,
:attr:`pdehead_addon.skull.SkullSegmentation.bone`) and the CT's geometry: no grey
values are used, so the same code runs on a head CT and on a dry-skull CT.

Method (every step a pure function of the mask):

1. **A first frame.** The skull's plane of reflective symmetry
   (:func:`~pdehead_addon.landmarks.symmetry_plane`, mirror ICP on the bone's voxel
   centres) gives the left-right axis; superior is the patient's +z made orthogonal to it.
2. **Views of the bone.** The mask is resampled in the frame on a 1 mm grid
   (``LANDMARK_GRID_MM``); three depth images are read off it: the *front* view (for each
   (x, z) the y of the first bone met from the face side), the two *side* views (the
   outermost x of bone for each (y, z)) and the mid-sagittal *profile* (bone in the plane
   x = 0, with the connected component of each pixel: skull or mandible).
3. **Holes.** Openings in the bone are pits of a depth image: the image closed by a disc
   (grey closing) minus the image, deeper than ``HOLE_DEPTH_MM``. In the front view the two
   large pits either side of the midline are the **orbits**; the pit on the midline below
   them is the **nasal aperture**. In a side view the small pit nearest the expected place
   (level with the orbit floor, half way back along the skull) is the **external acoustic
   meatus**.
4. **Frankfurt horizontal.** Porion (top of the meatus) and orbitale (lowest point of the
   orbit margin) on both sides give :func:`~pdehead_addon.landmarks.frankfurt_transform`;
   steps 2-3 are repeated in that frame and every other landmark is found there by the rule
   in :data:`RULES` (also in this module's functions' docstrings).
5. Points are mapped back to patient LPS mm (the CT's frame, not the aligned one).

Flags: ``ok`` (the rule's evidence was found as expected), ``uncertain`` (the rule placed a
point but its evidence was weak; :attr:`FoundLandmark.evidence` says which) and
``not_found`` (no point; the evidence says why, e.g. no mandible in the scan).

Nomenclature: the landmark set of :data:`~pdehead_addon.landmarks.STANDARD_LANDMARKS`,
with the depth-table codes of Caple & Stephan (2016) where they differ (pr = Supradentale,
pg = Pogonion, zy = Zygomatic arch, mso = Supraorbital, mio = Suborbital, sM2 = Supra M2,
iM2 = Sub M2) and the table's landmarks the set lacked (mn, ss, gn, ac, sC, iC, mr, mmb).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .errors import PDEHeadError

OK, UNCERTAIN, NOT_FOUND = "ok", "uncertain", "not_found"
FLAGS = (OK, UNCERTAIN, NOT_FOUND)

#: Grid (mm) the bone mask is resampled on in the landmark frame.
LANDMARK_GRID_MM = 1.0
#: A pit of a depth image deeper than this (mm) is an opening (orbit, aperture, meatus).
HOLE_DEPTH_MM = 10.0
#: Radius (mm) of the disc that closes the front view (wider than an orbit's half width).
FRONT_CLOSING_MM = 24.0
#: Radius (mm) of the disc that closes the side views (wider than the meatus's half width).
SIDE_CLOSING_MM = 9.0
#: Crown heights used where teeth and alveolar bone are one object in a bone mask (mm): upper and
#: lower central incisor crowns (Wheeler's Dental Anatomy, 10th ed., table 1-1: 10.5 and 9.0 mm).
UPPER_INCISOR_CROWN_MM = 10.5
LOWER_INCISOR_CROWN_MM = 9.0
#: Bone surface voxel centres used for the first frame's symmetry plane (a random subset).
SYMMETRY_POINTS = 20000
#: Length of the nasal bones, nasion to rhinion (mm; adult means are about 20-25 mm): without them in the
#: bone mask, the maxilla is looked for from this far below nasion.
NASAL_BONE_LENGTH_MM = 20.0
#: A flat side (the zygomatic arch): the outermost point is the middle of the bone within this (mm) of it.
SIDE_EXTREME_TOLERANCE_MM = 1.0
#: The margin of an opening (supraorbital, lateral orbit): the front-most point of this much bone (mm)
#: next to the opening.
RIM_MM = 3.0
#: Vertex is looked for on the vault's top within this distance (mm) of the mid-sagittal plane.
VERTEX_HALF_WIDTH_MM = 30.0
#: The upper jaw's mid-sagittal profile: rows whose front lies up to this far (mm) behind nasion's depth, down to
#: the first row whose front-most bone is more than OCCLUSAL_GAP_MM behind the last jaw row (below the incisors).
UPPER_JAW_DEPTH_MM = 25.0
OCCLUSAL_GAP_MM = 20.0
#: A piece of bone between the jaws (lower teeth split from the mandible by the threshold) counts as the
#: mandible's when it lies within this (mm) of it and no farther from it than from the upper skeleton.
LOWER_PIECE_REACH_MM = 10.0
#: Supramentale is uncertain where the mandible's profile from pogonion to infradentale misses more than
#: SUPRAMENTALE_GAP_MM of rows, or its deepest point lies more than SUPRAMENTALE_MAX_DEPTH_MM behind the chord
#: (the concavity above an adult chin is a few mm deep; deeper is other bone behind the mandible's front).
SUPRAMENTALE_GAP_MM = 3.0
SUPRAMENTALE_MAX_DEPTH_MM = 8.0
#: Glabella on a forehead without a prominence: the profile's turn is measured over this (mm) either side.
GLABELLA_TURN_MM = 5.0
#: Vertex's x is the middle of the vault's left-right extent this far (mm) below its top.
VERTEX_CHORD_MM = 15.0
#: Porions (orbitales) farther than this from mirror images of each other are flagged uncertain (mm).
MIRROR_TOLERANCE_MM = 12.0


#: The rule of every landmark (by the key of :data:`~pdehead_addon.landmarks.STANDARD_LANDMARKS`; "L/R"
#: rules apply to each side). Frame: the Frankfurt frame (x left, y posterior, z up), the mid-sagittal
#: plane x = 0; "front view" etc. are the depth images of the module docstring.
RULES: dict[str, str] = {
    "po": "Porion: the highest point of the upper margin of the external acoustic meatus -- in the side view, "
          "the outermost bone just above the meatus opening's highest pixel, moved half way back along the roof to "
          "where the canal has a floor (uncertain where the roof reaches more than 3 mm beyond it).",
    "or": "Orbitale: the lowest point of the infraorbital margin -- in the front view, the bone just below the "
          "lowest pixel of the orbit opening.",
    "v": "Vertex: the highest point of the skull near the mid-sagittal plane (the middle of a flat top: the top "
         "columns within 30 mm of the plane and 1.5 mm of the highest; a vault is rarely symmetric about the "
         "whole skull's plane), moved across to the vault's own midline there (the middle of its left-right "
         "extent 15 mm below the top) and taken at the top of that column.",
    "op": "Opisthocranion: the most posterior point of the skull on the mid-sagittal plane (middle of a flat back).",
    "g": "Glabella: the most anterior point of the mid-sagittal profile 25-65 mm above orbitale; where that is the "
         "band's lowest row and the profile comes forward all the way down to nasion (no prominence), the point "
         "of greatest convexity between nasion and 25 mm above it, where the nasal root turns into the forehead "
         "(uncertain).",
    "n": "Nasion: the deepest (most posterior) point of the profile's concavity below glabella, on the profile "
         "walked down continuously from glabella; with no concavity (receding forehead, nasal bones not in the "
         "mask), the lowest point of that walk -- where the frontal bone ends (uncertain).",
    "rhi": "Rhinion: the lowest point of the nasal bones -- the end of the continuous profile below nasion "
           "(not found when the walk ends at nasion).",
    "mn": "Mid-nasal: the profile point half way (in height) from nasion to rhinion.",
    "ss": "Subspinale (A point): the deepest point of the upper jaw's profile relative to the chord from the "
          "anterior nasal spine (front-most point of the top 8 mm of the upper jaw) to prosthion.",
    "sd": "Supradentale / prosthion: the upper jaw's profile point one upper central incisor crown (10.5 mm) "
          "above its lowest point (teeth and alveolar bone are one in a bone mask: always uncertain).",
    "mp": "Mid-philtrum: the upper jaw's profile point half way (in height) between subspinale and prosthion.",
    "id": "Infradentale: the mandible's profile point one lower incisor crown (9 mm) below its highest front "
          "point (always uncertain, as prosthion).",
    "sm": "Supramentale (B point): the deepest point of the mandible's profile relative to the chord from "
          "pogonion to infradentale (the mandible with the lower teeth split from it: pieces between the jaws "
          "nearer the mandible than the upper skeleton); uncertain with no concavity (under 1 mm), a concavity "
          "deeper than 8 mm, or a gap of more than 3 mm in the profile.",
    "pog": "Pogonion: the most anterior point of the lower half of the mandible's mid-sagittal profile.",
    "gn": "Gnathion: the point of the symphysis between pogonion and menton farthest along the "
          "anterior-inferior bisector.",
    "me": "Menton: the lowest point of the mandible on the mid-sagittal plane (middle of a flat bottom).",
    "fe": "Frontal eminence: on the vertical line of the front view through the orbit's centre, 10-60 mm above "
          "the supraorbital margin, the point farthest in front of the chord of that line (uncertain if < 1 mm).",
    "so": "Supraorbital (mso): the bone just above the orbit opening on its centre column (front view).",
    "sbo": "Suborbital (mio): the bone just below the orbit opening on its centre column (front view).",
    "lo": "Lateral orbit: the bone just lateral to the orbit opening, 70 % of the way up the opening.",
    "im": "Inferior malar: going down the front view from the orbit's bottom on the column a quarter of the "
          "orbit's width lateral of its centre, the last bone row before the view jumps back by > 8 mm.",
    "za": "Zygion: the outermost bone between 8 mm behind orbitale and 12 mm in front of porion, from 15 mm "
          "below orbitale to 5 mm above porion.",
    "sg": "Supraglenoid: the outermost bone 10 mm in front of porion and 8 mm above it (side view).",
    "ac": "Alare curvature (bony proxy): the bone just lateral to the nasal aperture at its widest point.",
    "sc": "Supra canine: the front-most bone 10 mm above prosthion's height, 13 % of the bizygomatic breadth "
          "from the midline (uncertain: the canine is not seen in a bone mask).",
    "ic": "Infra canine: the front-most mandible bone 10 mm below infradentale's height, 13 % of the "
          "bizygomatic breadth from the midline (uncertain).",
    "go": "Gonion: the mandible point farthest back-and-down (max y - z), then the outermost within 4 mm.",
    "ocl": "Occlusal line: the outermost mandible point at the occlusal plane (half way between prosthion and "
           "infradentale), behind 60 % of the way from menton to gonion.",
    "subm2": "Sub M2 (iM2): the outermost mandible point 60 % of the way from menton to gonion, at mid-height of "
             "the body.",
    "supm2": "Supra M2 (sM2): the outermost bone (side view) at sub M2's y, 8 mm above prosthion's height.",
    "mr": "Mid-ramus: the outermost mandible point half way up from gonion to the condyle's top, at the middle "
          "of the ramus' width.",
    "mmb": "Mid-mandibular border: the lowest mandible point half way (in y) from menton to gonion.",
}


@dataclass
class FoundLandmark:
    """One automatic landmark: ``point`` in patient LPS mm (None when not found), ``flag`` and why."""

    name: str
    point: np.ndarray | None
    flag: str
    evidence: str = ""


@dataclass
class LandmarkSearch:
    """Result of :func:`find_landmarks`: the landmarks by name, the Frankfurt transform used and notes."""

    landmarks: dict[str, FoundLandmark]
    frankfurt: np.ndarray | None
    info: dict = field(default_factory=dict)

    def points(self, include_uncertain: bool = True) -> dict[str, np.ndarray]:
        """name -> patient mm of the landmarks found (``ok``, and ``uncertain`` unless excluded)."""
        keep = (OK, UNCERTAIN) if include_uncertain else (OK,)
        return {n: lm.point for n, lm in self.landmarks.items() if lm.flag in keep and lm.point is not None}

    def flags(self) -> dict[str, str]:
        return {n: lm.flag for n, lm in self.landmarks.items()}


# ------------------------------------------------------------------------------------- the frame
class _Frame:
    """The bone resampled on a grid of a rigid frame: ``bone[ix, iy, iz]``, ``comp[...]`` labels."""

    def __init__(self, ct, bone, labels, rot, centre, step):
        self.rot, self.centre, self.step = rot, centre, step   # frame = rot @ (patient - centre)
        pts = ct.index_to_patient(np.argwhere(bone)[:: max(1, int(bone.sum() // 200_000))].astype(float))
        f = (pts - centre) @ rot.T
        lo, hi = f.min(0) - 4 * step, f.max(0) + 4 * step
        self.lo = np.floor(lo / step) * step
        n = np.ceil((hi - self.lo) / step).astype(int) + 1
        self.shape = tuple(int(v) for v in n)
        ax = [self.lo[i] + step * np.arange(n[i]) for i in range(3)]
        self.axes = ax
        bone_f = bone.astype(np.float32)
        out = np.zeros(self.shape, bool)
        lab = np.zeros(self.shape, np.int32)
        gx, gy = np.meshgrid(ax[0], ax[1], indexing="ij")           # (nx, ny), x-major
        for iz, z in enumerate(ax[2]):                                 # one z plane at a time: bounded memory
            fp = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], 1)   # (nx*ny, 3), x-major
            kji = ct.patient_to_index(fp @ rot + centre).T
            out[:, :, iz] = (ndimage.map_coordinates(bone_f, kji, order=1, cval=0.0) > 0.5).reshape(n[0], n[1])
            lab[:, :, iz] = ndimage.map_coordinates(labels, kji, order=0, cval=0).reshape(n[0], n[1])
        self.bone = out
        # bone pixels at the mask's edge may sample label 0 (nearest voxel outside): take a neighbour's label
        filled = np.where(lab > 0, lab, ndimage.grey_dilation(lab, size=(3, 3, 3)))
        self.comp = np.where(out, filled, 0)

    def to_patient(self, f) -> np.ndarray:
        return np.asarray(f, float) @ self.rot + self.centre

    def coord(self, axis: int, index) -> np.ndarray:
        return self.lo[axis] + self.step * np.asarray(index, float)

    def index(self, axis: int, value) -> int:
        return int(np.clip(np.round((value - self.lo[axis]) / self.step), 0, self.shape[axis] - 1))


#: Supra canine is not found when the front-most bone above the canine lies this far (mm) behind supradentale:
#: that bone is not the maxilla (CThead and the phantom: 4-16 mm behind).
SUPRA_CANINE_BEHIND_MM = 25.0


def _first_true(mask: np.ndarray, axis: int, reverse: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Index of the first True along ``axis`` (from the end if ``reverse``) and whether there is one."""
    m = np.flip(mask, axis) if reverse else mask
    idx = np.argmax(m, axis=axis)
    has = m.any(axis=axis)
    if reverse:
        idx = mask.shape[axis] - 1 - idx
    return idx, has


def _disc(radius_px: float) -> np.ndarray:
    r = int(np.ceil(radius_px))
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    return xx ** 2 + yy ** 2 <= radius_px ** 2


def _pits(height: np.ndarray, valid: np.ndarray, radius_px: float, depth_px: float,
          raw: bool = False) -> np.ndarray:
    """Labelled openings of a height image (larger = nearer the viewer): closing minus image > depth.

    Pixels where no bone is seen (``~valid``) count as infinitely deep; a pit must be enclosed
    by bone seen in the image (a component touching the image border or the outside is dropped).
    With ``raw`` the boolean pit mask before that test is returned.
    """
    low = np.nanmin(np.where(valid, height, np.nan)) - 10 * depth_px
    h = np.where(valid, height, low)
    closed = ndimage.grey_closing(h, footprint=_disc(radius_px))
    pits = (closed - h) > depth_px
    if raw:
        return pits
    lab, n = ndimage.label(pits)
    if n == 0:
        return lab
    # outside: background connected to the image border through unseen pixels
    outside_lab, _ = ndimage.label(~valid)
    border = np.unique(np.concatenate([outside_lab[0], outside_lab[-1], outside_lab[:, 0], outside_lab[:, -1]]))
    outside = np.isin(outside_lab, border[border > 0])
    bad = np.unique(lab[outside | np.pad(np.zeros((h.shape[0] - 2, h.shape[1] - 2), bool), 1,
                                         constant_values=True)])
    lab[np.isin(lab, bad[bad > 0])] = 0
    return ndimage.label(lab > 0)[0]


# ------------------------------------------------------------------------------------- views
class _Views:
    """Depth images of a :class:`_Frame` (axes x left, y posterior, z superior)."""

    def __init__(self, fr: _Frame):
        self.fr = fr
        b = fr.bone
        iy, self.front_has = _first_true(b, 1)                       # (nx, nz): first bone from the face
        self.front_y = fr.coord(1, iy)
        il, self.left_has = _first_true(b, 0, reverse=True)          # (ny, nz): outermost bone on the left
        self.left_x = fr.coord(0, il)
        ir, self.right_has = _first_true(b, 0)
        self.right_x = fr.coord(0, ir)

    def front_point(self, ix: int, iz: int) -> np.ndarray | None:
        if not self.front_has[ix, iz]:
            return None
        return np.array([self.fr.coord(0, ix), self.front_y[ix, iz], self.fr.coord(2, iz)])

    def side_point(self, side: int, iy: int, iz: int) -> np.ndarray | None:
        has, xs = (self.left_has, self.left_x) if side > 0 else (self.right_has, self.right_x)
        if not has[iy, iz]:
            return None
        return np.array([xs[iy, iz], self.fr.coord(1, iy), self.fr.coord(2, iz)])


def _orbits_and_aperture(v: _Views, mid_x: float):
    """Front-view openings: (left orbit, right orbit, nasal aperture) as pixel masks (nx, nz) or None.

    Orbits: the largest opening whose centre is on each side of the midline (more than 15 mm
    from it) with an area of at least 300 mm^2; the nasal aperture: the largest opening
    crossing the midline whose top is below the orbits' centres.
    """
    fr = v.fr
    px = fr.step
    lab = _pits(-v.front_y, v.front_has, FRONT_CLOSING_MM / px, HOLE_DEPTH_MM / px)
    n = lab.max()
    if n == 0:
        return None, None, None, lab
    idx = np.arange(1, n + 1)
    area = ndimage.sum(np.ones_like(lab), lab, idx) * px * px
    com = np.array(ndimage.center_of_mass(np.ones_like(lab), lab, idx))
    cx = fr.coord(0, com[:, 0]) - mid_x
    cz = fr.coord(2, com[:, 1])
    orbits = {}
    for side in (1, -1):
        cand = [i for i in range(n) if side * cx[i] > 15 and area[i] >= 300]
        if cand:
            orbits[side] = max(cand, key=lambda i: area[i])
    mirrored = _mirrored_orbit(v, mid_x, lab, orbits)
    top_z = min((cz[i] for i in orbits.values()), default=np.inf)
    ix_mid = fr.index(0, mid_x)
    crossing = [i for i in range(n) if (lab[max(ix_mid - 1, 0):ix_mid + 2] == i + 1).any(0).sum() >= 5
                and area[i] >= 100]
    ap = None
    if crossing:
        below = [i for i in crossing if fr.coord(2, np.flatnonzero((lab == i + 1).any(0)).max()) < top_z]
        if below:
            ap = max(below, key=lambda i: area[i])
    get = lambda i: None if i is None else lab == i + 1   # noqa: E731
    aperture = None
    if ap is not None:
        # the opening may run on, beside the maxilla, into the gap between the teeth: keep the rows from
        # its top down to where it stops on the midline (the nasal floor)
        aperture = get(ap)
        col = aperture[ix_mid]
        top = int(np.flatnonzero(col).max())
        bottom = top
        while bottom > 0 and col[bottom - 1]:
            bottom -= 1
        aperture[:, :bottom] = False
    out = {side: get(orbits.get(side)) for side in (1, -1)}
    out.update(mirrored)
    return out[1], out[-1], aperture, lab


#: An orbit whose opening runs into another one (its rim broken in the bone mask, e.g. thick oblique slices
#: at the orbit floor) is cut to the mirror image of the other orbit's opening grown by this much (mm).
ORBIT_MIRROR_GROW_MM = 3.0


class _MirroredOrbit(np.ndarray):
    """An orbit opening cut to the mirror image of the other orbit (a boolean mask; ``evidence`` says why)."""

    evidence = ""


def _mirror_fill(fr, pts: dict, fmt: str, orbits: dict) -> None:
    """For an orbit cut to the other's mirror image (:class:`_MirroredOrbit`), keep its landmark ``pts[fmt(tag)]``
    only within ``MIRROR_TOLERANCE_MM`` of the mirror image (x -> -x in the frame) of the other side's; else
    put the mirror image there (its broken rim gave a point inside the orbit)."""
    for tag, other in (("L", "R"), ("R", "L")):
        if not getattr(orbits.get(tag), "evidence", ""):
            continue
        q = pts.get(fmt.format(other))
        if q is None:
            continue
        m = np.asarray(q, float) * np.array([-1.0, 1.0, 1.0])
        p = pts.get(fmt.format(tag))
        if p is None or np.linalg.norm(np.asarray(p) - m) > MIRROR_TOLERANCE_MM:
            pts[fmt.format(tag)] = m


def _mirrored_orbit(v: _Views, mid_x: float, lab: np.ndarray, orbits: dict) -> dict:
    """When only one orbit opening is enclosed by bone in the front view, look for the other as the pit
    pixels (before the enclosure test) inside the mirror image of the found one across the mid-sagittal
    plane, grown by ``ORBIT_MIRROR_GROW_MM``; accepted when they cover at least 60 % of the mirror image.
    Returns {side: mask} for the side found this way (empty if none)."""
    if len(orbits) != 1:
        return {}
    fr = v.fr
    (side, i), = orbits.items()
    found = lab == i + 1
    xs = fr.coord(0, np.arange(fr.shape[0]))
    src = np.clip(np.round((2 * mid_x - xs - fr.lo[0]) / fr.step).astype(int), 0, fr.shape[0] - 1)
    mirror = found[src]                                   # mirror[ix] = found at the reflected column
    if not mirror.any():
        return {}
    raw = _pits(-v.front_y, v.front_has, FRONT_CLOSING_MM / fr.step, HOLE_DEPTH_MM / fr.step, raw=True)
    grow = ndimage.binary_dilation(mirror, structure=_disc(ORBIT_MIRROR_GROW_MM / fr.step))
    cand = raw & grow
    if cand.sum() < 0.6 * mirror.sum():
        return {}
    # the largest connected piece, so that a neighbouring opening's corner does not come along
    cl, n = ndimage.label(cand)
    cand = cl == 1 + int(np.argmax(ndimage.sum(np.ones_like(cl), cl, np.arange(1, n + 1))))
    out = cand.view(_MirroredOrbit)
    out.evidence = ("the orbit's opening runs into another opening in the bone mask (its rim is broken): cut to "
                    "the mirror image of the other orbit")
    return {-side: out}


#: Smallest side-view pit (mm^2) taken for the ear canal (an adult's is 40-50 mm^2 on CThead): the 10-16 mm^2
#: pits beside it (foramina, sutures) were nearer the expected point on a skull mesh of CThead (issue 22).
MEATUS_MIN_MM2 = 25.0


def _meatus(v: _Views, side: int, expect_y: float, expect_z: float):
    """Side-view opening of the external acoustic meatus on ``side`` (+1 left, -1 right) or None.

    The pit of the side view with an area of MEATUS_MIN_MM2-250 mm^2 nearest (expect_y, expect_z), within 30 mm.
    """
    fr = v.fr
    px = fr.step
    has, xs = (v.left_has, v.left_x) if side > 0 else (v.right_has, v.right_x)
    lab = _pits(side * xs, has, SIDE_CLOSING_MM / px, 0.6 * HOLE_DEPTH_MM / px)
    n = lab.max()
    best, best_d = None, 30.0
    if n:
        idx = np.arange(1, n + 1)
        area = ndimage.sum(np.ones_like(lab), lab, idx) * px * px
        com = np.array(ndimage.center_of_mass(np.ones_like(lab), lab, idx))
        for i in range(n):
            if not MEATUS_MIN_MM2 <= area[i] <= 250:
                continue
            d = np.hypot(fr.coord(1, com[i, 0]) - expect_y, fr.coord(2, com[i, 1]) - expect_z)
            if d < best_d:
                best, best_d = i, d
    return (None if best is None else lab == best + 1), best_d


def _rim_below(v: _Views, hole: np.ndarray, ix: int) -> np.ndarray | None:
    """Front-view bone point just below the lowest hole pixel of column ``ix``."""
    col = np.flatnonzero(hole[ix])
    if not len(col):
        return None
    for iz in range(col.min() - 1, max(col.min() - 6, -1), -1):
        p = v.front_point(ix, iz)
        if p is not None:
            return p
    return None


def _front_most(v: _Views, pixels) -> np.ndarray | None:
    """The most anterior front-view point of the first ``RIM_MM`` of bone along a list of (ix, iz) pixels
    leaving an opening: the margin of the opening, where a steep rim (under a brow ridge, the lateral
    orbital wall) would otherwise put the first bone pixel far behind its front edge."""
    pts = []
    for ix, iz in pixels:
        p = v.front_point(ix, iz)
        if p is not None:
            pts.append(p)
        if pts and len(pts) * v.fr.step >= RIM_MM:
            break
    return min(pts, key=lambda p: p[1]) if pts else None


def _rim_above(v: _Views, hole: np.ndarray, ix: int) -> np.ndarray | None:
    col = np.flatnonzero(hole[ix])
    if not len(col):
        return None
    return _front_most(v, [(ix, iz) for iz in range(col.max() + 1, min(col.max() + 9, hole.shape[1]))])


def orbitale(v: _Views, orbit: np.ndarray) -> np.ndarray | None:
    """Orbitale: the lowest point of the infraorbital margin -- over the orbit opening's columns in the
    front view, the bone pixel just below the opening's lowest pixel, the lowest of them (a flat rim:
    the middle of the columns within one grid step of the lowest)."""
    cols = np.flatnonzero(orbit.any(1))
    lows = [(np.flatnonzero(orbit[ix]).min(), ix) for ix in cols]
    lowest = min(l for l, _ in lows)
    ixs = [ix for l, ix in lows if l <= lowest + 1]
    return _rim_below(v, orbit, ixs[len(ixs) // 2])


#: The meatus' floor is looked for this far (mm) below the opening's top (for :func:`porion_overhang`).
PORION_FLOOR_MM = 14.0
#: A roof reaching more than this (mm) beyond the canal's floor makes porion ``uncertain``.
PORION_OVERHANG_MM = 3.0


def porion_overhang(v: _Views, side: int, meatus: np.ndarray, p: np.ndarray, search_mm: float = 15.0) -> float:
    """How far (mm) the bone above the meatus reaches laterally beyond the canal's floor at porion ``p``.

    Going medially from porion along its row, the canal's lateral end is the first x where there is bone
    within ``PORION_FLOOR_MM`` below the opening's top (a floor). Where the roof overhangs it (the root of
    the zygomatic arch, the supramastoid crest) a reader may put porion on the roof's edge or above the
    canal's end: the rule's point is uncertain by this much; :func:`find_landmarks` puts it half way (the roof
    above the middle) and flags it ``uncertain`` beyond ``PORION_OVERHANG_MM``.
    """
    fr = v.fr
    top = int(np.flatnonzero(meatus.any(0)).max())
    iy, ix0 = fr.index(1, p[1]), fr.index(0, p[0])
    n_floor = max(1, int(round(PORION_FLOOR_MM / fr.step)))
    for k in range(int(round(search_mm / fr.step)) + 1):
        ix = ix0 - side * k
        if not 0 <= ix < fr.shape[0]:
            break
        if fr.bone[ix, iy, max(top - n_floor, 0):max(top - 1, 0)].any():
            return k * fr.step
    return search_mm


def porion(v: _Views, side: int, meatus: np.ndarray) -> np.ndarray | None:
    """Porion: the highest point of the upper margin of the external acoustic meatus -- in the side
    view, the bone pixel just above the opening's highest pixel (the outermost bone there); see
    :func:`porion_overhang` for when it is uncertain."""
    rows = np.flatnonzero(meatus.any(0))
    top = rows.max()
    # the middle of the opening's top 2 mm (its top row alone may be a pixel or two: a slightly different
    # frame would move porion along y by the width of the opening)
    iys = np.flatnonzero(meatus[:, max(top - int(round(2.0 / v.fr.step)), 0):top + 1].any(1))
    iy = int(round(0.5 * (iys.min() + iys.max())))
    for iz in range(top + 1, min(top + 6, meatus.shape[1])):
        p = v.side_point(side, iy, iz)
        if p is not None:
            return p
    return None


# ------------------------------------------------------------------------------------- rules
def _nearest_surface(fr: _Frame, p: np.ndarray, comp_ids=None, radius: float = 6.0) -> np.ndarray | None:
    """The bone voxel of the frame grid nearest ``p`` (restricted to components) within ``radius`` mm."""
    lo = np.array([fr.index(a, p[a] - radius) for a in range(3)])
    hi = np.array([fr.index(a, p[a] + radius) for a in range(3)]) + 1
    sub = fr.bone[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
    if comp_ids is not None:
        sub = sub & np.isin(fr.comp[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]], comp_ids)
    idx = np.argwhere(sub)
    if not len(idx):
        return None
    q = fr.lo + fr.step * (idx + lo)
    return q[int(np.argmin(np.linalg.norm(q - p, axis=1)))]


def _profile(fr: _Frame, mid_x: float, comp_ids) -> tuple[np.ndarray, np.ndarray]:
    """Anterior mid-sagittal profile of the given components: for each z row, min y (NaN: no bone)."""
    ix = fr.index(0, mid_x)
    sl = fr.bone[max(ix - 1, 0):ix + 2] & np.isin(fr.comp[max(ix - 1, 0):ix + 2], comp_ids)
    sl = sl.any(0)                                                      # (ny, nz)
    iy, has = _first_true(sl, 0)
    y = np.where(has, fr.coord(1, iy), np.nan)
    return y, has


def _midline(res, fr, v, mid_x, skull_ids, mand_ids, orb_z, aperture, mand_top=None):
    """Midline landmarks (rules in :data:`RULES`)."""
    z = fr.coord(2, np.arange(fr.shape[2]))
    ix = fr.index(0, mid_x)
    slab = fr.bone[max(ix - 1, 0):ix + 2].any(0)                        # (ny, nz)
    skull_slab = slab & np.isin(fr.comp[max(ix - 1, 0):ix + 2], skull_ids).any(0)
    pts = np.argwhere(skull_slab)
    if not len(pts):
        for key in ("v", "op", "g", "n", "mn", "rhi", "ss", "mp", "sd"):
            res[key] = (None, NOT_FOUND, "no skull bone on the mid-sagittal plane")
        return {}
    # a flat top (or back) gives a plateau: its middle, from the points within 1.5 mm of the extreme
    # vertex: a vault is rarely symmetric about the whole skull's plane (its top may sit several mm to
    # one side), and a flat top makes the plane's x decide the point: take the top surface within
    # VERTEX_HALF_WIDTH_MM of the plane, the columns within 1.5 mm of its highest, and their middle
    ix_lo, ix_hi = fr.index(0, mid_x - VERTEX_HALF_WIDTH_MM), fr.index(0, mid_x + VERTEX_HALF_WIDTH_MM)
    band = fr.bone[ix_lo:ix_hi + 1] & np.isin(fr.comp[ix_lo:ix_hi + 1], skull_ids)
    top_iz, top_has = _first_true(band, 2, reverse=True)                 # (nx', ny)
    height = np.where(top_has, top_iz, -1)
    cols = np.argwhere(height >= height.max() - 1.5 / fr.step)
    cx, cy = np.median(cols, axis=0)
    k = int(np.argmin((cols[:, 0] - cx) ** 2 + (cols[:, 1] - cy) ** 2))   # a top column nearest the middle
    ixv, iyv = int(cols[k, 0]), int(cols[k, 1])
    # the vault's own midline at that y: the middle of its left-right extent VERTEX_CHORD_MM below the top (a
    # vault is rarely symmetric about the whole skull's plane; CThead's top sits 2-4 mm beside it)
    iz_c = int(height[ixv, iyv] - round(VERTEX_CHORD_MM / fr.step))
    if iz_c >= 0:
        row = np.flatnonzero(fr.bone[:, iyv, iz_c] & np.isin(fr.comp[:, iyv, iz_c], skull_ids))
        if len(row) >= 2:
            ixm = int(round(0.5 * (row.min() + row.max()))) - ix_lo
            if 0 <= ixm < height.shape[0] and height[ixm, iyv] >= height.max() - 3.0 / fr.step:
                ixv = ixm
    res["v"] = (np.array([fr.coord(0, ix_lo + ixv), fr.coord(1, iyv), fr.coord(2, height[ixv, iyv])]), OK, "")
    back = pts[pts[:, 0] >= pts[:, 0].max() - 1.5 / fr.step]
    iz = int(np.round(np.median(back[:, 1])))
    iy = int(np.flatnonzero(skull_slab[:, iz]).max())
    res["op"] = (np.array([mid_x, fr.coord(1, iy), fr.coord(2, iz)]), OK, "")

    py, has = _profile(fr, mid_x, skull_ids)
    band = has & (z >= orb_z + 25) & (z <= orb_z + 65)
    if not band.any():
        res["g"] = (None, NOT_FOUND, "no frontal bone 25-65 mm above orbitale on the midline")
        return {}
    ig = int(np.flatnonzero(band)[np.nanargmin(py[band])])
    res["g"] = (np.array([mid_x, py[ig], z[ig]]), OK, "")
    # walk down the continuous profile from glabella (frontal bone, then the nasal bones)
    walk = [ig]
    for k in range(ig - 1, -1, -1):
        if not has[k] or abs(py[k] - py[walk[-1]]) > 4.0 or z[k] < orb_z - 25:
            break
        walk.append(k)
    walk = np.array(walk)
    nas = walk[z[walk] >= orb_z]
    i_n = int(nas[np.argmax(py[nas])]) if len(nas) else ig
    below = walk[z[walk] < z[i_n]]
    if py[i_n] - py[ig] >= 2.0:
        res["n"] = (np.array([mid_x, py[i_n], z[i_n]]), OK, "")
        if len(below) >= 6 and py[below[-1]] < py[i_n] - 2:
            i_rhi = int(below[-1])
            res["rhi"] = (np.array([mid_x, py[i_rhi], z[i_rhi]]), OK, "")
        else:
            i_rhi = int(below[-1]) if len(below) else i_n
            res["rhi"] = (np.array([mid_x, py[i_rhi], z[i_rhi]]), UNCERTAIN,
                          f"the nasal bones run only {len(below) * fr.step:.0f} mm below nasion in the bone mask")
    else:
        # no concavity: the outline runs on from the forehead; without the nasal bones in the mask the
        # frontal bone's lowest point is where they would join
        i_n = int(walk[-1])
        res["n"] = (np.array([mid_x, py[i_n], z[i_n]]), UNCERTAIN,
                    "no concavity below glabella: nasion taken where the frontal bone's outline ends")
        i_rhi = i_n
        res["rhi"] = (None, NOT_FOUND, "the nasal bones are not in the bone mask below nasion")
    if ig <= int(np.flatnonzero(band).min()) + 1 and z[i_n] < z[ig] and py[i_n] < py[ig] - 2.0:
        # no prominence between the brows: the profile still comes forward below the band, all the way down to
        # nasion, which stands more than 2 mm in front of the band's front-most point (a receding forehead). Glabella is then where the profile turns from the nasal root up into
        # the forehead: its greatest convexity (the slope's largest fall over GLABELLA_TURN_MM either side)
        # between nasion and 25 mm above it
        w = max(1, int(round(GLABELLA_TURN_MM / fr.step)))
        ks = np.arange(i_n + w, min(fr.index(2, z[i_n] + 25.0), len(z) - 1 - w) + 1)
        ks = ks[has[ks] & has[ks - w] & has[ks + w]]
        if len(ks):
            turn = (py[ks] - py[ks - w]) - (py[ks + w] - py[ks])      # slope below minus slope above
            k = int(ks[np.argmax(turn)])
            res["g"] = (np.array([mid_x, py[k], z[k]]), UNCERTAIN,
                        "the forehead has no prominence (the profile comes forward all the way down to nasion): "
                        "glabella taken where the profile turns from the nasal root into the forehead")
    i_mn = int(np.round(0.5 * (i_n + i_rhi)))
    res["mn"] = (None, NOT_FOUND, res["rhi"][2]) if res["rhi"][0] is None else \
        (np.array([mid_x, py[i_mn] if has[i_mn] else py[i_n], z[i_mn]]), res["rhi"][1], res["rhi"][2])

    # upper jaw: going down the midline profile from rhinion, the nasal aperture is deep (the profile runs
    # back to the septum or finds no bone); the maxilla starts at the first row whose front-most bone is
    # the upper skeleton's and lies within 15 mm of nasion's depth (the anterior nasal spine)
    iy_all, has_all = _first_true(slab, 0)
    front_comp = fr.comp[max(ix - 1, 0):ix + 2].max(0)[iy_all, np.arange(fr.shape[2])]
    face_any = has & has_all & np.isin(front_comp, skull_ids) & (np.abs(fr.coord(1, iy_all) - py) < 1.5)
    face = face_any & (py < py[i_n] + 15)
    k = i_rhi - int(round(3 / fr.step))
    if res["rhi"][0] is None:
        # the nasal bones are not in the mask: the bone just below nasion (frontal processes, bits of the
        # nasal bones) would pass for the maxilla; look from one nasal-bone length below nasion
        k = min(k, fr.index(2, z[i_n] - NASAL_BONE_LENGTH_MM))
    while k > 0 and not face[k]:
        k -= 1
    if k <= 0 or z[k] < orb_z - 80:
        for key in ("ss", "mp", "sd"):
            res[key] = (None, NOT_FOUND, "no maxilla below the nasal aperture on the midline")
        return {}
    # the upper jaw's profile: the rows down from the spine until the front-most bone is the mandible's
    # (its teeth) or no bone is met for 10 mm; thin bone (the nasal floor, the spine) leaves shorter gaps
    i_top = k
    i_low, gap, j = i_top, 0, i_top - 1
    mand = set(mand_ids)
    # below the spine the maxilla's front may lie deeper than 15 mm behind nasion (the concavity of subspinale
    # on a skull whose nasal root juts forward): the profile rows go UPPER_JAW_DEPTH_MM behind it
    face = face_any & (py < py[i_n] + UPPER_JAW_DEPTH_MM)
    face[i_top + 1:] = False
    while j > 0:
        if has_all[j] and front_comp[j] in mand:
            break
        if has_all[j] and fr.coord(1, iy_all[j]) - py[i_low] > OCCLUSAL_GAP_MM:
            # the front-most bone jumps far back: below the upper incisors' edges (the lower teeth behind them
            # are split from the mandible by the threshold and would pass for the upper jaw)
            break
        if face[j]:
            i_low, gap = j, 0
        else:
            gap += 1
            if gap * fr.step > 10.0:
                break
        j -= 1
    rows = np.arange(i_low, i_top + 1)
    rows = rows[face[rows]]
    upper_ev = "" if aperture is not None else "no nasal aperture in the front view"
    i_sd = int(np.argmin(np.abs(z - (z[i_low] + UPPER_INCISOR_CROWN_MM))))
    i_sd = min(max(i_sd, i_low), i_top)
    seg = rows[(rows >= i_sd)]
    # subspinale: the deepest point of the concavity between the anterior nasal spine and prosthion
    spine_rows = seg[z[seg] >= z[i_top] - 8.0]          # the anterior nasal spine: the top 8 mm's front-most point
    i_ans = int(spine_rows[np.argmin(py[spine_rows])]) if len(spine_rows) else i_top
    upper = seg[(seg >= i_sd) & (seg <= max(i_ans, i_sd))]
    # deepest relative to the chord from prosthion to the spine
    if len(upper) >= 3 and i_ans != i_sd:
        chord = py[i_sd] + (py[i_ans] - py[i_sd]) * (z[upper] - z[i_sd]) / (z[i_ans] - z[i_sd])
        # the median of three rows: a single row missing the thin cortex in front of the maxilla is a notch of
        # the mask, not of the bone
        smooth = np.array([np.median(py[seg[max(i - 1, 0):i + 2]]) for i in np.searchsorted(seg, upper)])
        i_ss = int(upper[np.argmax(smooth - chord)])
        ss_y = float(smooth[np.argmax(smooth - chord)])
    else:
        top_rows = seg[seg > i_sd]
        i_ss = int(top_rows[np.argmax(py[top_rows])]) if len(top_rows) else i_sd
        ss_y = float(py[i_ss])
    res["ss"] = (np.array([mid_x, ss_y, z[i_ss]]), UNCERTAIN if upper_ev else OK, upper_ev)
    res["sd"] = (np.array([mid_x, py[i_sd], z[i_sd]]), UNCERTAIN,
                 f"teeth and alveolar bone are one in a bone mask: placed {UPPER_INCISOR_CROWN_MM:g} mm "
                 "(an upper incisor crown) above the lowest point of the upper jaw")
    i_mp = int(np.round(0.5 * (i_ss + i_sd)))
    res["mp"] = (np.array([mid_x, py[i_mp] if has[i_mp] else py[i_ss], z[i_mp]]), res["ss"][1], res["ss"][2])
    return {"sd_z": z[i_sd], "low_z": z[i_low], "sd_y": py[i_sd]}


def _mandible_midline(res, fr, mid_x, mand_ids):
    z = fr.coord(2, np.arange(fr.shape[2]))
    py, has = _profile(fr, mid_x, mand_ids)
    if not has.any():
        for key in ("id", "sm", "pog", "gn", "me"):
            res[key] = (None, NOT_FOUND, "the mandible does not cross the mid-sagittal plane")
        return {}
    rows = np.flatnonzero(has)
    i_bot, i_top = int(rows.min()), int(rows.max())
    ix = fr.index(0, mid_x)
    slab = (fr.bone[max(ix - 1, 0):ix + 2] & np.isin(fr.comp[max(ix - 1, 0):ix + 2], mand_ids)).any(0)
    low = np.argwhere(slab[:, i_bot])[:, 0]
    me = np.array([mid_x, fr.coord(1, np.median(low)), z[i_bot]])
    res["me"] = (me, OK, "")
    mid = 0.5 * (z[i_bot] + z[i_top])
    lower = rows[z[rows] <= mid]
    i_pog = int(lower[np.argmin(py[lower])])
    res["pog"] = (np.array([mid_x, py[i_pog], z[i_pog]]), OK, "")
    i_id = int(rows[np.argmin(np.abs(z[rows] - (z[i_top] - LOWER_INCISOR_CROWN_MM)))])
    i_id = max(min(i_id, i_top), i_pog)
    res["id"] = (np.array([mid_x, py[i_id], z[i_id]]), UNCERTAIN,
                 f"teeth and alveolar bone are one in a bone mask: placed {LOWER_INCISOR_CROWN_MM:g} mm "
                 "(a lower incisor crown) below the highest point of the mandible's front")
    seg = np.arange(i_pog, i_id + 1)
    seg = seg[has[seg]]
    if len(seg) >= 3 and i_id > i_pog:
        chord = py[i_pog] + (py[i_id] - py[i_pog]) * (z[seg] - z[i_pog]) / (z[i_id] - z[i_pog])
        dep = py[seg] - chord
        i_sm = int(seg[np.argmax(dep)])
        gap = float((np.diff(seg).max() - 1) * fr.step) if len(seg) > 1 else 0.0   # rows without the mandible
        if gap > SUPRAMENTALE_GAP_MM:
            flag, ev = UNCERTAIN, (f"the mandible's profile between pogonion and infradentale has a gap of "
                                   f"{gap:.0f} mm: not one anterior surface")
        elif dep.max() > SUPRAMENTALE_MAX_DEPTH_MM:
            flag, ev = UNCERTAIN, (f"the profile runs {dep.max():.0f} mm behind the chord from pogonion to "
                                   f"infradentale (more than {SUPRAMENTALE_MAX_DEPTH_MM:g} mm): bone behind the "
                                   "mandible's front, not its concavity")
        elif dep.max() < 1.0:
            flag, ev = UNCERTAIN, "the mandible's front has no concavity above the chin"
        else:
            flag, ev = OK, ""
        res["sm"] = (np.array([mid_x, py[i_sm], z[i_sm]]), flag, ev)
    else:
        res["sm"] = (None, NOT_FOUND, "no mandible profile between infradentale and pogonion")
    # gnathion: the profile point between pogonion and menton farthest along the anterior-inferior bisector
    pts = np.argwhere(slab[:, i_bot:i_pog + 1])
    cand = np.stack([fr.coord(1, pts[:, 0]), z[i_bot + pts[:, 1]]], 1)
    j = int(np.argmax(-cand[:, 0] - cand[:, 1]))
    res["gn"] = (np.array([mid_x, cand[j, 0], cand[j, 1]]), OK, "")
    return {"id_z": z[i_id], "me": me}


def _lower_teeth_pieces(fr, pieces: list[int], mand_id: int) -> list[int]:
    """Of the bone pieces (components) between the jaws, those of the mandible: lower teeth split from it by
    the threshold lie next to it, a palate or upper teeth split from the skull lie next to the upper
    skeleton. A piece counts as the mandible's when its gap (mm) to the mandible is no larger than its gap to
    the rest of the bone (every other component; the pieces themselves left out), both measured within
    ``LOWER_PIECE_REACH_MM`` of it (a piece with neither within reach is left out)."""
    if not pieces:
        return []
    inside = np.isin(fr.comp, pieces)
    where = np.argwhere(inside)
    reach = int(np.ceil(LOWER_PIECE_REACH_MM / fr.step))
    lo = np.maximum(where.min(0) - reach, 0)
    hi = np.minimum(where.max(0) + reach + 1, fr.shape)
    box = tuple(slice(a, b) for a, b in zip(lo, hi))
    comp, bone, piece = fr.comp[box], fr.bone[box], inside[box]
    mand = comp == mand_id
    upper = bone & ~mand & ~piece
    far = float(LOWER_PIECE_REACH_MM) + fr.step
    to_mand = ndimage.distance_transform_edt(~mand, sampling=fr.step) if mand.any() else np.full(comp.shape, far)
    to_upper = ndimage.distance_transform_edt(~upper, sampling=fr.step) if upper.any() else np.full(comp.shape, far)
    keep = []
    for i in pieces:
        own = comp == i
        gap_m, gap_u = float(to_mand[own].min()), float(to_upper[own].min())
        if gap_m <= min(gap_u, LOWER_PIECE_REACH_MM):
            keep.append(int(i))
    return keep


def _side_extreme(fr, side, mask):
    """Outermost (|x|) bone point of ``mask`` (frame grid) on ``side`` (the middle of the bone within
    ``SIDE_EXTREME_TOLERANCE_MM`` of the outermost, snapped to the bone); None if empty."""
    idx = np.argwhere(mask)
    if not len(idx):
        return None
    k = np.argmax(side * idx[:, 0])
    far = idx[side * idx[:, 0] >= side * idx[k, 0] - SIDE_EXTREME_TOLERANCE_MM / fr.step - 0.01]
    p = fr.lo + fr.step * far.mean(0)
    return _nearest_surface(fr, p, None, 3.0)


def _box(fr, x, y, z):
    """Boolean grid mask of the frame for coordinate ranges (lo, hi) per axis (None: all)."""
    sl = []
    for a, r in enumerate((x, y, z)):
        if r is None:
            sl.append(slice(None))
        else:
            sl.append(slice(fr.index(a, min(r)), fr.index(a, max(r)) + 1))
    m = np.zeros(fr.shape, bool)
    m[tuple(sl)] = True
    return m


# ------------------------------------------------------------------------------------- main
def _components(bone: np.ndarray) -> tuple[np.ndarray, int]:
    """Connected components of the bone, separated where they touch at partial volume.

    As in :func:`~pdehead_addon.skull.segment_skull`: the components of the bone eroded by one voxel
    (a closed bite or a joint at partial volume no longer joins the mandible to the skull), then the
    eroded rim given back to the component next to it (three constrained label dilations).
    """
    cross = ndimage.generate_binary_structure(3, 1)
    full = np.ones((3, 3, 3), bool)
    core = ndimage.binary_erosion(bone, structure=cross)
    if not core.any():
        core = bone
    labels, n = ndimage.label(core, structure=full)
    for _ in range(3):
        spread = ndimage.grey_dilation(labels, footprint=full)
        labels = np.where(bone & (labels == 0), spread, labels)
    return labels.astype(np.int32), int(n)


def find_landmarks(ct, bone: np.ndarray, *, grid_mm: float = LANDMARK_GRID_MM) -> LandmarkSearch:
    """Find every landmark of :data:`~pdehead_addon.landmarks.STANDARD_LANDMARKS` (and the depth
    table's extra ones) on a binary bone mask, with a flag each; see the module docstring and
    :data:`RULES`.

    Parameters
    ----------
    ct : CTVolume
        The scan (only its geometry is used).
    bone : ndarray of bool, shape ``ct.shape``
        The bone mask (threshold at a bone level, cleaned of supports and fragments).
    grid_mm : float
        Resampling grid of the landmark frame.

    Returns
    -------
    LandmarkSearch
        Landmarks by name (the standard names, e.g. ``"Porion L"``), in patient LPS mm.
    """
    from .landmarks import STANDARD_LANDMARKS, frankfurt_transform, symmetry_plane

    bone = np.asarray(bone, bool)
    if bone.shape != ct.shape:
        raise PDEHeadError(f"bone mask shape {bone.shape} differs from the CT's {ct.shape}")
    if bone.sum() < 1000:
        raise PDEHeadError("too little bone for landmarks (under 1000 voxels): check the bone level")
    labels, nlab = _components(bone)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    skull_id = int(np.argmax(sizes))
    vox_mm3 = float(np.prod(ct.spacing))
    info: dict = {"components": int(nlab)}

    # 1. first frame: symmetry plane
    # on the bone's surface voxels (what a mirror image must match; thick bone's inside adds weight, not
    # evidence), with enough points that the subset's noise stays under a millimetre at the face
    # (CThead: 4,000 voxels of the whole bone left the chin 1.9 mm and the vault's top 5 mm off the plane)
    surface = bone & ~ndimage.binary_erosion(bone, structure=ndimage.generate_binary_structure(3, 1))
    # a fixed random field picks the voxels, so that a voxel's choice does not depend on the rest of the
    # bone (the skull without its mandible keeps the same points of the skull, and the same plane)
    frac = min(1.0, SYMMETRY_POINTS / max(int(surface.sum()), 1))
    sub = np.argwhere(surface & (np.random.default_rng(0).random(bone.shape, dtype=np.float32) < frac))
    pts = ct.index_to_patient(sub.astype(float))
    c, n, sym = symmetry_plane(pts, max_points=len(pts))
    info["symmetry_residual_mm"] = sym["residual_mm"]
    x_ax = n / np.linalg.norm(n)
    z_ax = np.array([0.0, 0.0, 1.0]) - x_ax[2] * x_ax
    z_ax /= np.linalg.norm(z_ax)
    y_ax = np.cross(z_ax, x_ax)
    rot = np.stack([x_ax, y_ax, z_ax])
    found: dict[str, tuple] = {}

    def frankfurt_points(fr):
        v = _Views(fr)
        mid_x = 0.0
        orb_l, orb_r, aperture, _ = _orbits_and_aperture(v, mid_x)
        out = {}
        for side, orb, tag in ((1, orb_l, "L"), (-1, orb_r, "R")):
            if orb is None:
                out[f"or_{tag}"] = None
                continue
            out[f"or_{tag}"] = orbitale(v, orb)
        _mirror_fill(fr, out, "or_{}", {"L": orb_l, "R": orb_r})
        skull_front = np.nanmin(np.where(v.front_has, v.front_y, np.nan))
        skull_back = fr.coord(1, np.flatnonzero(fr.bone.any((0, 2))).max())
        ors = [p for p in (out["or_L"], out["or_R"]) if p is not None]
        expect_z = np.mean([p[2] for p in ors]) if ors else fr.coord(2, fr.shape[2] // 2)
        expect_y = skull_front + 0.47 * (skull_back - skull_front)
        for side, tag in ((1, "L"), (-1, "R")):
            m, d = _meatus(v, side, expect_y, expect_z)
            out[f"po_{tag}"] = None if m is None else porion(v, side, m)
            out[f"po_{tag}_d"] = d
            if out[f"po_{tag}"] is not None:
                over = out[f"po_{tag}_overhang"] = porion_overhang(v, side, m, out[f"po_{tag}"])
                if over > 0:
                    # half way between the roof's edge and the canal's end (the two readings), on the roof
                    # (always, not only when flagged: a threshold would make porion jump with the grid)
                    p = out[f"po_{tag}"]
                    ix, iy = fr.index(0, p[0] - side * 0.5 * over), fr.index(1, p[1])
                    top = int(np.flatnonzero(m.any(0)).max())
                    roof = np.flatnonzero(fr.bone[ix, iy, top - 1:top + 6])
                    z = fr.coord(2, top - 1 + roof[0]) if len(roof) else p[2]
                    out[f"po_{tag}"] = np.array([fr.coord(0, ix), p[1], z])
        return v, orb_l, orb_r, aperture, out

    fr0 = _Frame(ct, bone, labels, rot, c, grid_mm)
    _, _, _, _, fp = frankfurt_points(fr0)
    need = ["po_L", "po_R", "or_L", "or_R"]
    frank = None
    if all(fp.get(k) is not None for k in need):
        pat = {k: fr0.to_patient(fp[k]) for k in need}
        try:
            frank = frankfurt_transform(pat["po_L"], pat["po_R"], pat["or_L"], pat["or_R"])
        except PDEHeadError:
            frank = None
    if frank is not None:
        # x: the symmetry plane's normal, so that the mid-sagittal plane is x = 0 of the frame (the porion
        # line may be skewed by asymmetry); z: the Frankfurt plane's normal made orthogonal to it (the two
        # differ by the skull's roll against its own symmetry plane, a few degrees)
        up = frank[2, :3]
        zn = up - (up @ x_ax) * x_ax
        zn /= np.linalg.norm(zn)
        rot2 = np.stack([x_ax, np.cross(zn, x_ax), zn])
        # keep the frame's origin on the symmetry plane so that the midline is x = 0
        fr = _Frame(ct, bone, labels, rot2, c, grid_mm)
        info["frame"] = "frankfurt"
    else:
        fr = fr0
        info["frame"] = "symmetry plane (Frankfurt landmarks not all found)"
    v, orb_l, orb_r, aperture, fp = frankfurt_points(fr)
    mid_x = 0.0
    orbits = {1: orb_l, -1: orb_r}
    tags = {1: "L", -1: "R"}

    # Frankfurt landmarks
    for side in (1, -1):
        t = tags[side]
        p = fp.get(f"or_{t}")
        found[f"or_{t.lower()}"] = (p, OK, "") if p is not None else (None, NOT_FOUND, "no orbit opening in the front view")
        p = fp.get(f"po_{t}")
        if p is None:
            found[f"po_{t.lower()}"] = (None, NOT_FOUND, "no external acoustic meatus opening in the side view")
        else:
            d, over = fp[f"po_{t}_d"], fp[f"po_{t}_overhang"]
            if d >= 20:
                found[f"po_{t.lower()}"] = (p, UNCERTAIN, f"the meatus is {d:.0f} mm from where it was expected")
            elif over > PORION_OVERHANG_MM:
                found[f"po_{t.lower()}"] = (p, UNCERTAIN, f"the bone above the meatus reaches {over:.0f} mm beyond "
                                                           "the canal's floor: porion placed half way")
            else:
                found[f"po_{t.lower()}"] = (p, OK, "")
    ors = [found[k][0] for k in ("or_l", "or_r") if found[k][0] is not None]
    orb_z = float(np.mean([p[2] for p in ors])) if ors else 0.0
    pos = [found[k][0] for k in ("po_l", "po_r") if found[k][0] is not None]

    # orbit margins
    for side in (1, -1):
        t = tags[side].lower()
        orb = orbits[side]
        if orb is None:
            for key in ("so", "sbo", "lo", "fe", "im"):
                found[f"{key}_{t}"] = (None, NOT_FOUND, "no orbit opening in the front view")
            continue
        cols = np.flatnonzero(orb.any(1))
        rows = np.flatnonzero(orb.any(0))
        ixc = int(round(np.mean(cols)))
        found[f"so_{t}"] = _pt(_rim_above(v, orb, ixc), "no bone above the orbit's centre")
        found[f"sbo_{t}"] = _pt(_rim_below(v, orb, ixc), "no bone below the orbit's centre")
        izl = int(round(rows.min() + 0.7 * (rows.max() - rows.min())))
        row = np.flatnonzero(orb[:, izl])
        p = None
        if len(row):
            edge = row.max() if side > 0 else row.min()
            p = _front_most(v, [(ix, izl) for ix in range(edge + side, edge + 9 * side, side) if 0 <= ix < fr.shape[0]])
        found[f"lo_{t}"] = _pt(p, "no bone lateral to the orbit")
        # frontal eminence: most prominent point above the orbit's centre, relative to the chord
        so = found[f"so_{t}"][0]
        fe = None
        if so is not None:
            iz0, iz1 = fr.index(2, so[2] + 10), fr.index(2, so[2] + 60)
            zs = np.arange(iz0, iz1 + 1)
            ok = v.front_has[ixc, zs]
            if ok.sum() > 10:
                zs = zs[ok]
                y = v.front_y[ixc, zs]
                chord = y[0] + (y[-1] - y[0]) * (zs - zs[0]) / max(zs[-1] - zs[0], 1)
                k = int(np.argmin(y - chord))
                fe = (v.front_point(ixc, zs[k]), OK if (chord - y)[k] >= 1.0 else UNCERTAIN,
                      "" if (chord - y)[k] >= 1.0 else "the forehead has no boss above the orbit")
        found[f"fe_{t}"] = fe if fe is not None else (None, NOT_FOUND, "no frontal bone above the orbit")
        # inferior malar: down the front view from the orbit's lateral third, the last bone row
        # before the view jumps back (the lower edge of the zygomatic body)
        ixm = int(round(np.mean(cols) + side * 0.25 * (cols.max() - cols.min())))
        iz = rows.min() - 1
        p_im, ev = None, "no lower edge of the zygomatic bone within 45 mm below the orbit"
        while iz > 0 and fr.coord(2, iz) > fr.coord(2, rows.min()) - 45:
            if v.front_has[ixm, iz] and (not v.front_has[ixm, iz - 1] or v.front_y[ixm, iz - 1] - v.front_y[ixm, iz] > 8):
                p_im, ev = v.front_point(ixm, iz), ""
                break
            iz -= 1
        found[f"im_{t}"] = (p_im, OK, "") if p_im is not None else (None, NOT_FOUND, ev)

    # an orbit cut to the other's mirror image (its rim broken in the mask): its margins are checked against the
    # mirror images of the other side's, and replaced by them (snapped to the bone) where they are not there
    for side in (1, -1):
        orb, t = orbits[side], tags[side].lower()
        if not getattr(orb, "evidence", ""):
            continue
        for key in ("so", "sbo", "lo", "fe", "im"):
            pts = {f"{key}_L": found[f"{key}_l"][0], f"{key}_R": found[f"{key}_r"][0]}
            _mirror_fill(fr, pts, key + "_{}", {"L": orbits[1], "R": orbits[-1]})
            p = pts[f"{key}_{tags[side]}"]
            if p is not None and found[f"{key}_{t}"][0] is not p:
                p = _nearest_surface(fr, p, None, 6.0)
            found[f"{key}_{t}"] = (p, UNCERTAIN, orb.evidence) if p is not None else \
                (None, NOT_FOUND, orb.evidence + "; no bone near the mirror image of the other side's")
        found[f"or_{t}"] = (found[f"or_{t}"][0], UNCERTAIN, orb.evidence) if found[f"or_{t}"][0] is not None \
            else found[f"or_{t}"]

    # zygion and supraglenoid from the side views
    for side in (1, -1):
        t = tags[side].lower()
        po, orr = found[f"po_{t}"][0], found[f"or_{t}"][0]
        if po is None or orr is None:
            found[f"za_{t}"] = (None, NOT_FOUND, "needs porion and orbitale")
            found[f"sg_{t}"] = (None, NOT_FOUND, "needs porion")
            continue
        box = _box(fr, (0, side * 200), (orr[1] + 8, po[1] - 12), (orr[2] - 15, po[2] + 5))
        p = _side_extreme(fr, side, fr.bone & box)
        found[f"za_{t}"] = _pt(p, "no bone between orbit and meatus")
        iy, iz = fr.index(1, po[1] - 10), fr.index(2, po[2] + 8)
        found[f"sg_{t}"] = _pt(v.side_point(side, iy, iz), "no bone above the glenoid fossa")

    # the mandible: the largest other component below the orbits and in front of the porions
    mand_id, mand_ev = None, "no mandible: no separate bone component below the maxilla"
    if nlab > 1:
        comp_ids, counts = np.unique(fr.comp[fr.comp > 0], return_counts=True)
        best = 0
        for cid, cnt in zip(comp_ids, counts):
            if cid == skull_id or cnt * grid_mm ** 3 < 2000:
                continue
            where = np.argwhere(fr.comp == cid)
            cz = fr.coord(2, where[:, 2].mean())
            if cz < orb_z - 30 and cnt > best:
                mand_id, best = int(cid), cnt
        if mand_id is None and sizes[skull_id] * vox_mm3 > 0:
            mand_ev = ("no mandible: no separate bone component 30 mm below orbitale (missing, or joined to the "
                       "skull at the teeth)")
    info["mandible"] = mand_id is not None

    # the upper skeleton: every kept component but the mandible (thin bone splits a face into pieces)
    upper_ids = [int(i) for i in range(0, nlab + 1) if i != mand_id]    # 0: thin bone no component reached
    mand_top = None
    if mand_id is not None:
        ixm = fr.index(0, mid_x)
        col = (fr.comp[max(ixm - 1, 0):ixm + 2] == mand_id).any((0, 1))
        mand_top = fr.coord(2, np.flatnonzero(col).max()) if col.any() else None
    up = _midline(found, fr, v, mid_x, upper_ids, [mand_id] if mand_id else [], orb_z, aperture, mand_top)
    if mand_id is None:
        for key in ("id", "sm", "pog", "gn", "me"):
            found[key] = (None, NOT_FOUND, mand_ev)
        low = {}
    else:
        # lower teeth split from the mandible by the threshold count as the mandible: the pieces on the
        # midline between the upper jaw and the mandible's top that lie nearer the mandible than the upper
        # skeleton (a palate or upper teeth split from the skull reach down into that window too)
        ids = [mand_id]
        if up and mand_top is not None:
            ixm = fr.index(0, mid_x)
            izs = slice(fr.index(2, mand_top - 15), fr.index(2, up["low_z"] - 1) + 1)
            n_pt = found.get("n", (None,))[0]
            iy_lim = fr.shape[1] if n_pt is None else fr.index(1, n_pt[1] + 40.0)   # the face, not the spine
            pieces = np.unique(fr.comp[max(ixm - 1, 0):ixm + 2, :iy_lim, izs])
            ids += _lower_teeth_pieces(fr, [int(i) for i in pieces if i not in (0, skull_id, mand_id)], mand_id)
        low = _mandible_midline(found, fr, mid_x, ids)

    # alare curvature (bony proxy): the outermost point of the nasal aperture's margin
    for side in (1, -1):
        t = tags[side].lower()
        if aperture is None:
            found[f"ac_{t}"] = (None, NOT_FOUND, "no nasal aperture in the front view")
            continue
        half = aperture & ((side * (fr.coord(0, np.arange(fr.shape[0])) - mid_x)) > 0)[:, None]
        cols = np.flatnonzero(half.any(1))
        if not len(cols):
            found[f"ac_{t}"] = (None, NOT_FOUND, "the nasal aperture does not reach this side")
            continue
        edge = cols.max() if side > 0 else cols.min()
        izs = np.flatnonzero(half[edge])
        iz = int(izs[len(izs) // 2])
        p = None
        for ix in range(edge + side, edge + 6 * side, side):
            if 0 <= ix < fr.shape[0] and v.front_has[ix, iz]:
                p = v.front_point(ix, iz)
                break
        found[f"ac_{t}"] = (p, UNCERTAIN, "bony proxy of a soft-tissue landmark (the aperture's widest point)") \
            if p is not None else (None, NOT_FOUND, "no bone lateral to the nasal aperture")

    # canine and molar points
    zy = [found[f"za_{s}"][0] for s in "lr"]
    breadth = abs(zy[0][0] - zy[1][0]) if zy[0] is not None and zy[1] is not None else 130.0
    for side in (1, -1):
        t = tags[side].lower()
        ixc = fr.index(0, mid_x + side * 0.13 * breadth)
        if up:
            iz = fr.index(2, up["sd_z"] + 10)
            p = v.front_point(ixc, iz)
            if p is not None and p[1] - up["sd_y"] > SUPRA_CANINE_BEHIND_MM:
                # the maxilla above the canine is not in the mask: the column's front-most bone is the skull
                # base or the occiput, not the canine's (seen on a voxelised skull mesh: 190 mm behind)
                found[f"sc_{t}"] = (None, NOT_FOUND, f"no maxilla above the canine (the front-most bone there is "
                                                     f"{p[1] - up['sd_y']:.0f} mm behind supradentale)")
            else:
                found[f"sc_{t}"] = _pt(p, "no maxilla above the canine", UNCERTAIN,
                                       "the canine's place is taken 13 % of the bizygomatic breadth from the midline")
        else:
            found[f"sc_{t}"] = (None, NOT_FOUND, "no upper jaw found on the midline")
        if low:
            iz = fr.index(2, low["id_z"] - 10)
            col = fr.bone[ixc, :, iz] & (fr.comp[ixc, :, iz] == mand_id)
            p = None if not col.any() else np.array([fr.coord(0, ixc), fr.coord(1, np.argmax(col)), fr.coord(2, iz)])
            found[f"ic_{t}"] = _pt(p, "no mandible below the canine", UNCERTAIN,
                                   "the canine's place is taken 13 % of the bizygomatic breadth from the midline")
        else:
            found[f"ic_{t}"] = (None, NOT_FOUND, mand_ev if mand_id is None else "no mandible profile")

    # mandible, bilateral
    for side in (1, -1):
        t = tags[side].lower()
        keys = ("go", "ocl", "subm2", "mr", "mmb")
        if mand_id is None or not low:
            for key in keys:
                found[f"{key}_{t}"] = (None, NOT_FOUND, mand_ev)
            continue
        xs = fr.coord(0, np.arange(fr.shape[0])) - mid_x
        halfm = (fr.comp == mand_id) & (side * xs > 5)[:, None, None]
        w = np.argwhere(halfm)
        if not len(w):
            for key in keys:
                found[f"{key}_{t}"] = (None, NOT_FOUND, "no mandible on this side")
            continue
        P = fr.lo + fr.step * w
        # gonion: the outermost point of the angle -- the farthest back-and-down point, then laterally
        k = int(np.argmax(P[:, 1] - P[:, 2]))
        near = P[np.linalg.norm(P[:, 1:] - P[k, 1:], axis=1) < 4.0]
        go = near[np.argmax(side * near[:, 0])]
        found[f"go_{t}"] = (go, OK, "")
        me = low["me"]
        top_z = P[:, 2].max()
        z_occ = 0.5 * (up["sd_z"] + low["id_z"]) if up else low["id_z"] + 3
        # occlusal line on the ramus: outermost mandible point at the occlusal plane, behind the molars
        ram = P[(np.abs(P[:, 2] - z_occ) <= 1.5) & (P[:, 1] > me[1] + 0.6 * (go[1] - me[1]))]
        found[f"ocl_{t}"] = (ram[np.argmax(side * ram[:, 0])], OK, "") if len(ram) else \
            (None, NOT_FOUND, "the ramus does not reach the occlusal plane")
        # sub M2: body below the second molar -- 60 % of the way from menton to gonion, mid-height of the body
        y2 = me[1] + 0.6 * (go[1] - me[1])
        col = P[np.abs(P[:, 1] - y2) <= 1.5]
        if len(col):
            zmid = 0.5 * (col[:, 2].min() + min(col[:, 2].max(), low["id_z"]))
            ring = col[np.abs(col[:, 2] - zmid) <= 1.5]
            found[f"subm2_{t}"] = (ring[np.argmax(side * ring[:, 0])], OK, "") if len(ring) else \
                (None, NOT_FOUND, "no mandibular body at the second molar")
        else:
            found[f"subm2_{t}"] = (None, NOT_FOUND, "no mandibular body at the second molar")
        # mid-ramus: outermost point of the ramus half way up from gonion to the condyle's top
        zr = 0.5 * (go[2] + top_z)
        ram = P[(np.abs(P[:, 2] - zr) <= 1.5) & (P[:, 1] > me[1] + 0.6 * (go[1] - me[1]))]
        if len(ram):
            yc = 0.5 * (ram[:, 1].min() + ram[:, 1].max())
            band = ram[np.abs(ram[:, 1] - yc) <= 3]
            found[f"mr_{t}"] = (band[np.argmax(side * band[:, 0])], OK, "")
        else:
            found[f"mr_{t}"] = (None, NOT_FOUND, "no ramus above gonion")
        # mid-mandibular border: the lowest point of the body half way from menton to gonion
        ym = 0.5 * (me[1] + go[1])
        col = P[np.abs(P[:, 1] - ym) <= 1.0]
        found[f"mmb_{t}"] = (col[np.argmin(col[:, 2])], OK, "") if len(col) else \
            (None, NOT_FOUND, "no mandibular border half way to gonion")
        # supra M2 on the maxilla, same y as sub M2, 10 mm above prosthion's height
        if up:
            iy, iz = fr.index(1, y2), fr.index(2, up["sd_z"] + 8)
            p = v.side_point(side, iy, iz)
            found[f"supm2_{t}"] = _pt(p, "no maxilla above the second molar")
        else:
            found[f"supm2_{t}"] = (None, NOT_FOUND, "no upper jaw found on the midline")
    for side in (1, -1):
        t = tags[side].lower()
        if f"supm2_{t}" not in found:
            found[f"supm2_{t}"] = (None, NOT_FOUND, mand_ev)

    # bilateral Frankfurt landmarks must mirror each other across the mid-sagittal plane
    for key in ("po", "or"):
        a, b = found.get(f"{key}_l", (None,))[0], found.get(f"{key}_r", (None,))[0]
        if a is not None and b is not None:
            gap = float(np.linalg.norm(a * np.array([-1.0, 1.0, 1.0]) - b))
            if gap > MIRROR_TOLERANCE_MM:
                for side in "lr":
                    p, _, ev = found[f"{key}_{side}"]
                    found[f"{key}_{side}"] = (p, UNCERTAIN, f"left and right are {gap:.0f} mm from mirror images")
    if frank is None:   # every rule assumes the Frankfurt orientation
        for key, (p, flag, ev) in list(found.items()):
            if p is not None and flag == OK:
                found[key] = (p, UNCERTAIN, "no Frankfurt frame (porion or orbitale missing): found in the "
                                            "frame of the symmetry plane")

    # results in patient mm, by standard name
    out: dict[str, FoundLandmark] = {}
    for d in STANDARD_LANDMARKS:
        p, flag, ev = found.get(d.key, (None, NOT_FOUND, "no rule"))
        if p is None and flag != NOT_FOUND:
            flag = NOT_FOUND
        out[d.name] = FoundLandmark(d.name, None if p is None else fr.to_patient(p), flag, ev)
    info["found"] = sum(lm.flag != NOT_FOUND for lm in out.values())
    return LandmarkSearch(out, frank, info)


def _pt(p, missing: str, flag: str = OK, evidence: str = ""):
    return (p, flag, evidence) if p is not None else (None, NOT_FOUND, missing)
