"""Issue 40's fuzz suite: seeded, bounded mutations of real inputs through ``load_ct`` and the CLI.

The cases are ``scripts/fuzz_inputs.py``'s (the GE DICOM series and CThead's raw slices copied, a NIfTI
and a TIFF stack written from CThead; truncated files, flipped bytes, absurd header values, duplicated /
missing / mixed slices, unreadable files, symlink loops, memory bombs). Every case must end in a
``PDEHeadError`` with one line, or a volume with a warning (or, for mutations a reader cannot see such as
a flipped pixel byte, a plain volume); never another exception, nothing silent, a traced peak within
1 GB + 16 x the input's bytes, nothing written into the input folder. The long campaign is
``scripts/input_cases.py --fuzz N`` (counts in docs/input_cases.md).
"""
from __future__ import annotations

import builtins
import subprocess
import sys
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from datasets import shared_data

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
import fuzz_inputs  # noqa: E402
from pdehead_addon import load_ct  # noqa: E402


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    shared_data("ct_head_ge_tilt_dicom", "dicom")
    shared_data("cthead_stanford", "raw16")
    root = tmp_path_factory.mktemp("fuzz")
    cases = fuzz_inputs.make_cases(root, seed=0)
    results = [fuzz_inputs.run_case(c) for c in cases]
    return cases, results


def _by_name(results, source, name):
    hits = [r for r in results if r["source"] == source and r["name"] in (name, name + " (.gz)")]
    assert len(hits) == 1, (source, name, len(hits))
    return hits[0]


def test_every_case_ends_in_an_allowed_outcome(campaign):
    cases, results = campaign
    counts = fuzz_inputs.summarize(results)
    bad = [f"{r['outcome']}: {r['source']} {r['name']}: {r['message']} ({r['seconds']} s, {r['peak_mb']} MB)"
           for r in results if r["outcome"] not in fuzz_inputs.ALLOWED]
    assert not bad, "\n".join(bad)
    assert len(results) >= 300, counts
    # the mutations are noticed: most cases are refused or warned about, few pass unseen
    assert counts["error"] >= 150 and counts["warning"] >= 80, counts
    assert counts["ok"] <= 0.15 * len(results), counts
    for source in ("GE DICOM", "CThead raw", "NIfTI", "TIFF stack"):
        assert sum(r["source"] == source for r in results) >= 20, source
    # bounded: the peak of every case within 1 GB + 16 x its input (the bombs included)
    assert max(r["peak_mb"] - r["limit_mb"] for r in results) < 0


@pytest.mark.parametrize("source, name, outcome, words", [
    # campaign findings that used to raise another exception
    ("GE DICOM", "TransferSyntaxUID='1.2.3.4' in all file(s)", "error", "unknown TransferSyntaxUID '1.2.3.4'"),
    ("GE DICOM", "Rows='-1' in all file(s)", "error", "the header's 65535 x 512"),
    ("GE DICOM", "ImageOrientationPatient='0\\\\0\\\\0\\\\0\\\\0\\\\0' in all file(s)", "error",
     "ImageOrientationPatient missing or invalid"),
    ("GE DICOM", "PixelSpacing='1e-9\\\\1e-9' in all file(s)", "error", "PixelSpacing missing or invalid"),
    ("GE DICOM", "PixelSpacing='0\\\\0' in one file(s)", "warning", "PixelSpacing [0.0, 0.0] mm is outside"),
    ("NIfTI", "vox_offset=(-1.0,)", "error", "vox_offset is -1.0"),
    ("NIfTI", "dim=(3, -256, -256, 16, 1, 1, 1, 1)", "error", "every one must be at least 1"),
    ("CThead raw", "shape (128, 256) dtype <f4", "error", "not CT values"),
    # memory bombs and hangs: refused from the header, before allocating
    ("GE DICOM", "every file 65535 x 65535", "error", "more than the import budget"),
    ("GE DICOM", "NumberOfFrames='1000000000' in all file(s)", "error", "more than the import budget"),
    ("GE DICOM", "300 mm per slice of in-plane position drift", "error", "no gantry tilts more than 45 deg"),
    ("NIfTI", "gzip bomb: dims 2048 x 2048 x 1024 over zeros (.gz)", "error", "more than the import budget"),
    ("NIfTI", "gzip bomb: 300 MB of zeros after the voxels (.gz)", "error", "decompression bomb"),
    ("CThead raw", "gzipped raw bomb with a 2-D shape (any slice count)", "error", "decompression bomb"),
    ("TIFF stack", "zlib bomb: one 16000 x 16000 slice of zeros", "error", "decompression bomb"),
    ("TIFF stack", "65535 x 65535 in every file's tags (zlib)", "error", "more than the import budget"),
    # silently wrong before
    ("GE DICOM", "Rows='1' in all file(s)", "error", "the header's 1 x 512"),
    ("GE DICOM", "PixelPaddingRangeLimit='32767' in all file(s)", "error", "mark 100 % of the pixels as padding"),
    ("GE DICOM", "NumberOfFrames='-1' in one file(s)", "warning", "NumberOfFrames is -1"),
    ("GE DICOM", "SOPClassUID='1.2.840.10008.1.3.10' in one file(s)", "warning", "says DICOMDIR"),
    ("GE DICOM", "one ImagePositionPatient set to (0, 0, 0)", "error", "drift"),
    ("GE DICOM", "RescaleIntercept='1e38' in one file(s)", "warning", "RescaleIntercept 1e+38"),
    ("GE DICOM", "RescaleSlope=None in one file(s)", "warning", "RescaleSlope missing (taken as 1)"),
    ("GE DICOM", "a DICOMDIR entry pointing outside the folder", "warning", "outside its folder, not opened"),
    ("NIfTI", "pixdim=(1, -1, -1, -2, 0, 0, 0, 0)", "warning", "has zero or negative entries"),
    ("NIfTI", "vox_offset=(0.0,)", "error", "at least 352"),
    ("NIfTI", "srow_x=(1, 1, 0, 0)", "error", "shears the slices"),
    ("NIfTI", "srow_x=(nan, 0, 0, 0)", "error", "NaN or infinite"),
    ("TIFF stack", "one slice 8-bit among 16-bit ones (mixed sample types)", "error", "mixed sample types"),
])
def test_campaign_findings(campaign, source, name, outcome, words):
    _, results = campaign
    r = _by_name(results, source, name)
    assert r["outcome"] == outcome and words in r["message"], r


def test_an_unreadable_file_is_called_unreadable_not_non_dicom(tmp_path, monkeypatch):
    """chmod 000 cannot stop root (the test user here), so the refusal to open is simulated."""
    files = fuzz_inputs._copy_ge(tmp_path / "dcm", 5)
    locked = files[2]
    real_open = builtins.open

    def guarded(path, *args, **kwargs):
        if str(path) == str(locked):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", guarded)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ct = load_ct(tmp_path / "dcm")
    messages = [str(w.message) for w in caught]
    assert ct.meta["original_slice_count"] == 4
    assert any(locked.name in m and "cannot open it: Permission denied" in m for m in messages), messages
    assert not any("non-DICOM" in m for m in messages), messages


def test_dicomdir_never_opens_a_file_outside_its_folder(tmp_path, monkeypatch):
    outside = tmp_path / "secret.dcm"
    fuzz_inputs._copy_ge(tmp_path / "tmp", 1)[0].rename(outside)
    files = fuzz_inputs._copy_ge(tmp_path / "set" / "inner", 4)
    fuzz_inputs._write_dicomdir(tmp_path / "set" / "inner", [("..", "..", "secret.dcm")] + [(f.name,) for f in files])
    opened = []
    real_open = builtins.open
    monkeypatch.setattr(builtins, "open", lambda p, *a, **k: (opened.append(str(p)), real_open(p, *a, **k))[1])
    ct = load_ct(tmp_path / "set" / "inner" / "DICOMDIR")
    assert ct.meta["original_slice_count"] == 4
    assert not any("secret" in p for p in opened), opened
    assert any("outside its folder" in w and "../../secret.dcm" in w for w in ct.meta["warnings"])


def _cli_cases(cases, results, count=20):
    """``count`` refused cases the CLI can express, spread over the sources (deterministic)."""
    chosen, per_source = [], {}
    for case, r in zip(cases, results):
        o = case.options
        if r["outcome"] != "error" or set(o) - {"format", "shape", "dtype", "spacing", "first_slice"}:
            continue
        if "shape" in o and (len(o["shape"]) != 2 or min(o["shape"]) <= 0):
            continue
        if per_source.get(case.source, 0) >= count // 4:
            continue
        per_source[case.source] = per_source.get(case.source, 0) + 1
        chosen.append((case, r))
    return chosen[:count]


def test_twenty_refused_cases_through_the_cli(campaign):
    """The same inputs on the command line: exit 2 and one error line naming the problem, no traceback."""
    cases, results = campaign
    chosen = _cli_cases(cases, results)
    assert len(chosen) == 20, len(chosen)

    def run(item):
        case, r = item
        return case, r, subprocess.run(fuzz_inputs.cli_command(case), capture_output=True, text=True, timeout=300,
                                       cwd=ROOT)

    with ThreadPoolExecutor(max_workers=2) as pool:
        runs = list(pool.map(run, chosen))
    for case, r, proc in runs:
        lines = [line for line in proc.stderr.splitlines() if line.strip()]
        assert proc.returncode == 2, (case.name, proc.returncode, proc.stderr[-2000:])
        assert "Traceback" not in proc.stderr, (case.name, proc.stderr[-2000:])
        errors = [line for line in lines if line.startswith("pdehead: error:")]
        assert len(errors) == 1, (case.name, lines)
        problem = r["message"].split(": ", 1)[-1][:60]
        assert problem in errors[0], (case.name, problem, errors[0])


def test_cli_refuses_a_zero_raw_shape_in_one_line():
    """``--raw-shape 0 0`` was clamped to 1 x 1 by the operator's property and reported as such."""
    raw16 = shared_data("cthead_stanford", "raw16")
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "pdehead.py"), str(raw16), "--raw-shape", "0", "0",
                           "--dtype", ">i2", "--spacing", "2", "1", "1", "--no-volume"],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 2 and lines == ["pdehead: error: --raw-shape must be two positive numbers of pixels "
                                              "(rows, columns), got 0 0"], proc.stderr
