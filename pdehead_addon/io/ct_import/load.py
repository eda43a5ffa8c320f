"""``load_ct``: one entry point that dispatches to the format readers and checks the values.

The paper (Fig. 1) starts from "a sequence of head cross-sectional slices";
see :mod:`pdehead_addon.io.ct_import` for the axis convention every reader ends in.
"""
from __future__ import annotations

import os
import warnings
from typing import Sequence

import numpy as np

from ...core.ct_volume import CTVolume, downsample_volume
from ...core.errors import CTImportError
from .. import input_checks, scan_evidence
from ..mesh_input import load_skull_mesh  # a skull given as a surface mesh
from .dicom import load_dicom
from .folder_files import detect_format, expand_dicomdir, gather_files, source_label
from .images import load_images
from .nifti import load_nifti
from .raw import load_raw


class CTImportWarning(UserWarning):
    """Something in the input was skipped or looks suspicious, but a volume was loaded."""


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
    first_slice : {"auto", "inferior", "superior"}, optional
        Images and raw data: where the first slice of the numeric order lies. Same as
        ``orientation="LPS"`` / ``"LPI"``. Default (None or "auto", ``defaults.FIRST_SLICE``): inferior,
        unless the head's crown (the end whose cross-section closes to nothing inside the scan,
        :func:`~pdehead_addon.io.input_checks.crown_end`) lies at the first file; then the stack is read
        with the first file superior and ``meta["info"]`` says so (information: the choice is right for a
        correct stack). A given value is used as it is (with a
        warning when the crown then lies at the bottom).
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
        Average blocks of voxels after loading (:func:`~pdehead_addon.core.ct_volume.downsample_volume`),
        for scans too large to segment in memory (``segment_head`` says when).

    Returns
    -------
    CTVolume
        ``direction`` is the identity whenever the source allows it. ``meta``
        holds ``source``, ``format``, ``modality``, ``series_uid``,
        ``series_description``, ``original_slice_count``, ``gantry_tilt_deg``,
        ``resampled``, ``resample_reason``, ``hu_range``, ``units`` and the
        list ``warnings`` (each also issued as a :class:`CTImportWarning`);
        ``info`` (when present) lists the automatic choices made for a correct input (the Auto first slice),
        not issued as warnings; ``non_finite_voxels`` and ``out_of_field`` record repaired voxels.

    Raises
    ------
    CTImportError
        With the offending file or folder and the problem: missing path, empty
        folder, no CT series, mixed image sizes, duplicate slice positions,
        truncated or undecodable files, raw size mismatch, bad options.
    """
    warns: list[str] = []
    fmt = str(format).lower()
    if fmt in ("auto", "mesh") and isinstance(path, (str, os.PathLike)) \
            and os.fspath(path).lower().endswith((".stl", ".ply", ".obj")):
        return load_skull_mesh(path)
    fmt, first_slice, hu_said, axes = _checked_options(path, format, fmt, first_slice, orientation, units)
    # headerless stacks: no first_slice and no orientation = Auto (the documented default, defaults.FIRST_SLICE)
    auto_orientation = first_slice is None and orientation is None
    files, label = gather_files(path)
    if fmt in ("auto", "dicom"):
        files = expand_dicomdir(files, label, warns)

    if fmt == "auto":
        fmt = detect_format(files, label, shape)
    _warn_ignored_options(fmt, spacing, first_slice, orientation, units, series_uid, warns)
    if axes is None:
        axes = input_checks.parse_orientation("LPI" if first_slice == "superior" else "LPS")

    if fmt == "dicom":
        ct = load_dicom(files, label, series_uid, resample_spacing, warns)
    elif fmt == "nifti":
        ct = load_nifti(files, label, resample_spacing, warns, hu_said)
    elif fmt == "image":
        ct = load_images(files, label, spacing, axes, orientation is not None, hu_said, warns)
    else:
        ct = load_raw(files, label, shape, dtype, byte_order, header_bytes, spacing, axes,
                      orientation is not None, hu_said, warns)
    _check_values(ct, label, warns)
    if downsample is not None and np.any(np.asarray(downsample) != 1):
        ct = _downsampled(ct, downsample, label, warns)
    if fmt in ("image", "raw"):
        ct = _check_crown(ct, auto_orientation, warns)
        _check_face_side(ct, warns)

    ct.meta["warnings"] = list(warns)
    for message in warns:
        warnings.warn(f"{label}: {message}", CTImportWarning, stacklevel=2)
    return ct


def _checked_options(path, format, fmt: str, first_slice, orientation, units):
    """``(format, first_slice, units said HU, axes or None)`` from the options, or ``CTImportError``."""
    if fmt in ("images", "tiff", "tif", "png"):
        fmt = "image"
    if fmt not in ("auto", "dicom", "image", "raw", "nifti"):
        raise CTImportError(f"unknown format {format!r}; use 'auto', 'dicom', 'image', 'raw' or 'nifti'",
                            source_label(path))
    if first_slice == "auto":
        first_slice = None
    if first_slice not in (None, "inferior", "superior"):
        raise CTImportError(f"first_slice must be 'auto', 'inferior' or 'superior', got {first_slice!r}",
                            source_label(path))
    if units is not None and str(units).lower() not in ("hu", "stored"):
        raise CTImportError(f"units must be 'HU' or 'stored', got {units!r}", source_label(path))
    hu_said = units is not None and str(units).lower() == "hu"
    axes = None
    if orientation is not None:
        try:
            axes = input_checks.parse_orientation(orientation)
        except ValueError as exc:
            raise CTImportError(str(exc), source_label(path)) from None
        if first_slice is not None and not (abs(axes[2][2]) == 1
                                            and (axes[2][2] > 0) == (first_slice == "inferior")):
            raise CTImportError(f"first_slice={first_slice!r} contradicts orientation={orientation!r} "
                                "(its third letter says where the files go); give only orientation", source_label(path))
    return fmt, first_slice, hu_said, axes


def _warn_ignored_options(fmt: str, spacing, first_slice, orientation, units, series_uid, warns: list[str]) -> None:
    """A warning for each option the detected format does not use."""
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


def _downsampled(ct: CTVolume, downsample, label: str, warns: list[str]) -> CTVolume:
    """Block means of the loaded volume (:func:`~pdehead_addon.core.ct_volume.downsample_volume`), with a warning."""
    try:
        ct = downsample_volume(ct, downsample)
    except (ValueError, TypeError) as exc:
        raise CTImportError(f"downsample: {exc}", label) from None
    warns.append(f"downsampled {ct.meta['shape_before_downsample']} -> {ct.shape} voxels (block means of "
                 f"{' x '.join(map(str, ct.meta['downsampled']))}); spacing now {ct.spacing} mm (dz, dy, dx)")
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



def check_head_scan(ct: CTVolume) -> dict:
    """Refuse a volume that is no head scan (CT or MRI): portraits, smooth shapes, noise.

    :func:`load_ct` reads any volume (the geometry tests feed it ramps); the add-on's import, the command line
    and the batch call this right after it, before anything is segmented or built. The criteria are
    :func:`~pdehead_addon.io.scan_evidence.head_scan_evidence`'s (coherent structure, a sharp outline, anatomy
    inside it); its measures are kept in ``ct.meta["head_scan"]``.

    Returns
    -------
    The measures (correlation, edge_sharpness, interior_detail).

    Raises
    ------
    CTImportError
        "not a head scan (CT or MRI): <what failed>", naming the source.
    """
    if ct.meta.get("format") == "mesh":          # a skull mesh voxelised (load_skull_mesh): checked there
        return {}
    evidence = scan_evidence.head_scan_evidence(ct.data)
    measures = {k: v for k, v in evidence.items() if k != "failed"}
    ct.meta["head_scan"] = measures
    if evidence["failed"]:
        nz, ny, nx = ct.shape
        raise CTImportError(f"not a head scan (CT or MRI): {'; '.join(evidence['failed'])}; {nz} slice(s) of "
                            f"{nx} x {ny} pixels", ct.meta.get("source") or None)
    return measures


def _check_crown(ct: CTVolume, auto: bool, warns: list[str]) -> CTVolume:
    """Headerless stacks: with Auto orientation a crown at the inferior end is put on top (flipped; said as
    information in ``ct.meta["info"]``, naming first_slice); where the crown closes inside the scan, a
    vertex-to-widest-section height
    under ``input_checks.MIN_VERTEX_TO_WIDEST_MM`` is not a human head and is said (partial scans stay
    allowed: no crown, no check)."""
    crown = input_checks.crown_end(ct.data, ct.spacing)
    ct.meta["crown"] = {k: v for k, v in crown.items() if k != "areas"}
    if crown["end"] == "low" and auto:
        # k = 0 is the first file (Auto reads it as inferior): the head is upside down. Flipping k mirrors
        # nothing else: the stack read the other way round is the head the right way up.
        ct = CTVolume(np.ascontiguousarray(ct.data[::-1]), ct.spacing, ct.origin, ct.direction, ct.meta)
        code = ct.meta.get("orientation", "LPS")
        ct.meta["orientation"] = code[:2] + {"S": "I", "I": "S"}.get(code[2], code[2])
        ct.meta["first_slice"] = "superior"
        ct.meta["first_slice_detected"] = True
        ct.meta["crown"]["end"] = "high"
        if "orientation_assumed" in ct.meta:
            ct.meta["orientation_assumed"] = ct.meta["orientation_assumed"].replace("upward", "downward")
        # an automatic choice that is right for a correct stack: information, not a warning (warnings are
        # for what may be wrong)
        ct.meta.setdefault("info", []).append(
            f"the head's crown (the end whose cross-section closes to nothing) is at the first file "
            f"({ct.meta.get('first_file', 'file 1')}): the stack was read with the first file superior "
            f"(the top of the head, orientation {ct.meta['orientation']!r}); pass first_slice='inferior' if the "
            f"first file is the bottom")
    elif crown["end"] == "low":
        said = "first_slice" if "orientation_assumed" in ct.meta else "orientation"
        value = ct.meta.get("orientation") if said == "orientation" else ct.meta.get("first_slice")
        hint = ("first_slice='auto' puts the crown on top" if said == "first_slice" else
                "the third letter of the orientation says where the files go")
        warns.append(f"the head's crown (the end whose cross-section closes to nothing) lies at the bottom as "
                     f"{said}={value!r} places the files: the head may be upside down ({hint})")
    height = crown["vertex_to_widest_mm"]
    if height is not None and height < input_checks.MIN_VERTEX_TO_WIDEST_MM:
        dz = ct.spacing[0]
        warns.append(f"not a human head: from the crown to the widest cross-section is only {height:.0f} mm "
                     f"(a human head has more than {input_checks.MIN_VERTEX_TO_WIDEST_MM:.0f} mm) with a slice "
                     f"step of {dz:g} mm; pass the true spacing=(dz, dy, dx)")
    return ct


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
