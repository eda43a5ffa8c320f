"""What is in a folder: the files, their format, and the DICOM series in them (:func:`list_series`).

:func:`~pdehead_addon.io.ct_import.load_ct` starts here: the files of a folder
(recursively), a single file or a list, DICOMDIR file-sets expanded to the
files they index, the format detected (DICOM by its preamble or a leading
group 0002/0008 tag, images and NIfTI by extension), and for DICOM every
image series found by reading the headers only (pixel data deferred). The files and their format are
:mod:`.folder_files`; this module reads the DICOM headers.
"""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .folder_files import (
    IMAGE_EXTENSIONS,
    NIFTI_EXTENSIONS,
    TEXT_EXTENSIONS,
    expand_dicomdir,
    gather_files,
    has_ext,
    import_pydicom,
    looks_like_dicom,
)
from .geometry import ALIGNED_TOL
from .limits import BadHeader, TruncatedPixels, check_image_header

DICOMDIR_SOP_CLASS = "1.2.840.10008.1.3.10"


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
    files, label = gather_files(path)
    files = expand_dicomdir(files, label, [])
    scan = scan_dicom(files)
    return [series_info(s) for s in ranked_series(scan.series)]


def series_of_file(path: str | os.PathLike) -> str | None:
    """The SeriesInstanceUID of one single-frame DICOM file, so that choosing one file of a series
    loads the whole series from its folder (``load_ct(folder, series_uid=...)``); None for anything
    else (not DICOM, unreadable, no UID, or a multi-frame file that is a volume by itself)."""
    f = Path(path)
    if not f.is_file() or has_ext(f, IMAGE_EXTENSIONS + NIFTI_EXTENSIONS) or not looks_like_dicom(f):
        return None
    try:
        ds = _read_dicom_header(f)
    except Exception:  # noqa: BLE001 - not readable as DICOM: the loader will say why
        return None
    uid = str(ds.get("SeriesInstanceUID", "") or "").strip()
    try:
        frames = int(ds.get("NumberOfFrames", 1) or 1)
    except (TypeError, ValueError):
        frames = 1
    return uid if uid and frames <= 1 else None


# ----------------------------------------------------------------------------------------------
# DICOM: scanning headers
# ----------------------------------------------------------------------------------------------

@dataclass(eq=False)
class DicomFrame:
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
    notes: tuple = ()            # what was repaired in this frame's header (said in a warning)


@dataclass
class DicomSeries:
    uid: str
    frames: list[DicomFrame] = field(default_factory=list)
    localizers: int = 0

    @property
    def first(self) -> Any:
        return self.frames[0].ds


@dataclass
class _Scan:
    series: dict[str, DicomSeries]
    skipped: dict[str, list[Path]]      # reason -> files
    unreadable: dict[Path, str]         # DICOM-looking files that failed to parse -> error
    incomplete: dict[str, list[Path]]   # series uid -> image files cut off before their pixel data


_HEADER_KEYWORDS = ("SOPClassUID", "SeriesInstanceUID", "Rows", "Columns", "ImagePositionPatient",
                    "ImageOrientationPatient", "PixelSpacing", "SliceThickness", "RescaleSlope", "RescaleIntercept",
                    "NumberOfFrames", "SOPInstanceUID", "Modality", "ImageType", "SeriesNumber", "SeriesDescription",
                    "StudyDescription", "Manufacturer", "PatientPosition", "GantryDetectorTilt", "SamplesPerPixel",
                    "BitsAllocated", "BitsStored", "PixelRepresentation", "PhotometricInterpretation",
                    "PixelPaddingValue", "PixelPaddingRangeLimit", "SharedFunctionalGroupsSequence",
                    "PerFrameFunctionalGroupsSequence")


def _read_dicom_header(f: Path):
    """The dataset with pixel data deferred (read lazily from the file)."""
    pydicom = import_pydicom()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = pydicom.dcmread(f, defer_size=4096, force=True)
        # Touch the tags used later now, so that a header broken by truncation or a flipped byte (an
        # unknown VR, a value of the wrong type) fails here, inside the caller's try.
        for keyword in _HEADER_KEYWORDS:
            ds.get(keyword)
        meta = getattr(ds, "file_meta", None)
        if meta is not None:
            meta.get("TransferSyntaxUID")
            meta.get("MediaStorageSOPClassUID")
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


def float_or(value, default):
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


def _unit_pairs(iop: np.ndarray | None) -> np.ndarray | None:
    """ImageOrientationPatient with two unit, perpendicular direction cosines, else None."""
    if iop is None:
        return None
    a, b = iop[:3], iop[3:]
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if not (0.9 < na < 1.1 and 0.9 < nb < 1.1) or abs(a @ b) / (na * nb) > 0.05:
        return None
    return iop


def _scalar_or_note(value, default: float, keyword: str, notes: list[str], required: bool) -> float:
    """A finite number, else ``default`` with a note saying why (missing: only when ``required``)."""
    if value is None or value == "":
        if required:
            notes.append(f"{keyword} missing (taken as {default:g})")
        return default
    out = float_or(value, None)
    if out is None:
        notes.append(f"{keyword} {value!r} is not a finite number (taken as {default:g})")
        return default
    return out


def _frames_of(f: Path, ds, nframes: int = 1) -> list[DicomFrame]:
    rows, cols = int(ds.get("Rows", 0) or 0), int(ds.get("Columns", 0) or 0)
    sop_uid = str(ds.get("SOPInstanceUID", f))
    is_ct = str(ds.get("Modality", "") or "").upper() == "CT"
    shared_seq = ds.get("SharedFunctionalGroupsSequence")
    shared = shared_seq[0] if shared_seq else None
    per_frame = ds.get("PerFrameFunctionalGroupsSequence")
    frames = []
    for index in range(nframes):
        notes: list[str] = []
        groups = [per_frame[index] if per_frame is not None and index < len(per_frame) else None, shared]
        ipp = _floats(_group_value(groups, "PlanePositionSequence", "ImagePositionPatient")
                      or ds.get("ImagePositionPatient"), 3)
        if ipp is not None and np.abs(ipp).max() > 1e5:
            notes.append(f"ImagePositionPatient {np.round(ipp, 1).tolist()} lies more than 100 m away")
            ipp = None
        iop = _unit_pairs(_floats(_group_value(groups, "PlaneOrientationSequence", "ImageOrientationPatient")
                                  or ds.get("ImageOrientationPatient"), 6))
        ps = _floats(_group_value(groups, "PixelMeasuresSequence", "PixelSpacing") or ds.get("PixelSpacing"), 2)
        if ps is not None and not np.all((ps >= 0.01) & (ps <= 100.0)):
            notes.append(f"PixelSpacing {ps.tolist()} mm is outside 0.01 to 100 mm")
            ps = None
        thickness_value = _group_value(groups, "PixelMeasuresSequence", "SliceThickness") or ds.get("SliceThickness")
        thickness = float_or(thickness_value, None)
        if thickness_value not in (None, "") and not (thickness is not None and 0 < thickness <= 100):
            notes.append(f"SliceThickness {thickness_value!r} is not a size of 0 to 100 mm (ignored)")
            thickness = None
        slope_value = _group_value(groups, "PixelValueTransformationSequence", "RescaleSlope")
        slope_value = ds.get("RescaleSlope") if slope_value is None else slope_value
        intercept_value = _group_value(groups, "PixelValueTransformationSequence", "RescaleIntercept")
        intercept_value = ds.get("RescaleIntercept") if intercept_value is None else intercept_value
        slope = _scalar_or_note(slope_value, 1.0, "RescaleSlope", notes, is_ct)
        intercept = _scalar_or_note(intercept_value, 0.0, "RescaleIntercept", notes, is_ct)
        if slope == 0:
            notes.append("RescaleSlope 0 (taken as 1)")
            slope = 1.0
        if slope < 0 and is_ct:
            raise BadHeader(f"RescaleSlope {slope:g} is negative: a CT's values would come out inverted")
        if abs(slope) > 1e4 or abs(intercept) > 1e5:
            raise BadHeader(f"RescaleSlope {slope:g} / RescaleIntercept {intercept:g}: no CT or MR scaling is this "
                            "large (a corrupt header)")
        frames.append(DicomFrame(f, index if nframes > 1 else None, ds, ipp, iop,
                             None if ps is None else (float(ps[0]), float(ps[1])),
                             thickness if thickness and thickness > 0 else None,
                             slope, intercept, rows, cols, sop_uid, tuple(notes)))
    return frames


def scan_dicom(files: list[Path]) -> _Scan:
    series: dict[str, DicomSeries] = {}
    skipped: dict[str, list[Path]] = {}
    unreadable: dict[Path, str] = {}
    incomplete: dict[str, list[Path]] = {}

    def skip(reason: str, f: Path) -> None:
        skipped.setdefault(reason, []).append(f)

    for f in files:
        if f.name.upper() == "DICOMDIR":
            skip("DICOMDIR", f)
            continue
        if has_ext(f, IMAGE_EXTENSIONS + NIFTI_EXTENSIONS + TEXT_EXTENSIONS):
            skip("not DICOM", f)
            continue
        try:
            with open(f, "rb") as fh:
                empty = not fh.read(1)
        except OSError as exc:
            unreadable[f] = f"cannot open it: {exc.strerror or exc}"
            continue
        if empty:
            unreadable[f] = "empty file (0 bytes)"
            continue
        if not looks_like_dicom(f):
            skip("not DICOM", f)
            continue
        try:
            ds = _read_dicom_header(f)
            _add_file(f, ds, series, skip, unreadable, incomplete)
        except TruncatedPixels as exc:
            unreadable[f] = f"truncated file: {exc}"
            incomplete.setdefault(str(ds.get("SeriesInstanceUID", "")), []).append(f)
        except BadHeader as exc:
            unreadable[f] = str(exc)
        except Exception as exc:  # any parse failure of a DICOM-looking file
            unreadable[f] = f"{type(exc).__name__}: {exc}"
    series = {uid: s for uid, s in series.items() if s.frames}
    return _Scan(series, skipped, unreadable, incomplete)


def _add_file(f: Path, ds, series, skip, unreadable, incomplete) -> None:
    """Put one file's frames into its series (or skip it, saying why)."""
    media_class = str(getattr(ds, "file_meta", {}).get("MediaStorageSOPClassUID", ""))
    if media_class == DICOMDIR_SOP_CLASS or str(ds.get("SOPClassUID", "")) == DICOMDIR_SOP_CLASS:
        if "PixelData" in ds:
            raise BadHeader("its SOP class says DICOMDIR (a file-set index) but it holds pixel data")
        skip("DICOMDIR", f)
        return
    if "PixelData" not in ds:
        sop_class = ds.get("SOPClassUID")
        if sop_class is not None and "image storage" in str(getattr(sop_class, "name", "")).lower():
            # an image object without its pixels: the file was cut off inside the header
            incomplete.setdefault(str(ds.get("SeriesInstanceUID", "")), []).append(f)
            unreadable[f] = f"{sop_class.name} object without pixel data (file truncated?)"
        else:
            skip("no pixel data (not an image)", f)
        return
    nframes = check_image_header(f, ds)
    uid = str(ds.get("SeriesInstanceUID", "") or "(no SeriesInstanceUID)")
    image_type = ds.get("ImageType") or []
    if isinstance(image_type, str):
        image_type = image_type.split("\\")
    if "LOCALIZER" in {str(t).strip().upper() for t in image_type}:
        series.setdefault(uid, DicomSeries(uid)).localizers += 1
        skip("localizer", f)
        return
    frames = _frames_of(f, ds, nframes)
    series.setdefault(uid, DicomSeries(uid)).frames.extend(frames)


def _orientation_name(iop: np.ndarray | None) -> str:
    if iop is None:
        return "unknown"
    normal = np.cross(iop[:3], iop[3:])
    norm = np.linalg.norm(normal)
    if norm < 1e-6:
        return "unknown"
    normal = np.abs(normal / norm)
    axis = int(np.argmax(normal))
    if normal[axis] < 1 - ALIGNED_TOL:
        return "oblique"
    return ("sagittal", "coronal", "axial")[axis]


def series_info(s: DicomSeries) -> SeriesInfo:
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


def ranked_series(series: dict[str, DicomSeries]) -> list[DicomSeries]:
    def key(s: DicomSeries):
        info_number = s.first.get("SeriesNumber")
        try:
            number = int(info_number)
        except (TypeError, ValueError):
            number = 1 << 30
        return (str(s.first.get("Modality", "")).upper() != "CT", -len(s.frames), number, s.uid)
    return sorted(series.values(), key=key)


def skip_summary(skipped: dict[str, list[Path]]) -> str:
    parts = []
    for reason, fs in skipped.items():
        names = ", ".join(f.name for f in fs[:3]) + (", ..." if len(fs) > 3 else "")
        parts.append(f"{len(fs)} {reason} ({names})")
    return "; ".join(parts)
