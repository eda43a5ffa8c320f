"""Automatic craniometric landmarks on the bone, each by a written rule, with a confidence flag.

The input is the binary bone mask (the CT thresholded at a bone level and cleaned,
:attr:`pdehead_addon.forensic.skull.SkullSegmentation.bone`) and the CT's geometry: no grey
values are used, so the same code runs on a head CT and on a dry-skull CT.

Method (every step a pure function of the mask):

1. **A first frame.** The skull's plane of reflective symmetry
   (:func:`~pdehead_addon.forensic.landmarks.symmetry_plane`, mirror ICP on the bone's voxel
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
   orbit margin) on both sides give :func:`~pdehead_addon.forensic.landmarks.frankfurt_transform`;
   steps 2-3 are repeated in that frame and every other landmark is found there by the rule
   in :data:`RULES` (also in the docstrings of the rules' functions).
5. Points are mapped back to patient LPS mm (the CT's frame, not the aligned one).

Flags: ``ok`` (the rule's evidence was found as expected), ``uncertain`` (the rule placed a
point but its evidence was weak; :attr:`FoundLandmark.evidence` says which) and
``not_found`` (no point; the evidence says why, e.g. no mandible in the scan).

Code: this module runs the steps (:func:`find_landmarks`); the frame and its depth images are in
:mod:`.landmark_frame`, the openings and the Frankfurt points in :mod:`.landmark_openings`, the rules of
the mid-sagittal landmarks in :mod:`.landmark_midline` and of the bilateral ones in :mod:`.landmark_bilateral`.

Nomenclature: the landmark set of :data:`~pdehead_addon.forensic.landmarks.STANDARD_LANDMARKS`,
with the depth-table codes of Caple & Stephan (2016) where they differ (pr = Supradentale,
pg = Pogonion, zy = Zygomatic arch, mso = Supraorbital, mio = Suborbital, sM2 = Supra M2,
iM2 = Sub M2) and the table's landmarks the set lacked (mn, ss, gn, ac, sC, iC, mr, mmb).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from ..core.errors import PDEHeadError
from .landmark_bilateral import (
    alare,
    canine_points,
    mandible_bilateral,
    mid_ramus_on_rami,
    orbit_margins,
    zygion_supraglenoid,
)
from .landmark_frame import FLAGS, NOT_FOUND, OK, UNCERTAIN, LandmarkFrame, bone_components
from .landmark_midline import mandible_component, midline_landmarks
from .landmark_openings import MIRROR_TOLERANCE_MM, PORION_OVERHANG_MM, frankfurt_points
from .landmarks import STANDARD_LANDMARKS, frankfurt_transform, symmetry_plane
from .mandible_pieces import join_mandible_pieces

__all__ = ["FLAGS", "NOT_FOUND", "OK", "RULES", "UNCERTAIN", "FoundLandmark", "LandmarkSearch", "find_landmarks"]

#: Grid (mm) the bone mask is resampled on in the landmark frame.
LANDMARK_GRID_MM = 1.0
#: Shifts (fractions of a grid step along the frame's x, y, z) of the grids the landmark search compares; the
#: first is the unshifted grid.
GRID_PHASES = ((0.0, 0.0, 0.0), (0.5, 0.5, 0.5), (0.25, 0.75, 0.5), (0.75, 0.25, 0.25), (0.5, 0.0, 0.75))
#: Grids the search runs on by default (:func:`find_landmarks`): all five (an odd number: a medoid without ties).
#: On one grid CThead's and GE's landmarks moved by a median 3.3 / 4.5 mm when the grid was shifted, on four by
#: 1.2 / 0.6 mm. Five against one (scripts/bench/bench_face.py; each a CThead or GE check, none chosen on one
#: score): the face from the skull within +-2.5 mm on CThead stripped at 1500 / 1600 / its own level 52.7 / 55.2 /
#: 58.1 -> 53.1 / 53.6 / 59.9 %, GE 49.9 -> 54.4 %, the phantom 42.2 -> 42.5 %; CThead's landmarks against the
#: hand-placed ones 2.83 -> 2.72 mm median (four grids: 3.18); the search takes about 3x as long.
LANDMARK_GRID_PHASES = len(GRID_PHASES)
#: A landmark whose grids' points lie further than this (mm, median distance to the one kept) is uncertain.
PHASE_SPREAD_MM = 3.0
#: Bone surface voxel centres used for the first frame's symmetry plane (a random subset).
SYMMETRY_POINTS = 20000


#: The rule of every landmark (by the key of :data:`~pdehead_addon.forensic.landmarks.STANDARD_LANDMARKS`; "L/R"
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
          "point (the front walked up from menton ends where it steps back by more than 20 mm: bone joined behind "
          "it is not its front; always uncertain, as prosthion); not found where it lies more than 20 mm behind "
          "supradentale (the lower incisors close behind the upper ones: bone that far back is not theirs).",
    "sm": "Supramentale (B point): the deepest point of the mandible's profile relative to the chord from "
          "pogonion to infradentale (the mandible with the lower teeth split from it: pieces between the jaws "
          "nearer the mandible than the upper skeleton); uncertain with no concavity (under 1 mm), a concavity "
          "deeper than 8 mm, or a gap of more than 3 mm in the profile; not found where infradentale is not.",
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
    "supm2": "Supra M2 (sM2): the outermost bone (side view) at sub M2's y, 8 mm above prosthion's height; without "
             "the mandible, at 56 % of the way from prosthion to porion (uncertain).",
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



def find_landmarks(ct, bone: np.ndarray, *, grid_mm: float = LANDMARK_GRID_MM,
                   phases=LANDMARK_GRID_PHASES, mandible: np.ndarray | None = None) -> LandmarkSearch:
    """Find every landmark of :data:`~pdehead_addon.forensic.landmarks.STANDARD_LANDMARKS` (and the depth
    table's extra ones) on a binary bone mask, with a flag each; see the module docstring and
    :data:`RULES`.

    The rules read the bone resampled on a grid, and a rule that picks a pixel (the lowest, the deepest, the
    first after a jump) can move by several millimetres when the same bone is sampled on a grid shifted by half
    a step. So the search runs on ``phases`` grids shifted by fractions of a step (:data:`GRID_PHASES`) and keeps,
    for each landmark, the grid's point nearest all the others (the medoid): a point a rule actually produced,
    with that rule's flag; ``uncertain`` when the points of the grids lie more than :data:`PHASE_SPREAD_MM`
    apart (median distance to the medoid) or when fewer than all grids found it.

    Parameters
    ----------
    ct : CTVolume
        The scan (only its geometry is used).
    bone : ndarray of bool, shape ``ct.shape``
        The bone mask (threshold at a bone level, cleaned of supports and fragments).
    grid_mm : float
        Resampling grid of the landmark frame.
    phases : int or sequence of 3-tuples
        Number of shifted grids, the first of :data:`GRID_PHASES` (1: the grid anchored at the symmetry plane's
        centre only), or the shifts themselves (fractions of a step in [0, 1) along the frame's x, y, z).
    mandible : ndarray of bool, shape ``ct.shape``, optional
        The segmentation's mandible (``SkullSegmentation.mandible``). Where the rules find no mandible's body (a
        scan cut through the lower teeth) and this holds its rami, mid-ramus is placed on them
        (:func:`~.landmark_bilateral.mid_ramus_on_rami`).

    Returns
    -------
    LandmarkSearch
        Landmarks by name (the standard names, e.g. ``"Porion L"``), in patient LPS mm.
        ``info["phase_spread_mm"]``: for each landmark found, the median distance of the grids' points to the one
        kept.
    """
    bone = np.asarray(bone, bool)
    if bone.shape != ct.shape:
        raise PDEHeadError(f"bone mask shape {bone.shape} differs from the CT's {ct.shape}")
    if bone.sum() < 1000:
        raise PDEHeadError("too little bone for landmarks (under 1000 voxels): check the bone level")
    labels, nlab = bone_components(bone)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    shifts = (GRID_PHASES[:max(1, min(int(phases), len(GRID_PHASES)))] if np.ndim(phases) == 0
              else tuple(tuple(float(v) for v in s) for s in phases))
    info: dict = {"components": int(nlab), "grid_phases": len(shifts)}

    c, x_ax = _symmetry_plane(ct, bone, info)
    frames, frank = _frankfurt_frames(ct, bone, labels, c, x_ax, grid_mm, shifts, info)
    rami = None             # the segmentation's mandible in patient mm, once for every grid
    if mandible is not None and np.any(mandible):
        rami = ct.index_to_patient(np.argwhere(mandible).astype(float))
    runs = []
    for fr, fp in frames:
        run_info = dict(info)
        runs.append(_landmarks_on_grid(ct, bone, labels, sizes, nlab, fr, fp, frank, run_info, rami))
        if len(runs) == 1:
            info = run_info           # the mandible and the scan's cut as the first grid saw them
    out, spread = _medoids(runs) if len(runs) > 1 else (runs[0], {})
    info["phase_spread_mm"] = spread
    info["found"] = sum(lm.flag != NOT_FOUND for lm in out.values())
    return LandmarkSearch(out, frank, info)


def _landmarks_on_grid(ct, bone, labels, sizes, nlab, fr, fp_all, frank, info: dict,
                       rami=None) -> dict[str, FoundLandmark]:
    """Every rule on one resampled grid ``fr`` (with its :func:`frankfurt_points` ``fp_all``): landmarks by
    standard name in patient mm. ``rami``: the segmentation's mandible voxels (patient mm) or None."""
    skull_id = int(np.argmax(sizes))
    vox_mm3 = float(np.prod(ct.spacing))
    grid_mm = fr.step
    v, orb_l, orb_r, aperture, fp = fp_all
    mid_x = 0.0
    orbits = {1: orb_l, -1: orb_r}
    found: dict[str, tuple] = {}
    _frankfurt_landmarks(found, fp)
    ors = [found[k][0] for k in ("or_l", "or_r") if found[k][0] is not None]
    orb_z = float(np.mean([p[2] for p in ors])) if ors else 0.0
    orbit_margins(found, fr, v, orbits)
    zygion_supraglenoid(found, fr, v)
    pos_pts = [found[k][0] for k in ("po_l", "po_r") if found.get(k, (None,))[0] is not None]
    porion_y = float(np.mean([p[1] for p in pos_pts])) if pos_pts else None
    orbitale_y = float(np.mean([p[1] for p in ors])) if ors else None
    mand_id, mand_ev = mandible_component(fr, nlab, skull_id, sizes[skull_id] * vox_mm3, grid_mm, orb_z, porion_y,
                                          orbitale_y, mid_x)
    info["mandible"] = mand_id is not None
    up, low = midline_landmarks(found, fr, mid_x, nlab, skull_id, mand_id, mand_ev, orb_z, aperture)
    alare(found, fr, v, aperture, mid_x)
    canine_points(found, fr, v, mid_x, up, low, mand_id, mand_ev)
    if mand_id is not None:     # a ramus the threshold broke into pieces: its landmarks from the whole of it
        po_z = [fr.index(2, p[2]) for p in pos_pts]
        joined = join_mandible_pieces(fr.comp, fr.bone, grid_mm, mand_id, skull_id, ct.spacing,
                                      max(po_z) if po_z else None)
        info["mandible_pieces_joined"] = len(joined)
    mandible_bilateral(found, fr, v, mid_x, up, low, mand_id, mand_ev)
    if mand_id is None and rami is not None:
        mid_ramus_on_rami(found, (rami - fr.centre) @ fr.rot.T)
    _check_mirror_images(found)
    if frank is None:   # every rule assumes the Frankfurt orientation
        _flag_without_frankfurt(found)

    # results in patient mm, by standard name
    out: dict[str, FoundLandmark] = {}
    for d in STANDARD_LANDMARKS:
        p, flag, ev = found.get(d.key, (None, NOT_FOUND, "no rule"))
        if p is None and flag != NOT_FOUND:
            flag = NOT_FOUND
        out[d.name] = FoundLandmark(d.name, None if p is None else fr.to_patient(p), flag, ev)
    return _mandible_at_the_scan_end(ct, bone, labels, fr, mand_id, out, info)


def _medoid(points: np.ndarray) -> tuple[int, np.ndarray]:
    """The index of the point nearest all the others (least summed distance) and its distances to each."""
    dist = np.linalg.norm(points[:, None] - points[None], axis=2)
    best = int(np.argmin(dist.sum(axis=1)))
    return best, dist[best]


def _medoids(runs: list[dict[str, FoundLandmark]]) -> tuple[dict[str, FoundLandmark], dict[str, float]]:
    """One landmark set from the sets found on shifted grids: each landmark's medoid over the grids that found
    it (not found when at most half did), uncertain when the grids disagree; and each landmark's spread (mm)."""
    out: dict[str, FoundLandmark] = {}
    spread: dict[str, float] = {}
    n = len(runs)
    for name in runs[0]:
        hits = [r[name] for r in runs if r[name].point is not None]
        if 2 * len(hits) <= n:
            out[name] = next(r[name] for r in runs if r[name].point is None)
            continue
        best, dist = _medoid(np.array([h.point for h in hits]))
        lm = hits[best]
        spread[name] = float(np.median(dist))
        flag, ev = lm.flag, lm.evidence
        if flag == OK and spread[name] > PHASE_SPREAD_MM:
            flag, ev = UNCERTAIN, (f"the rule's point moves {spread[name]:.0f} mm when the bone is resampled on a "
                                   "shifted grid")
        elif flag == OK and len(hits) < n:
            flag, ev = UNCERTAIN, f"found on {len(hits)} of {n} shifted grids"
        out[name] = FoundLandmark(name, lm.point, flag, ev)
    return out, spread


def _flag_without_frankfurt(found: dict[str, tuple]) -> None:
    """Mark every landmark found OK as uncertain: its rule assumed the Frankfurt orientation, which is missing."""
    for key, (p, flag, _ev) in list(found.items()):
        if p is not None and flag == OK:
            found[key] = (p, UNCERTAIN, "no Frankfurt frame (porion or orbitale missing): found in the "
                                        "frame of the symmetry plane")


def _mandible_at_the_scan_end(ct, bone: np.ndarray, labels: np.ndarray, fr, mand_id, out: dict[str, FoundLandmark],
                              info: dict) -> dict[str, FoundLandmark]:
    """The landmarks ``out`` once the scan's lower end is accounted for: a narrow piece below the orbits that ends
    inside the scan is no mandible (its landmarks not found), and what the mandible carries below a scan cut through
    the face is outside the scan. Sets ``info["scan_cut"]`` (and ``info["mandible"]`` when the piece is dropped)."""
    cut, low_end = scan_cut_through_bone(ct, bone)
    info["scan_cut"] = cut
    width = 0.0
    if mand_id is not None:
        cols = np.argwhere(fr.comp == mand_id)[:, 0]
        width = float(fr.coord(0, cols.max()) - fr.coord(0, cols.min())) if len(cols) else 0.0
    if mand_id is not None and width < MANDIBLE_MIN_WIDTH_MM and not (labels[low_end] == mand_id).any():
        # a mandible is either whole (as wide as the face) or cut by the scan's end (and reaches it)
        mand_id, mand_ev = None, (f"no mandible: the piece below the orbits is {width:.0f} mm wide and ends inside "
                                  "the scan (the upper jaw's, split off by the bone level)")
        info["mandible"] = False
        out = {d.name: (out[d.name] if d.key.split("_")[0] not in MANDIBLE_KEYS
                        else FoundLandmark(d.name, None, NOT_FOUND, mand_ev)) for d in STANDARD_LANDMARKS}
    if cut and mand_id is None:     # the scan ends in the face: what the mandible carries lies below it
        for lm in out.values():
            if lm.flag == NOT_FOUND and lm.evidence.startswith("no mandible"):
                lm.evidence = f"outside the scan: {cut} ({lm.evidence})"
    elif cut and (labels[low_end] == mand_id).any():
        # the mandible runs out of the scan: its lower border, angle and chin lie below the scan's end, and the
        # rules' points on what is left (the cut's edge) are not those landmarks
        for d in STANDARD_LANDMARKS:
            if d.key.split("_")[0] in MANDIBLE_BORDER_KEYS and out[d.name].flag != NOT_FOUND:
                out[d.name] = FoundLandmark(d.name, None, NOT_FOUND,
                                            f"outside the scan: {cut}; the mandible runs out of it")
    return out


#: Every landmark on the mandible.
MANDIBLE_KEYS = ("id", "sm", "pog", "gn", "me", "go", "subm2", "mr", "mmb", "ic", "ocl")
#: The mandible's landmarks on its lower border, angle, chin and ramus (their rules need the lowest mandible):
#: outside the scan when the mandible runs out of its lower end.
MANDIBLE_BORDER_KEYS = ("pog", "gn", "me", "go", "subm2", "mr", "mmb", "ic")
#: Bone within this many voxels of the scan's lower end (its lowest slices, or a tilted slab's lower border) ...
SCAN_CUT_VOXELS = 2
#: ... of at least this volume (mm^3) means the scan ends through the skull (a scan cut at the maxilla or the teeth).
SCAN_CUT_MIN_MM3 = 100.0
#: A mandible wholly inside the scan is at least this wide (mm; adult bigonial breadth ~ 90-100 mm, bicondylar
#: ~ 120 mm): a narrower piece below the orbits that does not reach the scan's end is the upper jaw's (a premaxilla
#: split off by the bone level), not the mandible.
MANDIBLE_MIN_WIDTH_MM = 70.0


def scan_cut_through_bone(ct, bone: np.ndarray) -> tuple[str, np.ndarray]:
    """Where the scan ends through the skull: ("" when no bone lies at its lower end, else a description with the
    height in patient mm of the bone there; the lower end's voxels). The lower end: the ``SCAN_CUT_VOXELS``
    lowest slices, and where the scan has a coverage mask (a tilted slab resampled), the covered voxels within
    that many slices of its lower border."""
    bone = np.asarray(bone, bool)
    nz = bone.shape[0]
    n = SCAN_CUT_VOXELS
    up = float(ct.direction[2, 2]) >= 0              # slice index runs up (k = 0 lowest)
    low = np.zeros(bone.shape, bool)
    if up:
        low[:n] = True
    else:
        low[nz - n:] = True
    cov = getattr(ct, "coverage", None)
    if cov is not None:
        shifted = np.ones_like(cov)                  # True where the voxel n slices below is covered
        if up:
            shifted[n:] = cov[:-n]
            shifted[:n] = False
        else:
            shifted[:-n] = cov[n:]
            shifted[-n:] = False
        low |= cov & ~shifted
    at = np.argwhere(bone & low)
    volume = float(len(at)) * float(np.prod(ct.spacing))
    if volume < SCAN_CUT_MIN_MM3:
        return "", low
    z = ct.index_to_patient(at.astype(float))[:, 2]
    return (f"the scan ends through the skull at z = {np.median(z):.0f} mm ({volume:.0f} mm3 of bone at its lower "
            "end)"), low


def _symmetry_plane(ct, bone: np.ndarray, info: dict):
    """The first frame: the skull's plane of reflective symmetry (a point on it and its unit normal, the frame's x)
    on the bone's surface voxels (what a mirror image must match; thick bone's inside adds weight, not evidence),
    with enough points that the subset's noise stays under a millimetre at the face (CThead: 4,000 voxels of the
    whole bone left the chin 1.9 mm and the vault's top 5 mm off the plane)."""
    surface = bone & ~ndimage.binary_erosion(bone, structure=ndimage.generate_binary_structure(3, 1))
    # a fixed random field picks the voxels, so that a voxel's choice does not depend on the rest of the
    # bone (the skull without its mandible keeps the same points of the skull, and the same plane)
    frac = min(1.0, SYMMETRY_POINTS / max(int(surface.sum()), 1))
    sub = np.argwhere(surface & (np.random.default_rng(0).random(bone.shape, dtype=np.float32) < frac))
    pts = ct.index_to_patient(sub.astype(float))
    c, n, sym = symmetry_plane(pts, max_points=len(pts))
    info["symmetry_residual_mm"] = sym["residual_mm"]
    return c, n / np.linalg.norm(n)


def _frankfurt_frames(ct, bone, labels, c, x_ax, grid_mm: float, shifts, info: dict):
    """The landmark frames, one per grid shift: the Frankfurt frame when porions and orbitales are found in the
    symmetry plane's frame (each the medoid over the shifted grids, so that one rotation serves every grid), else
    that frame; returns ([(frame, :func:`frankfurt_points` in it)], Frankfurt transform or None)."""
    z_ax = np.array([0.0, 0.0, 1.0]) - x_ax[2] * x_ax
    z_ax /= np.linalg.norm(z_ax)
    y_ax = np.cross(z_ax, x_ax)
    rot = np.stack([x_ax, y_ax, z_ax])
    need = ["po_L", "po_R", "or_L", "or_R"]
    first = []
    for shift in shifts:
        fr0 = LandmarkFrame(ct, bone, labels, rot, c, grid_mm, shift)
        fp_all = frankfurt_points(fr0)
        first.append((fr0, fp_all))
    pat = {}
    for k in need:
        pts = [fr0.to_patient(fp_all[4][k]) for fr0, fp_all in first if fp_all[4].get(k) is not None]
        if 2 * len(pts) > len(first):
            pat[k] = pts[_medoid(np.array(pts))[0]]
    frank = None
    if len(pat) == len(need):
        try:
            frank = frankfurt_transform(pat["po_L"], pat["po_R"], pat["or_L"], pat["or_R"])
        except PDEHeadError:
            frank = None
    if frank is None:
        info["frame"] = "symmetry plane (Frankfurt landmarks not all found)"
        return first, None
    # x: the symmetry plane's normal, so that the mid-sagittal plane is x = 0 of the frame (the porion
    # line may be skewed by asymmetry); z: the Frankfurt plane's normal made orthogonal to it (the two
    # differ by the skull's roll against its own symmetry plane, a few degrees)
    up = frank[2, :3]
    zn = up - (up @ x_ax) * x_ax
    zn /= np.linalg.norm(zn)
    rot2 = np.stack([x_ax, np.cross(zn, x_ax), zn])
    info["frame"] = "frankfurt"
    # keep the frame's origin on the symmetry plane so that the midline is x = 0
    frames = []
    for shift in shifts:
        fr = LandmarkFrame(ct, bone, labels, rot2, c, grid_mm, shift)
        frames.append((fr, frankfurt_points(fr)))
    return frames, frank


def _frankfurt_landmarks(found: dict, fp: dict) -> None:
    """Orbitale and porion of both sides, flagged (from :func:`~.landmark_openings.frankfurt_points`)."""
    for t in ("L", "R"):
        p = fp.get(f"or_{t}")
        found[f"or_{t.lower()}"] = ((p, OK, "") if p is not None
                                    else (None, NOT_FOUND, "no orbit opening in the front view"))
        p = fp.get(f"po_{t}")
        if p is None:
            found[f"po_{t.lower()}"] = (None, NOT_FOUND, "no external acoustic meatus opening in the side view")
            continue
        d, over = fp[f"po_{t}_d"], fp[f"po_{t}_overhang"]
        if d >= 20:
            found[f"po_{t.lower()}"] = (p, UNCERTAIN, f"the meatus is {d:.0f} mm from where it was expected")
        elif over > PORION_OVERHANG_MM:
            found[f"po_{t.lower()}"] = (p, UNCERTAIN, f"the bone above the meatus reaches {over:.0f} mm beyond "
                                                       "the canal's floor: porion placed half way")
        else:
            found[f"po_{t.lower()}"] = (p, OK, "")


def _check_mirror_images(found: dict) -> None:
    """Bilateral landmarks must mirror each other across the mid-sagittal plane (x -> -x in the frame): both
    sides uncertain when they lie more than :data:`~.landmark_openings.MIRROR_TOLERANCE_MM` apart. Every pair, not
    only the Frankfurt points: a rule that caught the wrong bone on one side (CThead at 1600: mid-ramus L 18 mm
    below R, both ``ok``) is told by its other side, whichever of the two is wrong."""
    pairs = sorted({key[:-2] for key in found if key.endswith(("_l", "_r"))})
    for key in pairs:
        a, b = found.get(f"{key}_l", (None,))[0], found.get(f"{key}_r", (None,))[0]
        if a is None or b is None:
            continue
        gap = float(np.linalg.norm(np.asarray(a, float) * np.array([-1.0, 1.0, 1.0]) - np.asarray(b, float)))
        if gap <= MIRROR_TOLERANCE_MM:
            continue
        for side in "lr":
            p, flag, ev = found[f"{key}_{side}"]
            if flag == OK:
                found[f"{key}_{side}"] = (p, UNCERTAIN, f"left and right are {gap:.0f} mm from mirror images")
