"""Step 1: CT import (DICOM series, numbered 2-D image stacks, headerless raw, NIfTI) into a CTVolume.

The paper (Fig. 1) starts from "a sequence of head cross-sectional slices". This
module turns whatever the slices are stored as into one :class:`CTVolume` in
patient LPS millimetres with a fixed axis convention, so that every later step
(segmentation eq. 16-21, boundary extraction eq. 22, the PDE patches eq. 1-13)
can treat ``data[k]`` as an axial slice at height ``origin[2] + k*dz``:

* k increases toward the patient's SUPERIOR side,
* j increases toward POSTERIOR,
* i increases toward the patient's LEFT,

i.e. ``direction`` is the identity. Axis-aligned sources are only flipped and
transposed (like nibabel's ``as_closest_canonical``); sources whose slices are
tilted (gantry tilt: a sheared grid), oblique or unevenly spaced are resampled
(linear interpolation) onto a regular axis-aligned grid in which every source
pixel keeps its true patient position ``IPP + col*dc*rowdir + row*dr*coldir``.

Nothing is ever written into the input folder.
"""
from __future__ import annotations

import gzip
import math
import os
import re
import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from .. import input_checks
from ..ct_volume import CTVolume, downsample_volume
from ..errors import CTImportError

__all__ = ["load_ct", "list_series", "SeriesInfo", "CTImportWarning"]


class CTImportWarning(UserWarning):
    """Something in the input was skipped or looks suspicious, but a volume was loaded."""


IMAGE_EXTENSIONS = (".tif", ".tiff", ".png", ".jpg", ".jpeg", ".bmp", ".gif", ".pgm", ".ppm")
NIFTI_EXTENSIONS = (".nii", ".nii.gz")
# Companion files that sit next to slices and are skipped (with a warning) instead of failing a stack.
TEXT_EXTENSIONS = (".txt", ".md", ".json", ".xml", ".csv", ".ini", ".html", ".htm", ".pdf", ".log", ".cfg")
DICOMDIR_SOP_CLASS = "1.2.840.10008.1.3.10"
AIR_HU = input_checks.AIR_HU

# Tolerances of the geometry checks (see _stack_geometry).
_ALIGNED_TOL = 1e-3        # direction cosine off an axis before the grid counts as oblique (0.25 mm at 250 mm)
_IDENTITY_SNAP = 1e-5      # below this the direction is reported as the exact identity
_SHEAR_TOL_PX = 0.1        # in-plane drift of the slice origins (pixels) before the grid counts as sheared
_UNEVEN_TOL = 0.1          # position deviation from a regular step (fraction of the step) -> uneven
_MISSING_FACTOR = 1.5      # a step this many times the median (and the slice thickness) -> missing slice

# Pip packages that add pydicom decoders, per transfer-syntax family.
_DECODER_PACKAGES = {
    "jpeg_lossless": "pylibjpeg + pylibjpeg-libjpeg, or python-gdcm",
    "jpeg_ls": "pylibjpeg + pylibjpeg-libjpeg, pyjpegls, or python-gdcm",
    "jpeg2000": "pylibjpeg + pylibjpeg-openjpeg, or python-gdcm (or Pillow built with OpenJPEG)",
    "htj2k": "pylibjpeg + pylibjpeg-openjpeg",
    "jpeg": "Pillow, pylibjpeg + pylibjpeg-libjpeg, or python-gdcm",
    "rle": "pylibjpeg + pylibjpeg-rle (pydicom's own RLE decoder needs numpy)",
}


# ----------------------------------------------------------------------------------------------
# Public API
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SeriesInfo:
    """One DICOM image series found by :func:`list_series`.

    Attributes
    ----------
    uid : str
        SeriesInstanceUID (pass it as ``load_ct(path, series_uid=uid)``).
    description : str
        SeriesDescription (may be empty).
    modality : str
        Modality, e.g. ``"CT"`` or ``"MR"``.
    slice_count : int
        Number of image slices (frames), localizers excluded.
    rows, cols : int
        Image size in pixels (the most common one if the series is mixed).
    files : tuple of str
        The files holding the slices, sorted by name.
    series_number : int or None
        SeriesNumber.
    study_description : str
        StudyDescription.
    pixel_spacing : tuple of 2 float or None
        (row spacing, column spacing) in mm.
    orientation : str
        ``"axial"``, ``"coronal"``, ``"sagittal"``, ``"oblique"`` or ``"unknown"`` (from the slice normal).
    transfer_syntax : str
        Name of the transfer syntax of the first file.
    """

    uid: str
    description: str
    modality: str
    slice_count: int
    rows: int
    cols: int
    files: tuple[str, ...] = ()
    series_number: int | None = None
    study_description: str = ""
    pixel_spacing: tuple[float, float] | None = None
    orientation: str = "unknown"
    transfer_syntax: str = ""

    @property
    def is_ct(self) -> bool:
        return self.modality.upper() == "CT"

    @property
    def label(self) -> str:
        """A one-line human description, e.g. ``"#2 HEAD: CT, 28 slices of 512x512"``."""
        number = f"#{self.series_number} " if self.series_number is not None else ""
        desc = self.description or "(no description)"
        return f"{number}{desc}: {self.modality or '?'}, {self.slice_count} slices of {self.rows}x{self.cols}"


def list_series(path: str | os.PathLike | Sequence[str | os.PathLike]) -> list[SeriesInfo]:
    """List the DICOM image series under a folder (searched recursively) or in a list of files.

    Non-DICOM files, DICOMDIR, localizers and objects without pixel data are
    left out. The list is sorted as :func:`load_ct` chooses: CT before other
    modalities, then by slice count (largest first), then by series number.

    Parameters
    ----------
    path : path or sequence of paths
        A folder, a single file or a list of files.

    Returns
    -------
    list of SeriesInfo
        Empty when there is no DICOM image series.

    Raises
    ------
    CTImportError
        If the path does not exist or the folder is empty.
    """
    files, label = _gather_files(path)
    files = _expand_dicomdir(files, label, [])
    scan = _scan_dicom(files)
    return [_series_info(s) for s in _ranked_series(scan.series)]


def load_ct(
    path: str | os.PathLike | Sequence[str | os.PathLike],
    *,
    format: str = "auto",
    series_uid: str | None = None,
    spacing: Sequence[float] | None = None,
    first_slice: str | None = None,
    orientation: str | None = None,
    units: str | None = None,
    shape: Sequence[int] | None = None,
    dtype: str | np.dtype | None = None,
    byte_order: str | None = None,
    header_bytes: int = 0,
    resample_spacing: Sequence[float] | None = None,
    downsample: int | Sequence[int] | None = None,
) -> CTVolume:
    """Load head CT slices into a :class:`CTVolume` (float32 ``[z, y, x]``, LPS mm, k superior).

    Parameters
    ----------
    path : path or sequence of paths
        A folder (DICOM is searched recursively; image and raw slices are taken
        from the folder itself), a single file (DICOM, multi-page TIFF, NIfTI
        ``.nii``/``.nii.gz``, raw volume) or a list of files.
    format : {"auto", "dicom", "image", "raw", "nifti"}
        ``"auto"`` detects DICOM by its preamble ('DICM') or by parsing,
        images and NIfTI by extension; headerless raw data is used only when
        asked (``format="raw"``) or when ``shape`` is given.
    series_uid : str, optional
        DICOM: the SeriesInstanceUID to load (see :func:`list_series`).
        Default: the CT image series with the most slices.
    spacing : (dz, dy, dx), optional
        Voxel size in mm for images and raw data (they carry none); default
        (1, 1, 1) with a warning. Ignored (with a warning) for DICOM/NIfTI.
    first_slice : {"inferior", "superior"}, optional
        Images and raw data: where the first slice of the numeric order lies
        (default inferior). Same as ``orientation="LPS"`` / ``"LPI"``.
    orientation : str, optional
        Images and raw data: three letters naming the patient direction in which
        the column index, the row index and the file (slice) index increase, e.g.
        ``"LPS"`` (default: column 0 = patient right, row 0 = front, first file at
        the bottom), ``"LAS"`` (row 0 = the back of the head), ``"RAS"``,
        ``"PIL"`` (sagittal slices). A warning is issued when the face (the nose)
        seems to lie on the side the code calls posterior.
    units : {"HU", "stored"}, optional
        Images and raw data: ``"HU"`` says the samples are Hounsfield units (air
        -1000), which enables the HU rules (out-of-field values below -1500 HU);
        default: uncalibrated stored values. NIfTI: ``"HU"`` marks a CT NIfTI.
    shape : (ny, nx) or (nz, ny, nx), optional
        Raw data: slice (or volume) shape.
    dtype : str or numpy dtype, optional
        Raw data: sample type with byte order, e.g. ``">i2"`` (big-endian int16).
    byte_order : {"big", "little"}, optional
        Raw data: sets the byte order of ``dtype``.
    header_bytes : int
        Raw data: bytes to skip at the start of every file.
    resample_spacing : (dz, dy, dx), optional
        Voxel size of the output grid when the slices must be resampled
        (tilted, oblique or uneven). Default: the in-plane pixel spacing and the
        median slice step.
    downsample : int or (fz, fy, fx), optional
        Average blocks of voxels after loading (:func:`~.ct_volume.downsample_volume`),
        for scans too large to segment in memory (``segment_head`` says when).

    Returns
    -------
    CTVolume
        ``direction`` is the identity whenever the source allows it. ``meta``
        holds ``source``, ``format``, ``modality``, ``series_uid``,
        ``series_description``, ``original_slice_count``, ``gantry_tilt_deg``,
        ``resampled``, ``resample_reason``, ``hu_range``, ``units`` and the
        list ``warnings`` (each also issued as a :class:`CTImportWarning`);
        ``non_finite_voxels`` and ``out_of_field`` record repaired voxels.

    Raises
    ------
    CTImportError
        With the offending file or folder and the problem: missing path, empty
        folder, no CT series, mixed image sizes, duplicate slice positions,
        truncated or undecodable files, raw size mismatch, bad options.
    """
    warns: list[str] = []
    fmt = str(format).lower()
    if fmt in ("images", "tiff", "tif", "png"):
        fmt = "image"
    if fmt not in ("auto", "dicom", "image", "raw", "nifti"):
        raise CTImportError(f"unknown format {format!r}; use 'auto', 'dicom', 'image', 'raw' or 'nifti'",
                            _label(path))
    if first_slice not in (None, "inferior", "superior"):
        raise CTImportError(f"first_slice must be 'inferior' or 'superior', got {first_slice!r}", _label(path))
    if units is not None and str(units).lower() not in ("hu", "stored"):
        raise CTImportError(f"units must be 'HU' or 'stored', got {units!r}", _label(path))
    hu_said = units is not None and str(units).lower() == "hu"
    axes = None
    if orientation is not None:
        try:
            axes = input_checks.parse_orientation(orientation)
        except ValueError as exc:
            raise CTImportError(str(exc), _label(path)) from None
        if first_slice is not None and not (abs(axes[2][2]) == 1
                                            and (axes[2][2] > 0) == (first_slice == "inferior")):
            raise CTImportError(f"first_slice={first_slice!r} contradicts orientation={orientation!r} "
                                "(its third letter says where the files go); give only orientation", _label(path))
    files, label = _gather_files(path)
    if fmt in ("auto", "dicom"):
        files = _expand_dicomdir(files, label, warns)

    if fmt == "auto":
        fmt = _detect_format(files, label, shape)
    if fmt in ("dicom", "nifti"):
        if spacing is not None:
            warns.append(f"spacing={tuple(spacing)} ignored: {fmt.upper()} files carry their own geometry")
        if first_slice is not None:
            warns.append(f"first_slice={first_slice!r} ignored: {fmt.upper()} files carry their own geometry")
        if orientation is not None:
            warns.append(f"orientation={orientation!r} ignored: {fmt.upper()} files carry their own geometry")
        if fmt == "dicom" and units is not None:
            warns.append(f"units={units!r} ignored: DICOM says its own units (Modality, RescaleType)")
    elif series_uid is not None:
        warns.append("series_uid ignored: the input is not DICOM")
    if axes is None:
        axes = input_checks.parse_orientation("LPI" if first_slice == "superior" else "LPS")

    if fmt == "dicom":
        ct = _load_dicom(files, label, series_uid, resample_spacing, warns)
    elif fmt == "nifti":
        ct = _load_nifti(files, label, resample_spacing, warns, hu_said)
    elif fmt == "image":
        ct = _load_images(files, label, spacing, axes, orientation is not None, hu_said, warns)
    else:
        ct = _load_raw(files, label, shape, dtype, byte_order, header_bytes, spacing, axes,
                       orientation is not None, hu_said, warns)
    _check_values(ct, label, warns)
    if downsample is not None and np.any(np.asarray(downsample) != 1):
        try:
            ct = downsample_volume(ct, downsample)
        except (ValueError, TypeError) as exc:
            raise CTImportError(f"downsample: {exc}", label) from None
        warns.append(f"downsampled {ct.meta['shape_before_downsample']} -> {ct.shape} voxels (block means of "
                     f"{' x '.join(map(str, ct.meta['downsampled']))}); spacing now {ct.spacing} mm (dz, dy, dx)")
    if fmt in ("image", "raw"):
        _check_face_side(ct, warns)

    ct.meta["warnings"] = list(warns)
    for message in warns:
        warnings.warn(f"{label}: {message}", CTImportWarning, stacklevel=2)
    return ct


def _check_values(ct: CTVolume, label: str, warns: list[str]) -> None:
    """Non-finite voxels and out-of-field values become air, each with a warning naming the cause."""
    meta = ct.meta
    hu = meta.get("units") == "HU"
    try:
        bad, fill = input_checks.repair_non_finite(ct.data, hu)
    except ValueError as exc:
        raise CTImportError(f"no usable voxel: {exc}", label) from None
    meta["non_finite_voxels"] = bad
    if bad:
        warns.append(f"{bad} voxel(s) ({100.0 * bad / ct.data.size:.2g} % of the volume) are NaN or infinite; "
                     f"filled as air ({fill:g})")
    oof = input_checks.repair_out_of_field(ct.data, hu)
    meta["out_of_field"] = oof
    if oof:
        value = oof["value"]
        value = f"{value:g}" if not isinstance(value, tuple) else f"{value[0]:g} to {value[1]:g}"
        unit = " HU" if hu else ""
        warns.append(f"{oof['count']} voxel(s) ({100.0 * oof['count'] / ct.data.size:.1f} % of the volume, "
                     f"{100.0 * oof['outside_circle']:.0f} % of them outside the circular field of view) hold the "
                     f"out-of-field value {value}{unit} ({oof['rule']}; no PixelPaddingValue said so): set to air "
                     f"({oof['fill']:g}{unit})")
    if bad or oof:
        meta["hu_range"] = (float(ct.data.min()), float(ct.data.max()))


# ----------------------------------------------------------------------------------------------
# Files and format detection
# ----------------------------------------------------------------------------------------------

def _label(path) -> str:
    if isinstance(path, (str, os.PathLike)):
        return os.fspath(path)
    try:
        items = list(path)
    except TypeError:
        return repr(path)
    return f"{os.fspath(items[0])} (+{len(items) - 1} more files)" if items else "(empty file list)"


def _gather_files(path) -> tuple[list[Path], str]:
    """All regular files of a folder (recursively, sorted), a single file, or a list of files."""
    if isinstance(path, (str, os.PathLike)):
        p = Path(path)
        label = os.fspath(path)
        if not p.exists():
            raise CTImportError("no such file or folder", label)
        if p.is_file():
            return [p], label
        files = []
        for root, dirs, names in os.walk(p):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            files.extend(Path(root) / n for n in sorted(names) if not n.startswith("."))
        files = [f for f in files if f.is_file()]
        if not files:
            raise CTImportError("the folder is empty (no files in it or its subfolders)", label)
        return files, label
    try:
        items = [Path(f) for f in path]
    except TypeError:
        raise CTImportError(f"expected a folder, a file or a list of files, got {type(path).__name__}") from None
    label = _label(items)
    if not items:
        raise CTImportError("the list of files is empty")
    for f in items:
        if not f.is_file():
            raise CTImportError("no such file" if not f.exists() else "not a regular file", f)
    return items, label


def _is_dicomdir(f: Path) -> bool:
    return f.name.upper() == "DICOMDIR" and _looks_like_dicom(f)


def _expand_dicomdir(files: list[Path], label: str, warns: list[str]) -> list[Path]:
    """Add the image files a DICOMDIR (a DICOM file-set's index) refers to.

    A DICOMDIR names its files by ReferencedFileID (path components relative to
    the DICOMDIR's folder, often upper-case without extension, e.g.
    ``DICOM/ST000000/SE000001/IM000003``). Given the DICOMDIR itself, or a folder
    holding one, the referenced files are loaded like any other files of the
    folder; referenced files that are missing are reported in a warning.
    """
    dirs = [f for f in files if _is_dicomdir(f)]
    if not dirs:
        return files
    pydicom = _pydicom()
    out = list(files)
    seen = {os.path.normcase(os.path.abspath(f)) for f in files}
    for d in dirs:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                index = pydicom.dcmread(d, force=True)
            records = index.get("DirectoryRecordSequence") or []
        except Exception as exc:
            warns.append(f"cannot read DICOMDIR {d} ({type(exc).__name__}: {exc}); its folder is searched instead")
            continue
        missing = []
        for rec in records:
            ref = rec.get("ReferencedFileID")
            if ref is None:
                continue
            parts = [str(p) for p in ref] if not isinstance(ref, str) else str(ref).split("\\")
            target = d.parent.joinpath(*parts)
            if not target.is_file():
                # file systems that lost the upper case of ISO 9660 names
                alt = d.parent.joinpath(*(p.lower() for p in parts))
                target = alt if alt.is_file() else target
            if not target.is_file():
                missing.append("/".join(parts))
                continue
            key = os.path.normcase(os.path.abspath(target))
            if key not in seen:
                seen.add(key)
                out.append(target)
        if missing:
            warns.append(f"DICOMDIR {d} refers to {len(missing)} missing file(s): " + ", ".join(missing[:3])
                         + (", ..." if len(missing) > 3 else ""))
    return out


def _top_level(files: list[Path], label: str) -> list[Path]:
    """Files directly in the folder (image and raw stacks are not searched recursively)."""
    root = Path(label)
    if root.is_dir():
        return [f for f in files if f.parent == root]
    return files


def _has_ext(f: Path, exts: Iterable[str]) -> bool:
    name = f.name.lower()
    return any(name.endswith(e) for e in exts)


_DIGITS = re.compile(r"\d+")


def _numbered_key(f: Path) -> tuple:
    """Sort key ordering ``x2 < x10 < x100`` by the last number in the file name."""
    name = f.name
    runs = list(_DIGITS.finditer(name))
    if not runs:
        return (name, -1, name)
    last = runs[-1]
    template = name[:last.start()] + "#" + name[last.end():]
    return (template, int(last.group()), name)


def _numbered_files(files: list[Path], label: str, what: str, warns: list[str]) -> list[Path]:
    ordered = sorted(files, key=_numbered_key)
    templates = {_numbered_key(f)[0] for f in ordered}
    if len(templates) > 1:
        warns.append(f"{what} file names follow {len(templates)} different patterns "
                     f"({', '.join(sorted(templates)[:3])}...); sorted by pattern, then number")
    return ordered


def _looks_like_dicom(f: Path) -> bool:
    """'DICM' at byte 128, or a preamble-less file starting with a group 0002/0008 tag."""
    try:
        with open(f, "rb") as fh:
            head = fh.read(132)
    except OSError:
        return False
    if len(head) >= 132 and head[128:132] == b"DICM":
        return True
    return len(head) >= 8 and head[:2] in (b"\x02\x00", b"\x08\x00")


def _detect_format(files: list[Path], label: str, shape) -> str:
    if shape is not None:
        return "raw"
    if len(files) == 1 and _has_ext(files[0], NIFTI_EXTENSIONS):
        return "nifti"
    if any(_looks_like_dicom(f) for f in files if not _has_ext(f, IMAGE_EXTENSIONS + NIFTI_EXTENSIONS)):
        return "dicom"
    top = _top_level(files, label)
    if any(_has_ext(f, IMAGE_EXTENSIONS) for f in top):
        return "image"
    if any(_has_ext(f, NIFTI_EXTENSIONS) for f in top):
        raise CTImportError("found NIfTI files; pass one .nii/.nii.gz file, not the folder", label)
    if any(_has_ext(f, IMAGE_EXTENSIONS) for f in files):
        raise CTImportError("no slices directly in this folder (images found only in subfolders); "
                            "choose the folder that holds the numbered images", label)
    raise CTImportError(
        "no DICOM, image (TIFF/PNG/...) or NIfTI files found; for headerless raw slices pass "
        "format='raw', shape=(ny, nx) and dtype (e.g. '>i2')", label)


# ----------------------------------------------------------------------------------------------
# DICOM: scanning headers
# ----------------------------------------------------------------------------------------------

@dataclass(eq=False)
class _Frame:
    """One 2-D image of a DICOM series (a file, or one frame of a multi-frame file)."""

    path: Path
    frame: int | None            # frame index in a multi-frame file, None for single-frame
    ds: Any                      # pydicom Dataset, pixel data deferred
    ipp: np.ndarray | None       # ImagePositionPatient (3,)
    iop: np.ndarray | None       # ImageOrientationPatient (6,)
    pixel_spacing: tuple[float, float] | None
    thickness: float | None
    slope: float
    intercept: float
    rows: int
    cols: int
    sop_uid: str


@dataclass
class _Series:
    uid: str
    frames: list[_Frame] = field(default_factory=list)
    localizers: int = 0

    @property
    def first(self) -> Any:
        return self.frames[0].ds


@dataclass
class _Scan:
    series: dict[str, _Series]
    skipped: dict[str, list[Path]]      # reason -> files
    unreadable: dict[Path, str]         # DICOM-looking files that failed to parse -> error
    incomplete: dict[str, list[Path]]   # series uid -> image files cut off before their pixel data


def _pydicom():
    try:
        import pydicom
    except ImportError as exc:  # pragma: no cover - pydicom is a hard dependency
        raise CTImportError(f"reading DICOM needs the 'pydicom' package ({exc})") from None
    return pydicom


def _read_dicom_header(f: Path):
    """The dataset with pixel data deferred (read lazily from the file)."""
    pydicom = _pydicom()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = pydicom.dcmread(f, defer_size=4096, force=True)
        # Touch the tags we need now so that a header broken by truncation fails here.
        for keyword in ("SOPClassUID", "SeriesInstanceUID", "Rows", "Columns", "ImagePositionPatient"):
            ds.get(keyword)
    if "SOPClassUID" not in ds and "SeriesInstanceUID" not in ds and "Rows" not in ds:
        raise ValueError("no SOP class, series or image attributes")
    return ds


def _floats(value, n: int) -> np.ndarray | None:
    if value is None:
        return None
    try:
        arr = np.array([float(v) for v in value], dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return arr if arr.shape == (n,) and np.all(np.isfinite(arr)) else None


def _float_or(value, default):
    try:
        out = float(value)
    except (TypeError, ValueError):
        return default
    return out if math.isfinite(out) else default


def _group_value(groups: Sequence, sequence: str, keyword: str):
    """First value of ``keyword`` inside ``sequence`` of the first functional group that has it."""
    for group in groups:
        if group is None:
            continue
        seq = group.get(sequence)
        if seq:
            value = seq[0].get(keyword)
            if value is not None:
                return value
    return None


def _frames_of(f: Path, ds) -> list[_Frame]:
    rows, cols = int(ds.get("Rows", 0) or 0), int(ds.get("Columns", 0) or 0)
    sop_uid = str(ds.get("SOPInstanceUID", f))
    try:
        nframes = int(ds.get("NumberOfFrames", 1) or 1)
    except (TypeError, ValueError):
        nframes = 1
    shared_seq = ds.get("SharedFunctionalGroupsSequence")
    shared = shared_seq[0] if shared_seq else None
    per_frame = ds.get("PerFrameFunctionalGroupsSequence")
    frames = []
    for index in range(nframes):
        groups = [per_frame[index] if per_frame is not None and index < len(per_frame) else None, shared]
        ipp = _floats(_group_value(groups, "PlanePositionSequence", "ImagePositionPatient")
                      or ds.get("ImagePositionPatient"), 3)
        iop = _floats(_group_value(groups, "PlaneOrientationSequence", "ImageOrientationPatient")
                      or ds.get("ImageOrientationPatient"), 6)
        ps = _floats(_group_value(groups, "PixelMeasuresSequence", "PixelSpacing") or ds.get("PixelSpacing"), 2)
        thickness = _float_or(_group_value(groups, "PixelMeasuresSequence", "SliceThickness")
                              or ds.get("SliceThickness"), None)
        slope = _float_or(_group_value(groups, "PixelValueTransformationSequence", "RescaleSlope")
                          or ds.get("RescaleSlope"), 1.0)
        intercept = _float_or(_group_value(groups, "PixelValueTransformationSequence", "RescaleIntercept")
                              or ds.get("RescaleIntercept"), 0.0)
        frames.append(_Frame(f, index if nframes > 1 else None, ds, ipp, iop,
                             None if ps is None else (float(ps[0]), float(ps[1])),
                             thickness if thickness and thickness > 0 else None,
                             slope if slope != 0 else 1.0, intercept, rows, cols, sop_uid))
    return frames


def _scan_dicom(files: list[Path]) -> _Scan:
    series: dict[str, _Series] = {}
    skipped: dict[str, list[Path]] = {}
    unreadable: dict[Path, str] = {}
    incomplete: dict[str, list[Path]] = {}

    def skip(reason: str, f: Path) -> None:
        skipped.setdefault(reason, []).append(f)

    for f in files:
        if f.name.upper() == "DICOMDIR":
            skip("DICOMDIR", f)
            continue
        if _has_ext(f, IMAGE_EXTENSIONS + NIFTI_EXTENSIONS + TEXT_EXTENSIONS) or not _looks_like_dicom(f):
            skip("not DICOM", f)
            continue
        try:
            ds = _read_dicom_header(f)
        except Exception as exc:  # any parse failure of a DICOM-looking file
            unreadable[f] = f"{type(exc).__name__}: {exc}"
            continue
        media_class = str(getattr(ds, "file_meta", {}).get("MediaStorageSOPClassUID", ""))
        if media_class == DICOMDIR_SOP_CLASS or str(ds.get("SOPClassUID", "")) == DICOMDIR_SOP_CLASS:
            skip("DICOMDIR", f)
            continue
        if "PixelData" not in ds:
            sop_class = ds.get("SOPClassUID")
            if sop_class is not None and "image storage" in str(getattr(sop_class, "name", "")).lower():
                # an image object without its pixels: the file was cut off inside the header
                incomplete.setdefault(str(ds.get("SeriesInstanceUID", "")), []).append(f)
                unreadable[f] = f"{sop_class.name} object without pixel data (file truncated?)"
            else:
                skip("no pixel data (not an image)", f)
            continue
        uid = str(ds.get("SeriesInstanceUID", "") or "(no SeriesInstanceUID)")
        entry = series.setdefault(uid, _Series(uid))
        image_type = ds.get("ImageType") or []
        if isinstance(image_type, str):
            image_type = image_type.split("\\")
        if "LOCALIZER" in {str(t).strip().upper() for t in image_type}:
            entry.localizers += 1
            skip("localizer", f)
            continue
        entry.frames.extend(_frames_of(f, ds))
    series = {uid: s for uid, s in series.items() if s.frames}
    return _Scan(series, skipped, unreadable, incomplete)


def _orientation_name(iop: np.ndarray | None) -> str:
    if iop is None:
        return "unknown"
    normal = np.cross(iop[:3], iop[3:])
    norm = np.linalg.norm(normal)
    if norm < 1e-6:
        return "unknown"
    normal = np.abs(normal / norm)
    axis = int(np.argmax(normal))
    if normal[axis] < 1 - _ALIGNED_TOL:
        return "oblique"
    return ("sagittal", "coronal", "axial")[axis]


def _series_info(s: _Series) -> SeriesInfo:
    ds = s.first
    sizes: dict[tuple[int, int], int] = {}
    for fr in s.frames:
        sizes[(fr.rows, fr.cols)] = sizes.get((fr.rows, fr.cols), 0) + 1
    rows, cols = max(sizes, key=sizes.get)
    number = ds.get("SeriesNumber")
    try:
        number = int(number) if number not in (None, "") else None
    except (TypeError, ValueError):
        number = None
    ts = getattr(getattr(ds, "file_meta", None), "TransferSyntaxUID", None)
    return SeriesInfo(
        uid=s.uid,
        description=str(ds.get("SeriesDescription", "") or ""),
        modality=str(ds.get("Modality", "") or ""),
        slice_count=len(s.frames),
        rows=rows,
        cols=cols,
        files=tuple(sorted({os.fspath(fr.path) for fr in s.frames})),
        series_number=number,
        study_description=str(ds.get("StudyDescription", "") or ""),
        pixel_spacing=s.frames[0].pixel_spacing,
        orientation=_orientation_name(s.frames[0].iop),
        transfer_syntax=str(ts.name) if ts is not None else "",
    )


def _ranked_series(series: dict[str, _Series]) -> list[_Series]:
    def key(s: _Series):
        info_number = s.first.get("SeriesNumber")
        try:
            number = int(info_number)
        except (TypeError, ValueError):
            number = 1 << 30
        return (str(s.first.get("Modality", "")).upper() != "CT", -len(s.frames), number, s.uid)
    return sorted(series.values(), key=key)


def _skip_summary(skipped: dict[str, list[Path]]) -> str:
    parts = []
    for reason, fs in skipped.items():
        names = ", ".join(f.name for f in fs[:3]) + (", ..." if len(fs) > 3 else "")
        parts.append(f"{len(fs)} {reason} ({names})")
    return "; ".join(parts)


# ----------------------------------------------------------------------------------------------
# DICOM: loading one series
# ----------------------------------------------------------------------------------------------

def _load_dicom(files, label, series_uid, resample_spacing, warns) -> CTVolume:
    scan = _scan_dicom(files)
    ranked = _ranked_series(scan.series)
    if not ranked and len(files) == 1 and scan.unreadable:
        raise CTImportError(f"cannot read this DICOM file: {scan.unreadable[files[0]]}", files[0])
    if not ranked:
        details = []
        if scan.unreadable:
            f, err = next(iter(scan.unreadable.items()))
            details.append(f"{len(scan.unreadable)} DICOM-looking file(s) could not be read, e.g. {f}: {err}")
        if scan.skipped:
            details.append("skipped: " + _skip_summary(scan.skipped))
        raise CTImportError("no DICOM image series found" + (" (" + "; ".join(details) + ")" if details else ""),
                            label)
    if series_uid is not None:
        chosen = scan.series.get(str(series_uid))
        if chosen is None:
            available = ", ".join(f"{s.uid} [{_series_info(s).label}]" for s in ranked)
            raise CTImportError(f"series_uid {series_uid!r} not found; available series: {available}", label)
    else:
        chosen = ranked[0]
    info = _series_info(chosen)
    broken = scan.incomplete.get(chosen.uid)
    if broken:
        raise CTImportError(f"truncated file: {scan.unreadable[broken[0]]}; it belongs to the series being "
                            f"loaded ({len(broken)} such file(s))", broken[0])
    if not info.is_ct:
        warns.append(f"modality is {info.modality or 'unknown'}, not CT: intensities are not HU")
    if len(ranked) > 1 and series_uid is None:
        warns.append(f"{len(ranked)} image series found; loaded {info.label} (uid {info.uid}); "
                     "pass series_uid= to choose another")
    for path, err in scan.unreadable.items():  # (files of the chosen series raised above)
        warns.append(f"skipped unreadable DICOM file {path} ({err})")
    not_dicom = scan.skipped.get("not DICOM", [])
    if not_dicom:
        warns.append(f"skipped {len(not_dicom)} non-DICOM file(s): "
                     + ", ".join(f.name for f in not_dicom[:5]) + (", ..." if len(not_dicom) > 5 else ""))

    frames = _consistent_frames(chosen, warns)
    geometry = _stack_geometry(frames, label, warns)
    if len(frames) == 1 and geometry["resample_reasons"]:
        raise CTImportError("a single tilted or oblique slice cannot make a volume (it would be resampled into "
                            "a block of axial slices holding almost no measured voxel: "
                            + "; ".join(geometry["resample_reasons"]) + "); load the whole series",
                            frames[0].path)
    stack, pad_info = _read_pixels(frames, info.is_ct)

    reasons = geometry["resample_reasons"]
    if reasons:
        data, origin, spacing, coverage = _resample_slices(
            stack, geometry["positions"], geometry["u"], geometry["v"], geometry["dr"], geometry["dc"],
            geometry["steps"], resample_spacing, pad_info["fill"])
        direction = np.eye(3)
    else:
        coverage = None
        if resample_spacing is not None:
            warns.append("resample_spacing ignored: the slices are regular and axis-aligned (no resampling)")
        data, spacing, origin, direction = _canonical(
            stack, [geometry["n"], geometry["v"], geometry["u"]],
            [geometry["step"], geometry["dr"], geometry["dc"]], geometry["positions"][0])
    del stack

    ds = chosen.first
    ts = getattr(getattr(ds, "file_meta", None), "TransferSyntaxUID", None)
    meta = {
        "source": label,
        "format": "dicom",
        "modality": info.modality,
        "series_uid": info.uid,
        "series_description": info.description,
        "series_number": info.series_number,
        "study_description": info.study_description,
        "manufacturer": str(ds.get("Manufacturer", "") or ""),
        "patient_position": str(ds.get("PatientPosition", "") or ""),
        "transfer_syntax": str(ts.name) if ts is not None else "",
        "original_slice_count": len(frames),
        "original_shape": (len(frames), frames[0].rows, frames[0].cols),
        "pixel_spacing": (geometry["dr"], geometry["dc"]),
        "slice_steps_mm": [round(float(s), 4) for s in geometry["steps"]],
        "slice_thickness_mm": sorted({fr.thickness for fr in frames if fr.thickness}),
        "gantry_tilt_deg": round(geometry["tilt_deg"], 3),
        "gantry_tilt_header_deg": _float_or(ds.get("GantryDetectorTilt"), None),
        "resampled": bool(reasons),
        "resample_reason": "; ".join(reasons),
        "units": "HU" if pad_info["hu"] else "stored value x slope + intercept",
        "rescale": sorted({(fr.slope, fr.intercept) for fr in frames}),
        "padding_value": pad_info["padding_value"],
        "padding_fill": pad_info["fill"],
        "padding_fill_rule": pad_info["fill_rule"],
        "padding_pixels": pad_info["count"],
        "files": len({fr.path for fr in frames}),
        "skipped": {reason: len(fs) for reason, fs in scan.skipped.items()},
        "hu_range": (float(data.min()), float(data.max())),
        "covered_fraction": 1.0 if coverage is None else float(coverage.mean()),
    }
    return CTVolume(data, spacing, origin, direction, meta, coverage=coverage)


def _consistent_frames(series: _Series, warns: list[str]) -> list[_Frame]:
    """The frames of the dominant orientation, with exact duplicates removed; mixed sizes are an error."""
    frames = series.frames
    missing = [fr for fr in frames if fr.ipp is None or fr.iop is None or fr.pixel_spacing is None]
    if len(missing) == len(frames):
        raise CTImportError("has no ImagePositionPatient / ImageOrientationPatient / PixelSpacing, so its "
                            "slices cannot be placed in patient space", missing[0].path)
    if missing:
        warns.append(f"skipped {len(missing)} slice(s) without position/orientation/pixel spacing: "
                     + ", ".join(fr.path.name for fr in missing[:5]))
        missing_ids = {id(fr) for fr in missing}
        frames = [fr for fr in frames if id(fr) not in missing_ids]
    groups: dict[tuple, list[_Frame]] = {}
    for fr in frames:
        groups.setdefault(tuple(np.round(fr.iop, 3)), []).append(fr)
    if len(groups) > 1:
        main = max(groups.values(), key=len)
        others = [fr for g in groups.values() if g is not main for fr in g]
        warns.append(f"skipped {len(others)} slice(s) with a different orientation (scout/localizer?): "
                     + ", ".join(fr.path.name for fr in others[:5]))
        frames = main
    # The same file reached twice (copied into two folders): keep one.
    seen: dict[tuple, _Frame] = {}
    duplicates = []
    for fr in frames:
        key = (fr.sop_uid, fr.frame)
        if key in seen:
            duplicates.append(fr)
        else:
            seen[key] = fr
    if duplicates:
        warns.append(f"skipped {len(duplicates)} duplicate file(s) with the same SOPInstanceUID: "
                     + ", ".join(os.fspath(fr.path) for fr in duplicates[:3]))
        frames = list(seen.values())
    sizes = {(fr.rows, fr.cols) for fr in frames}
    if len(sizes) > 1:
        by_size: dict[tuple, _Frame] = {}
        for fr in frames:
            by_size.setdefault((fr.rows, fr.cols), fr)
        example = "; ".join(f"{r}x{c} in {fr.path}" for (r, c), fr in by_size.items())
        raise CTImportError(f"mixed image sizes within one series ({example})", frames[0].path.parent)
    spacings = {tuple(np.round(fr.pixel_spacing, 4)) for fr in frames}
    if len(spacings) > 1:
        raise CTImportError(f"mixed pixel spacings within one series: {sorted(spacings)}", frames[0].path.parent)
    return frames


def _stack_geometry(frames: list[_Frame], label: str, warns: list[str]) -> dict:
    """Sort the slices along their normal and decide whether the grid must be resampled.

    The slice normal is the cross product of the ImageOrientationPatient row and
    column directions; slices are sorted by their ImagePositionPatient projected
    on it (never by InstanceNumber or file name). The grid is *sheared* (gantry
    tilt) when the slice origins drift within the image plane, *uneven* when the
    positions along the normal are not a regular progression, and *oblique* when
    the image axes are not patient axes.
    """
    iop = frames[0].iop
    u = iop[:3] / np.linalg.norm(iop[:3])       # direction of increasing column index
    v = iop[3:] / np.linalg.norm(iop[3:])       # direction of increasing row index
    n = np.cross(u, v)
    if np.linalg.norm(n) < 1e-6:
        raise CTImportError("ImageOrientationPatient rows are parallel; cannot compute the slice normal",
                            frames[0].path)
    n /= np.linalg.norm(n)
    dr, dc = frames[0].pixel_spacing             # PixelSpacing = (between rows, between columns)
    positions = np.array([fr.ipp for fr in frames])
    along = positions @ n
    order = np.argsort(along, kind="stable")
    frames[:] = [frames[i] for i in order]
    positions, along = positions[order], along[order]
    steps = np.diff(along)

    # Duplicate positions: two different images at the same place.
    dup = np.flatnonzero(steps < 1e-3)
    if dup.size:
        a, b = frames[dup[0]], frames[dup[0] + 1]
        where = lambda fr: os.fspath(fr.path) + (f" frame {fr.frame}" if fr.frame is not None else "")
        raise CTImportError(f"duplicate slice position {np.round(a.ipp, 3).tolist()} in {where(a)} and {where(b)} "
                            f"({dup.size} duplicate(s)); the series mixes several acquisitions", label)

    reasons = []
    tilt_deg = 0.0
    if len(frames) > 1:
        offsets = positions - positions[0]
        in_plane = offsets - np.outer(offsets @ n, n)
        drift_px = max(np.abs(in_plane @ u).max() / dc, np.abs(in_plane @ v).max() / dr)
        stack_dir = offsets[-1] / np.linalg.norm(offsets[-1])
        tilt_deg = float(np.degrees(np.arccos(np.clip(abs(stack_dir @ n), 0.0, 1.0))))
        if drift_px > _SHEAR_TOL_PX:
            reasons.append(f"gantry tilt {tilt_deg:.2f} deg (image planes not perpendicular to the stacking "
                           "direction: sheared grid)")
        median_step = float(np.median(steps))
        regular = (along[-1] - along[0]) / (len(frames) - 1)
        deviation = np.abs(along - along[0] - regular * np.arange(len(frames))).max()
        if deviation > _UNEVEN_TOL * regular:
            reasons.append(f"uneven slice steps ({steps.min():.3g} to {steps.max():.3g} mm, median "
                           f"{median_step:.3g} mm)")
        # A missing slice: a step well over the median that the slice thicknesses do not explain.
        thick = np.array([fr.thickness or 0.0 for fr in frames])
        local = np.maximum(thick[:-1], thick[1:])
        gaps = np.flatnonzero((steps > _MISSING_FACTOR * median_step) & (steps > _MISSING_FACTOR * local))
        for g in gaps[:5]:
            warns.append(f"possible missing slice: step of {steps[g]:.3g} mm between {frames[g].path.name} and "
                         f"{frames[g + 1].path.name} (median step {median_step:.3g} mm); the gap is interpolated")
        step = regular
    else:
        step = frames[0].thickness or 1.0
        warns.append(f"single slice: slice step set to {'SliceThickness ' if frames[0].thickness else ''}"
                     f"{step:g} mm; a PDE head needs at least 4 slices (3t + 1 boundary curves, t >= 1)")
        steps = np.array([step])
    axes = np.abs(np.stack([u, v, n]))
    if axes.max(axis=1).min() < 1 - _ALIGNED_TOL or len(set(np.argmax(axes, axis=1))) < 3:
        reasons.append("image planes oblique to the patient axes (ImageOrientationPatient "
                       + np.array2string(np.round(iop, 4), separator=",") + ")")
    return dict(u=u, v=v, n=n, dr=float(dr), dc=float(dc), positions=positions, steps=steps, step=float(step),
                tilt_deg=tilt_deg, resample_reasons=reasons)


def _transfer_syntax(ds):
    pydicom = _pydicom()
    meta = getattr(ds, "file_meta", None)
    ts = getattr(meta, "TransferSyntaxUID", None) if meta is not None else None
    if ts is None:
        # Preamble-less file: the encoding pydicom detected while reading.
        implicit, little = getattr(ds, "original_encoding", (True, True))
        uid = pydicom.uid
        ts = (uid.ImplicitVRLittleEndian if implicit else
              uid.ExplicitVRLittleEndian if little else uid.ExplicitVRBigEndian)
        if meta is None:
            ds.file_meta = pydicom.dataset.FileMetaDataset()
        ds.file_meta.TransferSyntaxUID = ts
    return ts


def _decoder_family(ts) -> str:
    name = str(ts.name).lower()
    if "high-throughput" in name or "htj2k" in name:
        return "htj2k"
    if "2000" in name:
        return "jpeg2000"
    if "jpeg-ls" in name:
        return "jpeg_ls"
    if "lossless" in name and "jpeg" in name:
        return "jpeg_lossless"
    if "jpeg" in name:
        return "jpeg"
    if "rle" in name:
        return "rle"
    return ""


def _decode_file(ds, path: Path) -> np.ndarray:
    """Stored pixel values of one file, shape (frames, rows, cols); clear errors for every failure."""
    ts = _transfer_syntax(ds)
    samples = int(ds.get("SamplesPerPixel", 1) or 1)
    if samples != 1:
        raise CTImportError(f"colour image (SamplesPerPixel={samples}); CT slices must be greyscale", path)
    if ts.is_compressed:
        try:
            from pydicom.pixels import get_decoder
            decoder = get_decoder(ts)
            available = decoder.is_available
        except Exception:
            available, decoder = False, None
        if not available:
            packages = _DECODER_PACKAGES.get(_decoder_family(ts), "a pydicom pixel-data plugin")
            raise CTImportError(f"pixel data is compressed with {ts.name} ({ts}) and no installed decoder "
                                f"reads it; install {packages}", path)
    else:
        try:
            raw = ds.PixelData
        except Exception as exc:
            raise CTImportError(f"cannot read the pixel data (file truncated?): {exc}", path) from None
        frames = int(ds.get("NumberOfFrames", 1) or 1)
        expected = int(ds.Rows) * int(ds.Columns) * samples * frames * ((int(ds.BitsAllocated) + 7) // 8)
        if int(ds.BitsAllocated) == 1:
            expected = (int(ds.Rows) * int(ds.Columns) * frames + 7) // 8
        if raw is None or len(raw) < expected:
            actual = 0 if raw is None else len(raw)
            raise CTImportError(f"truncated file: the pixel data has {actual} bytes, expected {expected} "
                                f"({ds.Rows}x{ds.Columns}x{frames} frames, {ds.BitsAllocated} bits)", path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            arr = ds.pixel_array
    except CTImportError:
        raise
    except Exception as exc:
        detail = " ".join(str(exc).split())              # pydicom lists every plugin's failure on new lines
        raise CTImportError(f"cannot decode the pixel data ({ts.name}): {type(exc).__name__}: {detail}",
                            path) from None
    arr = np.asarray(arr)
    return arr.reshape((-1,) + arr.shape[-2:])


def _read_pixels(frames: list[_Frame], is_ct: bool) -> tuple[np.ndarray, dict]:
    """Rescaled float32 stack (n, rows, cols); padding pixels set to air."""
    n, rows, cols = len(frames), frames[0].rows, frames[0].cols
    stack = np.empty((n, rows, cols), dtype=np.float32)
    padding_mask = np.zeros((n, rows, cols), dtype=bool)
    cache: dict[Path, np.ndarray] = {}
    padding_values = set()
    for k, fr in enumerate(frames):
        pixels = cache.get(fr.path)
        if pixels is None:
            pixels = _decode_file(fr.ds, fr.path)
            if fr.frame is not None:     # keep multi-frame files decoded while their frames are used
                cache = {fr.path: pixels}
        image = pixels[fr.frame or 0]
        if image.shape != (rows, cols):
            raise CTImportError(f"pixel data is {image.shape[0]}x{image.shape[1]}, header says {rows}x{cols}",
                                fr.path)
        pad = fr.ds.get("PixelPaddingValue")
        if pad is not None and not isinstance(pad, (bytes, bytearray)):
            pad = int(pad)
            limit = fr.ds.get("PixelPaddingRangeLimit")
            if limit is not None and not isinstance(limit, (bytes, bytearray)):
                lo, hi = sorted((pad, int(limit)))
                padding_mask[k] = (image >= lo) & (image <= hi)
            else:
                padding_mask[k] = image == pad
            padding_values.add(pad)
        np.multiply(image, fr.slope, out=stack[k], casting="unsafe")
        stack[k] += fr.intercept
    count = int(padding_mask.sum())
    hu = is_ct
    if hu:
        fill, rule = AIR_HU, "air = -1000 HU"
    else:
        valid = stack[~padding_mask]
        fill = float(valid.min()) if valid.size else 0.0
        rule = "series minimum (not CT, no HU air value)"
    if count:
        stack[padding_mask] = fill
    pad_value = sorted(padding_values)[0] if len(padding_values) == 1 else (sorted(padding_values) or None)
    return stack, dict(fill=float(fill), fill_rule=rule, count=count, padding_value=pad_value, hu=hu)


# ----------------------------------------------------------------------------------------------
# Geometry: canonical reorientation and resampling
# ----------------------------------------------------------------------------------------------

def _canonical(data: np.ndarray, axis_dirs: Sequence[np.ndarray], axis_spacing: Sequence[float],
               origin: np.ndarray) -> tuple[np.ndarray, tuple, np.ndarray, np.ndarray]:
    """Flip/transpose a regular axis-aligned grid to ``[z, y, x]`` with k superior, j posterior, i left.

    Parameters
    ----------
    data : ndarray (n0, n1, n2)
    axis_dirs : three unit LPS vectors, the directions of array axes 0, 1, 2
    axis_spacing : the step (mm) along array axes 0, 1, 2
    origin : LPS position of ``data[0, 0, 0]``

    Returns
    -------
    data, spacing (dz, dy, dx), origin, direction (columns: i, j, k)
    """
    dirs = np.array(axis_dirs, dtype=np.float64)
    patient_axis = np.argmax(np.abs(dirs), axis=1)          # patient axis (0=x,1=y,2=z) of each array axis
    if len(set(patient_axis.tolist())) != 3:
        raise ValueError("grid is not axis-aligned")
    origin = np.asarray(origin, dtype=np.float64).copy()
    index = [slice(None)] * 3
    for m in range(3):
        sign = np.sign(dirs[m, patient_axis[m]])
        if sign < 0:                                        # flip this array axis
            origin += (data.shape[m] - 1) * axis_spacing[m] * dirs[m]
            dirs[m] = -dirs[m]
            index[m] = slice(None, None, -1)
    data = data[tuple(index)]
    # array axis that holds patient z, y, x (in that order)
    perm = [int(np.flatnonzero(patient_axis == p)[0]) for p in (2, 1, 0)]
    data = np.ascontiguousarray(data.transpose(perm), dtype=np.float32)
    spacing = tuple(float(axis_spacing[m]) for m in perm)
    direction = np.stack([dirs[perm[2]], dirs[perm[1]], dirs[perm[0]]], axis=1)  # columns i, j, k
    if np.abs(direction - np.eye(3)).max() < _IDENTITY_SNAP:
        direction = np.eye(3)
    return data, spacing, origin, direction


def _output_grid(positions, u, v, n, dr, dc, rows, cols, steps, resample_spacing):
    """Axis-aligned LPS box around all pixel centres and its spacing (x, y, z order)."""
    corners = np.array([[0, 0], [0, cols - 1], [rows - 1, 0], [rows - 1, cols - 1]], dtype=np.float64)
    in_plane = corners[:, 0:1] * dr * v + corners[:, 1:2] * dc * u
    points = positions[:, None, :] + in_plane[None, :, :]
    lo, hi = points.reshape(-1, 3).min(axis=0), points.reshape(-1, 3).max(axis=0)
    if resample_spacing is not None:
        dz, dy, dx = (float(s) for s in resample_spacing)
        spacing_xyz = np.array([dx, dy, dz])
    else:
        # each patient axis takes the spacing of the source axis closest to it
        median_step = float(np.median(steps)) if len(steps) else 1.0
        spacing_xyz = np.full(3, np.nan)
        for vec, sp in ((u, dc), (v, dr), (n, median_step)):
            a = int(np.argmax(np.abs(vec)))
            spacing_xyz[a] = sp if np.isnan(spacing_xyz[a]) else min(spacing_xyz[a], sp)
        spacing_xyz[np.isnan(spacing_xyz)] = min(dr, dc, median_step)
    counts = np.floor((hi - lo) / spacing_xyz + 1e-6).astype(int) + 1
    return lo, spacing_xyz, counts


def _resample_slices(stack: np.ndarray, positions: np.ndarray, u: np.ndarray, v: np.ndarray, dr: float,
                     dc: float, steps: np.ndarray, resample_spacing, fill: float,
                     max_voxels: int = 600_000_000) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Resample parallel slices (any tilt, spacing or orientation) onto a regular LPS grid.

    A point X of the output grid lies between the two source slices that
    bracket its coordinate along the slice normal n; it takes their values at
    its perpendicular foot points ``(X - IPP_k) . (u, v)`` (bilinear in each
    slice) mixed linearly along n. Every source pixel therefore keeps its true
    patient position ``IPP + col*dc*u + row*dr*v``; points outside the slab of
    the source slices get ``fill``.

    Parameters
    ----------
    stack : float32 (nslices, rows, cols), sorted along n
    positions : (nslices, 3) ImagePositionPatient of each slice
    u, v : unit directions of increasing column and row index
    dr, dc : row and column pixel spacing (mm)
    steps : (nslices - 1,) slice steps along n (mm)
    resample_spacing : (dz, dy, dx) or None
    fill : value outside the source slab

    Returns
    -------
    data (nz, ny, nx) float32, origin (3,), spacing (dz, dy, dx), coverage (nz, ny, nx) bool
        ``coverage`` is False where the point lies outside the source slab (filled with ``fill``).
    """
    nslices, rows, cols = stack.shape
    n = np.cross(u, v)
    n /= np.linalg.norm(n)
    lo, sp, counts = _output_grid(positions, u, v, n, dr, dc, rows, cols, steps, resample_spacing)
    total = int(np.prod(counts))
    if total > max_voxels:
        raise CTImportError(f"resampled grid would have {counts[::-1].tolist()} voxels ({total / 1e6:.0f} M); "
                            "pass a coarser resample_spacing=(dz, dy, dx)")
    along = positions @ n
    out = None
    # Fast path: one image axis is a patient axis and the slices do not move along it (the usual
    # gantry tilt: rows along x, tilt in the y-z plane). Then each output line along that axis is
    # a linear mix of whole source rows, so we only interpolate in the other two axes.
    for line_dir, line_sp, other_dir, other_sp, lines_are_rows in ((u, dc, v, dr, True), (v, dr, u, dc, False)):
        a = int(np.argmax(np.abs(line_dir)))
        if (abs(line_dir[a]) > 1 - 1e-9 and np.ptp(positions[:, a]) < 1e-3
                and abs(sp[a] - line_sp) < 1e-9):
            source = stack if lines_are_rows else np.ascontiguousarray(stack.transpose(0, 2, 1))
            if line_dir[a] < 0:
                source = np.ascontiguousarray(source[:, :, ::-1])
            out, coverage = _resample_lines(source, positions, other_dir, other_sp, n, along, lo, sp, counts,
                                            a, fill)
            break
    if out is None:
        out, coverage = _resample_general(stack, positions, u, v, dr, dc, n, along, lo, sp, counts, fill)
    return out, lo, (float(sp[2]), float(sp[1]), float(sp[0])), coverage


def _bracket(delta: np.ndarray, along: np.ndarray):
    """Lower slice index, weight of the upper slice, and the inside-the-slab mask for normal coords."""
    nslices = len(along)
    tol = 1e-4
    inside = (delta >= along[0] - tol) & (delta <= along[-1] + tol)
    frac_index = np.interp(delta, along, np.arange(nslices, dtype=np.float64))
    k0 = np.clip(np.floor(frac_index).astype(np.intp), 0, max(nslices - 2, 0))
    weight = np.clip(frac_index - k0, 0.0, 1.0).astype(np.float32)
    if nslices == 1:
        weight[:] = 0.0
    k1 = np.minimum(k0 + 1, nslices - 1)
    return k0, k1, weight, inside


def _resample_lines(source, positions, other_dir, other_sp, n, along, lo, sp, counts, a, fill):
    """Fast path of :func:`_resample_slices`: output lines along patient axis ``a`` copy source lines."""
    nslices, nlines, line_len = source.shape
    assert line_len == counts[a]
    b, c = [p for p in (2, 1, 0) if p != a]                 # output array order is z, y, x
    xb = lo[b] + sp[b] * np.arange(counts[b])
    xc = lo[c] + sp[c] * np.arange(counts[c])
    grid_b, grid_c = np.meshgrid(xb, xc, indexing="ij")
    delta = (grid_b * n[b] + grid_c * n[c]).ravel()
    proj = (grid_b * other_dir[b] + grid_c * other_dir[c]).ravel()
    k0, k1, weight, inside = _bracket(delta, along)
    offset = positions @ other_dir
    t0 = (proj - offset[k0]) / other_sp                     # line index in slice k0 (fractional)
    t1 = (proj - offset[k1]) / other_sp
    inside &= (t0 > -0.5) & (t0 < nlines - 0.5) & (t1 > -0.5) & (t1 < nlines - 0.5)
    flat = source.reshape(nslices * nlines, line_len)
    out2 = np.empty((delta.size, line_len), dtype=np.float32)
    chunk = max(1, 1_000_000 // line_len)           # ~4 MB per gathered block

    def lerp_lines(k, t, sl):
        t = np.clip(t[sl], 0.0, nlines - 1.0)
        t_lo = np.minimum(np.floor(t).astype(np.intp), max(nlines - 2, 0))
        w = (t - t_lo).astype(np.float32)[:, None]
        base = k[sl] * nlines + t_lo
        lower = flat[base]
        upper = flat[np.minimum(base + 1, flat.shape[0] - 1)]
        upper -= lower
        upper *= w
        lower += upper
        return lower

    for start in range(0, delta.size, chunk):
        sl = slice(start, min(start + chunk, delta.size))
        lower = lerp_lines(k0, t0, sl)
        upper = lerp_lines(k1, t1, sl)
        upper -= lower
        upper *= weight[sl, None]
        lower += upper
        lower[~inside[sl]] = fill
        out2[sl] = lower
    out = out2.reshape(counts[b], counts[c], line_len)
    covered = np.broadcast_to(inside.reshape(counts[b], counts[c], 1), out.shape)
    order = [b, c, a]
    perm = [order.index(p) for p in (2, 1, 0)]
    if perm == [0, 1, 2]:
        return out, np.ascontiguousarray(covered)
    return np.ascontiguousarray(out.transpose(perm)), np.ascontiguousarray(covered.transpose(perm))


def _resample_general(stack, positions, u, v, dr, dc, n, along, lo, sp, counts, fill):
    """General path of :func:`_resample_slices` (double-oblique planes): bilinear lookups per slab."""
    from scipy import ndimage

    nslices, rows, cols = stack.shape
    nx, ny, nz = (int(c) for c in counts)
    out = np.empty((nz, ny, nx), dtype=np.float32)
    coverage = np.empty((nz, ny, nx), dtype=bool)
    xs = lo[0] + sp[0] * np.arange(nx)
    ys = lo[1] + sp[1] * np.arange(ny)
    pu, pv = positions @ u, positions @ v
    planes_per_chunk = max(1, 2_000_000 // (nx * ny))
    gy, gx = np.meshgrid(ys, xs, indexing="ij")
    for z0 in range(0, nz, planes_per_chunk):
        zs = lo[2] + sp[2] * np.arange(z0, min(z0 + planes_per_chunk, nz))
        gz = zs[:, None, None]
        delta = (gx * n[0] + gy * n[1])[None] + gz * n[2]
        xu = (gx * u[0] + gy * u[1])[None] + gz * u[2]
        xv = (gx * v[0] + gy * v[1])[None] + gz * v[2]
        k0, k1, weight, inside = _bracket(delta.ravel(), along)
        values = []
        for k in (k0, k1):
            col = (xu.ravel() - pu[k]) / dc
            row = (xv.ravel() - pv[k]) / dr
            inside &= (col > -0.5) & (col < cols - 0.5) & (row > -0.5) & (row < rows - 0.5)
            coords = np.stack([k.astype(np.float64), row, col])
            values.append(ndimage.map_coordinates(stack, coords, order=1, mode="nearest", output=np.float32))
        lower, upper = values
        upper -= lower
        upper *= weight
        lower += upper
        lower[~inside] = fill
        out[z0:z0 + len(zs)] = lower.reshape(len(zs), ny, nx)
        coverage[z0:z0 + len(zs)] = inside.reshape(len(zs), ny, nx)
    return out, coverage


# ----------------------------------------------------------------------------------------------
# Numbered 2-D images
# ----------------------------------------------------------------------------------------------

def _read_image(f: Path) -> tuple[np.ndarray, bool]:
    """One image as a greyscale numpy array (TIFF through tifffile, others through Pillow), and
    whether it was converted from colour."""
    arr = None
    if _has_ext(f, (".tif", ".tiff")):
        try:
            import tifffile
            arr = tifffile.imread(f)
        except ImportError:
            arr = None
        except Exception as exc:
            raise CTImportError(f"cannot read TIFF image: {type(exc).__name__}: {exc}", f) from None
    if arr is None:
        try:
            from PIL import Image
        except ImportError:
            raise CTImportError("reading images needs Pillow (or tifffile for TIFF)", f) from None
        try:
            with Image.open(f) as im:
                frames = []
                for index in range(getattr(im, "n_frames", 1)):
                    im.seek(index)
                    frame = im
                    if frame.mode in ("P", "PA", "LA", "1"):
                        frame = frame.convert("L")
                    frames.append(np.asarray(frame))
                arr = frames[0] if len(frames) == 1 else np.stack(frames)
        except Exception as exc:
            raise CTImportError(f"cannot read image: {type(exc).__name__}: {exc}", f) from None
    arr = np.asarray(arr)
    if arr.ndim >= 3 and arr.shape[-1] in (3, 4):
        # colour (RGB/RGBA): luminance, ITU-R 601
        return arr[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32), True
    return arr, False


def _load_images(files, label, spacing, axes, oriented, hu, warns) -> CTVolume:
    top = _top_level(files, label)
    images = [f for f in top if _has_ext(f, IMAGE_EXTENSIONS)]
    others = [f for f in top if f not in images]
    if not images:
        raise CTImportError("no image files (TIFF/PNG/JPEG/BMP) found", label if len(files) != 1 else files[0])
    if others:
        warns.append(f"skipped {len(others)} non-image file(s): " + ", ".join(f.name for f in others[:5]))
    images = _numbered_files(images, label, "image", warns)
    slices = []
    colour = False
    shapes: dict[tuple, Path] = {}
    for f in images:
        arr, converted = _read_image(f)
        colour |= converted
        if arr.ndim == 2:
            slices.append(arr)
        elif arr.ndim == 3 and len(images) == 1:
            slices.extend(arr)                      # one multi-page file = the whole volume
        else:
            raise CTImportError(f"expected a 2-D greyscale image, got shape {arr.shape}", f)
        shapes.setdefault(arr.shape[-2:], f)
    if colour:
        warns.append("colour images converted to grey (luminance)")
    if len(shapes) > 1:
        example = "; ".join(f"{s[0]}x{s[1]} in {f.name}" for s, f in shapes.items())
        raise CTImportError(f"mixed image sizes ({example})", label)
    data = np.empty((len(slices),) + slices[0].shape, dtype=np.float32)
    for k, s in enumerate(slices):
        data[k] = s
    del slices
    return _headerless_volume(data, label, "image", spacing, axes, oriented, hu, warns,
                              {"files": len(images), "first_file": images[0].name, "last_file": images[-1].name})


def _headerless_volume(data, label, fmt, spacing, axes, oriented, hu, warns, extra) -> CTVolume:
    """Place a stack without geometry, in file order ``[file, row, column]``, by the orientation
    code's axis directions ``axes = [column, row, slice]`` (default LPS: row -> posterior,
    column -> patient left, later files superior); the origin stays at 0 (no patient position)."""
    if spacing is None:
        spacing = (1.0, 1.0, 1.0)
        warns.append("no spacing given: assumed (dz, dy, dx) = (1, 1, 1) mm; pass spacing=(dz, dy, dx)")
    spacing = _spacing_option(spacing, label)
    col, row, sl = axes
    data, spacing, _, direction = _canonical(data, [sl, row, col], spacing, np.zeros(3))
    code = input_checks.orientation_code(col, row, sl)
    meta = {
        "source": label,
        "format": fmt,
        "modality": "",
        "series_uid": "",
        "series_description": "",
        "original_slice_count": int(data.shape[0]),
        "first_slice": "inferior" if sl[2] > 0 else "superior" if sl[2] < 0 else "",
        "orientation": code,
        "gantry_tilt_deg": 0.0,
        "resampled": False,
        "resample_reason": "",
        "units": "HU" if hu else "stored value (not calibrated HU)",
        "hu_range": (float(data.min()), float(data.max())) if data.size else (0.0, 0.0),
    }
    if not oriented:
        meta["orientation_assumed"] = (f"{code}: row 0 anterior, column 0 patient right, files stacked "
                                       f"{'upward' if sl[2] > 0 else 'downward'}; pass orientation= if not")
    meta.update(extra)
    return CTVolume(data, spacing, np.zeros(3), direction, meta)


def _check_face_side(ct: CTVolume, warns: list[str]) -> None:
    """Warn when the nose lies on the side the (stated or assumed) orientation calls posterior."""
    side = input_checks.face_side(ct.data, ct.spacing) if min(ct.shape) >= 8 else {"side": "unknown"}
    ct.meta["face_side"] = side
    if side["side"] == "high":
        code = ct.meta["orientation"]
        flipped = code.translate(str.maketrans("AP", "PA"))
        said = "orientation" if "orientation_assumed" not in ct.meta else "the default orientation"
        warns.append(f"the face (nose) seems to lie on the side that {said} {code!r} calls posterior "
                     f"({side['high']} of {side['slices']} axial slices show the nose at the back): the head "
                     f"would come out mirrored front-to-back with the seam down the face; if the first rows "
                     f"hold the back of the head pass orientation={flipped!r}")


def _spacing_option(spacing, label) -> tuple[float, float, float]:
    try:
        values = tuple(float(s) for s in spacing)
    except (TypeError, ValueError):
        raise CTImportError(f"spacing must be three numbers (dz, dy, dx) in mm, got {spacing!r}", label) from None
    if len(values) != 3 or not all(math.isfinite(s) and s > 0 for s in values):
        raise CTImportError(f"spacing must be three positive numbers (dz, dy, dx) in mm, got {spacing!r}", label)
    return values


# ----------------------------------------------------------------------------------------------
# Headerless raw
# ----------------------------------------------------------------------------------------------

def _raw_dtype(dtype, byte_order, label) -> np.dtype:
    if dtype is None:
        raise CTImportError("raw data needs dtype, e.g. dtype='>i2' (big-endian int16) or '<u2'", label)
    try:
        dt = np.dtype(dtype)
    except TypeError:
        raise CTImportError(f"unknown dtype {dtype!r}; use a numpy dtype string such as '>i2'", label) from None
    if dt.kind not in "iuf" or dt.itemsize > 8:
        raise CTImportError(f"dtype {dtype!r} is not an integer or float sample type", label)
    if byte_order is not None:
        order = {"big": ">", "little": "<", ">": ">", "<": "<", "be": ">", "le": "<"}.get(str(byte_order).lower())
        if order is None:
            raise CTImportError(f"byte_order must be 'big' or 'little', got {byte_order!r}", label)
        if dt.itemsize > 1:
            dt = dt.newbyteorder(order)
    return dt


def _read_raw_bytes(f: Path) -> tuple[bytes | None, int]:
    """(decompressed bytes, size) of a gzipped raw file; (None, size on disk) of a plain one."""
    if not f.name.lower().endswith(".gz"):
        return None, f.stat().st_size
    try:
        with gzip.open(f, "rb") as fh:
            raw = fh.read()
    except (OSError, EOFError, gzip.BadGzipFile) as exc:
        raise CTImportError(f"cannot decompress the gzipped raw file: {exc}", f) from None
    return raw, len(raw)


def _raw_samples(f: Path, raw: bytes | None, dt: np.dtype, count: int, offset: int) -> np.ndarray:
    if raw is None:
        return np.fromfile(f, dtype=dt, count=count, offset=offset)
    return np.frombuffer(raw, dtype=dt, count=count, offset=offset)


def _load_raw(files, label, shape, dtype, byte_order, header_bytes, spacing, axes, oriented, hu,
              warns) -> CTVolume:
    if shape is None:
        raise CTImportError("raw data needs shape=(ny, nx) for one slice per file or (nz, ny, nx)", label)
    try:
        shape = tuple(int(s) for s in shape)
    except (TypeError, ValueError):
        raise CTImportError(f"shape must be integers (ny, nx) or (nz, ny, nx), got {shape!r}", label) from None
    if len(shape) not in (2, 3) or min(shape) <= 0:
        raise CTImportError(f"shape must be 2 or 3 positive integers, got {shape!r}", label)
    dt = _raw_dtype(dtype, byte_order, label)
    try:
        header_bytes = int(header_bytes)
    except (TypeError, ValueError):
        header_bytes = -1
    if header_bytes < 0:
        raise CTImportError(f"header_bytes must be a non-negative integer, got {header_bytes!r}", label)
    ny, nx = shape[-2:]
    slice_bytes = ny * nx * dt.itemsize

    top = _top_level(files, label)
    candidates = [f for f in top if not _has_ext(f, TEXT_EXTENSIONS)]
    if len(candidates) < len(top):
        skipped = [f.name for f in top if f not in candidates]
        warns.append(f"skipped {len(skipped)} text file(s): {', '.join(skipped[:5])}")
    if not candidates:
        raise CTImportError("no raw data files found", label)
    candidates = _numbered_files(candidates, label, "raw", warns)

    if len(candidates) == 1:
        # one file holding the whole volume
        f = candidates[0]
        raw, size = _read_raw_bytes(f)
        what = "decompressed (gzip) size" if raw is not None else "file size"
        if len(shape) == 3:
            expected = header_bytes + shape[0] * slice_bytes
            if size != expected:
                raise CTImportError(f"{what} {size} bytes does not match shape {shape} x {dt.str} + "
                                    f"{header_bytes} header bytes = {expected} bytes", f)
            nz = shape[0]
        else:
            body = size - header_bytes
            if body <= 0 or body % slice_bytes:
                raise CTImportError(f"{what} {size} bytes is not {header_bytes} header bytes + a whole number "
                                    f"of {ny}x{nx} {dt.str} slices ({slice_bytes} bytes each)", f)
            nz = body // slice_bytes
        data = np.empty((nz, ny, nx), dtype=np.float32)
        data[...] = _raw_samples(f, raw, dt, nz * ny * nx, header_bytes).reshape(nz, ny, nx)
        del raw
    else:
        if len(shape) == 3 and shape[0] != len(candidates):
            raise CTImportError(f"shape {shape} asks for {shape[0]} slices but the folder has "
                                f"{len(candidates)} files", label)
        expected = header_bytes + slice_bytes
        gz = any(f.name.lower().endswith(".gz") for f in candidates)
        for f in candidates if not gz else ():
            size = f.stat().st_size
            if size != expected:
                raise CTImportError(f"file size {size} bytes does not match one {ny}x{nx} {dt.str} slice + "
                                    f"{header_bytes} header bytes = {expected} bytes", f)
        data = np.empty((len(candidates), ny, nx), dtype=np.float32)
        for k, f in enumerate(candidates):
            raw, size = _read_raw_bytes(f)
            if size != expected:
                raise CTImportError(f"{'decompressed (gzip) size' if raw is not None else 'file size'} {size} "
                                    f"bytes does not match one {ny}x{nx} {dt.str} slice + {header_bytes} header "
                                    f"bytes = {expected} bytes", f)
            data[k] = _raw_samples(f, raw, dt, ny * nx, header_bytes).reshape(ny, nx)
    return _headerless_volume(data, label, "raw", spacing, axes, oriented, hu, warns,
                              {"files": len(candidates), "first_file": candidates[0].name,
                               "last_file": candidates[-1].name, "source_dtype": dt.str,
                               "header_bytes": header_bytes})


# ----------------------------------------------------------------------------------------------
# NIfTI-1 (single file .nii / .nii.gz)
# ----------------------------------------------------------------------------------------------

_NIFTI_DTYPES = {2: "u1", 4: "i2", 8: "i4", 16: "f4", 64: "f8", 256: "i1", 512: "u2", 768: "u4",
                 1024: "i8", 1280: "u8"}


def _nifti_affine(hdr: dict) -> np.ndarray:
    """Voxel (i, j, k) -> RAS mm affine from sform (preferred) or qform, else pixdim."""
    if hdr["sform_code"] > 0:
        m = np.eye(4)
        m[:3] = np.array([hdr["srow_x"], hdr["srow_y"], hdr["srow_z"]])
        return m
    pixdim = hdr["pixdim"]
    zooms = np.array(pixdim[1:4], dtype=np.float64)
    zooms[zooms <= 0] = 1.0
    if hdr["qform_code"] > 0:
        b, c, d = hdr["quatern"]
        a = math.sqrt(max(0.0, 1.0 - (b * b + c * c + d * d)))
        rot = np.array([[a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
                        [2 * (b * c + a * d), a * a + c * c - b * b - d * d, 2 * (c * d - a * b)],
                        [2 * (b * d - a * c), 2 * (c * d + a * b), a * a + d * d - c * c - b * b]])
        qfac = -1.0 if pixdim[0] < 0 else 1.0
        m = np.eye(4)
        m[:3, :3] = rot * (zooms * np.array([1.0, 1.0, qfac]))
        m[:3, 3] = hdr["qoffset"]
        return m
    m = np.eye(4)
    m[:3, :3] = np.diag(zooms)
    return m


def _load_nifti(files, label, resample_spacing, warns, hu=False) -> CTVolume:
    f = files[0]
    try:
        opener = gzip.open if f.name.lower().endswith(".gz") else open
        with opener(f, "rb") as fh:
            raw = fh.read()
    except (OSError, EOFError, gzip.BadGzipFile) as exc:
        raise CTImportError(f"cannot read NIfTI file: {exc}", f) from None
    if len(raw) < 348:
        raise CTImportError(f"not a NIfTI-1 file (only {len(raw)} bytes)", f)
    for endian in "<>":
        if struct.unpack(endian + "i", raw[:4])[0] == 348:
            break
    else:
        raise CTImportError("not a NIfTI-1 file (sizeof_hdr is not 348)", f)
    magic = raw[344:348]
    if magic not in (b"n+1\x00", b"ni1\x00"):
        raise CTImportError(f"not a single-file NIfTI-1 image (magic {magic!r})", f)
    if magic == b"ni1\x00":
        raise CTImportError("NIfTI header/image pairs (.hdr/.img) are not supported; convert to .nii", f)
    dim = struct.unpack(endian + "8h", raw[40:56])
    datatype = struct.unpack(endian + "h", raw[70:72])[0]
    pixdim = struct.unpack(endian + "8f", raw[76:108])
    vox_offset = int(struct.unpack(endian + "f", raw[108:112])[0])
    scl_slope, scl_inter = struct.unpack(endian + "2f", raw[112:120])
    qform_code, sform_code = struct.unpack(endian + "2h", raw[252:256])
    hdr = dict(pixdim=pixdim, qform_code=qform_code, sform_code=sform_code,
               quatern=struct.unpack(endian + "3f", raw[256:268]),
               qoffset=struct.unpack(endian + "3f", raw[268:280]),
               srow_x=struct.unpack(endian + "4f", raw[280:296]),
               srow_y=struct.unpack(endian + "4f", raw[296:312]),
               srow_z=struct.unpack(endian + "4f", raw[312:328]))
    description = raw[148:228].split(b"\x00", 1)[0].decode("latin-1").strip()
    ndim = dim[0]
    if not 3 <= ndim <= 7:
        raise CTImportError(f"NIfTI image has {ndim} dimensions; a 3-D volume is needed", f)
    if datatype not in _NIFTI_DTYPES:
        raise CTImportError(f"unsupported NIfTI datatype code {datatype}", f)
    nx, ny, nz = dim[1:4]
    extra = int(np.prod([max(1, d) for d in dim[4:ndim + 1]])) if ndim > 3 else 1
    if extra > 1:
        warns.append(f"NIfTI image has {extra} volumes; loaded the first")
    dt = np.dtype(endian + _NIFTI_DTYPES[datatype])
    count = nx * ny * nz
    if len(raw) < vox_offset + count * dt.itemsize:
        raise CTImportError(f"truncated NIfTI file: {len(raw)} bytes, needs {vox_offset + count * dt.itemsize}", f)
    # stored with i fastest, so C order reads it as [k, j, i]
    data = np.frombuffer(raw, dtype=dt, count=count, offset=vox_offset).reshape(nz, ny, nx).astype(np.float32)
    del raw
    if scl_slope not in (0.0, 1.0) and math.isfinite(scl_slope):
        data *= scl_slope
    if scl_inter != 0.0 and math.isfinite(scl_inter) and scl_slope != 0.0:
        data += scl_inter
    affine = _nifti_affine(hdr)
    affine[:2] *= -1.0                                   # RAS -> LPS
    columns = affine[:3, :3]
    zooms = np.linalg.norm(columns, axis=0)
    if np.any(zooms <= 0):
        raise CTImportError("NIfTI affine has a zero-length axis", f)
    units = columns / zooms                              # unit vectors of i, j, k
    origin = affine[:3, 3]
    aligned = (np.abs(units).max(axis=0).min() > 1 - _ALIGNED_TOL
               and len(set(np.argmax(np.abs(units), axis=0).tolist())) == 3)
    reasons = []
    coverage = None
    if aligned:
        out, spacing, origin_out, direction = _canonical(data, [units[:, 2], units[:, 1], units[:, 0]],
                                                         [zooms[2], zooms[1], zooms[0]], origin)
    else:
        reasons.append("oblique or sheared NIfTI affine")
        # the k planes are parallel slices: resample them like a tilted DICOM stack
        u, v = units[:, 0], units[:, 1]
        positions = origin[None, :] + np.arange(nz)[:, None] * columns[:, 2][None, :]
        n = np.cross(u, v)
        n /= np.linalg.norm(n)
        along = positions @ n
        if along[-1] < along[0]:
            positions, data = positions[::-1], data[::-1]
        steps = np.abs(np.diff(positions @ n))
        out, origin_out, spacing, coverage = _resample_slices(np.ascontiguousarray(data), positions, u, v,
                                                    float(zooms[1]), float(zooms[0]), steps, resample_spacing,
                                                    float(data.min()))
        direction = np.eye(3)
    meta = {
        "source": label,
        "format": "nifti",
        "modality": "",
        "series_uid": "",
        "series_description": description,
        "original_slice_count": int(nz),
        "original_shape": (int(nz), int(ny), int(nx)),
        "gantry_tilt_deg": 0.0,
        "resampled": bool(reasons),
        "resample_reason": "; ".join(reasons),
        "units": "HU" if hu else "stored value x scl_slope + scl_inter (modality unknown; not HU unless the file is CT)",
        "nifti_form": "sform" if sform_code > 0 else "qform" if qform_code > 0 else "pixdim",
        "hu_range": (float(np.nanmin(out)), float(np.nanmax(out))) if np.isfinite(out).any() else (0.0, 0.0),
    }
    lo = meta["hu_range"][0]
    if not hu and lo > -500.0:
        # CT in HU has air near -1000; an MRI (or any uncalibrated scan) has none
        meta["modality"] = "not CT?"
        warns.append(f"this does not look like CT: the values ({lo:g} to {meta['hu_range'][1]:g}) have no air "
                     "near -1000 HU, as an MRI or an uncalibrated scan; PDE Head segments CT, so the outline "
                     "follows whatever is brighter than the background (pass units='HU' if it is CT)")
    return CTVolume(out, spacing, origin_out, direction, meta, coverage=coverage)

