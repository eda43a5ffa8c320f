#!/usr/bin/env python3
"""Seeded, bounded mutations of real CT inputs, each run through ``load_ct`` and classified.

The sources are real files read in place and copied (a few of them) into the case's own folder:
the GE DICOM series (``ct_head_ge_tilt_dicom``), CThead's raw slices (``cthead_stanford/raw16``), and a
NIfTI file and a TIFF stack written here from CThead. Every case mutates its copy (truncated files, flipped
bytes in headers and pixel data, absurd header values, duplicated / missing / mixed slices, unreadable
files, symlink loops, memory bombs), loads it, and ends in one outcome:

* ``error``   - a :class:`~pdehead_addon.core.errors.PDEHeadError` with a one-line message (allowed);
* ``warning`` - a volume with at least one warning (allowed);
* ``ok``      - a volume without a warning (allowed only for mutations that may change nothing a reader
  can see, e.g. a flipped pixel byte; for the others it is ``silent``, forbidden);
* forbidden: ``exception`` (any other exception), ``silent``, ``slow`` (more than :data:`MAX_SECONDS`),
  ``memory`` (a traced peak above :data:`MEMORY_BASE` + :data:`MEMORY_PER_INPUT_BYTE` x the input's bytes),
  ``multi-line`` (an error message of more than one line) and ``wrote-input`` (the input folder changed).

Used by ``tests/io/test_fuzz_inputs.py`` (a quick subset) and ``scripts/input_cases.py --fuzz N`` (a long
campaign whose counts go into docs/input_cases.md). Nothing here imports from tests/.
"""
from __future__ import annotations

import gzip
import math
import os
import shutil
import struct
import sys
import time
import tracemalloc
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))
from _common import SHARED_DATA  # noqa: E402

#: Forbidden outcome thresholds (issue 40): one case at most this long ...
MAX_SECONDS = 30.0
#: ... and a traced peak of at most MEMORY_BASE + MEMORY_PER_INPUT_BYTE x the input's bytes.
MEMORY_BASE = 2 ** 30
MEMORY_PER_INPUT_BYTE = 16

ALLOWED = ("error", "warning", "ok")
FORBIDDEN = ("exception", "silent", "slow", "memory", "multi-line", "wrote-input")

GE_DIR = SHARED_DATA / "ct_head_ge_tilt_dicom" / "dicom"
CTHEAD_RAW = SHARED_DATA / "cthead_stanford" / "raw16"
#: Slices of each source copied into a case (small, so that a few hundred cases take a minute or two).
GE_FILES = 6
CTHEAD_SLICES = (40, 56)          # CThead.40 .. CThead.55: through the orbits and the nose


@dataclass
class Case:
    """One mutated input: where it is, how to load it, and whether an unchanged-looking result is allowed."""

    name: str
    source: str
    path: Path                        # what load_ct is given (a folder or a file)
    options: dict = field(default_factory=dict)
    may_pass: bool = False            # the mutation may leave nothing a reader can notice
    cli_args: list = field(default_factory=list)


# ------------------------------------------------------------------------------------------ sources
def _pydicom():
    import pydicom
    from pydicom import config
    config.settings.reading_validation_mode = config.IGNORE
    config.settings.writing_validation_mode = config.IGNORE
    return pydicom


def _copy_ge(folder: Path, n: int = GE_FILES) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for f in sorted(GE_DIR.glob("*.dcm"))[:n]:
        dst = folder / f.name
        shutil.copyfile(f, dst)
        out.append(dst)
    return out


def _copy_cthead(folder: Path) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for k in range(*CTHEAD_SLICES):
        dst = folder / f"CThead.{k}"
        shutil.copyfile(CTHEAD_RAW / f"CThead.{k}", dst)
        out.append(dst)
    return out


def _cthead_volume() -> np.ndarray:
    """CThead slices 40..55 as int16 [z, y, x] (read in place)."""
    return np.stack([np.fromfile(CTHEAD_RAW / f"CThead.{k}", dtype=">i2").reshape(256, 256)
                     for k in range(*CTHEAD_SLICES)]).astype(np.int16)


def write_nifti(path: Path, data: np.ndarray, pixdim=(1.0, 1.0, 2.0), sform=True) -> Path:
    """A single-file NIfTI-1 (int16, little-endian) of ``data`` [z, y, x]; ``.gz`` names are gzipped."""
    nz, ny, nx = data.shape
    hdr = bytearray(352)
    struct.pack_into("<i", hdr, 0, 348)
    struct.pack_into("<8h", hdr, 40, 3, nx, ny, nz, 1, 1, 1, 1)
    struct.pack_into("<h", hdr, 70, 4)                     # int16
    struct.pack_into("<h", hdr, 72, 16)                    # bitpix
    struct.pack_into("<8f", hdr, 76, 1.0, *pixdim, 0, 0, 0, 0)
    struct.pack_into("<f", hdr, 108, 352.0)
    struct.pack_into("<2f", hdr, 112, 1.0, 0.0)
    struct.pack_into("<2h", hdr, 252, 0, 1 if sform else 0)
    # RAS: i -> right-to-left is -x in RAS... keep it simple: i = x, j = -y (rows go posterior), k = z
    struct.pack_into("<4f", hdr, 280, pixdim[0], 0, 0, 0)
    struct.pack_into("<4f", hdr, 296, 0, -pixdim[1], 0, 0)
    struct.pack_into("<4f", hdr, 312, 0, 0, pixdim[2], 0)
    hdr[344:348] = b"n+1\x00"
    body = bytes(hdr) + np.ascontiguousarray(data, dtype="<i2").tobytes()
    if path.name.endswith(".gz"):
        path.write_bytes(gzip.compress(body, compresslevel=1))
    else:
        path.write_bytes(body)
    return path


def write_tiffs(folder: Path, data: np.ndarray, compression=None, dtype=np.uint16) -> list[Path]:
    import tifffile
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    values = (np.clip(data, 0, None).astype(dtype) if dtype != np.uint8
              else (np.clip(data, 0, None) // 16).astype(np.uint8))
    for k, s in enumerate(values):
        f = folder / f"slice{k + 1:03d}.tif"
        tifffile.imwrite(f, s, compression=compression)
        out.append(f)
    return out


# ------------------------------------------------------------------------------------------ mutations
def _flip(path: Path, rng, start: int, stop: int, count: int) -> None:
    data = bytearray(path.read_bytes())
    stop = min(stop, len(data))
    if stop <= start:
        return
    for pos in rng.integers(start, stop, size=count):
        data[pos] ^= 1 << int(rng.integers(0, 8))
    path.write_bytes(bytes(data))


def _truncate(path: Path, fraction: float) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:int(len(data) * fraction)])


def _pixel_offset(path: Path) -> int:
    """Byte offset of the DICOM pixel data's value (the end of the header)."""
    data = path.read_bytes()
    at = data.rfind(b"\xe0\x7f\x10\x00")
    return at + 12 if at >= 0 else len(data) // 2


_DICOM_VALUES = {
    "Rows": ["0", "-1", "1", "65535", "2", "1000000000"],
    "Columns": ["0", "-1", "1", "65535", "3"],
    "NumberOfFrames": ["0", "-1", "1000000000", "2", "nan"],
    "PixelSpacing": ["0\\0", "-0.5\\-0.5", "1e-9\\1e-9", "nan\\nan", "1e9\\1e9", "inf\\1", "0.5"],
    "ImageOrientationPatient": ["0\\0\\0\\0\\0\\0", "1\\0\\0\\1\\0\\0", "nan\\0\\0\\0\\1\\0", "1e9\\0\\0\\0\\1\\0",
                                "1\\0\\0\\0\\1"],
    "ImagePositionPatient": ["0\\0\\0", "nan\\0\\0", "1e9\\1e9\\1e9", "-1e38\\0\\0", "1\\2"],
    "RescaleSlope": ["0", "-1", "nan", "1e9", "1e38", "inf", None],
    "RescaleIntercept": ["1e38", "nan", "-1e9", "inf", None],
    "SliceThickness": ["0", "-1", "nan", "1e9"],
    "BitsAllocated": ["0", "8", "32", "1", "65535"],
    "BitsStored": ["0", "40", "1"],
    "PixelRepresentation": ["2", "1", "0"],
    "SamplesPerPixel": ["0", "3", "65535"],
    "PixelPaddingValue": ["0", "-32768", "65535"],
    "PixelPaddingRangeLimit": ["32767", "-1500", "-32768"],
    "SOPClassUID": ["1.2.3", "", "1.2.840.10008.1.3.10", None],
    "SeriesInstanceUID": ["", None, "9.9.9"],
    "Modality": ["MR", "", None],
    "PhotometricInterpretation": ["RGB", "PALETTE COLOR", ""],
    "TransferSyntaxUID": ["1.2.3.4", "1.2.840.10008.1.2.4.50", "1.2.840.10008.1.2.5", "1.2.840.10008.1.2.2",
                          "1.2.840.10008.1.2"],
}


# values a series may legitimately hold (GE's own, or a consistent relabelling)
_HARMLESS = {("PixelRepresentation", "1"), ("PixelPaddingValue", "-32768"), ("PixelPaddingValue", "0"),
             ("PixelPaddingValue", "65535"), ("PixelPaddingRangeLimit", "-1500"), ("SeriesInstanceUID", "9.9.9"),
             ("SeriesInstanceUID", ""), ("SeriesInstanceUID", None), ("SOPClassUID", "1.2.3"), ("SOPClassUID", ""),
             ("SOPClassUID", None), ("NumberOfFrames", "1"), ("TransferSyntaxUID", "1.2.840.10008.1.2.1"),
             ("TransferSyntaxUID", "1.2.840.10008.1.2"), ("BitsStored", "16"), ("Modality", "MR")}


def _set_tag(path: Path, keyword: str, value) -> None:
    """Set (or delete, value None) one DICOM attribute as a raw string, validation off."""
    pydicom = _pydicom()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = pydicom.dcmread(path, force=True)
        if keyword == "TransferSyntaxUID":
            ds.file_meta.TransferSyntaxUID = value
            # keep the bytes as they are: rewrite the file meta only
            raw = path.read_bytes()
            start = 132
            group_len = struct.unpack("<I", raw[start + 8:start + 12])[0]
            body = raw[start + 12 + group_len:]
            from io import BytesIO
            buf = BytesIO()
            pydicom.filewriter.write_file_meta_info(buf, ds.file_meta, enforce_standard=False)
            path.write_bytes(raw[:132] + buf.getvalue() + body)
            return
        tag = pydicom.datadict.tag_for_keyword(keyword)
        if value is None:
            if keyword in ds:
                del ds[keyword]
        else:
            vr = pydicom.datadict.dictionary_VR(tag)
            if vr in ("US", "SS", "UL", "SL", "US or SS"):
                # integers: write the bytes directly so that out-of-range values stay as they are
                v = float(value)
                num = int(v) if math.isfinite(v) else 0
                fmt = {"US": "<H", "SS": "<h", "UL": "<I", "SL": "<i"}.get(vr, "<H")
                lo, hi = {"<H": (0, 65535), "<h": (-32768, 32767), "<I": (0, 2 ** 32 - 1),
                          "<i": (-2 ** 31, 2 ** 31 - 1)}[fmt]
                num = num % (hi + 1) if fmt in ("<H", "<I") else min(max(num, lo), hi)
                vr = "US" if vr == "US or SS" else vr
                ds[tag] = pydicom.dataelem.RawDataElement(tag, vr, struct.calcsize(fmt), struct.pack(fmt, num),
                                                          0, False, True)
            else:
                raw = str(value).encode("ascii")
                if len(raw) % 2:
                    raw += b" "
                ds[tag] = pydicom.dataelem.RawDataElement(tag, vr, len(raw), raw, 0, False, True)
        ds.save_as(path, enforce_file_format=False)


def _rewrite(path: Path, fn: Callable) -> None:
    pydicom = _pydicom()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = pydicom.dcmread(path, force=True)
        fn(ds)
        ds.save_as(path, enforce_file_format=False)


def _header_value_cases(new, pick) -> None:
    """Absurd header values, in one file and in every file (``new``/``pick`` of :func:`dicom_cases`)."""
    for keyword, values in _DICOM_VALUES.items():
        for value in values:
            for where in ("one", "all"):
                if where == "all" and keyword in ("SOPClassUID",) and value is None:
                    continue
                _folder, files, c = new(f"{keyword}={value!r} in {where} file(s)")
                targets = [pick(files)] if where == "one" else files
                for f in targets:
                    _set_tag(f, keyword, value)
                # a few values are legitimate (ExplicitVRLittleEndian as 1.2.840.10008.1.2 implicit is
                # a lie; PixelRepresentation 1 is what GE has)
                c.may_pass = (keyword, value) in _HARMLESS


def dicom_cases(rng, root: Path) -> list[Case]:
    """Mutations of a copy of GE_FILES GE slices (one folder per case)."""
    cases: list[Case] = []
    counter = [0]

    def new(name: str, may_pass=False) -> tuple[Path, list[Path], Case]:
        counter[0] += 1
        folder = root / f"dcm{counter[0]:03d}"
        files = _copy_ge(folder)
        c = Case(name, "GE DICOM", folder, {}, may_pass)
        cases.append(c)
        return folder, files, c

    def pick(files):
        return files[int(rng.integers(len(files)))]
    _header_value_cases(new, pick)
    # truncated files
    for fraction in (0.0, 0.01, 0.05, 0.2, 0.5, 0.99):
        folder, files, c = new(f"one file truncated to {fraction:.0%}")
        _truncate(pick(files), fraction)
    folder, files, c = new("every file truncated to 60%")
    for f in files:
        _truncate(f, 0.6)
    # flipped bytes in the header and in the pixel data
    for count in (1, 4, 32):
        for _ in range(3):
            folder, files, c = new(f"{count} byte(s) flipped in one header", may_pass=True)
            f = pick(files)
            _flip(f, rng, 128, _pixel_offset(f), count)
    for count in (1, 64):
        folder, files, c = new(f"{count} byte(s) flipped in one file's pixel data", may_pass=True)
        f = pick(files)
        _flip(f, rng, _pixel_offset(f), f.stat().st_size, count)
    # geometry: one slice at the origin, position drift, duplicated / missing / mixed slices
    folder, files, c = new("one ImagePositionPatient set to (0, 0, 0)")
    _set_tag(files[2], "ImagePositionPatient", "0\\0\\0")
    folder, files, c = new("300 mm per slice of in-plane position drift")
    for k, f in enumerate(files):
        _rewrite(f, lambda ds, k=k: setattr(ds, "ImagePositionPatient",
                                            [float(ds.ImagePositionPatient[0]) + 300.0 * k,
                                             *map(float, ds.ImagePositionPatient[1:])]))
    folder, files, c = new("a file duplicated under another name")
    shutil.copyfile(files[1], folder / "copy.dcm")
    folder, files, c = new("a slice duplicated with a new SOPInstanceUID")
    shutil.copyfile(files[1], folder / "copy.dcm")
    _set_tag(folder / "copy.dcm", "SOPInstanceUID", "1.2.3.4.5.6.7")
    folder, files, c = new("a middle slice missing", may_pass=True)
    files[len(files) // 2].unlink()
    folder, files, c = new("a CThead raw slice dropped into the series", may_pass=True)
    shutil.copyfile(CTHEAD_RAW / "CThead.50", folder / "CThead.50")
    folder, files, c = new("one slice 256 x 256 (mixed sizes)")

    def shrink(ds):
        arr = ds.pixel_array[::2, ::2].copy()
        ds.Rows, ds.Columns = arr.shape
        ds.PixelData = arr.tobytes()
    _rewrite(files[3], shrink)
    folder, files, c = new("every file 65535 x 65535")
    for f in files:
        _set_tag(f, "Rows", "65535")
        _set_tag(f, "Columns", "65535")
    # unreadable files, symlinks
    folder, files, c = new("one file chmod 000", may_pass=True)     # root reads it anyway
    os.chmod(pick(files), 0)
    folder, files, c = new("a dangling symlink among the slices", may_pass=True)
    os.symlink(folder / "nowhere.dcm", folder / "dangling.dcm")
    folder, files, c = new("a symlink loop (a folder linking to itself)", may_pass=True)
    os.symlink(folder, folder / "loop")
    folder, files, c = new("an empty file among the slices")
    (folder / "empty.dcm").write_bytes(b"")
    folder, files, c = new("a DICOMDIR entry pointing outside the folder")
    _write_dicomdir(folder, [("..", "..", "..", "..", "etc", "passwd")] + [(f.name,) for f in files])
    # a single file given directly
    folder, files, c = new("one truncated file given alone")
    _truncate(files[0], 0.3)
    c.path = files[0]
    return cases


def _write_dicomdir(folder: Path, refs) -> None:
    pydicom = _pydicom()
    from pydicom.dataset import Dataset, FileMetaDataset
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = "1.2.840.10008.1.3.10"
    meta.MediaStorageSOPInstanceUID = pydicom.uid.generate_uid()
    meta.TransferSyntaxUID = pydicom.uid.ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.FileSetID = "FUZZ"
    records = []
    for ref in refs:
        r = Dataset()
        r.DirectoryRecordType = "IMAGE"
        r.ReferencedFileID = list(ref)
        records.append(r)
    ds.DirectoryRecordSequence = records
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds.save_as(folder / "DICOMDIR", enforce_file_format=True)


RAW_OPTIONS = dict(format="raw", shape=(256, 256), dtype=">i2", spacing=(2.0, 1.0, 1.0), first_slice="superior")


def raw_cases(rng, root: Path) -> list[Case]:
    cases: list[Case] = []
    counter = [0]

    def new(name: str, may_pass=False, **options) -> tuple[Path, list[Path], Case]:
        counter[0] += 1
        folder = root / f"raw{counter[0]:03d}"
        files = _copy_cthead(folder)
        c = Case(name, "CThead raw", folder, dict(RAW_OPTIONS, **options), may_pass)
        cases.append(c)
        return folder, files, c

    def pick(files):
        return files[int(rng.integers(len(files)))]
    for fraction in (0.0, 0.5, 0.999):
        folder, files, c = new(f"one slice truncated to {fraction:.1%}")
        _truncate(pick(files), fraction)
    folder, files, c = new("one slice with 2 extra bytes")
    f = pick(files)
    f.write_bytes(f.read_bytes() + b"\0\0")
    for count in (1, 100):
        folder, files, c = new(f"{count} byte(s) flipped in one slice", may_pass=True)
        f = pick(files)
        _flip(f, rng, 0, f.stat().st_size, count)
    for shape in ((128, 512), (512, 128), (128, 256), (1, 65536), (65535, 65535), (0, 0), (-1, 256)):
        for dtype in (">i2", "<f4", "u1", "<f8"):
            # the same bytes in rows of another length read as valid samples: refusing them (rows that do not
            # join up) is the raw-shape check's job, not a reader's
            same_bytes = dtype == ">i2" and len(shape) == 2 and shape[0] * shape[1] == 65536 and min(shape) > 0
            new(f"shape {shape} dtype {dtype}", may_pass=same_bytes, shape=shape, dtype=dtype)
    for header in (-1, 1, 131072, 10 ** 9):
        new(f"header_bytes={header}", header_bytes=header)
    for spacing in ((0, 1, 1), (-2, 1, 1), (float("nan"), 1, 1), (1e9, 1e9, 1e9), (1e-9, 1e-9, 1e-9)):
        new(f"spacing={spacing}", spacing=spacing)
    folder, files, c = new("a middle slice missing", may_pass=True)
    files[len(files) // 2].unlink()
    folder, files, c = new("a slice duplicated", may_pass=True)
    shutil.copyfile(files[3], folder / "CThead.45b")
    folder, files, c = new("a text file among the slices")
    (folder / "notes.txt").write_text("scanned on a Tuesday\n")
    folder, files, c = new("a symlink loop in the folder", may_pass=True)
    os.symlink(folder, folder / "loop")
    # the whole volume as one gzipped file, and gzip bombs
    folder, files, c = new("gzipped volume, corrupt deflate stream", shape=(16, 256, 256))
    vol = b"".join(f.read_bytes() for f in files)
    for f in files:
        f.unlink()
    blob = bytearray(gzip.compress(vol, compresslevel=1))
    for pos in rng.integers(20, len(blob) - 10, size=8):
        blob[pos] ^= 0xFF
    (folder / "vol.raw.gz").write_bytes(bytes(blob))
    c.path = folder / "vol.raw.gz"
    folder, files, c = new("gzipped raw bomb (200 MB of zeros behind a 16-slice shape)", shape=(16, 256, 256))
    for f in files:
        f.unlink()
    _gzip_zeros(folder / "bomb.raw.gz", 200 * 2 ** 20)
    c.path = folder / "bomb.raw.gz"
    folder, files, c = new("gzipped raw bomb with a 2-D shape (any slice count)")
    for f in files:
        f.unlink()
    _gzip_zeros(folder / "bomb.raw.gz", 200 * 2 ** 20)
    c.path = folder / "bomb.raw.gz"
    return cases


def _gzip_zeros(path: Path, size: int) -> None:
    chunk = bytes(2 ** 20)
    with gzip.open(path, "wb", compresslevel=1) as fh:
        for _ in range(size // len(chunk)):
            fh.write(chunk)


def _nifti_field(path: Path, offset: int, fmt: str, *values) -> None:
    raw = bytearray(gzip.decompress(path.read_bytes()) if path.name.endswith(".gz") else path.read_bytes())
    struct.pack_into(fmt, raw, offset, *values)
    path.write_bytes(gzip.compress(bytes(raw), compresslevel=1) if path.name.endswith(".gz") else bytes(raw))


_NIFTI_FIELDS = {
    "dim": (
        40,
        "<8h",
        [
            (3, 0, 256, 16, 1, 1, 1, 1),
            (3, -256, -256, 16, 1, 1, 1, 1),
            (3, 32767, 32767, 32767, 1, 1, 1, 1),
            (0, 256, 256, 16, 1, 1, 1, 1),
            (9, 256, 256, 16, 1, 1, 1, 1),
            (4, 256, 256, 16, 30000, 1, 1, 1),
            (3, 256, 256, 17, 1, 1, 1, 1),
        ],
    ),
    "datatype": (70, "<h", [(0,), (1,), (128,), (2,), (16,), (-5,)]),
    "pixdim": (
        76,
        "<8f",
        [
            (1, float("nan"), 1, 2, 0, 0, 0, 0),
            (1, -1, -1, -2, 0, 0, 0, 0),
            (1, 0, 0, 0, 0, 0, 0, 0),
            (1, 1e9, 1e9, 1e9, 0, 0, 0, 0),
            (1, 1e-9, 1e-9, 1e-9, 0, 0, 0, 0),
            (1, float("inf"), 1, 1, 0, 0, 0, 0),
        ],
    ),
    "vox_offset": (108, "<f", [(0.0,), (-1.0,), (float("nan"),), (float("inf"),), (1e9,), (351.0,), (353.5,)]),
    "scl": (112, "<2f", [(float("nan"), 0), (float("inf"), 0), (1e38, 0), (1, 1e38), (-1, 0), (0, 5)]),
    "srow_x": (
        280,
        "<4f",
        [(float("nan"), 0, 0, 0), (float("inf"), 0, 0, 0), (0, 0, 0, 0), (1, 1, 0, 0), (1e-9, 0, 0, 0), (1e9, 0, 0, 0)],
    ),
    "srow_z": (312, "<4f", [(0, 0.5, 2, 0), (0, 0, float("nan"), 0), (0, 0, -2, 0)]),
    "sform_code": (252, "<2h", [(0, 0), (1, 0), (-1, -1)]),
    "sizeof_hdr": (0, "<i", [(0,), (347,)]),
}


def nifti_cases(rng, root: Path) -> list[Case]:
    cases: list[Case] = []
    vol = _cthead_volume()
    counter = [0]

    def new(name: str, gz: bool, may_pass=False, sform=True) -> tuple[Path, Case]:
        counter[0] += 1
        folder = root / f"nii{counter[0]:03d}"
        folder.mkdir(parents=True)
        path = write_nifti(folder / ("ct.nii.gz" if gz else "ct.nii"), vol, sform=sform)
        c = Case(name, "NIfTI", path, {"units": "HU"} if False else {}, may_pass)
        cases.append(c)
        return path, c

    for field_name, (offset, fmt, values) in _NIFTI_FIELDS.items():
        for value in values:
            gz = bool(rng.integers(2))
            sform = field_name not in ("pixdim",)
            path, c = new(f"{field_name}={value}{' (.gz)' if gz else ''}", gz, sform=sform)
            _nifti_field(path, offset, fmt, *value)
    for fraction in (0.1, 0.5, 0.99):
        for gz in (False, True):
            path, c = new(f"truncated to {fraction:.0%}{' (.gz)' if gz else ''}", gz)
            _truncate(path, fraction)
    for count in (1, 16):
        path, c = new(f"{count} byte(s) flipped in the gzip stream", True)
        _flip(path, rng, 20, path.stat().st_size - 8, count)
        path, c = new(f"{count} byte(s) flipped in the header", False, may_pass=True)
        _flip(path, rng, 0, 348, count)
        path, c = new(f"{count} byte(s) flipped in the voxels", False, may_pass=True)
        _flip(path, rng, 352, path.stat().st_size, count)
    # a gzip bomb: a valid small header whose stream goes on with 300 MB of zeros
    path, c = new("gzip bomb: 300 MB of zeros after the voxels (.gz)", True)
    raw = gzip.decompress(path.read_bytes())
    with gzip.open(path, "wb", compresslevel=1) as fh:
        fh.write(raw)
        chunk = bytes(2 ** 20)
        for _ in range(300):
            fh.write(chunk)
    path, c = new("gzip bomb: dims 2048 x 2048 x 1024 over zeros (.gz)", True)
    hdr = bytearray(gzip.decompress(path.read_bytes())[:352])
    struct.pack_into("<8h", hdr, 40, 3, 2048, 2048, 1024, 1, 1, 1, 1)
    with gzip.open(path, "wb", compresslevel=1) as fh:
        fh.write(bytes(hdr))
        chunk = bytes(2 ** 20)
        for _ in range(200):
            fh.write(chunk)
    return cases


def tiff_cases(rng, root: Path) -> list[Case]:
    import tifffile
    cases: list[Case] = []
    vol = _cthead_volume()
    counter = [0]
    options = dict(spacing=(2.0, 1.0, 1.0), first_slice="superior")

    def new(name: str, may_pass=False, compression=None, dtype=np.uint16) -> tuple[Path, list[Path], Case]:
        counter[0] += 1
        folder = root / f"tif{counter[0]:03d}"
        files = write_tiffs(folder, vol, compression=compression, dtype=dtype)
        c = Case(name, "TIFF stack", folder, dict(options), may_pass)
        cases.append(c)
        return folder, files, c

    def pick(files):
        return files[int(rng.integers(len(files)))]
    for compression in (None, "zlib"):
        tag = f" ({compression})" if compression else ""
        for fraction in (0.0, 0.05, 0.5, 0.99):
            folder, files, c = new(f"one file truncated to {fraction:.0%}{tag}", compression=compression)
            _truncate(pick(files), fraction)
        for count in (1, 8, 64):
            folder, files, c = new(f"{count} byte(s) flipped in one file{tag}", may_pass=True, compression=compression)
            f = pick(files)
            _flip(f, rng, 0, min(f.stat().st_size, 512) if count > 1 else f.stat().st_size, count)
        folder, files, c = new(f"one slice 8-bit among 16-bit ones (mixed sample types){tag}",
                               compression=compression)
        f = pick(files)
        tifffile.imwrite(f, (vol[0] // 16).clip(0, 255).astype(np.uint8), compression=compression)
        folder, files, c = new(f"one slice 128 x 128 (mixed sizes){tag}", compression=compression)
        tifffile.imwrite(pick(files), vol[0, ::2, ::2].clip(0).astype(np.uint16), compression=compression)
        folder, files, c = new(f"one RGB slice{tag}", compression=compression)
        tifffile.imwrite(pick(files), np.repeat(vol[0, :, :, None].clip(0).astype(np.uint16), 3, axis=2),
                         compression=compression)
        folder, files, c = new(f"a garbage .tif among the slices{tag}", compression=compression)
        (folder / "slice999.tif").write_bytes(rng.bytes(4096))
        folder, files, c = new(f"65535 x 65535 in one file's tags{tag}", compression=compression)
        _tiff_dims(pick(files), 65535, 65535)
        folder, files, c = new(f"65535 x 65535 in every file's tags{tag}", compression=compression)
        for f in files:
            _tiff_dims(f, 65535, 65535)
    folder, files, c = new("zlib bomb: one 16000 x 16000 slice of zeros", compression="zlib")
    tifffile.imwrite(files[0], np.zeros((16000, 16000), np.uint8), compression="zlib")
    folder, files, c = new("a symlink loop in the folder", may_pass=True)
    os.symlink(folder, folder / "loop")
    folder, files, c = new("all slices 8-bit", may_pass=True, dtype=np.uint8)
    return cases


def _tiff_dims(path: Path, width: int, height: int) -> None:
    """Rewrite ImageWidth (256) and ImageLength (257) in the first IFD (little-endian classic TIFF)."""
    raw = bytearray(path.read_bytes())
    if raw[:4] != b"II*\x00":
        return
    ifd = struct.unpack_from("<I", raw, 4)[0]
    n = struct.unpack_from("<H", raw, ifd)[0]
    for k in range(n):
        at = ifd + 2 + 12 * k
        tag, typ = struct.unpack_from("<HH", raw, at)
        if tag in (256, 257):
            value = width if tag == 256 else height
            if typ == 3:
                struct.pack_into("<H", raw, at + 8, value)
            elif typ == 4:
                struct.pack_into("<I", raw, at + 8, value)
    path.write_bytes(bytes(raw))


SOURCES = {"dicom": dicom_cases, "raw": raw_cases, "nifti": nifti_cases, "tiff": tiff_cases}


def make_cases(root: Path, seed: int = 0, sources=tuple(SOURCES)) -> list[Case]:
    """Every mutation of every source, built under ``root`` with one seeded generator per source."""
    cases = []
    for k, name in enumerate(sources):
        rng = np.random.default_rng([seed, k])
        cases.extend(SOURCES[name](rng, root / name))
    return cases


# ------------------------------------------------------------------------------------------ running
def _snapshot(path: Path) -> dict:
    folder = path if path.is_dir() else path.parent
    out = {}
    for dirpath, _dirnames, filenames in os.walk(folder):
        for name in filenames:
            p = os.path.join(dirpath, name)
            try:
                st = os.lstat(p)
            except OSError:
                continue
            out[p] = (st.st_size, st.st_mtime_ns)
    return out


def input_bytes(path: Path) -> int:
    folder = path if path.is_dir() else path.parent
    total = 0
    for dirpath, _dirnames, filenames in os.walk(folder):
        for name in filenames:
            try:
                total += os.lstat(os.path.join(dirpath, name)).st_size
            except OSError:
                pass
    return total


def run_case(case: Case) -> dict:
    """Load the case with ``load_ct`` and classify the outcome (see the module docstring)."""
    from pdehead_addon import PDEHeadError, load_ct
    before = _snapshot(case.path)
    size = input_bytes(case.path)
    tracemalloc.start()
    t0 = time.perf_counter()
    outcome, message, warns = None, "", []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ct = load_ct(case.path, **case.options)
            warns = [str(w.message) for w in caught]
            del ct
        outcome = "warning" if warns else ("ok" if case.may_pass else "silent")
        message = warns[0] if warns else ""
    except PDEHeadError as exc:
        message = str(exc)
        outcome = "error" if "\n" not in message.strip() else "multi-line"
    except Exception as exc:  # noqa: BLE001 - the outcome being classified
        import traceback
        outcome, message = "exception", f"{type(exc).__name__}: {exc} @ " + " <- ".join(
            f"{Path(fr.filename).name}:{fr.lineno}" for fr in traceback.extract_tb(exc.__traceback__)[::-1][:4])
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    limit = MEMORY_BASE + MEMORY_PER_INPUT_BYTE * size
    if outcome in ALLOWED:
        if _snapshot(case.path) != before:
            outcome = "wrote-input"
        elif seconds > MAX_SECONDS:
            outcome = "slow"
        elif peak > limit:
            outcome = "memory"
    return dict(name=case.name, source=case.source, outcome=outcome, message=message.replace("\n", " | ")[:400],
                seconds=round(seconds, 3), peak_mb=round(peak / 2 ** 20, 1), limit_mb=round(limit / 2 ** 20),
                warnings=len(warns))


def cli_command(case: Case) -> list[str]:
    """The command line of ``scripts/pdehead.py`` that loads the case as ``load_ct(case.path, **options)``."""
    args = [sys.executable, str(ROOT / "scripts" / "pdehead.py"), str(case.path), "--no-volume"]
    o = case.options
    if o.get("format") == "raw":
        args += ["--format", "raw", "--raw-shape", *map(str, o["shape"][-2:]), "--dtype", str(o["dtype"])]
    if "spacing" in o:
        args += ["--spacing", *map(str, o["spacing"])]
    if "first_slice" in o:
        args += ["--first-slice", o["first_slice"]]
    return args


def summarize(results: list[dict]) -> dict:
    counts = {k: 0 for k in ALLOWED + FORBIDDEN}
    for r in results:
        counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
    return counts


if __name__ == "__main__":          # a quick look: python scripts/fuzz_inputs.py [seed] [source ...]
    import tempfile
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 0
    sources = sys.argv[2:] or tuple(SOURCES)
    with tempfile.TemporaryDirectory(prefix="pdehead-fuzz-") as tmp:
        t0 = time.perf_counter()
        cases = make_cases(Path(tmp), seed, sources)
        print(f"{len(cases)} cases built in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        results = []
        for c in cases:
            r = run_case(c)
            results.append(r)
            if r["outcome"] not in ALLOWED or "-v" in os.environ.get("FUZZ_VERBOSE", ""):
                print(f"{r['outcome']:10s} {r['source']:10s} {r['name']}: {r['message']} "
                      f"({r['seconds']} s, {r['peak_mb']} MB)")
        print(summarize(results), f"{time.perf_counter() - t0:.1f} s", file=sys.stderr)
