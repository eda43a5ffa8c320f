"""NIfTI-1 (single file .nii / .nii.gz): header parsed directly, sform/qform affine, RAS -> LPS."""
from __future__ import annotations

import math
import struct

import numpy as np

from ...core.ct_volume import CTVolume
from ...core.errors import CTImportError
from .geometry import ALIGNED_TOL, resample_limit, resample_slices, to_canonical
from .limits import check_budget, check_ratio, gunzip_bounded

_NIFTI_DTYPES = {2: "u1", 4: "i2", 8: "i4", 16: "f4", 64: "f8", 256: "i1", 512: "u2", 768: "u4",
                 1024: "i8", 1280: "u8"}


def _nifti_affine(hdr: dict) -> np.ndarray:
    """Voxel (i, j, k) -> RAS mm affine from sform (preferred) or qform, else pixdim."""
    if hdr["sform_code"] > 0:
        m = np.eye(4)
        m[:3] = np.array([hdr["srow_x"], hdr["srow_y"], hdr["srow_z"]])
        return m
    pixdim = hdr["pixdim"]
    zooms = np.abs(np.array(pixdim[1:4], dtype=np.float64))
    zooms[zooms == 0] = 1.0
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


def _read_header(f) -> bytes:
    """The first 352 bytes (the header and the extension flag), read without decompressing more."""
    try:
        if f.name.lower().endswith(".gz"):
            head, _ = gunzip_bounded(f, 352, "gzipped NIfTI file", verify=False)
        else:
            with open(f, "rb") as fh:
                head = fh.read(352)
    except OSError as exc:
        raise CTImportError(f"cannot read NIfTI file: {exc}", f) from None
    return head


def _read_body(f, needed: int, warns: list[str]) -> bytes:
    """The first ``needed`` bytes of the file (decompressed in bounded chunks for .gz), or a clear error."""
    gz = f.name.lower().endswith(".gz")
    if gz:
        check_ratio(needed, f.stat().st_size, "this gzipped NIfTI file's header says it", f)
        raw, extra = gunzip_bounded(f, needed, "gzipped NIfTI file")
        if extra:
            warns.append(f"{extra} bytes follow the voxels in the gzipped NIfTI file (ignored)")
    else:
        size = f.stat().st_size
        if size < needed:
            raise CTImportError(f"truncated NIfTI file: {size} bytes, its header needs {needed}", f)
        try:
            with open(f, "rb") as fh:
                raw = fh.read(needed)
        except OSError as exc:
            raise CTImportError(f"cannot read NIfTI file: {exc}", f) from None
    if len(raw) < needed:
        raise CTImportError(f"truncated NIfTI file: {len(raw)} {'decompressed ' if gz else ''}bytes, its header "
                            f"needs {needed}", f)
    return raw


def _check_geometry_fields(hdr: dict, f, warns: list[str]) -> None:
    """Refuse non-finite geometry; warn where a field is repaired (a zero or negative voxel size)."""
    if hdr["sform_code"] > 0:
        rows = np.array([hdr["srow_x"], hdr["srow_y"], hdr["srow_z"]], dtype=np.float64)
        if not np.isfinite(rows).all():
            raise CTImportError("NIfTI sform (srow_x/y/z) holds NaN or infinite values: the voxels cannot be "
                                "placed in space", f)
        return
    zooms = np.array(hdr["pixdim"][1:4], dtype=np.float64)
    if not np.isfinite(zooms).all():
        raise CTImportError(f"NIfTI voxel size pixdim[1:4] = {zooms.tolist()} is not finite", f)
    if hdr["qform_code"] > 0 and not np.isfinite(np.r_[hdr["quatern"], hdr["qoffset"]]).all():
        raise CTImportError("NIfTI qform (quatern / qoffset) holds NaN or infinite values", f)
    if (zooms <= 0).any():
        fixed = np.abs(zooms)
        fixed[fixed == 0] = 1.0
        warns.append(f"NIfTI voxel size pixdim[1:4] = {zooms.tolist()} has zero or negative entries: used "
                     f"{fixed.tolist()} mm (a negative size is read as its absolute value, zero as 1 mm)")


def _parse_header(raw: bytes, f, warns: list[str]):
    """The header's fields, each checked: ((nx, ny, nz), dtype, vox_offset, (scl_slope, scl_inter),
    the geometry fields, the description); a clear error for every impossible value."""
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
    vox_offset_f = struct.unpack(endian + "f", raw[108:112])[0]
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
    if min(nx, ny, nz) < 1:
        raise CTImportError(f"NIfTI header gives dimensions {nx} x {ny} x {nz} (dim[1:4]); every one must be "
                            "at least 1", f)
    if any(d < 0 for d in dim[4:ndim + 1]):
        raise CTImportError(f"NIfTI header gives a negative dimension ({list(dim[:ndim + 1])})", f)
    # NIfTI-1: a single file's voxels start at vox_offset >= 352 (header + extension flag)
    if not math.isfinite(vox_offset_f) or vox_offset_f < 352 or vox_offset_f != int(vox_offset_f):
        raise CTImportError(f"NIfTI vox_offset is {vox_offset_f!r}: the voxels of a .nii file start at a whole "
                            "byte offset of at least 352 (after the header)", f)
    vox_offset = int(vox_offset_f)
    extra = int(np.prod([max(1, d) for d in dim[4:ndim + 1]])) if ndim > 3 else 1
    if extra > 1:
        warns.append(f"NIfTI image has {extra} volumes; loaded the first")
    dt = np.dtype(endian + _NIFTI_DTYPES[datatype])
    return (nx, ny, nz), dt, vox_offset, (scl_slope, scl_inter), hdr, description


def load_nifti(files, label, resample_spacing, warns, hu=False) -> CTVolume:
    f = files[0]
    raw = _read_header(f)
    (nx, ny, nz), dt, vox_offset, (scl_slope, scl_inter), hdr, description = _parse_header(raw, f, warns)
    sform_code, qform_code = hdr["sform_code"], hdr["qform_code"]
    count = int(nx) * int(ny) * int(nz)
    check_budget(count * (4 + dt.itemsize), f"a {nx} x {ny} x {nz} NIfTI volume", f)
    if not math.isfinite(vox_offset + count * dt.itemsize) or vox_offset > 2 ** 40:
        raise CTImportError(f"NIfTI vox_offset {vox_offset} lies beyond any file", f)
    needed = vox_offset + count * dt.itemsize
    raw = _read_body(f, needed, warns)
    _check_geometry_fields(hdr, f, warns)
    # stored with i fastest, so C order reads it as [k, j, i]
    data = np.frombuffer(raw, dtype=dt, count=count, offset=vox_offset).reshape(nz, ny, nx).astype(np.float32)
    del raw
    if not math.isfinite(scl_slope) or not math.isfinite(scl_inter):
        warns.append(f"NIfTI scl_slope / scl_inter are {scl_slope!r} / {scl_inter!r} (not finite): ignored, the "
                     "stored values are used as they are")
    elif scl_slope < 0:
        warns.append(f"NIfTI scl_slope is {scl_slope:g} (negative): the intensities come out inverted")
    if math.isfinite(scl_slope) and math.isfinite(scl_inter) and scl_slope != 0.0 and (
            abs(scl_slope) > 1e6 or abs(scl_inter) > 1e6):
        raise CTImportError(f"NIfTI scl_slope / scl_inter are {scl_slope:g} / {scl_inter:g}: no CT or MRI "
                            "intensity scaling is this large (a corrupt header)", f)
    if scl_slope not in (0.0, 1.0) and math.isfinite(scl_slope) and math.isfinite(scl_inter):
        data *= scl_slope
    if scl_inter != 0.0 and math.isfinite(scl_inter) and math.isfinite(scl_slope) and scl_slope != 0.0:
        data += scl_inter
    affine = _nifti_affine(hdr)
    affine[:2] *= -1.0                                   # RAS -> LPS
    columns = affine[:3, :3]
    zooms = np.linalg.norm(columns, axis=0)
    if not np.all(zooms > 1e-3) or not np.all(zooms < 1e3):
        raise CTImportError(f"NIfTI affine gives voxel sizes {np.round(zooms, 6).tolist()} mm (i, j, k); a scan's "
                            "voxels measure between 0.001 and 1000 mm", f)
    units = columns / zooms                              # unit vectors of i, j, k
    # the slices (i, j planes) are resampled as they are; a shear within them cannot be
    in_plane = float(np.degrees(np.arccos(np.clip(abs(units[:, 0] @ units[:, 1]), 0.0, 1.0))))
    if abs(in_plane - 90.0) > 1.0:
        raise CTImportError(f"NIfTI affine shears the slices: its i and j axes meet at {in_plane:.1f} deg "
                            "instead of 90 (a corrupt sform/qform?)", f)
    if abs(float(np.linalg.det(units))) < 0.05:
        raise CTImportError("NIfTI affine puts the slices (k) almost within their own plane: the voxels cannot "
                            "be placed in space (a corrupt sform/qform?)", f)
    origin = affine[:3, 3]
    aligned = (np.abs(units).max(axis=0).min() > 1 - ALIGNED_TOL
               and len(set(np.argmax(np.abs(units), axis=0).tolist())) == 3)
    reasons = []
    coverage = None
    if aligned:
        out, spacing, origin_out, direction = to_canonical(data, [units[:, 2], units[:, 1], units[:, 0]],
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
        out, origin_out, spacing, coverage = resample_slices(np.ascontiguousarray(data), positions, u, v,
                                                    float(zooms[1]), float(zooms[0]), steps, resample_spacing,
                                                    float(data.min()), max_voxels=resample_limit(data.size),
                                                    label=f)
        direction = np.eye(3)
        covered = float(coverage.mean())
        if covered < 0.25:
            warns.append(f"the oblique or sheared NIfTI affine leaves only {100 * covered:.0f} % of the resampled "
                         "grid inside the slices; check the sform/qform")
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
        "units": "HU" if hu else "stored value x scl_slope + scl_inter (modality "
                                 "unknown; not HU unless the file is CT)",
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
