"""The CLI never loses nor leaks a file (scripts/pdehead.py's Staging and Watchdog, pdehead_addon/io/safe_io.py).

- two runs into one folder: Ctrl-C on one (during its render) keeps the other's finished .blend and .vdb,
  and a cancelled run with the same --out leaves the finished file as it was;
- Ctrl-C during a Cycles render, the DICOM scan or the skull steps ends the run (exit 130, nothing of it
  left); a second Ctrl-C too;
- --out (and the renders) inside the input folder are refused before any work (exit 2);
- a full disk (a small tmpfs, where this machine lets the test mount one) ends in one error naming the
  file, and leaves no partial or orphan file.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CLI = ROOT / "scripts" / "pdehead.py"
SMALL = ["--phantom", "--patches", "4", "--nu", "16", "--nv", "24", "--nw", "3", "--voxel-size", "6"]


def _env(tmp_path, name):
    # every progress report printed (the CLI prints one per half second): the tests cancel at a progress line
    return dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / f"user-{name}"), PYTHONUNBUFFERED="1",
                PDEHEAD_PROGRESS_INTERVAL_S="0")


def _start(tmp_path, name, *args):
    return subprocess.Popen([sys.executable, str(CLI), *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=_env(tmp_path, name), cwd=tmp_path,
                            # a shell's background job ignores SIGINT, and Python then keeps ignoring it
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _run(tmp_path, name, *args):
    return subprocess.run([sys.executable, str(CLI), *map(str, args)], capture_output=True, text=True,
                          env=_env(tmp_path, name), cwd=tmp_path)


def _wait_for(stream, prefix: str) -> list[str]:
    seen = []
    for line in stream:
        seen.append(line)
        if line.startswith(prefix):
            return seen
    raise AssertionError(f"no line starting {prefix!r}: {''.join(seen)[-2000:]}")


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _interrupt(proc) -> tuple[float, str]:
    """Ctrl-C to a run: (seconds until it exited, its stderr)."""
    proc.send_signal(signal.SIGINT)
    t0 = time.perf_counter()
    proc.wait(timeout=600)
    return time.perf_counter() - t0, proc.stderr.read()


def _assert_cancelled_leaving_nothing(proc, err: str, folder: Path) -> None:
    assert proc.returncode == 130, err[-2000:]
    assert "cancelled (Ctrl-C)" in err and "Traceback" not in err
    assert not folder.exists() or _files(folder) == [], _files(folder)


def test_ctrl_c_during_a_render_keeps_the_other_runs_outputs(tmp_path):
    d = tmp_path / "d"
    # A: a long render (it would take minutes); B runs to its end meanwhile into the same folder
    a = _start(tmp_path, "a", *SMALL, "--out", d / "a.blend", "--render", d / "a.png", "--resolution", 600,
               "--render-samples", 20000)
    try:
        _wait_for(a.stdout, "  total")           # A's steps are done: it saves privately, then renders
        time.sleep(2.0)
        b = _run(tmp_path, "b", *SMALL, "--out", d / "b.blend")
        assert b.returncode == 0, b.stderr[-2000:]
        assert a.poll() is None, "the render ended before the test could cancel it"
        b_files = {name: (d / name).read_bytes() for name in ("b.blend", "pdehead_vdb/b.Phantom.vdb")}
        latency, err = _interrupt(a)
    finally:
        if a.poll() is None:
            a.kill()
    print(f"Ctrl-C during a Cycles render: exit after {latency:.2f} s")
    assert a.returncode == 130, err[-2000:]
    assert "cancelled (Ctrl-C)" in err and "Traceback" not in err
    # A left nothing; B's files are all there, byte for byte
    assert _files(d) == ["b.blend", "pdehead_vdb", "pdehead_vdb/b.Phantom.vdb"]
    assert all((d / name).read_bytes() == data for name, data in b_files.items())

    # the same --out as B's finished file: cancelled during segmentation, B's file stays as it was
    c = _start(tmp_path, "c", *SMALL, "--out", d / "b.blend")
    try:
        _wait_for(c.stderr, "pdehead: segment")
        c.send_signal(signal.SIGINT)
        c.wait(timeout=600)
        err = c.stderr.read()
    finally:
        if c.poll() is None:
            c.kill()
    assert c.returncode == 130, err[-2000:]
    assert _files(d) == ["b.blend", "pdehead_vdb", "pdehead_vdb/b.Phantom.vdb"]
    assert all((d / name).read_bytes() == data for name, data in b_files.items())


def test_two_runs_with_the_same_out_never_share_a_file(tmp_path):
    """Both finish: the .blend is the last one's, each volume has its own .vdb and the .blend's loads."""
    d = tmp_path / "d"
    runs = [_start(tmp_path, f"r{n}", *SMALL, "--out", d / "same.blend") for n in range(2)]
    for r in runs:
        r.wait(timeout=900)
        assert r.returncode == 0, r.stderr.read()[-2000:]
    names = _files(d)
    assert sorted(names) == ["pdehead_vdb", "pdehead_vdb/same.Phantom-2.vdb", "pdehead_vdb/same.Phantom.vdb",
                             "same.blend"]
    check = ("import bpy, sys; bpy.ops.wm.open_mainfile(filepath=sys.argv[1]);"
             "v = [o for o in bpy.data.objects if o.type == 'VOLUME'][0];"
             "print(v.data.filepath, v.data.grids.load(), len(v.data.grids))")
    reopened = subprocess.run([sys.executable, "-c", check, str(d / "same.blend")], capture_output=True,
                              text=True, env=_env(tmp_path, "check"))
    path, loaded, grids = reopened.stdout.split()[-3:]
    assert path.startswith("//pdehead_vdb/same.Phantom") and loaded == "True" and int(grids) >= 2, reopened.stdout


def test_a_second_ctrl_c_ends_the_run_at_once_without_a_traceback(tmp_path):
    d = tmp_path / "d"
    a = _start(tmp_path, "a", *SMALL, "--out", d / "a.blend", "--render", d / "a.png", "--resolution", 600,
               "--render-samples", 20000)
    try:
        _wait_for(a.stdout, "  total")
        time.sleep(2.0)
        a.send_signal(signal.SIGINT)
        time.sleep(0.05)
        a.send_signal(signal.SIGINT)
        a.wait(timeout=600)
        err = a.stderr.read()
    finally:
        if a.poll() is None:
            a.kill()
    assert a.returncode == 130 and "Traceback" not in err, err[-2000:]
    assert not d.exists() or _files(d) == [], _files(d)


def test_ctrl_c_during_the_dicom_scan_ends_the_run(tmp_path):
    """A large folder (the GE series linked 150 times: 4200 files) is being scanned (a file of it open in the
    process) when Ctrl-C comes: exit 130, nothing written."""
    from datasets import shared_data
    ge = shared_data("ct_head_ge_tilt_dicom", "dicom").resolve()
    big = tmp_path / "big"
    for n in range(150):
        sub = big / f"s{n:03d}"
        sub.mkdir(parents=True)
        for f in sorted(ge.iterdir()):
            (sub / f.name).symlink_to(f)
    d = tmp_path / "d"
    proc = _start(tmp_path, "scan", big, "--out", d / "x.blend")
    try:
        deadline = time.monotonic() + 600
        while proc.poll() is None and time.monotonic() < deadline:
            try:
                links = [os.readlink(f"/proc/{proc.pid}/fd/{fd}") for fd in os.listdir(f"/proc/{proc.pid}/fd")]
            except OSError:
                links = []
            if any(link.startswith(str(ge)) for link in links):
                break
            time.sleep(0.005)
        assert proc.poll() is None, "the run ended before the test saw it scan"
        latency, err = _interrupt(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    print(f"Ctrl-C during the DICOM scan: exit after {latency:.2f} s")
    _assert_cancelled_leaving_nothing(proc, err, d)


def test_ctrl_c_during_the_skull_steps_ends_the_run(tmp_path):
    """Ctrl-C just after the solid, while the skull is built: exit 130, nothing written, no traceback."""
    d = tmp_path / "d"
    proc = _start(tmp_path, "skull", *SMALL, "--no-volume", "--skull", "--out", d / "x.blend")
    try:
        _wait_for(proc.stdout, "Info: PDE solid of")   # the next step is the skull
        time.sleep(0.5)
        assert proc.poll() is None
        latency, err = _interrupt(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    print(f"Ctrl-C during the skull steps: exit after {latency:.2f} s")
    _assert_cancelled_leaving_nothing(proc, err, d)


def test_out_inside_the_input_folder_is_refused(tmp_path):
    dicom = tmp_path / "series"
    dicom.mkdir()
    (dicom / "1.dcm").write_bytes(b"not read: refused before")
    for flag, target in (("--out", dicom / "x.blend"), ("--out", dicom / "sub" / "x.blend"),
                         ("--render", dicom / "x.png")):
        result = _run(tmp_path, "r", dicom, flag, target)
        assert result.returncode == 2, result.stderr
        assert result.stderr.strip().startswith(f"pdehead: error: {flag} ") and "input folder" in result.stderr
        assert "Traceback" not in result.stderr
    assert _files(dicom) == ["1.dcm"]


def _mount_tmpfs(folder: Path, size: str) -> bool:
    if not hasattr(os, "geteuid") or os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    folder.mkdir(parents=True, exist_ok=True)
    return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                          capture_output=True).returncode == 0


@pytest.mark.parametrize("size", ["1m"])
def test_a_full_disk_ends_in_one_error_and_leaves_no_file(tmp_path, size):
    """A tmpfs too small for the .vdb (1 MB: the .vdb does not fit) ends with exit 2 and one
    line naming the file; nothing is left on it."""
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, size):
        pytest.skip("cannot mount a tmpfs here (needs root); the write stubs in tests/io/test_safe_io.py cover it")
    try:
        result = _run(tmp_path, "full", *SMALL[:-1], "2", "--out", disk / "x.blend")
        left = _files(disk)
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)
    assert result.returncode == 2, (result.stdout[-2000:], result.stderr[-2000:])
    errors = [line for line in result.stderr.splitlines() if line.startswith("pdehead: error:")]
    assert len(errors) == 1 and str(disk) in errors[0], result.stderr[-2000:]
    assert "space" in errors[0].lower() or "disk full" in errors[0], errors
    assert "Volume built" not in result.stdout and "wrote" not in result.stdout
    assert "Traceback" not in result.stderr
    assert left == [], left
