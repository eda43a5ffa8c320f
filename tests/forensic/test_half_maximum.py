"""A calibrated scan's skull at the bone's half-maximum level, and its fillings found where its values clip (issue 39).

The unseen head of issue 39 was given in HU, stripped at and run with ``--bone-level 250`` as the README describes.
CThead given so (its stored values shifted to HU, 1.5 mm slabs, cut through the lower teeth) scored 50 % within
+-2.5 mm against 61 % at its own level: at 250 HU the bone's surface stands 0.6 mm (median) further out, the closed
bite and the jaw joints join the mandible to the cranium, and its fillings (2,248 HU, under METAL_HU) were not
found, so their streaks stood in the cheeks.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage as ndi

from pdehead_addon.core.wording import for_cli
from pdehead_addon.forensic.skull import BONE_LEVEL_RANGE_HU, TISSUE_HU, segment_skull
from pdehead_addon.forensic.value_levels import METAL_HU, half_maximum_level, metal_level

#: CThead's occlusal plane (z 69 mm, the suite's figure) less bench_face.UNSEEN_CUT_BELOW_MM: through the lower teeth.
UNSEEN_CUT_Z = 59.0


def _ball(radius_mm=20.0, step_mm=0.5, blur_mm=1.0, bone=1100.0, tissue=40.0):
    n = int(2 * (radius_mm + 8 * blur_mm) / step_mm)
    x = (np.arange(n) - (n - 1) / 2.0) * step_mm
    r = np.sqrt(x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2)
    vol = ndi.gaussian_filter(np.where(r < radius_mm, bone, tissue).astype(np.float32), blur_mm / step_mm)
    return x, vol


def _crossing(x, profile, level):
    """The outermost x > 0 where ``profile`` falls through ``level`` (linear interpolation)."""
    i = int(np.flatnonzero((profile[:-1] >= level) & (profile[1:] < level) & (x[:-1] > 0))[-1])
    return float(x[i] + (profile[i] - level) / (profile[i] - profile[i + 1]) * (x[i + 1] - x[i]))


def test_half_maximum_level_is_where_a_blurred_bone_ends():
    """A ball of bone (1100 HU, radius 20 mm) in soft tissue (40 HU), blurred as a CT blurs it (Gaussian, 1 mm): the
    half-maximum level of its values above 250 HU is 570 HU, and its iso-surface lies on the ball's surface (within
    0.1 mm) where the one at 250 HU stands 0.8 mm out. Values without a mode of their own give no level."""
    x, vol = _ball()
    found = half_maximum_level(vol[vol >= 250.0], TISSUE_HU, BONE_LEVEL_RANGE_HU)
    assert found is not None
    level, mode = found
    assert abs(mode - 1100.0) <= 10.0 and abs(level - 570.0) <= 5.0
    mid = len(x) // 2
    profile = vol[mid, mid, :]
    assert abs(_crossing(x, profile, level) - 20.0) < 0.1
    assert _crossing(x, profile, 250.0) - 20.0 > 0.6
    flat = np.random.default_rng(0).uniform(250.0, 1500.0, 200_000).astype(np.float32)
    assert half_maximum_level(flat, TISSUE_HU, BONE_LEVEL_RANGE_HU) is None


def test_a_clipped_calibrated_scans_fillings_are_metal(cthead_ct, ge_ct, bench_face):
    """CThead in HU clips its fillings at 2,248 HU, under METAL_HU: a spike at the top of its values, found as metal.
    GE's brightest bone thins out towards its top (a tail, no spike) and the phantom's fillings pass METAL_HU: both
    keep METAL_HU."""
    from pdehead_addon.io.phantom import make_phantom
    hu = bench_face.in_hu(cthead_ct)
    assert 2200.0 < metal_level(hu.data, True) < METAL_HU
    assert metal_level(ge_ct.data, True) == METAL_HU
    assert metal_level(make_phantom(metal=True).ct.data, True) == METAL_HU


def test_cthead_in_hu_stripped_at_250_is_made_at_its_half_maximum(cthead_ct, bench_face):
    """CThead in HU stripped at and run with 250 HU: the skull is made at its half-maximum level (about 560 HU), the
    same skull as stripped at and run with that level, with a warning naming --bone-level; its fillings are metal and
    its mandible is its own (at 250 HU itself the bite and the joints join it to the cranium: no mandible)."""
    B = bench_face
    hu = B.in_hu(cthead_ct)
    sk = segment_skull(B.stripped(hu, 250.0), bone_level=250.0)
    m = sk.meta
    level = m["bone_level_stored"]
    assert m["bone_level_below"] == 250.0 and 520.0 < level < 600.0
    assert level == pytest.approx(0.5 * (TISSUE_HU + m["bone_mode"]))
    assert for_cli(m["warnings"][0]).startswith("--bone-level 250 lies below the bone's half-maximum surface: the "
                                                f"skull is made at {level:.0f} HU")
    same = segment_skull(B.stripped(hu, level), bone_level=level)
    assert np.array_equal(sk.bone, same.bone)
    assert m["metal_voxels"] > 1000
    assert m["mandible"]["present"] and m["mandible"]["articulated"]


def test_cthead_as_the_unseen_head_was_given_scores_as_at_its_own_level(cthead_ct, cthead_skull, bench_face):
    """CThead as the unseen head of issue 39 was given (HU, 1.5 mm slabs, cut through the lower teeth, stripped at and
    run with 250 HU): at least 60 % of its remaining face within +-2.5 mm of the real face and a mean under 2.6 mm
    (measured 64.4 % and 2.30 mm; before: 50.2 % and 3.18 mm)."""
    B = bench_face
    centre = cthead_ct.index_to_patient(np.argwhere(cthead_skull.bone).mean(axis=0)[None])[0]
    ref = B.reference_face(cthead_ct, centre[:2])
    unseen = B.in_hu(B.cut_slices(B.resliced(cthead_ct, 1.5), z_low=UNSEEN_CUT_Z))
    row = B.score_variant("unseen-like", unseen, ref, bone_level=B.UNSEEN_LEVEL_HU, floor_z=UNSEEN_CUT_Z)
    assert "refused" not in row, row
    assert row["has_mandible"]
    assert row["face"]["within_2_5"] >= 0.60 and row["face"]["mean_mm"] <= 2.6, row["face"]
