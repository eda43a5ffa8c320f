#!/usr/bin/env python3
"""Feed PDE Head the unusual and bad inputs of issue 11 and write the table docs/input_cases.md.

Each case builds its input in a temporary folder (from the phantom, or a few real files read in
place), runs the engine step that must notice it (``load_ct`` and, where the case is about the
head, ``segment_head``) and records the outcome: the error raised, or the warnings issued, or
"ok". Nothing is written outside the temporary folder and docs/input_cases.md.

    python3 scripts/input_cases.py              # writes docs/input_cases.md (about a minute)
    python3 scripts/input_cases.py --print      # print the table only

The tests that assert each outcome are in tests/io/test_input_cases.py (and tests/blender/test_cli.py
for the command line).
"""
from __future__ import annotations

import argparse
import gzip
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from pdehead_addon import CTVolume, PDEHeadError, load_ct, make_phantom, segment_head  # noqa: E402
from pdehead_addon.validation import write_dicom_series  # noqa: E402

OUT = ROOT / "docs" / "input_cases.md"
CASES: list[tuple[str, str, Callable]] = []


def case(number: str, title: str):
    def register(fn):
        CASES.append((number, title, fn))
        return fn
    return register


def _phantom():
    if not hasattr(_phantom, "value"):
        _phantom.value = make_phantom()
    return _phantom.value


def _outside_circle(shape):
    ny, nx = shape[-2:]
    yy, xx = np.mgrid[:ny, :nx]
    return ((yy - (ny - 1) / 2) / ((ny - 1) / 2)) ** 2 + ((xx - (nx - 1) / 2) / ((nx - 1) / 2)) ** 2 > 1.0


def _raw(tmp: Path, data, name="vol.raw", dtype=">i2") -> Path:
    path = tmp / name
    np.ascontiguousarray(data).astype(dtype).tofile(path)
    return path


def _raw_opts(**kw):
    ph = _phantom()
    return dict(format="raw", shape=ph.ct.shape, dtype=">i2", spacing=ph.ct.spacing, **kw)


# ------------------------------------------------------------------------------------ the cases
@case("1", "out-of-field pixels at -3024 HU, no PixelPaddingValue (DICOM)")
def _(tmp):
    ph = _phantom()
    data = ph.ct.data.copy()
    data[np.broadcast_to(_outside_circle(data.shape), data.shape)] = -3024.0
    write_dicom_series(CTVolume(data, ph.ct.spacing, ph.ct.origin), tmp / "dcm", rescale_intercept=-1024.0)
    ct = load_ct(tmp / "dcm")
    seg = segment_head(ct)
    return f"mask {100 * seg.mask.mean():.1f} % of the volume (truth {100 * ph.head_mask.mean():.1f} %)"


@case("1b", "out-of-field -3024 in uncalibrated raw data (histogram + circular field of view)")
def _(tmp):
    data = _phantom().ct.data.copy()
    data[np.broadcast_to(_outside_circle(data.shape), data.shape)] = -3024.0
    load_ct(_raw(tmp, np.rint(data)), **_raw_opts())


@case("2", "a single tilted DICOM slice")
def _(tmp):
    from test_ct_import import write_slice
    t = np.radians(18.5)
    write_slice(tmp / "one.dcm", np.full((64, 64), 1024), (0.0, 0.0, 0.0), (1, 0, 0, 0, np.cos(t), -np.sin(t)))
    load_ct(tmp / "one.dcm")


@case("3", "NaN / inf voxels in a float volume")
def _(tmp):
    data = _phantom().ct.data.copy()
    data.flat[np.random.default_rng(3).choice(data.size, 57, replace=False)] = np.nan
    ct = load_ct(_raw(tmp, data, dtype="<f4"), **dict(_raw_opts(), dtype="<f4"))
    return f"{int(np.isfinite(ct.data).sum())} of {ct.data.size} voxels finite after loading"


@case("3b", "NaN voxels given straight to segment_head")
def _(tmp):
    data = _phantom().ct.data.copy()
    data[5, 5, 5] = np.nan
    segment_head(CTVolume(data, _phantom().ct.spacing))


@case("4", "spacing 10x too large (a head of metres)")
def _(tmp):
    ph = _phantom()
    segment_head(CTVolume(ph.ct.data, tuple(10 * h for h in ph.ct.spacing)))


@case("4b", "spacing 200x too small (a head of millimetres)")
def _(tmp):
    ph = _phantom()
    segment_head(CTVolume(ph.ct.data, tuple(h / 200 for h in ph.ct.spacing)))


@case("4c", "a 16 x 16 test series of 0.5 mm pixels (an 8 mm head)")
def _(tmp):
    segment_head(CTVolume(_phantom().ct.data[:, ::8, ::8], (2.3, 0.5, 0.5)))


@case("4d", "spacing 2x too large (head outside the human range, not absurd)")
def _(tmp):
    ph = _phantom()
    segment_head(CTVolume(ph.ct.data, tuple(2 * h for h in ph.ct.spacing)))


@case("4e", "the phantom itself (must stay valid)")
def _(tmp):
    seg = segment_head(_phantom().ct)
    return "head mask {:.0f} x {:.0f} x {:.0f} mm, no warning".format(*seg.meta["head_extent_mm"])


@case("5", "raw volume stored posterior-first (row 0 = back of the head), no orientation given")
def _(tmp):
    load_ct(_raw(tmp, np.rint(_phantom().ct.data[:, ::-1])), **_raw_opts())


@case("5b", "the same with orientation='LAS'")
def _(tmp):
    ct = load_ct(_raw(tmp, np.rint(_phantom().ct.data[:, ::-1])), **_raw_opts(orientation="LAS"))
    return "equal to the phantom: " + str(bool(np.array_equal(ct.data, np.rint(_phantom().ct.data))))


@case("5c", "sagittal raw slices with orientation='PIL'")
def _(tmp):
    ph = _phantom()
    sag = np.rint(ph.ct.data[::-1].transpose(2, 0, 1))
    (tmp / "sag").mkdir()
    for f, image in enumerate(sag):
        _raw(tmp / "sag", image, f"s{f:03d}.raw")
    dz, dy, dx = ph.ct.spacing
    ct = load_ct(tmp / "sag", format="raw", shape=sag.shape[1:], dtype=">i2", spacing=(dx, dz, dy),
                 orientation="PIL")
    return "equal to the phantom: " + str(bool(np.array_equal(ct.data, np.rint(ph.ct.data))))


@case("5d", "orientation code naming an axis twice ('LLS')")
def _(tmp):
    load_ct(_raw(tmp, np.rint(_phantom().ct.data)), **_raw_opts(orientation="LLS"))


@case("6", "MRI (NIfTI, Colin27 T1)")
def _(tmp):
    from _common import data_path
    load_ct(data_path("mri_colin27_ch2", "ch2.nii.gz"))


@case("6b", "raw data said to be HU (units='HU')")
def _(tmp):
    ct = load_ct(_raw(tmp, np.rint(_phantom().ct.data)), **_raw_opts(units="HU"))
    return f"units = {ct.meta['units']!r}"


@case("6c", "a single axial slice (paper's per-slice mode)")
def _(tmp):
    from test_ct_import import write_slice
    write_slice(tmp / "one.dcm", np.full((64, 64), 1024), (0.0, 0.0, 0.0), thickness=2.0)
    load_ct(tmp / "one.dcm")


@case("6d", "a 3 x 8 x 8 volume")
def _(tmp):
    segment_head(CTVolume(_phantom().ct.data[40:43, ::16, ::16], (2.3, 16.0, 16.0)))


@case("6e", "gzipped raw file (.raw.gz)")
def _(tmp):
    plain = _raw(tmp, np.rint(_phantom().ct.data))
    packed = tmp / "vol.raw.gz"
    packed.write_bytes(gzip.compress(plain.read_bytes(), compresslevel=1))
    ct = load_ct(packed, **_raw_opts())
    return f"read directly, {ct.shape} voxels"


@case("6f", "gzipped raw file with a wrong shape")
def _(tmp):
    plain = _raw(tmp, np.rint(_phantom().ct.data))
    packed = tmp / "vol.raw.gz"
    packed.write_bytes(gzip.compress(plain.read_bytes(), compresslevel=1))
    nz, ny, nx = _phantom().ct.shape
    load_ct(packed, **dict(_raw_opts(), shape=(nz + 1, ny, nx)))


def _series(tmp: Path) -> list[Path]:
    return write_dicom_series(_phantom().ct, tmp / "plain")


@case("C1", "DICOM series re-encoded as JPEG 2000 lossless")
def _(tmp):
    return _compressed(tmp, "JPEG2000Lossless")


@case("C2", "DICOM series re-encoded as RLE lossless")
def _(tmp):
    return _compressed(tmp, "RLELossless")


def _compressed(tmp, name):
    import pydicom
    from pydicom import uid
    files = _series(tmp)
    (tmp / name).mkdir()
    for f in files:
        ds = pydicom.dcmread(f)
        ds.compress(getattr(uid, name))
        ds.save_as(tmp / name / f.name)
    a, b = load_ct(tmp / "plain"), load_ct(tmp / name)
    same = np.array_equal(segment_head(a).mask, segment_head(b).mask)
    return f"{b.meta['transfer_syntax']}: same mask as uncompressed: {same}"


@case("C3", "DICOMDIR file-set (files without extension, read through the DICOMDIR)")
def _(tmp):
    import pydicom
    from pydicom.fileset import FileSet
    fs = FileSet()
    for f in _series(tmp):
        ds = pydicom.dcmread(f)
        ds.StudyDate, ds.StudyTime, ds.StudyID = "20260101", "120000", "1"
        fs.add(ds)
    fs.write(tmp / "cd")
    ct = load_ct(tmp / "cd" / "DICOMDIR")
    return f"{ct.meta['files']} files, {ct.shape} voxels"


@case("M", "dental metal with radial streaks into the air (phantom, metal=True)")
def _(tmp):
    from pdehead_addon.validation import metrics as M
    ph = make_phantom(metal=True)
    seg = segment_head(ph.ct)
    per = M.per_slice_jaccard(seg.mask, ph.head_mask)[ph.params["metal_slices"]]
    return f"per-slice Jaccard in the {per.size} streak slices: min {per.min():.4f}, mean {per.mean():.4f}"


@case("L", "a scan too large for the memory budget (the phantom against a 0.02 GB budget)")
def _(tmp):
    segment_head(_phantom().ct, max_memory_gb=0.02)


def _cli(tmp, *args):
    import os
    import subprocess
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp / "blender-user"))
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "pdehead.py"), *map(str, args)], capture_output=True,
                       text=True, env=env, cwd=tmp)
    lines = [line for line in (r.stdout + r.stderr).splitlines() if "error" in line.lower()]
    return f"exit {r.returncode}; " + (" / ".join(lines) if lines else r.stdout.strip().splitlines()[-1])


@case("7a", "CLI: --patches 0")
def _(tmp):
    return _cli(tmp, "--phantom", "--patches", 0)


@case("7b", "CLI: an empty folder with --out over an existing file")
def _(tmp):
    (tmp / "empty").mkdir()
    (tmp / "kept.blend").write_bytes(b"earlier")
    out = _cli(tmp, tmp / "empty", "--out", tmp / "kept.blend")
    return out + f"; kept.blend unchanged: {(tmp / 'kept.blend').read_bytes() == b'earlier'}"


@case("7c", "CLI: --orientation together with --first-slice")
def _(tmp):
    return _cli(tmp, "--phantom", "--orientation", "LAS", "--first-slice", "superior")


# ------------------------------------------------------------------------------------ issue 18: nothing silently wrong
def _shared(*parts) -> Path:
    from _common import data_path
    return data_path(*parts)


@case("8", "CThead's 8-bit TIFF stack (first file at the top) with no first_slice (Auto)")
def _(tmp):
    ct = load_ct(_shared("cthead_stanford", "tiff8"), spacing=(2, 1, 1))
    return (f"orientation {ct.meta['orientation']}, crown at k = {ct.shape[0] - 1} (the top); information, not a "
            f"warning: {' / '.join(ct.meta.get('info', []))}")


@case("8b", "CThead's big-endian raw slices read as little-endian (dtype='<i2')")
def _(tmp):
    load_ct(_shared("cthead_stanford", "raw16"), format="raw", shape=(256, 256), dtype="<i2", spacing=(2, 1, 1))


@case("8c", "CThead's TIFF stack without spacing (1 mm assumed for its 2 mm step)")
def _(tmp):
    ct = load_ct(_shared("cthead_stanford", "tiff8"))
    return f"crown to widest section {ct.meta['crown']['vertex_to_widest_mm']:.0f} mm"


@case("8d", "a folder of 20 colour photographs (PNG, a coloured block on a landscape)")
def _(tmp):
    import numpy as np
    from PIL import Image
    rng = np.random.default_rng(18)
    (tmp / "photos").mkdir()
    yy, xx = np.mgrid[:240, :320] / np.array([240, 320])[:, None, None]
    for k in range(20):
        sky = np.stack([90 + 80 * yy, 140 + 60 * yy, 230 - 120 * yy], axis=-1)
        ground = np.stack([60 + 40 * xx, 120 + 30 * xx, 40 + 20 * xx], axis=-1)
        img = np.where((yy > 0.55 + 0.1 * np.sin(6 * xx))[..., None], ground, sky) + rng.normal(0, 12, (240, 320, 3))
        img[60:120, 80 + 4 * k:160 + 4 * k] = (220, 40, 30)
        Image.fromarray(np.clip(img, 0, 255).astype(np.uint8)).save(tmp / "photos" / f"IMG_{k + 1:04d}.png")
    load_ct(tmp / "photos")


@case("8e", "CLI: a folder of 20 colour-noise PNGs")
def _(tmp):
    import numpy as np
    from PIL import Image
    (tmp / "photos").mkdir()
    rng = np.random.default_rng(5)
    for k in range(20):
        Image.fromarray(rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)).save(tmp / "photos" / f"p{k}.png")
    return _cli(tmp, tmp / "photos")


# ------------------------------------------------------------------------------------ the table
def run_case(fn) -> tuple[str, str]:
    with tempfile.TemporaryDirectory(prefix="pdehead-case-") as tmp, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            note = fn(Path(tmp))
        except PDEHeadError as exc:
            return "error", _clean(str(exc), tmp)
        messages = [_clean(str(w.message), tmp) for w in caught if issubclass(w.category, UserWarning)]
        note = _clean(note, tmp) if note else ""
    if note.startswith("exit ") and not note.startswith("exit 0"):     # a CLI case that failed as it should
        return "error", note
    if messages:
        return "warning", " / ".join(dict.fromkeys(messages)) + (f" ({note})" if note else "")
    return "ok", note


def _clean(text: str, tmp: str) -> str:
    from _common import SHARED_DATA
    text = text.replace(str(SHARED_DATA.resolve()), "shared/data").replace(str(SHARED_DATA), "shared/data")
    return text.replace(tmp + "/", "").replace(tmp, ".").replace("|", "\\|").replace("\n", " ")


def table() -> str:
    rows = ["| # | case | outcome | message |", "|---|---|---|---|"]
    for number, title, fn in CASES:
        outcome, message = run_case(fn)
        rows.append(f"| {number} | {title} | **{outcome}** | {message} |")
        print(f"{number:>3} {outcome:8} {title}", file=sys.stderr)
    return "\n".join(rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--print", action="store_true", help="print the table instead of writing docs/input_cases.md")
    p.add_argument("--fuzz", type=int, metavar="N", help="instead: run N fuzz cases (scripts/fuzz_inputs.py, seeds "
                   "0, 1, ...) and write their counts per outcome into the fuzz section of docs/input_cases.md")
    args = p.parse_args(argv)
    if args.fuzz:
        return fuzz_campaign(args.fuzz, args.print)
    text = ("# Unusual and bad inputs: cases and outcomes\n\n"
            "Generated by `scripts/input_cases.py` (do not edit by hand). Each case is built from the phantom "
            "(or real files read in place) and fed to `load_ct` / `segment_head`; the outcome is the error "
            "raised, the warnings issued, or ok with a measured note. File names are relative to the "
            "temporary folder of the case. Asserted in `tests/io/test_input_cases.py` (and "
            "`tests/blender/test_cli.py` for the command line; large scans: `scripts/bench/bench_large_scan.py`, "
            "docs/benchmarks.md).\n\n" + table() + "\n")
    if args.print:
        print(text)
    else:
        # the sections after the generated table (## headings, the fuzz campaign's marked one) are kept as they are
        old = OUT.read_text() if OUT.exists() else ""
        starts = [i for i in (old.find("\n## "), old.find("\n" + FUZZ_BEGIN)) if i >= 0]
        OUT.write_text(text + (old[min(starts):] if starts else ""))
        print(f"wrote {OUT}", file=sys.stderr)
    return 0


FUZZ_BEGIN, FUZZ_END = "<!-- fuzz campaign: begin (scripts/input_cases.py --fuzz N) -->", "<!-- fuzz campaign: end -->"


def _fuzz_section() -> str:
    """The fuzz campaign's section of docs/input_cases.md as it is now (kept when the table is rewritten)."""
    old = OUT.read_text() if OUT.exists() else ""
    if FUZZ_BEGIN in old and FUZZ_END in old:
        return "\n" + old[old.index(FUZZ_BEGIN):old.index(FUZZ_END) + len(FUZZ_END)] + "\n"
    return ""


def fuzz_campaign(n: int, print_only: bool) -> int:
    """Run ``n`` cases of scripts/fuzz_inputs.py (seed 0, 1, ... until n) and write the counts per outcome."""
    import platform
    import time

    import fuzz_inputs as fz
    results, seeds, t0 = [], 0, time.perf_counter()
    while len(results) < n:
        with tempfile.TemporaryDirectory(prefix="pdehead-fuzz-") as tmp:
            for c in fz.make_cases(Path(tmp), seed=seeds):
                if len(results) >= n:
                    break
                results.append(fz.run_case(c))
        seeds += 1
    counts = fz.summarize(results)
    sources = sorted({r["source"] for r in results})
    lines = [FUZZ_BEGIN, "## Fuzz campaign", "",
             f"Generated by `scripts/input_cases.py --fuzz {n}` ({len(results)} cases of `scripts/fuzz_inputs.py`, "
             f"seeds 0 to {seeds - 1}, {time.perf_counter() - t0:.0f} s on {platform.machine()}; the quick subset, "
             "seed 0, is `tests/io/test_fuzz_inputs.py`). Allowed: error (a PDEHeadError, one line), warning (a "
             "volume with a warning naming the cause), ok (a mutation a reader cannot see, e.g. a flipped pixel "
             f"byte). Forbidden: any other exception, silent, over {fz.MAX_SECONDS:g} s, a traced peak over 1 GB + "
             "16 x the input's bytes, a multi-line message, a changed input folder.", "",
             "| source | cases | " + " | ".join(fz.ALLOWED + fz.FORBIDDEN) + " | slowest s | largest peak MB |",
             "|---|---" + "|---" * (len(fz.ALLOWED + fz.FORBIDDEN) + 2) + "|"]
    for source in sources + ["all"]:
        rs = [r for r in results if source in ("all", r["source"])]
        c = fz.summarize(rs)
        lines.append(f"| {source} | {len(rs)} | " + " | ".join(str(c[k]) for k in fz.ALLOWED + fz.FORBIDDEN)
                     + f" | {max(r['seconds'] for r in rs):.2f} | {max(r['peak_mb'] for r in rs):.0f} |")
    bad = [r for r in results if r["outcome"] not in fz.ALLOWED]
    lines += ["", "Forbidden outcomes: " + (str(len(bad)) if bad else "none") + ".", FUZZ_END]
    section = "\n".join(lines)
    for r in bad:
        print(f"{r['outcome']}: {r['source']} {r['name']}: {r['message']}", file=sys.stderr)
    if print_only:
        print(section)
    else:
        old = OUT.read_text() if OUT.exists() else ""
        if FUZZ_BEGIN in old and FUZZ_END in old:
            text = old[:old.index(FUZZ_BEGIN)] + section + old[old.index(FUZZ_END) + len(FUZZ_END):]
        else:
            text = old.rstrip("\n") + "\n\n" + section + "\n"
        OUT.write_text(text)
        print(f"wrote the fuzz section of {OUT}: {counts}", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
