"""The skull from the same CT: bone segmentation, the skull envelope for the PDE path, a bone mesh.

Forensic facial reconstruction works on the skull (the outer table of the
cranial vault and the facial skeleton) and on the soft tissue between it and
the skin.  :func:`segment_skull` finds the bone in the head CT and returns a
:class:`SkullSegmentation`, which is a :class:`~.segmentation.Segmentation`
whose ``mask`` is the skull's filled outer *envelope*: so the skull becomes a
second PDE surface by exactly the skin's path (paper eq. 22 boundary curves,
section 4.1 slice choice, eq. 1-13 patches)::

    skull = segment_skull(ct, head=seg)
    bset = extract_boundaries(skull, patches=t)       # the skull's 3t+1 outer outlines
    skull_head = solve_pde(bset)
    skull_surface = skull_head.surface(nu, nv, caps=True)

The envelope is what one axial outline per slice can describe: the cranial
vault exactly, the face's outer envelope with the orbits, the nasal aperture
and the gaps between the zygomatic arches and the temporal bone closed over
(the per-slice convex hull).  The bone itself (``bone``: cavities filled) is kept for
what the PDE smooths over; :func:`skull_mesh` turns it into a marching-cubes
mesh and :func:`~.tissue_depth.tissue_depth` uses it to refuse depths that end
on the closed-over envelope rather than on bone.

Steps of :func:`segment_skull`:

1. intensities in HU: as stored where the scan is calibrated (``meta["units"]
   == "HU"``), else mapped linearly by the histogram's air and soft-tissue modes
   (:func:`~.segmentation.auto_window`) onto -1000 and +40 HU (CThead is raw);
2. the bone level from the histogram inside the head (:func:`bone_level`): half
   way between the soft-tissue mode and the bone mode, the 50 % partial-volume
   level of a tissue/bone interface (the skin rule of the segmentation step);
   where the bone has no mode of its own (thick slices), ``DEFAULT_BONE_HU``;
3. metal (dental fillings: above ``METAL_HU`` or in the scanner's saturation
   spike) and its 1-voxel bloom are removed;
4. only bone inside the head mask counts: head holders, table and cradle arcs
   (the GE holder is above 300 HU and touches the head) lie outside the skin
   envelope that :func:`~.segmentation.segment_head` cleans;
5. components (26-connected): the largest is the cranium; every other component
   of at least ``min_component_mm3`` is kept (the mandible, which is separate at
   a bone level, nasal bones, teeth) except the cervical vertebrae (below the
   skull base and not in front of the cranium's centre);
6. enclosed cavities (diploe, closed sinuses) are filled (``bone``), then each
   slice's convex hull is the envelope (``mask``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage as ndi

from .ct_volume import CTVolume
from .errors import SegmentationError
from .mesh import Mesh
from .segmentation import Segmentation, auto_window, segment_head

#: HU assigned to the air and soft-tissue modes when the scan is not calibrated.
AIR_HU, TISSUE_HU = -1000.0, 40.0
#: Bone level (HU) when the histogram has no bone mode of its own.
DEFAULT_BONE_HU = 400.0
#: The bone level is kept in this HU range (below it: cartilage, contrast; above it: the outer table is lost).
BONE_LEVEL_RANGE_HU = (250.0, 700.0)
#: Above this (HU) a voxel is metal, not bone (enamel and cortical bone stay below ~2500 HU).
METAL_HU = 3000.0
#: Smallest bone component kept besides the cranium (mm^3).
MIN_COMPONENT_MM3 = 200.0
#: A bone component below the skull base whose centroid is less than this (mm) in front of the
#: cranium's centroid is a cervical vertebra (CThead: C2 31 mm; mandibles: phantom 40, CThead 100 mm).
VERTEBRA_FRONT_MM = 35.0


@dataclass
class SkullSegmentation(Segmentation):
    """Result of :func:`segment_skull`: a :class:`Segmentation` of the skull's envelope plus the bone.

    Attributes (besides those of :class:`Segmentation`)
    ----------------------------------------------------
    mask : ndarray of bool
        The skull's filled outer envelope, one closed region per slice (what the
        boundary curves of :func:`~.boundaries.extract_boundaries` follow).
    probability : ndarray of float32
        ``mask`` as 0/1 (the envelope has no soft membership).
    bone : ndarray of bool
        The bone kept (cranium, mandible, ...), enclosed cavities filled, metal removed.
    hu : ndarray of float32
        The intensities in (pseudo-)HU the levels refer to.
    bone_level, metal_level : float
        HU levels used (bone: the iso-level of :func:`skull_mesh`).
    """

    bone: np.ndarray | None = None
    hu: np.ndarray | None = None
    bone_level: float = DEFAULT_BONE_HU
    metal_level: float = METAL_HU


def hounsfield(ct: CTVolume, window: tuple[float, float] | None = None) -> tuple[np.ndarray, bool]:
    """The CT in HU (float32) and whether the scan was calibrated.

    Uncalibrated data (raw, 8-bit) is mapped linearly so that the histogram's air
    mode becomes ``AIR_HU`` and its soft-tissue mode ``TISSUE_HU``.
    """
    if str(ct.meta.get("units", "")).upper() == "HU":
        return ct.data, True
    low, high = auto_window(ct.data) if window is None else window
    scale = np.float32((TISSUE_HU - AIR_HU) / (float(high) - float(low)))
    hu = np.subtract(ct.data, np.float32(low), dtype=np.float32)
    hu *= scale
    hu += np.float32(AIR_HU)
    return hu, False


def bone_level(hu: np.ndarray, head: np.ndarray | None = None, bins_hu: float = 10.0) -> tuple[float, dict]:
    """The bone iso-level (HU) from the histogram of the head: half way between soft tissue and bone.

    Parameters
    ----------
    hu : ndarray
        Intensities in HU (or pseudo-HU, :func:`hounsfield`).
    head : ndarray of bool, optional
        Only these voxels are counted (the head mask keeps pillows and holders out).
    bins_hu : float
        Histogram bin width.

    Returns
    -------
    (level, info)
        ``info``: ``tissue_mode``, ``bone_mode`` (None if there is none) and
        ``source`` ("histogram" or "default").
    """
    values = hu[head] if head is not None else hu.reshape(-1)
    values = values[::max(1, values.size // 4_000_000)]
    if values.size == 0:
        raise SegmentationError("no voxels inside the head to find the bone level from")
    edges = np.arange(-200.0, 2600.0 + bins_hu, bins_hu)
    hist, _ = np.histogram(values, bins=edges)
    centres = 0.5 * (edges[:-1] + edges[1:])
    smooth = ndi.gaussian_filter1d(hist.astype(np.float64), 3.0)
    soft = (centres > -150) & (centres < 200)
    tissue = float(centres[soft][np.argmax(smooth[soft])])
    info: dict[str, Any] = {"tissue_mode": tissue, "bone_mode": None, "source": "default"}
    search = (centres >= tissue + 400) & (centres <= 2000)
    level = DEFAULT_BONE_HU
    if search.any():
        idx = np.flatnonzero(search)
        peak = int(idx[np.argmax(smooth[idx])])
        valley = float(smooth[np.flatnonzero((centres > tissue + 150) & (centres <= centres[peak]))].min())
        # a mode of its own: an interior maximum clearly above the valley towards soft tissue
        if idx[0] < peak < idx[-1] and smooth[peak] > 1.3 * valley and smooth[peak] > 0:
            info["bone_mode"] = float(centres[peak])
            info["source"] = "histogram"
            level = 0.5 * (tissue + float(centres[peak]))
    lo, hi = BONE_LEVEL_RANGE_HU
    info["unclamped"] = level
    return float(min(max(level, lo), hi)), info


def _metal_level(ct: CTVolume, hu: np.ndarray, calibrated: bool) -> float:
    """METAL_HU, or lower where the scanner saturated (a spike of equal values at the top of the range)."""
    level = METAL_HU
    if not calibrated:
        top = float(ct.data.max())
        span = top - float(ct.data.min())
        near_top = ct.data >= np.float32(top - 0.005 * span)
        if np.count_nonzero(near_top) > 1e-5 * ct.data.size:
            level = min(level, float(hu[near_top].min()))
    return level


def _vertebra_components(labels: np.ndarray, centroids_xyz: np.ndarray, cranium: int, ct: CTVolume) -> np.ndarray:
    """True for components that are cervical vertebrae: below the skull base, not in front of the cranium.

    Patient coordinates (mm): the centroid lies below the lowest tenth of the cranium's
    height and less than VERTEBRA_FRONT_MM in front of the cranium's centroid (the mandible, the hyoid and
    facial fragments are further forward).
    """
    ks = np.flatnonzero(np.any(labels == cranium, axis=(1, 2)))
    z = ct.index_to_patient(np.column_stack([ks, np.zeros_like(ks), np.zeros_like(ks)]).astype(float))[:, 2]
    base = z.min() + 0.1 * (z.max() - z.min())
    cranium_y = centroids_xyz[cranium - 1, 1]
    return (centroids_xyz[:, 2] < base) & (centroids_xyz[:, 1] > cranium_y - VERTEBRA_FRONT_MM)


def segment_skull(ct: CTVolume, head: Segmentation | None = None, *, level: float | None = None,
                  min_component_mm3: float = MIN_COMPONENT_MM3) -> SkullSegmentation:
    """Segment the skull (cranium, facial skeleton, mandible) from a head CT.

    Parameters
    ----------
    ct : CTVolume
    head : Segmentation, optional
        The head segmentation of the same CT (:func:`~.segmentation.segment_head`);
        computed when not given. Bone outside its mask (holders, table) is ignored.
    level : float, optional
        Bone level in HU (pseudo-HU for uncalibrated scans); default :func:`bone_level`.
    min_component_mm3 : float
        Smaller bone fragments are dropped.

    Returns
    -------
    SkullSegmentation
        ``mask`` = envelope (for :func:`~.boundaries.extract_boundaries`), ``bone``,
        ``hu``, ``bone_level``, ``metal_level``; ``meta`` with the levels, the
        histogram modes, the components kept and dropped and their volumes (mm^3).

    Raises
    ------
    SegmentationError
        Not a CTVolume, MR data, no bone above the level inside the head.
    """
    if not isinstance(ct, CTVolume):
        raise SegmentationError(f"segment_skull needs a CTVolume, got {type(ct).__name__}")
    if str(ct.meta.get("modality", "")).upper() in ("MR", "MRI"):
        raise SegmentationError(f"{ct.meta.get('source', 'this scan')}: bone is dark in MRI; the skull needs a CT")
    if head is None:
        head = segment_head(ct)
    if head.mask.shape != ct.shape:
        raise SegmentationError(f"head mask shape {head.mask.shape} != CT shape {ct.shape}")
    window = head.meta.get("window")
    hu, calibrated = hounsfield(ct, tuple(window) if window else None)
    head_mask = head.mask
    info: dict[str, Any] = {}
    if level is None:
        level, info = bone_level(hu, head_mask)
    level = float(level)
    metal_level = _metal_level(ct, hu, calibrated)
    dz, dy, dx = ct.spacing
    voxel_mm3 = dz * dy * dx

    metal = hu >= np.float32(metal_level)
    n_metal = int(np.count_nonzero(metal))
    if n_metal:
        metal = ndi.binary_dilation(metal, structure=ndi.generate_binary_structure(3, 1))
    bone = (hu >= np.float32(level)) & head_mask & ~metal
    if not bone.any():
        raise SegmentationError(f"{ct.meta.get('source', 'the CT')}: nothing inside the head is above the bone "
                                f"level {level:.0f} HU")
    # components on the bone eroded by one voxel: joints and tooth contacts at partial volume
    # (atlanto-occipital, TMJ, closed bite) join the vertebrae or the mandible to the cranium at the
    # bone level; one voxel of erosion separates them (CThead), thicker bone stays whole
    cross = ndi.generate_binary_structure(3, 1)
    full = np.ones((3, 3, 3), bool)
    core = ndi.binary_erosion(bone, structure=cross)
    if not core.any():
        core = bone
    labels, n = ndi.label(core, structure=full)
    sizes = np.bincount(labels.reshape(-1), minlength=n + 1)[1:]
    cranium = int(np.argmax(sizes)) + 1
    centroids = np.array(ndi.center_of_mass(core, labels, np.arange(1, n + 1))).reshape(n, 3)
    centroids_xyz = ct.index_to_patient(centroids)
    big = sizes * voxel_mm3 >= float(min_component_mm3)
    vertebra = _vertebra_components(labels, centroids_xyz, cranium, ct) & big
    vertebra[cranium - 1] = False
    keep = big & ~vertebra
    keep[cranium - 1] = True
    # give the eroded rim back to the component it came from (a few constrained label dilations)
    grown = labels
    for _ in range(3):
        spread = ndi.grey_dilation(grown, footprint=full)
        grown = np.where(bone & (grown == 0), spread, grown)
    dropped = bone & np.concatenate([[False], vertebra])[grown]
    rest, m = ndi.label(bone & ~dropped, structure=full)
    holds_kept = np.unique(rest[np.concatenate([[False], keep])[grown] & (rest > 0)])
    skull = np.isin(rest, holds_kept[holds_kept > 0])
    del labels, grown, rest, core
    skull = ndi.binary_fill_holes(skull)
    envelope = _envelope(skull)

    order = np.argsort(sizes)[::-1]
    components = [dict(label=int(i + 1), volume_mm3=float(sizes[i] * voxel_mm3),
                       centroid_mm=[round(float(c), 1) for c in centroids_xyz[i]],
                       kept=bool(keep[i]), vertebra=bool(vertebra[i])) for i in order[:12]]
    meta = dict(mode="skull", bone_level=level, metal_level=metal_level, calibrated=calibrated,
                histogram=info, metal_voxels=n_metal, 
                components=components, components_total=int(n),
                kept_components=int(np.count_nonzero(keep)),
                dropped_vertebra_mm3=float(np.count_nonzero(dropped) * voxel_mm3),
                dropped_small_mm3=float(sizes[~big].sum() * voxel_mm3),
                bone_mm3=float(np.count_nonzero(skull) * voxel_mm3),
                window=head.meta.get("window"))
    return SkullSegmentation(mask=envelope, probability=envelope.astype(np.float32), c1=float(level),
                             c2=float(info.get("tissue_mode", TISSUE_HU) if info else TISSUE_HU),
                             iterations=0, ct=ct, meta=meta, bone=skull, hu=hu, bone_level=level,
                             metal_level=metal_level)


def _envelope(bone: np.ndarray) -> np.ndarray:
    """Per axial slice the convex hull of the bone: the outer outline one closed curve per slice can follow.

    A closing cannot bridge the orbits (30-40 mm wide openings at eye level, CThead),
    so the per-slice envelope is the convex hull; at the vault it equals the filled
    outer table, at the face it closes over the orbits, the nasal aperture and the
    temporal fossae behind the zygomatic arches.
    """
    from skimage.morphology import convex_hull_image

    out = np.zeros_like(bone)
    for k in np.flatnonzero(bone.any(axis=(1, 2))):
        sl = bone[k]
        if np.count_nonzero(sl) >= 3:
            # hull of the pixel centres: with corners the hull grows by up to half a pixel
            out[k] = convex_hull_image(sl, offset_coordinates=False) | sl
        else:
            out[k] = sl
    return out


#: Largest triangle count of the bone skull (:func:`skull_mesh`): printable, and light enough for Blender.
MAX_SKULL_TRIANGLES = 500_000
#: Gaussian blur (voxels) of the binary bone mask before marching cubes: sub-voxel, stair-free edges.
SKULL_MASK_SIGMA = 1.0
#: Taubin smoothing passes of the bone skull (lambda/mu: smooths without shrinking).
SKULL_SMOOTHING_PASSES = 10


def skull_mesh(skull: SkullSegmentation, step: int = 1, max_triangles: int = MAX_SKULL_TRIANGLES,
               smoothing_passes: int = SKULL_SMOOTHING_PASSES) -> Mesh:
    """The bone skull: smoothed marching cubes of the binary bone mask, watertight, in patient mm.

    What ``skull.<fmt>`` is: the bone surface a practitioner can peg and print, with the orbits, the
    nasal aperture and the zygomatic arches open as they are in bone (the PDE skull envelope of
    :func:`segment_skull`'s ``mask`` closes over them). From the bone level on it depends on the
    binary mask ``skull.bone`` alone, not on the intensities: a CT and the same CT with every voxel
    below the level set to air give the same skull.

    1. the bone mask (kept components, cavities filled) is blurred by a Gaussian of
       ``SKULL_MASK_SIGMA`` voxels and meshed at 0.5 by marching cubes (Lewiner), padded so the
       surface is closed;
    2. the marching-cubes step grows (1, 2, 3 ...) until the mesh has at most ``max_triangles``;
    3. Taubin lambda/mu smoothing (Taubin 1995: lambda 0.5, mu -0.53) removes the voxel terraces
       without shrinking the skull; it moves vertices only, so the mesh stays closed.

    Parameters
    ----------
    skull : SkullSegmentation
    step : int
        Smallest marching-cubes step in voxels.
    max_triangles : int
        Triangle budget (default 500k).
    smoothing_passes : int
        Taubin passes (0: none).

    Returns
    -------
    Mesh
        Triangles in patient LPS mm, wound outward (counter-clockwise seen from outside).
    """
    from skimage.measure import marching_cubes

    if skull.bone is None:
        raise SegmentationError("skull_mesh needs the result of segment_skull (the bone mask)")
    bone = skull.bone
    box = ndi.find_objects(bone.astype(np.uint8))
    if not box or box[0] is None:
        raise SegmentationError("the skull segmentation has no bone")
    box = tuple(slice(max(0, s.start - 2), s.stop + 2) for s in box[0])
    field = ndi.gaussian_filter(bone[box].astype(np.float32), SKULL_MASK_SIGMA)
    field = np.pad(field, 2, constant_values=0.0)
    origin = np.array([s.start - 2 for s in box], float)
    step = max(1, int(step))
    while True:
        verts, faces, _, _ = marching_cubes(field, level=0.5, step_size=step, allow_degenerate=False)
        if len(faces) <= max_triangles or step >= 8:
            break
        step += 1
    if len(faces) > max_triangles:
        raise SegmentationError(f"the bone skull has {len(faces)} triangles at marching-cubes step {step}, "
                                f"more than {max_triangles}")
    faces = faces.astype(np.int64)
    if smoothing_passes:
        verts = taubin_smooth(verts, faces, passes=int(smoothing_passes))
    pts = skull.ct.index_to_patient(verts + origin)
    mesh = Mesh(vertices=pts, quads=np.zeros((0, 4), np.int64), triangles=faces)
    if _signed_volume(mesh) < 0:  # index (k, j, i) -> patient may flip handedness
        mesh.triangles = faces[:, ::-1].copy()
    mesh.vertex_attributes = {}
    return mesh


def taubin_smooth(vertices: np.ndarray, triangles: np.ndarray, passes: int = 8, lam: float = 0.5,
                  mu: float = -0.53) -> np.ndarray:
    """Taubin's lambda/mu smoothing (Taubin, SIGGRAPH 1995) with the umbrella operator; vertices only.

    Each pass moves every vertex by ``lam`` then ``mu`` times the mean of its neighbours minus itself
    (a low-pass filter that does not shrink the surface as repeated Laplacian smoothing does).
    """
    from scipy import sparse

    v = np.asarray(vertices, np.float64).copy()
    t = np.asarray(triangles, np.int64)
    i = np.concatenate([t[:, 0], t[:, 1], t[:, 2], t[:, 1], t[:, 2], t[:, 0]])
    j = np.concatenate([t[:, 1], t[:, 2], t[:, 0], t[:, 0], t[:, 1], t[:, 2]])
    adj = sparse.csr_matrix((np.ones(len(i)), (i, j)), shape=(len(v), len(v)))
    adj.sum_duplicates()
    adj.data[:] = 1.0                                   # an edge shared by two triangles counted once
    deg = np.asarray(adj.sum(axis=1)).ravel()
    inv = np.divide(1.0, deg, out=np.zeros_like(deg), where=deg > 0)[:, None]
    for _ in range(int(passes)):
        for f in (lam, mu):
            v += f * (adj @ v * inv - v)
    return v


def _signed_volume(mesh: Mesh) -> float:
    v = mesh.vertices
    t = mesh.triangles
    return float(np.einsum("ij,ij->i", v[t[:, 0]], np.cross(v[t[:, 1]], v[t[:, 2]])).sum() / 6.0)
