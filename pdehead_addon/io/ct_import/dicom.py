"""DICOM: one series loaded into a CTVolume (sorting along the normal, tilt/uneven checks, decoding).

The headers were read by :mod:`.discovery`; here the chosen series is checked
(one orientation, one size, no duplicate positions), sorted by
ImagePositionPatient along the slice normal, decoded (clear errors naming the
missing decoder package) and rescaled to HU, then either placed as it is
(:func:`.geometry.to_canonical`) or resampled (:func:`.geometry.resample_slices`)
when the grid is sheared by gantry tilt, unevenly spaced or oblique.
"""
from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from ...core.ct_volume import CTVolume
from ...core.errors import CTImportError
from ..input_checks import AIR_HU
from .discovery import (
    DicomFrame,
    DicomSeries,
    float_or,
    ranked_series,
    scan_dicom,
    series_info,
    skip_summary,
)
from .folder_files import import_pydicom
from .geometry import ALIGNED_TOL, resample_limit, resample_slices, to_canonical

# Tolerances of the stack checks (see _stack_geometry; the axis tolerances live in .geometry).
_SHEAR_TOL_PX = 0.1        # in-plane drift of the slice origins (pixels) before the grid counts as sheared
_UNEVEN_TOL = 0.1          # position deviation from a regular step (fraction of the step) -> uneven
_MISSING_FACTOR = 1.5      # a step this many times the median (and the slice thickness) -> missing slice
_MAX_TILT_DEG = 45.0       # CT gantries tilt up to about 30 deg; a stack leaning more has corrupt positions
_OUTLIER_FACTOR = 4.0      # a slice this many median steps off the regular progression is misplaced

# Transfer-syntax name words -> decoder family, first match wins (HTJ2K names also say "2000").
_DECODER_FAMILIES = ((("high-throughput",), "htj2k"), (("htj2k",), "htj2k"), (("2000",), "jpeg2000"),
                     (("jpeg-ls",), "jpeg_ls"), (("lossless", "jpeg"), "jpeg_lossless"), (("jpeg",), "jpeg"),
                     (("rle",), "rle"))
# Pip packages that add pydicom decoders, per transfer-syntax family.
_DECODER_PACKAGES = {
    "jpeg_lossless": "pylibjpeg + pylibjpeg-libjpeg, or python-gdcm",
    "jpeg_ls": "pylibjpeg + pylibjpeg-libjpeg, pyjpegls, or python-gdcm",
    "jpeg2000": "pylibjpeg + pylibjpeg-openjpeg, or python-gdcm (or Pillow built with OpenJPEG)",
    "htj2k": "pylibjpeg + pylibjpeg-openjpeg",
    "jpeg": "Pillow, pylibjpeg + pylibjpeg-libjpeg, or python-gdcm",
    "rle": "pylibjpeg + pylibjpeg-rle (pydicom's own RLE decoder needs numpy)",
}



def load_dicom(files, label, series_uid, resample_spacing, warns) -> CTVolume:
    scan = scan_dicom(files)
    ranked = ranked_series(scan.series)
    chosen = _choose_series(scan, ranked, files, label, series_uid)
    info = series_info(chosen)
    broken = scan.incomplete.get(chosen.uid)
    if broken:
        problem = scan.unreadable[broken[0]]
        problem = problem if problem.startswith("truncated file") else f"truncated file: {problem}"
        raise CTImportError(f"{problem}; it belongs to the series being loaded ({len(broken)} such file(s))",
                            broken[0])
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
    _warn_repaired_headers(chosen, info, warns)

    frames = _consistent_frames(chosen, warns)
    geometry = _stack_geometry(frames, label, warns)
    if len(frames) == 1 and geometry["resample_reasons"]:
        raise CTImportError("a single tilted or oblique slice cannot make a volume (it would be resampled into "
                            "a block of axial slices holding almost no measured voxel: "
                            + "; ".join(geometry["resample_reasons"]) + "); load the whole series",
                            frames[0].path)
    stack, pad_info = _read_pixels(frames, info.is_ct)
    if pad_info["padded_slices"]:
        names = pad_info["padded_slices"]
        warns.append(f"PixelPaddingValue / PixelPaddingRangeLimit mark more than 95 % of {len(names)} slice(s) as "
                     f"padding (set to air): " + ", ".join(names[:5]) + (", ..." if len(names) > 5 else ""))

    reasons = geometry["resample_reasons"]
    if reasons:
        data, origin, spacing, coverage = resample_slices(
            stack, geometry["positions"], geometry["u"], geometry["v"], geometry["dr"], geometry["dc"],
            geometry["steps"], resample_spacing, pad_info["fill"], max_voxels=resample_limit(stack.size),
            label=label)
        direction = np.eye(3)
    else:
        coverage = None
        if resample_spacing is not None:
            warns.append("resample_spacing ignored: the slices are regular and axis-aligned (no resampling)")
        data, spacing, origin, direction = to_canonical(
            stack, [geometry["n"], geometry["v"], geometry["u"]],
            [geometry["step"], geometry["dr"], geometry["dc"]], geometry["positions"][0],
            in_place=stack.dtype == np.float32)
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
        "gantry_tilt_header_deg": float_or(ds.get("GantryDetectorTilt"), None),
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


def _choose_series(scan, ranked, files, label, series_uid) -> DicomSeries:
    """The series to load: ``series_uid``'s, else the best ranked; a clear error when there is none."""
    if not ranked and len(files) == 1 and scan.unreadable:
        raise CTImportError(f"cannot read this DICOM file: {scan.unreadable[files[0]]}", files[0])
    if not ranked:
        details = []
        if scan.unreadable:
            f, err = next(iter(scan.unreadable.items()))
            details.append(f"{len(scan.unreadable)} DICOM-looking file(s) could not be read, e.g. {f}: {err}")
        if scan.skipped:
            details.append("skipped: " + skip_summary(scan.skipped))
        raise CTImportError("no DICOM image series found" + (" (" + "; ".join(details) + ")" if details else ""),
                            label)
    if series_uid is not None:
        chosen = scan.series.get(str(series_uid))
        if chosen is None:
            available = ", ".join(f"{s.uid} [{series_info(s).label}]" for s in ranked)
            raise CTImportError(f"series_uid {series_uid!r} not found; available series: {available}", label)
    else:
        chosen = ranked[0]
    return chosen


def _warn_repaired_headers(chosen: DicomSeries, info, warns: list[str]) -> None:
    """One warning per header repair of the series' frames (``DicomFrame.notes``) and for mixed modalities."""
    notes: dict[str, list] = {}
    for fr in chosen.frames:
        for note in fr.notes:
            notes.setdefault(note, []).append(fr.path.name)
    for note, names in notes.items():
        warns.append(f"{note} in {len(names)} file(s) of the series, e.g. {names[0]}")
    modalities: dict[str, list] = {}
    for fr in chosen.frames:
        modalities.setdefault(str(fr.ds.get("Modality", "") or "(none)"), []).append(fr.path.name)
    if len(modalities) > 1:
        warns.append("mixed Modality within the series: " + "; ".join(
            f"{m} in {len(names)} file(s), e.g. {names[0]}" for m, names in modalities.items())
            + f"; read as {info.modality or 'unknown'}")


def _consistent_frames(series: DicomSeries, warns: list[str]) -> list[DicomFrame]:
    """The frames of the dominant orientation, with exact duplicates removed; mixed sizes are an error."""
    frames = series.frames
    missing = [fr for fr in frames if fr.ipp is None or fr.iop is None or fr.pixel_spacing is None]
    if len(missing) == len(frames):
        raise CTImportError("has no ImagePositionPatient / ImageOrientationPatient / PixelSpacing (or an invalid one: "
                            + _missing_what(missing[0]) + "), so its slices cannot be placed in patient space",
                            missing[0].path)
    if missing:
        warns.append(f"skipped {len(missing)} slice(s) without "
                     f"position/orientation/pixel spacing or with an invalid one ("
                     + _missing_what(missing[0]) + "): " + ", ".join(fr.path.name for fr in missing[:5]))
        missing_ids = {id(fr) for fr in missing}
        frames = [fr for fr in frames if id(fr) not in missing_ids]
    groups: dict[tuple, list[DicomFrame]] = {}
    for fr in frames:
        groups.setdefault(tuple(np.round(fr.iop, 3)), []).append(fr)
    if len(groups) > 1:
        main = max(groups.values(), key=len)
        others = [fr for g in groups.values() if g is not main for fr in g]
        warns.append(f"skipped {len(others)} slice(s) with a different orientation (scout/localizer?): "
                     + ", ".join(fr.path.name for fr in others[:5]))
        frames = main
    # The same file reached twice (copied into two folders): keep one.
    seen: dict[tuple, DicomFrame] = {}
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
        by_size: dict[tuple, DicomFrame] = {}
        for fr in frames:
            by_size.setdefault((fr.rows, fr.cols), fr)
        example = "; ".join(f"{r}x{c} in {fr.path}" for (r, c), fr in by_size.items())
        raise CTImportError(f"mixed image sizes within one series ({example})", frames[0].path.parent)
    spacings = {tuple(np.round(fr.pixel_spacing, 4)) for fr in frames}
    if len(spacings) > 1:
        raise CTImportError(f"mixed pixel spacings within one series: {sorted(spacings)}", frames[0].path.parent)
    return frames


def _missing_what(fr: DicomFrame) -> str:
    """Which placement attribute of a frame is missing or invalid, e.g. "PixelSpacing invalid in 03.dcm"."""
    what = [name for name, value in (("ImagePositionPatient", fr.ipp), ("ImageOrientationPatient", fr.iop),
                                     ("PixelSpacing", fr.pixel_spacing)) if value is None]
    return " and ".join(what) + f" missing or invalid in {fr.path.name}"


def _stack_geometry(frames: list[DicomFrame], label: str, warns: list[str]) -> dict:
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
        def where(fr):
            return os.fspath(fr.path) + (f" frame {fr.frame}" if fr.frame is not None else "")
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
        if tilt_deg > _MAX_TILT_DEG:
            raise CTImportError(f"the slice positions (ImagePositionPatient) drift {tilt_deg:.0f} deg away from the "
                                f"slice normal from {frames[0].path.name} to {frames[-1].path.name}: no gantry "
                                f"tilts more than {_MAX_TILT_DEG:g} deg (corrupt positions?)", label)
        _warn_outliers(frames, positions, n, u, v, warns)
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
    if axes.max(axis=1).min() < 1 - ALIGNED_TOL or len(set(np.argmax(axes, axis=1))) < 3:
        reasons.append("image planes oblique to the patient axes (ImageOrientationPatient "
                       + np.array2string(np.round(iop, 4), separator=",") + ")")
    return dict(u=u, v=v, n=n, dr=float(dr), dc=float(dc), positions=positions, steps=steps, step=float(step),
                tilt_deg=tilt_deg, resample_reasons=reasons)


def _warn_outliers(frames: list[DicomFrame], positions: np.ndarray, n: np.ndarray, u: np.ndarray, v: np.ndarray,
                   warns: list[str]) -> None:
    """Warn about a slice whose position lies far off the others' regular progression (a corrupt or zeroed
    ImagePositionPatient): the stack would be resampled around a gap or a shear that is not in the scan.

    Along the normal and within the plane, each coordinate of the slice origins is fitted linearly in the
    slice index without the worst slice; it is an outlier when it lies more than ``_OUTLIER_FACTOR`` median
    slice steps and ten times the other slices' largest deviation off that line.
    """
    count = len(frames)
    if count < 4:
        return
    index = np.arange(count, dtype=np.float64)
    coords = positions @ np.stack([n, u, v], axis=1)
    step = float(np.median(np.abs(np.diff(coords[:, 0]))))
    for column in coords.T:
        fit = np.polyval(np.polyfit(index, column, 1), index)
        k = int(np.argmax(np.abs(column - fit)))
        keep = np.arange(count) != k
        line = np.polyfit(index[keep], column[keep], 1)
        off = abs(column[k] - np.polyval(line, k))
        rest = np.abs(column[keep] - np.polyval(line, index[keep])).max()
        if step > 0 and off > _OUTLIER_FACTOR * step and off > 10 * max(rest, 1e-3):
            warns.append(f"slice {frames[k].path.name} lies {off:.0f} mm off the regular progression of the other "
                         f"slices' positions (ImagePositionPatient {np.round(frames[k].ipp, 2).tolist()}, median "
                         f"step {step:.3g} mm): a misplaced slice; the stack is resampled around it")
            return


def _transfer_syntax(ds):
    pydicom = import_pydicom()
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
    """The key of :data:`_DECODER_PACKAGES` for a transfer syntax (first row whose words are all in its name)."""
    name = str(ts.name).lower()
    return next((family for words, family in _DECODER_FAMILIES if all(w in name for w in words)), "")


def _decode_file(ds, path: Path) -> np.ndarray:
    """Stored pixel values of one file, shape (frames, rows, cols); clear errors for every failure."""
    ts = _transfer_syntax(ds)
    samples = int(ds.get("SamplesPerPixel", 1) or 1)
    if samples != 1:
        raise CTImportError(f"colour image (SamplesPerPixel={samples}); CT slices must be greyscale", path)
    if ts.is_compressed:
        try:
            from pydicom.pixels import get_decoder  # deferred: pydicom adds ~0.12 s to `import pdehead_addon`
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


#: Hounsfield units a CT stores: -1024 (or -3024 outside the field) to about 3071, 30,000 with extended
#: ranges for metal (Siemens' extended scale: up to 30,710). Far above, the pixels were read with a wrong
#: PixelRepresentation or rescale.
_CT_VALID_HU = (-10000.0, 40000.0)


def _check_ct_range(stack: np.ndarray, frames: list[DicomFrame]) -> None:
    """Refuse CT slices whose rescaled values lie far outside any CT's range, naming the first such file.

    Judged on each slice's 0.5th and 99.5th percentiles (of every 4th pixel): an out-of-field value
    outside the circle (-3024, or -32768 without a PixelPaddingValue) or a few corrupt pixels do not
    count; a whole slice read with a wrong PixelRepresentation or rescale does (its air wraps to the top)."""
    sample = stack[:, ::4, ::4].reshape(len(stack), -1)
    lo, hi = np.percentile(sample, [0.5, 99.5], axis=1)
    # only the top: the bottom holds the out-of-field ring (21 % of a square slice), down to -32768 + intercept
    bad = np.flatnonzero(hi > _CT_VALID_HU[1])
    if bad.size:
        k = int(bad[0])
        fr = frames[k]
        raise CTImportError(f"the pixels range from {lo[k]:.0f} to {hi[k]:.0f} HU after rescaling (a CT holds "
                            f"{_CT_VALID_HU[0]:.0f} to {_CT_VALID_HU[1]:.0f}): wrong PixelRepresentation "
                            f"({fr.ds.get('PixelRepresentation')}), BitsStored or RescaleSlope/Intercept "
                            f"({fr.slope:g}/{fr.intercept:g}); {bad.size} slice(s) affected", fr.path)


def _read_pixels(frames: list[DicomFrame], is_ct: bool) -> tuple[np.ndarray, dict]:
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
    if count > 0.95 * padding_mask.size:
        fr = frames[0]
        raise CTImportError(f"PixelPaddingValue {fr.ds.get('PixelPaddingValue')} / PixelPaddingRangeLimit "
                            f"{fr.ds.get('PixelPaddingRangeLimit')} mark {100 * count / padding_mask.size:.0f} % of "
                            "the pixels as padding (outside the scan): the volume would be empty", fr.path)
    per_slice = padding_mask.mean(axis=(1, 2))
    padded_slices = [frames[k].path.name for k in np.flatnonzero(per_slice > 0.95)]
    hu = is_ct
    if hu:
        _check_ct_range(stack, frames)
    if hu:
        fill, rule = AIR_HU, "air = -1000 HU"
    else:
        valid = stack[~padding_mask]
        fill = float(valid.min()) if valid.size else 0.0
        rule = "series minimum (not CT, no HU air value)"
    if count:
        stack[padding_mask] = fill
    pad_value = sorted(padding_values)[0] if len(padding_values) == 1 else (sorted(padding_values) or None)
    return stack, dict(fill=float(fill), fill_rule=rule, count=count, padding_value=pad_value, hu=hu,
                       padded_slices=padded_slices)
