"""The analytic head of the synthetic CT (:mod:`.phantom`): its geometry, tissues, labels and HU.

:data:`GEOMETRY` (mm, patient LPS, eye line at z = 0) builds the skin (:func:`head_sd`), the tissue layers
(labels and HU per point), the skull's outer surface (:func:`skull_outer_sd`) and the metal streaks;
:func:`evaluate_tissues` evaluates all of it at a set of points with the partial-volume blur.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.special import erfc

from ..core.errors import PDEHeadError
from .phantom_primitives import (
    EMPTY,
    Cylinder,
    Ellipsoid,
    Plate,
    Points,
    SmoothUnion,
    blend,
    ellipse_sd,
    ellipsoid_sd,
    rotation_about_x,
    rotation_ear,
    smax,
)

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
TOP_Z = 110.0          # patient z of the centre of the top slice (vertex at +98)
CENTRE_Y = 4.0         # patient y of the grid centre (nose tip -106, holder back +122)
CHUNK_VOXELS = 1 << 20  # evaluate the grid in slabs of about this many voxels (bounded memory)


class PhantomParameterError(PDEHeadError, ValueError):
    """A phantom parameter is out of range (catchable as PDEHeadError or ValueError)."""


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
    # facial skeleton: what automatic craniometric landmarks need, every part a primitive
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
    e = Ellipsoid
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
            ("union", Cylinder((ncx, ncy), nr, top=ntop), 20.0),
            ("union", SmoothUnion(e(bc, br, axes=rotation_about_x(-lean)),
                                   (e(*g["nose_tip"]), 5.0), (e(*g["columella"]), 3.0)), 5.0),
            ("union", e(*g["nose_ala"], mirror=True), 4.0),
            ("union", e(*g["upper_lip"]), 4.0),
            ("union", e(*g["lower_lip"]), 4.0),
            ("union", Plate(ec, er, mirror=True, axes=rotation_ear(flare, roll), half=True), 4.0),
            ("carve", e(*g["eye_socket"], mirror=True), 4.0),
            ("union", e(*g["eyeball"], mirror=True), 2.0),
            ("carve", e(*g["mouth_line"]), 1.0),
        ],
        "skull_outer": e(*g["skull_outer"]),
        "skull_inner": e(*g["skull_inner"]),
        "ventricle": e(*g["ventricle"], mirror=True),
        "eyeball": e(*g["eyeball"], mirror=True),
        "internal_air": [Cylinder((acx, acy), ar, top=atop), e(*g["nasal_cavity"]),
                         e(*g["maxillary_sinus"], mirror=True), e(*g["frontal_sinus"])],
        "fillings": [e(c, r, mirror=True) for c, r in g["fillings"]],
    }


SHAPES = _build_shapes(GEOMETRY)


def head_sd(p) -> np.ndarray:
    """Signed distance (approx., mm; exact zero set) of the head: skin and all inside it."""
    d = np.broadcast_to(SHAPES["cranium"].sd(p), p.shape).copy()
    for operation, prim, k in SHAPES["head_parts"]:
        blend(d, p, prim, k, carve=operation == "carve")
    return d


def _box(lo, hi):
    return np.asarray(lo, float), np.asarray(hi, float), False


def _layers(p, head: np.ndarray, hu: dict[str, float]):
    """Painter's list of ``(label, HU, selection, signed distance)``; later layers overwrite.

    ``selection`` picks the points the layer may occupy (None: all; see
    ``Points.select`` / ``Grid.select``); the signed distance and the HU (scalar
    or array) are given on those points only.
    """
    g, s = GEOMETRY, SHAPES
    layers = []

    def add(label, value, box, sd_fn, head_margin=None):
        selection = p.select(box) if box is not None else None
        if selection is EMPTY:
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
        shell = np.abs(ellipse_sd(q.x - hcx, q.y - hcy, hr)) - hhalf
        return np.maximum(np.maximum(shell, hymin - q.y), q.z - hzmax)

    def cushion_sd(q):  # fills the cradle behind the head, up to z = czmax
        return smax(np.maximum(ellipse_sd(q.x - hcx, q.y - hcy, inner_r), cymin - q.y), q.z - czmax, 6.0)

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
        return smax(s["skull_inner"].sd(q), g["brain_floor_z"] - q.z, 3.0)

    fc, fr_ = g["facial_skeleton"]["temporal_fossa"]

    def skull_sd(q):
        shell = np.maximum(smax(s["skull_outer"].sd(q), g["skull_base_z"] - q.z, 3.0), -cavity_sd(q))
        return np.maximum(shell, -ellipsoid_sd(q.ax - fc[0], q.y - fc[1], q.z - fc[2], fr_))

    def brain_sd(q):
        return cavity_sd(q) + g["csf_layer"]

    add(BONE, hu["skull"], s["skull_outer"].box(8.0), lambda q: _face_carves(q, skull_sd(q)), 2.0)
    add(CSF, hu["csf"], s["skull_inner"].box(8.0), cavity_sd, 3.0)
    add(BRAIN, hu["brain"], s["skull_inner"].box(8.0), brain_sd, 3.0 + g["csf_layer"])
    add(CSF, hu["csf"], s["ventricle"].box(8.0), s["ventricle"].sd, 3.0)
    add(EYE, hu["eye"], s["eyeball"].box(8.0), s["eyeball"].sd, 1.0)  # 1 mm lid in front

    add(BONE, hu["mandible"], _FACE_BOX, _mandible_sd, 3.0)
    (scx, scy), sr, stop, period, disc_half = g["spine"]
    column = Cylinder((scx, scy), sr, top=stop)

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
    ring = np.abs(ellipse_sd(q.x - centre[0], q.y - centre[1], radii)) - half
    return np.maximum(ring, np.abs(q.z - 0.5 * (zlo + zhi)) - 0.5 * (zhi - zlo))


def _face_carves(q, d):
    """Bone ``d`` with the orbits, the nasal aperture, the meatus and the temporal fossae carved out."""
    f = GEOMETRY["facial_skeleton"]
    (ox, oz), orad = f["orbit"]
    orbit = np.maximum(ellipse_sd(q.ax - ox, q.z - oz, orad), q.y + 40.0)          # open from y = -40 forward
    az, arad, ay = f["aperture"]
    aperture = np.maximum(ellipse_sd(q.x, q.z - az, arad), q.y - ay)
    (my, mz), mrad, mx = f["meatus"]
    meatus = np.maximum(np.hypot(q.y - my, q.z - mz) - mrad, mx - q.ax)
    hole = np.minimum(np.minimum(orbit, aperture), meatus)
    return np.maximum(d, -hole)


def _upper_face_sd(q):
    """Face block, brow, zygomatic arches, petrous blocks, upper alveolus and teeth, carved."""
    f = GEOMETRY["facial_skeleton"]
    c, r, ymax = f["face_block"]
    outer = ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], r)
    inner = ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], tuple(v - FACE_WALL_MM for v in r))
    block = np.maximum(np.maximum(outer, -inner), q.y - ymax)                        # a shell, open behind
    c, r = f["brow_ridge"]
    brow = ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], r)
    c, r, half, zc, hh, (ylo, yhi) = f["zygomatic_arch"]
    arch = np.maximum(_ring_sd(q, c, r, half, zc - hh, zc + hh), np.maximum(ylo - q.y, q.y - yhi))
    arch = np.maximum(arch, 40.0 - q.ax)                                             # the lateral parts only
    c, r = f["petrous"]
    petrous = ellipsoid_sd(q.ax - c[0], q.y - c[1], q.z - c[2], r)
    mc = GEOMETRY["mandible"][0]
    r, half, zlo, zhi = f["upper_alveolus"]
    alveolus = np.maximum(_ring_sd(q, mc, r, half, zlo, zhi), q.y + 15.0)
    d = np.minimum.reduce([block, brow, arch, petrous, alveolus])
    # the nasal cavity as it is, the maxillary sinuses 3 mm smaller (a bony wall in front of them)
    c, r = GEOMETRY["nasal_cavity"]
    d = np.maximum(d, -ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], r))
    c, r = GEOMETRY["maxillary_sinus"]
    d = np.maximum(d, -ellipsoid_sd(q.ax - c[0], q.y - c[1], q.z - c[2], tuple(v - 3.0 for v in r)))
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
    nasal = ellipsoid_sd(q.x - m[0], u, w, (rx, half, rt))
    c, r = f["nasal_spine"]
    spine = ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], r)
    return np.minimum(nasal, spine)


def _mandible_sd(q):
    """Mandible: the U-shaped body, the chin, the rami and the lower teeth."""
    g, f = GEOMETRY, GEOMETRY["facial_skeleton"]
    mc, mr, mhalf, mz, mhh, mymax = g["mandible"]
    body = np.maximum(_ring_sd(q, mc, mr, mhalf, mz - mhh, mz + mhh), q.y - mymax)
    c, r = f["chin"]
    chin = ellipsoid_sd(q.x - c[0], q.y - c[1], q.z - c[2], r)
    (rx, ry), rr, zlo, zhi = f["ramus"]
    ramus = np.maximum(ellipse_sd(q.ax - rx, q.y - ry, rr), np.abs(q.z - 0.5 * (zlo + zhi)) - 0.5 * (zhi - zlo))
    r, half, zlo, zhi = f["lower_teeth"]
    teeth = np.maximum(_ring_sd(q, mc, r, half, zlo, zhi), q.y + 15.0)
    return np.minimum.reduce([body, chin, ramus, teeth])


def skull_outer_sd(p, head: np.ndarray) -> np.ndarray:
    """Signed distance (approx., mm; exact zero set) of the skull's OUTER surface (the filled skull).

    The outer ellipsoid cut by the flat base, as painted by :func:`_layers` (which also
    keeps the bone at least 2 mm under the skin; that clamp is applied here too).
    """
    g, s = GEOMETRY, SHAPES
    d = smax(s["skull_outer"].sd(p), g["skull_base_z"] - p.z, 3.0)
    return np.maximum(d, head + 2.0)



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
    if selection is EMPTY:
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


def evaluate_tissues(p, hu: dict[str, float], blur: float, want_hu: bool = True, want_labels: bool = True,
              metal: bool = False):
    """Head signed distance, HU (noise-free, partial-volume blurred) and labels at points ``p``.

    HU: starting from air, each layer mixes in its value with the weight
    ``0.5 erfc(d / (sqrt(2) blur))`` (a plane interface convolved with a Gaussian PSF);
    beyond 6 blur from an interface the weight is taken as exactly 0 or 1. With ``metal``
    the dental fillings are a layer and their streaks (:func:`_streaks`) are added last.
    """
    head = head_sd(p)
    layers = _layers(p, head, hu)
    if metal:
        for filling in SHAPES["fillings"]:
            selection = p.select(filling.box(8.0))
            if selection is not EMPTY:
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


def points_from_array(points_xyz) -> tuple[Points, tuple[int, ...]]:
    pts = np.asarray(points_xyz, dtype=np.float64)
    if pts.ndim == 0 or pts.shape[-1] != 3:
        raise PhantomParameterError(f"points must have shape (..., 3) (x, y, z in mm), got {pts.shape}")
    flat = pts.reshape(-1, 3)
    return Points(flat[:, 0].copy(), flat[:, 1].copy(), flat[:, 2].copy()), pts.shape[:-1]
