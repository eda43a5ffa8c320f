"""NIfTI-1 (single file .nii / .nii.gz): header parsed directly, sform/qform affine, RAS -> LPS."""
from __future__ import annotations

import gzip
import math
import struct

import numpy as np

from ...core.ct_volume import CTVolume
from ...core.errors import CTImportError
from .geometry import ALIGNED_TOL, to_canonical, resample_slices



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


def load_nifti(files, label, resample_spacing, warns, hu=False) -> CTVolume:
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
