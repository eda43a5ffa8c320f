"""The engine's CT volume helpers (pdehead_addon/core/ct_volume.py) and the defaults table (defaults.py)."""
from __future__ import annotations

import numpy as np
import pytest

from pdehead_addon import CTVolume, defaults as D
from pdehead_addon.core import ct_volume as CV


# ----------------------------------------------------------------------------- windowing (volume, solid colours)
def test_intensity_window_presets():
    rng = np.random.default_rng(1)
    values = np.concatenate([rng.normal(20, 10, 50_000), rng.normal(1050, 40, 30_000), rng.normal(2200, 200, 5000)])
    lo, hi = CV.intensity_window(values)
    np.testing.assert_allclose((lo, hi), np.percentile(values, [1.0, 99.5]), rtol=1e-6)
    assert CV.intensity_window(values, "full") == (pytest.approx(values.min()), pytest.approx(values.max()))
    assert CV.intensity_window(values, (-100, 300)) == (-100.0, 300.0)
    with pytest.raises(ValueError):
        CV.intensity_window(values, (5, 5))
    with pytest.raises(ValueError):
        CV.intensity_window(values, "bone-ish")
    out = CV.apply_window(np.array([-1e4, lo, 0.5 * (lo + hi), hi, 1e5, np.nan]), (lo, hi))
    np.testing.assert_allclose(out, [0, 0, 0.5, 1, 1, 0], atol=1e-6)
    assert out.dtype == np.float32




# ----------------------------------------------------------------------------- the one grid affine
def _oblique_ct():
    angle = np.deg2rad(20.0)
    c, s = np.cos(angle), np.sin(angle)
    direction = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # a tilted k axis
    data = np.fromfunction(lambda k, j, i: 3.0 * i + 2.0 * j + 1.0 * k, (6, 7, 8), dtype=np.float32)
    return CTVolume(data, (2.0, 0.8, 0.6), origin=(-30.0, 12.0, 85.0), direction=direction)


def test_grid_affine_is_the_ctvolume_geometry():
    ct = _oblique_ct()
    m = CV.grid_affine(ct.spacing, ct.origin, ct.direction)
    np.testing.assert_array_equal(m, ct.affine)
    kji = np.array([[0, 0, 0], [5, 6, 7], [2.5, 1.25, 3.0]])
    ijk1 = np.c_[kji[:, ::-1], np.ones(len(kji))]
    np.testing.assert_allclose((ijk1 @ m.T)[:, :3], ct.index_to_patient(kji), atol=1e-12)
    # one voxel step along k moves dz mm along the tilted direction column
    np.testing.assert_allclose(m[:3, 2], 2.0 * ct.direction[:, 2], atol=1e-12)


def test_sample_ct_is_linear_inside_and_the_lowest_value_outside():
    ct = _oblique_ct()
    kji = np.array([[1.0, 2.0, 3.0], [2.5, 3.5, 4.25], [4.0, 0.0, 6.5]])
    values = CV.sample_ct(ct, ct.index_to_patient(kji))
    np.testing.assert_allclose(values, 3.0 * kji[:, 2] + 2.0 * kji[:, 1] + kji[:, 0], rtol=1e-6)
    far = ct.index_to_patient(np.array([[20.0, 3.0, 3.0]]))
    assert CV.sample_ct(ct, far)[0] == pytest.approx(float(ct.data.min()))
    # a linear field: higher orders agree away from the edges (the third point is half a voxel from one)
    cubic = CV.sample_ct(ct, ct.index_to_patient(kji[:2]), order=3)
    np.testing.assert_allclose(cubic, values[:2], rtol=1e-4)


# ----------------------------------------------------------------------------- the defaults table
def test_every_default_lies_in_its_range_and_choices():
    assert len(D.PARAMS) >= 30
    for name, p in D.PARAMS.items():
        assert p.name == name
        values = p.default if isinstance(p.default, tuple) else (p.default,)
        for v in values:
            if isinstance(v, str):
                assert v in p.choices, name
            elif not isinstance(v, bool):
                assert p.min is None or v >= p.min, name
                assert p.max is None or v <= p.max, name
        if p.soft_min is not None:
            assert p.min <= p.soft_min <= p.soft_max <= p.max, name


def test_the_values_the_add_on_user_sees():
    # where two owners disagreed before the one table, the add-on's value won (issue 13)
    assert (D.NU.default, D.NV.default) == (120, 240)
    assert D.DENSITY.default == 40.0
    assert (D.PATCHES.default, D.PATCHES.min, D.PATCHES.max) == (15, 1, 60)
    assert D.SELECTION.default == "auto" and D.CONTINUITY.default == "c2"
    assert (D.LOW_ALPHA.default, D.HIGH_ALPHA.default) == (0.1, 0.9)   # section 5.3
    assert D.default("samples") == 256


def test_param_limits_check_and_help():
    assert D.PATCHES.limits() == {"default": 15, "min": 1, "max": 60}
    assert D.V_RANGE.limits()["soft_max"] == pytest.approx(2 * np.pi)
    assert "soft_min" not in D.NU.limits()
    assert D.PATCHES.check(60) == 60
    with pytest.raises(ValueError, match="patches must be at least 1, got 0"):
        D.PATCHES.check(0)
    with pytest.raises(ValueError, match="--nv must be at most 800"):
        D.NV.check(5000, "--nv")
    with pytest.raises(ValueError, match="selection must be one of uniform, shape-change"):
        D.SELECTION.check("random")
    assert D.VOXEL_SIZE.help("volume voxel size") == "volume voxel size; default 2 mm"
    with pytest.raises(ValueError, match="defined twice"):
        D._param("patches", 3)


def test_head_mask_on_an_axis_aligned_grid_is_the_per_voxel_lookup():
    """The intensity grid's head mask on a grid of the w-field's direction (the outer-product lookup)
    equals the nearest w-field voxel looked up voxel by voxel through the full affine map."""
    from types import SimpleNamespace

    from pdehead_addon.core.ct_volume import grid_affine, head_mask_on_grid
    rng = np.random.default_rng(3)
    w = np.where(rng.random((12, 15, 17)) < 0.03, 0.5, 2.0).astype(np.float32)
    wf = SimpleNamespace(w=w, spacing=(2.0, 1.1, 0.9), origin=np.array([-7.0, 3.0, 11.0]), direction=np.eye(3))
    shape, spacing, origin = (9, 13, 11), (2.7, 1.6, 1.3), np.array([-9.5, 1.2, 8.0])    # reaches past it
    mask = head_mask_on_grid(wf, shape, spacing, origin, np.eye(3), margin_mm=1.0)
    from scipy.ndimage import binary_dilation
    inside = binary_dilation(w <= 1.0, iterations=2)                    # ceil(1.0 / 0.9) steps
    m = np.linalg.inv(grid_affine(wf.spacing, wf.origin, wf.direction)) @ grid_affine(spacing, origin, np.eye(3))
    k, j, i = np.indices(shape).reshape(3, -1)
    ijk = np.rint(m[:3, :3] @ np.stack([i, j, k]) + m[:3, 3:]).astype(np.int64)
    ok = np.all((ijk >= 0) & (ijk < np.array(w.shape[::-1])[:, None]), axis=0)
    expected = np.zeros(len(k), bool)
    expected[ok] = inside[ijk[2, ok], ijk[1, ok], ijk[0, ok]]
    assert 0 < mask.sum() < mask.size and not ok.all()
    assert np.array_equal(mask.ravel(), expected)


# ----------------------------------------------------------------------------- the volume's decimated ct grid
@pytest.mark.parametrize("values", ["unsigned", "signed", "fractional", "huge", "nan"])
def test_decimated_block_mean_is_scipys_filter_then_decimation_bit_for_bit(values):
    """The ct grid's block means are exactly what the whole-volume uniform_filter + decimation gave (the .vdb's
    values must not move), for CT numbers (the fast exact sums) and for any other data (scipy's passes)."""
    from scipy.ndimage import uniform_filter

    rng = np.random.default_rng(5)
    checked = 0
    for shape in [(1, 5, 6), (4, 4, 4), (9, 13, 11), (33, 40, 37)]:
        if values == "unsigned":      # CT numbers from 0 (raw scanner units), zeros of air among them
            a = rng.integers(0, 65536, shape) * (rng.random(shape) < 0.7)
        elif values == "signed":      # Hounsfield units
            a = rng.integers(-32768, 32768, shape)
        elif values == "fractional":  # rescaled with a non-integer slope
            a = rng.random(shape) * 3000 - 1000
        elif values == "huge":        # whole numbers beyond 16 bits: not the exact fast path
            a = rng.integers(-200_000, 200_000, shape)
        else:
            a = rng.integers(0, 3000, shape).astype(float)
            a.flat[3] = np.nan
        a = a.astype(np.float32)
        for steps in [(2, 3, 3), (1, 2, 2), (4, 1, 3), (3, 2, 1), (5, 4, 2), (8, 8, 8), (16, 16, 16), (1, 1, 1)]:
            want = uniform_filter(a, size=steps, mode="nearest")[::steps[0], ::steps[1], ::steps[2]]
            for block_bytes in (1, 1 << 23):  # one output slice per slab, and the default
                got = CV.decimated_block_mean(a, steps, block_bytes=block_bytes)
                assert got.dtype == np.float32 and got.shape == want.shape
                assert np.array_equal(got, want, equal_nan=True), (shape, steps, block_bytes)
                checked += 1
    assert checked == 64


def test_whole_numbers_tells_the_exact_fast_path():
    assert CV._whole_numbers(np.array([[[0, 65535]]], np.float32)) == "unsigned"
    assert CV._whole_numbers(np.array([[[-1024, 3071]]], np.float32)) == "signed"
    for other in ([0.5, 1], [-1, 65535], [70000, 0], [np.nan, 0]):
        assert CV._whole_numbers(np.array([[other]], np.float32)) is None
    assert CV._whole_numbers(np.zeros((1, 1, 2), np.float64)) is None
