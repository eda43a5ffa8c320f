"""Write CT volumes as DICOM CT series (one file per slice) with pydicom.

Two entry points:

* :func:`write_dicom_series` writes a :class:`CTVolume` as it is: slice ``data[k]``
  becomes one image whose rows follow the volume's j axis and columns its i axis.
  Works for axis-aligned volumes and for sheared (gantry-tilted) ones whose k axis
  is not normal to the image plane.
* :func:`write_phantom_series` samples the analytic phantom of :mod:`.phantom` on
  arbitrary oblique planes at arbitrary (uneven) positions, mimicking the real
  GE HiSpeed series in ``ct_head_ge_tilt_dicom`` (gantry tilt, IPP x/y fixed,
  z stepping unevenly), so the CT importer can be tested against exact truth.

Both produce CT Image Storage files in Explicit VR Little Endian with a 128-byte
preamble and file meta information, int16 pixels (PixelRepresentation 1) and a
RescaleSlope/RescaleIntercept mapping stored values to HU:
``HU = stored * slope + intercept``.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pydicom
from pydicom.dataset import FileDataset, FileMetaDataset
from pydicom.uid import PYDICOM_IMPLEMENTATION_UID, CTImageStorage, ExplicitVRLittleEndian, generate_uid

from ..core.ct_volume import CTVolume
from ..core.errors import PDEHeadError

_INT16_MIN, _INT16_MAX = -32768, 32767


def _prepare_folder(folder: str | os.PathLike, file_prefix: str, overwrite: bool) -> Path:
    """Create ``folder`` (parents included); refuse a non-empty one unless ``overwrite``.

    With ``overwrite=True`` the files this writer would name (``<prefix>*.dcm``)
    are removed first, so no stale slice of an earlier, longer series survives;
    any other file in the folder is left alone.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise PDEHeadError(f"{folder}: exists and is not a folder; cannot write a DICOM series there")
    if folder.is_dir():
        entries = sorted(folder.iterdir())
        if entries and not overwrite:
            raise PDEHeadError(
                f"{folder}: folder is not empty ({len(entries)} entries, e.g. '{entries[0].name}'); "
                "refusing to write a DICOM series into it (pass overwrite=True to replace "
                f"'{file_prefix}*.dcm' files)")
        for entry in entries:
            if entry.is_file() and entry.name.startswith(file_prefix) and entry.suffix.lower() == ".dcm":
                entry.unlink()
    else:
        try:
            folder.mkdir(parents=True)
        except OSError as exc:
            raise PDEHeadError(f"{folder}: cannot create the output folder ({exc.strerror or exc})") from None
    return folder


def _uid(uid_seed: Any, *parts: Any) -> str:
    """A DICOM UID: random when ``uid_seed`` is None, else a deterministic hash of seed and parts."""
    if uid_seed is None:
        return str(generate_uid())
    return str(generate_uid(entropy_srcs=[repr(uid_seed), *[str(p) for p in parts]]))


def _ds_str(value: float, digits: int = 6) -> str:
    """A DS (decimal string) value of at most 16 characters."""
    text = f"{float(value):.{digits}f}".rstrip("0").rstrip(".")
    if text in ("-0", ""):
        text = "0"
    while len(text) > 16 and digits > 0:
        digits -= 1
        text = f"{float(value):.{digits}f}"
    return text


def _tilt_from_axes(row_dir: np.ndarray, col_dir: np.ndarray) -> float:
    """Gantry tilt (degrees) of an image plane whose rows run along patient x.

    For the GE convention IOP = [1, 0, 0, 0, cos t, -sin t] this returns +t.
    Planes whose row direction is not patient x report 0 (no gantry tilt meaning).
    """
    if abs(abs(row_dir[0]) - 1.0) > 1e-6:
        return 0.0
    return float(np.degrees(np.arctan2(-col_dir[2], col_dir[1])))


def _hu_to_stored(image_hu: np.ndarray, slope: float, intercept: float,
                  pixel_padding_value: int | None, where: str) -> np.ndarray:
    """HU -> int16 stored values ``round((HU - intercept) / slope)``, clipped to int16.

    Non-finite HU are written as ``pixel_padding_value`` (error if that is None).
    """
    image_hu = np.asarray(image_hu, dtype=np.float64)
    bad = ~np.isfinite(image_hu)
    if bad.any() and pixel_padding_value is None:
        raise PDEHeadError(f"{where}: {int(bad.sum())} non-finite voxel values; give pixel_padding_value "
                           "to write them as padding")
    stored = np.rint((np.where(bad, 0.0, image_hu) - intercept) / slope)
    stored = np.clip(stored, _INT16_MIN, _INT16_MAX).astype(np.int16)
    if bad.any():
        stored[bad] = np.int16(pixel_padding_value)
    return stored


def _write_slices(folder: Path, images_hu: Sequence[np.ndarray], positions: np.ndarray,
                  row_dir: np.ndarray, col_dir: np.ndarray, pixel_spacing: tuple[float, float],
                  thicknesses: Sequence[float], *, series_description: str, patient_name: str,
                  patient_id: str, study_description: str, series_number: int, gantry_tilt: float,
                  rescale_slope: float, rescale_intercept: float, window_center: float,
                  window_width: float, pixel_padding_value: int | None, uid_seed: Any,
                  file_prefix: str, extra_tags: dict[str, Any] | None) -> list[Path]:
    """Write one CT Image Storage file per 2-D image (the common back end).

    ``positions[n]`` is ImagePositionPatient (centre of the first transmitted pixel),
    ``row_dir``/``col_dir`` the IOP direction cosines (along a row / down a column),
    ``pixel_spacing`` = (row spacing, column spacing) = (between rows, between columns).
    """
    row_dir = np.asarray(row_dir, float)
    col_dir = np.asarray(col_dir, float)
    normal = np.cross(row_dir, col_dir)
    study_uid = _uid(uid_seed, "study")
    series_uid = _uid(uid_seed, "series", series_number, series_description)
    frame_uid = _uid(uid_seed, "frame-of-reference")
    iop = [_ds_str(v, 7) for v in (*row_dir, *col_dir)]
    paths: list[Path] = []
    for n, (image, ipp, thickness) in enumerate(zip(images_hu, positions, thicknesses)):
        image = np.asarray(image)
        path = folder / f"{file_prefix}{n + 1:04d}.dcm"
        stored = _hu_to_stored(image, rescale_slope, rescale_intercept, pixel_padding_value, str(path))
        sop_uid = _uid(uid_seed, "sop", series_uid, n)

        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = CTImageStorage
        meta.MediaStorageSOPInstanceUID = sop_uid
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        meta.ImplementationClassUID = PYDICOM_IMPLEMENTATION_UID
        meta.ImplementationVersionName = f"PDEHEAD_{pydicom.__version__}"[:16]

        ds = FileDataset(str(path), {}, file_meta=meta, preamble=b"\0" * 128)
        ds.SpecificCharacterSet = "ISO_IR 100"
        ds.ImageType = ["DERIVED", "SECONDARY", "AXIAL"]
        ds.SOPClassUID = CTImageStorage
        ds.SOPInstanceUID = sop_uid
        ds.StudyDate = ""
        ds.SeriesDate = ""
        ds.StudyTime = ""
        ds.SeriesTime = ""
        ds.AccessionNumber = ""
        ds.Modality = "CT"
        ds.Manufacturer = "PDE Head"
        ds.ReferringPhysicianName = ""
        ds.StudyDescription = study_description
        ds.SeriesDescription = series_description
        ds.PatientName = patient_name
        ds.PatientID = patient_id
        ds.PatientBirthDate = ""
        ds.PatientSex = ""
        ds.BodyPartExamined = "HEAD"
        ds.SliceThickness = _ds_str(thickness)
        ds.KVP = ""
        ds.GantryDetectorTilt = _ds_str(gantry_tilt, 4)
        ds.PatientPosition = "HFS"
        ds.StudyInstanceUID = study_uid
        ds.SeriesInstanceUID = series_uid
        ds.StudyID = ""
        ds.SeriesNumber = int(series_number)
        ds.AcquisitionNumber = 1
        ds.InstanceNumber = n + 1
        ds.ImagePositionPatient = [_ds_str(v) for v in ipp]
        ds.ImageOrientationPatient = iop
        ds.FrameOfReferenceUID = frame_uid
        ds.PositionReferenceIndicator = ""
        ds.SliceLocation = _ds_str(float(np.dot(ipp, normal)))
        ds.SamplesPerPixel = 1
        ds.PhotometricInterpretation = "MONOCHROME2"
        ds.Rows, ds.Columns = int(stored.shape[0]), int(stored.shape[1])
        ds.PixelSpacing = [_ds_str(pixel_spacing[0]), _ds_str(pixel_spacing[1])]
        ds.BitsAllocated = 16
        ds.BitsStored = 16
        ds.HighBit = 15
        ds.PixelRepresentation = 1
        if pixel_padding_value is not None:
            ds.PixelPaddingValue = int(pixel_padding_value)  # SS because PixelRepresentation is 1
        ds.WindowCenter = _ds_str(window_center)
        ds.WindowWidth = _ds_str(window_width)
        ds.RescaleIntercept = _ds_str(rescale_intercept)
        ds.RescaleSlope = _ds_str(rescale_slope)
        ds.RescaleType = "HU"
        for keyword, value in (extra_tags or {}).items():
            setattr(ds, keyword, value)
        ds.PixelData = np.ascontiguousarray(stored.astype("<i2")).tobytes()
        try:
            ds.save_as(path, enforce_file_format=True)
        except OSError as exc:
            raise PDEHeadError(f"{path}: cannot write DICOM file ({exc.strerror or exc})") from None
        paths.append(path)
    return paths


def write_dicom_series(ct: CTVolume, folder: str | os.PathLike, *,
                       series_description: str = "PDE Head CT",
                       patient_name: str = "PDE^Phantom",
                       patient_id: str = "PDEHEAD0001",
                       study_description: str = "HEAD",
                       series_number: int = 1,
                       gantry_tilt: float | None = None,
                       slice_thickness: float | None = None,
                       rescale_slope: float = 1.0,
                       rescale_intercept: float = -1024.0,
                       window_center: float = 40.0,
                       window_width: float = 400.0,
                       pixel_padding_value: int | None = None,
                       uid_seed: Any = None,
                       file_prefix: str = "CT",
                       extra_tags: dict[str, Any] | None = None,
                       overwrite: bool = False) -> list[Path]:
    """Write a CT volume as a DICOM CT series, one file per axial slice ``data[k]``.

    Image ``k`` has ImagePositionPatient ``origin + direction[:, 2] * k * dz``,
    ImageOrientationPatient ``[direction[:, 0], direction[:, 1]]`` (rows run along
    i, columns along j), PixelSpacing ``[dy, dx]``, InstanceNumber ``k + 1`` and
    SliceLocation = IPP . normal. A sheared volume (k axis not normal to the
    image plane, e.g. a gantry-tilted acquisition) is written as such: IPP then
    steps along the k axis, exactly as real tilted scanners do.

    Parameters
    ----------
    ct : CTVolume
        Volume in HU. Its i and j directions must be orthonormal.
    folder : path
        Output folder, created if missing. Must be empty unless ``overwrite``.
    series_description, patient_name, patient_id, study_description, series_number
        Written to the corresponding tags.
    gantry_tilt : float, optional
        GantryDetectorTilt in degrees. Default: derived from the image plane
        (``atan2(-col_z, col_y)`` when rows run along patient x), i.e. 0 for an
        axis-aligned volume.
    slice_thickness : float, optional
        SliceThickness tag; default the slice step measured along the normal.
    rescale_slope, rescale_intercept : float
        ``HU = stored * slope + intercept``; stored values are
        ``round((HU - intercept) / slope)`` clipped to int16, so the round-trip
        error is at most ``slope / 2`` HU inside the representable range.
    window_center, window_width : float
        Default display window (HU).
    pixel_padding_value : int, optional
        Stored value written for non-finite voxels (and the PixelPaddingValue tag).
        If None, non-finite voxels are an error.
    uid_seed : any, optional
        If given, all UIDs are derived deterministically from it (same seed, same
        files byte for byte); if None they are random (``generate_uid``).
    file_prefix : str
        Files are named ``<prefix>0001.dcm``, ``<prefix>0002.dcm``, ...
    extra_tags : dict, optional
        Additional ``{keyword: value}`` data elements (e.g. ``{"KVP": "120"}``).
    overwrite : bool
        Allow a non-empty folder; existing ``<prefix>*.dcm`` files are removed first.

    Returns
    -------
    list of Path
        The written files in InstanceNumber order.

    Raises
    ------
    PDEHeadError
        Non-empty folder without ``overwrite``, non-orthonormal image axes,
        non-finite voxels without padding value, unwritable folder.
    """
    direction = np.asarray(ct.direction, float)
    row_dir, col_dir, k_dir = direction[:, 0], direction[:, 1], direction[:, 2]
    if (abs(np.linalg.norm(row_dir) - 1) > 1e-6 or abs(np.linalg.norm(col_dir) - 1) > 1e-6
            or abs(np.dot(row_dir, col_dir)) > 1e-6):
        raise PDEHeadError(f"{folder}: the volume's i and j directions are not orthonormal "
                           f"({row_dir}, {col_dir}); a DICOM image plane needs orthonormal axes")
    normal = np.cross(row_dir, col_dir)
    dz, dy, dx = ct.spacing
    normal_step = dz * float(np.dot(k_dir, normal))
    if abs(normal_step) < 1e-9:
        raise PDEHeadError(f"{folder}: the volume's k axis lies in the image plane; cannot stack slices")
    folder = _prepare_folder(folder, file_prefix, overwrite)
    nz = ct.shape[0]
    positions = ct.origin[None, :] + np.arange(nz)[:, None] * dz * k_dir[None, :]
    thickness = abs(normal_step) if slice_thickness is None else float(slice_thickness)
    tilt = _tilt_from_axes(row_dir, col_dir) if gantry_tilt is None else float(gantry_tilt)
    return _write_slices(folder, ct.data, positions, row_dir, col_dir, (dy, dx), [thickness] * nz,
                         series_description=series_description, patient_name=patient_name,
                         patient_id=patient_id, study_description=study_description,
                         series_number=series_number, gantry_tilt=tilt, rescale_slope=rescale_slope,
                         rescale_intercept=rescale_intercept, window_center=window_center,
                         window_width=window_width, pixel_padding_value=pixel_padding_value,
                         uid_seed=uid_seed, file_prefix=file_prefix, extra_tags=extra_tags)


# The real GE series (ct_head_ge_tilt_dicom): steps along the slice normal, in mm.
GE_LIKE_NORMAL_STEPS: tuple[float, ...] = (4.0,) * 13 + (1.08,) + (7.0,) * 13


def tilted_plane_axes(gantry_tilt: float) -> tuple[np.ndarray, np.ndarray]:
    """Row and column direction cosines of a gantry-tilted axial plane (GE convention).

    ``row = (1, 0, 0)``, ``col = (0, cos t, -sin t)``: rows still run to the
    patient's left, going down a column moves posterior and (for t > 0) inferior.
    """
    t = math.radians(gantry_tilt)
    return np.array([1.0, 0.0, 0.0]), np.array([0.0, math.cos(t), -math.sin(t)])


def write_phantom_series(phantom: Any, folder: str | os.PathLike, *,
                         gantry_tilt: float = 18.5,
                         slice_positions: Sequence[float] | None = None,
                         slice_thickness: float | Sequence[float] | None = None,
                         rows: int = 256, columns: int = 256,
                         pixel_spacing: tuple[float, float] = (1.0, 1.0),
                         image_center_xy: tuple[float, float] | None = None,
                         fov_diameter: float | None = None,
                         pixel_padding_value: int = -1500,
                         noise: bool = True, noise_seed: int = 0,
                         series_description: str = "PDE Head phantom, tilted",
                         patient_name: str = "PDE^Phantom",
                         patient_id: str = "PDEHEAD0001",
                         study_description: str = "HEAD",
                         series_number: int = 2,
                         rescale_slope: float = 1.0,
                         rescale_intercept: float = 0.0,
                         window_center: float = 40.0,
                         window_width: float = 400.0,
                         uid_seed: Any = None,
                         file_prefix: str = "CT",
                         extra_tags: dict[str, Any] | None = None,
                         overwrite: bool = False) -> list[Path]:
    """Sample the analytic phantom on oblique planes and write them as a DICOM series.

    Mimics the real GE HiSpeed series: ImageOrientationPatient
    ``[1, 0, 0, 0, cos t, -sin t]``, ImagePositionPatient x and y fixed, only z
    changing (so the slice grid is sheared, not stacked along the normal),
    GantryDetectorTilt ``t``, uneven steps and RescaleIntercept 0 (stored = HU).
    Pixel ``(r, c)`` of image ``n`` is the analytic phantom
    (:meth:`Phantom.sample_hu`) at ``IPP_n + c * dc * row_dir + r * dr * col_dir``:
    the exact truth a DICOM importer must reproduce. Each image is sampled on its
    plane (SliceThickness is metadata only, no slab averaging).

    Parameters
    ----------
    phantom : Phantom
        From :func:`make_phantom`.
    folder : path
        Output folder (created; must be empty unless ``overwrite``).
    gantry_tilt : float
        Tilt t in degrees (the GE set has +18.5). 0 gives an ordinary axial series.
    slice_positions : sequence of float, optional
        ImagePositionPatient z (mm) of each image, in the order written (any
        spacing). Default: the GE steps along the normal ``GE_LIKE_NORMAL_STEPS``
        (13 x 4.0, 1.08, 13 x 7.0 mm, i.e. z steps of step / cos t), the first
        image centre 10 mm below the nose tip, so the series reaches the vertex.
    slice_thickness : float or sequence, optional
        SliceThickness per image; default the larger of the normal steps to the
        neighbouring images, which reproduces the GE set (14 x 4.0, 14 x 7.0:
        the 1.08 mm overlap step does not count as a thickness).
    rows, columns : int
        Image size in pixels.
    pixel_spacing : (float, float)
        (between rows, between columns) in mm.
    image_center_xy : (float, float), optional
        Patient (x, y) of the image centre; default ``(0, head_center_y)`` of
        the phantom. IPP x and y follow from it and are the same for all images.
    fov_diameter : float, optional
        If given, pixels farther than ``fov_diameter / 2`` from the image centre
        are written as ``pixel_padding_value`` (the circular reconstruction field).
    pixel_padding_value : int
        Stored padding value and PixelPaddingValue tag (the GE set uses -1500).
    noise : bool
        Add the phantom's Gaussian noise (sigma ``phantom.noise`` HU), seeded by
        ``noise_seed`` (deterministic).
    series_description ... overwrite
        As in :func:`write_dicom_series`.

    Returns
    -------
    list of Path
        Files in InstanceNumber order (the order of ``slice_positions``).
    """
    row_dir, col_dir = tilted_plane_axes(gantry_tilt)
    dr, dc = float(pixel_spacing[0]), float(pixel_spacing[1])
    if image_center_xy is None:
        image_center_xy = (0.0, float(phantom.params["head_center_y"]))
    # IPP is the centre of pixel (0, 0): half an image back along rows and columns.
    half_r, half_c = (rows - 1) / 2 * dr, (columns - 1) / 2 * dc
    x0 = image_center_xy[0] - half_c * row_dir[0]
    y0 = image_center_xy[1] - half_r * col_dir[1]
    centre_minus_ipp_z = half_r * col_dir[2]
    if slice_positions is None:
        steps_z = np.asarray(GE_LIKE_NORMAL_STEPS) / math.cos(math.radians(gantry_tilt))
        centre_z = float(phantom.params["nose_tip_z"]) - 10.0 + np.concatenate([[0.0], np.cumsum(steps_z)])
        slice_positions = centre_z - centre_minus_ipp_z
    z = np.asarray(slice_positions, dtype=np.float64).ravel()
    if z.size == 0 or not np.all(np.isfinite(z)):
        raise PDEHeadError(f"{folder}: slice_positions must be a non-empty list of finite z values")
    positions = np.stack([np.full_like(z, x0), np.full_like(z, y0), z], axis=1)
    if slice_thickness is None:  # the larger step to a neighbour: an overlap step keeps its group's value
        step = np.abs(np.diff(positions @ np.cross(row_dir, col_dir)))
        thickness = (np.maximum(np.append(step, 0.0), np.insert(step, 0, 0.0)) if step.size
                     else np.array([1.0]))
    else:
        thickness = np.broadcast_to(np.asarray(slice_thickness, float), z.shape)
    folder = _prepare_folder(folder, file_prefix, overwrite)

    rng = np.random.default_rng(noise_seed) if noise else None
    r = np.arange(rows, dtype=np.float64)[:, None, None] * dr
    c = np.arange(columns, dtype=np.float64)[None, :, None] * dc
    in_plane = c * row_dir + r * col_dir  # (rows, columns, 3) offsets from IPP
    outside_fov = None
    if fov_diameter is not None:
        rr, cc = np.meshgrid(np.arange(rows) * dr - half_r, np.arange(columns) * dc - half_c, indexing="ij")
        outside_fov = np.hypot(rr, cc) > fov_diameter / 2

    def images():
        for ipp in positions:
            hu = phantom.sample_hu(ipp + in_plane, noise_rng=rng).astype(np.float64)
            if outside_fov is not None:
                hu[outside_fov] = np.nan
            yield hu

    return _write_slices(folder, images(), positions, row_dir, col_dir, (dr, dc), thickness,
                         series_description=series_description, patient_name=patient_name,
                         patient_id=patient_id, study_description=study_description,
                         series_number=series_number, gantry_tilt=float(gantry_tilt),
                         rescale_slope=rescale_slope, rescale_intercept=rescale_intercept,
                         window_center=window_center, window_width=window_width,
                         pixel_padding_value=pixel_padding_value, uid_seed=uid_seed,
                         file_prefix=file_prefix, extra_tags=extra_tags)
