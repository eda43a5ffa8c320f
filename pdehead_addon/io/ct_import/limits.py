"""Size limits of the readers: a file's declared size is checked against its real length and the memory
budget (:data:`~pdehead_addon.defaults.IMPORT_MEMORY_BUDGET_BYTES`) before anything is allocated, and
compressed streams are decompressed in bounded chunks, never past what the header asks for; a DICOM
image's size attributes are checked against its PixelData element (:func:`check_image_header`).
"""
from __future__ import annotations

import gzip
import math
import os
import zlib
from pathlib import Path

from ... import defaults
from ...core.errors import CTImportError


def _gb(nbytes: float) -> str:
    return f"{nbytes / 2 ** 30:.3g} GB"


def check_budget(nbytes: int, what: str, path) -> None:
    """Refuse a volume of ``nbytes`` (float32 samples) above the import memory budget, naming ``what``."""
    budget = defaults.IMPORT_MEMORY_BUDGET_BYTES
    if nbytes > budget:
        raise CTImportError(f"{what} would need {_gb(nbytes)} of memory, more than the import budget of "
                            f"{_gb(budget)}; the header is wrong or the scan must be cropped first", path)


def check_ratio(decoded: int, stored: int, what: str, path) -> None:
    """Refuse compressed data that would decode to implausibly many times its stored bytes."""
    ratio = defaults.IMPORT_MAX_COMPRESSION_RATIO
    if decoded > defaults.IMPORT_RATIO_FLOOR_BYTES and decoded > ratio * max(stored, 1):
        raise CTImportError(f"{what} would decode to {_gb(decoded)} from {stored} stored bytes (more than "
                            f"{ratio} times; a corrupt header or a decompression bomb)", path)


def gunzip_bounded(path: Path, limit: int, what: str = "gzip stream", verify: bool = True) -> tuple[bytes, int]:
    """Decompress ``path`` in chunks: at most ``limit`` bytes are kept, the rest of the stream is read
    through (``verify``, to check its CRC) without being kept, up to
    ``IMPORT_MAX_COMPRESSION_RATIO`` x the file's size. Returns (the kept bytes, the bytes that followed).

    Errors of the stream (corrupt deflate data, a CRC mismatch, a truncated file) and a stream that goes on
    past the ratio become a :class:`CTImportError` naming the file.
    """
    chunk = defaults.IMPORT_CHUNK_BYTES
    parts, total, extra = [], 0, 0
    ceiling = max(defaults.IMPORT_MAX_COMPRESSION_RATIO * os.path.getsize(path), defaults.IMPORT_RATIO_FLOOR_BYTES)
    try:
        with gzip.open(path, "rb") as fh:
            while total < limit:
                block = fh.read(min(chunk, limit - total))
                if not block:
                    return b"".join(parts), 0
                parts.append(block)
                total += len(block)
                if total > ceiling:
                    raise CTImportError(f"the {what} decompresses to more than {_gb(total)} from "
                                        f"{os.path.getsize(path)} stored bytes (more than "
                                        f"{defaults.IMPORT_MAX_COMPRESSION_RATIO} times: a decompression bomb?)",
                                        path)
            while verify:
                block = fh.read(chunk)
                if not block:
                    break
                extra += len(block)
                if total + extra > ceiling:
                    raise CTImportError(f"the {what} decompresses to more than {_gb(total + extra)} from "
                                        f"{os.path.getsize(path)} stored bytes (more than "
                                        f"{defaults.IMPORT_MAX_COMPRESSION_RATIO} times: a decompression bomb?)",
                                        path)
    except (OSError, EOFError, zlib.error) as exc:
        raise CTImportError(f"cannot decompress the {what}: {type(exc).__name__}: {exc}", path) from None
    return b"".join(parts), extra


# ----------------------------------------------------------------------------- DICOM headers
class BadHeader(ValueError):
    """A DICOM header whose values contradict each other or the file (the message says which)."""


class TruncatedPixels(BadHeader):
    """An image file whose pixel data is shorter than its header says (cut off)."""


def _int_attr(ds, keyword: str, default=None) -> int | None:
    value = ds.get(keyword, default)
    if value is None or value == "":
        return default
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise BadHeader(f"{keyword} is {value!r}, not a number") from None
    if not math.isfinite(number) or number != int(number):
        raise BadHeader(f"{keyword} is {value!r}, not a whole number")
    return int(number)


def check_image_header(f: Path, ds) -> int:
    """The number of frames of an image file whose size attributes are consistent, else :class:`BadHeader`.

    Rows, Columns, NumberOfFrames, BitsAllocated and SamplesPerPixel are checked for range, the transfer
    syntax for being known, and the declared pixel bytes against the length of the PixelData element
    (uncompressed) or the file (compressed) and the import memory budget, all before any pixel is read.
    """
    rows, cols = _int_attr(ds, "Rows", 0), _int_attr(ds, "Columns", 0)
    if not (1 <= rows <= 65535 and 1 <= cols <= 65535):
        raise BadHeader(f"image size Rows x Columns = {rows} x {cols} (each must be 1 to 65535)")
    frames = _int_attr(ds, "NumberOfFrames", 1)
    if frames < 1:
        raise BadHeader(f"NumberOfFrames is {frames}")
    bits = _int_attr(ds, "BitsAllocated", 16)
    if bits not in (1, 8, 16, 32, 64):
        raise BadHeader(f"BitsAllocated is {bits} (1, 8, 16, 32 or 64)")
    samples = _int_attr(ds, "SamplesPerPixel", 1)
    if not 1 <= samples <= 4:
        raise BadHeader(f"SamplesPerPixel is {samples}")
    meta = getattr(ds, "file_meta", None)
    ts = meta.get("TransferSyntaxUID") if meta is not None else None
    if ts is not None and not ts.is_transfer_syntax:
        raise BadHeader(f"unknown TransferSyntaxUID {str(ts)!r}: the pixel data cannot be decoded")
    stored = _int_attr(ds, "BitsStored", None)
    if stored is not None and not (min(8, bits) <= stored <= bits):
        raise BadHeader(f"BitsStored {stored} does not fit BitsAllocated {bits}")
    photometric = str(ds.get("PhotometricInterpretation", "") or "").strip().upper()
    if photometric and samples == 1 and photometric not in ("MONOCHROME1", "MONOCHROME2"):
        raise BadHeader(f"PhotometricInterpretation is {photometric} with one sample per pixel (CT slices are "
                        "MONOCHROME2)")
    expected = (rows * cols * frames * samples * bits + 7) // 8
    budget = defaults.IMPORT_MEMORY_BUDGET_BYTES
    if rows * cols * frames * 4 > budget:
        raise BadHeader(f"{rows} x {cols} x {frames} frame(s) would need {rows * cols * frames * 4 / 2 ** 30:.3g} GB "
                        f"of memory, more than the import budget of {budget / 2 ** 30:.3g} GB")
    _check_pixel_length(f, ds, ts, (rows, cols, frames, bits), expected)
    return frames


def _check_pixel_length(f: Path, ds, ts, size: tuple[int, int, int, int], expected: int) -> None:
    """The PixelData element's length (uncompressed) or the file's size (compressed) against the ``expected``
    bytes of ``size`` = (rows, cols, frames, bits): :class:`TruncatedPixels` or :class:`BadHeader` when they
    disagree."""
    rows, cols, frames, bits = size
    element = ds.get_item("PixelData", keep_deferred=True)
    length = getattr(element, "length", None)
    if length is None:
        value = getattr(element, "value", None)
        length = len(value) if isinstance(value, (bytes, bytearray)) else None
    compressed = ts is not None and ts.is_transfer_syntax and ts.is_compressed
    if length is not None and length != 0xFFFFFFFF and not compressed:
        if length < expected:
            raise TruncatedPixels(f"the pixel data has {length} bytes, the header's {rows} x {cols} x {frames} "
                                  f"frame(s) of {bits} bits need {expected} (truncated file or wrong "
                                  "Rows/Columns/NumberOfFrames)")
        if length > expected + (expected & 1) + 1:
            raise BadHeader(f"the pixel data has {length} bytes, the header's {rows} x {cols} x {frames} frame(s) "
                            f"of {bits} bits only {expected} (wrong Rows/Columns/NumberOfFrames/BitsAllocated)")
    elif compressed or (length == 0xFFFFFFFF):
        stored = f.stat().st_size
        ratio = defaults.IMPORT_MAX_COMPRESSION_RATIO
        if expected > defaults.IMPORT_RATIO_FLOOR_BYTES and expected > ratio * stored:
            raise BadHeader(f"{rows} x {cols} x {frames} compressed frame(s) would decode to {expected} bytes from a "
                            f"{stored}-byte file (more than {ratio} times: a corrupt header)")
        if frames > stored // 4:
            raise BadHeader(f"NumberOfFrames is {frames} in a file of {stored} bytes")
