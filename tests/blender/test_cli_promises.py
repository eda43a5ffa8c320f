"""Issue 18: the command line keeps its promises and speaks in flags; the import dialog speaks in its fields.

Every test runs scripts/pdehead.py (or the add-on's import operator) in its own Blender process, as a
user would, and checks the exit code, the lines on stderr, the files written and the --summary-json.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np

from test_cli import ROOT, run_cli

sys.path.insert(0, str(ROOT / "tests"))
from datasets import shared_data  # noqa: E402

LIGHT = ["--no-volume", "--patches", 3, "--nu", 24, "--nv", 32, "--nw", 2, "--samples", 64]


def error_lines(result) -> list[str]:
    return [line for line in result.stderr.splitlines() if line.strip()]


def assert_one_line_error(result, code: int, *needles: str) -> str:
    lines = error_lines(result)
    assert result.returncode == code, (result.returncode, result.stderr[-2000:])
    assert len(lines) == 1 and lines[0].startswith("pdehead: error: "), result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------------ 1. + 4. + 5. an image stack, Auto, JPEG, JSON
def test_image_stack_auto_flips_warns_once_in_flags_writes_jpeg_and_summary_json(tmp_path):
    """`pdehead.py .../tiff8 --spacing 2 1 1`: main put the crown at the bottom without a word and wrote
    x.png for --render x.jpg."""
    summary, jpg = tmp_path / "out" / "summary.json", tmp_path / "out" / "head.jpg"
    result = run_cli(shared_data("cthead_stanford", "tiff8"), "--spacing", 2, 1, 1, *LIGHT,
                     "--render", jpg, "--resolution", 48, "--render-samples", 1, "--summary-json", summary,
                     tmp_path=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    warnings = [line for line in result.stderr.splitlines() if line.startswith("pdehead: warning: ")]
    # the Auto first slice is right for this stack: information in the summary, not a warning
    assert not any("crown" in w for w in warnings), result.stderr
    crown = [line for line in result.stdout.splitlines() if line.startswith("  info ") and "crown" in line]
    assert len(crown) == 1 and "--first-slice inferior" in crown[0], result.stdout
    assert "first_slice" not in result.stdout + result.stderr and "orientation=" not in result.stderr  # no Python
    assert all(line.startswith("pdehead: ") for line in error_lines(result)), result.stderr  # no source lines
    # --render x.jpg writes a JPEG at that name, and only that
    assert jpg.read_bytes()[:3] == b"\xff\xd8\xff" and not jpg.with_suffix(".png").exists()
    assert f"wrote {jpg}" in result.stdout
    data = json.loads(summary.read_text())
    assert data["status"] == "ok" and data["exit_code"] == 0
    assert data["ct"]["voxels_xyz"] == [256, 256, 99] and data["ct"]["spacing_mm_xyz"] == [1.0, 1.0, 2.0]
    assert data["ct"]["orientation"] == "LPI" and data["ct"]["first_slice"] == "superior"
    assert data["curves"]["count"] == 10 and data["surface"]["vertices"] > 500
    assert set(data["timings_s"]) >= {"import", "segment", "boundaries", "surface", "solid"}
    assert data["warnings"] == [w.removeprefix("pdehead: warning: ") for w in warnings]
    assert data["info"] == [crown[0].split("info", 1)[1].strip()]
    assert data["outputs"] == {"render": str(jpg)}


# ------------------------------------------------------------------ 5. exit 2 for every bad input, one line
def test_bad_inputs_exit_2_with_one_line(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert_one_line_error(run_cli(empty, tmp_path=tmp_path), 2, str(empty), "empty")
    text = tmp_path / "notes.txt"
    text.write_text("scan notes\n")
    assert_one_line_error(run_cli(text, tmp_path=tmp_path), 2, str(text), "--format raw", "--raw-shape NY NX",
                          "--dtype '>i2'")
    # CThead's big-endian slices read as little-endian: refused, naming the flag's right value
    summary = tmp_path / "bad.json"
    line = assert_one_line_error(run_cli(shared_data("cthead_stanford", "raw16"), "--raw-shape", 256, 256,
                                         "--dtype", "<i2", "--spacing", 2, 1, 1, "--summary-json", summary,
                                         tmp_path=tmp_path), 2, "wrong byte order", "--dtype '>i2'")
    assert json.loads(summary.read_text()) == {"status": "error", "exit_code": 2,
                                               "error": line.removeprefix("pdehead: error: "), "warnings": []}


def test_folder_of_photos_exits_2_before_segmentation(tmp_path):
    from PIL import Image

    from made_inputs import photo
    rng = np.random.default_rng(3)
    photos = tmp_path / "photos"
    photos.mkdir()
    for k in range(20):
        Image.fromarray(photo(rng)).save(photos / f"DSC{k:04d}.png")
    out = tmp_path / "photos.blend"
    result = run_cli(photos, "--out", out, tmp_path=tmp_path)
    assert_one_line_error(result, 2, "does not look like a head CT", "colour images", "20 image(s) of 320 x 240")
    assert "Segmented" not in result.stdout and not out.exists()


def test_unwritable_outputs_are_one_line_before_any_work(tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    for flag, path in (("--out", blocker / "x.blend"), ("--render", blocker / "x.png"),
                       ("--summary-json", blocker / "s.json"), ("--out", tmp_path)):
        result = run_cli("--phantom", flag, path, tmp_path=tmp_path)
        assert_one_line_error(result, 2, f"{flag} {path}: ")
        assert "Imported" not in result.stdout and "Phantom loaded" not in result.stdout
    result = run_cli("--phantom", "--render", tmp_path / "x.tif", tmp_path=tmp_path)
    assert result.returncode == 2 and "--render" in result.stderr and ".jpg" in result.stderr
    assert not list(tmp_path.glob("x.*"))


# ------------------------------------------------------------------ 5. one DICOM file loads its series
def test_single_dicom_file_loads_the_series_it_belongs_to(tmp_path):
    """A folder with two series; the file given belongs to the smaller one (the folder default would
    load the larger, main loaded the one file)."""
    sys.path.insert(0, str(ROOT))
    from pdehead_addon import CTVolume, make_phantom
    from pdehead_addon.validation import write_dicom_series
    ph = make_phantom(noise=0.0)
    folder = tmp_path / "dicom"
    head = write_dicom_series(ph.ct, folder, series_description="phantom head", series_number=1, file_prefix="A",
                              uid_seed="head")
    rng = np.random.default_rng(0)
    other = CTVolume(rng.normal(0, 50, (140, 32, 32)).astype(np.float32), (1.0, 4.0, 4.0))
    write_dicom_series(other, folder, series_description="scout junk", series_number=2, file_prefix="B",
                       uid_seed="junk", overwrite=True)
    summary = tmp_path / "s.json"
    light = [a for a in LIGHT if a not in ("--patches", 3)]
    result = run_cli(head[40], *light, "--tolerance", 0.3, "--summary-json", summary, tmp_path=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    data = json.loads(summary.read_text())
    assert data["study"] == "phantom head" and data["ct"]["voxels_xyz"] == [128, 128, 100]
    # numbers are rounded for people: spacing 2.3 mm, not 2.299999952316284; the tolerance 0.3 mm (a float32
    # property), not 0.30000001192092896
    printed = result.stdout + result.stderr
    assert "2.2999" not in printed and data["ct"]["spacing_mm_xyz"] == [2.0, 2.0, 2.3]
    assert "asked mean <= 0.3 mm, max <= none mm" in printed and "0.3000000" not in printed, printed


# ------------------------------------------------------------------ 4. the dialog speaks in its fields
DIALOG_SCRIPT = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
import _common
addon = _common.load_addon(register=True)
import bpy
state = addon.operators.state
out = {}
r = bpy.ops.pdehead.import_ct(directory=sys.argv[2], format='IMAGES', use_spacing=True, spacing=(2, 1, 1))
coll = bpy.context.scene.pdehead.active_study
s = coll.pdehead
out["auto"] = [state.user_text(w) for w in addon.operators.study.entity.Study.of(coll).warnings]
out["info"] = [state.user_text(w) for w in addon.operators.study.entity.Study.of(coll).notes]
out["orientation"] = state.cache_for(s.study_id).ct.meta["orientation"]
try:
    bpy.ops.pdehead.import_ct(directory=sys.argv[3], format='RAW', raw_shape=(256, 256), raw_dtype='i2',
                              byte_order='LITTLE', spacing=(2, 1, 1))
except RuntimeError as exc:
    out["byte_order_error"] = str(exc)
print("RESULT" + json.dumps(out))
"""


def test_import_dialog_auto_and_messages_name_its_fields(tmp_path):
    script = tmp_path / "dialog.py"
    script.write_text(DIALOG_SCRIPT)
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender-user"))
    result = subprocess.run(
        [
            sys.executable,
            str(script),
            str(ROOT / "scripts"),
            str(shared_data("cthead_stanford", "tiff8")),
            str(shared_data("cthead_stanford", "raw16")),
        ],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    out = json.loads(result.stdout.split("RESULT", 1)[1])
    assert out["orientation"] == "LPI"                       # Auto in the dialog = the engine's rule
    assert not any("crown" in w for w in out["auto"]), out          # a correct stack: no warning ...
    crown = [n for n in out["info"] if "crown" in n]                 # ... the automatic choice as information
    assert len(crown) == 1 and "set 'First Slice' Inferior" in crown[0] and "first_slice" not in crown[0], out
    error = out["byte_order_error"]
    assert "wrong byte order" in error and "'Byte Order' Big Endian" in error and "dtype=" not in error, error
