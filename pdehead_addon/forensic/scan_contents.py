"""What a head CT holds: soft tissue or a skull alone (:func:`soft_tissue_present`), the bone level of a skull alone
(:func:`air_bone_level`), and a mandible cut by the scan's end (:func:`partial_mandible`); used by
:func:`~.skull.segment_skull`, in any units (HU, a scanner's raw values, 8 bits).
"""
from __future__ import annotations

from typing import Any

import numpy as np
from scipy import ndimage as ndi
from skimage.filters import threshold_otsu

from ..core.errors import SegmentationError


def _x_extent(ct, box) -> np.ndarray:
    """Patient x (mm) of an index box's (slices k, j, i) lowest and highest column corners."""
    corners = np.array([[b.start for b in box], [b.stop - 1 for b in box]], float)
    kji = np.array(np.meshgrid(*corners.T, indexing="ij")).reshape(3, -1).T
    x = ct.index_to_patient(kji)[:, 0]
    return np.array([x.min(), x.max()])


def soft_tissue_present(data: np.ndarray, split: float | None = None, spacing=(1.0, 1.0, 1.0),
                        calibrated: bool = False) -> tuple[bool, dict[str, Any]]:
    """Whether the scan has soft tissue around the bone (a head CT) or is a skull alone (a dry skull, or soft
    tissue removed: every voxel below a bone level set to air), whatever part of the head it covers and in
    any units.

    Rule: the layer under every surface of the non-air voxels (above the histogram's air/rest split,
    :func:`_air_split`), ``SOFT_TISSUE_LAYER_MM`` deep in the slice's plane (past the partial-volume voxel
    at the surface), is soft tissue in a head (skin, fat, muscle, mucosa) and bone in a skull alone. Its
    median value is placed between the air mode and the bright end of the non-air values (their
    ``SOFT_TISSUE_BRIGHT_PERCENTILE``-th percentile: dense bone):

        layer_ratio = (median(layer) - air) / (bright - air)

    Soft tissue lies about 1040 HU above air and dense bone 1000-2500 HU above soft tissue, so a head gives
    0.3-0.5; the layer of a skull alone is bone, 0.7 and more. The ratio is the same in HU, in a scanner's
    raw units or in 8 bits (any linear map of the values). Soft tissue is present when the ratio is below
    ``SKULL_ONLY_LAYER_RATIO``. Unlike the braincase's fill (``fill_ratio``: the non-air voxels filled
    per slice grow 2-3x in a skull alone, reported), it does not need the vault in the scan.

    In a calibrated scan (HU) soft tissue must also hold its own values: at least ``SOFT_TISSUE_MIN_SHARE`` of the
    non-air voxels (above ``-500`` HU) lie in ``SOFT_TISSUE_HU``, soft tissue's range (fat, muscle, skin, brain). A
    head's soft tissue and brain fill most of its non-air voxels; a skull stripped at any level above soft tissue
    keeps none of them, and a dry skull only the partial volume at its edges. The layer alone can take a skull for
    a head where its bone is thin and blurred: CThead in HU, resliced to 1.5 mm slabs, cropped to the skull base and
    face and stripped at 150 HU, has a layer ratio of 0.55 (its maxilla's and orbits' walls are thinner than the
    layer is deep) and a soft-tissue share of 0.000.

    Parameters
    ----------
    data : ndarray (nz, ny, nx)
    split : float, optional
        The air/rest split (default: Otsu's, :func:`_air_split`).
    spacing : (dz, dy, dx) mm
    calibrated : bool
        The values are HU: the soft-tissue share is checked too.

    Returns
    -------
    (present, info)
        ``info``: ``layer_ratio`` (None: no layer that deep) and its ``layer_ratio_limit``; calibrated,
        ``soft_tissue_share``, its ``soft_tissue_share_limit`` and ``soft_tissue_hu``;
        ``layer_median``, ``air_mode``, ``bright_end`` (stored units), ``fill_ratio`` and ``air_split``.
    """
    split = _air_split(data) if split is None else split
    solid = data > np.float32(split)
    n = int(np.count_nonzero(solid))
    info: dict[str, Any] = {"air_split": split, "fill_ratio": None, "layer_ratio": None,
                            "layer_ratio_limit": SKULL_ONLY_LAYER_RATIO}
    if n == 0:
        return False, info
    info["fill_ratio"] = round((n + _enclosed_per_slice(solid)) / n, 3)
    ratio, layer_info = _surface_layer_ratio(data, solid, spacing)
    info.update(layer_info)
    if calibrated:
        share = soft_tissue_share(data)
        info["soft_tissue_share"] = round(share, 3)
        info["soft_tissue_share_limit"], info["soft_tissue_hu"] = SOFT_TISSUE_MIN_SHARE, list(SOFT_TISSUE_HU)
        if share < SOFT_TISSUE_MIN_SHARE:
            return False, info
    if ratio is None:                      # no layer that deep (bone thinner than the layer): no soft tissue
        return False, info
    return bool(ratio < SKULL_ONLY_LAYER_RATIO), info


def soft_tissue_share(hu: np.ndarray) -> float:
    """The share of a calibrated scan's non-air voxels (above -500 HU, half way from air to water) whose values lie
    in ``SOFT_TISSUE_HU`` (0 when there are none)."""
    sample = hu.reshape(-1)[:: max(1, hu.size // 4_000_000)]
    body = sample[sample > np.float32(-500.0)]
    if body.size == 0:
        return 0.0
    lo, hi = SOFT_TISSUE_HU
    return float(np.count_nonzero((body >= np.float32(lo)) & (body <= np.float32(hi)))) / body.size


def _surface_layer_ratio(data: np.ndarray, solid: np.ndarray, spacing) -> tuple[float | None, dict]:
    """(layer_ratio, info) of :func:`soft_tissue_present`; the layer from at most ``SOFT_TISSUE_LAYER_SLICES``
    slices evenly spread over the scan (per-slice 2-D distance transforms)."""
    # pixels finer than 1 mm are read every few (the layer is 1.5 mm thick): a quarter of the transforms' work
    stride = max(1, int(round(1.0 / max(min(float(spacing[1]), float(spacing[2])), 1e-6))))
    dy, dx = stride * float(spacing[1]), stride * float(spacing[2])
    lo, hi = SOFT_TISSUE_LAYER_MM
    occupied = np.flatnonzero(solid.any(axis=(1, 2)))
    ks = occupied[np.unique(np.linspace(0, len(occupied) - 1, min(len(occupied), SOFT_TISSUE_LAYER_SLICES))
                            .round().astype(int))]
    layer = []
    for k in ks:                                        # tens of slices, each one 2-D transform
        depth = ndi.distance_transform_edt(solid[k, ::stride, ::stride], sampling=(dy, dx))
        layer.append(data[k, ::stride, ::stride][(depth > lo) & (depth <= hi)])
    layer = np.concatenate(layer) if layer else np.zeros(0, np.float32)
    sample = data.reshape(-1)[:: max(1, data.size // 4_000_000)]
    keep = solid.reshape(-1)[:: max(1, data.size // 4_000_000)]
    air_values, body = sample[~keep], sample[keep]
    if layer.size < SOFT_TISSUE_MIN_LAYER or air_values.size == 0 or body.size == 0:
        return None, {"layer_voxels": int(layer.size)}
    hist, edges = np.histogram(air_values, bins=256)
    k = int(np.argmax(hist))
    air = 0.5 * float(edges[k] + edges[k + 1])
    bright = float(np.percentile(body, SOFT_TISSUE_BRIGHT_PERCENTILE))
    median = float(np.median(layer))
    if not bright > air:
        return None, {"layer_voxels": int(layer.size)}
    ratio = (median - air) / (bright - air)
    return ratio, {"layer_ratio": round(ratio, 3), "layer_median": median, "air_mode": air, "bright_end": bright,
                   "layer_voxels": int(layer.size)}


def _enclosed_per_slice(solid: np.ndarray) -> int:
    """Number of voxels not in ``solid`` that no in-slice path connects to the slice's border (holes)."""
    in_plane = np.zeros((3, 3, 3), bool)
    in_plane[1] = ndi.generate_binary_structure(2, 1)
    labels, n = ndi.label(~solid, structure=in_plane)
    border = np.zeros(n + 1, bool)
    for edge in (labels[:, 0, :], labels[:, -1, :], labels[:, :, 0], labels[:, :, -1]):
        border[np.unique(edge)] = True
    border[0] = True
    return int(np.count_nonzero(~border[labels]))


def _air_split(data: np.ndarray) -> float:
    """Otsu's split of the histogram (of a subsample): air below, everything else above."""
    sample = data.reshape(-1)[:: max(1, data.size // 2_000_000)]
    return float(threshold_otsu(sample[np.isfinite(sample)]))


#: The layer under the non-air voxels' surfaces that :func:`soft_tissue_present` reads (mm from the surface, in
#: the slice's plane): past the partial-volume voxel, within the thinnest skin over bone (forehead, nasion:
#: 3-6 mm, T-Table 2023).
SOFT_TISSUE_LAYER_MM = (1.5, 3.0)
#: The bright end of the non-air values (percentile): dense bone in a head and in a skull alone.
SOFT_TISSUE_BRIGHT_PERCENTILE = 99.0
#: Soft tissue is present when the layer's median lies less than this fraction of the way from air to the bright
#: end (a head: soft tissue, ~1040 HU above air against dense bone 2000-3500 HU above it). Chosen half way between
#: the heads and the skulls measured: CThead (raw and 8-bit), GE and the phantom, whole or cropped to the skull
#: base and face, 0.39-0.44; the three stripped at 250-1600 (HU or stored), whole or cropped, 0.70-0.87.
SKULL_ONLY_LAYER_RATIO = 0.57
#: Soft tissue's values (HU): fat about -100, muscle, skin and brain 20-80 (the Hounsfield scale's tissues; 50 HU of
#: noise either side).
SOFT_TISSUE_HU = (-200.0, 100.0)
#: A calibrated scan holds soft tissue only when at least this share of its non-air voxels lies in SOFT_TISSUE_HU.
#: Measured: heads (CThead given in HU, whole, resliced to 1.5 mm, cropped to the skull base and face or to the face;
#: GE; the phantom) 0.56-0.71; the same stripped at 100-250 HU at most 0.004; a dry skull, simulated by blurring
#: those stripped at 250 HU by 0.7-1.5 voxels (plus 15 HU of noise), 0.07-0.28. Chosen between the two (0.28 and
#: 0.56). A scan stripped just above soft tissue (60 HU: 0.15-0.39) has lost its fat and most of its skin: a
#: skull alone too.
SOFT_TISSUE_MIN_SHARE = 0.4
#: At most this many slices (evenly spread) give the layer; a layer of fewer voxels says nothing (no soft tissue).
SOFT_TISSUE_LAYER_SLICES = 32
SOFT_TISSUE_MIN_LAYER = 200


def air_bone_level(data: np.ndarray, split: float | None = None, bins: int = 256) -> tuple[float, dict]:
    """Bone level (stored units) of a scan without soft tissue: half way between the air and bone modes.

    The 50 % partial-volume level of an air/bone interface. The modes are the histogram maxima below and
    above Otsu's split (:func:`_air_split`); needs no soft-tissue mode, and no calibration.
    """
    split = _air_split(data) if split is None else split
    sample = data.reshape(-1)[:: max(1, data.size // 4_000_000)]
    sample = sample[np.isfinite(sample)]
    out = {}
    for name, part in (("air_mode", sample[sample <= split]), ("bone_mode", sample[sample > split])):
        if part.size == 0:
            raise SegmentationError("the scan has no air/bone contrast to find a bone level from")
        hist, edges = np.histogram(part, bins=bins)
        smooth = ndi.gaussian_filter1d(hist.astype(np.float64), 2.0)
        k = int(np.argmax(smooth))
        out[name] = float(0.5 * (edges[k] + edges[k + 1]))
    level = 0.5 * (out["air_mode"] + out["bone_mode"])
    out.update(source="air/bone rule", split=split)
    return float(level), out


#: A mandible cut by the scan's end (a scan ending at the teeth) is its rami: components reaching the scan's lowest
#: ``PARTIAL_END_SLICES`` slices, below the cranium's centre, in front of it and at least ``PARTIAL_RAMUS_SIDE_MM``
#: either side of its midline (the rami stand 45-55 mm from it, CThead; a vertebra or the upper jaw's pieces lie
#: within 25 mm).
PARTIAL_END_SLICES = 2
PARTIAL_RAMUS_SIDE_MM = 30.0
#: ... and more than this (mm) in front of the cranium's centre: the cervical vertebrae lie less far in front of it
#: (``skull.VERTEBRA_FRONT_MM``; the atlas's transverse processes span 70-80 mm, as wide as the rami).
PARTIAL_FRONT_MM = 35.0


def _condyle_gap(core_labels, part: int, cranium: int, ct, boxes, gap_mm: float) -> float:
    """The distance (mm) from the top 15 % of a component (its condyle) to the cranium, within 3 x ``gap_mm``
    (farther: that bound)."""
    pad = np.ceil(3 * gap_mm / np.asarray(ct.spacing)).astype(int)
    box = tuple(slice(max(0, b.start - p), min(n, b.stop + p)) for b, p, n in zip(boxes[part - 1], pad, ct.shape))
    sub = core_labels[box]
    if not (sub == cranium).any():
        return float(3 * gap_mm)
    kji = np.argwhere(sub == part)
    z = ct.index_to_patient((kji + [b.start for b in box]).astype(float))[:, 2]
    top = kji[z >= z.max() - 0.15 * np.ptp(z)]
    dist = ndi.distance_transform_edt(sub != cranium, sampling=ct.spacing)
    return float(dist[tuple(top.T)].min())


def partial_mandible(core_labels, keep, sizes, centroids_xyz, cranium: int, ct, voxel_mm3: float, boxes,
                     gap_mm: float) -> dict:
    """A mandible cut by the scan's lower end: a ramus on each side of the cranium's midline, each reaching the
    scan's end (or one piece reaching it that spans both sides), its condyles articulated (within
    ``gap_mm`` of the cranium); ``present`` False when there is none (the scan ends above the
    mandible, or there is no mandible)."""
    up = float(ct.direction[2, 2]) >= 0
    nz = ct.shape[0]
    cc = centroids_xyz[cranium - 1]
    sides: dict[int, list[int]] = {1: [], -1: []}
    across = []                           # a body cut below the teeth: one piece from one ramus to the other
    for i in np.flatnonzero(keep):
        if i == cranium - 1:
            continue
        b = boxes[i][0]
        at_end = b.start < PARTIAL_END_SLICES if up else b.stop > nz - PARTIAL_END_SLICES
        if not at_end or centroids_xyz[i, 2] >= cc[2] or centroids_xyz[i, 1] > cc[1] - PARTIAL_FRONT_MM:
            continue
        dx = centroids_xyz[i, 0] - cc[0]
        x0, x1 = _x_extent(ct, boxes[i]) - cc[0]
        if abs(dx) >= PARTIAL_RAMUS_SIDE_MM:
            sides[int(np.sign(dx))].append(int(i))
        elif x0 <= -PARTIAL_RAMUS_SIDE_MM and x1 >= PARTIAL_RAMUS_SIDE_MM:
            across.append(int(i))
    if across:
        parts = [max(across, key=lambda i: sizes[i])]
        sides = {1: parts, -1: []}
    elif not sides[1] or not sides[-1]:
        return {"present": False, "articulated": None}
    else:
        parts = [max(sides[s], key=lambda i: sizes[i]) for s in (1, -1)]
    gaps = [_condyle_gap(core_labels, i + 1, cranium, ct, boxes, gap_mm) for i in parts]
    if max(gaps) > gap_mm:
        return {"present": False, "articulated": None}
    parts = sides[1] + sides[-1]
    volume = float(sum(sizes[i] for i in parts) * voxel_mm3)
    return {"present": True, "partial": True, "articulated": True, "condyle_gap_mm": round(max(gaps), 1),
            "volume_mm3": volume, "component": int(parts[0] + 1), "components": [int(i + 1) for i in parts],
            "centroid_mm": [round(float(c), 1) for c in np.mean(centroids_xyz[parts], axis=0)]}
