"""A new user's inputs that used to build a wrong "head" or fail late (docs/input_cases.md, "New-user cases"):
the engine's side. The command line and the import operator: tests/blender/test_new_user_cli.py.
"""
from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage as ndi

from datasets import CTHEAD_RAW16_OPTIONS, shared_data
from made_inputs import portrait
from pdehead_addon import (
    CTImportError,
    Mesh,
    SegmentationError,
    bone_level_range,
    check_bone_level,
    check_head_scan,
    load_ct,
    make_phantom,
)
from pdehead_addon.core.wording import for_cli, for_dialog
from pdehead_addon.io import scan_evidence as IC
from pdehead_addon.io.mesh_input import MAX_SKULL_HULL_FILL, hull_fill, load_skull_mesh

ROOT = Path(__file__).resolve().parents[2]


def quiet(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_ct(path, **kw)


@pytest.fixture(scope="module")
def cthead():
    return quiet(shared_data("cthead_stanford", "raw16"), **CTHEAD_RAW16_OPTIONS)


@pytest.fixture(scope="module")
def ge():
    return quiet(shared_data("ct_head_ge_tilt_dicom", "dicom"))


@pytest.fixture(scope="module")
def phantom_ct():
    return make_phantom().ct


# ------------------------------------------------------------------ 1. not a head scan
def test_every_real_scan_cropped_and_resampled_is_a_head_scan(cthead, ge, phantom_ct):
    """CThead, GE, the phantom, the MRI and CThead's TIFFs pass, and so does CThead cropped (a slab of 20 slices,
    the face cut off at the sides), resampled (0.5 x, 4 x 4 x 4 block means, 3 x cubic in plane); each measure
    keeps a margin over its threshold."""
    scans = {"cthead": cthead.data, "ge": ge.data, "phantom": phantom_ct.data,
             "mri": quiet(shared_data("mri_colin27_ch2", "ch2.nii.gz")).data,
             "tiff8": quiet(shared_data("cthead_stanford", "tiff8"), spacing=(2, 1, 1)).data,
             "slab": cthead.data[40:60], "cropped": cthead.data[:, 60:200, 30:220],
             "zoom_0.5": ndi.zoom(cthead.data, 0.5, order=1),
             "blocks_4": cthead.data[:112].reshape(28, 4, 64, 4, 64, 4).mean(axis=(1, 3, 5)),
             "cubic_3x": ndi.zoom(cthead.data[::16], (1, 3, 3), order=3)}
    for name, data in scans.items():
        got = IC.head_scan_evidence(data)
        assert got["failed"] == [], (name, got)
        assert got["correlation"] >= 1.8 * IC.HEAD_MIN_NEIGHBOUR_CORRELATION, (name, got)
        assert got["edge_sharpness"] >= 2.0 * IC.HEAD_MIN_EDGE_SHARPNESS, (name, got)
        assert got["interior_detail"] >= 2.0 * IC.HEAD_MIN_INTERIOR_DETAIL, (name, got)
    # skull-only scans (everything below a bone level set to air: a dry skull's CT) are head scans too
    for name, data, level, air in (("cthead", cthead.data, 1500, 0), ("ge", ge.data, 400, -1000),
                                   ("phantom", phantom_ct.data, 565, -1000)):
        got = IC.head_scan_evidence(np.where(data >= level, data, air).astype(np.float32))
        assert got["failed"] == [] and got["interior_detail"] >= 1.4 * IC.HEAD_MIN_INTERIOR_DETAIL, (name, got)


def _png_folder(folder: Path, images) -> Path:
    from PIL import Image
    folder.mkdir()
    for k, img in enumerate(images):
        Image.fromarray(img).save(folder / f"IMG_{k + 1:04d}.png")
    return folder


def test_portraits_and_noise_are_not_a_head_scan(tmp_path):
    """A folder of 20 same-size greyscale portraits (smooth bright ovals) loads as a volume (load_ct reads any
    stack) but check_head_scan refuses it, as it refuses greyscale noise and identical sharp uniform discs."""
    rng = np.random.default_rng(1)
    cases = {
        "portraits": ([portrait(rng) for _ in range(20)], ["no sharp outline", "no anatomy inside"]),
        "noise": ([rng.integers(0, 256, (128, 128), dtype=np.uint8) for _ in range(30)], ["no coherent structure"]),
    }
    yy, xx = np.mgrid[:200, :200]
    disc = np.where(np.hypot(yy - 100, xx - 100) < 70, 200, 10).astype(np.float64)
    cases["discs"] = ([np.clip(disc + rng.normal(0, 2, disc.shape), 0, 255).astype(np.uint8) for _ in range(20)],
                      ["no anatomy inside"])
    for name, (images, needles) in cases.items():
        ct = quiet(_png_folder(tmp_path / name, images), spacing=(1, 1, 1))
        with pytest.raises(CTImportError) as refused:
            check_head_scan(ct)
        text = str(refused.value)
        assert text.startswith(f"{tmp_path / name}: not a head scan (CT or MRI): "), text
        for needle in needles:
            assert needle in text, text
        assert "\n" not in text


# ------------------------------------------------------------------ 2. a raw stack read with a wrong shape
def test_wrong_raw_shape_with_the_right_byte_count_is_refused_naming_the_shape():
    folder = shared_data("cthead_stanford", "raw16")
    opts = dict(CTHEAD_RAW16_OPTIONS)
    for shape in ((512, 128), (1024, 64)):
        with pytest.raises(CTImportError) as refused:
            quiet(folder, **dict(opts, shape=shape))
        text = str(refused.value)
        assert f"shape={shape} is not the slices' shape: its rows do not join up" in text, text
        assert text.endswith("the samples join up in rows of 256: shape=(256, 256)"), text
        cli = for_cli(text)
        assert f"--raw-shape {shape[0]} {shape[1]} is not the slices' shape" in cli and "--raw-shape 256 256" in cli
    rows, cols = IC.neighbour_correlation(quiet(folder, **opts).data)
    assert rows > 0.95 and cols > 0.95                         # the right shape: both high, nothing said
    bad = IC.wrong_row_length(np.fromfile(sorted(folder.iterdir())[50], ">i2").astype(np.float32)
                              .reshape(1, 512, 128).repeat(2, axis=0))
    assert bad["rows"] < 0.0 and bad["columns"] > 0.95 and bad["row_length"] == 256


# ------------------------------------------------------------------ 4. a bone level above the scan's bone
def test_bone_level_above_the_scans_bone_is_refused_with_the_range(cthead, ge, phantom_ct):
    cases = [(cthead, 2800.0, "stored"), (ge, 1200.0, "HU"), (phantom_ct, 1200.0, "HU")]
    for ct, level, units in cases:
        r = bone_level_range(ct)
        assert r["units"] == units and r["low"] < r["high"] < level < r["max"], r
        with pytest.raises(SegmentationError) as refused:
            check_bone_level(ct, level)
        text = str(refused.value)
        assert f"bone_level={level:g} is above this scan's bone: its bone spans {r['low']:.0f} to {r['max']:.0f} " \
               f"{units}" in text, text
        assert f"give a level from {r['low']:.0f} to {r['high']:.0f} {units}" in text
        assert for_cli(text).startswith(f"--bone-level {level:g} is above")
        assert for_dialog(text).startswith(f"'Bone Level' {level:g} is above")
    # the documented valid range: CThead 1284-2205 stored, GE 250-912 HU, the phantom 250-1105 HU; the levels
    # in it are accepted, those below the soft-tissue side refused too
    for ct, (low, high) in ((cthead, (1284, 2205)), (ge, (250, 912)), (phantom_ct, (250, 1105))):
        r = bone_level_range(ct)
        assert abs(r["low"] - low) <= 2 and abs(r["high"] - high) <= 2, r
        check_bone_level(ct, 0.5 * (low + high))
    with pytest.raises(SegmentationError, match="is below this scan's bone"):
        check_bone_level(ge, 100.0)


# ------------------------------------------------------------------ 5. a cube or a sphere as the skull mesh
def test_convex_meshes_are_refused_on_reading_and_skulls_are_not(tmp_path, phantom_ct):
    from skimage import measure

    from pdehead_addon.forensic.skull import segment_skull, skull_mesh
    from pdehead_addon.io.export import export_mesh
    v = np.array([[x, y, z] for x in (-75, 75) for y in (-75, 75) for z in (-75, 75)], float)
    quads = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])
    cube = export_mesh(Mesh(v, quads, np.zeros((0, 3), np.int64)), tmp_path / "cube.stl")
    z, y, x = np.mgrid[-100:101:2, -100:101:2, -100:101:2].astype(float)
    vv, f, _, _ = measure.marching_cubes(((x ** 2 + y ** 2 + z ** 2) < 75 ** 2).astype(np.float32), 0.5)
    sphere = export_mesh(Mesh(vv[:, ::-1] * 2 - 100, np.zeros((0, 4)), f[:, ::-1]), tmp_path / "sphere.stl")
    for path, fill in ((cube, 100), (sphere, 98)):
        with pytest.raises(CTImportError) as refused:
            load_skull_mesh(path)
        text = str(refused.value)
        assert f"does not look like a skull: the mesh is convex (it fills {fill} % of its convex hull" in text
        assert "Qhull" not in text and "QH" not in text and len(text) < 400, text
    bone = skull_mesh(segment_skull(phantom_ct))
    assert hull_fill(bone) < 0.5 * MAX_SKULL_HULL_FILL                # the phantom's bone skull: 22 %
    flat = Mesh(np.array([[0, 0, 0], [150, 0, 0], [0, 150, 0], [150, 150, 0]], float), np.zeros((0, 4), np.int64),
                np.array([[0, 1, 2], [1, 3, 2]]))
    with pytest.raises(ValueError, match="span no volume"):
        hull_fill(flat)


# ------------------------------------------------------------------ 7. the batch reads what the CLI reads
def test_the_batch_has_every_loader_option_of_the_cli_from_one_definition():
    sys.path.insert(0, str(ROOT / "scripts"))
    import _common
    import pdehead
    import pdehead_batch

    def loader_group(parser):
        groups = [g for g in parser._action_groups if g.title == "loader options"]
        assert len(groups) == 1
        return {a.dest: (tuple(a.option_strings), a.choices, a.nargs, a.default, a.help)
                for a in groups[0]._group_actions}

    cli = loader_group(pdehead._parser())
    batch_parser = pdehead_batch.parsers()[1]
    assert set(cli) == set(_common.LOADER_FLAGS) and loader_group(batch_parser) == cli
    args = pdehead_batch.parse_args(["run", "in", "--out", "o", "--raw-shape", "256", "256", "--dtype", ">i2",
                                     "--spacing", "2", "1", "1", "--first-slice", "superior", "--units", "stored",
                                     "--series-uid", "1.2", "--downsample", "2"])
    assert pdehead_batch.study_settings(args)["loader"] == dict(
        format="raw", shape=[256, 256], dtype=">i2", spacing=[2.0, 1.0, 1.0], first_slice="superior",
        units="stored", series_uid="1.2", downsample=2)
    with pytest.raises(pdehead_batch.CLIError, match="raw input needs --raw-shape NY NX, --dtype and --spacing"):
        pdehead_batch.parse_args(["run", "in", "--out", "o", "--raw-shape", "256", "256"])
    with pytest.raises(pdehead_batch.CLIError, match="give either --orientation or --first-slice"):
        pdehead_batch.parse_args(["run", "in", "--out", "o", "--orientation", "LAS", "--first-slice", "inferior"])


def test_the_batch_reads_a_raw_stack_with_the_loader_options(tmp_path):
    """CThead's raw slices through `pdehead_batch.py run --workers 0` with the loader options: ok, with the
    CLI's reading (first file superior, 2 x 2 x 2 block means); without them: recorded as failed (no raw
    options, no format detected), never a head of garbage."""
    import csv
    import json
    import subprocess
    folder = shared_data("cthead_stanford", "raw16")
    common = [sys.executable, str(ROOT / "scripts" / "pdehead_batch.py"), "run", str(folder), "--workers", "0",
              "--patches", "3", "--samples", "64", "--selection", "uniform"]
    raw = ["--raw-shape", "256", "256", "--dtype", ">i2", "--spacing", "2", "1", "1", "--first-slice", "superior",
           "--downsample", "2"]
    import os

    # this tree's engine
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run(common + ["--out", str(tmp_path / "ok")] + raw, capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr[-3000:]
    with open(tmp_path / "ok" / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 1 and rows[0]["status"] == "ok", rows
    study = next(p for p in (tmp_path / "ok").iterdir() if p.is_dir())
    from pdehead_addon import load_boundaries
    bset = load_boundaries(study / "boundaries.pdeh")
    assert bset.curves.shape[0] == 10
    spread = np.ptp(bset.curves[..., 2])                     # 113 slices of 2 mm: the curves span the head
    assert 150 < spread < 230, spread
    failed = subprocess.run(common + ["--out", str(tmp_path / "bare")], capture_output=True, text=True, env=env)
    assert failed.returncode == 0, failed.stderr[-3000:]
    with open(tmp_path / "bare" / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert rows[0]["status"] == "failed" and rows[0]["error"], rows
    assert json.loads(json.dumps(rows))[0]["error"].count("\n") == 0
