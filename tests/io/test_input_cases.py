"""Unusual and bad inputs (issue 11): each case is fed and its error or warning asserted.

Every case here was once silent or misleading. The phantom (exact truth) is written to disk in the
form of the case (DICOM with out-of-field pixels, raw posterior-first, NaN floats, ...) in tmp_path.
"""
from __future__ import annotations

import gzip
import warnings
from pathlib import Path

import numpy as np
import pydicom
import pytest
from pydicom.uid import JPEG2000Lossless, RLELossless

from datasets import shared_data
from pdehead_addon import (
    CTImportError,
    CTImportWarning,
    CTVolume,
    HeadSizeWarning,
    SegmentationError,
    load_ct,
    make_phantom,
    segment_head,
)
from pdehead_addon.io.input_checks import parse_orientation
from pdehead_addon.validation import metrics as M, write_dicom_series


def load_w(*args, **kw):
    """load_ct and the text of its CTImportWarnings."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ct = load_ct(*args, **kw)
    return ct, [str(w.message) for w in caught if issubclass(w.category, CTImportWarning)]


def segment_w(ct, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        seg = segment_head(ct, **kw)
    return seg, [str(w.message) for w in caught if issubclass(w.category, HeadSizeWarning)]


@pytest.fixture(scope="module")
def ph():
    return make_phantom()


def outside_circle(shape):
    ny, nx = shape[-2:]
    yy, xx = np.mgrid[:ny, :nx]
    return ((yy - (ny - 1) / 2) / ((ny - 1) / 2)) ** 2 + ((xx - (nx - 1) / 2) / ((nx - 1) / 2)) ** 2 > 1.0


def write_raw(path: Path, data: np.ndarray, dtype=">i2") -> Path:
    np.ascontiguousarray(data).astype(dtype).tofile(path)
    return path


def raw_opts(ph, **kw):
    nz, ny, nx = ph.ct.shape
    return dict(format="raw", shape=(nz, ny, nx), dtype=">i2", spacing=ph.ct.spacing, **kw)


def per_slice_ok(mask, truth, mean_min=0.99, min_min=0.97):
    per = M.slice_jaccard_on_head(mask, truth, 0.01)
    assert per.mean() >= mean_min and per.min() >= min_min, (per.mean(), per.min())
    return per


# ------------------------------------------------------------------------- 1. out-of-field values
def test_out_of_field_minus_3024_without_padding_tag_dicom(ph, tmp_path):
    """GE/Siemens: the pixels outside the scan circle are -3024 HU and no PixelPaddingValue says so."""
    data = ph.ct.data.copy()
    corners = np.broadcast_to(outside_circle(data.shape), data.shape)
    data[corners] = -3024.0
    write_dicom_series(CTVolume(data, ph.ct.spacing, ph.ct.origin), tmp_path / "dcm", rescale_intercept=-1024.0)
    ct, warns = load_w(tmp_path / "dcm")
    hit = [w for w in warns if "out-of-field value -3024 HU" in w]
    assert len(hit) == 1, warns
    assert "100 % of them outside the circular field of view" in hit[0] and "no PixelPaddingValue" in hit[0]
    assert ct.meta["out_of_field"]["count"] == int(corners.sum())
    assert ct.data.min() > -1200 and np.all(ct.data[corners] == -1000.0)
    seg = segment_head(ct)
    assert seg.mask.mean() < 0.5                       # not the scan circle (85 % before the fix)
    per_slice_ok(seg.mask, ph.head_mask)


@pytest.mark.parametrize("units", [None, "HU"])
def test_out_of_field_in_raw_data_from_histogram_and_circle(ph, tmp_path, units):
    data = ph.ct.data.copy()
    corners = np.broadcast_to(outside_circle(data.shape), data.shape)
    data[corners] = -3024.0
    path = write_raw(tmp_path / "vol.raw", np.rint(data))
    ct, warns = load_w(path, **raw_opts(ph, units=units))
    rule = "below -1500 HU" if units == "HU" else "a spike at the minimum, outside the circular field of view"
    assert any("out-of-field value -3024" in w and rule in w for w in warns), warns
    fill = ct.meta["out_of_field"]["fill"]
    assert (fill == -1000.0) if units == "HU" else (-1060 < fill < -940)   # the air level of the scan
    assert ct.meta["units"] == ("HU" if units == "HU" else "stored value (not calibrated HU)")


def test_real_air_at_the_minimum_is_not_out_of_field(ph, tmp_path):
    """Clipped air (-1024 everywhere in the air, not only outside the circle) is not touched."""
    data = np.maximum(ph.ct.data, -1010.0)
    ct, warns = load_w(write_raw(tmp_path / "v.raw", np.rint(data)), **raw_opts(ph))
    assert ct.meta["out_of_field"] is None and not any("out-of-field" in w for w in warns)


# ------------------------------------------------------------------------- 2. single tilted slice
def test_single_tilted_slice_cannot_make_a_volume(tmp_path):
    from test_ct_import import write_slice
    t = np.radians(18.5)
    path = tmp_path / "one.dcm"
    write_slice(path, np.full((64, 64), 1024), (-32.0, -32.0, 0.0), (1, 0, 0, 0, np.cos(t), -np.sin(t)),
                intercept=-1024)
    with pytest.raises(CTImportError, match="a single tilted or oblique slice cannot make a volume") as err:
        load_ct(path)
    assert str(path) in str(err.value)
    # an axial single slice still loads (the paper's per-slice mode), with advice that names slices
    (tmp_path / "ax").mkdir()
    write_slice(tmp_path / "ax" / "one.dcm", np.full((64, 64), 1024), (0.0, 0.0, 0.0), thickness=2.0)
    ct, warns = load_w(tmp_path / "ax")
    assert ct.shape == (1, 64, 64)
    assert any("single slice" in w and "needs at least 4 slices" in w for w in warns), warns


# ------------------------------------------------------------------------- 3. NaN voxels
def test_nan_voxels_are_counted_filled_as_air_and_refused_by_segmentation(ph, tmp_path):
    data = ph.ct.data.copy()
    rng = np.random.default_rng(3)
    idx = rng.choice(data.size, 57, replace=False)
    data.flat[idx] = np.nan
    data.flat[idx[:3]] = np.inf
    path = write_raw(tmp_path / "f.raw", data, "<f4")
    ct, warns = load_w(path, **dict(raw_opts(ph), dtype="<f4"))
    assert any(": 57 voxel(s)" in w and "NaN or infinite" in w and "filled as air" in w for w in warns), warns
    assert np.isfinite(ct.data).all() and ct.meta["non_finite_voxels"] == 57
    assert ct.meta["hu_range"][0] == float(np.nanmin(ph.ct.data))
    with pytest.raises(SegmentationError, match="57 voxel.*NaN or infinite"):
        segment_head(CTVolume(data, ph.ct.spacing))
    all_nan = write_raw(tmp_path / "n.raw", np.full((2, 4, 4), np.nan), "<f4")
    with pytest.raises(CTImportError, match="NaN or infinite"):
        load_ct(all_nan, format="raw", shape=(4, 4), dtype="<f4", spacing=(1, 1, 1))


# ------------------------------------------------------------------------- 4. implausible geometry
@pytest.mark.parametrize("factor, match", [(10.0, "metres, not a human head"),
                                           (0.005, "no human head is this small")])
def test_absurd_spacing_is_refused_early_and_names_the_spacing(ph, factor, match):
    spacing = tuple(h * factor for h in ph.ct.spacing)
    with pytest.raises(SegmentationError, match=match) as err:
        segment_head(CTVolume(ph.ct.data, spacing))
    assert f"({spacing[0]:g}, {spacing[1]:g}, {spacing[2]:g}) mm" in str(err.value)


def test_tiny_test_series_is_not_an_8_mm_head(ph):
    small = CTVolume(ph.ct.data[:, ::8, ::8], (2.3, 0.5, 0.5))      # 16 x 16 pixels of 0.5 mm
    with pytest.raises(SegmentationError, match="no human head is this small"):
        segment_head(small)
    with pytest.raises(SegmentationError, match=r"3 x 8 x 8 voxels .* too small"):
        segment_head(CTVolume(ph.ct.data[40:43, ::16, ::16], (2.3, 16.0, 16.0)))


def test_head_outside_human_range_warns_and_phantom_does_not(ph):
    seg, warns = segment_w(ph.ct)
    assert warns == [] and seg.meta["warnings"] == []
    ex, ey, ez = seg.meta["head_extent_mm"]
    assert 160 < ex < 175 and 200 < ey < 215 and 180 < ez < 230
    big, warns = segment_w(CTVolume(ph.ct.data, tuple(2.0 * h for h in ph.ct.spacing)))
    assert len(warns) == 1 and "outside the human range" in warns[0] and "y 4" in warns[0], warns
    assert "(4.6, 4, 4) mm" in warns[0] and big.meta["warnings"] == warns


# ------------------------------------------------------------------------- 5. orientation codes
def test_posterior_first_raw_warns_and_orientation_fixes_it(ph, tmp_path):
    path = write_raw(tmp_path / "back_first.raw", np.rint(ph.ct.data[:, ::-1]))   # row 0 = back of the head
    ct, warns = load_w(path, **raw_opts(ph))
    hit = [w for w in warns if "the face (nose) seems to lie on the side" in w]
    assert len(hit) == 1 and "orientation='LAS'" in hit[0], warns
    assert ct.meta["face_side"]["side"] == "high"
    ct, warns = load_w(path, **raw_opts(ph, orientation="LAS"))
    assert warns == [] and ct.meta["orientation"] == "LAS" and ct.meta["face_side"]["side"] == "low"
    np.testing.assert_array_equal(ct.data, np.rint(ph.ct.data))


def test_sagittal_stack_with_orientation_PIL(ph, tmp_path):
    """Files toward the patient's left, rows toward inferior, columns toward posterior."""
    folder = tmp_path / "sag"
    folder.mkdir()
    sag = np.rint(ph.ct.data[::-1].transpose(2, 0, 1))          # [file (x), row (-z), column (y)]
    for f, image in enumerate(sag):
        write_raw(folder / f"s{f:03d}.raw", image)
    dz, dy, dx = ph.ct.spacing
    ct, warns = load_w(folder, format="raw", shape=sag.shape[1:], dtype=">i2", spacing=(dx, dz, dy),
                       orientation="PIL")
    assert ct.spacing == ph.ct.spacing and warns == []
    np.testing.assert_array_equal(ct.data, np.rint(ph.ct.data))


def test_orientation_code_errors(ph, tmp_path):
    path = write_raw(tmp_path / "v.raw", np.rint(ph.ct.data))
    for bad in ("LPX", "LLS", "LP"):
        with pytest.raises(CTImportError, match="orientation"):
            load_ct(path, **raw_opts(ph, orientation=bad))
    with pytest.raises(CTImportError, match="contradicts orientation"):
        load_ct(path, **raw_opts(ph, orientation="LPS", first_slice="superior"))
    assert [list(v) for v in parse_orientation("ras")] == [[-1, 0, 0], [0, -1, 0], [0, 0, 1]]


# ------------------------------------------------------------------------- 6. MRI, units, gzip
def test_mri_nifti_says_it_is_not_ct():
    ct, warns = load_w(shared_data("mri_colin27_ch2", "ch2.nii.gz"))
    assert any("this does not look like CT" in w and "MRI" in w for w in warns), warns
    assert ct.meta["modality"] == "not CT?"


def test_gzipped_raw_is_read_directly(ph, tmp_path):
    plain = write_raw(tmp_path / "v.raw", np.rint(ph.ct.data))
    packed = tmp_path / "v.raw.gz"
    packed.write_bytes(gzip.compress(plain.read_bytes(), compresslevel=1))
    a, _ = load_w(plain, **raw_opts(ph))
    b, _ = load_w(packed, **raw_opts(ph))
    np.testing.assert_array_equal(a.data, b.data)
    nz, ny, nx = ph.ct.shape
    with pytest.raises(CTImportError, match=r"decompressed \(gzip\) size"):
        load_ct(packed, format="raw", shape=(nz + 1, ny, nx), dtype=">i2", spacing=ph.ct.spacing)


# ------------------------------------------------------------------------- compressed DICOM, DICOMDIR
@pytest.fixture(scope="module")
def phantom_series(ph, tmp_path_factory):
    folder = tmp_path_factory.mktemp("series") / "plain"
    files = write_dicom_series(ph.ct, folder)
    return folder, files


@pytest.fixture(scope="module")
def plain_seg(phantom_series):
    ct = load_ct(phantom_series[0])
    return ct, segment_head(ct)


@pytest.mark.parametrize("syntax", [RLELossless, JPEG2000Lossless], ids=["rle", "jpeg2000"])
def test_compressed_series_give_the_same_mask(phantom_series, plain_seg, syntax, tmp_path):
    folder = tmp_path / syntax.name.split()[0]
    folder.mkdir()
    for f in phantom_series[1]:
        ds = pydicom.dcmread(f)
        ds.compress(syntax)
        ds.save_as(folder / f.name)
    assert pydicom.dcmread(next(folder.iterdir())).file_meta.TransferSyntaxUID == syntax
    ct, _ = load_w(folder)
    assert ct.meta["transfer_syntax"] == syntax.name
    plain_ct, plain = plain_seg
    np.testing.assert_array_equal(ct.data, plain_ct.data)
    np.testing.assert_array_equal(segment_head(ct).mask, plain.mask)


def test_dicomdir_file_set_is_read(phantom_series, plain_seg, tmp_path):
    from pydicom.fileset import FileSet
    fs = FileSet()
    for f in phantom_series[1]:
        ds = pydicom.dcmread(f)
        # the STUDY record of a file-set needs these (the export leaves them empty)
        ds.StudyDate, ds.StudyTime, ds.StudyID = "20260101", "120000", "1"
        fs.add(ds)
    out = tmp_path / "cd"
    fs.write(out)
    names = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert "DICOMDIR" in names and not any(n.endswith(".dcm") for n in names)
    plain_ct, _ = plain_seg
    from pdehead_addon import list_series
    assert [i.slice_count for i in list_series(out / "DICOMDIR")] == [len(phantom_series[1])]
    for source in (out / "DICOMDIR", out):
        ct, warns = load_w(source)
        np.testing.assert_array_equal(ct.data, plain_ct.data)
        assert ct.meta["files"] == len(phantom_series[1]) and warns == []
    # a DICOMDIR whose files were lost says so
    first = next(p for p in sorted(out.rglob("*")) if p.is_file() and p.name != "DICOMDIR")
    first.unlink()
    _, warns = load_w(out / "DICOMDIR")
    assert any("refers to 1 missing file(s)" in w for w in warns), warns


# ------------------------------------------------------------------------- large scans
def test_downsample_keeps_patient_positions_and_means(ph, tmp_path):
    from pdehead_addon.core.ct_volume import downsample_volume
    small = downsample_volume(ph.ct, 2)
    assert small.shape == (50, 64, 64) and small.spacing == tuple(2 * h for h in ph.ct.spacing)
    np.testing.assert_allclose(small.data[3, 4, 5], ph.ct.data[6:8, 8:10, 10:12].mean(), rtol=1e-5)
    # voxel (k, j, i) of the small grid sits at the centre of its block
    centre = ph.ct.index_to_patient(np.array([6.5, 8.5, 10.5]))
    np.testing.assert_allclose(small.index_to_patient(np.array([3, 4, 5])), centre, atol=1e-9)
    ct, warns = load_w(write_raw(tmp_path / "v.raw", np.rint(ph.ct.data)), **raw_opts(ph, downsample=(1, 2, 2)))
    assert ct.shape == (100, 64, 64) and any("downsampled (100, 128, 128) -> (100, 64, 64)" in w for w in warns)


def test_shoulders_do_not_join_the_head_mask():
    """A head-and-neck scan (the phantom with a trunk painted below the neck) stops at the neck."""
    sys_path = str(Path(__file__).resolve().parents[2] / "scripts" / "bench")
    import sys
    sys.path.insert(0, sys_path)
    import bench_large_scan as B
    shape = (200, 256, 256)
    spacing = tuple(f / n for f, n in zip(B.FOV_MM, shape))
    ph = make_phantom(shape=shape, spacing=spacing)
    trunk = B.add_shoulders(ph.ct)
    assert trunk.sum() > 80
    seg, warns = segment_w(ph.ct)
    neck = seg.meta["cleanup"]["neck_cut"]
    assert neck is not None and len(warns) == 1 and "into the shoulders" in warns[0]
    assert not seg.mask[trunk].any()                               # nothing of the trunk
    zs = ph.ct.slice_heights()
    lowest = zs[np.flatnonzero(seg.mask.any(axis=(1, 2)))[0]]
    assert B.SHOULDER["z_neck"] < lowest < B.SHOULDER["z_neck"] + 30  # ... and the neck down to near the shoulders
    width = [np.ptp(np.flatnonzero(m.any(axis=0))) * spacing[2] for m in seg.mask if m.any()]
    assert max(width) < 175                                        # the head's own width (166 mm with ears)
    above = ~trunk & (zs > lowest)
    per = M.slice_jaccard_on_head(seg.mask[above], ph.head_mask[above], 0.01)
    assert per.mean() > 0.97


def test_too_large_scan_is_offered_a_downsample_before_any_work(ph):
    # the phantom's 1.6 M voxels need about 0.049 GB: a budget of 0.02 GB stands for a scan too large
    with pytest.raises(SegmentationError, match=r"128 x 128 x 100 voxels \(x, y, z\) needs about 0.0492 GB, more "
                                                r"than the 0.02 GB budget; import the scan again with "
                                                r"downsample=2 for about 0.0061\d GB"):
        segment_head(ph.ct, max_memory_gb=0.02)


def test_jpeg_ls_file_decodes_like_the_uncompressed_one():
    """JPEG-LS (pydicom cannot write it): pydicom's own test pair, decoded by pylibjpeg-libjpeg."""
    from pydicom.data import get_testdata_file
    plain, _ = load_w(get_testdata_file("MR_small.dcm"))
    jls, warns = load_w(get_testdata_file("MR_small_jpeg_ls_lossless.dcm"))
    assert jls.meta["transfer_syntax"] == "JPEG-LS Lossless Image Compression"
    np.testing.assert_array_equal(jls.data, plain.data)
    assert any("modality is MR, not CT" in w for w in warns)


def test_image_stack_orientation_and_face_warning(ph, tmp_path):
    """Numbered 8-bit PNG slices stored back-of-the-head first, as in the raw case."""
    from PIL import Image
    grey = np.clip((ph.ct.data[:, ::-1] + 1000.0) / 8.0, 0, 255).astype(np.uint8)
    folder = tmp_path / "png"
    folder.mkdir()
    for k, image in enumerate(grey):
        Image.fromarray(image).save(folder / f"slice{k + 1}.png")
    ct, warns = load_w(folder, spacing=ph.ct.spacing)
    assert any("the face (nose) seems to lie on the side" in w for w in warns), warns
    ct, warns = load_w(folder, spacing=ph.ct.spacing, orientation="LAS")
    assert warns == [] and ct.meta["format"] == "image"
    np.testing.assert_array_equal(ct.data, grey[:, ::-1].astype(np.float32))
