"""Automatic craniometric landmarks (issue 22): the phantom's analytic facial skeleton, CThead's
hand-placed landmarks (tests/fixtures/cthead_landmarks.csv), the missing-mandible path (GE)."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from pdehead_addon.forensic.auto_landmarks import NOT_FOUND, OK, UNCERTAIN, find_landmarks
from pdehead_addon.forensic.landmarks import STANDARD_LANDMARKS, landmark
from pdehead_addon.forensic.skull import segment_skull
from pdehead_addon.io.phantom import GEOMETRY

FIXTURE = Path(__file__).parent.parent / "fixtures" / "cthead_landmarks.csv"
MANDIBLE = {"Infradentale", "Supramentale", "Pogonion", "Gnathion", "Menton"} | {
    f"{n} {s}" for n in ("Gonion", "Occlusal line", "Sub M2", "Infra canine", "Mid-ramus", "Mid-mandibular border")
    for s in "LR"}


@pytest.fixture(scope="module")
def phantom_bone(phantom_skull):
    return phantom_skull.bone


@pytest.fixture(scope="module")
def phantom_truth(phantom):
    return phantom.bone_landmarks()


def test_depth_table_codes_are_in_the_set():
    for key in ("mn", "ss", "gn", "ac_l", "sc_r", "ic_l", "mr_r", "mmb_l"):
        assert landmark(key).key == key
    names = [d.name for d in STANDARD_LANDMARKS]
    assert len(names) == len(set(names)) == 24 * 2 - 11 + 3 + 5 * 2   # 11 midline + 13 pairs, + 3 midline + 5 pairs


def test_phantom_analytic_landmarks_follow_the_geometry(phantom_truth):
    f = GEOMETRY["facial_skeleton"]
    (ox, oz), (_, orz) = f["orbit"]
    (my, mz), mrad, _ = f["meatus"]
    # the Frankfurt plane of the phantom: porions and orbitales at the same height
    assert phantom_truth["Orbitale L"][2] == pytest.approx(oz - orz, abs=0.02)
    assert phantom_truth["Porion R"][2] == pytest.approx(mz + mrad, abs=0.02)
    assert phantom_truth["Porion L"][1] == my and phantom_truth["Orbitale R"][0] == -ox
    # glabella in front of nasion, rhinion in front of nasion and below it, pogonion in front of menton
    g, n, rhi = phantom_truth["Glabella"], phantom_truth["Nasion"], phantom_truth["Rhinion"]
    assert g[1] < n[1] - 4 and rhi[1] < n[1] - 4 and rhi[2] < n[2] - 10
    assert phantom_truth["Pogonion"][1] < phantom_truth["Menton"][1] - 5


def test_phantom_every_landmark_found_and_accurate(phantom_search, phantom_truth):
    flags = phantom_search.flags()
    assert set(flags) == {d.name for d in STANDARD_LANDMARKS}
    assert all(f in (OK, UNCERTAIN) for f in flags.values()), {n: f for n, f in flags.items() if f == NOT_FOUND}
    assert phantom_search.frankfurt is not None and phantom_search.info["frame"] == "frankfurt"
    err = {n: float(np.linalg.norm(phantom_search.landmarks[n].point - p)) for n, p in phantom_truth.items()}
    print({n: round(e, 2) for n, e in err.items()})
    # default grid 2.3 x 2 x 2 mm with 20 HU noise: about a voxel (measured: median 1.5, largest 5.2 mm at
    # porion L, flagged uncertain: the roof reaches 4 mm beyond the canal's floor, and porion is put half way;
    # the supraorbital margins, 6.8 mm before the margins took the rim's front-most point, are 3.2 / 3.0)
    assert np.median(list(err.values())) <= 2.0
    assert max(err.values()) <= 6.0, max(err.items(), key=lambda kv: kv[1])
    for name in ("Supraorbital L", "Supraorbital R", "Lateral orbit L", "Lateral orbit R"):
        assert err[name] <= 4.0, (name, err[name])
    # every uncertain landmark says why
    assert all(lm.evidence for lm in phantom_search.landmarks.values() if lm.flag != OK)


def test_phantom_without_mandible_reports_it(phantom, phantom_bone, phantom_search):
    from pdehead_addon.forensic.landmark_frame import bone_components
    labels, _ = bone_components(phantom_bone)
    mandible = labels == labels[tuple(np.round(phantom.ct.patient_to_index([0.0, -67.0, -79.0])).astype(int))]
    assert 0.02 < mandible.mean() / phantom_bone.mean() < 0.2
    search = find_landmarks(phantom.ct, phantom_bone & ~mandible)
    for name in MANDIBLE:
        lm = search.landmarks[name]
        assert lm.flag == NOT_FOUND and lm.point is None and "mandible" in lm.evidence, (name, lm)
    # the rest is where it was with the mandible (same frame, same rules)
    for name in ("Porion L", "Orbitale R", "Nasion", "Zygomatic arch L", "Supradentale"):
        assert np.linalg.norm(search.landmarks[name].point - phantom_search.landmarks[name].point) < 1.5
    # supra M2 is on the maxilla: without the mandible to place it by, it is taken SUPRA_M2_PORION_FRACTION of the
    # way from prosthion to porion (the phantom's sub M2 lies at 0.63 of the way, CThead's at 0.56), uncertain
    for side in "LR":
        lm, ref = search.landmarks[f"Supra M2 {side}"], phantom_search.landmarks[f"Supra M2 {side}"]
        off = float(np.linalg.norm(lm.point - ref.point))
        print(f"supra M2 {side} without the mandible: {off:.1f} mm from where the mandible put it")
        assert lm.flag == UNCERTAIN and "porion" in lm.evidence and off <= 8.0, (lm, off)


def _fixture():
    with open(FIXTURE, newline="") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    return {r["landmark"]: np.array([float(r[k]) for k in ("x_mm", "y_mm", "z_mm")]) for r in rows}


def test_cthead_fixture_is_documented():
    with open(FIXTURE, newline="") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    assert len(rows) >= 18 and all(len(r["how"]) > 30 for r in rows)
    assert {r["landmark"] for r in rows} <= {d.name for d in STANDARD_LANDMARKS}


def test_cthead_landmarks_against_the_hand_placed_ones(cthead_search):
    search = cthead_search
    ref = _fixture()
    err = {n: float(np.linalg.norm(search.landmarks[n].point - p)) for n, p in ref.items()
           if search.landmarks[n].point is not None}
    print({n: (search.landmarks[n].flag, round(e, 1)) for n, e in err.items()})
    assert search.info["frame"] == "frankfurt" and search.info["mandible"]
    assert len(err) == len(ref)                                  # every hand-placed landmark was found
    # measured (docs/benchmarks.md, bench_landmarks.py); the targets are 3 / 6 mm
    assert np.median(list(err.values())) <= CTHEAD_MEDIAN_MM
    assert max(e for n, e in err.items() if search.landmarks[n].flag == OK) <= CTHEAD_MAX_OK_MM
    # the Frankfurt landmarks themselves are within 5 mm (measured: porion 1.4 / 4.4, orbitale 3.1 / 1.5)
    for name in ("Porion L", "Porion R", "Orbitale L", "Orbitale R"):
        assert err[name] <= 5.0, (name, err[name])
    # the mid-sagittal plane (symmetry of the bone's surface): the chin's landmarks lie on the bone's own
    # midline there (the front-most bone of the symphysis spans x = 99..123, centre 110.8; measured 111.5-111.6)
    for name in ("Pogonion", "Gnathion", "Menton"):
        assert abs(search.landmarks[name].point[0] - 110.8) <= 1.0, (name, search.landmarks[name].point)
    # bilateral landmarks mirror each other; a pair that does not is flagged whichever side is wrong
    from pdehead_addon.forensic.face_pegs import midsagittal_plane, mirrored
    from pdehead_addon.forensic.landmark_openings import MIRROR_TOLERANCE_MM
    pts = search.points()
    plane = midsagittal_plane(pts)
    # the left ramus and both coronoids lie in ~30 pieces the threshold split from the mandible; joined to it
    # (mandible_pieces), mid-ramus is half way from gonion to the condyle on both sides and the pair mirrors. Before:
    # mid-ramus L 22.6 mm from R's mirror image, both flagged, L 24 mm too low (placed from the body's top).
    assert search.info["mandible_pieces_joined"] >= 10
    for side in "LR":
        mr, go, po = (search.landmarks[f"{n} {side}"] for n in ("Mid-ramus", "Gonion", "Porion"))
        up = float(np.dot(mr.point - go.point, [0, 0, 1]) / np.dot(po.point - go.point, [0, 0, 1]))
        print(side, mr.flag, round(up, 2))
        assert mr.flag == OK and 0.4 <= up <= 0.6, (mr, up)
    gap = float(np.linalg.norm(mirrored(pts["Mid-ramus L"], plane) - pts["Mid-ramus R"]))
    print("mid-ramus mirror gap", round(gap, 1))
    for left in (n for n in pts if n.endswith(" L") and n[:-1] + "R" in pts):
        right = left[:-1] + "R"
        if search.landmarks[left].flag == OK and search.landmarks[right].flag == OK:
            gap = float(np.linalg.norm(mirrored(pts[left], plane) - pts[right]))
            assert gap <= MIRROR_TOLERANCE_MM, (left, gap)


# measured (bench_landmarks.py): median 2.84 mm, largest ok 5.7 mm (subspinale: the thin cortex in front of the
# maxilla is not in the bone mask; gonion 4.5 / 4.5, vertex 4.6); glabella 5.7 is uncertain (no prominence). The
# issue's targets are 3 / 6 mm. Before: 3.9 / 6.0 (fixture x = 108 for the face), 5.0 / 6.3 before that. Of the
# 3.9 -> 2.84, the fixture's corrected x took the chin landmarks from 3.8-3.9 to 1.0-1.9 mm; supradentale went
# 10.6 -> 6.2 (the upper jaw stops at the incisors' edges), vertex 5.3 -> 4.6 (the vault's own midline).
CTHEAD_MEDIAN_MM = 3.0
CTHEAD_MAX_OK_MM = 6.0


def test_every_bilateral_pair_is_checked_against_its_mirror_image():
    """Not only porion and orbitale: any pair farther than MIRROR_TOLERANCE_MM from mirror images (x -> -x in the
    landmark frame) has both sides uncertain with the reason; a nearer pair and a side already uncertain keep theirs."""
    from pdehead_addon.forensic.auto_landmarks import _check_mirror_images
    from pdehead_addon.forensic.landmark_openings import MIRROR_TOLERANCE_MM

    far = MIRROR_TOLERANCE_MM + 8.0
    found = {"mr_l": (np.array([40.0, 10.0, -30.0]), OK, ""), "mr_r": (np.array([-40.0, 10.0, -30.0 + far]), OK, ""),
             "go_l": (np.array([45.0, 0.0, -60.0]), OK, ""), "go_r": (np.array([-44.0, 1.0, -57.0]), OK, ""),
             "sc_l": (np.array([15.0, 60.0, -40.0]), UNCERTAIN, "own reason"),
             "sc_r": (np.array([-15.0, 60.0, -40.0 - far]), OK, ""),
             "im_l": (None, NOT_FOUND, "no bone"), "im_r": (np.array([-30.0, 40.0, -20.0]), OK, ""),
             "n": (np.array([0.0, 80.0, 0.0]), OK, "")}
    _check_mirror_images(found)
    assert [found[k][1] for k in ("mr_l", "mr_r")] == [UNCERTAIN, UNCERTAIN]
    assert all(f"{far:.0f} mm from mirror images" in found[k][2] for k in ("mr_l", "mr_r", "sc_r"))
    assert found["sc_l"][1:] == (UNCERTAIN, "own reason")
    assert found["go_l"][1] == found["go_r"][1] == found["im_r"][1] == found["n"][1] == OK


def test_every_landmark_has_a_written_rule():
    from pdehead_addon.forensic.auto_landmarks import RULES
    keys = {d.key.rsplit("_", 1)[0] if d.bilateral else d.key for d in STANDARD_LANDMARKS}
    assert keys == set(RULES) and all(len(r) > 40 for r in RULES.values())


def test_ge_has_no_mandible(ge_ct):
    """The GE series stops at the maxilla: every mandible landmark is not_found and says why."""
    search = find_landmarks(ge_ct, segment_skull(ge_ct).bone)
    assert not search.info["mandible"]
    for name in MANDIBLE:
        lm = search.landmarks[name]
        assert lm.flag == NOT_FOUND and "mandible" in lm.evidence, (name, lm)
    assert search.landmarks["Vertex"].point is not None and search.landmarks["Porion R"].point is not None
    # the Frankfurt frame without a mandible: the left orbit's opening runs into the space below it in the bone
    # mask (its rim is broken on the 4 mm tilted slices), so it is cut to the right orbit's mirror image and its
    # margins are uncertain; orbitale L 40 mm and R 34 mm from the face's midline (x = -22), both at z = -8
    assert search.frankfurt is not None and search.info["frame"] == "frankfurt"
    ol, orr = search.landmarks["Orbitale L"], search.landmarks["Orbitale R"]
    assert ol.flag == UNCERTAIN and "mirror" in ol.evidence and orr.flag == OK
    assert abs(ol.point[2] - orr.point[2]) < 3.0 and ol.point[0] > 0 > orr.point[0]
    # the face from the skull needs both orbits and 8 ok landmarks (measured 13 ok, 22 found)
    assert sum(lm.flag == OK for lm in search.landmarks.values()) >= 10


def test_scaled_phantom_mandible_midline_is_on_the_mandible(monkeypatch):
    """The phantom scaled by 1.12 (test_batch's second study): the floor of the face block (the palate), split
    from the skull by the threshold, hangs between the jaws on the midline. It was taken for lower teeth split
    from the mandible, and infradentale and supramentale landed on it (supramentale 30 mm behind pogonion, ok).
    A piece between the jaws now counts as the mandible's only when it lies no farther from the mandible than
    from the upper skeleton; and supramentale on a profile with a gap is uncertain."""
    import pdehead_addon.forensic.landmark_midline as M
    from pdehead_addon import CTVolume, make_phantom
    from pdehead_addon.io.phantom_anatomy import _mandible_sd

    scale = 1.12
    ct = make_phantom(shape=(60, 96, 96), seed=1).ct
    ct = CTVolume(ct.data, tuple(np.asarray(ct.spacing) * scale), origin=np.asarray(ct.origin) * scale,
                  direction=ct.direction, meta=dict(ct.meta))
    bone = segment_skull(ct).bone

    class Q:  # the phantom's point record (x, y, z, |x|), in the unscaled head
        def __init__(self, p):
            self.x, self.y, self.z = p[:, 0] / scale, p[:, 1] / scale, p[:, 2] / scale
            self.ax = np.abs(self.x)

    search = find_landmarks(ct, bone)
    for name in ("Infradentale", "Supramentale"):
        lm = search.landmarks[name]
        gap = float(_mandible_sd(Q(lm.point[None]))[0]) * scale   # mm from the mandible's surface (+ outside)
        assert abs(gap) <= 2.5, (name, lm.point, gap)
    pog = search.landmarks["Pogonion"].point
    sm = search.landmarks["Supramentale"]
    assert abs(sm.point[1] - pog[1]) < 10.0                       # was 31.6 mm behind pogonion
    # the phantom's chin has no concavity above it (chin ellipsoid on a straight front): uncertain, says why
    assert sm.flag == UNCERTAIN and "no concavity" in sm.evidence
    # the old rule (every piece between the jaws is the mandible's): the mandible's front, ending where it steps back
    # by more than MANDIBLE_FRONT_STEP_MM, still keeps the palate out (measured: supramentale 6.1 mm from pogonion)
    monkeypatch.setattr(M, "_lower_teeth_pieces", lambda fr, pieces, mand_id: pieces)
    sm_step = find_landmarks(ct, bone).landmarks["Supramentale"]
    assert abs(sm_step.point[1] - pog[1]) < 10.0, sm_step
    # ... and without that end either, it lands on the palate: no longer silent
    monkeypatch.setattr(M, "MANDIBLE_FRONT_STEP_MM", np.inf)
    old = find_landmarks(ct, bone).landmarks["Supramentale"]
    assert abs(old.point[1] - pog[1]) > 20.0
    assert old.flag == UNCERTAIN and "gap" in old.evidence, old


def test_cthead_landmarks_do_not_follow_the_resampling_grid(cthead_ct, cthead_skull, cthead_search):
    """The rules read the bone resampled on a 1 mm grid; the same bone on a grid shifted by a fraction of a step must
    give the same landmarks. Measured (CThead, its own bone level): one grid against one shifted by half a step,
    median 1.37 mm, 90th percentile 4.1 mm apart; the default search (the medoid over five grids) against five
    other shifts, 0.77 / 3.0 mm."""
    from pdehead_addon.forensic.auto_landmarks import GRID_PHASES

    bone = cthead_skull.bone

    def apart(a, b):
        pa, pb = a.points(), b.points()
        return np.array([np.linalg.norm(pa[n] - pb[n]) for n in pa if n in pb])

    one = apart(find_landmarks(cthead_ct, bone, phases=[GRID_PHASES[0]]),
                find_landmarks(cthead_ct, bone, phases=[(0.5, 0.5, 0.5)]))
    default = cthead_search
    other = [tuple((v + 0.125) % 1.0 for v in s) for s in GRID_PHASES[:default.info["grid_phases"]]]
    five = apart(default, find_landmarks(cthead_ct, bone, phases=other))
    print("one grid", np.median(one), np.percentile(one, 90), "five", np.median(five), np.percentile(five, 90))
    assert default.info["grid_phases"] == 5 and len(five) >= 45
    assert np.median(five) <= 1.0 and np.percentile(five, 90) <= 3.5
    assert np.median(five) < 0.7 * np.median(one)
    # every landmark found reports how far its grids' points lay from the one kept
    assert set(default.info["phase_spread_mm"]) == {n for n, lm in default.landmarks.items() if lm.point is not None}
    # a landmark whose grids disagree by more than PHASE_SPREAD_MM is not ok
    from pdehead_addon.forensic.auto_landmarks import PHASE_SPREAD_MM
    for n, spread in default.info["phase_spread_mm"].items():
        assert spread <= PHASE_SPREAD_MM or default.landmarks[n].flag != OK, (n, spread)


def test_bone_joined_behind_the_mandibles_front_is_not_its_front(phantom, phantom_bone, phantom_search):
    """CThead resliced to 1.5 mm joins the atlas's anterior arch to the mandible at the occlusal plane's height,
    43 mm behind the incisors. Read as the mandible's top, it put infradentale 8.6 mm too high, the infra
    canines 8 mm and an occlusal line 20 mm off. The mandible's front now ends at the first row that steps back
    by more than MANDIBLE_FRONT_STEP_MM. Here the phantom's mandible gets a post joined to its symphysis,
    35 mm behind its front, reaching 5 mm above its top (below the palate: joined to them, it would
    join the mandible to the skull). Measured: every landmark checked within 0.9 mm of where it was without the
    post; the old rule puts infradentale 5.0 mm higher."""
    from pdehead_addon.forensic.landmark_midline import MANDIBLE_FRONT_STEP_MM

    ct = phantom.ct
    idn, pog = (phantom_search.landmarks[n].point for n in ("Infradentale", "Pogonion"))
    top = idn[2] + 9.0                                               # the mandible's front's highest point
    bone = phantom_bone.copy()

    def block(x, y, z):
        corners = np.array([[x[i], y[j], z[k]] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
        ijk = np.round(ct.patient_to_index(corners)).astype(int)
        lo, hi = np.maximum(ijk.min(0), 0), ijk.max(0) + 1
        bone[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = True

    post_y = pog[1] + 35.0
    assert post_y - pog[1] > MANDIBLE_FRONT_STEP_MM
    block((-4, 4), (pog[1] + 4, post_y + 6), (pog[2] - 3, pog[2] + 3))      # the joint, through the symphysis
    block((-4, 4), (post_y, post_y + 6), (pog[2] - 3, top + 5.0))           # the post, up past the incisors
    found = find_landmarks(ct, bone).landmarks
    for name in ("Infradentale", "Pogonion", "Menton", "Infra canine L", "Occlusal line R"):
        assert found[name].point is not None, (name, found[name].evidence)
        moved = float(np.linalg.norm(found[name].point - phantom_search.landmarks[name].point))
        print(name, moved)
        assert moved <= 1.5, (name, moved)
    # the old rule (every row of the mandible's midline profile) takes the post's top for the incisors'
    import pdehead_addon.forensic.landmark_midline as M
    try:
        M.MANDIBLE_FRONT_STEP_MM = np.inf
        old = find_landmarks(ct, bone).landmarks["Infradentale"].point
    finally:
        M.MANDIBLE_FRONT_STEP_MM = MANDIBLE_FRONT_STEP_MM
    print("old rule: infradentale", old[2] - idn[2], "mm higher")
    assert old[2] - idn[2] > 3.0, old


def test_supra_m2_without_the_mandible_on_a_missing_wall_is_the_other_sides_mirror_image(phantom, phantom_bone,
                                                                                           phantom_search):
    """Supra M2 placed without the mandible is the outermost bone of its row; where a side's maxillary wall is not
    in the bone (CThead resliced to 1.5 mm and cut through the lower teeth: its point 12 mm from the midline against
    46 mm on the other side, and the face's cheek pulled 20 mm in), it is the other side's mirror image, uncertain."""
    from pdehead_addon.forensic import landmark_bilateral
    from pdehead_addon.forensic.landmark_frame import bone_components
    labels, _ = bone_components(phantom_bone)
    mandible = labels == labels[tuple(np.round(phantom.ct.patient_to_index([0.0, -67.0, -79.0])).astype(int))]
    bone = phantom_bone & ~mandible
    whole = find_landmarks(phantom.ct, bone).landmarks
    p = whole["Supra M2 L"].point
    # the left wall around it taken out: everything beyond 14 mm inside its outermost bone, 12 x 10 mm about it
    xyz = phantom.ct.index_to_patient(np.argwhere(bone).astype(float))
    box = (xyz[:, 0] > p[0] - 14.0) & (np.abs(xyz[:, 1] - p[1]) <= 6.0) & (np.abs(xyz[:, 2] - p[2]) <= 5.0)
    holed = bone.copy()
    holed[tuple(np.argwhere(bone)[box].T)] = False
    found = find_landmarks(phantom.ct, holed).landmarks
    lm, other = found["Supra M2 L"], found["Supra M2 R"]
    mirror = other.point * np.array([-1.0, 1.0, 1.0])
    print("supra M2 L", lm, "whole scan's", p, "R mirrored", mirror)
    assert lm.flag == UNCERTAIN and "mirror image" in lm.evidence, lm
    assert lm.point[0] > p[0] - 6.0 and np.linalg.norm(lm.point - p) <= 8.0, (lm.point, p)
    # without the guard the point is on the bone within, far from the wall
    guard = landmark_bilateral._supra_m2_mirrored
    try:
        landmark_bilateral._supra_m2_mirrored = lambda found, fr: None
        unguarded = find_landmarks(phantom.ct, holed).landmarks["Supra M2 L"]
    finally:
        landmark_bilateral._supra_m2_mirrored = guard
    print("without the guard", unguarded)
    assert unguarded.point is None or unguarded.point[0] < p[0] - 12.0


def test_mid_ramus_where_nothing_lies_between_the_ramus_edges():
    """A ramus seen at one height as its front and back edges with nothing between (thick slabs, a thin ramus:
    CThead given in HU in 5 mm slabs ended in a traceback here, an empty band's argmax): the band is the points
    nearest the middle, the outermost of them the mid-ramus."""
    from pdehead_addon.forensic.landmark_bilateral import _mid_ramus_band
    front = np.array([[50.0, 10.0, 0.0], [51.0, 11.0, 0.0], [52.0, 12.0, 0.0]])
    back = np.array([[49.0, 29.0, 0.0], [48.0, 31.0, 0.0]])
    band = _mid_ramus_band(np.vstack([front, back]))        # middle y = 20.5: the nearest lie 8.5 mm off it
    assert len(band) == 2 and set(band[:, 1]) == {12.0, 29.0}
    solid = np.array([[50.0, y, 0.0] for y in np.arange(10.0, 31.0)])
    assert set(_mid_ramus_band(solid)[:, 1]) == set(np.arange(17.0, 24.0))   # within 3 mm of 20, as before


def test_cthead_in_5_mm_slabs_keeps_its_orbits(cthead_ct, cthead_search, bench_face):
    """In 5 mm slabs CThead's nasal aperture runs on into the mouth: one opening across the midline, 1,300 mm^2
    with its centre 17 mm to the right, larger than the right orbit, was taken for it (orbitale R 84 mm, supraorbital
    R 87 mm from their places at 1 mm, on the first grid as on two of the other four). An opening across the midline
    is no orbit: on the first grid alone (a fifth of the search's time; one grid's landmarks spread by up to ~4 mm)
    the orbits' landmarks stay within 6 mm of the default search's at 1 mm."""
    from pdehead_addon.forensic.auto_landmarks import GRID_PHASES
    thick = bench_face.resliced(cthead_ct, 5.0)
    sk = segment_skull(thick)
    found = find_landmarks(thick, sk.bone, mandible=sk.mandible, phases=[GRID_PHASES[0]]).points()
    ref = cthead_search.points()
    names = ("Orbitale R", "Supraorbital R", "Lateral orbit R", "Orbitale L", "Supraorbital L", "Lateral orbit L")
    apart = {n: round(float(np.linalg.norm(found[n] - ref[n])), 1) for n in names}
    assert max(apart.values()) <= 6.0, apart
