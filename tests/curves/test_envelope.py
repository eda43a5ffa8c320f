"""The default curve path of ``extract_boundaries``: the 3-D envelope, star hulls, the spine and the angular
samples, each on shapes with a known answer, then the whole default path on a synthetic ellipsoid.

The per-slice path (2-D mask outline, arc-length / aligned samples) is tested in test_boundaries.py.
"""
from __future__ import annotations

import numpy as np
import pytest

from pdehead_addon import CTVolume, Segmentation, defaults, extract_boundaries
from pdehead_addon.curves.curve_sampling import STAR_MAX_SLOPE, angular_curves, signed_area, spine_centres, star_hull
from pdehead_addon.curves.envelope import head_envelope
from pdehead_addon.curves.slice_outlines import contour_from_field

SPACING = (2.0, 0.8, 0.9)          # dz, dy, dx: anisotropic on purpose
ORIGIN = (-40.0, -55.0, 12.0)


def grid(shape):
    return np.mgrid[:shape[0], :shape[1], :shape[2]].astype(float)


def ball_mask(shape=(50, 140, 130), centre=(24.5, 70.2, 64.7), radius=30.0, spacing=SPACING):
    zz, yy, xx = grid(shape)
    dist = np.sqrt(((zz - centre[0]) * spacing[0]) ** 2 + ((yy - centre[1]) * spacing[1]) ** 2
                   + ((xx - centre[2]) * spacing[2]) ** 2)
    return dist <= radius


# --- the envelope --------------------------------------------------------------------------------------------

def test_envelope_of_a_ball_keeps_its_radius_and_places_its_window():
    """The 0.5 level of the envelope of a 30 mm ball, traced on one slice and put back in volume pixels by the
    window, is the ball's circle there (the Gaussian moves a 30 mm sphere's level by sigma^2 / R = 0.03 mm)."""
    centre, radius = (24.5, 70.2, 64.7), 30.0
    mask = ball_mask(centre=centre, radius=radius)
    field, window = head_envelope(mask, SPACING)
    assert field.dtype == np.float32 and 0.0 <= field.min() and field.max() <= 1.0
    zs = np.flatnonzero(mask.any(axis=(1, 2)))
    assert (window[0].start, window[0].stop) == (zs[0], zs[-1] + 1) and len(field) == len(zs)
    for k in (25, 30, 35):
        rc, info = contour_from_field(field[k - window[0].start], origin=(window[1].start, window[2].start))
        r = np.hypot((rc[:, 0] - centre[1]) * SPACING[1], (rc[:, 1] - centre[2]) * SPACING[2])
        expected = np.sqrt(radius ** 2 - ((k - centre[0]) * SPACING[0]) ** 2)
        assert abs(r.mean() - expected) < 0.1 and np.abs(r - expected).max() < 0.5, (k, r.mean(), expected)
        assert info["area_px"] * SPACING[1] * SPACING[2] == pytest.approx(np.pi * expected ** 2, rel=0.01)


def test_envelope_closing_bridges_a_narrow_inlet_that_the_gaussian_alone_leaves_open():
    """A 2.4 mm slot 8 mm deep in the ball (a nostril): the 3 mm ball closing fills it (field ~1 inside it);
    without the closing the slot stays below the 0.5 level."""
    centre, radius = (24.5, 70.2, 64.7), 30.0
    zz, yy, xx = grid((50, 140, 130))
    slot = (np.abs((yy - centre[1]) * SPACING[1]) < 1.2) & ((xx - centre[2]) * SPACING[2] > radius - 8.0)
    mask = ball_mask(centre=centre, radius=radius) & ~slot
    k, j, i = 25, int(round(centre[1])), int(round(centre[2] + (radius - 4.0) / SPACING[2]))
    assert not mask[k, j, i]
    values = {}
    for closing in (3.0, 0.0):
        field, window = head_envelope(mask, SPACING, closing_mm=closing)
        values[closing] = float(field[k - window[0].start, j - window[1].start, i - window[2].start])
    assert values[3.0] > 0.95 and values[0.0] < 0.4, values


def test_envelope_keeps_a_head_cut_by_the_scan_square_and_rounds_one_ending_inside_it():
    """A cylinder running out of the bottom of the scan keeps its full cross-section in the first slice (the
    neck's cut is not rounded off); where it ends inside the scan its last slice is rounded."""
    shape, centre_yx, radius = (30, 100, 100), (50.0, 50.0), 25.0
    zz, yy, xx = grid(shape)
    mask = (np.hypot((yy - centre_yx[0]) * SPACING[1], (xx - centre_yx[1]) * SPACING[2]) <= radius) & (zz <= 20)
    field, window = head_envelope(mask, SPACING)
    assert window[0].start == 0 and window[0].stop == 21
    j, i = 50 - window[1].start, 50 - window[2].start
    assert field[0, j, i] == pytest.approx(1.0, abs=1e-4) and field[10, j, i] == pytest.approx(1.0, abs=1e-4)
    rc, _ = contour_from_field(field[0], origin=(window[1].start, window[2].start))
    r = np.hypot((rc[:, 0] - centre_yx[0]) * SPACING[1], (rc[:, 1] - centre_yx[1]) * SPACING[2])
    assert abs(r.mean() - radius) < 0.3
    # the last slice of the head inside the scan: the Gaussian along z (sigma 1 mm = half a slice; weights
    # exp(-2 n^2) over n = -2..2) sees the air above it, unlike the cut end
    w = np.exp(-2.0 * np.arange(-2, 3) ** 2)
    assert field[20, j, i] == pytest.approx(w[:3].sum() / w.sum(), abs=1e-4)


def test_envelope_refuses_an_empty_mask_and_negative_sizes():
    from pdehead_addon import BoundaryError
    with pytest.raises(BoundaryError):
        head_envelope(np.zeros((5, 10, 10), bool), SPACING)
    with pytest.raises(BoundaryError):
        head_envelope(ball_mask(), SPACING, sigma_mm=-1.0)


# --- star hulls ----------------------------------------------------------------------------------------------

THETA = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)


def polar_curve(r, centre=(0.0, 0.0)):
    return np.column_stack([centre[0] + r * np.cos(THETA), centre[1] + r * np.sin(THETA)])


def test_star_hull_of_a_circle_is_the_circle_counter_clockwise():
    hull = star_hull(polar_curve(np.full(720, 50.0), centre=(3.0, -2.0))[::-1])      # given clockwise
    assert hull.shape == (1440, 2)
    assert np.abs(np.hypot(hull[:, 0] - 3.0, hull[:, 1] + 2.0) - 50.0).max() < 1e-3
    assert signed_area(hull) == pytest.approx(np.pi * 50.0 ** 2, rel=1e-3)          # > 0: counter-clockwise


def test_star_hull_fills_an_inlet_whose_walls_face_the_centre():
    """An oblique slit 15 mm deep (the notch behind an ear): every ray meets the outer circle beyond it, so
    the plain hull is the circle again; the input is inside the hull everywhere."""
    r = 50.0
    k = 100                                                           # the slit leaves the circle here
    tip = (r - 15.0) * np.array([np.cos(THETA[k] + 0.3), np.sin(THETA[k] + 0.3)])
    curve = np.vstack([polar_curve(np.full(720, r))[:k + 1], tip, polar_curve(np.full(720, r))[k + 1:]])
    assert np.hypot(*curve.T).min() == pytest.approx(r - 15.0)
    hull = star_hull(curve, centre=np.zeros(2), max_slope=None)
    radius = np.hypot(*hull.T)
    assert radius.min() > r - 0.5 and radius.max() < r + 1e-6
    phi = np.arctan2(curve[:, 1], curve[:, 0])
    hull_r_at = np.interp(phi, np.arctan2(hull[:, 1], hull[:, 0]), radius, period=2 * np.pi)
    inside = np.hypot(*curve.T) - hull_r_at
    # the rays through the slit's mouth (0.44 mm wide) meet only its walls: there the hull dips by 0.47 mm
    assert np.all(inside <= 0.5) and np.count_nonzero(inside > 1e-3) <= 2


@pytest.mark.parametrize("slope", [None, STAR_MAX_SLOPE, 1.0])
def test_star_hull_slope_bound_turns_a_spike_into_a_web(slope):
    """A 2-degree spike to 80 mm on a 50 mm circle: the plain hull keeps it as a radial wall (2.5 degrees wide
    at the 1440 rays); with the bound, |d ln r / d theta| <= slope everywhere and the web is as wide as
    ln(80 / 50) / slope demands on each side (the corners' fillet off: it is tested below)."""
    r = np.where(np.abs(np.angle(np.exp(1j * (THETA - 1.0)))) < np.radians(1.0), 80.0, 50.0)
    hull = star_hull(polar_curve(r), centre=np.zeros(2), max_slope=slope, fillet_mm=0.0)
    radius = np.hypot(*hull.T)
    assert radius.max() == pytest.approx(80.0, abs=1e-3) and radius.min() == pytest.approx(50.0, abs=1e-3)
    log_r = np.log(radius)
    steepest = np.abs(np.diff(np.r_[log_r, log_r[:1]])).max() / (2 * np.pi / len(radius))
    raised_deg = np.count_nonzero(radius > 50.01) * 360.0 / len(radius)
    if slope is None:
        assert steepest > 50 and raised_deg == pytest.approx(2.5, abs=0.3)
    else:
        assert steepest == pytest.approx(slope, rel=1e-6)
        web_deg = 2 * np.degrees(np.log(80.0 / 50.0) / slope) + 2.0
        assert raised_deg == pytest.approx(web_deg, abs=0.6), (raised_deg, web_deg)


def test_star_hull_carries_z():
    curve = np.column_stack([polar_curve(np.full(720, 40.0)), np.full(720, 17.5)])
    hull = star_hull(curve)
    assert hull.shape == (1440, 3) and np.allclose(hull[:, 2], 17.5)


# --- the spine and the angular samples ------------------------------------------------------------------------

def ellipse_outlines(a=40.0, b=28.0, heights=tuple(5.0 * k for k in range(8)), tilt=0.5, jitter=0.0):
    """Ellipses x = 10 + tilt z + a cos, y = -5 + b sin at each height; every other one moved by +-jitter in x."""
    return [np.column_stack([10.0 + tilt * z + jitter * (-1) ** n + a * np.cos(THETA), -5.0 + b * np.sin(THETA),
                             np.full(720, z)]) for n, z in enumerate(heights)]


def test_spine_follows_a_straight_axis_exactly_and_smooths_a_jittering_one():
    heights = np.arange(8) * 5.0
    axis = np.column_stack([10.0 + 0.5 * heights, np.full(8, -5.0)])
    assert np.abs(spine_centres(ellipse_outlines()) - axis).max() < 1e-9        # a line: the spline keeps it
    jittered = spine_centres(ellipse_outlines(jitter=1.0))                     # +-1 mm from slice to slice
    assert np.abs(jittered - axis).max() < 0.15
    assert np.abs(spine_centres(ellipse_outlines(jitter=1.0)[::-1]) - jittered[::-1]).max() < 1e-9  # any order


@pytest.mark.parametrize("smooth", [0.0, 1.5])
def test_angular_curves_sample_each_ellipse_at_equal_angles_from_the_spine(smooth):
    """Sample m lies on the ray at pi/2 + 2 pi m / M from the spine (m = 0 posterior, +y), at the ellipse's
    radius there, r = ab / sqrt((b cos)^2 + (a sin)^2); the slope bound (3) leaves an ellipse of 40 x 28
    alone (its |d ln r / d theta| <= 0.37) and the low-pass moves it by well under 0.1 mm."""
    a, b, samples = 40.0, 28.0, 64
    heights = np.arange(8) * 5.0
    curves = angular_curves(ellipse_outlines(a, b, heights), samples, smooth=smooth)
    assert curves.shape == (8, samples, 3)
    theta = 0.5 * np.pi + 2 * np.pi * np.arange(samples) / samples
    r = a * b / np.hypot(b * np.cos(theta), a * np.sin(theta))
    for n, z in enumerate(heights):
        expected = np.column_stack([10.0 + 0.5 * z + r * np.cos(theta), -5.0 + r * np.sin(theta), np.full(samples, z)])
        assert np.abs(curves[n] - expected).max() < (0.03 if smooth == 0 else 0.1), n


# --- the whole default path ----------------------------------------------------------------------------------

ELLIPSOID_AXES = (55.0, 48.0, 40.0)      # semi-axes z, y, x in mm
ELLIPSOID_CENTRE = (34.3, 74.6, 69.2)    # voxel (k, j, i)


def ellipsoid_segmentation(slot: bool = False):
    shape = (70, 150, 140)
    zz, yy, xx = grid(shape)
    rel = [(zz - ELLIPSOID_CENTRE[0]) * SPACING[0], (yy - ELLIPSOID_CENTRE[1]) * SPACING[1],
           (xx - ELLIPSOID_CENTRE[2]) * SPACING[2]]
    mask = sum((q / s) ** 2 for q, s in zip(rel, ELLIPSOID_AXES)) <= 1.0
    if slot:        # a 2.4 mm wide, 10 mm deep slit on the patient's right (-x) side, 20 mm high
        mask &= ~((np.abs(rel[1]) < 1.2) & (rel[2] < -(ELLIPSOID_AXES[2] - 10.0)) & (np.abs(rel[0]) < 10.0))
    ct = CTVolume(mask.astype(np.float32), SPACING, origin=ORIGIN, meta={"source": "synthetic"})
    return Segmentation(mask, mask.astype(np.float32), 1.0, 0.0, 0, ct, {}), ct


def ellipsoid_error_mm(ct, curves):
    """Signed distance (about, in mm) of curve points from the ellipsoid: (implicit radius - 1) x 40 mm."""
    rel = curves - ct.index_to_patient(np.array(ELLIPSOID_CENTRE))
    az, ay, ax = ELLIPSOID_AXES
    return (np.sqrt((rel[..., 0] / ax) ** 2 + (rel[..., 1] / ay) ** 2 + (rel[..., 2] / az) ** 2) - 1.0) * min(ax, ay)


def test_default_path_on_an_ellipsoid_records_itself_and_samples_at_equal_angles_on_the_surface():
    seg, ct = ellipsoid_segmentation()
    bset = extract_boundaries(seg)                                              # every default
    meta = bset.meta
    assert (meta["level_field"], meta["parameterisation"], meta["star_shaped"]) == ("envelope", "angular", True)
    assert meta["selection"] == "uniform"
    assert bset.curves.shape == (3 * defaults.PATCHES.default + 1, defaults.SAMPLES.default, 3)
    err = ellipsoid_error_mm(ct, bset.curves)
    assert np.abs(err).mean() < 0.1 and np.abs(err).max() < 0.5, (np.abs(err).mean(), np.abs(err).max())
    rel = bset.curves - ct.index_to_patient(np.array(ELLIPSOID_CENTRE))
    theta = 0.5 * np.pi + 2 * np.pi * np.arange(256) / 256
    off = np.angle(np.exp(1j * (np.arctan2(rel[..., 1], rel[..., 0]) - theta)))
    assert np.abs(off).max() < 0.005                                            # rad: the spine is the axis
    assert np.all(bset.curves[..., 2] == bset.heights[:, None])                 # each curve on its slice
    assert np.all(np.diff(bset.heights) > 0)


def test_default_path_bridges_a_slit_that_the_per_slice_outline_follows():
    """The slit (a nostril) is bridged by the envelope: the default curves stay within about a millimetre of the
    ellipsoid (0.93 mm at most, on the curves at the slit's ends; 0.31 mm without a slit); the per-slice
    outline without closing or star hull runs 10 mm into the slit."""
    seg, ct = ellipsoid_segmentation(slot=True)
    default = ellipsoid_error_mm(ct, extract_boundaries(seg).curves)
    raw = ellipsoid_error_mm(ct, extract_boundaries(seg, level_field="mask", parameterisation="arc-length",
                                                    star_shaped=False, closing_mm=0.0).curves)
    assert np.abs(default).max() < 1.2, np.abs(default).max()
    assert raw.min() < -5.0, raw.min()


def test_star_hull_rounds_the_sharp_corner_where_a_web_meets_the_outline_and_nothing_else():
    """A spike (an ear seen from above) becomes a web at the slope bound; where the web lands on the outline it
    turns by 68 deg (over 0.75 mm chords), a slit on the columns. The 3 mm fillet turns that corner into an arc
    (at most ~21 deg), raising r by < 1 mm on a few samples at the web's feet; a gentle 3 mm valley elsewhere
    (a turn of 2 deg) keeps its shape exactly, and r never decreases."""
    from pdehead_addon.curves.curve_sampling import STAR_FILLET_MM, polar_turns
    n = 1440
    phi = (np.arange(n) + 0.5) / n * 2 * np.pi - np.pi
    r = 100 - 3 * np.exp(-0.5 * ((phi - 2.0) / 0.1) ** 2)
    r[np.abs(phi) < 0.02] = 140
    pts = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
    sharp = np.hypot(*star_hull(pts, np.zeros(2), fillet_mm=0).T)
    rounded = np.hypot(*star_hull(pts, np.zeros(2)).T)
    assert STAR_FILLET_MM == 3.0
    assert polar_turns(sharp, 0.75).min() < -60 and polar_turns(rounded, 0.75).min() > -30
    raised = rounded - sharp
    assert raised.min() >= 0 and 0.3 < raised.max() < 1.5
    assert np.all(np.abs(phi[raised > 1e-9]) < 0.2)                    # only at the web's feet
    valley = np.abs(phi - 2.0) < 0.5
    assert np.array_equal(rounded[valley], sharp[valley]) and sharp[valley].min() < 97.5
