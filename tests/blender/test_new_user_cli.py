"""A new user's inputs through the command line and the import operator (docs/input_cases.md, "New-user
cases"): each ends as the table says. The engine's side: tests/io/test_new_user_inputs.py.

Every test runs scripts/pdehead.py (or a script driving the add-on's operators) in its own Blender process.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np

from test_cli import ROOT, run_cli
from test_cli_promises import LIGHT, assert_one_line_error

sys.path.insert(0, str(ROOT / "tests"))
from datasets import shared_data  # noqa: E402
from made_inputs import portrait  # noqa: E402

RAW16 = ["--raw-shape", 256, 256, "--dtype", ">i2", "--spacing", 2, 1, 1]


def _pngs(folder, images):
    from PIL import Image
    folder.mkdir(parents=True)
    for k, img in enumerate(images):
        Image.fromarray(img).save(folder / f"IMG_{k + 1:04d}.png")
    return folder


def _before_segmentation(result) -> None:
    """Nothing was segmented: no segmentation progress, no 'Segmented' report."""
    assert "Segmented" not in result.stdout and "segment " not in result.stderr, result.stdout + result.stderr


# ------------------------------------------------------------------ 1. not a head scan
def test_cli_refuses_portraits_as_not_a_head_scan_before_segmentation(tmp_path):
    """A folder of 20 same-size greyscale portraits (smooth bright ovals): it built a flat slab, exit 0."""
    folder = _pngs(tmp_path / "portraits", [portrait(np.random.default_rng(k)) for k in range(20)])
    result = run_cli(folder, *LIGHT, tmp_path=tmp_path)
    line = assert_one_line_error(result, 2, "not a head scan (CT or MRI)", str(folder), "no sharp outline")
    assert "Traceback" not in line
    _before_segmentation(result)


IMPORT_SCRIPT = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
import _common
addon = _common.load_addon(register=True)
import bpy
out = {}
try:
    out["result"] = sorted(bpy.ops.pdehead.import_ct(directory=sys.argv[2], format='IMAGES'))
except RuntimeError as exc:
    out["error"] = str(exc)
out["studies"] = int(bpy.context.scene.pdehead.active_study is not None)
print("RESULT" + json.dumps(out))
"""


def test_import_operator_reports_greyscale_noise_as_not_a_head_scan(tmp_path):
    """In Blender greyscale noise built a ball: the import operator reports the refusal; no study is made."""
    rng = np.random.default_rng(3)
    folder = _pngs(tmp_path / "noise", [rng.integers(0, 256, (160, 160), dtype=np.uint8) for _ in range(30)])
    script = tmp_path / "import.py"
    script.write_text(IMPORT_SCRIPT)
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender-user"))
    result = subprocess.run([sys.executable, str(script), str(ROOT / "scripts"), str(folder)],
                            capture_output=True, text=True, env=env, cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    out = json.loads(result.stdout.split("RESULT", 1)[1])
    assert "not a head scan (CT or MRI)" in out.get("error", "") and "no coherent structure" in out["error"], out
    assert out["studies"] == 0, out


# ------------------------------------------------------------------ 2. a raw stack read with a wrong shape
def test_cli_wrong_raw_shape_exit_2_naming_raw_shape(tmp_path):
    result = run_cli(shared_data("cthead_stanford", "raw16"), "--raw-shape", 512, 128, "--dtype", ">i2",
                     "--spacing", 2, 1, 1, *LIGHT, tmp_path=tmp_path)
    assert_one_line_error(result, 2, "--raw-shape 512 128 is not the slices' shape: its rows do not join up",
                          "--raw-shape 256 256")
    _before_segmentation(result)


# ---------------------------------------------------- 3. every choice the CLI offers, through the operators
CHOICES_SCRIPT = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
import _common
addon = _common.load_addon(register=True)
import bpy
import pdehead
inputs = json.loads(sys.argv[2])
parser = pdehead._parser()
group = next(g for g in parser._action_groups if g.title == "loader options")
out = []
for action in group._group_actions:
    for choice in action.choices or ():
        flag = action.option_strings[0]
        if action.dest == "format":
            argv = [inputs[choice]] + (inputs["raw_flags"] if choice == "raw" else [])
        else:
            argv = [inputs["raw"]] + inputs["raw_flags"]
        argv += [flag, choice]
        row = {"flag": flag, "choice": choice}
        try:
            args = pdehead.parse_args(argv + ["--no-volume"])
            assert bpy.ops.pdehead.import_ct(**pdehead.loader_kwargs(args)) == {'FINISHED'}
            coll = bpy.context.scene.pdehead.active_study
            study = addon.operators.study.entity.Study.of(coll)
            meta = addon.operators.state.cache_for(coll.pdehead.study_id).ct.meta
            row.update(format=meta.get("format"), units=meta.get("units"), first_slice=meta.get("first_slice"),
                       warnings=study.warnings, notes=study.notes)
            bpy.ops.pdehead.remove_study()
            # the CLI's own path: the same values into the study's import, without the operator
            path, options = addon.operators.ui.import_options.import_request(**pdehead.loader_kwargs(args))
            study = addon.operators.study.entity.Study.import_ct(bpy.context, path, options)
            meta = addon.operators.state.cache_for(study.study_id).ct.meta
            row["cli"] = [meta.get("format"), meta.get("units"), meta.get("first_slice")]
            study.remove()
        except Exception as exc:
            row["error"] = f"{type(exc).__name__}: {exc}"
        out.append(row)
print("RESULT" + json.dumps(out))
"""


def test_every_choice_of_the_cli_loader_flags_runs_through_the_operators(tmp_path):
    """--units stored (offered by --help) ended in TypeError: enum "STORED" not found. Each choices= of the
    loader flags (--format, --first-slice, --units) goes through loader_kwargs into bpy.ops.pdehead.import_ct
    and, as the CLI imports, into the study's import (import_request), and gives the CT it names."""
    from pdehead_addon import make_phantom
    from pdehead_addon.validation import write_dicom_series
    dicom = tmp_path / "dicom"
    write_dicom_series(make_phantom(shape=(40, 96, 96)).ct, dicom)
    raw = str(shared_data("cthead_stanford", "raw16"))
    inputs = {"auto": str(dicom), "dicom": str(dicom), "images": str(shared_data("cthead_stanford", "tiff8")),
              "raw": raw, "raw_flags": [str(a) for a in RAW16]}
    script = tmp_path / "choices.py"
    script.write_text(CHOICES_SCRIPT)
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender-user"))
    result = subprocess.run([sys.executable, str(script), str(ROOT / "scripts"), json.dumps(inputs)],
                            capture_output=True, text=True, env=env, cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    rows = {(r["flag"], r["choice"]): r for r in json.loads(result.stdout.split("RESULT", 1)[1])}
    assert set(rows) == {("--format", c) for c in ("auto", "dicom", "images", "raw")} | \
        {("--first-slice", c) for c in ("auto", "superior", "inferior")} | {("--units", c) for c in ("HU", "stored")}
    assert not [r for r in rows.values() if "error" in r], [r for r in rows.values() if "error" in r]
    assert all(r["cli"] == [r["format"], r["units"], r["first_slice"]] for r in rows.values()), rows
    assert [rows[("--format", c)]["format"] for c in ("auto", "dicom", "images", "raw")] == \
        ["dicom", "dicom", "image", "raw"]
    assert rows[("--units", "HU")]["units"] == "HU" and rows[("--units", "stored")]["units"] != "HU"
    # CThead's first file is the top: Auto and Superior read it so, Inferior as asked (and questioned)
    assert [rows[("--first-slice", c)]["first_slice"] for c in ("auto", "superior", "inferior")] == \
        ["superior", "superior", "inferior"]
    # 8. the automatic choice on a correct stack is information, not a warning
    auto = rows[("--first-slice", "auto")]
    assert not any("crown" in w for w in auto["warnings"]), auto
    assert any("crown" in n and "first file" in n for n in auto["notes"]), auto
    assert any("upside down" in w for w in rows[("--first-slice", "inferior")]["warnings"])


# ------------------------------------------------------------------ 4. a bone level above the scan's bone
def test_cli_bone_level_above_the_bone_exit_2_before_segmentation(tmp_path):
    result = run_cli(shared_data("cthead_stanford", "raw16"), *RAW16, *LIGHT, "--skull", "--bone-level", 2800,
                     tmp_path=tmp_path)
    assert_one_line_error(result, 2, "--bone-level 2800 is above this scan's bone: its bone spans 1284 to 3272 "
                                     "stored", "give a level from 1284 to 2205 stored")
    _before_segmentation(result)


# ------------------------------------------------------------------ 5. a cube or a sphere as the skull
def test_cli_cube_and_sphere_skull_mesh_refused_on_reading(tmp_path):
    from skimage import measure

    from pdehead_addon import Mesh
    from pdehead_addon.io.export import export_mesh
    (tmp_path / "in").mkdir()
    v = np.array([[x, y, z] for x in (-75, 75) for y in (-75, 75) for z in (-75, 75)], float)
    quads = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])
    cube = export_mesh(Mesh(v, quads, np.zeros((0, 3), np.int64)), tmp_path / "in" / "cube.stl")
    z, y, x = np.mgrid[-100:101:2, -100:101:2, -100:101:2].astype(float)
    vv, f, _, _ = measure.marching_cubes(((x ** 2 + y ** 2 + z ** 2) < 75 ** 2).astype(np.float32), 0.5)
    sphere = export_mesh(Mesh(vv[:, ::-1] * 2 - 100, np.zeros((0, 4)), f[:, ::-1]), tmp_path / "in" / "sphere.stl")
    for mesh in (cube, sphere):
        t0 = time.perf_counter()
        result = run_cli("--skull-mesh", mesh, *LIGHT, tmp_path=tmp_path)
        seconds = time.perf_counter() - t0                      # reported, not asserted (shared machines)
        line = assert_one_line_error(result, 2, "does not look like a skull: the mesh is convex", str(mesh))
        assert "Qhull" not in result.stderr and "QH" not in result.stderr and len(line) < 400, result.stderr
        _before_segmentation(result)
        print(f"{os.path.basename(mesh)}: refused after {seconds:.1f} s (the whole process)")


# ------------------------------------------------------------------ 6. no --out: nothing left in the system temp
def test_cli_without_out_leaves_no_vdb_in_the_system_temp_folder(tmp_path):
    system_tmp = tmp_path / "system-tmp"
    system_tmp.mkdir()
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender-user"), TMPDIR=str(system_tmp))
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "pdehead.py"), "--phantom", "--patches", "3",
                             "--nu", "24", "--nv", "32", "--nw", "2", "--samples", "64", "--voxel-size", "4"],
                            capture_output=True, text=True, env=env, cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    volume = next(line for line in result.stdout.splitlines() if line.startswith("  volume "))
    vdb = volume.split()[1].rstrip(",")
    assert vdb.endswith(".vdb") and vdb.startswith(str(system_tmp / "pdehead-cli-tmp-")), volume
    assert not os.path.exists(vdb)                                   # written during the run, removed at exit
    left = [p for p in system_tmp.rglob("*") if p.suffix == ".vdb" or p.name.startswith("pdehead")]
    assert left == [], left
