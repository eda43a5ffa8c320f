"""The skull from the same CT: bone segmentation, the skull envelope for the PDE path, a bone mesh.

Forensic facial reconstruction works on the skull (the outer table of the cranial vault and the facial
skeleton) and on the soft tissue between it and the skin.  :func:`segment_skull` finds the bone in the head CT
and returns a :class:`SkullSegmentation`, which is a :class:`~.segmentation.Segmentation` whose ``mask`` is the
skull's filled outer *envelope*: so the skull becomes a second PDE surface by exactly the skin's path (paper
eq. 22 boundary curves, section 4.1 slice choice, eq. 1-13 patches)::

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
   spike) and its bloom, the bone within 3 mm of it, are removed
   (:func:`~.skull_parts.metal_bloom`: a distance, so the grid's nodes do not decide it);
4. only bone inside the head mask counts: head holders, table and cradle arcs
   (the GE holder is above 300 HU and touches the head) lie outside the skin
   envelope that :func:`~.segmentation.segment_head` cleans;
5. components (26-connected): the largest is the cranium; every other component
   of at least ``min_component_mm3`` is kept (the mandible, which is separate at
   a bone level, nasal bones, teeth) except the cervical vertebrae (below the
   skull base and not in front of the cranium's centre);
6. enclosed cavities (diploe, closed sinuses) are filled (``bone``); the metal's
   streak artefacts that pass the bone level (loose straight pieces in the metal's
   slices pointing at it: :func:`~.skull_parts.metal_streaks`) are removed; then
   each slice's convex hull is the envelope (``mask``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage as ndi, sparse
from skimage.measure import marching_cubes

from ..core.ct_volume import CTVolume
from ..core.errors import SegmentationError
from ..core.mesh import Mesh
from ..core.mesh_geometry import signed_volume
from ..segment.segmentation import Segmentation, auto_window, segment_head
from .scan_contents import (  # noqa: F401
    PARTIAL_RAMUS_SIDE_MM,
    SKULL_ONLY_LAYER_RATIO,
    air_bone_level,
    partial_mandible,
    soft_tissue_present,
)
from .skull_parts import bone_parts, give_back_rim, mandible_report, metal_bloom, metal_streaks, rami_in_the_bone
from .value_levels import METAL_HU, SATURATION_MIN_HU, bone_mode, half_maximum_level, metal_level, smoothed_histogram  # noqa: F401

#: HU assigned to the air and soft-tissue modes when the scan is not calibrated.
AIR_HU, TISSUE_HU = -1000.0, 40.0
#: Bone level (HU) when the histogram has no bone mode of its own.
DEFAULT_BONE_HU = 400.0
#: The bone level is kept in this HU range (below it: cartilage, contrast; above it: the outer table is lost).
BONE_LEVEL_RANGE_HU = (250.0, 700.0)
#: A calibrated scan's given (or default) level is raised to the bone's half-maximum level when it lies more than this
#: (HU) below it: within it the surface moves by less than 0.1 mm (CThead: 86 units, 0.15 mm median).
SURFACE_MARGIN_HU = 50.0
#: Smallest bone component kept besides the cranium (mm^3).
MIN_COMPONENT_MM3 = 200.0


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
    mandible : ndarray of bool or None
        The mandible's voxels (part of ``bone``) when one was found.
    bone_level, metal_level : float
        HU levels used (bone: the iso-level of :func:`skull_mesh`).
    """

    bone: np.ndarray | None = None
    mandible: np.ndarray | None = None
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


def bone_level_rule(hu: np.ndarray, head: np.ndarray | None = None, bins_hu: float = 10.0) -> tuple[float, dict]:
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
    centres, smooth = smoothed_histogram(values, edges)
    soft = (centres > -150) & (centres < 200)
    tissue = float(centres[soft][np.argmax(smooth[soft])])
    info: dict[str, Any] = {"tissue_mode": tissue, "bone_mode": None, "source": "default"}
    level = DEFAULT_BONE_HU
    mode = bone_mode(centres, smooth, tissue)
    if mode is not None:
        info["bone_mode"] = mode
        info["source"] = "histogram"
        level = 0.5 * (tissue + mode)
    lo, hi = BONE_LEVEL_RANGE_HU
    info["unclamped"] = level
    return float(min(max(level, lo), hi)), info


#: The histogram rule, under its old name.
bone_level = bone_level_rule


def _to_stored(value_hu: float, calibrated: bool, window) -> float:
    if calibrated:
        return float(value_hu)
    low, high = float(window[0]), float(window[1])
    return float(low + (value_hu - AIR_HU) * (high - low) / (TISSUE_HU - AIR_HU))


def _to_hu(value: float, calibrated: bool, window) -> float | None:
    if calibrated:
        return float(value)
    if window is None:
        return None
    low, high = float(window[0]), float(window[1])
    return float(AIR_HU + (value - low) * (TISSUE_HU - AIR_HU) / (high - low))


def segment_skull(ct: CTVolume, head: Segmentation | None = None, *, level: float | None = None,
                  bone_level: float | None = None, min_component_mm3: float = MIN_COMPONENT_MM3) -> SkullSegmentation:
    """Segment the skull (cranium, facial skeleton, mandible) from a head CT, or from a skull alone.

    From the bone level on, the skull comes from the binary bone mask ``ct.data >= level`` alone (in the
    scan's stored units): a CT and the same CT with every voxel below the level set to air give the same
    skull. Soft tissue, when there is any, only serves to find the default level.

    The level (stored units; :data:`DEFAULT_BONE_HU` and the rules below are documented in docs/forensic_guide.md):

    * ``bone_level`` given (``--bone-level``): that, but in a calibrated scan not below the bone's half-maximum
      level (:func:`~.value_levels.half_maximum_level` of the skull's voxels at the given level, with
      :data:`TISSUE_HU`) by more than :data:`SURFACE_MARGIN_HU`: the skull is then made again at that level, with a
      warning (a skull-only scan stripped at 250 HU, run at it: the surface 0.6 mm out, the bite and the joints
      joined);
    * HU-calibrated scans: half way between the soft-tissue mode and the bone mode of the head's histogram
      (the 50 % partial-volume level), kept within ``BONE_LEVEL_RANGE_HU``; ``DEFAULT_BONE_HU`` when the
      bone has no mode of its own or there is no soft tissue (:func:`soft_tissue_present`: the layer under
      the scan's surfaces is bone, not soft tissue), then raised to the half-maximum level as a given level is;
    * uncalibrated scans with soft tissue: the same rule on the pseudo-HU scale (air and soft-tissue modes
      mapped to -1000 / +40 HU), converted back to stored units;
    * uncalibrated scans without soft tissue: :func:`air_bone_level` (half way between the air and the
      bone modes).

    Then: metal and its bloom removed (above ``METAL_HU`` or the saturation spike, and the bone within
    :data:`~.skull_parts.METAL_BLOOM_MM` of it); components of the bone eroded by
    one voxel (26-connected); the largest is the cranium; the others are kept when at least
    ``min_component_mm3``, not a cervical vertebra, and inside the cranium's box grown by
    ``SUPPORT_MARGIN_MM`` (below it by ``MANDIBLE_BELOW_MM``): supports, foam, the table, holders and loose
    fragments lie outside or are small; the metal's streaks that pass the bone level are dropped
    (:func:`~.skull_parts.metal_streaks`). The mandible is reported (``meta["mandible"]``: present,
    articulated, the condyle gap), with a warning when it is missing or not articulated.

    Parameters
    ----------
    ct : CTVolume
    head : Segmentation, optional
        The head segmentation of the same CT (its window and mask give the default level).
    level : float, optional
        Bone level in HU (pseudo-HU for uncalibrated scans).
    bone_level : float, optional
        Bone level in the scan's stored units (overrides ``level``).
    min_component_mm3 : float
        Smaller bone fragments are dropped.

    Returns
    -------
    SkullSegmentation
        ``mask`` = envelope (for :func:`~.boundaries.extract_boundaries`), ``bone``, ``hu``,
        ``bone_level`` (HU, estimated for uncalibrated scans), ``metal_level``; ``meta`` with the stored
        level and its source, ``has_skin``, the components kept and dropped, ``mandible`` and ``warnings``.

    Raises
    ------
    SegmentationError
        Not a CTVolume, MR data, no bone above the level.
    """
    sk = _segment_skull(ct, head, level=level, bone_level=bone_level, min_component_mm3=min_component_mm3)
    m = sk.meta
    if not m["calibrated"] or m.get("skull_mesh_file") or not (
            bone_level is not None or str(m["bone_level_source"]).startswith("default")):
        return sk
    values = ct.data[sk.bone]
    surface = half_maximum_level(values[values >= np.float32(m["bone_level_stored"])], TISSUE_HU, BONE_LEVEL_RANGE_HU)
    if surface is None or surface[0] <= m["bone_level_stored"] + SURFACE_MARGIN_HU:
        return sk
    given = m["bone_level_stored"]
    again = _segment_skull(ct, head, level=None, bone_level=surface[0], min_component_mm3=min_component_mm3)
    again.meta.update(bone_level_source=f"half maximum (bone mode {surface[1]:.0f} HU), above "
                      + (f"the given level {given:g}" if bone_level is not None else f"the default {given:g}"),
                      bone_level_below=float(given), bone_mode=surface[1])
    again.meta["histogram"] = dict(again.meta["histogram"], source=again.meta["bone_level_source"],
                                   bone_mode=surface[1], tissue_mode=TISSUE_HU)
    what = f"bone_level={given:g}" if bone_level is not None else f"the default bone level ({given:g} HU)"
    again.meta["warnings"] = [f"{what} lies below the bone's half-maximum surface: the skull is made at "
                              f"{surface[0]:.0f} HU, half way between soft tissue ({TISSUE_HU:g} HU) and the bone's "
                              f"mode ({surface[1]:.0f} HU); a lower level stands the bone's surface out and joins the "
                              "teeth and the joints"] + list(again.meta["warnings"])
    return again


def _segment_skull(ct: CTVolume, head: Segmentation | None, *, level: float | None, bone_level: float | None,
                   min_component_mm3: float) -> SkullSegmentation:
    """:func:`segment_skull` at one level (its rules, without the half-maximum check)."""
    _check_skull_input(ct, head)
    calibrated = str(ct.meta.get("units", "")).upper() == "HU"
    has_skin, skin_info = soft_tissue_present(ct.data, spacing=ct.spacing, calibrated=calibrated)
    if ct.meta.get("skull_mesh") is not None:          # a skull given as a mesh (mesh_input): no skin
        has_skin = False
    window = tuple(head.meta["window"]) if head is not None and head.meta.get("window") else None
    if window is None and has_skin and not calibrated:
        window = auto_window(ct.data)
    units = "HU" if calibrated else "stored"
    stored, info, window = _stored_bone_level(ct, head, window, calibrated, has_skin, skin_info, level, bone_level)
    level_hu = _to_hu(stored, calibrated, window)
    metal_stored = metal_level(ct.data, calibrated)
    dz, dy, dx = ct.spacing
    voxel_mm3 = dz * dy * dx

    metal = ct.data >= np.float32(metal_stored) if np.isfinite(metal_stored) else np.zeros(ct.shape, bool)
    n_metal = int(np.count_nonzero(metal))
    if n_metal:
        metal = metal_bloom(metal, ct.spacing)
    bone = (ct.data >= np.float32(stored)) & ~metal
    del metal
    if not bone.any():
        raise SegmentationError(f"{ct.meta.get('source', 'the CT')}: nothing is above the bone level {stored:g} "
                                f"({units})")
    # joints and tooth contacts at partial volume (atlanto-occipital, TMJ, closed bite) join the vertebrae or the
    # mandible to the cranium at the bone level; one voxel of erosion separates them (CThead at its own level)
    parts = bone_parts(bone, ct, 1, min_component_mm3, voxel_mm3)
    core, labels, n, sizes, boxes, cranium, centroids_xyz, big, vertebra, outside, keep, crbox = (
        parts[k] for k in ("core", "labels", "n", "sizes", "boxes", "cranium", "centroids_xyz", "big", "vertebra",
                           "outside", "keep", "crbox"))
    # give the eroded rim back to the component it came from (a few constrained label dilations)
    grown = give_back_rim(labels, bone, steps=parts["erosion"] + 2)
    mandible = mandible_report(labels, keep, sizes, centroids_xyz, cranium, ct, voxel_mm3, crbox, boxes,
                               bone_sizes=np.bincount(grown.reshape(-1), minlength=n + 1)[1:])
    dropped = bone & np.concatenate([[False], vertebra | outside])[grown]
    dropped_vertebra = int(np.count_nonzero(dropped & np.concatenate([[False], vertebra])[grown]))
    dropped_support = int(np.count_nonzero(dropped)) - dropped_vertebra
    rest, m = ndi.label(bone & ~dropped, structure=np.ones((3, 3, 3), bool))
    holds_kept = np.unique(rest[np.concatenate([[False], keep])[grown] & (rest > 0)])
    skull = np.isin(rest, holds_kept[holds_kept > 0])
    mandible_mask = (skull & np.isin(grown, mandible.get("components", [mandible.get("component")]))) \
        if mandible["present"] else None
    if not mandible["present"]:
        # thin rami cut by the scan's end break into pieces when eroded (CThead cut below the teeth at its own
        # level): look for them in the bone itself, less the cranium's grown core
        mandible, mandible_mask = rami_in_the_bone(bone & ~dropped, grown == cranium, ct, min_component_mm3)
        if mandible_mask is not None:
            skull |= mandible_mask
    erosion, spine_split = parts["erosion"], parts["spine_split"]
    del labels, grown, rest, core, parts
    skull = ndi.binary_fill_holes(skull)
    streaks, streak_pieces = (metal_streaks(skull, ct.data >= np.float32(metal_stored), ct.spacing,
                                            keep=mandible_mask) if n_metal else (None, 0))
    if streak_pieces:
        skull &= ~streaks
        if mandible_mask is not None:
            mandible_mask &= ~streaks
    n_streak = int(np.count_nonzero(streaks)) if streak_pieces else 0
    del streaks
    envelope = _envelope(skull)

    warnings_ = _mandible_warnings(mandible)
    hu = hounsfield(ct, window)[0] if (calibrated or window is not None) else ct.data
    order = np.argsort(sizes)[::-1]
    components = [dict(label=int(i + 1), volume_mm3=float(sizes[i] * voxel_mm3),
                       centroid_mm=[round(float(c), 1) for c in centroids_xyz[i]],
                       kept=bool(keep[i]), vertebra=bool(vertebra[i]), support=bool(outside[i])) for i in order[:12]]
    meta = dict(mode="skull", bone_level=level_hu, skull_mesh_file=ct.meta.get("skull_mesh_file"),
                bone_level_stored=float(stored), units=units,
                bone_level_source=info.get("source", ""), metal_level=metal_stored, calibrated=calibrated,
                histogram=info, has_skin=has_skin, soft_tissue=skin_info, metal_voxels=n_metal,
                components=components, components_total=int(n), erosion_voxels=erosion, spine_split=spine_split,
                metal_streak_voxels=n_streak, metal_streak_pieces=int(streak_pieces),
                kept_components=int(np.count_nonzero(keep)),
                dropped_vertebra_mm3=float(dropped_vertebra * voxel_mm3),
                dropped_support_mm3=float(dropped_support * voxel_mm3),
                dropped_small_mm3=float(sizes[~big].sum() * voxel_mm3),
                bone_mm3=float(np.count_nonzero(skull) * voxel_mm3), mandible=mandible, warnings=warnings_,
                window=list(window) if window is not None else None)
    level_report = level_hu if level_hu is not None else float(stored)
    return SkullSegmentation(mask=envelope, probability=envelope.astype(np.float32), c1=float(level_report),
                             c2=float(info.get("tissue_mode", TISSUE_HU) or TISSUE_HU),
                             iterations=0, ct=ct, meta=meta, bone=skull, mandible=mandible_mask, hu=hu,
                             bone_level=float(level_report),
                             metal_level=metal_stored)


def _check_skull_input(ct: CTVolume, head: Segmentation | None) -> None:
    """Raise :class:`SegmentationError` unless ``ct`` is a CT volume (not MR) and ``head`` (if any) matches it."""
    if not isinstance(ct, CTVolume):
        raise SegmentationError(f"segment_skull needs a CTVolume, got {type(ct).__name__}")
    if str(ct.meta.get("modality", "")).upper() in ("MR", "MRI"):
        raise SegmentationError(f"{ct.meta.get('source', 'this scan')}: bone is dark in MRI; the skull needs a CT")
    if head is not None and head.mask.shape != ct.shape:
        raise SegmentationError(f"head mask shape {head.mask.shape} != CT shape {ct.shape}")


def _stored_bone_level(ct: CTVolume, head: Segmentation | None, window: tuple | None, calibrated: bool,
                       has_skin: bool, skin_info: dict, level: float | None,
                       bone_level: float | None) -> tuple[float, dict[str, Any], tuple | None]:
    """The bone level in the scan's stored units by the rules of :func:`segment_skull`, the histogram information
    behind it (``"source"`` says which rule) and the window (the head segmentation's when it had to be made)."""
    if bone_level is not None:
        return float(bone_level), {"source": "given (--bone-level)"}, window
    if level is not None:
        if not calibrated and window is None:
            raise SegmentationError("a bone level in HU needs soft tissue to calibrate an uncalibrated scan; "
                                    "give it in stored units (--bone-level)")
        return _to_stored(level, calibrated, window), {"source": "given (HU)"}, window
    if has_skin:
        if head is None:
            head = segment_head(ct)
            window = window or tuple(head.meta["window"])
        hu_all, _ = hounsfield(ct, window)
        level_hu, info = bone_level_rule(hu_all, head.mask)
        del hu_all
        return _to_stored(level_hu, calibrated, window), info, window
    if calibrated:
        return DEFAULT_BONE_HU, {"source": "default (no soft tissue)"}, window
    stored, info = air_bone_level(ct.data, skin_info["air_split"])
    return stored, info, window


def _mandible_warnings(mandible: dict) -> list[str]:
    """The warnings of a mandible report (:func:`~.skull_parts.mandible_report`): missing, cut by the scan, or
    not articulated."""
    if not mandible["present"]:
        return ["no mandible found: the face has no jaw or chin and ends along the scan's cut"]
    if mandible.get("partial"):
        return ["the mandible is cut by the scan's end (its rami only): the landmarks below the scan are "
                "not found and the face ends along the scan's cut"]
    if not mandible["articulated"]:
        return [f"the mandible is not articulated (its condyles lie {mandible['condyle_gap_mm']:.0f} mm "
                "from the glenoid fossae): articulate it before approximating the face"]
    return []


def _envelope(bone: np.ndarray) -> np.ndarray:
    """Per axial slice the convex hull of the bone: the outer outline one closed curve per slice can follow.

    A closing cannot bridge the orbits (30-40 mm wide openings at eye level, CThead),
    so the per-slice envelope is the convex hull; at the vault it equals the filled
    outer table, at the face it closes over the orbits, the nasal aperture and the
    temporal fossae behind the zygomatic arches.
    """
    from skimage.morphology import convex_hull_image  # deferred: ~10 ms at `import pdehead_addon`

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


#: Slices this many times thicker than the pixels (or more) are interpolated before marching cubes.
THICK_SLICE_RATIO = 3.0
#: At most this many interpolated slices per slice step.
MAX_SLICE_UPSAMPLING = 4


def slice_upsampling(spacing) -> int:
    """How many sub-steps :func:`skull_mesh` divides each slice step into (1: none).

    Thick slices (step at least ``THICK_SLICE_RATIO`` times the pixel size; e.g. GE's 4-7 mm tilted
    slices over 0.5 mm pixels) leave terraces one slice high in a marching-cubes surface; thinner
    ones (CThead 2 x 1 mm, the phantom) are meshed as they are.
    """
    dz, dy, dx = (float(v) for v in spacing)
    ratio = dz / max(min(dy, dx), 1e-9)
    return 1 if ratio < THICK_SLICE_RATIO else int(min(MAX_SLICE_UPSAMPLING, round(ratio)))


def shape_based_upsample(mask: np.ndarray, factor: int, pixel_mm=(1.0, 1.0)) -> np.ndarray:
    """A binary stack with ``factor - 1`` slices interpolated between each two (shape-based).

    Shape-based interpolation (Raya & Udupa, IEEE Trans Med Imaging 9(1):32-42, 1990): each slice's
    in-plane signed distance to its mask's outline (mm; negative inside) is interpolated linearly
    between slices and thresholded at 0, so an outline moves smoothly from one slice to the next
    instead of stepping half way between them. Returns ``(n - 1) * factor + 1`` slices; slice
    ``k * factor`` is input slice ``k``.
    """
    mask = np.asarray(mask, bool)
    n = mask.shape[0]
    far = 1e3
    sd = np.empty(mask.shape, np.float32)
    for k in range(n):                                  # per slice (tens of slices), 2-D transforms
        m = mask[k]
        if not m.any():
            sd[k] = far
        elif m.all():
            sd[k] = -far
        else:
            sd[k] = (ndi.distance_transform_edt(~m, sampling=pixel_mm)
                     - ndi.distance_transform_edt(m, sampling=pixel_mm))
    out = np.empty(((n - 1) * factor + 1,) + mask.shape[1:], bool)
    out[::factor] = mask
    for j in range(1, factor):
        w = j / factor
        out[j::factor] = ((1.0 - w) * sd[:-1] + w * sd[1:]) < 0.0
    return out


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
    given = skull.ct.meta.get("skull_mesh") if skull.ct is not None else None
    if isinstance(given, Mesh) and len(given.triangles) <= max_triangles:
        return given                                   # the skull given as a mesh is the skull itself
    if skull.bone is None:
        raise SegmentationError("skull_mesh needs the result of segment_skull (the bone mask)")
    bone = skull.bone
    box = ndi.find_objects(bone.astype(np.uint8))
    if not box or box[0] is None:
        raise SegmentationError("the skull segmentation has no bone")
    box = tuple(slice(max(0, s.start - 2), s.stop + 2) for s in box[0])
    sub = bone[box]
    factor = slice_upsampling(skull.ct.spacing)
    if factor > 1:
        sub = shape_based_upsample(sub, factor, skull.ct.spacing[1:])
    field = ndi.gaussian_filter(sub.astype(np.float32), SKULL_MASK_SIGMA)
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
        # more passes do not remove the terraces of thick slices (GE) but let the two sides of thin slits
        # meet: coincident vertices, which an STL reader merges into a non-manifold surface
        verts = taubin_smooth(verts, faces, passes=int(smoothing_passes))
    if factor > 1:                                   # upsampled slice index -> the CT's slice index
        verts[:, 0] = (verts[:, 0] - 2.0) / factor + 2.0
    pts = skull.ct.index_to_patient(verts + origin)
    mesh = Mesh(vertices=pts, quads=np.zeros((0, 4), np.int64), triangles=faces)
    if signed_volume(mesh) < 0:  # index (k, j, i) -> patient may flip handedness
        mesh.triangles = faces[:, ::-1].copy()
    mesh.vertex_attributes = {}
    return mesh


def taubin_smooth(vertices: np.ndarray, triangles: np.ndarray, passes: int = 8, lam: float = 0.5,
                  mu: float = -0.53) -> np.ndarray:
    """Taubin's lambda/mu smoothing (Taubin, SIGGRAPH 1995) with the umbrella operator; vertices only.

    Each pass moves every vertex by ``lam`` then ``mu`` times the mean of its neighbours minus itself
    (a low-pass filter that does not shrink the surface as repeated Laplacian smoothing does).
    """
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
