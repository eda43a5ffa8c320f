"""Which bone levels make a skull of a scan: from the automatic rule's lowest level to the level that keeps a
quarter of the scan's bone (:func:`bone_level_range`); a level outside is refused before any work
(:func:`check_bone_level`, called by the add-on's segmentation and skull steps and the command line).
"""
from __future__ import annotations

import numpy as np

from ..core.ct_volume import CTVolume
from ..core.errors import SegmentationError
from ..segment.segmentation import auto_window
from .skull import AIR_HU, BONE_LEVEL_RANGE_HU, TISSUE_HU, soft_tissue_present

#: Valid bone levels keep at least this share of the scan's bone (its voxels from the lowest valid level up):
#: above it the skull falls apart into its densest spots (CThead at 2800 stored keeps 1 %, the GE series at
#: 1200 HU 11 %, the phantom at 1200 HU 12 %; their automatic levels keep 70 % to 100 %).
BONE_LEVEL_MIN_KEPT = 0.25


def bone_level_range(ct: CTVolume, has_skin: bool | None = None) -> dict:
    """The bone levels that make a skull of this scan, in its stored units.

    * lowest: the lowest level of the automatic rule, ``BONE_LEVEL_RANGE_HU[0]`` (below it cartilage and
      contrast count as bone), in stored units (uncalibrated scans: on the pseudo-HU scale of
      :func:`.skull.hounsfield`); a scan without soft tissue: Otsu's air/bone split (everything not air is bone);
    * highest: the level that keeps :data:`BONE_LEVEL_MIN_KEPT` of the scan's bone (the voxels from the
      lowest level up): the 75th percentile of their values.

    Returns
    -------
    dict(low, high, max (the brightest voxel), units ("HU" or "stored"), bone_voxels)
    """
    calibrated = str(ct.meta.get("units", "")).upper() == "HU"
    split = None
    if has_skin is None:
        has_skin, info = soft_tissue_present(ct.data, spacing=ct.spacing, calibrated=calibrated)
        split = info["air_split"]
    if not has_skin:
        split = soft_tissue_present(ct.data, spacing=ct.spacing)[1]["air_split"] if split is None else split
        low = max(split, BONE_LEVEL_RANGE_HU[0]) if calibrated else split
    elif calibrated:
        low = BONE_LEVEL_RANGE_HU[0]
    else:                       # the pseudo-HU scale of skull.hounsfield: air and soft-tissue modes -> AIR_HU,
                                # TISSUE_HU
        air, tissue = auto_window(ct.data)
        low = air + (BONE_LEVEL_RANGE_HU[0] - AIR_HU) * (tissue - air) / (TISSUE_HU - AIR_HU)
    sample = ct.data.reshape(-1)[:: max(1, ct.data.size // 8_000_000)]
    bone = sample[sample >= np.float32(low)]
    units = "HU" if calibrated else "stored"
    if bone.size == 0:
        return dict(low=float(low), high=float(low), max=float(np.nanmax(sample)), units=units, bone_voxels=0)
    high = float(np.percentile(bone, 100.0 * (1.0 - BONE_LEVEL_MIN_KEPT)))
    return dict(low=float(low), high=high, max=float(bone.max()), units=units, bone_voxels=int(bone.size))


def check_bone_level(ct: CTVolume, bone_level: float, has_skin: bool | None = None) -> dict:
    """Refuse a bone level outside :func:`bone_level_range` (before any segmentation), naming the range.

    Raises
    ------
    SegmentationError
        "bone_level=V is above (below) this scan's bone ...", with the valid levels.
    """
    r = bone_level_range(ct, has_skin)
    level, units = float(bone_level), r["units"]
    valid = (f"give a level from {r['low']:.0f} to {r['high']:.0f} {units}, or none (the automatic rule)")
    if r["bone_voxels"] == 0:
        raise SegmentationError(f"bone_level={level:g}: this scan has no bone (nothing from {r['low']:.0f} {units} "
                                f"up; its brightest voxel is {r['max']:.0f})")
    if level > r["high"]:
        sample = ct.data.reshape(-1)[:: max(1, ct.data.size // 8_000_000)]
        kept = float(np.count_nonzero(sample >= np.float32(level))) / r["bone_voxels"]
        raise SegmentationError(f"bone_level={level:g} is above this scan's bone: its bone spans {r['low']:.0f} to "
                                f"{r['max']:.0f} {units} and the level keeps {100 * kept:.0f} % of it (a skull needs "
                                f"at least {100 * BONE_LEVEL_MIN_KEPT:.0f} %); {valid}")
    if level < r["low"]:
        raise SegmentationError(f"bone_level={level:g} is below this scan's bone (from {r['low']:.0f} {units}: "
                                f"soft tissue would count as bone); {valid}")
    return r
