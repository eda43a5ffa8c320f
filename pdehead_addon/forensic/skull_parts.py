"""The skull's bone parts: components of the bone eroded by one voxel, the cranium, the mandible and its
rami, and what is not skull (cervical vertebrae, supports, holders, loose fragments).

:func:`~.skull.segment_skull` keeps the parts :func:`bone_parts` finds; the landmark frame separates the
bone by the same components (:func:`eroded_components`, :func:`give_back_rim`).
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi

from ..core.ct_volume import CTVolume
from .scan_contents import PARTIAL_RAMUS_SIDE_MM, partial_mandible

__all__ = ["eroded_components", "give_back_rim", "rami_in_the_bone", "bone_parts", "mandible_report",
           "split_spine_from_cranium", "metal_bloom", "metal_streaks", "joined_metal_streaks", "STREAK_ELONGATION",
           "SPOKE_LENGTH_MM", "SPOKE_WIDTH_MM", "SPOKE_REACH_MM", "STREAK_AIM_MM", "STREAK_MIN_LENGTH_MM",
           "VERTEBRA_FRONT_MM", "ARTICULATED_GAP_MM", "MANDIBLE_MIN_MM3", "METAL_BLOOM_MM"]

#: Bone within this distance (mm) of the metal is taken for the metal's bloom, not bone (see :func:`metal_bloom`).
METAL_BLOOM_MM = 3.0


#: A loose piece is a streak when its in-plane length is at least this many times its width.
STREAK_ELONGATION = 2.0
#: ... and its long axis, extended, passes within this (mm, or its own width when wider) of the metal.
STREAK_AIM_MM = 2.0
#: ... and it is at least this long (mm; shorter bits beside a filling may be the tooth's own edge).
STREAK_MIN_LENGTH_MM = 5.0

#: A streak joined to the bone (a spoke leaving a filling) is straight for at least this long (mm) along the line
#: through the metal ...
SPOKE_LENGTH_MM = 8.0
#: ... and narrower than this across it (mm; a streak is one or two pixels wide, a tooth or a jaw's body wider) ...
SPOKE_WIDTH_MM = 3.0
#: ... within this (mm) of the metal in its slice (CThead: the fans reach the cheeks, 20-45 mm from the molars).
SPOKE_REACH_MM = 50.0

#: A bone component below the skull base whose centroid is less than this (mm) in front of the
#: cranium's centroid is a cervical vertebra (CThead: C2 31 mm; mandibles: phantom 40, CThead 100 mm).
VERTEBRA_FRONT_MM = 35.0


def eroded_components(bone: np.ndarray, erosion: int = 1) -> tuple[np.ndarray, np.ndarray, int]:
    """The components of the bone eroded by ``erosion`` voxels (a joint or a tooth contact at partial volume no
    longer joins them; thicker bone stays whole): (the eroded core, or the bone when nothing is left; its labels;
    their count)."""
    core = ndi.binary_erosion(bone, structure=ndi.generate_binary_structure(3, 1), iterations=int(erosion))
    if not core.any():
        core = bone
    labels, n = ndi.label(core, structure=np.ones((3, 3, 3), bool))
    return core, labels, n


def give_back_rim(labels: np.ndarray, bone: np.ndarray, steps: int = 3) -> np.ndarray:
    """The labels of :func:`eroded_components` with the eroded rim given back to the component next to it
    (``steps`` label dilations constrained to ``bone``)."""
    full = np.ones((3, 3, 3), bool)
    for _ in range(steps):
        spread = ndi.grey_dilation(labels, footprint=full)
        labels = np.where(bone & (labels == 0), spread, labels)
    return labels


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


#: Bone components outside the cranium's box grown by this (mm; x and y; and below it by
#: MANDIBLE_BELOW_MM) are supports, table, holders or loose fragments, not skull.
SUPPORT_MARGIN_MM = 10.0
#: ... or reaching beyond that box by more than this (mm).
SUPPORT_REACH_MM = 20.0
MANDIBLE_BELOW_MM = 90.0
#: A separate component of at least this volume (mm^3), below the cranium's centre and in front of it, is
#: the mandible (phantom 40 cm^3, CThead 60 cm^3; loose teeth and the hyoid are far smaller).
MANDIBLE_MIN_MM3 = 8000.0
#: The mandible is articulated when its condyles (its top 15 % of height behind its centre) lie within
#: this distance (mm) of the cranium (the glenoid fossae; measured on the bone eroded by one voxel: CThead,
#: articulated, 6.7 mm); a dry mandible set apart lies farther.
ARTICULATED_GAP_MM = 12.0


#: Voxels of growth (in the bone) that the cranium's core takes before the rami are looked for in the bone itself.
RAMI_CRANIUM_GROWTH = 3


def rami_in_the_bone(bone: np.ndarray, cranium: np.ndarray, ct: CTVolume,
                     min_component_mm3: float) -> tuple[dict, np.ndarray | None]:
    """A mandible cut by the scan's end found in the bone itself rather than in its eroded components: the
    components of ``bone`` outside ``cranium`` (the cranium's eroded core given its rim back; the condyles touch
    it at the glenoid fossae) are tried as :func:`~.scan_contents.partial_mandible`'s pieces, their condyles'
    gap to ``cranium``. Returns (the mandible's report, its mask or None)."""
    # the cranium's thin walls next to its core (the maxilla's, the pterygoid plates) go with it: a few
    # voxels more of constrained growth; the rami, 40 mm and more of bone below the condyles, stay
    for _ in range(RAMI_CRANIUM_GROWTH):
        cranium = cranium | (ndi.binary_dilation(cranium, structure=np.ones((3, 3, 3), bool)) & bone)
    free = bone & ~cranium
    pieces, m = ndi.label(free, structure=np.ones((3, 3, 3), bool))
    if m == 0:
        return {"present": False, "articulated": None}, None
    labels = np.where(cranium, 1, np.where(pieces > 0, pieces + 1, 0)).astype(np.int32)
    del pieces, free
    n = m + 1
    sizes = np.bincount(labels.reshape(-1), minlength=n + 1)[1:]
    boxes = ndi.find_objects(labels)
    voxel_mm3 = float(np.prod(ct.spacing))
    centroids_xyz = ct.index_to_patient(np.array(ndi.center_of_mass(labels > 0, labels, np.arange(1, n + 1)))
                                        .reshape(n, 3))
    keep = sizes * voxel_mm3 >= float(min_component_mm3)
    keep[0] = True
    report = partial_mandible(labels, keep, sizes, centroids_xyz, 1, ct, voxel_mm3, boxes, ARTICULATED_GAP_MM)
    if not report["present"]:
        return report, None
    # the rami, less what a closed bite joins to them (the upper molars, the maxilla's tuberosity nearer the midline)
    mask = np.isin(labels, report["components"])
    kji = np.argwhere(mask)
    x = ct.index_to_patient(kji.astype(float))[:, 0]
    mask[tuple(kji[np.abs(x - centroids_xyz[0, 0]) < PARTIAL_RAMUS_SIDE_MM].T)] = False
    report.update(found_in="the bone (its eroded pieces too small): the rami beyond "
                           f"{PARTIAL_RAMUS_SIDE_MM:g} mm of the midline",
                  volume_mm3=float(np.count_nonzero(mask) * voxel_mm3))
    return report, mask


def _box_mm(ct: CTVolume, box) -> np.ndarray:
    """(2, 3) patient min/max corners (x, y, z) of an index box (slices k, j, i)."""
    corners = np.array([[s.start for s in box], [s.stop - 1 for s in box]], float)
    kji = np.array(np.meshgrid(*corners.T, indexing="ij")).reshape(3, -1).T
    xyz = ct.index_to_patient(kji)
    return np.stack([xyz.min(0), xyz.max(0)])


def mandible_report(core_labels, keep, sizes, centroids_xyz, cranium: int, ct: CTVolume, voxel_mm3: float,
                     crbox: np.ndarray, boxes, bone_sizes: np.ndarray | None = None) -> dict:
    """The mandible: found (a separate component below and in front of the cranium) and articulated.

    ``sizes`` are the eroded cores' voxel counts; ``bone_sizes``, when given, each component's with its rim given
    back (:func:`give_back_rim`), which the mandible's least volume is checked on: a voxel's erosion takes a share of
    a thin bone that grows with the voxel (CThead's mandible in 3 mm slabs keeps a core of 8.5 cm^3, just over
    :data:`MANDIBLE_MIN_MM3`, and 7.9 once the metal's bloom took its fillings' teeth)."""
    cc = centroids_xyz[cranium - 1]
    volume = sizes if bone_sizes is None else bone_sizes
    cand = [i for i in np.flatnonzero(keep) if i != cranium - 1 and volume[i] * voxel_mm3 >= MANDIBLE_MIN_MM3
            and centroids_xyz[i, 2] < cc[2] and centroids_xyz[i, 1] < cc[1]
            and centroids_xyz[i, 2] < crbox[0, 2] + 0.5 * (crbox[1, 2] - crbox[0, 2])]
    if not cand:
        return partial_mandible(core_labels, keep, sizes, centroids_xyz, cranium, ct, voxel_mm3, boxes,
                                ARTICULATED_GAP_MM)
    m = max(cand, key=lambda i: sizes[i])
    # work in the mandible's box grown by 3 * the articulation gap (the distance beyond it does not matter)
    pad = np.ceil(3 * ARTICULATED_GAP_MM / np.asarray(ct.spacing)).astype(int)
    box = tuple(slice(max(0, b.start - p), min(n, b.stop + p)) for b, p, n in zip(boxes[m], pad, ct.shape))
    sub = core_labels[box]
    offset = np.array([b.start for b in box])
    kji = np.argwhere(sub == m + 1)
    xyz = ct.index_to_patient((kji + offset).astype(float))
    ztop = xyz[:, 2].max() - 0.15 * np.ptp(xyz[:, 2])
    condyles = (xyz[:, 2] >= ztop) & (xyz[:, 1] > np.median(xyz[:, 1]))
    if not condyles.any():
        condyles = xyz[:, 2] >= ztop
    if not (sub == cranium).any():
        return {"present": True, "articulated": False, "condyle_gap_mm": float(3 * ARTICULATED_GAP_MM),
                "volume_mm3": float(sizes[m] * voxel_mm3), "component": int(m + 1),
                "centroid_mm": [round(float(c), 1) for c in centroids_xyz[m]]}
    dist = ndi.distance_transform_edt(sub != cranium, sampling=ct.spacing)
    pts = kji[condyles]
    # the nearest condyle voxel on each side of the mandible's centre
    x = xyz[condyles, 0]
    mid = float(np.median(xyz[:, 0]))
    gaps = [float(dist[tuple(pts[side].T)].min()) for side in (x < mid, x >= mid) if side.any()]
    gap = max(gaps) if gaps else float("inf")
    return {"present": True, "articulated": bool(gap <= ARTICULATED_GAP_MM), "condyle_gap_mm": round(gap, 1),
            "volume_mm3": float(sizes[m] * voxel_mm3), "component": int(m + 1),
            "centroid_mm": [round(float(c), 1) for c in centroids_xyz[m]]}


#: A cervical spine joined to the cranium at the atlanto-occipital joint at partial volume (a low bone level: CThead
#: at 1500) is split off by eroding the cranium's component by up to this many more voxels: the joint's cartilage
#: space (1-2 mm) is bridged by a voxel of partial volume, the skull base around it is thicker (two more voxels
#: broke GE's skull base, cut by its tilted slab, into pieces below the core).
SPINE_SPLIT_EXTRA_EROSION = 1
#: ... and what is split off is at most this share of the component: the upper cervical spine at a bone level is a
#: few percent of the skull (CThead at 1500: C1-C3 3 %); a larger part is the cranium itself broken by the erosion
#: (the phantom's face and skull base at two more voxels).
SPINE_MAX_SHARE = 0.1
#: ... and reaches at least this far (mm) below the cranium's core: the atlas and the axis's body reach 35-40 mm
#: below the occipital condyles, which stand less than 15 mm below the skull base's thick core (left with the
#: cranium; CThead at its own level: a piece 16 mm deep by the left condyle).
SPINE_MIN_DROP_MM = 25.0


def split_spine_from_cranium(labels: np.ndarray, n: int, cranium: int, ct: CTVolume,
                             min_component_mm3: float) -> tuple[np.ndarray, int, dict]:
    """Split a cervical spine still joined to the cranium's component off it.

    The cranium's component (of the bone eroded once) is eroded by 1 to :data:`SPINE_SPLIT_EXTRA_EROSION` more
    voxels: the thick cranium stays one piece (the largest), the joint's bridge and the thin vertebrae break into
    pieces. The pieces whose centroid lies below the largest's lowest point (the skull base's core) and not more
    than :data:`VERTEBRA_FRONT_MM` in front of its centroid (the teeth and the maxilla's edge lie in front) are the
    spine's. Every voxel of the component goes to the nearest piece (Euclidean; the pieces in front below the skull
    base take none); the spine's pieces' voxels, together of at least ``min_component_mm3``, at most
    :data:`SPINE_MAX_SHARE` of the component and reaching :data:`SPINE_MIN_DROP_MM` below the largest piece, get
    a new label; the rest stays the cranium.

    Returns
    -------
    (labels, n, info)
        ``labels`` with the spine labelled ``n + 1`` (the input is changed in place), the new count, and ``info``:
        ``extra_erosion`` (0: nothing split) and ``split_mm3``.
    """
    info = {"extra_erosion": 0, "split_mm3": 0.0}
    box = ndi.find_objects((labels == cranium).astype(np.int8))[0]
    comp = labels[box] == cranium
    offset = np.array([b.start for b in box], float)
    voxel_mm3 = float(np.prod(ct.spacing))
    core = comp
    for extra in range(1, SPINE_SPLIT_EXTRA_EROSION + 1):
        core = ndi.binary_erosion(core, structure=ndi.generate_binary_structure(3, 1))
        sub, m = ndi.label(core, structure=np.ones((3, 3, 3), bool))
        if m < 2:
            continue
        sizes = np.bincount(sub.reshape(-1), minlength=m + 1)[1:]
        main = int(np.argmax(sizes)) + 1
        cents = np.zeros((m + 1, 3))
        cents[1:] = ct.index_to_patient(np.array(ndi.center_of_mass(core, sub, np.arange(1, m + 1))).reshape(m, 3)
                                        + offset)
        main_xyz = ct.index_to_patient(np.argwhere(sub == main) + offset)
        bottom, c = float(main_xyz[:, 2].min()), main_xyz.mean(axis=0)
        low = cents[:, 2] < bottom
        spine = low & (cents[:, 1] > c[1] - VERTEBRA_FRONT_MM)
        spine[[0, main]] = False
        if not spine.any():
            continue
        # every voxel of the component goes to the nearest piece, but for the pieces in front below the skull base
        # (teeth, the maxilla's edge): eroded thin, the lower vertebrae have no piece of their own and the teeth
        # would be nearer to them than the spine's pieces above
        seeds = np.where(np.isin(sub, np.flatnonzero(low & ~spine)), 0, sub)
        near = ndi.distance_transform_edt(seeds == 0, sampling=ct.spacing, return_distances=False,
                                          return_indices=True)
        owner = seeds[tuple(near)]
        del near, seeds
        kji = np.argwhere(comp)
        xyz = ct.index_to_patient(kji + offset)
        below = spine[owner[tuple(kji.T)]]
        split = float(np.count_nonzero(below) * voxel_mm3)
        if (split < float(min_component_mm3) or np.count_nonzero(below) > SPINE_MAX_SHARE * len(kji)
                or xyz[below, 2].min() > bottom - SPINE_MIN_DROP_MM):
            continue
        region = labels[box]
        region[tuple(kji[below].T)] = n + 1
        z = xyz[below, 2]
        return labels, n + 1, {"extra_erosion": extra, "split_mm3": split, "label": n + 1,
                               "centroid_mm": [round(float(v), 1) for v in xyz[below].mean(axis=0)],
                               "z_range_mm": [round(float(z.min()), 1), round(float(z.max()), 1)],
                               "cranium_core_bottom_mm": round(bottom, 1)}
    return labels, n, info


def bone_parts(bone: np.ndarray, ct: CTVolume, erosion: int, min_component_mm3: float, voxel_mm3: float) -> dict:
    """The components of the bone eroded by ``erosion`` voxels and what each is: the cranium, cervical vertebrae
    (:func:`_vertebra_components`), supports outside the cranium's box, the rest kept (see :func:`segment_skull`)."""
    core, labels, n = eroded_components(bone, erosion)
    sizes = np.bincount(labels.reshape(-1), minlength=n + 1)[1:]
    boxes = ndi.find_objects(labels)
    # the cranium: the largest component clear of the scan's side borders (a table or a holder running
    # out of the field of view can be larger; the eroded core stops a voxel short of the border); the
    # largest of all when every one touches them
    _, ny, nx = ct.shape
    clear = np.array([b[1].start > 1 and b[2].start > 1 and b[1].stop < ny - 1 and b[2].stop < nx - 1 for b in boxes])
    cranium = int(np.argmax(np.where(clear, sizes, -1) if clear.any() else sizes)) + 1
    labels, n, spine_split = split_spine_from_cranium(labels, n, cranium, ct, min_component_mm3)
    if spine_split["extra_erosion"]:
        sizes = np.bincount(labels.reshape(-1), minlength=n + 1)[1:]
        boxes = ndi.find_objects(labels)
    centroids = np.array(ndi.center_of_mass(core, labels, np.arange(1, n + 1))).reshape(n, 3)
    centroids_xyz = ct.index_to_patient(centroids)
    big = sizes * voxel_mm3 >= float(min_component_mm3)
    vertebra = _vertebra_components(labels, centroids_xyz, cranium, ct) & big
    if spine_split["extra_erosion"]:
        vertebra[spine_split["label"] - 1] = True
    vertebra[cranium - 1] = False
    # supports, table, holders: outside the cranium's box (grown by a margin, and downward for the mandible)
    crbox = _box_mm(ct, boxes[cranium - 1])
    lo = crbox[0] - [SUPPORT_MARGIN_MM, SUPPORT_MARGIN_MM, MANDIBLE_BELOW_MM]
    hi = crbox[1] + SUPPORT_MARGIN_MM
    outside = np.zeros(n, bool)
    for i in np.flatnonzero(big & ~vertebra):
        b = _box_mm(ct, boxes[i])
        c = centroids_xyz[i]
        # the centre outside the grown box, or reaching far beyond it (a table, a holder's arc)
        outside[i] = bool(np.any(c < lo) or np.any(c > hi) or np.any(b[0] < lo - SUPPORT_REACH_MM)
                          or np.any(b[1] > hi + SUPPORT_REACH_MM))
    outside[cranium - 1] = False
    keep = big & ~vertebra & ~outside
    keep[cranium - 1] = True
    return dict(core=core, labels=labels, n=n, sizes=sizes, boxes=boxes, cranium=cranium, centroids_xyz=centroids_xyz,
                big=big, vertebra=vertebra, outside=outside, keep=keep, crbox=crbox, erosion=int(erosion),
                spine_split=spine_split)


def metal_bloom(metal: np.ndarray, spacing, radius_mm: float = METAL_BLOOM_MM) -> np.ndarray:
    """The metal and its bloom: every voxel within ``radius_mm`` of a metal voxel (and its six neighbours).

    A filling is brighter than any bone, but the voxels about its edge hold part metal, part tooth or soft tissue
    (partial volume, widened by the reconstruction kernel and the metal's blooming: Barrett & Keat 2004); they pass
    the bone level and join the metal's streaks to the tooth, so the streaks are no longer loose pieces that
    :func:`metal_streaks` can recognise. How many such voxels there are depends on where the grid's nodes fall:
    one voxel about the saturated metal separated CThead's streaks from its teeth on its own grid, but after a
    quarter-pixel shift (one linear interpolation: the metal's edge is no longer saturated) they stayed joined and
    stood in the cheeks, and the face moved with them. The bloom is therefore a distance in mm, not a voxel count,
    and its radius is the smallest at which the face stops depending on the grid: CThead's face shifted by a
    quarter pixel against the unshifted one, share of the face within 1 mm (at the automatic level / at 1500 /
    shifted by half a pixel): one voxel 67 / 76 / -, 2.5 mm 71 / 72 / 66, 3 mm 81 / 90 / 79, 3.5 mm 81 / 86 / 74,
    4 mm 83 / 82 / 82 %. Chosen for that invariance on CThead's shifted copies (the only head here with metal),
    not on a face's score.

    Parameters
    ----------
    metal : ndarray of bool (z, y, x)
        The metal voxels (above the metal level).
    spacing : sequence of float
        (dz, dy, dx) in mm.
    radius_mm : float
        The bloom's radius.

    Returns
    -------
    ndarray of bool
        ``metal`` grown by the bloom (at least its six neighbours, as before on any grid).

    References
    ----------
    Barrett JF, Keat N. Artifacts in CT: recognition and avoidance. RadioGraphics 2004;24(6):1679-1691
    (metal: streaks and blooming about high-density objects; partial volume at their edges).
    """
    out = ndi.binary_dilation(metal, structure=ndi.generate_binary_structure(3, 1))
    if not metal.any() or radius_mm <= 0:
        return out
    reach = [int(np.ceil(radius_mm / float(h))) for h in spacing]
    rows = [np.flatnonzero(metal.any(axis=tuple(a for a in range(3) if a != k))) for k in range(3)]
    box = tuple(slice(max(int(i[0]) - r, 0), min(int(i[-1]) + r + 1, n))       # the distance only about the metal
                for i, r, n in zip(rows, reach, metal.shape))
    near = ndi.distance_transform_edt(~metal[box], sampling=[float(h) for h in spacing]) <= radius_mm
    out[box] |= near
    return out


def metal_streaks(bone: np.ndarray, metal: np.ndarray, spacing, keep: np.ndarray | None = None,
                  elongation: float = STREAK_ELONGATION, aim_mm: float = STREAK_AIM_MM,
                  min_length_mm: float = STREAK_MIN_LENGTH_MM) -> tuple[np.ndarray, int]:
    """The metal streak artefacts among the bone: loose straight pieces in the metal's slices that point at it.

    Dental fillings and other metal throw bright streaks along the projection lines through them (photon
    starvation and beam hardening: Barrett & Keat 2004); in a 2-D axial reconstruction they are confined to
    the slices holding the metal and radiate from it in-plane. Where a streak is bright enough to pass the
    bone level it lies in the soft tissue as a thin, straight piece that does not join the bone. A piece of
    ``bone`` (6-connected, any but the largest) is a streak when at least half of its voxels lie in slices
    holding ``metal``, its in-plane extent (principal axes of its pixel positions in mm) is at least
    ``min_length_mm`` long and ``elongation`` times longer than wide, and its long axis, extended, passes
    within ``aim_mm`` (or its own width, when wider) of a metal voxel of its slices. Bone joined to the
    skull, pieces in metal-free slices (nasal bones, thin maxillae, teeth without fillings) and compact,
    short or off-axis pieces stay.

    Parameters
    ----------
    bone : ndarray of bool (z, y, x)
    metal : ndarray of bool (z, y, x)
        Metal voxels (above the metal level), not dilated.
    spacing : sequence of float
        (dz, dy, dx) in mm.
    keep : ndarray of bool, optional
        Bone found to be a part of the skull (the mandible): pieces touching it stay.

    Returns
    -------
    streaks : ndarray of bool
        The streak voxels.
    pieces : int
        How many pieces they form.

    References
    ----------
    Barrett JF, Keat N. Artifacts in CT: recognition and avoidance. RadioGraphics 2004;24(6):1679-1691
    (metal streaking: "streaks" from photon starvation and beam hardening radiating from high-density
    objects such as dental fillings).
    """
    streaks = np.zeros(bone.shape, dtype=bool)
    has_metal = metal.any(axis=(1, 2))
    if not has_metal.any() or not bone.any():
        return streaks, 0
    labels, n = ndi.label(bone)
    sizes = np.bincount(labels.reshape(-1), minlength=n + 1)
    sizes[0] = 0
    largest = int(np.argmax(sizes))
    kept = np.zeros(n + 1, dtype=bool)
    if keep is not None:
        kept[np.unique(labels[keep])] = True
    dy, dx = (float(h) for h in spacing[1:])
    pieces = 0
    for index, sl in enumerate(ndi.find_objects(labels), start=1):
        if sl is None or index == largest or kept[index] or sizes[index] < 3 or not has_metal[sl[0]].any():
            continue
        kk, jj, ii = np.nonzero(labels[sl] == index)
        kk = kk + sl[0].start
        if 2 * np.count_nonzero(has_metal[kk]) < kk.size:
            continue
        pts = np.stack([(jj + sl[1].start) * dy, (ii + sl[2].start) * dx], axis=1)
        centre = pts.mean(axis=0)
        evals, evecs = np.linalg.eigh(np.cov((pts - centre).T))
        evals = np.maximum(evals, 0.0)
        if evals[1] <= 0 or evals[1] < elongation ** 2 * evals[0]:
            continue                                   # a point, or not elongated (a straight line has evals[0] = 0)
        if 12.0 * evals[1] < min_length_mm ** 2:       # the length of a straight piece is sqrt(12 var)
            continue
        axis = evecs[:, 1]
        mj, mi = np.nonzero(metal[np.unique(kk[has_metal[kk]])].any(axis=0))
        off_axis = np.abs((mj * dy - centre[0]) * axis[1] - (mi * dx - centre[1]) * axis[0])
        if float(off_axis.min()) <= max(aim_mm, 2.0 * float(np.sqrt(evals[0]))):
            streaks[sl] |= labels[sl] == index
            pieces += 1
    return streaks, pieces


def _line(length_px: float, theta: float) -> np.ndarray:
    """A one-pixel line structuring element ``length_px`` long at ``theta`` (radians, from the +x axis)."""
    n = max(int(round(length_px)), 1)
    t = np.linspace(-(n - 1) / 2.0, (n - 1) / 2.0, n)
    yy = np.round(t * np.sin(theta)).astype(int)
    xx = np.round(t * np.cos(theta)).astype(int)
    s = int(max(np.abs(yy).max(), np.abs(xx).max()))
    se = np.zeros((2 * s + 1, 2 * s + 1), dtype=bool)
    se[yy + s, xx + s] = True
    return se


def joined_metal_streaks(bone: np.ndarray, metal: np.ndarray, spacing, length_mm: float = SPOKE_LENGTH_MM,
                         width_mm: float = SPOKE_WIDTH_MM, reach_mm: float = SPOKE_REACH_MM,
                         aim_mm: float = STREAK_AIM_MM, angles: int = 24) -> np.ndarray:
    """The metal's streaks that are joined to the bone: thin straight spokes along lines through the metal.

    A filling's streaks lie along the projection lines through it, in the slices holding it (Barrett & Keat
    2004); where one starts at a tooth it is joined to the bone and :func:`metal_streaks` (loose pieces) keeps it.
    Here, slice by slice where ``metal`` is present, a bone pixel is a spoke when, for one of ``angles``
    directions: it lies on a straight run of bone at least ``length_mm`` long in that direction (an opening by a
    line), the bone across that direction is narrower than ``width_mm`` there (not kept by an opening by the
    perpendicular line), the line through it in that direction passes within ``aim_mm`` of a metal pixel of the
    slice, and it lies within ``reach_mm`` of the metal, not on the metal's own rim. Real bone continues through
    the neighbouring slices while a streak is confined to its slice and turns with the metal's shape from one
    slice to the next: a pixel with bone within one pixel of it in BOTH neighbouring slices stays (the mandible's
    rami and cortices at the teeth's level, which are also thin, straight and in line with the molars).

    Parameters
    ----------
    bone, metal : ndarray of bool (z, y, x)
        The bone mask and the metal voxels (above the metal level, not dilated).
    spacing : sequence of float
        (dz, dy, dx) in mm.

    Returns
    -------
    ndarray of bool
        The spoke voxels (a subset of ``bone``; empty without metal).

    References
    ----------
    Barrett JF, Keat N. Artifacts in CT: recognition and avoidance. RadioGraphics 2004;24(6):1679-1691
    (metal streaking along the projection lines through high-density objects such as dental fillings; streaks
    are an in-plane effect of the slices through the metal).
    """
    out = np.zeros(bone.shape, dtype=bool)
    if not bone.any() or not metal.any():
        return out
    px = float(min(spacing[1], spacing[2]))
    sampling = (float(spacing[1]), float(spacing[2]))
    nz = bone.shape[0]
    for k in np.nonzero(metal.any(axis=(1, 2)))[0]:
        b, m = bone[k], metal[k]
        if not b.any():
            continue
        near = ndi.distance_transform_edt(~m, sampling=sampling) <= reach_mm
        rim = ndi.binary_dilation(m)
        cand = np.zeros_like(b)
        for theta in np.arange(angles) * (np.pi / angles):
            along = ndi.binary_opening(b, _line(length_mm / px, theta))
            if not along.any():
                continue
            across = ndi.binary_opening(b, _line(width_mm / px, theta + np.pi / 2))
            ray = ndi.binary_dilation(m, _line(2.0 * reach_mm / px, theta))
            ray = ndi.binary_dilation(ray, _line(2.0 * aim_mm / px + 1.0, theta + np.pi / 2))
            cand |= along & ~across & ray
        cand &= near & ~rim & b
        if not cand.any():
            continue
        lo = bone[k - 1] if k > 0 else np.zeros_like(b)
        hi = bone[k + 1] if k + 1 < nz else np.zeros_like(b)
        supported = ndi.binary_dilation(lo) & ndi.binary_dilation(hi)
        out[k] = cand & ~supported
    return out
