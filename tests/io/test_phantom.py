"""The synthetic head phantom (exact truth, realism hooks) and the DICOM writer."""
from __future__ import annotations

import math

import numpy as np
import pydicom
import pytest
from scipy import ndimage as ndi

from pdehead_addon import PDEHeadError, make_phantom
from pdehead_addon.core.ct_volume import CTVolume
from pdehead_addon.io.phantom import (
    AIR,
    BONE,
    BRAIN,
    CUSHION,
    EYE,
    HOLDER,
    INTERNAL_AIR,
    LABEL_NAMES,
    SOFT_TISSUE,
    Phantom,
)
from pdehead_addon.validation import write_dicom_series
from pdehead_addon.validation.dicom_export import GE_LIKE_NORMAL_STEPS, write_phantom_series


def voxel_centres(ct: CTVolume) -> np.ndarray:
    kji = np.stack(np.meshgrid(*[np.arange(n) for n in ct.shape], indexing="ij"), axis=-1)
    return ct.index_to_patient(kji)


def surface_y(phantom: Phantom, x: float, z: float) -> float:
    """y (mm) of the first skin point met coming from the front (-y) at (x, z), 0.05 mm steps."""
    ys = np.arange(-140.0, 0.0, 0.05)
    inside = phantom.inside_head(np.stack([np.full_like(ys, x), ys, np.full_like(ys, z)], axis=-1))
    assert inside.any(), (x, z)
    return float(ys[np.argmax(inside)])


@pytest.fixture(scope="module")
def clean():
    """The default phantom without noise (same geometry and blur as the session fixture)."""
    return make_phantom(noise=0.0)


# --------------------------------------------------------------------------------------------
# Phantom
# --------------------------------------------------------------------------------------------
def test_deterministic_and_seeded(phantom):
    again = make_phantom()
    assert np.array_equal(again.ct.data, phantom.ct.data)
    assert np.array_equal(again.labels, phantom.labels)
    other = make_phantom(seed=1)
    assert np.array_equal(other.labels, phantom.labels)
    diff = other.ct.data - phantom.ct.data
    assert 0.95 * 20 * math.sqrt(2) < diff.std() < 1.05 * 20 * math.sqrt(2)  # independent noise


def test_grid_conventions_and_extent(phantom):
    ct = phantom.ct
    assert ct.shape == (100, 128, 128) and ct.data.dtype == np.float32
    assert ct.spacing == pytest.approx((2.3, 2.0, 2.0))
    assert np.array_equal(ct.direction, np.eye(3))
    m = phantom.head_mask
    assert m.shape == ct.shape and m.dtype == bool and phantom.labels.dtype == np.uint8
    pts = ct.index_to_patient(np.argwhere(m))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    assert abs(pts[:, 0].mean()) < 0.5                   # centred on x = 0 (symmetric)
    assert 160 <= hi[0] - lo[0] <= 172                   # width incl. ears
    assert 195 <= hi[1] - lo[1] <= 215                   # nose tip to occiput
    assert lo[1] < -100 and hi[1] > 95
    # vertex inside the field of view with air above; the bottom slice cuts the neck
    rows_with_head = np.flatnonzero(m.any(axis=(1, 2)))
    assert rows_with_head[-1] <= ct.shape[0] - 4 and rows_with_head[0] == 0
    neck_area = m[0].sum() * 4.0
    assert 0.85 * math.pi * 50 * 54 < neck_area < 1.1 * math.pi * 50 * 54
    # the most anterior head point is the nose tip, in front of the mouth
    front = pts[np.argmin(pts[:, 1])]
    assert abs(front[0]) <= 4 and -45 < front[2] < -25


def test_head_mask_is_exact_truth_at_voxel_centres(phantom):
    centres = voxel_centres(phantom.ct)
    assert np.array_equal(phantom.inside_head(centres), phantom.head_mask)
    assert np.array_equal(phantom.labels_at(centres), phantom.labels)
    head_labels = ~np.isin(phantom.labels, [AIR, CUSHION, HOLDER])
    assert np.array_equal(head_labels, phantom.head_mask)
    assert phantom.inside_head(centres[40, 60, 64]) and not phantom.inside_head(np.array([0.0, 0.0, 108.0]))


def test_sample_hu_equals_grid_without_noise(clean):
    centres = voxel_centres(clean.ct)
    hu = clean.sample_hu(centres)
    assert hu.shape == clean.ct.shape and hu.dtype == np.float32
    assert np.abs(hu - clean.ct.data).max() < 1e-3
    # with a generator: the same plus white noise of the phantom's sigma
    noisy = make_phantom(noise=30.0)
    sample = noisy.sample_hu(centres[60:70], noise_rng=np.random.default_rng(5)) - clean.ct.data[60:70]
    assert 29 < sample.std() < 31 and abs(sample.mean()) < 0.5


def test_hu_per_label_hard_and_blurred(clean):
    hard = make_phantom(noise=0.0, blur=0.0)
    expected = {AIR: (-1000, -1000), SOFT_TISSUE: (0, 60), BONE: (700, 1500), BRAIN: (20, 40), EYE: (0, 20),
                INTERNAL_AIR: (-1000, -1000), CUSHION: (-900, -150), HOLDER: (200, 400)}
    for label, (lo, hi) in expected.items():
        values = hard.ct.data[hard.labels == label]
        assert values.size > 100, LABEL_NAMES[label]
        assert lo <= values.min() and values.max() <= hi, (LABEL_NAMES[label], values.min(), values.max())
    assert np.array_equal(hard.labels, clean.labels)
    # partial-volume blur changes values only near interfaces: medians stay put
    for label, med in {AIR: -1000, SOFT_TISSUE: 40, BONE: 1100, BRAIN: 32}.items():
        assert abs(np.median(clean.ct.data[clean.labels == label]) - med) < 15, LABEL_NAMES[label]
    boundary = clean.head_mask & ~ndi.binary_erosion(clean.head_mask)
    assert np.mean(clean.ct.data[boundary] < 0) > 0.1  # the skin boundary is partial-volumed


def test_noise_level(phantom, clean):
    noise = phantom.ct.data - clean.ct.data
    assert abs(noise.std() - 20.0) < 0.2 and abs(noise.mean()) < 0.2
    air = phantom.ct.data[-3:, :12, :12]           # a corner of air above the head
    assert np.all(clean.ct.data[-3:, :12, :12] == -1000.0)
    assert 18.5 < air.std() < 21.5
    brain = phantom.ct.data[80, 50:70, 55:75]
    assert np.all(phantom.labels[80, 50:70, 55:75] == BRAIN)
    assert 18.5 < brain.std() < 21.5 and abs(brain.mean() - 32) < 3


def test_cushion_and_holder_touch_the_head(phantom):
    near_head = ndi.binary_dilation(phantom.head_mask)
    labels = phantom.labels
    assert (near_head & (labels == CUSHION)).sum() > 500
    assert (near_head & (labels == HOLDER)).sum() > 20
    # a naive threshold + largest 3-D component keeps both (segmentation must remove them)
    dense = phantom.ct.data > -400
    lab, _ = ndi.label(dense)
    largest = lab == np.argmax(np.bincount(lab.ravel())[1:]) + 1
    assert (largest & (labels == HOLDER)).sum() > 0.8 * (labels == HOLDER).sum()
    cushion_dense = (largest & (labels == CUSHION)).sum() / (labels == CUSHION).sum()
    assert 0.02 < cushion_dense < 0.3   # only the compressed layer where the head rests
    # the holder touches the ears (sides), the cushion the back of the head
    touch = phantom.ct.index_to_patient(np.argwhere(near_head & (labels == HOLDER)))
    assert np.all(np.abs(touch[:, 0]) > 70)
    touch = phantom.ct.index_to_patient(np.argwhere(near_head & (labels == CUSHION)))
    assert np.all(touch[:, 1] > 55)


def test_axial_sections_connected_and_ears_not_star_shaped(phantom):
    for k, section in enumerate(phantom.head_mask):
        if section.any():
            assert ndi.label(section)[1] == 1, f"slice {k} has several head components"
            assert np.array_equal(ndi.binary_fill_holes(section), section), f"slice {k} has holes"
    # at ear level a ray from the centre leaves the head, crosses air behind the ear and the ear
    z = phantom.params["ear_level_z"]
    angles = np.radians(np.arange(0, 180, 1.0))
    radii = np.arange(0, 110, 0.25)
    pts = np.stack([np.cos(angles)[:, None] * radii, 10 + np.sin(angles)[:, None] * radii,
                    np.full((angles.size, radii.size), z)], axis=-1)
    crossings = np.abs(np.diff(phantom.inside_head(pts).astype(int), axis=1)).sum(axis=1)
    assert crossings.max() >= 3
    # the same holds on a finer grid (no detached bits of ears, nose or chin)
    fine = make_phantom(shape=(90, 256, 256), spacing=(1.0, 1.0, 1.0), noise=0.0)
    z0 = fine.ct.slice_heights()
    for k in np.flatnonzero(fine.head_mask.any(axis=(1, 2))):
        assert ndi.label(fine.head_mask[k])[1] == 1, f"fine slice at z={z0[k]:.1f} has several components"


def test_face_features(phantom):
    tip_y = min(surface_y(phantom, 0.0, z) for z in np.arange(-40.0, -25.0, 0.5))
    assert -110 < tip_y < -100
    cheek_y = surface_y(phantom, 25.0, -33.0)
    assert 20 <= cheek_y - tip_y <= 30                              # nose protrudes 20-30 mm
    eye, brow, below = (surface_y(phantom, 32.0, z) for z in (0.0, 12.0, -12.0))
    assert 4 <= eye - brow <= 12 and 1 <= eye - below <= 8          # shallow eye sockets
    upper, mouth, lower = (surface_y(phantom, 0.0, z) for z in (-50.0, -55.5, -61.0))
    assert mouth - upper > 4 and mouth - lower > 3                  # lips with a mouth line
    chin = surface_y(phantom, 0.0, -80.0)
    assert -85 < chin < -75
    # both ears stand out, with air between the ear's back edge and the head
    for side in (-1, 1):
        assert phantom.inside_head(np.array([side * 79.0, 20.0, -6.0]))
        assert not phantom.inside_head(np.array([side * 71.5, 20.0, -6.0]))
        assert phantom.inside_head(np.array([side * 66.0, 20.0, -6.0]))
    sym = voxel_centres(phantom.ct)[::5, ::5, ::5] * np.array([-1.0, 1.0, 1.0])
    assert np.array_equal(phantom.inside_head(sym), phantom.head_mask[::5, ::5, ::5])  # mirror symmetric


def test_resolution_independent_geometry(phantom):
    coarse = make_phantom(shape=(50, 64, 64), noise=0.0)
    fine_volume = phantom.head_mask.sum() * np.prod(phantom.ct.spacing)
    coarse_volume = coarse.head_mask.sum() * np.prod(coarse.ct.spacing)
    assert abs(coarse_volume / fine_volume - 1) < 0.02
    assert 3.0e6 < fine_volume < 3.6e6                                  # mm^3 (head + neck in the FOV)
    assert coarse.ct.spacing == pytest.approx((4.6, 4.0, 4.0))


@pytest.mark.parametrize("kwargs", [dict(shape=(10, 10)), dict(spacing=(1.0, -1.0, 1.0)), dict(noise=-1.0),
                                    dict(blur=float("nan")), dict(hu={"bone": 1000})])
def test_bad_parameters(kwargs):
    with pytest.raises(PDEHeadError):
        make_phantom(**kwargs)


# --------------------------------------------------------------------------------------------
# DICOM writer
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_ct(phantom):
    """A slab of the phantom (8 slices through the eyes, nose and ears)."""
    ct = phantom.ct
    k0 = int(np.argmin(np.abs(ct.slice_heights() + 20)))
    return CTVolume(ct.data[k0:k0 + 8], ct.spacing, origin=ct.index_to_patient(np.array([k0, 0, 0])),
                    direction=ct.direction)


def test_write_dicom_round_trip(small_ct, tmp_path):
    files = write_dicom_series(small_ct, tmp_path / "series", series_description="round trip", uid_seed=7)
    assert [f.name for f in files] == [f"CT{n:04d}.dcm" for n in range(1, 9)]
    with open(files[0], "rb") as fh:
        assert fh.read(132)[128:] == b"DICM"
    datasets = [pydicom.dcmread(f) for f in files]
    dz, dy, dx = small_ct.spacing
    for k, ds in enumerate(datasets):
        assert ds.file_meta.TransferSyntaxUID == pydicom.uid.ExplicitVRLittleEndian
        assert ds.SOPClassUID == pydicom.uid.CTImageStorage == ds.file_meta.MediaStorageSOPClassUID
        assert ds.SOPInstanceUID == ds.file_meta.MediaStorageSOPInstanceUID
        assert ds.Modality == "CT" and ds.PhotometricInterpretation == "MONOCHROME2"
        assert (ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation) == (16, 16, 15, 1)
        assert (ds.Rows, ds.Columns) == small_ct.shape[1:] and ds.InstanceNumber == k + 1
        assert ds.SeriesDescription == "round trip" and str(ds.PatientName) == "PDE^Phantom"
        assert [float(v) for v in ds.PixelSpacing] == [dy, dx]
        assert [float(v) for v in ds.ImageOrientationPatient] == [1, 0, 0, 0, 1, 0]
        ipp = np.array([float(v) for v in ds.ImagePositionPatient])
        assert np.allclose(ipp, small_ct.origin + [0, 0, k * dz], atol=1e-4)
        assert float(ds.SliceLocation) == pytest.approx(ipp[2], abs=1e-4)
        assert float(ds.SliceThickness) == pytest.approx(dz) and float(ds.GantryDetectorTilt) == 0
        assert ds.pixel_array.dtype == np.int16
        hu = ds.pixel_array * float(ds.RescaleSlope) + float(ds.RescaleIntercept)
        assert float(ds.RescaleIntercept) == -1024
        assert np.abs(hu - small_ct.data[k]).max() <= 0.5 + 1e-4
    for keyword in ("SeriesInstanceUID", "StudyInstanceUID", "FrameOfReferenceUID"):
        assert len({ds[keyword].value for ds in datasets}) == 1
    assert len({ds.SOPInstanceUID for ds in datasets}) == 8
    # deterministic UIDs with a seed: byte-identical files; random UIDs without
    again = write_dicom_series(small_ct, tmp_path / "again", series_description="round trip", uid_seed=7)
    assert all(a.read_bytes() == b.read_bytes() for a, b in zip(files, again))
    random_uid = write_dicom_series(small_ct, tmp_path / "random")
    assert pydicom.dcmread(random_uid[0]).SOPInstanceUID != datasets[0].SOPInstanceUID


def test_write_refuses_non_empty_folder_and_overwrites_own_files(small_ct, tmp_path):
    folder = tmp_path / "out"
    write_dicom_series(small_ct, folder)
    with pytest.raises(PDEHeadError, match="not empty"):
        write_dicom_series(small_ct, folder)
    (folder / "notes.txt").write_text("keep me")
    three = CTVolume(small_ct.data[:3], small_ct.spacing, small_ct.origin)
    files = write_dicom_series(three, folder, overwrite=True)
    assert sorted(p.name for p in folder.iterdir()) == ["CT0001.dcm", "CT0002.dcm", "CT0003.dcm", "notes.txt"]
    assert len(files) == 3
    with pytest.raises(PDEHeadError, match="not a folder"):
        write_dicom_series(small_ct, folder / "notes.txt")
    bad = CTVolume(np.where(np.arange(3)[:, None, None] == 1, np.nan, small_ct.data[:3]), small_ct.spacing)
    with pytest.raises(PDEHeadError, match="non-finite"):
        write_dicom_series(bad, tmp_path / "nan")
    padded = write_dicom_series(bad, tmp_path / "pad", pixel_padding_value=-2000)
    ds = pydicom.dcmread(padded[1])
    assert ds.PixelPaddingValue == -2000 and np.all(ds.pixel_array == -2000)


def test_write_sheared_volume_keeps_geometry(tmp_path):
    tilt = math.radians(18.5)
    direction = np.array([[1, 0, 0], [0, math.cos(tilt), 0], [0, -math.sin(tilt), 1]], float)
    ct = CTVolume(np.zeros((4, 6, 5), np.float32), (4.22, 0.5, 0.5), origin=(-1, -2, 3), direction=direction)
    files = write_dicom_series(ct, tmp_path / "shear")
    ds = [pydicom.dcmread(f) for f in files]
    assert float(ds[0].GantryDetectorTilt) == pytest.approx(18.5, abs=1e-3)
    assert np.allclose([float(v) for v in ds[2].ImagePositionPatient], [-1, -2, 3 + 2 * 4.22], atol=1e-5)
    assert float(ds[0].SliceThickness) == pytest.approx(4.22 * math.cos(tilt), abs=1e-4)


def test_write_phantom_series_ge_like_tilt(phantom, tmp_path):
    files = write_phantom_series(phantom, tmp_path / "tilt", rows=128, columns=128, pixel_spacing=(2.0, 2.0),
                                 fov_diameter=250.0, noise=False, uid_seed=3)
    assert len(files) == len(GE_LIKE_NORMAL_STEPS) + 1 == 28
    ds = [pydicom.dcmread(f) for f in files]
    t = math.radians(18.5)
    row, col = np.array([1.0, 0, 0]), np.array([0, math.cos(t), -math.sin(t)])
    ipp = np.array([[float(v) for v in d.ImagePositionPatient] for d in ds])
    for d in ds:
        assert np.allclose([float(v) for v in d.ImageOrientationPatient], [*row, *col], atol=1e-7)
        assert float(d.GantryDetectorTilt) == 18.5 and d.PixelPaddingValue == -1500
    assert np.allclose(ipp[:, :2], ipp[0, :2])                         # x, y fixed, only z moves
    normal = np.cross(row, col)
    assert np.allclose(np.diff(ipp @ normal), GE_LIKE_NORMAL_STEPS, atol=1e-4)
    assert np.allclose(np.diff(ipp[:, 2]), np.array(GE_LIKE_NORMAL_STEPS) / math.cos(t), atol=1e-4)
    assert [float(d.SliceThickness) for d in ds] == [4.0] * 14 + [7.0] * 14         # as in the GE set
    # every pixel is the analytic phantom at its patient position
    for n in (0, 13, 27):
        r, c = np.meshgrid(np.arange(128) * 2.0, np.arange(128) * 2.0, indexing="ij")
        pts = ipp[n] + c[..., None] * row + r[..., None] * col
        stored = ds[n].pixel_array
        inside_fov = stored != -1500
        assert 0.7 < inside_fov.mean() < 0.8 and not inside_fov[0, 0]
        truth = phantom.sample_hu(pts)
        assert np.abs(stored[inside_fov] - truth[inside_fov]).max() <= 0.5 + 1e-3
    # the series spans the head from below the nose to above the vertex
    top_centre = ipp[-1] + 127 * (row + col)
    assert top_centre[2] > phantom.params["vertex_z"] and not phantom.inside_head(top_centre)
    bottom_centre = ipp[0] + 127 * (row + col)
    assert bottom_centre[2] < phantom.params["nose_tip_z"] and phantom.inside_head(bottom_centre)


def test_load_ct_reads_the_writer(phantom, small_ct, tmp_path):
    from pdehead_addon import load_ct
    write_dicom_series(small_ct, tmp_path / "axial", uid_seed=1)
    ct = load_ct(tmp_path / "axial")
    assert ct.shape == small_ct.shape and ct.spacing == pytest.approx(small_ct.spacing)
    assert np.allclose(ct.origin, small_ct.origin) and np.allclose(ct.direction, np.eye(3))
    assert np.abs(ct.data - small_ct.data).max() <= 0.5 + 1e-4
    # tilted, uneven GE-like series: the importer's volume against the exact truth
    files = write_phantom_series(phantom, tmp_path / "tilt", fov_diameter=250.0, uid_seed=2)
    tilted = load_ct(tmp_path / "tilt")
    assert np.allclose(tilted.direction, np.eye(3))
    pts = voxel_centres(tilted)
    t = math.radians(18.5)
    normal = np.array([0.0, math.sin(t), math.cos(t)])
    planes = np.array([[float(v) for v in pydicom.dcmread(f).ImagePositionPatient] for f in files]) @ normal
    along = pts @ normal
    covered = (along > planes.min() + 2) & (along < planes.max() - 2)
    assert covered.mean() > 0.5
    truth = phantom.sample_hu(pts) > -400
    found = tilted.data > -400
    jaccard = (truth & found & covered).sum() / ((truth | found) & covered).sum()
    assert jaccard > 0.95


def test_metal_fillings_and_streaks_change_hu_only():
    from pdehead_addon.io.phantom import METAL
    plain, metal = make_phantom(noise=0.0), make_phantom(noise=0.0, metal=True)
    assert np.array_equal(plain.head_mask, metal.head_mask)        # streaks are not tissue
    fillings = metal.labels == METAL
    assert 20 < fillings.sum() < 400 and metal.head_mask[fillings].all()
    assert np.array_equal(plain.labels[~fillings], metal.labels[~fillings])
    assert metal.ct.data[fillings].max() > 2500
    diff = metal.ct.data - plain.ct.data
    ks = metal.params["metal_slices"]
    near = set(ks) | {k - 1 for k in ks} | {k + 1 for k in ks}   # (a neighbour may graze a filling)
    others = np.setdiff1d(np.arange(plain.ct.shape[0]), sorted(near))
    assert np.abs(diff[others]).max() < 1.0                      # streaks stay in the fillings' slices
    air = ~metal.head_mask & (plain.labels == 0)
    front = air.copy()
    front[:, 20:, :] = False                                      # the air in front of the face (small j)
    assert diff[ks][front[ks]].max() > 500 and diff[ks][front[ks]].min() < -300   # bright and dark rays
    # the analytic model gives the same values anywhere (sample_hu at the voxel centres)
    k = ks[len(ks) // 2]
    ct = metal.ct
    jj, ii = np.mgrid[0:ct.shape[1], 0:ct.shape[2]]
    pts = ct.index_to_patient(np.stack([np.full_like(jj, k), jj, ii], axis=-1))
    np.testing.assert_allclose(metal.sample_hu(pts), ct.data[k], atol=1e-3)
