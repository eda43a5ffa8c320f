"""Boundary curves (paper eq. 22, sections 3 and 4.1): synthetic stacks with known answers, then real CT."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage as ndi
from scipy.spatial import cKDTree

from pdehead_addon import (
    BoundaryError,
    BoundarySet,
    CTVolume,
    Segmentation,
    defaults,
    extract_boundaries as _extract_default,
)
from pdehead_addon.curves.curve_sampling import (
    contour_from_mask,
    parameter_offsets,
    polygon_centroid,
    resample_closed_curve,
    self_intersections,
    signed_area,
)
from pdehead_addon.curves.slice_outlines import boundary_ring, outer_contour, outer_region
from pdehead_addon.curves.slice_selection import (
    SELECTION_STRATEGIES,
    _assign_monotone,
    register_selection,
    scan_edge_slices,
    usable_slices,
)

#: The per-slice path (2-D mask outline, aligned samples) these tests were written for; the default path
#: (the 3-D envelope, star hulls, the spine, angular samples) is tested in test_envelope.py.
PER_SLICE = dict(level_field="mask", parameterisation="aligned", star_shaped=False)


def extract_boundaries(seg, **kwargs):
    return _extract_default(seg, **{**PER_SLICE, **kwargs})

SPACING = (2.0, 0.8, 0.9)          # dz, dy, dx: anisotropic on purpose
ORIGIN = (-40.0, -55.0, 12.0)      # LPS mm of voxel (0, 0, 0)


def make_seg(mask, probability=None, spacing=SPACING, origin=ORIGIN):
    mask = np.asarray(mask, bool)
    ct = CTVolume(mask.astype(np.float32), spacing, origin=origin, meta={"source": "synthetic"})
    prob = mask.astype(np.float32) if probability is None else probability
    return Segmentation(mask, prob, 1.0, 0.0, 0, ct, {})


def ellipse_stack(nz=40, shape=(120, 130), a=40.0, b=28.0, center=(58.3, 63.6), angle_deg=0.0,
                  turn_deg=0.0, shift=(0.0, 0.0), empty_ends=0):
    """Ellipse masks per slice: semi-axes a (along x/col) and b (along y/row) in pixels, turning
    by turn_deg and shifting by shift (rows, cols) per slice; empty_ends empty slices at both ends."""
    yy, xx = np.mgrid[:shape[0], :shape[1]].astype(float)
    mask = np.zeros((nz,) + shape, bool)
    for k in range(empty_ends, nz - empty_ends):
        cy, cx = center[0] + shift[0] * k, center[1] + shift[1] * k
        t = np.deg2rad(angle_deg + turn_deg * k)
        u = (xx - cx) * np.cos(t) + (yy - cy) * np.sin(t)
        v = -(xx - cx) * np.sin(t) + (yy - cy) * np.cos(t)
        mask[k] = (u / a) ** 2 + (v / b) ** 2 <= 1.0
    return mask


def to_pixels(seg, curve):
    """(row, col) pixel coordinates of a curve's points."""
    return seg.ct.patient_to_index(curve)[:, 1:]


def pixel_edge_points(mask2d):
    """Midpoints (row, col) of all edges between a mask pixel and a 4-adjacent background pixel."""
    m = np.pad(np.asarray(mask2d, bool), 1)
    r, c = np.nonzero(m[:, 1:] != m[:, :-1])
    horizontal = np.column_stack([r, c + 0.5])
    r, c = np.nonzero(m[1:, :] != m[:-1, :])
    vertical = np.column_stack([r + 0.5, c])
    return np.vstack([horizontal, vertical]) - 1.0


def segment_lengths(curve):
    return np.linalg.norm(np.diff(np.vstack([curve, curve[:1]]), axis=0), axis=1)


# --------------------------------------------------------------------------- eq. 22
def test_boundary_ring_is_eq22():
    rng = np.random.default_rng(1)
    for _ in range(20):
        m = ndi.gaussian_filter(rng.random((40, 50)), 2) > 0.5
        ref = m & ~ndi.binary_erosion(m, border_value=0)
        assert np.array_equal(boundary_ring(m), ref)
        square = np.ones((3, 3), bool)
        assert np.array_equal(boundary_ring(m, square), m & ~ndi.binary_erosion(m, square, border_value=0))
    m = np.zeros((9, 9), bool)
    m[2:7, 2:7] = True
    ring = boundary_ring(m)
    assert ring.sum() == 16 and not ring[3:6, 3:6].any() and ring[2, 2]
    # Pixels on the image border are boundary pixels (outside counts as background).
    assert boundary_ring(np.ones((5, 6), bool)).sum() == 2 * 5 + 2 * 6 - 4
    with pytest.raises(BoundaryError):
        boundary_ring(np.ones((2, 3, 4), bool))


def test_outer_region_drops_blobs_and_fills_holes():
    yy, xx = np.mgrid[:100, :100]
    disk = (yy - 50) ** 2 + (xx - 45) ** 2 <= 30 ** 2
    hole = (yy - 50) ** 2 + (xx - 45) ** 2 <= 10 ** 2
    blob = (yy - 8) ** 2 + (xx - 92) ** 2 <= 5 ** 2
    region = outer_region((disk & ~hole) | blob)
    assert np.array_equal(region, disk)
    assert not outer_region(np.zeros((5, 5), bool)).any()


# --------------------------------------------------------------------------- single contours
@pytest.mark.parametrize("radius", [12.3, 30.3, 45.55])
def test_contour_of_disk_is_subpixel_circle(radius):
    yy, xx = np.mgrid[:128, :128]
    cy, cx = 64.2, 61.7
    mask = (yy - cy) ** 2 + (xx - cx) ** 2 <= radius ** 2
    dy, dx = 0.8, 0.9
    c = contour_from_mask(mask, spacing_yx=(dy, dx), samples=200)
    assert c.shape == (200, 2)
    x_px, y_px = c[:, 0] / dx, c[:, 1] / dy
    err = np.hypot(x_px - cx, y_px - cy) - radius
    # A binary mask only knows the edge to +-0.5 px (flat pixel runs at the extremes);
    # on average the sub-pixel curve is much closer.
    assert np.sqrt(np.mean(err ** 2)) < 0.2
    assert np.abs(err).max() <= 0.52
    seg = segment_lengths(c)
    assert seg.std() / seg.mean() < 0.02              # uniform arc length
    assert signed_area(c) > 0                          # counter-clockwise in (x, y)
    centroid = polygon_centroid(c)
    assert abs(c[0, 0] - centroid[0]) < 0.02           # seam on x = centroid x ...
    assert c[0, 1] > centroid[1] + 0.9 * radius * dy   # ... on the +y side
    # CCW from +y goes to -x: a quarter turn later the curve is on the -x side.
    assert c[50, 0] < centroid[0] - 0.9 * radius * dx and abs(c[50, 1] - centroid[1]) < 1.0


def test_probability_field_gives_true_subpixel_edge():
    yy, xx = np.mgrid[:128, :128].astype(float)
    cy, cx, radius = 60.4, 66.1, 33.27
    prob = 1.0 / (1.0 + np.exp((np.hypot(yy - cy, xx - cx) - radius) / 0.8))
    mask = prob > 0.5
    rc = outer_contour(mask, probability=prob, sigma=0.0)
    err_prob = np.hypot(rc[:, 0] - cy, rc[:, 1] - cx) - radius
    rc_mask = outer_contour(mask)
    err_mask = np.hypot(rc_mask[:, 0] - cy, rc_mask[:, 1] - cx) - radius
    assert np.abs(err_prob).max() < 0.05
    assert np.abs(err_mask).max() > 0.2   # the mask alone cannot do that
    # The band keeps the probability contour close to the cleaned mask even if p disagrees.
    wild = np.where(xx > 80, 1.0, prob)   # p says "head" everywhere right of x = 80
    rc_wild = outer_contour(mask, probability=wild, sigma=0.0, band=1)
    dist, _ = cKDTree(np.argwhere(boundary_ring(mask))).query(rc_wild)
    assert dist.max() <= 2.0 + 1e-9


def test_hole_and_blob_give_only_outer_contour():
    yy, xx = np.mgrid[:110, :120]
    cy, cx, radius = 55.5, 52.25, 35.2
    disk = (yy - cy) ** 2 + (xx - cx) ** 2 <= radius ** 2
    hole = (yy - 50) ** 2 + (xx - 55) ** 2 <= 12 ** 2
    blob = (yy - 10) ** 2 + (xx - 108) ** 2 <= 6 ** 2
    c = contour_from_mask((disk & ~hole) | blob, samples=128)
    r = np.hypot(c[:, 0] - cx, c[:, 1] - cy)
    assert np.abs(r - radius).max() <= 0.52
    # Whole slice stack with the same picture: meta area is the filled disk.
    mask = np.repeat(((disk & ~hole) | blob)[None], 10, axis=0)
    bset = extract_boundaries(make_seg(mask), patches=3, samples=64)
    assert np.allclose(bset.meta["slice_areas_mm2"], disk.sum() * SPACING[1] * SPACING[2])
    assert min(bset.meta["ring_coverage"]) > 0.99


def test_mask_touching_image_border_gives_closed_curve():
    mask = np.zeros((50, 60), bool)
    mask[:30, 10:50] = True          # cut by the top image edge
    c = contour_from_mask(mask, samples=64)
    assert self_intersections(c) == 0
    assert c[:, 1].min() == pytest.approx(-0.5, abs=0.05)   # closed along the image edge


def test_resample_closed_curve_uniform_and_start():
    square = np.array([[0, 0], [4, 0], [4, 4], [0, 4]], float)
    r = resample_closed_curve(square, 8, start=1.0)
    assert np.allclose(r[0], [1, 0]) and np.allclose(r[1], [3, 0]) and np.allclose(r[-1], [0, 1])
    assert np.allclose(segment_lengths(r)[[0, 2, 4, 6]], 2.0)


def test_parameter_offsets_detects_twist():
    t = np.linspace(0, 2 * np.pi, 128, endpoint=False)
    ellipse = np.stack([40 * np.cos(t), 25 * np.sin(t), np.zeros_like(t)], axis=1)
    curves = np.stack([ellipse + [0, 0, z] for z in range(4)])
    assert np.array_equal(parameter_offsets(curves), [0, 0, 0])
    curves[2] = np.roll(curves[2], 9, axis=0)
    assert np.array_equal(parameter_offsets(curves), [0, 9, -9])   # b_{i+s} matches a_i


def test_self_intersections_counts_crossings():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    bowtie = np.array([[0, 0], [1, 1], [1, 0], [0, 1]], float)
    assert self_intersections(square) == 0
    assert self_intersections(bowtie) == 1


# --------------------------------------------------------------------------- whole stacks
def test_ellipse_stack_curves_geometry():
    a, b, center = 40.0, 28.0, (58.3, 63.6)
    seg = make_seg(ellipse_stack(nz=41, a=a, b=b, center=center, empty_ends=2))
    bset = extract_boundaries(seg, patches=4, samples=180)
    assert isinstance(bset, BoundarySet)
    assert bset.curves.shape == (13, 180, 3) and bset.patches == 4 and bset.samples == 180
    # Inferior -> superior, ends of the non-empty extent, evenly spaced (36 slice steps / 12 = 3).
    assert np.array_equal(bset.slice_indices, np.arange(2, 39, 3))
    z = ORIGIN[2] + SPACING[0] * bset.slice_indices
    assert np.allclose(bset.heights, z) and np.allclose(bset.curves[:, :, 2], z[:, None])
    assert np.allclose(bset.u_knots, np.arange(13) / 12)
    dz, dy, dx = SPACING
    for c in bset.curves:
        rc = to_pixels(seg, c)
        ell = np.hypot((rc[:, 1] - center[1]) / a, (rc[:, 0] - center[0]) / b)
        # Radial distance from the ellipse, in pixels (to first order).
        err = (ell - 1.0) * np.hypot(a * np.cos(np.arctan2(rc[:, 0] - center[0], rc[:, 1] - center[1])),
                                     b * np.sin(np.arctan2(rc[:, 0] - center[0], rc[:, 1] - center[1])))
        assert np.sqrt(np.mean(err ** 2)) < 0.2 and np.abs(err).max() < 0.6
        seg_len = segment_lengths(c)
        assert seg_len.std() / seg_len.mean() < 0.02
        assert signed_area(c[:, :2]) > 0
        cen = polygon_centroid(c[:, :2])
        assert abs(c[0, 0] - cen[0]) < 0.02 and c[0, 1] > cen[1] + 0.9 * b * dy
    assert np.all(parameter_offsets(bset.curves) == 0)
    meta = bset.meta
    assert meta["selection"] == "uniform" and meta["patches"] == 4 and meta["samples"] == 180
    assert meta["spacing"] == list(SPACING) and len(meta["slice_areas_mm2"]) == 13
    assert np.allclose(meta["slice_areas_mm2"], np.pi * a * b * dy * dx, rtol=0.01)


def test_rotating_shifting_ellipses_do_not_twist():
    # 60 slices, turning 1.5 deg and moving (0.25, 0.35) px per slice: 88 deg and 25 px in total.
    mask = ellipse_stack(nz=60, shape=(150, 160), a=42, b=27, center=(55.0, 50.0), angle_deg=-30,
                         turn_deg=1.5, shift=(0.25, 0.35))
    seg = make_seg(mask)
    bset = extract_boundaries(seg, patches=6, samples=256)
    offsets = parameter_offsets(bset.curves)
    assert np.abs(offsets).max() <= 1
    # Same index = nearby points: corresponding samples of neighbours are much closer than the
    # distance to the neighbouring samples' far side, for every pair of consecutive curves.
    d = np.linalg.norm(bset.curves[1:, :, :2] - bset.curves[:-1, :, :2], axis=2)
    assert d.max() < 10.0                              # mm; curves 3 slices apart
    seams = bset.curves[:, 0, :2]
    for c, s in zip(bset.curves, seams):
        cen = polygon_centroid(c[:, :2])
        assert abs(s[0] - cen[0]) < 0.02 and s[1] > cen[1]


def test_shape_change_selection_concentrates_where_shape_changes():
    nz = 80
    yy, xx = np.mgrid[:120, :120]
    radius = np.full(nz, 25.0)
    radius[40:50] = np.linspace(25, 50, 10)   # a fast-growing "chin" between slices 40 and 50
    radius[50:] = 50.0
    mask = np.stack([(yy - 60) ** 2 + (xx - 60) ** 2 <= r ** 2 for r in radius])
    seg = make_seg(mask)
    uni = extract_boundaries(seg, patches=5, samples=32, selection="uniform")
    adapt = extract_boundaries(seg, patches=5, samples=32, selection="shape-change")
    in_ramp = lambda ks: int(np.count_nonzero((ks >= 40) & (ks <= 50)))  # noqa: E731
    assert adapt.meta["selection"] == "shape-change"
    assert in_ramp(adapt.slice_indices) >= in_ramp(uni.slice_indices) + 3
    assert adapt.slice_indices[0] == 0 and adapt.slice_indices[-1] == nz - 1
    assert np.all(np.diff(adapt.slice_indices) > 0)


def test_usable_slices_leave_out_tiny_end_caps():
    radius = np.r_[np.full(3, 2.0), np.full(30, 30.0), 1.0, 0.0]
    yy, xx = np.mgrid[:80, :80]
    mask = np.stack([(yy - 40) ** 2 + (xx - 40) ** 2 <= r ** 2 for r in radius])
    heights = np.arange(len(radius), dtype=float)
    assert np.array_equal(usable_slices(mask, heights, 0.05), np.arange(3, 33))
    bset = extract_boundaries(make_seg(mask), patches=3, samples=16)
    assert bset.slice_indices[0] == 3 and bset.slice_indices[-1] == 32


def test_assign_monotone_never_repeats_on_uneven_spacing():
    h = np.array([0.0, 1, 2, 3, 4, 10, 11])
    picks = _assign_monotone(h, np.array([0.0, 0.2, 0.4, 10.5]))
    assert np.array_equal(picks, [0, 1, 2, 5]) or np.array_equal(picks, [0, 1, 2, 6])
    picks = _assign_monotone(h, np.linspace(0, 11, 7))
    assert np.array_equal(picks, np.arange(7))


def test_explicit_and_callable_selection():
    seg = make_seg(ellipse_stack(nz=30))
    chosen = [1, 4, 6, 9, 12, 15, 27]
    bset = extract_boundaries(seg, patches=2, samples=32, selection=chosen)
    assert np.array_equal(bset.slice_indices, chosen) and bset.meta["selection"] == "explicit"
    assert np.allclose(bset.heights, ORIGIN[2] + SPACING[0] * np.array(chosen))
    # Knots follow the heights inside each patch (paper p1, p2), ends at k/t.
    assert np.allclose(bset.u_knots, [0, 3 / 16, 5 / 16, 0.5, 0.5 + 3 / 36, 0.5 + 6 / 36, 1])

    calls = []

    def every_fourth(mask, n, heights):
        calls.append((mask.shape, n, len(heights)))
        return np.arange(n) * 4

    bset = extract_boundaries(seg, patches=2, samples=32, selection=every_fourth)
    assert calls == [((30, 120, 130), 7, 30)]
    assert np.array_equal(bset.slice_indices, np.arange(7) * 4)
    assert bset.meta["selection"] == "callable:every_fourth"

    register_selection("lowest", lambda mask, n, heights, **_: np.arange(n))
    try:
        bset = extract_boundaries(seg, patches=2, samples=32, selection="lowest")
        assert np.array_equal(bset.slice_indices, np.arange(7))
    finally:
        SELECTION_STRATEGIES.pop("lowest")


@pytest.mark.parametrize("selection, message", [
    ([1, 4, 6, 9, 12, 15], "7 are needed"),
    ([1, 4, 6, 9, 12, 15, 15], "repeat"),
    ([1, 4, 6, 9, 12, 15, 30], "out of range"),
    ([-1, 4, 6, 9, 12, 15, 20], "out of range"),
    ([27, 15, 12, 9, 6, 4, 1], "inferior -> superior"),
    ([0, 4, 6, 9, 12, 15, 20], "empty head mask"),
    ([1.5, 4, 6, 9, 12, 15, 20], "integers"),
    ("no-such-strategy", "unknown selection"),
    (lambda mask, n, heights: [1, 2, 3], "3 slices given"),
])
def test_bad_selections_raise(selection, message):
    mask = ellipse_stack(nz=30)
    mask[0] = False
    with pytest.raises(BoundaryError, match=message):
        extract_boundaries(make_seg(mask), patches=2, samples=32, selection=selection)


def test_bad_parameters_raise():
    seg = make_seg(ellipse_stack(nz=12))
    for kwargs, message in [(dict(patches=0), "patches"), (dict(patches=2.5), "patches"),
                            (dict(samples=7), "samples"), (dict(patches=4), r"only 12 slices .*t <= 3"),
                            (dict(level_field="intensity"), "level_field")]:
        with pytest.raises(BoundaryError, match=message):
            extract_boundaries(seg, **kwargs)
    with pytest.raises(BoundaryError, match="empty"):
        extract_boundaries(make_seg(np.zeros((12, 20, 20), bool)), patches=1)
    with pytest.raises(BoundaryError, match="empty"):
        contour_from_mask(np.zeros((20, 20), bool))


def test_flipped_axes_keep_conventions():
    """Orientation and seam are fixed in patient space, whatever the voxel axes do."""
    mask = ellipse_stack(nz=20, a=30, b=20)
    ct_dir = np.diag([-1.0, 1.0, -1.0])    # i -> patient right, k -> inferior: mirrors (x, y)
    ct = CTVolume(mask.astype(np.float32), SPACING, origin=(10.0, 20.0, 100.0), direction=ct_dir)
    seg = Segmentation(mask, mask.astype(np.float32), 1.0, 0.0, 0, ct, {})
    bset = extract_boundaries(seg, patches=3, samples=64)
    assert np.all(np.diff(bset.heights) > 0)
    assert np.all(np.diff(bset.slice_indices) < 0)      # k points inferior: superior = lower k
    for c in bset.curves:
        cen = polygon_centroid(c[:, :2])
        assert signed_area(c[:, :2]) > 0 and abs(c[0, 0] - cen[0]) < 0.02 and c[0, 1] > cen[1]


# --------------------------------------------------------------------------- real CT
def _check_real(seg, bset, n_expected, max_edge_dist=1.0, max_ring_dist=1.5):
    """Conventions and geometry of real-data curves. The distances to the mask's pixel edges and
    eq. 22 ring grow by the closing radius (inlets bridged); arc-length spacing is only checked
    for arc-length sets."""
    mask = seg.mask
    closing_px = bset.meta["closing_mm"] / (0.5 * (seg.ct.spacing[1] + seg.ct.spacing[2]))
    max_edge_dist, max_ring_dist = max_edge_dist + closing_px, max_ring_dist + closing_px
    arc_length = bset.meta["parameterisation"] == "arc-length"
    assert bset.curves.shape == (n_expected, 256, 3)
    assert np.all(np.diff(bset.heights) > 0)
    assert np.all(np.isfinite(bset.u_knots)) and bset.u_knots[0] == 0 and bset.u_knots[-1] == 1
    # Covers the head's extent: from the lowest usable to the highest usable slice.
    nz, ny, nx = mask.shape
    centre = np.column_stack([np.arange(nz, dtype=float), np.full(nz, (ny - 1) / 2), np.full(nz, (nx - 1) / 2)])
    selectable = mask.copy()
    selectable[scan_edge_slices(mask, seg.ct.coverage)] = False
    usable = usable_slices(selectable, seg.ct.index_to_patient(centre)[:, 2])
    assert {int(bset.slice_indices[0]), int(bset.slice_indices[-1])} == {int(usable[0]), int(usable[-1])}
    worst_dist, offsets = [], parameter_offsets(bset.curves)
    for k, c in zip(bset.slice_indices, bset.curves):
        assert self_intersections(c) == 0
        seg_len = segment_lengths(c)
        # Closed: the closing segment (last -> first) is an ordinary arc-length step.
        if arc_length:
            assert seg_len[-1] < 1.5 * np.median(seg_len)
            assert seg_len.max() < 1.5 * np.median(seg_len)
        else:   # aligned: spacing within the stretch bound (+ slack for the smoothed maps)
            assert seg_len.max() < 1.2 * bset.meta["align_max_stretch"] * seg_len.mean()
        assert signed_area(c[:, :2]) > 0
        cen = polygon_centroid(c[:, :2])
        # seam at the back, on the midline (of the sampled polygon: an aligned set samples it unevenly)
        assert c[0, 1] > cen[1] and abs(c[0, 0] - cen[0]) < (0.05 if arc_length else 0.3)
        assert c[c.shape[0] // 2, 1] < cen[1]                       # the middle of v is at the front
        # On the mask boundary: every point within 1 px of the pixel-edge boundary of its
        # slice (midpoints between 4-adjacent mask / background pixels) and within 1.5 px of
        # an eq. 22 ring pixel centre (bridging a 1-px crack costs ~1.05 px there).
        rc = to_pixels(seg, c)
        assert np.allclose(seg.ct.patient_to_index(c)[:, 0], k, atol=1e-6)
        dist, _ = cKDTree(pixel_edge_points(mask[k])).query(rc)
        ring_dist, _ = cKDTree(np.argwhere(boundary_ring(mask[k]))).query(rc)
        worst_dist.append(dist.max())
        assert ring_dist.max() <= max_ring_dist
    assert max(worst_dist) <= max_edge_dist
    assert min(bset.meta["ring_coverage"]) > 0.85
    # No twist: the best cyclic shift between neighbours is ~0. Uniform arc length lets
    # features on one side (an ear, the nose) move the samples by a few steps, never far.
    assert np.median(np.abs(offsets)) <= 1 and np.abs(offsets).mean() <= 3 and np.abs(offsets).max() <= 12
    return worst_dist, offsets


def test_cthead_boundaries(cthead_seg):
    # pixel-exact geometry without closing, uniform in arc length
    exact = extract_boundaries(cthead_seg, patches=10, samples=256, parameterisation="arc-length", closing_mm=0)
    _check_real(cthead_seg, exact, 31)
    # the per-slice path: inlets closed (3 mm), aligned
    cthead_bset = extract_boundaries(cthead_seg, patches=10, samples=256)
    assert cthead_bset.meta["parameterisation"] == "aligned" and cthead_bset.meta["closing_mm"] == 3.0
    _check_real(cthead_seg, cthead_bset, 31)
    assert cthead_bset.meta["selection"] == "uniform" and cthead_bset.patches == 10
    # The extent spans most of the head: CThead covers neck to vertex (~220 mm).
    assert cthead_bset.heights[-1] - cthead_bset.heights[0] > 180
    # The face is in the curves: the nose tip sticks out in front of the curves far below/above it.
    front = -cthead_bset.curves[:, :, 1].min(axis=1)    # most anterior point (-y) per curve
    assert front.max() - np.median(front) > 10.0


def test_cthead_shape_change_selection(cthead_seg):
    bset = extract_boundaries(cthead_seg, patches=10, samples=256, selection="shape-change")
    _check_real(cthead_seg, bset, 31)


def test_cthead_probability_level_field(cthead_seg):
    # The soft p (before clean-up) refines the curve, clamped to band = 1 px around the mask edge.
    bset = extract_boundaries(cthead_seg, patches=10, samples=256, level_field="probability", band=1)
    _check_real(cthead_seg, bset, 31, max_edge_dist=2.0, max_ring_dist=2.5)
    assert bset.meta["level_field"] == "probability"


def test_ge_boundaries(ge_seg):
    nz, ny, nx = ge_seg.mask.shape
    centre = np.column_stack([np.arange(nz, dtype=float), np.full(nz, (ny - 1) / 2), np.full(nz, (nx - 1) / 2)])
    edge = scan_edge_slices(ge_seg.mask, ge_seg.ct.coverage)
    assert edge.any(), "the tilted GE slab leaves axial planes whose head outline is the scan's edge"
    selectable = ge_seg.mask.copy()
    selectable[edge] = False
    usable = usable_slices(selectable, ge_seg.ct.index_to_patient(centre)[:, 2])
    t = min(10, (len(usable) - 1) // 3)
    assert t >= 4
    bset = extract_boundaries(ge_seg, patches=t, samples=256)
    _check_real(ge_seg, bset, 3 * t + 1)
    # no curve follows the straight edge of the scanned slab instead of the skin
    assert not edge[bset.slice_indices].any()
    assert bset.meta["scan_edge_slices"] == np.flatnonzero(edge).tolist()
    if t < 10:
        with pytest.raises(BoundaryError, match="use fewer patches"):
            extract_boundaries(ge_seg, patches=10)


# --------------------------------------------------------------------------- parameterisation, low-pass, closing
def _distance_to_polyline(q, curve):
    """Distance of points q (n, 2) to the closed polyline through curve (M, 2)."""
    p = np.vstack([curve, curve[:1]])
    a, d = p[:-1], np.diff(p, axis=0)
    t = np.clip(np.einsum("qsi,si->qs", q[:, None] - a[None], d) / (d * d).sum(1), 0, 1)
    return np.linalg.norm(q[:, None] - (a[None] + t[..., None] * d[None]), axis=2).min(axis=1)


def test_smooth_closed_curve_removes_pixel_ripple_keeps_shape():
    from pdehead_addon.curves.parameterisation import smooth_closed_curve
    th = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    r = 80 + 0.08 * np.sin(240 * th)                          # ~2 mm wavelength ripple on an 80 mm circle
    pts = np.column_stack([r * np.cos(th), r * np.sin(th), np.full_like(th, 12.5)])
    out = smooth_closed_curve(pts, 1.0)
    radius = np.hypot(out[:, 0], out[:, 1])
    assert np.ptp(radius) < 0.01 and abs(radius.mean() - 80) < 0.02   # ripple gone, circle kept
    assert np.all(out[:, 2] == 12.5)                                   # planar curves stay exactly planar
    assert np.array_equal(smooth_closed_curve(pts, 0.0), pts)
    with pytest.raises(BoundaryError, match="sigma"):
        smooth_closed_curve(pts, -1.0)


def test_close_region_bridges_narrow_inlets_only():
    from pdehead_addon.curves.slice_outlines import close_region
    yy, xx = np.mgrid[:80, :80]
    disk = (yy - 40) ** 2 + (xx - 40) ** 2 <= 30 ** 2
    notched = disk & ~((np.abs(yy - 40) <= 1) & (xx > 50))        # 3 px wide, 20 px deep slit
    wide = disk & ~((np.abs(yy - 40) <= 8) & (xx > 50))           # 17 px wide inlet
    assert np.array_equal(close_region(notched, 0), notched)
    closed = close_region(notched, 3.0)
    assert closed[40, 55:68].all()                                 # slit bridged
    assert np.count_nonzero(closed ^ disk) <= 6                    # and nothing else moved (rim pixels)
    assert not close_region(wide, 3.0)[40, 60:70].any()            # wide inlet stays open


def test_extract_boundaries_parameterisation_options():
    seg = make_seg(ellipse_stack(nz=21, a=40, b=28))
    arc = extract_boundaries(seg, patches=2, samples=64, parameterisation="arc-length")
    assert arc.meta["parameterisation"] == "arc-length"
    assert extract_boundaries(seg, patches=2, samples=64).meta["parameterisation"] == "aligned"
    for kwargs, message in [(dict(parameterisation="polar"), "parameterisation"),
                            (dict(curve_sigma=-1.0), "curve_sigma"), (dict(closing_mm=-2.0), "closing_mm"),
                            (dict(max_stretch=1.0), "max_stretch")]:
        with pytest.raises(BoundaryError, match=message):
            extract_boundaries(seg, patches=2, samples=64, **kwargs)


def test_cthead_aligned_default_keeps_polylines_and_improves_correspondence(cthead_seg):
    from pdehead_addon.core.curve_alignment import align_parameterisation, correspondence_error
    arc = extract_boundaries(cthead_seg, patches=10, samples=256, parameterisation="arc-length")
    aligned = extract_boundaries(cthead_seg, patches=10, samples=256)
    assert np.array_equal(arc.slice_indices, aligned.slice_indices)
    assert np.array_equal(arc.curves[:, 0], aligned.curves[:, 0])       # seam sample unchanged
    for a, b in zip(arc.curves, aligned.curves):
        assert _distance_to_polyline(b[:, :2], a[:, :2]).max() < 1e-9   # same polyline
        assert signed_area(b[:, :2]) > 0 and np.all(b[:, 2] == a[0, 2])
    assert align_parameterisation(aligned) is aligned                   # aligning twice: no-op
    before, after = correspondence_error(arc.curves), correspondence_error(aligned.curves)
    print("CThead t=10 correspondence error (mm) arc-length / aligned:", before.mean(), after.mean())
    assert after.mean() < 0.6 * before.mean() and np.median(after / before) < 0.75


def test_cthead_curve_lowpass_removes_pixel_ripple(cthead_seg):
    """The pixel-grid ripple (wavelengths below 3 px) repeats on every slice and streaks the surface."""
    def ripple(bset):
        spec = np.abs(np.fft.rfft(bset.curves[..., :2], axis=1))        # (n, H, 2)
        length = np.linalg.norm(np.diff(bset.curves, axis=1, append=bset.curves[:, :1]), axis=2).sum(1)
        wavelength = length[:, None] / np.maximum(np.arange(spec.shape[1]), 1)[None]
        return np.sqrt((spec ** 2).sum(2) * (wavelength < 3.0 * 1.0)).sum() / len(spec)
    kw = dict(patches=10, samples=1024, parameterisation="arc-length")
    raw = extract_boundaries(cthead_seg, curve_sigma=0.0, **kw)
    smooth = extract_boundaries(cthead_seg, **kw)
    print("CThead ripple (<3 px) raw / low-passed:", ripple(raw), ripple(smooth))
    assert ripple(smooth) < 0.3 * ripple(raw)
    # the shape is kept: the low-passed curves stay within ~0.1 mm (0.3 mm at the sharpest corners)
    for a, b in zip(raw.curves, smooth.curves):
        d = _distance_to_polyline(b[:, :2], a[:, :2])
        assert np.percentile(d, 99) < 0.3 and d.max() < 0.5


def test_max_patches_is_the_largest_t_the_named_selections_accept(ge_seg, cthead_seg):
    from pdehead_addon import max_patches

    for seg in (ge_seg, cthead_seg):
        t = max_patches(seg)
        assert t >= 4
        assert extract_boundaries(seg, patches=t, samples=64).patches == t
        with pytest.raises(BoundaryError, match="use fewer patches"):
            extract_boundaries(seg, patches=t + 1, samples=64)
    assert max_patches(ge_seg) < 10 <= max_patches(cthead_seg)  # the tilted GE slab is short


def test_patches_for_scan_gives_a_short_scan_the_patches_it_has(phantom_seg):
    """One rule for the add-on and the batch: a scan with fewer than 3t+1 usable slices gets the largest t it
    has, with the message that says so (the batch failed the GE slab, 28 usable slices, at t = 10 before)."""
    from pdehead_addon import max_patches, patches_for_scan
    limit = max_patches(phantom_seg)
    assert limit >= 4
    assert patches_for_scan(phantom_seg, limit) == (limit, None)
    assert patches_for_scan(phantom_seg, limit - 2) == (limit - 2, None)
    patches, message = patches_for_scan(phantom_seg, limit + 5)
    assert patches == limit
    assert f"patches reduced from {limit + 5} to {limit}" in message and f"({3 * limit + 1} slices)" in message
    extract_boundaries(phantom_seg, patches=patches)          # the reduced count is extractable
    with pytest.raises(BoundaryError):
        extract_boundaries(phantom_seg, patches=limit + 5)


def test_options_object_gives_what_the_keyword_arguments_give():
    """extract_boundaries(seg, BoundaryOptions(...)) == extract_boundaries(seg, **same fields); keywords override
    the options' fields; anything else than a BoundaryOptions in second place, or an unknown name, is refused."""
    from dataclasses import FrozenInstanceError

    from pdehead_addon import BoundaryOptions
    seg = make_seg(ellipse_stack(nz=30))
    kw = dict(PER_SLICE, patches=2, samples=48, selection="shape-change")
    by_keywords = _extract_default(seg, **kw)
    by_options = _extract_default(seg, BoundaryOptions(**kw))
    assert np.array_equal(by_keywords.curves, by_options.curves)
    assert np.array_equal(by_keywords.slice_indices, by_options.slice_indices)
    assert by_keywords.meta == by_options.meta
    overridden = _extract_default(seg, BoundaryOptions(**kw), samples=64)
    assert overridden.curves.shape == (7, 64, 3)
    assert BoundaryOptions().parameterisation == "angular" and BoundaryOptions().patches == defaults.PATCHES.default
    with pytest.raises(FrozenInstanceError):
        BoundaryOptions().patches = 3
    with pytest.raises(TypeError, match="BoundaryOptions"):
        _extract_default(seg, 3)
    with pytest.raises(TypeError):
        _extract_default(seg, no_such_option=1)
