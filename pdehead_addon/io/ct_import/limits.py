"""Size limits of the readers: a file's declared size is checked against its real length and the memory
budget (:data:`~pdehead_addon.defaults.IMPORT_MEMORY_BUDGET_BYTES`) before anything is allocated, and
compressed streams are decompressed in bounded chunks, never past what the header asks for.
"""
from __future__ import annotations

import gzip
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


def gzip_size_bound(path: Path) -> int:
    """The most bytes a gzip file of this size can decompress to (deflate: 1032 x its stored size)."""
    return 1032 * os.path.getsize(path) + 1024
