"""The headless CLI scripts/pdehead.py (its own Blender process, add-on registered from source)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
CLI = ROOT / "scripts" / "pdehead.py"


def run_cli(*args, tmp_path):
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender-user"))
    return subprocess.run([sys.executable, str(CLI), *map(str, args)], capture_output=True, text=True,
                          env=env, cwd=tmp_path)


def png_stats(path: Path) -> dict:
    from PIL import Image
    img = np.asarray(Image.open(path).convert("RGB"), np.float32) / 255.0
    border = np.concatenate([img[0], img[-1], img[:, 0], img[:, -1]])
    fg = np.abs(img - np.median(border, axis=0)).max(axis=2) > 0.06
    rows, cols = np.nonzero(fg)
    return dict(shape=img.shape, std=float(img.std()), fg=float(fg.mean()),
                cx=float(cols.mean() / img.shape[1]) if cols.size else None)


def test_cli_phantom_writes_blend_vdb_and_renders(tmp_path):
    out = tmp_path / "out"
    result = run_cli("--phantom", "--patches", 6, "--nu", 32, "--nv", 48, "--nw", 4, "--voxel-size", 4,
                     "--out", out / "phantom.blend", "--render", out / "surface.png",
                     "--render-volume", out / "volume.png", "--resolution", 120, "--render-samples", 8,
                     tmp_path=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    stdout = result.stdout
    for step in ("import", "segment", "boundaries", "surface", "solid", "w_field", "volume", "total"):
        assert f"\n  {step}" in stdout, stdout
    assert "19 x 256 points (t = 6, auto selection)" in stdout
    assert (out / "phantom.blend").is_file() and not (out / "phantom.blend1").exists()
    assert not list(out.glob(".*partial*"))                     # the scratch file is gone
    assert "Saved as" not in stdout and "wrote " in stdout         # written once, at the end, when it worked
    # one order (x, y, z) for dimensions and spacing: the phantom is 128 x 128 x 100 voxels of 2 x 2 x 2.3 mm
    assert "128 x 128 x 100 voxels (x, y, z), spacing 2 x 2 x 2.3 mm (x, y, z)" in stdout
    vdbs = list((out / "pdehead_vdb").glob("*.vdb"))
    assert [v.name for v in vdbs] == ["phantom.Phantom.vdb"] and vdbs[0].stat().st_size > 10_000
    for png in ("surface.png", "volume.png"):
        stats = png_stats(out / png)
        assert stats["shape"] == (120, 120, 3)
        assert 0.1 < stats["fg"] < 0.95, (png, stats)  # a head, not a blank or a filled frame
        assert stats["std"] > 0.03 and abs(stats["cx"] - 0.5) < 0.1, (png, stats)  # centred, symmetric head

    # the .blend written by the CLI reopens with the study, its objects and the relative VDB path
    check = ("import bpy, sys; bpy.ops.wm.open_mainfile(filepath=sys.argv[1]);"
             "c = [c for c in bpy.data.collections if c.get('pdehead_boundaries')][0];"
             "v = [o for o in c.all_objects if o.type == 'VOLUME'][0];"
             "print(c.name, len(c.all_objects), v.data.filepath)")
    reopened = subprocess.run([sys.executable, "-c", check, str(out / "phantom.blend")], capture_output=True,
                              text=True, env=dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "u2")))
    assert reopened.returncode == 0, reopened.stderr[-2000:]
    assert reopened.stdout.split()[-3:] == ["Phantom", "5", "//pdehead_vdb/phantom.Phantom.vdb"]  # + the settings Empty


def test_cli_bad_input_is_one_clear_line(tmp_path):
    result = run_cli(tmp_path / "missing-folder", "--out", tmp_path / "x.blend", tmp_path=tmp_path)
    assert result.returncode == 2
    assert result.stderr.strip() == f"pdehead: error: {tmp_path / 'missing-folder'}: no such file or folder"
    assert not (tmp_path / "x.blend").exists()

    empty = tmp_path / "empty"
    empty.mkdir()
    result = run_cli(empty, tmp_path=tmp_path)
    assert result.returncode == 2          # bad input (issue 18: it was 1)
    lines = result.stderr.strip().splitlines()
    assert lines[-1].startswith("pdehead: error: ") and str(empty) in lines[-1], result.stderr
    assert "Traceback" not in result.stderr


def test_cli_failure_prints_one_line_and_keeps_an_existing_out_file(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    old = tmp_path / "kept.blend"
    old.write_bytes(b"earlier result")
    result = run_cli(empty, "--out", old, tmp_path=tmp_path)
    assert result.returncode == 2
    errors = [line for line in (result.stdout + result.stderr).splitlines() if "error" in line.lower()]
    assert errors == [f"pdehead: error: {empty}: the folder is empty (no files in it or its subfolders)"], \
        (result.stdout, result.stderr)
    assert old.read_bytes() == b"earlier result"
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "blender-user") == [
        "empty", "kept.blend"]


def test_cli_rejects_zero_patches_and_conflicting_orientation(tmp_path):
    result = run_cli("--phantom", "--patches", 0, tmp_path=tmp_path)
    assert result.returncode == 2 and "--patches must be at least 1, got 0" in result.stderr
    result = run_cli("--phantom", "--orientation", "LAS", "--first-slice", "superior", tmp_path=tmp_path)
    assert result.returncode == 2 and "either --orientation or --first-slice" in result.stderr


def test_cli_raw_orientation_and_no_out_says_nothing_saved(tmp_path):
    """A posterior-first raw volume: the warning names the cause, --orientation LAS fixes it."""
    sys.path.insert(0, str(ROOT))
    from pdehead_addon import make_phantom
    ph = make_phantom(noise=0.0)
    raw = tmp_path / "back_first.raw"
    np.rint(ph.ct.data[:, ::-1]).astype(">i2").tofile(raw)
    dz, dy, dx = ph.ct.spacing
    common = ["--raw-shape", 128, 128, "--dtype", ">i2", "--spacing", dz, dy, dx, "--units", "HU",
              "--patches", 3, "--nu", 24, "--nv", 32, "--nw", 2, "--no-volume"]
    result = run_cli(raw, *common, tmp_path=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "warning   " in result.stdout and "the face (nose) seems to lie on the side" in result.stdout
    assert result.stdout.rstrip().endswith("not saved: no --out given (pass --out FILE.blend to keep the result)")
    result = run_cli(raw, *common, "--orientation", "LAS", tmp_path=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "the face (nose)" not in result.stdout and "warning" not in result.stdout
    # twice the true spacing makes a head outside the human range: the segmentation's warning reaches
    # the summary
    doubled = [str(2 * float(a)) if i in (6, 7, 8) else a for i, a in enumerate(common)]  # dz, dy, dx
    result = run_cli(raw, *doubled, "--orientation", "LAS", tmp_path=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "warning   the head mask is" in result.stdout and "outside the human range" in result.stdout


def test_cli_tolerance_picks_the_count_and_prints_the_achieved_error(tmp_path):
    """--tolerance: automatic selection of the fewest curves; the count and the achieved distance are printed,
    the .blend keeps that many curves; --tolerance with --patches is refused."""
    import re
    out = tmp_path / "tol.blend"
    result = run_cli("--phantom", "--tolerance", 0.3, "--nu", 24, "--nv", 32, "--nw", 2, "--no-volume",
                     "--out", out, tmp_path=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    m = re.search(r"selection auto: (\d+) curves of (\d+) usable slices; surface from all outlines mean "
                  r"(\d+\.\d+) mm.*: met", result.stdout)
    assert m, result.stdout[-2000:]
    count, usable, mean = int(m.group(1)), int(m.group(2)), float(m.group(3))
    assert 4 < count < usable and mean <= 0.3
    assert re.search(rf"curves\s+{count} x 256 points \(counted for the tolerance, auto selection\)", result.stdout)
    assert out.exists()
    result = run_cli("--phantom", "--tolerance", 0.3, "--patches", 4, tmp_path=tmp_path)
    assert result.returncode == 2 and "give either --patches or --tolerance" in result.stderr
    result = run_cli("--phantom", "--tolerance", 0.3, "--selection", "uniform", tmp_path=tmp_path)
    assert result.returncode == 2 and "chooses the slices itself" in result.stderr


def test_ctrl_c_stops_the_cli_with_130_and_leaves_no_output(tmp_path):
    """SIGINT while a long step runs: exit 130, one line saying so, no .blend / .vdb / folder left."""
    import signal
    out = tmp_path / "out"
    # every progress report printed (not one per half second: on a quiet machine the phantom segments faster)
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender-user"), PDEHEAD_PROGRESS_INTERVAL_S="0")
    proc = subprocess.Popen([sys.executable, str(CLI), "--phantom", "--patches", "6", "--nu", "32", "--nv", "48",
                             "--out", str(out / "phantom.blend"), "--render", str(out / "surface.png")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path,
                            # a shell's background job ignores SIGINT, and Python then keeps ignoring it
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    progress = []
    try:
        for line in proc.stderr:   # piped: plain progress lines, one per update
            progress.append(line)
            # the first progress line of a long step (segmentation, or the curves when a fast machine
            # segments the phantom between two progress updates)
            if line.startswith(("pdehead: segment", "pdehead: boundaries")) and "%" in line:
                proc.send_signal(signal.SIGINT)
                break
        rest = proc.stderr.read()
        stdout = proc.stdout.read()
        proc.wait(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert progress and progress[-1].startswith(("pdehead: segment", "pdehead: boundaries")), progress
    assert proc.returncode == 130, (stdout[-2000:], rest[-2000:])
    assert "cancelled (Ctrl-C)" in rest and "Traceback" not in rest
    assert not out.exists(), sorted(str(p) for p in out.rglob("*"))
    assert "wrote" not in stdout


def _cli_module():
    """scripts/pdehead.py as a module (its folder on sys.path for ``_common``)."""
    import importlib.util
    sys.path.insert(0, str(CLI.parent))
    spec = importlib.util.spec_from_file_location("pdehead_cli_under_test", CLI)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("ending", ["ok", "internal_error", "bad_input", "ctrl_c"])
def test_cli_removes_its_temporary_blender_folder_on_every_exit(tmp_path, monkeypatch, ending):
    """The CLI's own Blender user folder (/tmp/pdehead-cli-*) is gone after exit 0, 1, 2 and 130 (each run
    left an empty one behind); a folder given in BLENDER_USER_RESOURCES is the caller's and is not made."""
    import tempfile
    cli = _cli_module()
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    monkeypatch.setenv("BLENDER_USER_RESOURCES", "restored-after-the-test")
    monkeypatch.delenv("BLENDER_USER_RESOURCES")
    seen = []

    def run(args):
        folder = os.environ["BLENDER_USER_RESOURCES"]
        seen.append(folder)
        (Path(folder) / "config").mkdir()                    # Blender writes into it
        if ending == "internal_error":
            raise RuntimeError("a bug")
        if ending == "bad_input":
            raise cli.CLIError("INPUT: no head CT", 2)
        if ending == "ctrl_c":
            raise cli.Interrupted()
        return {}

    monkeypatch.setattr(cli, "run", run)
    if ending == "internal_error":
        with pytest.raises(RuntimeError):                    # uncaught: Python exits 1
            cli.main(["--phantom"])
    else:
        assert cli.main(["--phantom"]) == {"ok": 0, "bad_input": 2, "ctrl_c": 130}[ending]
    assert len(seen) == 1 and Path(seen[0]).parent == scratch and Path(seen[0]).name.startswith("pdehead-cli-")
    assert list(scratch.iterdir()) == [] and "BLENDER_USER_RESOURCES" not in os.environ


def test_cli_run_leaves_no_temporary_folder(tmp_path):
    """The same with Blender itself: a real run that ends in exit 2 after Blender started (an empty folder)."""
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    (tmp_path / "empty").mkdir()
    env = {k: v for k, v in os.environ.items() if k != "BLENDER_USER_RESOURCES"}
    env["TMPDIR"] = str(scratch)
    result = subprocess.run([sys.executable, str(CLI), str(tmp_path / "empty")], capture_output=True, text=True,
                            env=env, cwd=tmp_path)
    assert result.returncode == 2, result.stderr[-2000:]
    assert not [p.name for p in scratch.iterdir() if p.name.startswith("pdehead-cli-")]
