"""The face's features facing the head's own front: a head turned in the scanner keeps a straight nose.

The shape rules of :mod:`.face_features` and :mod:`.face_eyes` (the nose, the lips, the closed eyes, the ears) build
each part "in front of the face": along the scanner's -y, with the midline at one x. A head turned about the
scanner's vertical axis (GE's bilateral landmarks: 8-15 degrees; CThead's 0-4) then had a nose built along the
scanner's y, not its own: at 10 degrees slightly asymmetric, at 20 degrees one side flattened into the cheek with a
dark fold (CThead's skull and landmarks turned without interpolation; the share of the real face within 2.5 mm
hardly moved, 53.5-54.3 %, the score seeing little of a nose).

Here the rules run in the head's frame: the landmarks (and the skull, for the nasal aperture) turned about the face
grid's vertical axis by the head's yaw (:func:`head_yaw`, from its bilateral landmarks), and the grid's column
angles by the same yaw, so "-y" and "x" are the head's front and left-right (:func:`to_head_frame`,
:func:`head_grid`). The parts come back as radial changes on the model's own columns: nothing else of the face moves.
A pitch of the head tilts the grid's rows themselves (the profile, the cheeks, the field): the whole model is made in
the head's Frankfurt frame (:func:`frankfurt_rotation`), the skull and the landmarks turned about the left-right axis
so that the orbitales stand level with the porions. The model keeps its grid, its rule sites and its landmarks in
that frame; the peg bases, normals and tips, the PDE's curves and the mesh stay in patient mm (the model's
``to_frame`` / ``from_frame`` turn points at that boundary). A roll is not addressed.

References
----------
.. [1] Garson, J. G. (1885). The Frankfort craniometric agreement, with critical remarks thereon. Journal of the
   Anthropological Institute of Great Britain and Ireland 14, 64-83 (the Frankfurt horizontal: the lowest points of
   the orbits' margins and the upper margins of the ear canals in one horizontal plane).
"""
from __future__ import annotations

import numpy as np

from ..core.mesh import Mesh
from .face_eyes import eye_shape
from .face_features import FRONT_COS, ear_shape, mouth_shape, nose_bump, straight_ahead
from .face_pegs import midsagittal_plane, mirrored
from .face_profile import FaceGrid

#: A bilateral pair counts for the yaw when its two points are at least this far apart (mm) left to right: the
#: pairs near the midline (alare curvature, ~25 mm) turn by a degree for every 0.4 mm of error across them.
YAW_PAIR_MIN_MM = 30.0
#: Fewer pairs than this: no yaw (the scanner's axes are the head's).
YAW_MIN_PAIRS = 3
#: The most yaw (degrees) taken from the landmarks; beyond it (a skull on its side, landmarks gone astray) the
#: scanner's axes are kept: the front's columns (``cos(theta + yaw) < FRONT_COS``) must stay one run.
YAW_MAX_DEG = 45.0
#: The most pitch (degrees) taken from the Frankfurt landmarks; beyond it (landmarks gone astray) the scanner's
#: axes are kept. Heads lie in scanners within about 20 degrees of the Frankfurt plane (CThead 9-10; GE about 2 with
#: its porions level, -4 with its left one off its canal).
PITCH_MAX_DEG = 30.0
#: The porions' roll (the slope of the line from Porion R to Porion L) and the orbitales' must agree within this many
#: degrees for the Frankfurt frame (:func:`frankfurt_disagreement`): a head is rigid, so both pairs show its roll,
#: and a porion found on another opening of the temporal bone (the middle ear's air, a mastoid cell) moves one side's
#: height alone. Measured: CThead (eight strips, slicings and cuts), the phantom (also in 3 mm slabs), GE stripped at
#: 250 HU and GE in 3 mm slabs agree within 2.2 degrees; GE at its own bone level differs by 6.4 (its left porion 13 mm
#: above the right while its orbitales and zygomatic arches stand level within 0.4 degrees; in the CT's sagittal
#: section that porion lies in the soft tissue in front of the canal, the 250 HU one on the canal's roof). 4 lies
#: between the two; chosen on these heads, GE being the one that fails.
ROLL_AGREEMENT_DEG = 4.0


def head_yaw(landmarks: dict) -> float:
    """The head's turn about the scanner's vertical axis (radians; + : the patient's left side further back).

    Each bilateral pair ``"<name> L"`` / ``"<name> R"`` whose points are at least :data:`YAW_PAIR_MIN_MM` apart in x
    gives the angle of L - R in the horizontal plane (0 for a head facing -y); the yaw is their median (robust to a
    landmark found on the wrong bone). 0 with fewer than :data:`YAW_MIN_PAIRS` pairs or beyond :data:`YAW_MAX_DEG`.
    """
    angles = []
    for name, left in landmarks.items():
        if not name.endswith(" L") or left is None:
            continue
        right = landmarks.get(name[:-2] + " R")
        if right is None:
            continue
        d = np.asarray(left, float) - np.asarray(right, float)
        if d[0] >= YAW_PAIR_MIN_MM:
            angles.append(np.arctan2(d[1], d[0]))
    if len(angles) < YAW_MIN_PAIRS:
        return 0.0
    yaw = float(np.median(angles))
    return yaw if abs(yaw) <= np.radians(YAW_MAX_DEG) else 0.0


def pair_roll(landmarks: dict, name: str) -> float | None:
    """The roll (degrees; + : the patient's left side higher) of the bilateral pair ``"<name> L"`` / ``"<name> R"``:
    the slope of the line from R to L against the horizontal; None without both points."""
    left, right = landmarks.get(f"{name} L"), landmarks.get(f"{name} R")
    if left is None or right is None:
        return None
    d = np.asarray(left, float) - np.asarray(right, float)
    return float(np.degrees(np.arctan2(d[2], np.hypot(d[0], d[1]))))


def frankfurt_disagreement(landmarks: dict) -> str | None:
    """Why the Frankfurt frame is not trusted (one line), or None: the porions' roll (:func:`pair_roll`) and the
    orbitales' differ by more than :data:`ROLL_AGREEMENT_DEG`, so one porion is not on its ear canal's upper margin
    and the porions' midpoint, which sets the pitch, is off by half that side's error."""
    po, orb = pair_roll(landmarks, "Porion"), pair_roll(landmarks, "Orbitale")
    if po is None or orb is None or abs(po - orb) <= ROLL_AGREEMENT_DEG:
        return None
    return (f"the porions' roll ({po:.1f} degrees) and the orbitales' ({orb:.1f}) differ by more than "
            f"{ROLL_AGREEMENT_DEG:g}: one porion is off its ear canal; the face is made in the scanner's axes")


def ear_porions(landmarks: dict) -> tuple[dict, str | None]:
    """``landmarks`` with the porion that is off its ear canal replaced, for the ears, by the other's mirror image
    across the mid-sagittal plane (:func:`.face_pegs.midsagittal_plane`), and which one (None: unchanged). Only where
    the porions disagree with the orbitales (:func:`frankfurt_disagreement`): the one off its canal is the one
    farther in height from its side's zygion (the zygomatic arch's outermost point, which runs along the Frankfurt
    plane). Measured, porion minus zygion: -1.4 to -5.6 mm on every agreeing head and variant (CThead's eight, the
    phantom, GE at 250 HU), +11.4 mm on GE's automatic left porion, which stands in the soft tissue in front of the
    canal; its ear was 13 mm higher than the right one."""
    off = _porion_off_its_canal(landmarks) if frankfurt_disagreement(landmarks) is not None else None
    if off is None:
        return landmarks, None
    kept = "R" if off == "L" else "L"
    out = dict(landmarks)
    out[f"Porion {off}"] = mirrored(np.asarray(landmarks[f"Porion {kept}"], float), midsagittal_plane(landmarks))
    return out, f"Porion {off}"


def _porion_off_its_canal(landmarks: dict) -> str | None:
    """The side ("L" / "R") whose porion lies farther in height from its zygion (:func:`ear_porions`), or None
    without both pairs or a mid-sagittal plane to mirror across."""
    gap = {}
    for side in "LR":
        po, zy = landmarks.get(f"Porion {side}"), landmarks.get(f"Zygomatic arch {side}")
        if po is not None and zy is not None:
            gap[side] = abs(float(po[2]) - float(zy[2]))
    if len(gap) < 2 or midsagittal_plane(landmarks) is None:
        return None
    return max(gap, key=gap.get)


def frame_refusal(landmarks: dict) -> dict:
    """The provenance of a Frankfurt frame refused (:func:`frankfurt_disagreement`): why (``frankfurt_frame``) and the
    porion the ears do not follow (``ear_porion``, :func:`ear_porions`); {} where the porions agree."""
    why = frankfurt_disagreement(landmarks)
    if why is None:
        return {}
    out = {"frankfurt_frame": why}
    off = _porion_off_its_canal(landmarks)
    if off is not None:
        out["ear_porion"] = (f"Porion {off} is off its ear canal (farther from its zygion than the other): its ear "
                             "stands at the other's mirror image")
    return out


def frankfurt_rotation(landmarks: dict) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The turn (3 x 3, patient -> frame), its pivot (3,) and its angle (radians, + : the orbitales above the
    porions in the scan) that put the head's Frankfurt horizontal [1]_ level:
    about the horizontal axis across the head, by the angle at which the orbitales' midpoint rises over the
    porions' (the front's bearing and the scanner's vertical kept). None without a porion and an orbitale, beyond
    :data:`PITCH_MAX_DEG`, or where the porions disagree with the orbitales (:func:`frankfurt_disagreement`).
    Pivot: the porions' midpoint."""
    if frankfurt_disagreement(landmarks) is not None:
        return None

    def mean_of(*names):
        pts = [np.asarray(landmarks[n], float) for n in names if landmarks.get(n) is not None]
        return np.mean(pts, axis=0) if pts else None
    porion, orbitale = mean_of("Porion L", "Porion R"), mean_of("Orbitale L", "Orbitale R")
    if porion is None or orbitale is None:
        return None
    d = orbitale - porion
    h = float(np.hypot(d[0], d[1]))
    if h < 1e-6:
        return None
    pitch = float(np.arctan2(d[2], h))
    if pitch == 0.0 or abs(pitch) > np.radians(PITCH_MAX_DEG):
        return None
    front = np.array([d[0] / h, d[1] / h, 0.0])
    axis = np.cross(d / np.linalg.norm(d), front)
    axis /= np.linalg.norm(axis)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    rot = np.eye(3) + np.sin(abs(pitch)) * k + (1.0 - np.cos(pitch)) * (k @ k)          # Rodrigues
    return rot, porion, pitch


def turned(points, rotation: np.ndarray | None, pivot, back: bool = False) -> np.ndarray:
    """Points (..., 3) turned by ``rotation`` about ``pivot`` (into the frame), or with ``back`` out of it."""
    p = np.array(points, float)
    if rotation is None:
        return p
    r = rotation if back else rotation.T
    return (p - pivot) @ r + pivot


def into_frankfurt_frame(skull: Mesh, landmarks: dict, plane=None) -> tuple[Mesh, dict, tuple | None, tuple | None]:
    """The ``skull``, the ``landmarks`` and the scan's cut ``plane`` ((normal, offset) in the scan's axes, with every
    skull vertex on or above it: :func:`.face_profile.scan_cut_plane`; None) turned into the head's Frankfurt frame
    (:func:`frankfurt_rotation`), and that frame; as given and None where it is not found. The cut is the scan's, so
    it is found in the scan's axes and turned (in the frame GE's cut, 22 degrees off the head's horizontal, was no
    longer the hull's largest downward face)."""
    frame = frankfurt_rotation(landmarks)
    if frame is None:
        return skull, landmarks, plane, None
    rot, pivot, _ = frame
    vertices = turned(skull.vertices, rot, pivot)
    if plane is not None:
        normal = rot @ np.asarray(plane[0], float)
        plane = (normal, float((vertices @ normal).max()))
    return (Mesh(vertices, skull.quads, skull.triangles), {n: turned(p, rot, pivot) for n, p in landmarks.items()},
            plane, frame)


def to_head_frame(points, centre, yaw: float, back: bool = False) -> np.ndarray:
    """Points (..., 3) patient mm turned by ``-yaw`` about the vertical axis through ``centre`` (x, y): into the
    head's frame, where the face looks along -y; with ``back``, from the head's frame to the patient's."""
    p = np.array(points, float)
    if yaw == 0.0:
        return p
    a = yaw if back else -yaw
    ca, sa = np.cos(a), np.sin(a)
    dx, dy = p[..., 0] - centre[0], p[..., 1] - centre[1]
    p[..., 0], p[..., 1] = centre[0] + ca * dx - sa * dy, centre[1] + sa * dx + ca * dy
    return p


def head_grid(grid: FaceGrid, yaw: float) -> FaceGrid:
    """The same columns with their angles in the head's frame: column angle theta (patient) is theta + yaw there."""
    return grid if yaw == 0.0 else FaceGrid(grid.centre, grid.z, grid.theta + yaw)


def landmarks_in_head_frame(landmarks: dict, centre, yaw: float) -> dict:
    return {n: to_head_frame(p, centre, yaw) for n, p in landmarks.items() if p is not None}


class HeadFrameFeatures:
    """The face model's shape rules made in the head's frame (mixed into :class:`.face_from_skull.FaceModel`).

    The model keeps ``frame_rotation`` and ``frame_pivot`` (:func:`frankfurt_rotation` at
    :meth:`~.FaceModel.prepare`: its grid, rule sites and landmarks lie in that frame; a model kept before it has
    none: the scanner's axes), ``face_yaw`` (radians, :func:`head_yaw` in that frame; none: 0) and its ``nose`` and
    ``mouth`` predicted in the frame turned by the yaw."""

    @property
    def yaw(self) -> float:
        return float(self.__dict__.get("face_yaw", 0.0))

    def to_frame(self, points) -> np.ndarray:
        """Patient mm -> the model's frame (the grid's)."""
        return turned(points, self.__dict__.get("frame_rotation"), self.__dict__.get("frame_pivot"))

    def from_frame(self, points) -> np.ndarray:
        """The model's frame -> patient mm."""
        return turned(points, self.__dict__.get("frame_rotation"), self.__dict__.get("frame_pivot"), back=True)

    def keep_frame(self, frame: tuple | None) -> None:
        """Keep the Frankfurt ``frame`` (:func:`frankfurt_rotation`; None: the scanner's axes) the model was made in,
        its peg bases and normals (made in it) handed back in patient mm, the pitch in the provenance."""
        if frame is None:
            return
        rot, pivot, pitch = frame
        self.frame_rotation, self.frame_pivot = rot, pivot
        self.peg_bases = turned(self.peg_bases, rot, pivot, back=True)
        self.peg_normals = self.peg_normals @ rot
        self.provenance["frankfurt_pitch_deg"] = round(float(np.degrees(pitch)), 1)

    def _head(self, points) -> np.ndarray:
        """Patient mm -> the head's frame (the model's, turned by the yaw)."""
        return to_head_frame(self.to_frame(points), self.grid.centre, self.yaw)

    def _patient(self, points) -> np.ndarray:
        """The head's frame -> patient mm (:meth:`_head`'s inverse)."""
        return self.from_frame(to_head_frame(points, self.grid.centre, self.yaw, back=True))

    def _head_landmarks(self) -> dict:
        return landmarks_in_head_frame(getattr(self, "landmarks_used", None) or {}, self.grid.centre, self.yaw)

    def _front(self) -> tuple[slice, FaceGrid]:
        """The columns the nose, the lips and the eyes can touch (``cos < FRONT_COS`` of the angle in the head's
        frame: all three are zero elsewhere) as a slice, and the grid of those columns in the head's frame: the
        features are made there alone (live speed)."""
        if "_front_grid" not in self.__dict__:
            g = self.grid
            j = np.flatnonzero(np.cos(g.theta + self.yaw) < FRONT_COS)
            if j.size and j[-1] - j[0] + 1 == j.size:
                cols = slice(int(j[0]), int(j[-1]) + 1)
            else:                                     # never for theta = 0 behind the head; all columns then
                cols = slice(0, len(g.theta))
            self.__dict__["_front_grid"] = (cols, head_grid(FaceGrid(g.centre, g.z, g.theta[cols]), self.yaw))
        return self.__dict__["_front_grid"]

    def _mouth_shape(self, base: np.ndarray, grid: FaceGrid | None = None) -> np.ndarray | None:
        """The lips over the face ``base`` (:func:`.face_features.mouth_shape`; on ``grid`` in the head's frame,
        default the model's)."""
        return mouth_shape(grid or head_grid(self.grid, self.yaw), self.mouth, base)

    def _eye_shape(self, base: np.ndarray, grid: FaceGrid | None = None) -> np.ndarray | None:
        """The closed eyes over the face ``base`` (:func:`.face_eyes.eye_shape`)."""
        return eye_shape(grid or head_grid(self.grid, self.yaw), self._head_landmarks(), base)

    def _ear_shape(self) -> np.ndarray | None:
        """The default ears at the porions (:func:`.face_features.ear_shape`; one off its ear canal mirrored from the
        other: :func:`ear_porions`). Fixed by the skull: computed once."""
        if "_ears" not in self.__dict__:
            porions, _ = ear_porions(self._head_landmarks())
            self.__dict__["_ears"] = ear_shape(head_grid(self.grid, self.yaw), porions)
        return self.__dict__["_ears"]

    def _peg_tip(self, tips: np.ndarray, *names) -> np.ndarray | None:
        return next((tips[self.peg_names.index(n)] for n in names if n in self.peg_names), None)

    def _nose_bump(self, base: np.ndarray, tips: np.ndarray, grid: FaceGrid | None = None, anchor=None):
        """The nose over the face ``base`` on the current peg ``tips`` (:func:`.face_features.nose_bump`), in the
        head's frame."""
        tips = self._head(tips)
        ss = self.peg_names.index("Subspinale") if "Subspinale" in self.peg_names else None
        lip_from = None if ss is None else straight_ahead(self._head(self.peg_bases[ss]), tips[ss])  # upper_lip's
        return nose_bump(grid or head_grid(self.grid, self.yaw), self.nose, base,
                         lambda *n: self._peg_tip(tips, *n), anchor, lip_from)
