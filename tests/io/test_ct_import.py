"""CT import (pdehead_addon.io.ct_import): real data sets, exact geometry on synthetic series, bad input.

Synthetic DICOM files are written with pydicom into tmp_path; real files are read in place
(or a few copied into tmp_path when they must be modified).
"""
from __future__ import annotations

import hashlib
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pydicom
import pytest
from pydicom.dataset import Dataset, FileMetaDataset
from pydicom.uid import (
    CTImageStorage,
    ExplicitVRLittleEndian,
    JPEG2000Lossless,
    JPEGLosslessSV1,
    MRImageStorage,
    RLELossless,
    generate_uid,
)
from scipy import ndimage

from datasets import CTHEAD_RAW16_OPTIONS, CTHEAD_TIFF8_OPTIONS, shared_data
from pdehead_addon import CTImportError, CTImportWarning, SeriesInfo, list_series, load_ct

AXIAL = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)


# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------

def write_slice(path, pixels, ipp, iop=AXIAL, spacing=(1.0, 1.0), series_uid="1.2.3.4", modality="CT",
                slope=1.0, intercept=0.0, thickness=None, image_type=("ORIGINAL", "PRIMARY", "AXIAL"),
                padding=None, sop_uid=None, description="", number=1, transfer_syntax=ExplicitVRLittleEndian):
    """A minimal but valid single-frame DICOM image (signed 16-bit) written with pydicom."""
    pixels = np.asarray(pixels, dtype=np.int16)
    sop_class = CTImageStorage if modality == "CT" else MRImageStorage
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = sop_class
    meta.MediaStorageSOPInstanceUID = sop_uid or generate_uid()
    meta.TransferSyntaxUID = transfer_syntax
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID = sop_class
    ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
    ds.Modality = modality
    ds.ImageType = list(image_type)
    ds.StudyInstanceUID = "1.2.3"
    ds.SeriesInstanceUID = series_uid
    ds.SeriesNumber = number
    ds.SeriesDescription = description
    ds.InstanceNumber = 1
    ds.ImagePositionPatient = [f"{float(x):.6f}" for x in ipp]
    ds.ImageOrientationPatient = [f"{float(x):.8f}" for x in iop]
    ds.PixelSpacing = [f"{float(s):.6f}" for s in spacing]
    if thickness is not None:
        ds.SliceThickness = thickness
    ds.Rows, ds.Columns = pixels.shape
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    ds.BitsAllocated = 16
    ds.BitsStored = 16
    ds.HighBit = 15
    ds.PixelRepresentation = 1
    ds.RescaleSlope = f"{slope:g}"
    ds.RescaleIntercept = f"{intercept:g}"
    if padding is not None:
        ds.PixelPaddingValue = int(padding)
    ds.PixelData = pixels.tobytes()
    ds.save_as(path, enforce_file_format=True)
    return ds


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def write_linear_series(folder, u, v, positions, rows=24, cols=20, spacing=(1.5, 1.2), coef=(0.3, -0.2, 0.5),
                        offset=7.0, **kw):
    """Slices whose values are the affine function ``coef . X + offset`` of the true pixel position X.

    Linear interpolation reproduces affine functions exactly, so any geometry error of the
    importer shows up as a value error. Stored with RescaleSlope 0.01 / intercept -5.
    """
    folder.mkdir(parents=True, exist_ok=True)
    u, v = unit(u), unit(v)
    dr, dc = spacing
    r, c = np.mgrid[0:rows, 0:cols]
    for k, p in enumerate(positions):
        x = np.asarray(p) + (c[..., None] * dc) * u + (r[..., None] * dr) * v
        value = x @ np.asarray(coef) + offset
        stored = np.round((value + 5.0) / 0.01)
        write_slice(folder / f"im{k:03d}.dcm", stored, p, tuple(u) + tuple(v), spacing, slope=0.01,
                    intercept=-5.0, **kw)


def check_linear(ct, coef=(0.3, -0.2, 0.5), offset=7.0, min_inside=500):
    """Every voxel that holds data equals the affine function at its patient position."""
    inside = ct.data > -900                       # outside the slab is air (-1000 HU)
    core = ndimage.binary_erosion(inside)          # drop the half-pixel edge band (nearest extension)
    assert core.sum() >= min_inside
    kji = np.argwhere(core)
    expected = ct.index_to_patient(kji) @ np.asarray(coef) + offset
    err = np.abs(ct.data[core] - expected)
    assert err.max() < 0.02, f"max geometry/value error {err.max():.4f}"
    return inside


def tree_state(folder):
    """(relative path, size, mtime_ns, sha1) of every file under folder."""
    state = []
    for root, _, names in os.walk(folder):
        for name in sorted(names):
            p = Path(root) / name
            st = p.stat()
            state.append((str(p.relative_to(folder)), st.st_size, st.st_mtime_ns,
                          hashlib.sha1(p.read_bytes()).hexdigest()))
    return sorted(state)


def ge_dir():
    return shared_data("ct_head_ge_tilt_dicom", "dicom")


def copy_ge(dst, numbers):
    dst.mkdir(parents=True, exist_ok=True)
    for i in numbers:
        shutil.copy(ge_dir() / f"{i:02d}.dcm", dst / f"{i:02d}.dcm")
    return dst


def load_quiet(*args, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ct = load_ct(*args, **kw)
    return ct, [str(w.message) for w in caught if issubclass(w.category, CTImportWarning)]


# ------------------------------------------------------------------------------------------------
# real data: CThead raw16 / tiff8
# ------------------------------------------------------------------------------------------------

def test_cthead_raw16_values_order_and_geometry(cthead_ct):
    ct = cthead_ct
    assert ct.shape == (113, 256, 256) and ct.data.dtype == np.float32
    assert ct.spacing == (2.0, 1.0, 1.0)
    np.testing.assert_array_equal(ct.direction, np.eye(3))
    np.testing.assert_array_equal(ct.origin, np.zeros(3))
    folder = shared_data("cthead_stanford", "raw16")
    # first_slice="superior": k = 0 is the LAST file (numeric order: CThead.113), k = 112 is CThead.1
    for k, n in ((0, 113), (112, 1), (103, 10), (13, 100)):
        raw = np.fromfile(folder / f"CThead.{n}", dtype=">i2").reshape(256, 256)
        np.testing.assert_array_equal(ct.data[k], raw.astype(np.float32))
    assert ct.meta["format"] == "raw" and ct.meta["original_slice_count"] == 113
    assert ct.meta["hu_range"] == (0.0, 3272.0) and ct.meta["warnings"] == []


def test_cthead_orientation_superior_and_anterior(cthead_ct):
    data = cthead_ct.data
    head = data > 600
    area = head.sum(axis=(1, 2))
    # k increases superior: the top slices are above the vertex (air/cloth), k = 0 is the neck
    assert area[-3:].max() < 0.15 * area[0] and area[0] > 5000
    assert area[50:70].mean() > 2 * area[-5:].mean()
    # j increases posterior: the cloth/pillow (100..400) lies behind the head ...
    cloth = (data > 100) & (data < 400)
    for k in (20, 40, 60, 80, 100):
        assert np.nonzero(cloth[k])[0].mean() > np.nonzero(head[k])[0].mean() + 30
    # ... and the lower jaw (bone > 1500) lies in front of the head's centre (small j)
    for k in (15, 20):
        assert np.nonzero(data[k] > 1500)[0].mean() < np.nonzero(head[k])[0].mean() - 20
    # the nose tip (most anterior head point) is in the lower half of the head, near j = 0
    front = np.array([np.nonzero(head[k].any(axis=1))[0].min() for k in range(100)])
    assert 30 < int(np.argmin(front)) < 70 and front.min() < 20


def test_cthead_tiff8_matches_raw16(cthead_ct, cthead_tiff_ct):
    tiff = cthead_tiff_ct
    assert tiff.shape == (99, 256, 256) and tiff.spacing == (2.0, 1.0, 1.0)
    assert tiff.meta["format"] == "image" and tiff.meta["first_file"] == "cthead-8bit001.tif"
    # tiff8 holds slices 1..99; with first_slice="superior" its k = 0 is slice 99 = raw16 k = 14
    v16 = cthead_ct.data[14:].ravel()
    v8 = tiff.data.ravel()
    unsaturated = v16 < 3200
    assert np.corrcoef(v8, v16)[0, 1] >= 0.99
    scale = float(np.dot(v8[unsaturated], v16[unsaturated]) / np.dot(v16[unsaturated], v16[unsaturated]))
    assert scale == pytest.approx(0.0782, abs=0.002)
    assert np.median(np.abs(v8[unsaturated] - v16[unsaturated] * 0.0782)) <= 1.0
    # slice by slice, too (a wrong numeric sort would break single slices)
    for k in (0, 40, 98):
        assert np.corrcoef(tiff.data[k].ravel(), cthead_ct.data[14 + k].ravel())[0, 1] > 0.99


def test_raw_options_byte_order_and_single_volume_file(tmp_path):
    folder = shared_data("cthead_stanford", "raw16")
    small = tmp_path / "raw"
    small.mkdir()
    for n in (1, 2, 10, 100):                    # numeric, not lexicographic, order
        shutil.copy(folder / f"CThead.{n}", small / f"CThead.{n}")
    a = load_ct(small, format="raw", shape=(256, 256), dtype=">i2", spacing=(2, 1, 1))
    b = load_ct(small, format="raw", shape=[256, 256], dtype="i2", byte_order="big", spacing=[2, 1, 1])
    np.testing.assert_array_equal(a.data, b.data)
    for k, n in enumerate((1, 2, 10, 100)):      # first_slice="inferior" (default): file order = k
        np.testing.assert_array_equal(a.data[k], np.fromfile(folder / f"CThead.{n}", ">i2").reshape(256, 256))
    # little-endian reading gives noise spanning the whole int16 range: refused, naming the right order
    with pytest.raises(CTImportError, match="wrong byte order.*dtype='>i2'"):
        load_ct(small, format="raw", shape=(256, 256), dtype="<i2", spacing=(2, 1, 1))
    # one volume file with a header
    vol = tmp_path / "volume.bin"
    with open(vol, "wb") as fh:
        fh.write(b"H" * 64)
        for n in (1, 2, 10, 100):
            fh.write((folder / f"CThead.{n}").read_bytes())
    d = load_ct(vol, format="raw", shape=(4, 256, 256), dtype=">i2", header_bytes=64, spacing=(2, 1, 1))
    e = load_ct(vol, shape=(256, 256), dtype=">i2", header_bytes=64, spacing=(2, 1, 1))  # shape => raw
    np.testing.assert_array_equal(d.data, a.data)
    np.testing.assert_array_equal(e.data, a.data)


# ------------------------------------------------------------------------------------------------
# real data: GE tilted DICOM
# ------------------------------------------------------------------------------------------------

def test_ge_dicom_meta_and_grid(ge_ct):
    ct = ge_ct
    m = ct.meta
    assert m["format"] == "dicom" and m["modality"] == "CT"
    assert m["series_uid"] == "1.2.826.0.1.3680043.9.4245.3115138630835728997848661150714813892"
    assert m["original_slice_count"] == 28 and m["original_shape"] == (28, 512, 512)
    assert m["gantry_tilt_deg"] == pytest.approx(18.5, abs=0.05)
    assert m["gantry_tilt_header_deg"] == pytest.approx(18.5)
    assert m["resampled"] is True
    assert "tilt" in m["resample_reason"] and "uneven" in m["resample_reason"]
    steps = np.array(m["slice_steps_mm"])      # along the slice normal: 13 x 4.0, 1.08, 13 x 7.0
    np.testing.assert_allclose(steps[:13], 4.0, atol=0.01)
    assert steps[13] == pytest.approx(1.08, abs=0.01)
    np.testing.assert_allclose(steps[14:], 7.0, atol=0.01)
    assert m["padding_value"] == -1500 and m["padding_fill"] == -1000.0 and m["padding_pixels"] > 10**6
    assert m["warnings"] == []                  # 7 mm steps match the 7 mm slice thickness: no "missing slice"
    np.testing.assert_array_equal(ct.direction, np.eye(3))
    assert ct.spacing == pytest.approx((4.0, 0.4882812, 0.4882812), abs=0.01)
    assert ct.data.dtype == np.float32
    # no padding value left, HU range plausible
    assert ct.data.min() >= -1024.5 and 2000 < ct.data.max() < 2200
    assert m["hu_range"] == (float(ct.data.min()), float(ct.data.max()))
    # the grid covers every raw pixel centre: x,y as in the header, z from the tilted corners
    lo, hi = ct.bounds()
    assert lo[0] == pytest.approx(-125.0, abs=1e-3) and hi[0] == pytest.approx(-125.0 + 511 * 0.4882812, abs=0.01)
    assert lo[2] == pytest.approx(5.836 - 511 * 0.4882812 * 0.3173047, abs=0.1)     # row 511 of slice 1
    assert hi[2] == pytest.approx(157.78, abs=ct.spacing[0])                          # row 0 of slice 28


def _raw_ge_slices():
    out = []
    for f in sorted(ge_dir().glob("*.dcm")):
        ds = pydicom.dcmread(f)
        img = ds.pixel_array.astype(np.float32)
        img[img == -1500] = -1000.0
        iop = np.array(ds.ImageOrientationPatient, dtype=float)
        out.append((img, np.array(ds.ImagePositionPatient, dtype=float), iop[:3], iop[3:],
                    [float(s) for s in ds.PixelSpacing]))
    return out


def _plane_comparison(ct, slices, assume_no_tilt=False):
    """For each raw slice: Dice of the head (> -400 HU) between the raw pixels and the volume sampled
    at the pixels' patient positions, and the centroid difference (mm) along y and z; plus the
    correlation of all raw and sampled values."""
    result, raw_values, sampled_values = [], [], []
    r, c = np.mgrid[0:512:2, 0:512:2]
    for img, ipp, u, v, (dr, dc) in slices:
        true_x = ipp + (c[..., None] * dc) * u + (r[..., None] * dr) * v
        v_used = np.array([0.0, 1.0, 0.0]) if assume_no_tilt else v
        x = ipp + (c[..., None] * dc) * u + (r[..., None] * dr) * v_used
        sampled = ndimage.map_coordinates(ct.data, ct.patient_to_index(x.reshape(-1, 3)).T, order=1,
                                          cval=-1000.0).reshape(r.shape)
        ref, got = img[::2, ::2] > -400, sampled > -400
        dice = 2 * (ref & got).sum() / max(1, ref.sum() + got.sum())
        diff = true_x[got].mean(axis=0) - true_x[ref].mean(axis=0) if got.any() else np.full(3, np.nan)
        result.append((ipp[2], dice, diff[1], diff[2]))
        raw_values.append(img[::2, ::2].ravel())
        sampled_values.append(sampled.ravel())
    corr = np.corrcoef(np.concatenate(raw_values[1:-1]), np.concatenate(sampled_values[1:-1]))[0, 1]
    return np.array(result), corr


def test_ge_resampled_pixels_sit_at_their_true_patient_positions(ge_ct):
    """Sample the resampled volume at IPP + col*dc*rowdir + row*dr*coldir of raw pixels."""
    slices = _raw_ge_slices()
    res, corr = _plane_comparison(ge_ct, slices)
    inner = res[1:-1]           # the first/last plane border the empty outside of the slab
    assert np.median(inner[:, 1]) > 0.99 and inner[:, 1].min() > 0.97
    assert np.abs(inner[:, 2:]).max() < 0.5                       # centroid within 0.5 mm
    assert corr > 0.97
    # no shear: the centroid error does not drift with height
    assert abs(np.polyfit(inner[:, 0], inner[:, 2], 1)[0]) < 0.005
    # control: the same check with the tilt ignored fails clearly (the test can fail)
    naive, naive_corr = _plane_comparison(ge_ct, slices, assume_no_tilt=True)
    assert np.median(naive[:, 1]) < 0.95 and naive_corr < 0.8
    # single landmarks in homogeneous tissue (brain, 9x9 neighbourhood within 10 HU) and in air
    # outside the head: the volume has the raw slice's HU at the raw pixel's patient position
    for index in (7, 19):
        img, ipp, u, v, (dr, dc) = slices[index]
        mean = ndimage.uniform_filter(img, 9)
        spread = ndimage.maximum_filter(img, 9) - ndimage.minimum_filter(img, 9)
        for select in ((mean > 15) & (mean < 60) & (spread < 25), (mean < -990) & (spread < 15)):
            rows, cols = np.nonzero(select)
            pick = np.linspace(0, rows.size - 1, 25).astype(int)
            x = ipp + np.outer(cols[pick] * dc, u) + np.outer(rows[pick] * dr, v)
            got = ndimage.map_coordinates(ge_ct.data, ge_ct.patient_to_index(x).T, order=1)
            assert np.median(np.abs(got - mean[rows[pick], cols[pick]])) < 10


def test_ge_head_is_upright_not_sheared(ge_ct):
    """Per axial slab, the head centroid in the resampled volume matches the raw pixels' true positions;
    the naive stack (rows taken as y, slices at their IPP z) is sheared by up to ~1 cm."""
    slices = _raw_ge_slices()
    r, c = np.mgrid[0:512:2, 0:512:2]
    points, raw_head = [], []
    for img, ipp, u, v, (dr, dc) in slices[1:-1]:
        points.append((ipp + (c[..., None] * dc) * u + (r[..., None] * dr) * v).reshape(-1, 3))
        raw_head.append(img[::2, ::2].ravel() > -400)
    x, raw_head = np.concatenate(points), np.concatenate(raw_head)
    resampled_head = ndimage.map_coordinates(ge_ct.data, ge_ct.patient_to_index(x).T, order=1, cval=-1000.0) > -400
    # the naive stack evaluated at the same true positions (nearest naive slice and pixel)
    images = np.stack([s[0] for s in slices])
    slice_z = np.array([s[1][2] for s in slices])
    first, spacing = slices[0][1], slices[0][4][0]
    # nearest slice in z (slice_z is ascending)
    upper = np.clip(np.searchsorted(slice_z, x[:, 2]), 1, len(slice_z) - 1)
    k = np.where(x[:, 2] - slice_z[upper - 1] < slice_z[upper] - x[:, 2], upper - 1, upper)
    row = np.rint((x[:, 1] - first[1]) / spacing).astype(int)
    col = np.rint((x[:, 0] - first[0]) / spacing).astype(int)
    ok = (row >= 0) & (row < 512) & (col >= 0) & (col < 512)
    naive_values = np.full(len(x), -1000.0)
    naive_values[ok] = images[k[ok], row[ok], col[ok]]
    naive_head = naive_values > -400

    def centroid_errors(head):
        errors = []
        for z0 in np.arange(-60.0, 160.0, 8.0):
            slab = (x[:, 2] >= z0) & (x[:, 2] < z0 + 8.0)
            if (slab & raw_head).sum() > 500 and (slab & head).sum() > 500:
                errors.append(x[slab & head, :2].mean(axis=0) - x[slab & raw_head, :2].mean(axis=0))
        return np.array(errors)

    good = centroid_errors(resampled_head)
    bad = centroid_errors(naive_head)
    assert len(good) >= 18
    assert np.abs(good).max() < 0.5                 # mm, in x and y, at every height
    assert np.abs(bad[:, 1]).max() > 5.0            # the naive stack leans (control)


def test_ge_list_series():
    infos = list_series(ge_dir())
    assert len(infos) == 1
    info = infos[0]
    assert isinstance(info, SeriesInfo)
    assert info.modality == "CT" and info.is_ct and info.slice_count == 28
    assert (info.rows, info.cols) == (512, 512) and info.series_number == 2
    assert info.study_description == "HEAD" and info.orientation == "oblique"
    assert len(info.files) == 28 and info.files[0].endswith("01.dcm")
    assert info.pixel_spacing == pytest.approx((0.4882812, 0.4882812))
    assert "28 slices of 512x512" in info.label


def test_ge_missing_slice_warns_and_resamples(tmp_path):
    folder = copy_ge(tmp_path / "gap", [1, 2, 3, 5, 6, 7])      # 04 missing: one 8 mm step among 4 mm
    with pytest.warns(CTImportWarning, match="possible missing slice.*03.dcm and 05.dcm"):
        ct = load_ct(folder)
    assert ct.meta["resampled"] and "uneven" in ct.meta["resample_reason"]
    assert any("missing slice" in w for w in ct.meta["warnings"])
    assert ct.meta["original_slice_count"] == 6


def test_ge_truncated_file_is_an_error(tmp_path):
    folder = copy_ge(tmp_path / "trunc", [1, 2, 3, 4])
    data = (folder / "03.dcm").read_bytes()
    (folder / "03.dcm").write_bytes(data[: int(len(data) * 0.6)])
    with pytest.raises(CTImportError, match=r"03\.dcm: truncated file: the pixel data has \d+ bytes, expected 524288"):
        load_ct(folder)
    # cut inside the header (no pixel data at all), loaded as the only file
    (folder / "03.dcm").write_bytes(data[:1052])
    with pytest.raises(CTImportError, match=r"03\.dcm: cannot read this DICOM file.*truncated"):
        load_ct(folder / "03.dcm")


def test_input_folders_are_not_modified(tmp_path):
    ge = copy_ge(tmp_path / "ge", [1, 2, 3, 15, 16])
    raw = tmp_path / "raw"
    raw.mkdir()
    for n in (1, 2, 3):
        shutil.copy(shared_data("cthead_stanford", "raw16") / f"CThead.{n}", raw)
    tif = tmp_path / "tif"
    tif.mkdir()
    for n in (1, 2, 3):
        shutil.copy(shared_data("cthead_stanford", "tiff8") / f"cthead-8bit{n:03d}.tif", tif)
    before = {p: tree_state(p) for p in (ge, raw, tif)}
    load_quiet(ge)
    list_series(ge)
    load_quiet(raw, **CTHEAD_RAW16_OPTIONS)
    load_quiet(tif, **CTHEAD_TIFF8_OPTIONS)
    for p, state in before.items():
        assert tree_state(p) == state, f"{p} changed"


# ------------------------------------------------------------------------------------------------
# exact geometry on synthetic series (linear intensity = position)
# ------------------------------------------------------------------------------------------------

def _positions(origin, step_dir, steps):
    origin = np.asarray(origin, dtype=float)
    t = np.concatenate([[0.0], np.cumsum(steps)])
    return [origin + ti * unit(step_dir) for ti in t]


@pytest.mark.parametrize("case", ["axial", "flipped", "sagittal", "coronal_reversed"])
def test_axis_aligned_series_are_only_flipped_and_transposed(tmp_path, case):
    if case == "axial":
        u, v, step_dir = (1, 0, 0), (0, 1, 0), (0, 0, 1)
    elif case == "flipped":            # rows toward anterior, columns toward right, stacked downward
        u, v, step_dir = (-1, 0, 0), (0, -1, 0), (0, 0, -1)
    elif case == "sagittal":           # columns posterior, rows inferior
        u, v, step_dir = (0, 1, 0), (0, 0, -1), (1, 0, 0)
    else:                              # coronal, columns toward left, rows inferior, stacked anterior
        u, v, step_dir = (1, 0, 0), (0, 0, -1), (0, -1, 0)
    positions = _positions((-10, 5, 20), step_dir, [2.5] * 9)
    order = np.random.default_rng(1).permutation(len(positions))      # file order must not matter
    # SliceThickness 5 mm on purpose: the spacing must come from the positions (2.5 mm)
    write_linear_series(tmp_path / case, u, v, [positions[i] for i in order], thickness=5.0)
    ct, warns = load_quiet(tmp_path / case)
    assert warns == []
    assert ct.meta["resampled"] is False and ct.meta["original_slice_count"] == 10
    np.testing.assert_array_equal(ct.direction, np.eye(3))
    inside = check_linear(ct)
    assert inside.all()                                     # no resampling: every voxel is data
    assert sorted(ct.spacing) == sorted((2.5, 1.5, 1.2))


@pytest.mark.parametrize("case", ["tilt_x_uneven", "tilt_y", "double_oblique", "tilt_x_reversed_rows"])
def test_tilted_oblique_uneven_series_are_resampled_exactly(tmp_path, case):
    a = np.radians(18.5)
    steps = [2.0] * 5 + [0.6] + [3.5] * 5
    if case == "tilt_x_uneven":        # GE-like: rows along x, tilt about x, slices stacked along z
        u, v, step_dir = (1, 0, 0), (0, np.cos(a), -np.sin(a)), (0, 0, 1)
    elif case == "tilt_y":             # tilt about y: the row direction (v) stays a patient axis
        u, v, step_dir = (np.cos(a), 0, np.sin(a)), (0, 1, 0), (0, 0, 1)
        steps = [2.0] * 10
    elif case == "double_oblique":     # no image axis is a patient axis: general resampling path
        rot = np.radians(12.0)
        u = (np.cos(rot), np.sin(rot) * np.cos(a), -np.sin(rot) * np.sin(a))
        v0 = np.array([-np.sin(rot), np.cos(rot) * np.cos(a), -np.cos(rot) * np.sin(a)])
        v = tuple(v0)
        step_dir = np.cross(u, v)
    else:                              # columns toward the right, rows anterior, tilt: flips inside
        u, v, step_dir = (-1, 0, 0), (0, -np.cos(a), np.sin(a)), (0, 0, -1)
    positions = _positions((-12, -15, 30), step_dir, steps)
    write_linear_series(tmp_path / case, u, v, positions, thickness=2.0)
    ct, warns = load_quiet(tmp_path / case)
    assert ct.meta["resampled"] is True
    np.testing.assert_array_equal(ct.direction, np.eye(3))
    check_linear(ct, min_inside=2000)
    # the grid spans the raw pixel centres
    u, v = unit(u), unit(v)
    corners = np.array([p + i * 23 * 1.5 * v + j * 19 * 1.2 * u for p in positions for i in (0, 1) for j in (0, 1)])
    lo, hi = ct.bounds()
    np.testing.assert_allclose(lo, corners.min(axis=0), atol=1e-6)
    assert np.all(hi <= corners.max(axis=0) + 1e-6) and np.all(hi > corners.max(axis=0) - np.array(ct.spacing[::-1]))
    if case == "tilt_x_uneven":
        assert "tilt" in ct.meta["resample_reason"] and "uneven" in ct.meta["resample_reason"]
        assert ct.meta["gantry_tilt_deg"] == pytest.approx(18.5, abs=0.01)
        # 3.3 mm steps (along the normal) with 2 mm thick slices and a 1.9 mm median step: a gap
        assert any("possible missing slice" in w for w in warns)
    if case == "double_oblique":
        assert "oblique" in ct.meta["resample_reason"] and ct.meta["gantry_tilt_deg"] < 0.01


def test_resample_spacing_option(tmp_path):
    a = np.radians(10.0)
    positions = _positions((0, 0, 0), (0, 0, 1), [2.0] * 8)
    write_linear_series(tmp_path / "s", (1, 0, 0), (0, np.cos(a), -np.sin(a)), positions)
    ct = load_ct(tmp_path / "s", resample_spacing=(1.0, 0.8, 0.7))     # x spacing differs: general path
    assert ct.spacing == (1.0, 0.8, 0.7)
    check_linear(ct, min_inside=2000)


def test_rescale_padding_and_non_ct_fill(tmp_path):
    pixels = np.full((8, 8), 1100, dtype=np.int16)
    pixels[0, :] = -2000                                        # padding
    (tmp_path / "ct").mkdir()
    for k in range(3):
        write_slice(tmp_path / "ct" / f"{k}.dcm", pixels, (0, 0, k * 2.0), intercept=-1024, padding=-2000)
    ct = load_ct(tmp_path / "ct")
    assert np.all(ct.data[:, 0, :] == -1000.0)                  # padding -> air
    assert np.all(ct.data[:, 1:, :] == 76.0)                    # 1100 - 1024
    assert ct.meta["padding_fill_rule"].startswith("air") and ct.meta["units"] == "HU"
    (tmp_path / "mr").mkdir()
    for k in range(3):
        write_slice(tmp_path / "mr" / f"{k}.dcm", pixels, (0, 0, k * 2.0), modality="MR", padding=-2000)
    with pytest.warns(CTImportWarning, match="modality is MR, not CT"):
        mr = load_ct(tmp_path / "mr")
    assert np.all(mr.data[:, 0, :] == 1100.0)                   # series minimum of the real pixels
    assert "minimum" in mr.meta["padding_fill_rule"]


def test_rle_compressed_series_decodes(tmp_path):
    positions = _positions((0, 0, 0), (0, 0, 1), [2.0] * 4)
    write_linear_series(tmp_path / "plain", (1, 0, 0), (0, 1, 0), positions)
    (tmp_path / "rle").mkdir()
    for f in sorted((tmp_path / "plain").iterdir()):
        ds = pydicom.dcmread(f)
        ds.compress(RLELossless)
        ds.save_as(tmp_path / "rle" / f.name, enforce_file_format=True)
    a = load_ct(tmp_path / "plain")
    b = load_ct(tmp_path / "rle")
    assert b.meta["transfer_syntax"] == "RLE Lossless"
    np.testing.assert_array_equal(a.data, b.data)


def test_multiframe_enhanced_ct(tmp_path):
    """One file, frames placed by the per-frame functional groups (Enhanced CT style)."""
    a = np.radians(15.0)
    u, v = np.array([1.0, 0, 0]), np.array([0, np.cos(a), -np.sin(a)])
    positions = _positions((-5, -5, 0), (0, 0, 1), [3.0] * 5)
    write_linear_series(tmp_path / "single", u, v, positions)
    frames = [pydicom.dcmread(f) for f in sorted((tmp_path / "single").iterdir())]
    ds = frames[0]
    ds.NumberOfFrames = len(frames)
    pixels = [f.PixelData for f in frames]      # (ds is frames[0]: its own PixelData is replaced below)
    shared = Dataset()
    orientation = Dataset()
    orientation.ImageOrientationPatient = frames[0].ImageOrientationPatient
    measures = Dataset()
    measures.PixelSpacing = frames[0].PixelSpacing
    transform = Dataset()
    transform.RescaleSlope, transform.RescaleIntercept = "0.01", "-5"
    shared.PlaneOrientationSequence = [orientation]
    shared.PixelMeasuresSequence = [measures]
    shared.PixelValueTransformationSequence = [transform]
    ds.SharedFunctionalGroupsSequence = [shared]
    per_frame = []
    for f in frames[::-1]:                      # frames stored in reverse order on purpose
        group, plane = Dataset(), Dataset()
        plane.ImagePositionPatient = f.ImagePositionPatient
        group.PlanePositionSequence = [plane]
        per_frame.append(group)
    ds.PerFrameFunctionalGroupsSequence = per_frame
    ds.PixelData = b"".join(pixels[::-1])
    for keyword in ("ImagePositionPatient", "ImageOrientationPatient", "PixelSpacing", "RescaleSlope",
                    "RescaleIntercept"):
        delattr(ds, keyword)
    (tmp_path / "multi").mkdir()
    ds.save_as(tmp_path / "multi" / "enhanced.dcm", enforce_file_format=True)
    single = load_ct(tmp_path / "single")
    multi = load_ct(tmp_path / "multi" / "enhanced.dcm")
    assert multi.meta["original_slice_count"] == 6 and multi.meta["resampled"]
    np.testing.assert_array_equal(single.data, multi.data)
    check_linear(multi, min_inside=1000)


# ------------------------------------------------------------------------------------------------
# series selection, skipping
# ------------------------------------------------------------------------------------------------

def _small_series(folder, uid, n, modality="CT", description="", number=1, iop=AXIAL, shape=(6, 5), z0=0.0):
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(n):
        write_slice(folder / f"{uid}_{k}.dcm", np.full(shape, 10 * k + number, np.int16), (0, 0, z0 + 2.0 * k),
                    iop=iop, series_uid=uid, modality=modality, description=description, number=number)


def test_series_selection_and_list_series(tmp_path):
    _small_series(tmp_path / "study" / "a", "1.1", 5, description="bone", number=3)
    _small_series(tmp_path / "study" / "b" / "deep", "1.2", 8, description="soft", number=2)
    _small_series(tmp_path / "study" / "c", "1.3", 12, modality="MR", description="t1", number=1)
    infos = list_series(tmp_path / "study")
    assert [(i.uid, i.slice_count, i.modality) for i in infos] == [("1.2", 8, "CT"), ("1.1", 5, "CT"),
                                                                    ("1.3", 12, "MR")]
    assert infos[0].description == "soft" and (infos[0].rows, infos[0].cols) == (6, 5)
    assert infos[0].orientation == "axial" and len(infos[0].files) == 8
    with pytest.warns(CTImportWarning, match="3 image series found"):
        ct = load_ct(tmp_path / "study")                   # the CT series with the most slices
    assert ct.meta["series_uid"] == "1.2" and ct.shape == (8, 6, 5)
    assert ct.meta["series_description"] == "soft"
    ct = load_ct(tmp_path / "study", series_uid="1.1")
    assert ct.meta["series_uid"] == "1.1" and ct.shape == (5, 6, 5)
    np.testing.assert_array_equal(ct.data[:, 0, 0], 10 * np.arange(5) + 3)
    with pytest.raises(CTImportError, match=r"series_uid '9\.9' not found; available series: 1\.2 .*1\.1 .*1\.3"):
        load_ct(tmp_path / "study", series_uid="9.9")
    # a list of files works like a folder
    files = sorted((tmp_path / "study" / "a").iterdir())
    assert load_ct(files).shape == (5, 6, 5)


def test_localizers_dicomdir_non_image_and_non_dicom_are_skipped(tmp_path):
    folder = tmp_path / "mixed"
    _small_series(folder, "2.1", 6)
    # a localizer in the same series (flagged in ImageType, sagittal)
    write_slice(folder / "scout.dcm", np.zeros((6, 5)), (0, 0, 0), iop=(0, 1, 0, 0, 0, -1), series_uid="2.1",
                image_type=("ORIGINAL", "PRIMARY", "LOCALIZER"))
    # a non-image object (no PixelData), e.g. a structured report
    sr = Dataset()
    sr.file_meta = FileMetaDataset()
    sr.file_meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.88.11"
    sr.file_meta.MediaStorageSOPInstanceUID = generate_uid()
    sr.file_meta.TransferSyntaxUID = ExplicitVRLittleEndian
    sr.SOPClassUID = sr.file_meta.MediaStorageSOPClassUID
    sr.SOPInstanceUID = sr.file_meta.MediaStorageSOPInstanceUID
    sr.SeriesInstanceUID = "2.9"
    sr.Modality = "SR"
    sr.save_as(folder / "report.dcm", enforce_file_format=True)
    # a DICOMDIR
    dd = Dataset()
    dd.file_meta = FileMetaDataset()
    dd.file_meta.MediaStorageSOPClassUID = "1.2.840.10008.1.3.10"
    dd.file_meta.MediaStorageSOPInstanceUID = generate_uid()
    dd.file_meta.TransferSyntaxUID = ExplicitVRLittleEndian
    dd.FileSetID = "TEST"
    dd.save_as(folder / "DICOMDIR", enforce_file_format=True)
    # non-DICOM files
    (folder / "notes.txt").write_text("patient notes\n")
    (folder / "thumbnail.bin").write_bytes(b"THUMB" + bytes(range(256)))
    infos = list_series(folder)
    assert [(i.uid, i.slice_count) for i in infos] == [("2.1", 6)]
    with pytest.warns(CTImportWarning, match=r"skipped 2 non-DICOM file\(s\): notes.txt, thumbnail.bin"):
        ct = load_ct(folder)
    assert ct.shape == (6, 6, 5)
    assert ct.meta["skipped"] == {"localizer": 1, "no pixel data (not an image)": 1, "DICOMDIR": 1,
                                  "not DICOM": 2}
    assert len(ct.meta["warnings"]) == 1
    # a scout without the LOCALIZER flag but with another orientation is skipped with a warning
    write_slice(folder / "scout2.dcm", np.zeros((6, 5)), (0, 0, 0), iop=(0, 1, 0, 0, 0, -1), series_uid="2.1")
    ct, warns = load_quiet(folder)
    assert ct.shape == (6, 6, 5)
    assert any("different orientation" in w and "scout2.dcm" in w for w in warns)


def test_duplicate_file_copies_are_dropped_but_duplicate_positions_fail(tmp_path):
    folder = tmp_path / "dup"
    _small_series(folder, "3.1", 4)
    (folder / "copy").mkdir()
    shutil.copy(folder / "3.1_2.dcm", folder / "copy" / "3.1_2.dcm")       # same SOPInstanceUID
    ct, warns = load_quiet(folder)
    assert ct.shape[0] == 4 and any("duplicate file" in w for w in warns)
    # a different image at the same position
    write_slice(folder / "other.dcm", np.zeros((6, 5)), (0, 0, 4.0), series_uid="3.1")
    with pytest.raises(CTImportError, match=r"duplicate slice position \[0\.0, 0\.0, 4\.0\]"):
        load_ct(folder)


def test_slices_without_position_are_skipped_or_fail(tmp_path):
    folder = tmp_path / "nopos"
    _small_series(folder, "5.1", 4)
    ds = pydicom.dcmread(folder / "5.1_3.dcm")
    del ds.ImagePositionPatient
    ds.save_as(folder / "5.1_3.dcm", enforce_file_format=True)
    ct, warns = load_quiet(folder)
    assert ct.shape == (3, 6, 5) and any("without position" in w and "5.1_3.dcm" in w for w in warns)
    with pytest.raises(CTImportError, match=r"5\.1_3\.dcm: has no ImagePositionPatient"):
        load_ct(folder / "5.1_3.dcm")


def test_only_non_image_dicom_or_text_is_an_error(tmp_path):
    folder = tmp_path / "sr"
    folder.mkdir()
    sr = Dataset()
    sr.file_meta = FileMetaDataset()
    sr.file_meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.88.11"
    sr.file_meta.MediaStorageSOPInstanceUID = generate_uid()
    sr.file_meta.TransferSyntaxUID = ExplicitVRLittleEndian
    sr.SOPClassUID = sr.file_meta.MediaStorageSOPClassUID
    sr.SOPInstanceUID = sr.file_meta.MediaStorageSOPInstanceUID
    sr.Modality = "SR"
    sr.save_as(folder / "report.dcm", enforce_file_format=True)
    with pytest.raises(CTImportError, match=r"sr: no DICOM image series found.*no pixel data"):
        load_ct(folder)
    assert list_series(folder) == []
    text = tmp_path / "text"
    text.mkdir()
    (text / "a.txt").write_text("hello")
    (text / "b").write_text("world")
    with pytest.raises(CTImportError, match=r"text: no DICOM, image .* found; for headerless raw"):
        load_ct(text)
    with pytest.raises(CTImportError, match=r"a\.txt: no image files"):
        load_ct(text / "a.txt", format="image")


def test_mixed_image_sizes_in_a_series(tmp_path):
    folder = tmp_path / "mixed"
    _small_series(folder, "4.1", 3)
    write_slice(folder / "big.dcm", np.zeros((7, 5)), (0, 0, 10.0), series_uid="4.1")
    with pytest.raises(CTImportError, match=r"mixed image sizes within one series \(6x5 in .*; 7x5 in .*big\.dcm\)"):
        load_ct(folder)


def test_compressed_transfer_syntax_without_decoder_or_broken(tmp_path):
    from pydicom.encaps import encapsulate
    for name, uid in (("jpeg_lossless", JPEGLosslessSV1), ("j2k", JPEG2000Lossless)):
        folder = tmp_path / name
        folder.mkdir()
        ds = write_slice(folder / "a.dcm", np.zeros((6, 5)), (0, 0, 0))
        ds.file_meta.TransferSyntaxUID = uid
        ds.PixelData = encapsulate([b"\xff\xd8 not really compressed data \xff\xd9"])
        ds["PixelData"].VR = "OB"
        ds.save_as(folder / "a.dcm", enforce_file_format=True)
        with pytest.raises(CTImportError) as info:
            load_ct(folder)
        message = str(info.value)
        assert message.startswith(str(folder / "a.dcm"))
        assert uid.name in message
        assert "\n" not in message
        if name == "jpeg_lossless":
            from pydicom.pixels import get_decoder
            if not get_decoder(uid).is_available:
                assert "no installed decoder" in message and "pylibjpeg" in message and "gdcm" in message


# ------------------------------------------------------------------------------------------------
# images and raw: ordering and bad input
# ------------------------------------------------------------------------------------------------

def test_image_stack_numeric_order_and_skips(tmp_path):
    from PIL import Image
    folder = tmp_path / "png"
    folder.mkdir()
    for n in (100, 2, 10, 1):
        Image.fromarray(np.full((9, 7), n, np.uint8)).save(folder / f"slice{n}.png")
    (folder / "readme.txt").write_text("scan notes")
    with pytest.warns(CTImportWarning, match=r"skipped 1 non-image file\(s\): readme.txt"):
        ct = load_ct(folder, spacing=(3, 0.5, 0.5))
    np.testing.assert_array_equal(ct.data[:, 0, 0], [1, 2, 10, 100])       # first_slice="inferior"
    assert ct.spacing == (3.0, 0.5, 0.5)
    ct, _ = load_quiet(folder, spacing=(3, 0.5, 0.5), first_slice="superior", format="image")
    np.testing.assert_array_equal(ct.data[:, 0, 0], [100, 10, 2, 1])
    # no spacing: 1 mm with a warning
    ct, warns = load_quiet(folder)
    assert ct.spacing == (1.0, 1.0, 1.0) and any("no spacing given" in w for w in warns)
    # mixed sizes
    Image.fromarray(np.zeros((8, 7), np.uint8)).save(folder / "slice3.png")
    with pytest.raises(CTImportError, match=r"mixed image sizes \(9x7 in slice1.png; 8x7 in slice3.png\)"):
        load_quiet(folder)
    # a broken image among the slices names the file
    (folder / "slice3.png").write_bytes(b"not a png at all")
    with pytest.raises(CTImportError, match=r"slice3\.png: cannot read image"):
        load_quiet(folder)


def test_raw_errors_name_the_file_and_sizes(tmp_path):
    folder = tmp_path / "raw"
    folder.mkdir()
    for n in (1, 2, 3):
        (folder / f"s.{n}").write_bytes(np.zeros((4, 5), ">i2").tobytes())
    (folder / "s.2").write_bytes(np.zeros((4, 6), ">i2").tobytes())
    with pytest.raises(CTImportError, match=r"s\.2: file size 48 bytes does not match one 4x5 >i2 slice \+ 0 "
                                            r"header bytes = 40 bytes"):
        load_ct(folder, format="raw", shape=(4, 5), dtype=">i2", spacing=(1, 1, 1))
    (folder / "s.2").write_bytes(np.zeros((4, 5), ">i2").tobytes())
    assert load_ct(folder, format="raw", shape=(4, 5), dtype=">i2", spacing=(1, 1, 1)).shape == (3, 4, 5)
    with pytest.raises(CTImportError, match="needs dtype"):
        load_ct(folder, format="raw", shape=(4, 5))
    with pytest.raises(CTImportError, match="needs shape"):
        load_ct(folder, format="raw", dtype=">i2")
    with pytest.raises(CTImportError, match="byte_order must be"):
        load_ct(folder, format="raw", shape=(4, 5), dtype="i2", byte_order="middle")
    with pytest.raises(CTImportError, match=r"shape \(7, 4, 5\) asks for 7 slices but the folder has 3 files"):
        load_ct(folder, format="raw", shape=(7, 4, 5), dtype=">i2")
    with pytest.raises(CTImportError, match=r"s\.1: file size 40 bytes does not match shape \(3, 4, 5\)"):
        load_ct(folder / "s.1", format="raw", shape=(3, 4, 5), dtype=">i2")
    with pytest.raises(CTImportError, match="spacing must be three positive numbers"):
        load_ct(folder, format="raw", shape=(4, 5), dtype=">i2", spacing=(1, 0, 1))


def test_missing_and_empty_paths(tmp_path):
    with pytest.raises(CTImportError, match=r"nope: no such file or folder"):
        load_ct(tmp_path / "nope")
    with pytest.raises(CTImportError, match=r"nope: no such file or folder"):
        list_series(tmp_path / "nope")
    (tmp_path / "empty" / "sub").mkdir(parents=True)
    with pytest.raises(CTImportError, match=r"empty: the folder is empty"):
        load_ct(tmp_path / "empty")
    with pytest.raises(CTImportError, match="the list of files is empty"):
        load_ct([])
    with pytest.raises(CTImportError, match="unknown format"):
        load_ct(tmp_path, format="vtk")
    with pytest.raises(CTImportError, match="first_slice must be"):
        load_ct(tmp_path, first_slice="top")


# ------------------------------------------------------------------------------------------------
# NIfTI (optional extra: the MRI ch2)
# ------------------------------------------------------------------------------------------------

def test_nifti_ras_to_lps():
    import gzip
    path = shared_data("mri_colin27_ch2", "ch2.nii.gz")
    ct = load_ct(path)
    raw = np.frombuffer(gzip.open(path).read()[352:], np.uint8).reshape(181, 217, 181)   # [k, j(A), i(R)]
    assert ct.shape == (181, 217, 181) and ct.spacing == (1.0, 1.0, 1.0)
    np.testing.assert_array_equal(ct.direction, np.eye(3))
    # RAS origin (-90, -125, -71), i toward Right and j toward Anterior are both flipped for LPS
    np.testing.assert_allclose(ct.origin, [-90.0, -91.0, -71.0])
    np.testing.assert_array_equal(ct.data, raw[:, ::-1, ::-1])
    assert ct.meta["format"] == "nifti" and ct.meta["nifti_form"] == "sform"
    # the MRI head: face (anterior) at small j, the top of the head at large k
    head = ct.data > 5
    prof_j = head.sum(axis=(0, 2))
    assert np.flatnonzero(prof_j)[0] < 20 and head[-5:].sum() < head[90].sum() * 0.3


def test_tilted_series_records_which_voxels_the_scan_covered(ge_ct):
    """Resampling a tilted slab leaves wedges of the axial grid unscanned; coverage marks them."""
    cov = ge_ct.coverage
    assert cov is not None and cov.shape == ge_ct.shape
    assert 0.5 < ge_ct.meta["covered_fraction"] < 0.95
    # the unscanned wedges are at the bottom-front / top-back of the oblique slab and hold air
    assert not cov[0].all() and not cov[-1].all()
    assert np.all(ge_ct.data[~cov] == -1000.0)
    # the middle of the head was scanned
    nz = ge_ct.shape[0]
    assert cov[nz // 2].mean() > 0.95


def test_axis_aligned_series_has_no_coverage_mask(cthead_ct):
    assert cthead_ct.coverage is None


def test_canonical_flip_in_place_equals_the_copy():
    """``to_canonical(in_place=True)`` (a reader's own float32 stack: no 300 MB copy) gives the flipped copy's
    data, origin and direction for every combination of flipped axes, and falls back to the copy where a
    transpose is needed."""
    import itertools

    from pdehead_addon.io.ct_import.geometry import to_canonical
    rng = np.random.default_rng(5)
    base = rng.normal(size=(5, 4, 6)).astype(np.float32)
    eye = np.eye(3)
    for signs in itertools.product((1, -1), repeat=3):
        # array axes 0, 1, 2 hold patient z, y, x
        dirs = [signs[0] * eye[2], signs[1] * eye[1], signs[2] * eye[0]]
        want = to_canonical(base.copy(), dirs, (2.0, 1.0, 0.5), np.array([3.0, -4.0, 7.0]))
        scratch = base.copy()
        got = to_canonical(scratch, dirs, (2.0, 1.0, 0.5), np.array([3.0, -4.0, 7.0]), in_place=True)
        assert np.array_equal(got[0], want[0]) and got[0] is scratch
        for a, b in zip(got[1:], want[1:]):
            assert np.allclose(a, b)
        if signs == (-1, 1, 1):
            assert np.array_equal(got[0], base[::-1])        # slices stacked downward: reversed
    # a transpose: the copy, the caller's array untouched
    scratch = base.copy()
    out = to_canonical(scratch, [eye[1], eye[2], eye[0]], (1.0, 2.0, 0.5), np.zeros(3), in_place=True)[0]
    assert out is not scratch and np.array_equal(scratch, base) and out.shape == (4, 5, 6)


def test_slice_positions_spanning_no_scan_are_refused_with_their_extent():
    """Corrupt positions (a slice a kilometre away) give a clear error with the positions' extent in mm,
    before any grid is allocated."""
    from pdehead_addon.io.ct_import.geometry import resample_slices
    stack = np.zeros((3, 4, 4), np.float32)
    positions = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1e9]])
    with pytest.raises(CTImportError, match=r"positions span \[3\.0, 3\.0, 1000000000\.0\] mm"):
        resample_slices(stack, positions, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 1.0, 1.0,
                        np.diff(positions[:, 2]), (1.0, 1.0, 1.0), -1000.0, label="corrupt.dcm")
