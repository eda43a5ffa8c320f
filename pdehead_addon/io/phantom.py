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

from ..core.ct_volume import CTVolume
from .phantom_anatomy import (
    AIR,
    BONE,
    BRAIN,
    CENTRE_Y,
    CHUNK_VOXELS,
    CSF,
    CUSHION,
    DEFAULT_FOV_MM,
    DEFAULT_HU,
    DEFAULT_SHAPE,
    EYE,
    GEOMETRY,
    HOLDER,
    INTERNAL_AIR,
    LABEL_NAMES,
    METAL,
    SOFT_TISSUE,
    TOP_Z,
    PhantomParameterError,
    evaluate_tissues,
    head_sd,
    points_from_array,
    skull_outer_sd,
)
from .phantom_primitives import Grid, Points

__all__ = ["make_phantom", "Phantom", "phantom_bone_landmarks", "AIR", "SOFT_TISSUE", "BONE", "BRAIN", "CSF", "EYE",
           "INTERNAL_AIR", "CUSHION", "HOLDER", "METAL", "LABEL_NAMES", "DEFAULT_HU", "DEFAULT_FOV_MM",
           "DEFAULT_SHAPE", "GEOMETRY"]


def _analytic_tissue_depth(points: np.ndarray, max_depth: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Skin points (projected onto the exact skin), inward normals and the depth to the skull along them."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3).copy()
    h = 1e-3

    def sd_and_grad(q):
        base = head_sd(Points(q[:, 0], q[:, 1], q[:, 2]))
        grad = np.empty_like(q)
        for a in range(3):
            e = np.zeros(3)
            e[a] = h
            hi, lo = q + e, q - e
            grad[:, a] = (head_sd(Points(hi[:, 0], hi[:, 1], hi[:, 2]))
                          - head_sd(Points(lo[:, 0], lo[:, 1], lo[:, 2]))) / (2 * h)
        return base, grad

    for _ in range(3):  # Newton steps onto the zero set of the skin
        d, grad = sd_and_grad(pts)
        pts -= (d / np.maximum(np.einsum("ij,ij->i", grad, grad), 1e-12))[:, None] * grad
    _, grad = sd_and_grad(pts)
    inward = -grad / np.linalg.norm(grad, axis=1, keepdims=True)

    def skull_sd(t):
        q = pts + t[:, None] * inward
        qp = Points(q[:, 0], q[:, 1], q[:, 2])
        return skull_outer_sd(qp, head_sd(qp))

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
                qp = Points(q[:, 0], q[:, 1], q[:, 2])
                inside = skull_outer_sd(qp, head_sd(qp)) <= 0
                hi = np.where(inside, mid, hi)
                lo = np.where(inside, lo, mid)
            depth[hit] = 0.5 * (lo + hi)
            open_ &= ~hit
        if not open_.any():
            break
    return pts, inward, depth




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
        p, shape = points_from_array(points_xyz)
        return (head_sd(p) < 0).reshape(shape)

    def head_signed_distance(self, points_xyz: np.ndarray) -> np.ndarray:
        """Approximate signed distance (mm, negative inside) to the skin; its zero set is exact."""
        p, shape = points_from_array(points_xyz)
        return head_sd(p).reshape(shape)

    def skull_signed_distance(self, points_xyz: np.ndarray) -> np.ndarray:
        """Approximate signed distance (mm, negative inside) to the skull's outer surface; exact zero set."""
        p, shape = points_from_array(points_xyz)
        return skull_outer_sd(p, head_sd(p)).reshape(shape)

    def tissue_depth(self, points_xyz: np.ndarray, max_depth: float = 60.0, step: float = 0.25) -> np.ndarray:
        """Analytic soft-tissue depth (mm): from the skin along its inward normal to the outer skull.

        Each point is first projected onto the exact skin (Newton steps on the skin's signed
        distance); the inward normal is the negative gradient there; the depth is the first
        crossing of the outer skull surface along it (sampled every ``step`` mm, then bisected
        to 1e-9 mm). NaN where no skull is met within ``max_depth`` (face below the vault, neck).
        """
        pts = np.asarray(points_xyz, dtype=np.float64)
        if pts.ndim == 0 or pts.shape[-1] != 3:
            raise PhantomParameterError(f"points must have shape (..., 3) (x, y, z in mm), got {pts.shape}")
        return _analytic_tissue_depth(pts, float(max_depth), float(step))[2].reshape(pts.shape[:-1])

    def bone_landmarks(self) -> dict[str, np.ndarray]:
        """Analytic craniometric landmarks of the facial skeleton (patient mm, by standard name).

        Each is the rule of :mod:`pdehead_addon.forensic.auto_landmarks` applied to the exact geometry
        (bone crossings found along rays sampled every 0.02 mm, or extremes of the bone on a
        0.1 mm grid), not to a voxel grid; the phantom's Frankfurt plane is z = -14 (porion and
        orbitale), so the phantom is already in the Frankfurt orientation. Landmarks whose rule
        depends on other estimates (canines, molars, rami, mid-points) are not listed.
        """
        return phantom_bone_landmarks()

    def labels_at(self, points_xyz: np.ndarray) -> np.ndarray:
        """Tissue label (uint8, see :data:`LABEL_NAMES`) at patient LPS points (..., 3)."""
        p, shape = points_from_array(points_xyz)
        return evaluate_tissues(p, self.params["hu"], self.blur, want_hu=False,
                         metal=self.params.get("metal", False))[2].reshape(shape)

    def sample_hu(self, points_xyz: np.ndarray,
                  noise_rng: np.random.Generator | int | None = None) -> np.ndarray:
        """HU of the phantom at patient LPS points (mm, shape (..., 3)), float32.

        Without ``noise_rng``: the noise-free model (partial-volume blur included),
        equal to ``ct`` minus its noise at voxel centres. With a numpy Generator
        (or an int seed): plus white Gaussian noise of standard deviation ``noise``.
        """
        p, shape = points_from_array(points_xyz)
        values = evaluate_tissues(p, self.params["hu"], self.blur, want_labels=False,
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
        raise PhantomParameterError(f"phantom shape must be 3 sizes >= 2 (nz, ny, nx), got {shape}")
    if spacing is None:
        spacing = tuple(f / n for f, n in zip(DEFAULT_FOV_MM, shape))
    spacing = tuple(float(s) for s in np.atleast_1d(spacing))
    if len(spacing) != 3 or not all(math.isfinite(s) and s > 0 for s in spacing):
        raise PhantomParameterError(f"phantom spacing must be 3 positive numbers (dz, dy, dx) in mm, got {spacing}")
    if not (math.isfinite(noise) and noise >= 0):
        raise PhantomParameterError(f"phantom noise must be a finite number >= 0 (HU), got {noise}")
    blur = 0.4 * min(spacing) if blur is None else float(blur)
    if not (math.isfinite(blur) and blur >= 0):
        raise PhantomParameterError(f"phantom blur must be a finite number >= 0 (mm), got {blur}")
    unknown = sorted(set(hu or {}) - set(DEFAULT_HU))
    if unknown:
        raise PhantomParameterError(f"unknown tissue(s) in hu: {unknown}; known: {sorted(DEFAULT_HU)}")
    table = dict(DEFAULT_HU)
    table.update({k: float(v) for k, v in (hu or {}).items()})

    nz, ny, nx = shape
    dz, dy, dx = spacing
    origin = np.array([-(nx - 1) / 2 * dx, CENTRE_Y - (ny - 1) / 2 * dy, TOP_Z - (nz - 1) * dz])
    xs = origin[0] + np.arange(nx) * dx
    ys = origin[1] + np.arange(ny) * dy
    zs = origin[2] + np.arange(nz) * dz

    data = np.empty(shape, dtype=np.float32)
    labels = np.empty(shape, dtype=np.uint8)
    head_mask = np.empty(shape, dtype=bool)
    slab = max(1, CHUNK_VOXELS // (ny * nx))  # bounded peak memory at any resolution
    rng = np.random.default_rng(seed)  # slab-wise draws of one stream = one draw of the whole volume
    for k0 in range(0, nz, slab):
        zc = zs[k0:k0 + slab]
        head, values, lab = evaluate_tissues(Grid(xs, ys, zc), table, blur, metal=metal)
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
        "head_center_y": CENTRE_Y,
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
    p, shape = points_from_array(points)
    return (evaluate_tissues(p, DEFAULT_HU, 0.0, want_hu=False)[2] == BONE).reshape(shape)


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
