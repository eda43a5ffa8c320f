"""A deterministic synthetic head CT with exact ground truth (the demo data and quick tests).

The head is defined analytically in patient LPS millimetres (+x patient left,
+y posterior, +z superior; the face looks toward -y) by approximate signed
distance functions (negative inside) of ellipsoids, elliptic cylinders, a few
rotated ellipsoids and two flat plates (the ears), combined with smooth unions
and differences. Because it is
a function of position, the same phantom can be sampled on any grid, including
tilted, sheared or unevenly spaced slices (:meth:`Phantom.sample_hu`), and its
truth is known at any point (:meth:`Phantom.inside_head`).

Anatomy (eye line at z = 0, head centred on x = 0):

* skin surface: cranium (vertex at z = +98), forehead with brow ridge, cheeks,
  jaw, chin, a nose whose tip (y = -106, z = -33) stands 22-26 mm in front of
  the cheeks, upper and lower lips (protruding 5-7 mm) with a 2 mm mouth line,
  shallow eye sockets (the skin over the eyes lies 7 mm behind the brow and
  3 mm behind the cheek) holding eyeballs under lids, two ears flaring
  backwards from the sides (they make axial cross-sections non-star-shaped;
  each section of an ear is attached to the head), and a neck cut by the
  bottom of the field of view. Size: 166 mm wide with the ears (150 without),
  206 mm from nose tip to occiput, vertex to chin 190 mm;
* inside: a 7 mm skull shell with a flat base, CSF layer, brain with two
  lateral ventricles, eyes, mandible, cervical vertebrae with discs, and
  internal air (nasal cavity, maxillary and frontal sinuses, pharyngeal airway
  open at the bottom of the field of view, like a real neck);
* outside, touching the head like in real scans: a foam pillow behind the
  head whose foam is compressed (denser, up to about -150 HU) where the head
  rests on it, so a -400 HU threshold picks up a thin layer of it, and a
  4 mm thick curved head-holder shell (+300 HU) around the back and sides
  whose side walls press against the ears.

Imaging model: every tissue interface is blurred by a Gaussian point spread
function of standard deviation ``blur`` mm (partial volume), evaluated
analytically as ``0.5 * erfc(d / (sqrt(2) * blur))`` of the signed distance
``d``, so the blur is identical on any sampling grid. Then independent
Gaussian noise of standard deviation ``noise`` HU is added to every voxel
(white noise; real CT noise is somewhat correlated, this is a simplification).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import erfc

from .ct_volume import CTVolume
from .errors import PDEHeadError

# Tissue labels of :attr:`Phantom.labels` (uint8).
AIR = 0            # outside air
SOFT_TISSUE = 1    # skin, fat, muscle, cartilage (nose, ears, lips)
BONE = 2           # skull, mandible, vertebrae
BRAIN = 3
CSF = 4            # CSF layer under the skull, ventricles, intervertebral discs (soft, ~CSF/disc HU)
EYE = 5            # vitreous body
INTERNAL_AIR = 6   # nasal cavity, sinuses, airway (inside the head mask)
CUSHION = 7        # foam pillow (not head)
HOLDER = 8         # plastic head-holder shell (not head)
METAL = 9          # dental fillings (``make_phantom(metal=True)``; inside the head)

LABEL_NAMES: dict[int, str] = {
    AIR: "air (outside)", SOFT_TISSUE: "soft tissue / skin", BONE: "bone", BRAIN: "brain",
    CSF: "CSF / discs", EYE: "eye (vitreous)", INTERNAL_AIR: "internal air (sinuses, airway)",
    CUSHION: "foam pillow", HOLDER: "head holder", METAL: "metal (dental fillings)",
}

#: Default tissue values in HU (the cushion value is the uncompressed foam).
DEFAULT_HU: dict[str, float] = {
    "air": -1000.0, "soft_tissue": 40.0, "skull": 1100.0, "mandible": 1300.0, "vertebra": 750.0,
    "brain": 32.0, "csf": 8.0, "disc": 80.0, "eye": 12.0, "internal_air": -1000.0,
    "cushion": -900.0, "cushion_compressed": -150.0, "holder": 300.0,
    "metal": 3071.0,      # amalgam saturates the 12-bit CT range
    "streak": 2500.0,     # peak HU of a metal streak 10 mm from a filling (decays as 10 mm / r)
}

#: Field of view (z, y, x) in mm covered by the default grid for any shape.
DEFAULT_FOV_MM = (230.0, 256.0, 256.0)
DEFAULT_SHAPE = (100, 128, 128)
_TOP_Z = 110.0          # patient z of the centre of the top slice (vertex at +98)
_CENTRE_Y = 4.0         # patient y of the grid centre (nose tip -106, holder back +122)
_CHUNK_VOXELS = 1 << 20  # evaluate the grid in slabs of about this many voxels (bounded memory)


class _ParameterError(PDEHeadError, ValueError):
    """A phantom parameter is out of range (catchable as PDEHeadError or ValueError)."""


# --------------------------------------------------------------------------------------------
# Signed-distance building blocks (mm, negative inside), evaluated on flat point sets.
# Every primitive only touches the points in its bounding box (grown by the blend width);
# elsewhere it is "far" and leaves the field exactly unchanged, which is what makes the
# default grid fast. Grid and arbitrary points go through the same code, so the truth at
# voxel centres is bit-identical to :meth:`Phantom.inside_head` there.
# --------------------------------------------------------------------------------------------
_EMPTY = "empty"  # selection of no point


class _Points:
    """Flat patient LPS coordinates (mm) of arbitrary points; fields are 1-D arrays."""

    __slots__ = ("x", "y", "z", "ax")

    def __init__(self, x: np.ndarray, y: np.ndarray, z: np.ndarray):
        self.x, self.y, self.z = x, y, z
        self.ax = np.abs(x)

    @property
    def shape(self) -> tuple[int, ...]:
        return self.x.shape

    def take(self, selection) -> "_Points":
        return self if selection is None else _Points(self.x[selection], self.y[selection], self.z[selection])

    def select(self, box: tuple[np.ndarray, np.ndarray, bool]):
        """Indices of the points inside ``box = (lo, hi, mirror)`` (None: all, ``_EMPTY``: none)."""
        lo, hi, mirror = box
        x = self.ax if mirror else self.x
        inside = (x >= lo[0]) & (x <= hi[0]) & (self.y >= lo[1]) & (self.y <= hi[1])
        inside &= (self.z >= lo[2]) & (self.z <= hi[2])
        if inside.all():
            return None
        return np.flatnonzero(inside) if inside.any() else _EMPTY


class _Grid:
    """The points of a rectilinear grid given by its axes; fields are ``(nz, ny, nx)`` arrays.

    Coordinates are broadcast views, so per-axis terms cost 1-D work, and a box
    selection is a sub-grid (slices, or an index array along x for mirrored
    boxes). The box test is the same predicate as :meth:`_Points.select` on the
    same coordinates, and all arithmetic is element-wise, so a grid and a flat
    list of its points give bit-identical fields.
    """

    __slots__ = ("xs", "ys", "zs", "x", "y", "z", "ax")

    def __init__(self, xs: np.ndarray, ys: np.ndarray, zs: np.ndarray):
        self.xs, self.ys, self.zs = xs, ys, zs
        self.x, self.y, self.z = xs[None, None, :], ys[None, :, None], zs[:, None, None]
        self.ax = np.abs(self.x)

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.zs.size, self.ys.size, self.xs.size)

    def take(self, selection) -> "_Grid":
        if selection is None:
            return self
        kz, jy, ix = selection
        return _Grid(self.xs[ix], self.ys[jy], self.zs[kz])

    def select(self, box: tuple[np.ndarray, np.ndarray, bool]):
        lo, hi, mirror = box
        parts = []
        for values, low, high in ((self.zs, lo[2], hi[2]), (self.ys, lo[1], hi[1]),
                                  (np.abs(self.xs) if mirror else self.xs, lo[0], hi[0])):
            index = np.flatnonzero((values >= low) & (values <= high))
            if index.size == 0:
                return _EMPTY
            if index.size == values.size:
                parts.append(slice(None))
            elif index[-1] - index[0] + 1 == index.size:  # contiguous: a view
                parts.append(slice(int(index[0]), int(index[-1]) + 1))
            else:  # |x| in [lo, hi] on both sides of x = 0 (only x can be split)
                parts.append(index)
        if all(isinstance(part, slice) and part == slice(None) for part in parts):
            return None
        return tuple(parts)


def _ellipsoid_sd(u, v, w, r):
    """Approximate signed distance to the ellipsoid u^2/a^2 + v^2/b^2 + w^2/c^2 = 1.

    ``(k0 - 1) k0 / k1`` with k0 = |p/r|, k1 = |p/r^2| (Quilez): exact zero set,
    a good distance estimate near the surface, correct sign everywhere.
    """
    pu, pv, pw = u / r[0], v / r[1], w / r[2]
    k0 = np.sqrt(pu * pu + pv * pv + pw * pw)
    k1 = np.sqrt(pu * pu / (r[0] * r[0]) + pv * pv / (r[1] * r[1]) + pw * pw / (r[2] * r[2]))
    radius = np.divide(k0, k1, out=np.full(k0.shape, float(min(r))), where=k1 > 0)
    return (k0 - 1.0) * radius


def _ellipse_sd(u, v, r):
    """2-D version of :func:`_ellipsoid_sd` (an infinite elliptic cylinder)."""
    pu, pv = u / r[0], v / r[1]
    k0 = np.sqrt(pu * pu + pv * pv)
    k1 = np.sqrt(pu * pu / (r[0] * r[0]) + pv * pv / (r[1] * r[1]))
    radius = np.divide(k0, k1, out=np.full(k0.shape, float(min(r))), where=k1 > 0)
    return (k0 - 1.0) * radius


def _smin(a, b, k):
    """Smooth union (polynomial smooth minimum, blend width k mm); exactly min(a, b) if |a-b| >= k."""
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - 0.25 * k * h * h


def _smax(a, b, k):
    """Smooth intersection; ``_smax(a, -b, k)`` is the smooth difference a minus b."""
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.maximum(a, b) + 0.25 * k * h * h


def _rotation_ear(flare_deg: float, roll_deg: float) -> np.ndarray:
    """Rows: local axes (u, v, w) of the left ear plate: w (the front edge) tilted by ``roll_deg``
    about y so the top leans outwards, then v (backwards) turned by ``flare_deg`` towards +x."""
    cf, sf = math.cos(math.radians(flare_deg)), math.sin(math.radians(flare_deg))
    cr, sr = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
    return np.array([[cr * cf, -cr * sf, -sr], [sf, cf, 0.0], [sr * cf, -sr * sf, cr]])


def _rotation_about_x(angle_deg: float) -> np.ndarray:
    """Rows: local axes (u, v, w) rotated by ``angle_deg`` about +x (u = x)."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


class _Ellipsoid:
    """Ellipsoid, optionally rotated (semi-axes along the rows of ``axes``), mirrored in x
    (``|x|``) and cut in half (``half``: only the part with local v >= 0)."""

    def __init__(self, centre, radii, *, mirror: bool = False, axes: np.ndarray | None = None,
                 half: bool = False):
        self.centre, self.radii = np.asarray(centre, float), tuple(float(r) for r in radii)
        self.mirror, self.axes, self.half = mirror, axes, half

    def sd(self, p) -> np.ndarray:
        dx = (p.ax if self.mirror else p.x) - self.centre[0]
        dy, dz = p.y - self.centre[1], p.z - self.centre[2]
        if self.axes is not None:
            a = self.axes
            dx, dy, dz = (a[0, 0] * dx + a[0, 1] * dy + a[0, 2] * dz,
                          a[1, 0] * dx + a[1, 1] * dy + a[1, 2] * dz,
                          a[2, 0] * dx + a[2, 1] * dy + a[2, 2] * dz)
        d = _ellipsoid_sd(dx, dy, dz, self.radii)
        return np.maximum(d, -dy) if self.half else d  # half: keep local v >= 0 only

    def box(self, margin: float):
        reach = np.full(3, max(self.radii)) if self.axes is not None else np.asarray(self.radii)
        return self.centre - reach - margin, self.centre + reach + margin, self.mirror


class _Plate(_Ellipsoid):
    """Flat elliptic plate of uniform thickness ``2 * radii[0]`` (edges rounded by 1.5 mm):
    an ellipse of semi-axes ``radii[1:]`` in the local (v, w) plane. Unlike a thin ellipsoid
    its rim does not taper, so any sampling finer than its thickness keeps it connected."""

    def sd(self, p) -> np.ndarray:
        dx = (p.ax if self.mirror else p.x) - self.centre[0]
        dy, dz = p.y - self.centre[1], p.z - self.centre[2]
        if self.axes is not None:
            a = self.axes
            dx, dy, dz = (a[0, 0] * dx + a[0, 1] * dy + a[0, 2] * dz,
                          a[1, 0] * dx + a[1, 1] * dy + a[1, 2] * dz,
                          a[2, 0] * dx + a[2, 1] * dy + a[2, 2] * dz)
        d = _smax(_ellipse_sd(dy, dz, self.radii[1:]), np.abs(dx) - self.radii[0], 1.5)
        return np.maximum(d, -dy) if self.half else d


class _Cylinder:
    """Elliptic cylinder along z between ``bottom`` and ``top`` (hard caps)."""

    def __init__(self, centre_xy, radii_xy, *, top: float = math.inf, bottom: float = -math.inf):
        self.centre, self.radii = np.asarray(centre_xy, float), tuple(float(r) for r in radii_xy)
        self.top, self.bottom = float(top), float(bottom)

    def sd(self, p) -> np.ndarray:
        d = _ellipse_sd(p.x - self.centre[0], p.y - self.centre[1], self.radii)
        if math.isfinite(self.top):
            d = np.maximum(d, p.z - self.top)
        if math.isfinite(self.bottom):
            d = np.maximum(d, self.bottom - p.z)
        return d

    def box(self, margin: float):
        lo = np.array([*(self.centre - self.radii - margin), self.bottom - margin])
        hi = np.array([*(self.centre + self.radii + margin), self.top + margin])
        return lo, hi, False


class _SmoothUnion:
    """Smooth union of primitives: ``first`` then ``(primitive, blend)`` pairs."""

    def __init__(self, first, *rest):
        self.first, self.rest = first, rest

    def sd(self, p) -> np.ndarray:
        d = self.first.sd(p)
        for prim, k in self.rest:
            d = _smin(d, prim.sd(p), k)
        return d

    def box(self, margin: float):
        boxes = [self.first.box(margin)] + [prim.box(margin + k) for prim, k in self.rest]
        if len({b[2] for b in boxes}) != 1:
            raise ValueError("a smooth union must not mix mirrored and plain primitives")
        return (np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0), boxes[0][2])


def _blend(field: np.ndarray, p, prim, k: float, carve: bool = False) -> None:
    """In place: smooth union (or smooth difference if ``carve``) of ``prim`` into ``field``.

    Only points within ``2k + 6`` mm of the primitive's bounding box are touched:
    beyond it the primitive is farther than the blend width from any surface of
    ``field`` that matters (the sign and the near field are unchanged).
    """
    selection = p.select(prim.box(2.0 * k + 6.0))
    if selection is _EMPTY:
        return
    d = prim.sd(p.take(selection))
    old = field if selection is None else field[selection]
    new = _smax(old, -d, k) if carve else _smin(old, d, k)
    if selection is None:
        field[...] = new
    else:
        field[selection] = new


# --------------------------------------------------------------------------------------------
# The analytic head. Geometry in mm (patient LPS, eye line at z = 0); mirrored parts use |x|.
# --------------------------------------------------------------------------------------------
GEOMETRY: dict[str, Any] = {
    # skin body: (centre, radii) of ellipsoids unless noted
    "cranium": ((0.0, 8.0, 22.0), (74.0, 95.0, 76.0)),
    "face": ((0.0, -22.0, -30.0), (60.0, 62.0, 60.0)),
    "cheek": ((38.0, -50.0, -18.0), (22.0, 24.0, 22.0)),
    "brow": ((0.0, -62.0, 12.0), (54.0, 24.0, 13.0)),
    "muzzle": ((0.0, -52.0, -50.0), (32.0, 31.0, 24.0)),
    "jaw": ((0.0, -16.0, -60.0), (54.0, 58.0, 30.0)),
    "chin": ((0.0, -66.0, -78.0), (19.0, 13.0, 13.0)),
    "under_chin": ((0.0, -40.0, -78.0), (36.0, 34.0, 13.0)),
    "neck": ((0.0, 20.0), (50.0, 54.0), 0.0),                        # centre xy, radii xy, top z
    "nose_bridge": ((0.0, -83.0, -17.0), (7.5, 8.5, 23.0), 28.0),   # + backward lean of the top (deg)
    "nose_tip": ((0.0, -97.5, -33.0), (8.0, 8.5, 7.0)),
    "nose_ala": ((11.0, -86.5, -34.0), (7.0, 7.0, 6.0)),
    "columella": ((0.0, -91.0, -37.0), (5.0, 9.0, 4.5)),
    "upper_lip": ((0.0, -80.0, -50.0), (19.0, 5.5, 4.5)),
    "lower_lip": ((0.0, -78.5, -61.0), (17.0, 5.5, 5.0)),
    "mouth_line": ((0.0, -90.0, -55.5), (22.0, 11.0, 1.6)),        # carved
    "eye_socket": ((32.0, -86.0, 1.0), (16.0, 13.0, 11.0)),        # carved
    "eyeball": ((32.0, -62.0, 0.0), (12.0, 12.0, 12.0)),
    # ear: a D-shaped plate (half an elliptic plate) whose straight front edge runs through
    # the centre, 3-6 mm under the skin over the whole ear height (leaning out by the roll angle
    # like the side of the head), so every axial section of the ear is attached to the head.
    # radii (half-thickness, depth backwards, half-height); flare (deg) of the back edge; roll (deg)
    "ear": ((63.5, 0.0, -6.0), (3.5, 30.0, 24.0), 38.0, 15.0),
    # inside
    "skull_outer": ((0.0, 8.0, 22.0), (68.0, 89.0, 70.0)),
    "skull_inner": ((0.0, 8.0, 22.0), (61.0, 82.0, 63.0)),
    "skull_base_z": -26.0, "brain_floor_z": -19.0, "csf_layer": 1.5,
    "ventricle": ((10.0, 14.0, 34.0), (6.0, 24.0, 10.0)),
    # mandible: U-shaped bar = ring around (centre xy, radii xy) of half-thickness, at z centre with
    # half-height, cut at y max (the body; the chin, rami and lower teeth are in "facial_skeleton")
    "mandible": ((0.0, -10.0), (45.0, 55.0), 4.5, -79.0, 8.5, 6.0),
    # facial skeleton (issue 22): what automatic craniometric landmarks need, every part a primitive
    # so that the landmarks have analytic positions (:meth:`Phantom.bone_landmarks`). Mirrored in x.
    "facial_skeleton": {
        # orbit openings: elliptic cylinders along y, centre (x, z), radii (x, z), through the bone
        "orbit": ((32.0, 0.0), (18.0, 14.0)),
        # nasal aperture: elliptic cylinder along y on the midline, centre z, radii (x, z), y in front of
        "aperture": (-28.0, (12.0, 11.0), -45.0),
        # external acoustic meatus: cylinder along x, centre (y, z), radius, from |x| outwards; in a
        # petrous block (ellipsoid centre, radii) so that the canal is blind, as in bone
        "meatus": ((4.0, -18.0), 4.0, 44.0),
        "petrous": ((46.0, 4.0, -18.0), (9.0, 10.0, 8.0)),
        # temporal fossa carved from the cranium behind the zygomatic arch (ellipsoid)
        "temporal_fossa": ((66.0, -18.0, -4.0), (12.0, 20.0, 16.0)),
        # zygomatic arch: a ring (centre xy, radii xy) of half-thickness, z centre, half-height, y range
        "zygomatic_arch": ((0.0, -20.0), (59.0, 40.0), 2.0, -10.0, 4.0, (-45.0, 2.0)),
        # maxilla and zygomatic bodies: an ellipsoid block in front of the cranium, cut behind y max
        "face_block": ((0.0, -22.0, -18.0), (56.0, 50.0, 38.0), -20.0),
        # supraorbital ridges (brow): ellipsoid
        "brow_ridge": ((0.0, -72.0, 12.0), (42.0, 10.5, 7.0)),
        # nasal bones: a thin rotated ellipsoid from nasion's notch to rhinion (end points, radii x / thickness)
        "nasal_bones": ((0.0, -75.0, -2.0), (0.0, -84.0, -20.0), 4.0, 2.5),
        # anterior nasal spine: ellipsoid at the bottom of the aperture
        "nasal_spine": ((0.0, -76.0, -39.5), (3.0, 5.0, 2.0)),
        # dental arches (rings about the mandible's centre): upper alveolar process and upper teeth,
        # lower teeth on the mandible; (radii xy, half-thickness, z bottom, z top). The mouth is open
        # 6.5 mm between the incisal edges so that skull and mandible stay separate objects.
        "upper_alveolus": ((42.0, 58.0), 5.0, -44.0, -30.0),
        "upper_teeth": ((42.0, 58.0), 3.0, -54.5, -44.0),
        "lower_teeth": ((40.0, 56.0), 3.0, -70.5, -61.0),
        # chin (mental eminence): ellipsoid on the symphysis
        "chin": ((0.0, -68.0, -81.0), (9.0, 5.0, 6.0)),
        # rami: elliptic cylinders along z, centre xy, radii xy, z bottom, z top (below the skull base)
        "ramus": ((40.0, -4.0), (3.5, 10.0), -87.5, -34.0),
    },
    # cervical spine: centre xy, radii xy, top z, vertebra period, disc half-height
    "spine": ((0.0, 26.0), (11.0, 10.0), -34.0, 16.0, 2.0),
    "nasal_cavity": ((0.0, -70.0, -20.0), (10.0, 16.0, 16.0)),
    "maxillary_sinus": ((26.0, -56.0, -24.0), (12.0, 13.0, 13.0)),
    "frontal_sinus": ((0.0, -80.0, 28.0), (14.0, 4.0, 8.0)),
    "airway": ((0.0, -2.0), (8.0, 6.0), -42.0),                      # centre xy, radii xy, top z
    # apparatus. holder: centre xy, mid-wall radii xy, half-thickness, y min, z max
    "holder": ((0.0, 8.0), (80.0, 112.0), 2.0, -22.0, 30.0),
    "cushion": (58.0, 24.0, 8.0),  # y min, z max, compression decay length (mm)
    # metal (make_phantom(metal=True)): dental fillings = small ellipsoids (centre, radii) in the
    # teeth rows behind the lips, mirrored in x
    "fillings": (((14.0, -66.0, -52.0), (3.5, 3.0, 3.5)), ((20.0, -60.0, -59.0), (3.0, 3.0, 3.5))),
    # streaks: rays from every filling in the axial planes through it, alternately bright and dark:
    # (number of rays per filling, perpendicular sigma mm, sigma mm of the fall-off above and below
    #  the filling, reach mm (amplitude fades to 0 there), random seed of the ray angles)
    "streaks": (14, 1.0, 0.5, 90.0, 11),
}


def _build_shapes(g: dict[str, Any]) -> dict[str, Any]:
    """Primitive objects for the geometry table."""
    e = _Ellipsoid
    bc, br, lean = g["nose_bridge"]
    ec, er, flare, roll = g["ear"]
    (ncx, ncy), nr, ntop = g["neck"]
    (acx, acy), ar, atop = g["airway"]
    return {
        "cranium": e(*g["cranium"]),
        # (operation, primitive, blend width mm) applied in this order to the cranium
        "head_parts": [
            ("union", e(*g["face"]), 14.0),
            ("union", e(*g["cheek"], mirror=True), 14.0),
            ("union", e(*g["brow"]), 10.0),
            ("union", e(*g["muzzle"]), 10.0),
            ("union", e(*g["jaw"]), 12.0),
            ("union", e(*g["chin"]), 8.0),
            ("union", e(*g["under_chin"]), 10.0),
            ("union", _Cylinder((ncx, ncy), nr, top=ntop), 20.0),
            ("union", _SmoothUnion(e(bc, br, axes=_rotation_about_x(-lean)),
                                   (e(*g["nose_tip"]), 5.0), (e(*g["columella"]), 3.0)), 5.0),
            ("union", e(*g["nose_ala"], mirror=True), 4.0),
            ("union", e(*g["upper_lip"]), 4.0),
            ("union", e(*g["lower_lip"]), 4.0),
            ("union", _Plate(ec, er, mirror=True, axes=_rotation_ear(flare, roll), half=True), 4.0),
            ("carve", e(*g["eye_socket"], mirror=True), 4.0),
            ("union", e(*g["eyeball"], mirror=True), 2.0),
            ("carve", e(*g["mouth_line"]), 1.0),
        ],
        "skull_outer": e(*g["skull_outer"]),
        "skull_inner": e(*g["skull_inner"]),
        "ventricle": e(*g["ventricle"], mirror=True),
        "eyeball": e(*g["eyeball"], mirror=True),
        "internal_air": [_Cylinder((acx, acy), ar, top=atop), e(*g["nasal_cavity"]),
                         e(*g["maxillary_sinus"], mirror=True), e(*g["frontal_sinus"])],
        "fillings": [e(c, r, mirror=True) for c, r in g["fillings"]],
    }


_SHAPES = _build_shapes(GEOMETRY)


def _head_sd(p) -> np.ndarray:
    """Signed distance (approx., mm; exact zero set) of the head: skin and all inside it."""
    d = np.broadcast_to(_SHAPES["cranium"].sd(p), p.shape).copy()
    for operation, prim, k in _SHAPES["head_parts"]:
        _blend(d, p, prim, k, carve=operation == "carve")
    return d


def _box(lo, hi):
    return np.asarray(lo, float), np.asarray(hi, float), False


def _layers(p, head: np.ndarray, hu: dict[str, float]):
    """Painter's list of ``(label, HU, selection, signed distance)``; later layers overwrite.

    ``selection`` picks the points the layer may occupy (None: all; see
    ``_Points.select`` / ``_Grid.select``); the signed distance and the HU (scalar
    or array) are given on those points only.
    """
    g, s = GEOMETRY, _SHAPES
    layers = []

    def add(label, value, box, sd_fn, head_margin=None):
        selection = p.select(box) if box is not None else None
        if selection is _EMPTY:
            return
        q = p.take(selection)
        h = head if selection is None else head[selection]
        sd = np.broadcast_to(sd_fn(q), h.shape)
        if head_margin is not None:  # keep inner tissue at least head_margin mm under the skin
            sd = np.maximum(sd, h + head_margin)
        value = value(q, h) if callable(value) else value
        layers.append((label, value, selection, sd))

    # apparatus first: the head is painted over it, so it touches the head but never overlaps
    (hcx, hcy), hr, hhalf, hymin, hzmax = g["holder"]
    inner_r = (hr[0] - hhalf, hr[1] - hhalf)
    cymin, czmax, decay = g["cushion"]

    def holder_sd(q):  # elliptic shell of the cradle, open at the front and the top
        shell = np.abs(_ellipse_sd(q.x - hcx, q.y - hcy, hr)) - hhalf
        return np.maximum(np.maximum(shell, hymin - q.y), q.z - hzmax)

    def cushion_sd(q):  # fills the cradle behind the head, up to z = czmax
        return _smax(np.maximum(_ellipse_sd(q.x - hcx, q.y - hcy, inner_r), cymin - q.y), q.z - czmax, 6.0)

    def cushion_hu(q, h):  # foam compressed (denser) where the head rests on it
        compression = np.exp(-np.maximum(h, 0.0) / decay)
        return hu["cushion"] + (hu["cushion_compressed"] - hu["cushion"]) * compression

    reach = (hr[0] + hhalf + 8.0, hr[1] + hhalf + 8.0)
    add(HOLDER, hu["holder"],
        _box([hcx - reach[0], hymin - 8, -np.inf], [hcx + reach[0], hcy + reach[1], hzmax + 8]), holder_sd)
    add(CUSHION, cushion_hu,
        _box([hcx - inner_r[0] - 8, cymin - 8, -np.inf], [hcx + inner_r[0] + 8, hcy + inner_r[1] + 8, czmax + 8]),
        cushion_sd)
    layers.append((SOFT_TISSUE, hu["soft_tissue"], None, head))

    # skull: shell between the outer and inner ellipsoids, closed by a flat base
    def cavity_sd(q):
        return _smax(s["skull_inner"].sd(q), g["brain_floor_z"] - q.z, 3.0)

    fc, fr_ = g["facial_skeleton"]["temporal_fossa"]

    def skull_sd(q):
        shell = np.maximum(_smax(s["skull_outer"].sd(q), g["skull_base_z"] - q.z, 3.0), -cavity_sd(q))
        return np.maximum(shell, -_ellipsoid_sd(q.ax - fc[0], q.y - fc[1], q.z - fc[2], fr_))

    def brain_sd(q):
        return cavity_sd(q) + g["csf_layer"]

    add(BONE, hu["skull"], s["skull_outer"].box(8.0), lambda q: _face_carves(q, skull_sd(q)), 2.0)
    add(CSF, hu["csf"], s["skull_inner"].box(8.0), cavity_sd, 3.0)
    add(BRAIN, hu["brain"], s["skull_inner"].box(8.0), brain_sd, 3.0 + g["csf_layer"])
    add(CSF, hu["csf"], s["ventricle"].box(8.0), s["ventricle"].sd, 3.0)
    add(EYE, hu["eye"], s["eyeball"].box(8.0), s["eyeball"].sd, 1.0)  # 1 mm lid in front

    add(BONE, hu["mandible"], _FACE_BOX, _mandible_sd, 3.0)
    (scx, scy), sr, stop, period, disc_half = g["spine"]
    column = _Cylinder((scx, scy), sr, top=stop)

    def disc_sd(q):  # every ``period`` mm a disc of 2 * disc_half mm between vertebral bodies
        return np.maximum(column.sd(q), disc_half - np.abs(np.mod(q.z - stop, period) - period / 2))

    add(BONE, hu["vertebra"], column.box(8.0), column.sd, 3.0)
    add(CSF, hu["disc"], column.box(8.0), disc_sd, 3.0)
    for cavity in s["internal_air"]:
        add(INTERNAL_AIR, hu["internal_air"], cavity.box(8.0), cavity.sd, 4.0)
    # the facial skeleton is painted after the air: it walls the maxillary sinuses in (they would open
    # through the front of the maxilla) and the nasal bones and spine stand over the nasal cavity
    add(BONE, hu["mandible"], _FACE_BOX, _upper_face_sd, 2.0)
    add(BONE, hu["mandible"], _FACE_BOX, _nasal_sd, 2.0)
    add(BONE, hu["mandible"], _FACE_BOX, _upper_teeth_sd, 2.0)
    return layers


# --------------------------------------------------------------------------------------------
# The facial skeleton (GEOMETRY["facial_skeleton"]): signed distances of plain numpy expressions.
# --------------------------------------------------------------------------------------------
FACE_WALL_MM = 6.0   # wall of the maxillo-zygomatic shell
_FACE_BOX = (np.array([-80.0, -110.0, -100.0]), np.array([80.0, 40.0, 40.0]), False)


def _ring_sd(q, centre, radii, half, zlo, zhi):
    """A slab (z in [zlo, zhi]) of an elliptic ring about ``centre`` (xy) of half-thickness ``half``."""
    ring = np.abs(_ellipse_sd(q.x - centre[0], q.y - centre[1], radii)) - half
    return np.maximum(ring, np.abs(q.z - 0.5 * (zlo + zhi)) - 0.5 * (zhi - zlo))


def _face_carves(q, d):
    """Bone ``d`` with the orbits, the nasal aperture, the meatus and the temporal fossae carved out."""
    f = GEOMETRY["facial_skeleton"]
    (ox, oz), orad = f["orbit"]
    orbit = np.maximum(_ellipse_sd(q.ax - ox, q.z - oz, orad), q.y + 40.0)          # open from y = -40 forward
    az, arad, ay = f["aperture"]
    aperture = np.maximum(_ellipse_sd(q.x, q.z - az, arad), q.y - ay)
    (my, mz), mrad, mx = f["meatus"]
    meatus = np.maximum(np.hypot(q.y - my, q.z - mz) - mrad, mx - q.ax)
    hole = np.minimum(np.minimum(orbit, aperture), meatus)
    return np.maximum(d, -hole)


def _upper_face_sd(q):
    """Face block, brow, zygomatic arches, petrous blocks, upper alveolus and teeth, carved."""
    f = GEOMETRY["facial_skeleton"]
    c, r, ymax = f["face_block"]
    outer = _ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], r)
    inner = _ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], tuple(v - FACE_WALL_MM for v in r))
    block = np.maximum(np.maximum(outer, -inner), q.y - ymax)                        # a shell, open behind
    c, r = f["brow_ridge"]
    brow = _ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], r)
    c, r, half, zc, hh, (ylo, yhi) = f["zygomatic_arch"]
    arch = np.maximum(_ring_sd(q, c, r, half, zc - hh, zc + hh), np.maximum(ylo - q.y, q.y - yhi))
    arch = np.maximum(arch, 40.0 - q.ax)                                             # the lateral parts only
    c, r = f["petrous"]
    petrous = _ellipsoid_sd(q.ax - c[0], q.y - c[1], q.z - c[2], r)
    mc = GEOMETRY["mandible"][0]
    r, half, zlo, zhi = f["upper_alveolus"]
    alveolus = np.maximum(_ring_sd(q, mc, r, half, zlo, zhi), q.y + 15.0)
    d = np.minimum.reduce([block, brow, arch, petrous, alveolus])
    # the nasal cavity as it is, the maxillary sinuses 3 mm smaller (a bony wall in front of them)
    c, r = GEOMETRY["nasal_cavity"]
    d = np.maximum(d, -_ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], r))
    c, r = GEOMETRY["maxillary_sinus"]
    d = np.maximum(d, -_ellipsoid_sd(q.ax - c[0], q.y - c[1], q.z - c[2], tuple(v - 3.0 for v in r)))
    return _face_carves(q, d)


def _upper_teeth_sd(q):
    """Upper teeth: a ring under the upper alveolus (denser than the skull, painted with the mandible's HU)."""
    r, half, zlo, zhi = GEOMETRY["facial_skeleton"]["upper_teeth"]
    return np.maximum(_ring_sd(q, GEOMETRY["mandible"][0], r, half, zlo, zhi), q.y + 15.0)


def _nasal_sd(q):
    """Nasal bones (a thin ellipsoid between their end points) and the anterior nasal spine."""
    f = GEOMETRY["facial_skeleton"]
    a, b, rx, rt = f["nasal_bones"]
    a, b = np.asarray(a, float), np.asarray(b, float)
    axis = (b - a) / np.linalg.norm(b - a)
    half = 0.5 * np.linalg.norm(b - a)
    m = 0.5 * (a + b)
    u = (q.y - m[1]) * axis[1] + (q.z - m[2]) * axis[2]            # along the bones (in the yz plane)
    w = (q.y - m[1]) * -axis[2] + (q.z - m[2]) * axis[1]           # across (thickness)
    nasal = _ellipsoid_sd(q.x - m[0], u, w, (rx, half, rt))
    c, r = f["nasal_spine"]
    spine = _ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], r)
    return np.minimum(nasal, spine)


def _mandible_sd(q):
    """Mandible: the U-shaped body, the chin, the rami and the lower teeth."""
    g, f = GEOMETRY, GEOMETRY["facial_skeleton"]
    mc, mr, mhalf, mz, mhh, mymax = g["mandible"]
    body = np.maximum(_ring_sd(q, mc, mr, mhalf, mz - mhh, mz + mhh), q.y - mymax)
    c, r = f["chin"]
    chin = _ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], r)
    (rx, ry), rr, zlo, zhi = f["ramus"]
    ramus = np.maximum(_ellipse_sd(q.ax - rx, q.y - ry, rr), np.abs(q.z - 0.5 * (zlo + zhi)) - 0.5 * (zhi - zlo))
    r, half, zlo, zhi = f["lower_teeth"]
    teeth = np.maximum(_ring_sd(q, mc, r, half, zlo, zhi), q.y + 15.0)
    return np.minimum.reduce([body, chin, ramus, teeth])


def _skull_outer_sd(p, head: np.ndarray) -> np.ndarray:
    """Signed distance (approx., mm; exact zero set) of the skull's OUTER surface (the filled skull).

    The outer ellipsoid cut by the flat base, as painted by :func:`_layers` (which also
    keeps the bone at least 2 mm under the skin; that clamp is applied here too).
    """
    g, s = GEOMETRY, _SHAPES
    d = _smax(s["skull_outer"].sd(p), g["skull_base_z"] - p.z, 3.0)
    return np.maximum(d, head + 2.0)


def _analytic_tissue_depth(points: np.ndarray, max_depth: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Skin points (projected onto the exact skin), inward normals and the depth to the skull along them."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3).copy()
    h = 1e-3

    def sd_and_grad(q):
        base = _head_sd(_Points(q[:, 0], q[:, 1], q[:, 2]))
        grad = np.empty_like(q)
        for a in range(3):
            e = np.zeros(3)
            e[a] = h
            hi, lo = q + e, q - e
            grad[:, a] = (_head_sd(_Points(hi[:, 0], hi[:, 1], hi[:, 2]))
                          - _head_sd(_Points(lo[:, 0], lo[:, 1], lo[:, 2]))) / (2 * h)
        return base, grad

    for _ in range(3):  # Newton steps onto the zero set of the skin
        d, grad = sd_and_grad(pts)
        pts -= (d / np.maximum(np.einsum("ij,ij->i", grad, grad), 1e-12))[:, None] * grad
    _, grad = sd_and_grad(pts)
    inward = -grad / np.linalg.norm(grad, axis=1, keepdims=True)

    def skull_sd(t):
        q = pts + t[:, None] * inward
        qp = _Points(q[:, 0], q[:, 1], q[:, 2])
        return _skull_outer_sd(qp, _head_sd(qp))

    n = len(pts)
    depth = np.full(n, np.nan)
    prev_t = np.zeros(n)
    prev = skull_sd(prev_t)
    open_ = prev > 0
    for t in np.arange(step, max_depth + step / 2, step):
        tt = np.full(n, t)
        cur = skull_sd(tt)
        hit = open_ & (cur <= 0)
        if hit.any():  # bisection between the last outside and the first inside sample
            lo, hi = np.full(hit.sum(), t - step), np.full(hit.sum(), t)
            sub = pts[hit], inward[hit]
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                q = sub[0] + mid[:, None] * sub[1]
                qp = _Points(q[:, 0], q[:, 1], q[:, 2])
                inside = _skull_outer_sd(qp, _head_sd(qp)) <= 0
                hi = np.where(inside, mid, hi)
                lo = np.where(inside, lo, mid)
            depth[hit] = 0.5 * (lo + hi)
            open_ &= ~hit
        if not open_.any():
            break
    return pts, inward, depth


def _streak_rays() -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(centre (3,), unit in-plane directions (n, 2), sign per ray) of the streaks of every filling."""
    count, _, _, _, seed = GEOMETRY["streaks"]
    rng = np.random.default_rng(seed)
    rays = []
    for centre, _ in GEOMETRY["fillings"]:
        for side in (1.0, -1.0):                                  # the filling and its mirror image
            c = np.array([side * centre[0], centre[1], centre[2]])
            angles = np.sort(rng.uniform(0.0, 2.0 * math.pi, count))
            signs = np.where(np.arange(count) % 2 == 0, 1.0, -0.6)  # bright, and weaker dark ones
            rays.append((c, np.stack([np.cos(angles), np.sin(angles)], axis=1), signs))
    return rays


_STREAK_RAYS = _streak_rays()


def _streaks(p, amplitude: float) -> np.ndarray | None:
    """Metal streak artefact (HU added) at points ``p``: rays from each filling in its axial plane.

    A ray adds ``amplitude * sign * (10 mm / max(r, 10 mm)) * fade(r)`` times a Gaussian of the
    perpendicular distance to the ray (sigma ``width``) and a height profile that is 1 across
    the filling's height and falls off above and below it like an edge blurred by
    ``thickness`` (streaks appear in the slices that cut the metal); ``fade`` goes linearly to
    0 at ``reach``. Streaks are an artefact: they change the HU only, never the truth labels
    or the head mask.
    """
    _, width, thickness, reach, _ = GEOMETRY["streaks"]
    half = {c[2]: r[2] for c, r in GEOMETRY["fillings"]}
    lo = min(c[2] - half[c[2]] for c, _, _ in _STREAK_RAYS) - 6 * thickness
    hi = max(c[2] + half[c[2]] for c, _, _ in _STREAK_RAYS) + 6 * thickness
    selection = p.select((np.array([-reach - 30, -reach - 120, lo]), np.array([reach + 30, reach, hi]), False))
    if selection is _EMPTY:
        return None
    q = p.take(selection)
    total = np.zeros(np.broadcast_shapes(q.x.shape, q.y.shape, q.z.shape))
    for c, dirs, signs in _STREAK_RAYS:
        dx, dy = q.x - c[0], q.y - c[1]
        r = np.hypot(dx, dy)
        height = 0.5 * erfc((np.abs(q.z - c[2]) - half[c[2]]) / (math.sqrt(2.0) * thickness))
        envelope = height * (10.0 / np.maximum(r, 10.0))
        envelope = envelope * np.clip(1.0 - r / reach, 0.0, 1.0)
        for (ux, uy), sign in zip(dirs, signs):
            along = dx * ux + dy * uy
            perp = dx * uy - dy * ux
            total += sign * np.where(along > 0, np.exp(-0.5 * (perp / width) ** 2), 0.0) * envelope
    out = np.zeros(p.shape)
    if selection is None:
        out[...] = amplitude * total
    else:
        out[selection] = amplitude * total
    return out


def _evaluate(p, hu: dict[str, float], blur: float, want_hu: bool = True, want_labels: bool = True,
              metal: bool = False):
    """Head signed distance, HU (noise-free, partial-volume blurred) and labels at points ``p``.

    HU: starting from air, each layer mixes in its value with the weight
    ``0.5 erfc(d / (sqrt(2) blur))`` (a plane interface convolved with a Gaussian PSF);
    beyond 6 blur from an interface the weight is taken as exactly 0 or 1. With ``metal``
    the dental fillings are a layer and their streaks (:func:`_streaks`) are added last.
    """
    head = _head_sd(p)
    layers = _layers(p, head, hu)
    if metal:
        for filling in _SHAPES["fillings"]:
            selection = p.select(filling.box(8.0))
            if selection is not _EMPTY:
                sd = np.broadcast_to(filling.sd(p.take(selection)),
                                     head.shape if selection is None else head[selection].shape)
                layers.append((METAL, hu["metal"], selection, sd))
    values = np.full(p.shape, hu["air"], dtype=np.float64) if want_hu else None
    labels = np.zeros(p.shape, dtype=np.uint8) if want_labels else None
    for label, value, selection, sd in layers:
        if want_labels:
            sub = labels if selection is None else labels[selection]
            sub[sd < 0] = label
            if selection is not None:
                labels[selection] = sub
        if not want_hu:
            continue
        sub = values if selection is None else values[selection]
        if blur > 0:
            deep, near = sd <= -6.0 * blur, np.abs(sd) < 6.0 * blur
            sub[deep] = value if np.ndim(value) == 0 else value[deep]
            weight = 0.5 * erfc(sd[near] / (math.sqrt(2.0) * blur))
            target = value if np.ndim(value) == 0 else value[near]
            sub[near] += (target - sub[near]) * weight
        else:
            inside = sd < 0
            sub[inside] = value if np.ndim(value) == 0 else value[inside]
        if selection is not None:
            values[selection] = sub
    if metal and want_hu:
        streaks = _streaks(p, hu["streak"])
        if streaks is not None:
            values += streaks
    return head, values, labels


def _points_from_array(points_xyz) -> tuple[_Points, tuple[int, ...]]:
    pts = np.asarray(points_xyz, dtype=np.float64)
    if pts.ndim == 0 or pts.shape[-1] != 3:
        raise _ParameterError(f"points must have shape (..., 3) (x, y, z in mm), got {pts.shape}")
    flat = pts.reshape(-1, 3)
    return _Points(flat[:, 0].copy(), flat[:, 1].copy(), flat[:, 2].copy()), pts.shape[:-1]


@dataclass
class Phantom:
    """A synthetic head CT and its exact truth.

    Attributes
    ----------
    ct : CTVolume
        float32 HU, axis-aligned (direction identity: i -> patient left,
        j -> posterior, k -> superior), head centred on x = 0.
    head_mask : ndarray of bool, shape (nz, ny, nx)
        Truth of "head" (skin and everything inside it, internal air included,
        neck down to the bottom of the field of view); pillow and holder excluded.
    labels : ndarray of uint8, shape (nz, ny, nx)
        Tissue label per voxel centre, see :data:`LABEL_NAMES`.
    noise : float
        Standard deviation (HU) of the white Gaussian noise in ``ct``.
    blur : float
        Standard deviation (mm) of the Gaussian partial-volume blur of interfaces.
    seed : int
        Seed of the noise.
    params : dict
        Everything used: shape, spacing, origin, hu table, geometry, landmarks
        (``vertex_z``, ``nose_tip`` (x, y, z), ``nose_tip_z``, ``head_center_y``,
        ``eye_centres``, ``ear_level_z``) and ``label_names``.
    """

    ct: CTVolume
    head_mask: np.ndarray
    labels: np.ndarray
    noise: float
    blur: float
    seed: int
    params: dict[str, Any] = field(default_factory=dict)

    legend = LABEL_NAMES

    def inside_head(self, points_xyz: np.ndarray) -> np.ndarray:
        """Exact truth: is each patient LPS point (mm, shape (..., 3)) inside the head?"""
        p, shape = _points_from_array(points_xyz)
        return (_head_sd(p) < 0).reshape(shape)

    def head_signed_distance(self, points_xyz: np.ndarray) -> np.ndarray:
        """Approximate signed distance (mm, negative inside) to the skin; its zero set is exact."""
        p, shape = _points_from_array(points_xyz)
        return _head_sd(p).reshape(shape)

    def skull_signed_distance(self, points_xyz: np.ndarray) -> np.ndarray:
        """Approximate signed distance (mm, negative inside) to the skull's outer surface; exact zero set."""
        p, shape = _points_from_array(points_xyz)
        return _skull_outer_sd(p, _head_sd(p)).reshape(shape)

    def tissue_depth(self, points_xyz: np.ndarray, max_depth: float = 60.0, step: float = 0.25) -> np.ndarray:
        """Analytic soft-tissue depth (mm): from the skin along its inward normal to the outer skull.

        Each point is first projected onto the exact skin (Newton steps on the skin's signed
        distance); the inward normal is the negative gradient there; the depth is the first
        crossing of the outer skull surface along it (sampled every ``step`` mm, then bisected
        to 1e-9 mm). NaN where no skull is met within ``max_depth`` (face below the vault, neck).
        """
        pts = np.asarray(points_xyz, dtype=np.float64)
        if pts.ndim == 0 or pts.shape[-1] != 3:
            raise _ParameterError(f"points must have shape (..., 3) (x, y, z in mm), got {pts.shape}")
        return _analytic_tissue_depth(pts, float(max_depth), float(step))[2].reshape(pts.shape[:-1])

    def bone_landmarks(self) -> dict[str, np.ndarray]:
        """Analytic craniometric landmarks of the facial skeleton (patient mm, by standard name).

        Each is the rule of :mod:`pdehead_addon.auto_landmarks` applied to the exact geometry
        (bone crossings found along rays sampled every 0.02 mm, or extremes of the bone on a
        0.1 mm grid), not to a voxel grid; the phantom's Frankfurt plane is z = -14 (porion and
        orbitale), so the phantom is already in the Frankfurt orientation. Landmarks whose rule
        depends on other estimates (canines, molars, rami, mid-points) are not listed.
        """
        return phantom_bone_landmarks()

    def labels_at(self, points_xyz: np.ndarray) -> np.ndarray:
        """Tissue label (uint8, see :data:`LABEL_NAMES`) at patient LPS points (..., 3)."""
        p, shape = _points_from_array(points_xyz)
        return _evaluate(p, self.params["hu"], self.blur, want_hu=False,
                         metal=self.params.get("metal", False))[2].reshape(shape)

    def sample_hu(self, points_xyz: np.ndarray,
                  noise_rng: np.random.Generator | int | None = None) -> np.ndarray:
        """HU of the phantom at patient LPS points (mm, shape (..., 3)), float32.

        Without ``noise_rng``: the noise-free model (partial-volume blur included),
        equal to ``ct`` minus its noise at voxel centres. With a numpy Generator
        (or an int seed): plus white Gaussian noise of standard deviation ``noise``.
        """
        p, shape = _points_from_array(points_xyz)
        values = _evaluate(p, self.params["hu"], self.blur, want_labels=False,
                           metal=self.params.get("metal", False))[1]
        if noise_rng is not None and self.noise > 0:
            rng = noise_rng if isinstance(noise_rng, np.random.Generator) else np.random.default_rng(noise_rng)
            values = values + self.noise * rng.standard_normal(values.shape)
        return values.astype(np.float32).reshape(shape)


def _metal_slices(zs: np.ndarray) -> list[int]:
    """Indices of the slices (heights ``zs``) that cut a filling (and so carry its streaks)."""
    inside = np.zeros(zs.shape, dtype=bool)
    for centre, radii in GEOMETRY["fillings"]:
        inside |= np.abs(zs - centre[2]) <= radii[2]
    return [int(k) for k in np.flatnonzero(inside)]


def make_phantom(shape: tuple[int, int, int] = DEFAULT_SHAPE,
                 spacing: tuple[float, float, float] | None = None,
                 noise: float = 20.0,
                 seed: int = 0,
                 blur: float | None = None,
                 hu: dict[str, float] | None = None,
                 metal: bool = False) -> Phantom:
    """Make the synthetic head CT (deterministic for equal arguments).

    Parameters
    ----------
    shape : (nz, ny, nx)
        Grid size. The default (100, 128, 128) takes about 0.3 s and is meant
        for the whole pipeline to run in seconds.
    spacing : (dz, dy, dx) mm, optional
        Default ``DEFAULT_FOV_MM / shape``, i.e. always the same 230 x 256 x 256 mm
        field of view (2.3 x 2.0 x 2.0 mm for the default shape, 1.4375 x 1 x 1 mm
        for (160, 256, 256)). The grid is centred on x = 0 and y = 4 mm; its top
        slice is at z = +110 mm (12 mm of air above the vertex) and it extends
        down ``nz * dz`` mm, so the default bottom slice cuts the neck 25 mm
        below the chin.
    noise : float
        Standard deviation of the white Gaussian CT noise in HU (0 for none).
    seed : int
        Seed of the noise generator.
    blur : float, optional
        Partial-volume blur (standard deviation of a Gaussian PSF, mm) applied
        analytically to every interface. Default ``0.4 * min(spacing)``; 0
        gives hard tissue boundaries.
    hu : dict, optional
        Overrides of :data:`DEFAULT_HU`.
    metal : bool
        Add dental fillings (label :data:`METAL`, ``hu["metal"]``) and their radial
        streak artefacts (alternately bright and dark rays in the axial planes of the
        fillings, reaching into the air in front of the mouth; ``hu["streak"]``). The
        truth (head mask, labels except the fillings) is unchanged: streaks are not
        tissue. ``params["metal_slices"]`` lists the slices the streaks reach.

    Returns
    -------
    Phantom

    Raises
    ------
    PDEHeadError
        (also a ValueError) for an invalid shape, spacing, noise, blur or hu table.

    Notes
    -----
    Default grid: 100 x 128 x 128 voxels of 2.3 x 2.0 x 2.0 mm, generated in about
    0.3 s; (160, 256, 256) takes about 2 s and (300, 512, 512) about 15-20 s with
    650 MB peak (the outputs are 6 bytes per voxel; the grid is evaluated in slabs
    of about 1 M voxels, so the temporaries stay bounded at any size).
    """
    shape = tuple(int(n) for n in np.atleast_1d(shape))
    if len(shape) != 3 or min(shape) < 2:
        raise _ParameterError(f"phantom shape must be 3 sizes >= 2 (nz, ny, nx), got {shape}")
    if spacing is None:
        spacing = tuple(f / n for f, n in zip(DEFAULT_FOV_MM, shape))
    spacing = tuple(float(s) for s in np.atleast_1d(spacing))
    if len(spacing) != 3 or not all(math.isfinite(s) and s > 0 for s in spacing):
        raise _ParameterError(f"phantom spacing must be 3 positive numbers (dz, dy, dx) in mm, got {spacing}")
    if not (math.isfinite(noise) and noise >= 0):
        raise _ParameterError(f"phantom noise must be a finite number >= 0 (HU), got {noise}")
    blur = 0.4 * min(spacing) if blur is None else float(blur)
    if not (math.isfinite(blur) and blur >= 0):
        raise _ParameterError(f"phantom blur must be a finite number >= 0 (mm), got {blur}")
    unknown = sorted(set(hu or {}) - set(DEFAULT_HU))
    if unknown:
        raise _ParameterError(f"unknown tissue(s) in hu: {unknown}; known: {sorted(DEFAULT_HU)}")
    table = dict(DEFAULT_HU)
    table.update({k: float(v) for k, v in (hu or {}).items()})

    nz, ny, nx = shape
    dz, dy, dx = spacing
    origin = np.array([-(nx - 1) / 2 * dx, _CENTRE_Y - (ny - 1) / 2 * dy, _TOP_Z - (nz - 1) * dz])
    xs = origin[0] + np.arange(nx) * dx
    ys = origin[1] + np.arange(ny) * dy
    zs = origin[2] + np.arange(nz) * dz

    data = np.empty(shape, dtype=np.float32)
    labels = np.empty(shape, dtype=np.uint8)
    head_mask = np.empty(shape, dtype=bool)
    slab = max(1, _CHUNK_VOXELS // (ny * nx))  # bounded peak memory at any resolution
    rng = np.random.default_rng(seed)  # slab-wise draws of one stream = one draw of the whole volume
    for k0 in range(0, nz, slab):
        zc = zs[k0:k0 + slab]
        head, values, lab = _evaluate(_Grid(xs, ys, zc), table, blur, metal=metal)
        data[k0:k0 + slab] = values
        if noise > 0:
            data[k0:k0 + slab] += np.float32(noise) * rng.standard_normal((zc.size, ny, nx), dtype=np.float32)
        labels[k0:k0 + slab] = lab
        head_mask[k0:k0 + slab] = head < 0

    g = GEOMETRY
    params = {
        "shape": shape, "spacing": spacing, "origin": tuple(origin), "noise": float(noise),
        "seed": int(seed), "blur": blur, "hu": table, "geometry": g,
        "vertex_z": g["cranium"][0][2] + g["cranium"][1][2],
        "nose_tip": (0.0, g["nose_tip"][0][1] - g["nose_tip"][1][1], g["nose_tip"][0][2]),
        "nose_tip_z": g["nose_tip"][0][2],
        "head_center_y": _CENTRE_Y,
        "eye_centres": ((-g["eyeball"][0][0],) + g["eyeball"][0][1:], g["eyeball"][0]),
        "ear_level_z": g["ear"][0][2],
        "label_names": dict(LABEL_NAMES),
        "metal": bool(metal),
        "metal_slices": _metal_slices(zs) if metal else [],
    }
    ct = CTVolume(data, spacing, origin=origin, direction=np.eye(3),
                  meta={"source": "pdehead synthetic phantom", "modality": "CT", "units": "HU",
                        "series_description": "PDE Head phantom",
                        "noise_hu": float(noise), "blur_mm": blur, "seed": int(seed)})
    return Phantom(ct=ct, head_mask=head_mask, labels=labels, noise=float(noise), blur=blur,
                   seed=int(seed), params=params)


def _is_bone(points: np.ndarray) -> np.ndarray:
    p, shape = _points_from_array(points)
    return (_evaluate(p, DEFAULT_HU, 0.0, want_hu=False)[2] == BONE).reshape(shape)


def _first_bone(start, direction, length: float = 150.0, step: float = 0.02) -> np.ndarray:
    """First bone point along a ray (exact geometry sampled every ``step`` mm)."""
    t = np.arange(0.0, length, step)
    pts = np.asarray(start, float) + t[:, None] * np.asarray(direction, float)
    hit = np.flatnonzero(_is_bone(pts))
    if not len(hit):
        raise RuntimeError(f"no bone along the ray from {start}")
    return pts[hit[0]]


def phantom_bone_landmarks() -> dict[str, np.ndarray]:
    f = GEOMETRY["facial_skeleton"]
    (ox, oz), (orx, orz) = f["orbit"]
    (my, mz), mrad, _ = f["meatus"]
    arch_y, arch_z = f["zygomatic_arch"][0][1], f["zygomatic_arch"][3]
    az, (arx, _), _ = f["aperture"]
    out: dict[str, np.ndarray] = {}
    front, eps = (0.0, 1.0, 0.0), 0.01
    oc, orad = GEOMETRY["skull_outer"]
    out["Vertex"] = np.array([0.0, oc[1], oc[2] + orad[2]])
    out["Opisthocranion"] = np.array([0.0, oc[1] + orad[1], oc[2]])
    for side, tag in ((1.0, "L"), (-1.0, "R")):
        out[f"Orbitale {tag}"] = _first_bone((side * ox, -130.0, oz - orz - eps), front)
        out[f"Supraorbital {tag}"] = _first_bone((side * ox, -130.0, oz + orz + eps), front)
        zl = oz - orz + 0.7 * 2 * orz                      # the rule's row: 70 % up the opening
        xl = ox + orx * math.sqrt(1.0 - ((zl - oz) / orz) ** 2)
        out[f"Lateral orbit {tag}"] = _first_bone((side * (xl + eps), -130.0, zl), front)
        out[f"Porion {tag}"] = _first_bone((side * 100.0, my, mz + mrad + eps), (-side, 0.0, 0.0))
        out[f"Zygomatic arch {tag}"] = _first_bone((side * 100.0, arch_y, arch_z), (-side, 0.0, 0.0))
        out[f"Alare curvature {tag}"] = _first_bone((side * (arx + eps), -130.0, az), front)
    # mid-sagittal profile on a 0.1 mm grid of rays from the face
    zs = np.arange(-30.0, 40.0, 0.1)
    ys = np.arange(-100.0, -30.0, 0.05)
    yy, zz = np.meshgrid(ys, zs, indexing="ij")
    grid = _is_bone(np.stack([np.zeros(yy.size), yy.ravel(), zz.ravel()], 1)).reshape(yy.shape)
    prof = np.where(grid.any(0), ys[np.argmax(grid, 0)], np.nan)
    band = (zs >= oz - orz + 25) & (zs <= oz - orz + 65)
    ig = np.flatnonzero(band)[np.nanargmin(prof[band])]
    out["Glabella"] = np.array([0.0, prof[ig], zs[ig]])
    notch = (zs > -10) & (zs < zs[ig])
    i_n = np.flatnonzero(notch)[np.nanargmax(prof[notch])]
    out["Nasion"] = np.array([0.0, prof[i_n], zs[i_n]])
    nasal = np.flatnonzero((zs < zs[i_n]) & (zs > -30) & (prof < prof[i_n] + 4))
    i_r = nasal.min()
    out["Rhinion"] = np.array([0.0, prof[i_r], zs[i_r]])
    zc = f["upper_alveolus"][2]
    out["Supradentale"] = _first_bone((0.0, -130.0, zc + eps), front)
    mc, mr, mhalf, mzc, mhh, _ = GEOMETRY["mandible"]
    out["Infradentale"] = _first_bone((0.0, -130.0, mzc + mhh - eps), front)
    c, r = f["chin"]
    out["Pogonion"] = np.array([0.0, c[1] - r[1], c[2]])
    bottom = mzc - mhh
    out["Menton"] = np.array([0.0, mc[1] - mr[1], bottom])                         # middle of the flat bottom
    # gnathion: the symphysis' bone point farthest along the anterior-inferior bisector
    yy, zz = np.meshgrid(np.arange(-80.0, -55.0, 0.1), np.arange(bottom - 1, c[2] + 1, 0.1), indexing="ij")
    pts = np.stack([np.zeros(yy.size), yy.ravel(), zz.ravel()], 1)
    b = pts[_is_bone(pts)]
    out["Gnathion"] = b[np.argmax(-b[:, 1] - b[:, 2])]
    # gonion: the farthest back-and-down mandible point, then the outermost within 4 mm (the rule)
    (rx, ry), rr, zlo, _ = f["ramus"]
    xx, yy, zz = np.meshgrid(np.arange(30.0, 56.0, 0.25), np.arange(ry - 6, ry + rr[1] + 3, 0.25),
                             np.arange(zlo - 1, zlo + 8, 0.25), indexing="ij")
    pts = np.stack([xx.ravel(), yy.ravel(), zz.ravel()], 1)
    b = pts[_is_bone(pts)]
    k = np.argmax(b[:, 1] - b[:, 2])
    near = b[np.linalg.norm(b[:, 1:] - b[k, 1:], axis=1) < 4.0]
    go = near[np.argmax(near[:, 0])]
    out["Gonion L"] = go
    out["Gonion R"] = go * np.array([-1.0, 1.0, 1.0])
    # the ellipse's lowest point lies on its centre column: suborbital = orbitale here
    for tag in "LR":
        out[f"Suborbital {tag}"] = out[f"Orbitale {tag}"].copy()
    return out
