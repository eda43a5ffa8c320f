"""Checked file writes: a file appears under its name whole, or not at all.

Every output (.vdb, .blend, meshes, CSV, JSON) is written to a temporary name in its destination
folder (``.<name>.<pid>-<random>.partial``: one name per write, so two processes writing the same
output never share a partial file), its size checked against what was written (a full disk can make a
library's write fail without an error: the file is then short), flushed to the disk, and only then
renamed into place (``os.replace``: atomic on one file system). A failing write ends in one
:class:`WriteError` naming the destination and the cause, and the temporary file is removed.
"""
from __future__ import annotations

import os
import shutil
import uuid
import zlib
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from ..core.errors import StorageError

PARTIAL_SUFFIX = ".partial"


class WriteError(StorageError):
    """An output could not be written whole (disk full, permission, a short file); nothing was left."""


def partial_name(path: str | os.PathLike) -> Path:
    """A fresh temporary name beside `path` (hidden, unique to this write)."""
    path = Path(os.fspath(path))
    return path.with_name(f".{path.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}{PARTIAL_SUFFIX}")


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError):
        return exc.strerror or str(exc)
    return str(exc) or type(exc).__name__


def _sync(path: Path) -> None:
    """Flush `path` to the disk: a full disk that the page cache hid fails here, not after the rename."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def disk_full(path: str | os.PathLike, needed: int = 1 << 20) -> bool:
    """Whether the file system of `path` has less than `needed` bytes free (why a write came out short)."""
    try:
        st = os.statvfs(Path(os.fspath(path)).parent)
    except (OSError, AttributeError):
        return False
    return st.f_bavail * st.f_frsize < needed


def check_size(path: str | os.PathLike, expected: int | None = None, minimum: int = 1) -> int:
    """The size of the written `path`; raises :class:`WriteError` when it is not `expected` (or below `minimum`)."""
    size = os.stat(path).st_size
    if (expected is not None and size != expected) or size < minimum:
        want = f"{expected} bytes" if expected is not None else f"at least {minimum} bytes"
        why = "no space left on device" if disk_full(path) else "disk full?"
        raise WriteError(f"{path}: the written file has {size} bytes, expected {want} ({why})")
    return size


@contextmanager
def checked_output(path: str | os.PathLike, *, replace: bool = True) -> Iterator[Path]:
    """Context manager: yields a temporary path to write; on success it is flushed and renamed to `path`.

    The body must write the whole file to the yielded path (and may call :func:`check_size` on it).
    With ``replace=False`` an existing `path` is never overwritten (:class:`FileExistsError`).
    Any failure removes the temporary file and raises :class:`WriteError` naming `path` (a
    :class:`WriteError` or a cancellation from the body passes through unchanged).
    """
    path = Path(os.fspath(path))
    tmp = partial_name(path)
    try:
        yield tmp
        if not tmp.is_file():
            raise WriteError(f"{path}: cannot be written (nothing was written)")
        check_size(tmp, minimum=0)
        _sync(tmp)
        if replace:
            os.replace(tmp, path)
        else:
            os.link(tmp, path)  # fails if `path` exists: never overwrites
    except WriteError as exc:  # named as the user's file, not the temporary one
        raise WriteError(str(exc).replace(str(tmp), str(path))) from None
    except FileExistsError:
        raise
    except OSError as exc:
        raise WriteError(f"{path}: cannot be written ({_reason(exc)})") from None
    finally:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass
        except OSError:
            pass


def write_bytes_checked(path: str | os.PathLike, data: bytes) -> Path:
    """Write `data` to `path` whole or not at all (:func:`checked_output`), its size checked."""
    path = Path(os.fspath(path))
    with checked_output(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
        check_size(tmp, len(data), minimum=0)
    return path


def write_text_checked(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write `text` to `path` whole or not at all (:func:`write_bytes_checked`)."""
    return write_bytes_checked(path, text.encode(encoding))


def write_with(path: str | os.PathLike, writer: Callable[[Path], object], minimum: int = 1) -> Path:
    """Run ``writer(tmp)`` (a library's save function) and rename its file to `path` when it wrote at
    least `minimum` bytes (:func:`checked_output`)."""
    path = Path(os.fspath(path))
    with checked_output(path) as tmp:
        writer(tmp)
        check_size(tmp, minimum=minimum)
    return path


def copy_checked(src: str | os.PathLike, dst: str | os.PathLike) -> Path:
    """Copy `src` to the new name `dst` (never overwriting it), the copy's size equal to the source's."""
    src, dst = Path(os.fspath(src)), Path(os.fspath(dst))
    size = os.stat(src).st_size
    with checked_output(dst, replace=False) as tmp:
        shutil.copyfile(src, tmp)
        check_size(tmp, size, minimum=0)
    return dst


def decompress_bounded(packed: bytes, max_bytes: int, what: str) -> bytes:
    """``zlib.decompress`` that never produces more than `max_bytes` (a stored payload is data: a small
    compressed blob may claim gigabytes); raises :class:`StorageError` naming `what` beyond it."""
    d = zlib.decompressobj()
    try:
        out = d.decompress(packed, int(max_bytes))
        if d.unconsumed_tail or (not d.eof and d.decompress(b"", 1)):
            raise StorageError(f"{what}: more than {int(max_bytes) // 2 ** 20} MB when decompressed (the budget); "
                               "not read")
        if not d.eof:
            raise StorageError(f"{what}: truncated compressed data")
    except zlib.error as exc:
        raise StorageError(f"{what}: corrupt compressed data ({exc})") from None
    return out
