"""Headerless raw slices: one file per slice or one file for the volume, optionally gzipped."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ... import defaults
from ...core.ct_volume import CTVolume
from ...core.errors import CTImportError
from .. import scan_evidence
from .folder_files import TEXT_EXTENSIONS, has_ext, numbered_files, top_level
from .geometry import headerless_volume
from .limits import check_budget, gunzip_bounded


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


def _read_raw_bytes(f: Path, limit: int) -> tuple[bytes | None, int]:
    """(decompressed bytes, size) of a gzipped raw file; (None, size on disk) of a plain one.

    A gzipped file is decompressed in chunks and at most ``limit + 1`` bytes are kept (enough to tell that
    it does not match the shape); the stream is read through to check it, within
    ``defaults.IMPORT_MAX_COMPRESSION_RATIO`` times the file's size."""
    if not f.name.lower().endswith(".gz"):
        return None, f.stat().st_size
    raw, extra = gunzip_bounded(f, limit + 1, "gzipped raw file")
    return raw, len(raw) + extra


def _raw_samples(f: Path, raw: bytes | None, dt: np.dtype, count: int, offset: int) -> np.ndarray:
    if raw is None:
        return np.fromfile(f, dtype=dt, count=count, offset=offset)
    return np.frombuffer(raw, dtype=dt, count=count, offset=offset)


def load_raw(files, label, shape, dtype, byte_order, header_bytes, spacing, axes, oriented, hu,
              warns) -> CTVolume:
    shape, header_bytes = _checked_layout(shape, header_bytes, label)
    dt = _raw_dtype(dtype, byte_order, label)

    top = top_level(files, label)
    candidates = [f for f in top if not has_ext(f, TEXT_EXTENSIONS)]
    if len(candidates) < len(top):
        skipped = [f.name for f in top if f not in candidates]
        warns.append(f"skipped {len(skipped)} text file(s): {', '.join(skipped[:5])}")
    if not candidates:
        raise CTImportError("no raw data files found", label)
    candidates = numbered_files(candidates, label, "raw", warns)

    if len(candidates) == 1:
        data = _read_one_file(candidates[0], shape, dt, header_bytes)
    else:
        data = _read_slice_files(candidates, shape, dt, header_bytes, label)
    _refuse_wrong_byte_order(data, dt, label)
    _refuse_absurd_floats(data, dt, label)
    _refuse_wrong_row_length(data, shape, label)
    return headerless_volume(data, label, "raw", spacing, axes, oriented, hu, warns,
                              {"files": len(candidates), "first_file": candidates[0].name,
                               "last_file": candidates[-1].name, "source_dtype": dt.str,
                               "header_bytes": header_bytes})


def _checked_layout(shape, header_bytes, label) -> tuple[tuple[int, ...], int]:
    """``shape`` as 2 or 3 positive integers and ``header_bytes`` as a non-negative integer, or a clear error."""
    if shape is None:
        raise CTImportError("raw data needs shape=(ny, nx) for one slice per file or (nz, ny, nx)", label)
    try:
        shape = tuple(int(s) for s in shape)
    except (TypeError, ValueError):
        raise CTImportError(f"shape must be integers (ny, nx) or (nz, ny, nx), got {shape!r}", label) from None
    if len(shape) not in (2, 3) or min(shape) <= 0:
        raise CTImportError(f"shape must be 2 or 3 positive integers, got {shape!r}", label)
    try:
        header_bytes = int(header_bytes)
    except (TypeError, ValueError):
        header_bytes = -1
    if header_bytes < 0:
        raise CTImportError(f"header_bytes must be a non-negative integer, got {header_bytes!r}", label)
    return shape, header_bytes


def _read_one_file(f, shape, dt, header_bytes) -> np.ndarray:
    """One file holding the whole volume: (nz, ny, nx) float32, nz from ``shape`` or from the file's size."""
    ny, nx = shape[-2:]
    slice_bytes = ny * nx * dt.itemsize
    limit = (header_bytes + shape[0] * slice_bytes if len(shape) == 3
             else defaults.IMPORT_MEMORY_BUDGET_BYTES // 2)
    raw, size = _read_raw_bytes(f, limit)
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
    check_budget(nz * ny * nx * 4, f"{nz} x {ny} x {nx} raw slices", f)
    data = np.empty((nz, ny, nx), dtype=np.float32)
    data[...] = _raw_samples(f, raw, dt, nz * ny * nx, header_bytes).reshape(nz, ny, nx)
    del raw
    return data


def _read_slice_files(candidates, shape, dt, header_bytes, label) -> np.ndarray:
    """One slice per file: (len(candidates), ny, nx) float32."""
    ny, nx = shape[-2:]
    slice_bytes = ny * nx * dt.itemsize
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
    check_budget(len(candidates) * ny * nx * 4, f"{len(candidates)} x {ny} x {nx} raw slices", label)
    data = np.empty((len(candidates), ny, nx), dtype=np.float32)
    for k, f in enumerate(candidates):
        raw, size = _read_raw_bytes(f, expected)
        if size != expected:
            raise CTImportError(f"{'decompressed (gzip) size' if raw is not None else 'file size'} {size} "
                                f"bytes does not match one {ny}x{nx} {dt.str} slice + {header_bytes} header "
                                f"bytes = {expected} bytes", f)
        data[k] = _raw_samples(f, raw, dt, ny * nx, header_bytes).reshape(ny, nx)
    return data


def _refuse_absurd_floats(data: np.ndarray, dt: np.dtype, label) -> None:
    """Refuse float samples whose magnitudes no scan has (bytes read as the wrong type, shape or offset)."""
    if dt.kind != "f":
        return
    sample = np.abs(data[:: max(1, data.shape[0] // 16)].astype(np.float64))
    finite = sample[np.isfinite(sample)]
    share = float(np.mean(finite > 1e6)) if finite.size else 1.0
    if finite.size < 0.5 * sample.size or share > 0.01:
        raise CTImportError(f"read as dtype={dt.str!r} the samples are not CT values ({100 * share:.0f} % beyond "
                            f"1e6 in magnitude, {100 * (1 - finite.size / max(sample.size, 1)):.0f} % NaN or "
                            "infinite): wrong dtype, byte order, shape or header_bytes", label)


def _refuse_wrong_byte_order(data: np.ndarray, dt: np.dtype, label) -> None:
    """Refuse samples read in the wrong byte order (``scan_evidence.wrong_byte_order``): noise spanning
    the whole int16 range would otherwise segment as a "head" filling the field of view."""
    bad = scan_evidence.wrong_byte_order(data, dt)
    if bad:
        (lo, hi), (slo, shi) = bad["read"], bad["swapped"]
        order = "big-endian" if bad["swapped_dtype"].startswith(">") else "little-endian"
        raise CTImportError(f"wrong byte order: read as dtype={dt.str!r} the samples span {lo:.0f}..{hi:.0f} "
                            f"(noise, no CT spans that many values), read in the other byte order they span "
                            f"{slo:.0f}..{shi:.0f} like a CT; pass dtype={bad['swapped_dtype']!r} ({order})", label)


def _refuse_wrong_row_length(data: np.ndarray, shape, label) -> None:
    """Refuse slices read with a wrong row length (``scan_evidence.wrong_row_length``): with the right byte
    count they would otherwise segment as garbage."""
    bad = scan_evidence.wrong_row_length(data)
    if bad:
        count = data.shape[1] * data.shape[2]
        hint = (f"; the samples join up in rows of {bad['row_length']}: shape=({count // bad['row_length']}, "
                f"{bad['row_length']})" if bad["row_length"] else "")
        raise CTImportError(f"shape={tuple(shape)} is not the slices' shape: its rows do not join up (row-to-row "
                            f"correlation {bad['rows']:.2f}, column-to-column {bad['columns']:.2f}; in a scan both "
                            f"are high){hint}", label)
