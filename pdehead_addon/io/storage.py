"""Compact storage of the PDE boundary conditions (paper section 5.2).

Instead of a surface mesh, only the 3t+1 boundary curves (and the solver
settings) are stored; the head is re-solved on load (:mod:`pdehead_addon.pde.head_files`). The format (``.pdeh``,
version 1) is described in ``docs/boundary_format.md``: a small JSON header
and a zlib-compressed payload holding every curve as coordinates quantised to
``quantum_mm`` (0.01 mm) relative to a per-curve origin, second-order
differenced along the curve and zigzag-encoded in byte planes; a curve lying
in an axial plane stores its z once (exactly). For t = 10, M = 256 (31
curves) a CThead file is about 14 kB; a reloaded head differs from the
original by a few micrometres.
"""
from __future__ import annotations

import json
import os
import struct
import zlib
from typing import Any

import numpy as np

from ..core.boundary_set import BoundarySet, knots_from_heights
from ..core.errors import BoundaryError, StorageError
from ..defaults import CONTINUITY, MAX_STORED_BOUNDARY_BYTES
from .safe_io import decompress_bounded

MAGIC = b"PDEHBND\x00"
VERSION = 1
#: Quantisation step of the stored coordinates (mm); the reconstruction error is at most half of it.
QUANTUM_MM = 0.01
_FIXED = struct.Struct("<8sHI")          # magic, version, header length
_PAYLOAD = struct.Struct("<II")          # payload length, CRC-32 of header + compressed payload


def _json_safe(value: Any, depth: int = 0) -> Any:
    """A JSON-serialisable copy of provenance metadata (numpy scalars/arrays converted, others dropped)."""
    if depth > 8:
        return None
    if isinstance(value, (str, bool)) or value is None:
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        f = float(value)
        return f if np.isfinite(f) else None
    if isinstance(value, np.ndarray):
        return _json_safe(value.tolist(), depth + 1) if value.size <= 100_000 else None
    if isinstance(value, (list, tuple)):
        return [_json_safe(v, depth + 1) for v in value]
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            safe = _json_safe(v, depth + 1)
            if safe is not None or v is None:
                out[str(k)] = safe
        return out
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return None


def _monotone(h: np.ndarray) -> bool:
    d = np.diff(np.asarray(h, float))
    return len(h) >= 4 and (len(h) - 1) % 3 == 0 and (bool(np.all(d > 0)) or bool(np.all(d < 0)))


def _zigzag(a: np.ndarray) -> np.ndarray:
    return np.where(a >= 0, 2 * a, -2 * a - 1).astype(np.uint64)


def _unzigzag(z: np.ndarray) -> np.ndarray:
    z = z.astype(np.int64)
    return np.where(z & 1, -((z + 1) >> 1), z >> 1)


def _split(obj) -> tuple[BoundarySet, dict | None]:
    # a solved head says what it stores (PDEHead.storage_settings): the file format needs no solver
    if callable(getattr(obj, "storage_settings", None)) and isinstance(getattr(obj, "bset", None), BoundarySet):
        return obj.bset, obj.storage_settings()
    if isinstance(obj, BoundarySet):
        settings = obj.meta.get("pde_settings")
        # a set saved from now on says which surface it was made for (older files: the paper's)
        settings = dict(settings) if isinstance(settings, dict) else {"smoothing_is_default": True}
        settings.setdefault("continuity", CONTINUITY.default)
        return obj, settings
    raise StorageError(f"can only store a BoundarySet or a PDEHead, got {type(obj).__name__}")


def dumps_boundaries(obj) -> bytes:
    """Encode a BoundarySet or a PDEHead (curves + solver settings) as bytes (format version 1).

    Parameters
    ----------
    obj : BoundarySet or PDEHead

    Returns
    -------
    bytes
    """
    bset, settings = _split(obj)
    curves = bset.curves
    n, M, _ = curves.shape
    planar = bool(np.all(np.ptp(curves[..., 2], axis=1) == 0))
    coords = 2 if planar else 3
    # per-curve origin on the quantum grid (stored as integers), z exact for planar curves
    origins = np.round(curves.mean(axis=1) / QUANTUM_MM) * QUANTUM_MM
    if planar:
        origins[:, 2] = curves[:, 0, 2]
    origin_q = np.round(origins[:, :2] / QUANTUM_MM).astype("<i8")
    derived_knots = (bool(np.array_equal(knots_from_heights(bset.heights), bset.u_knots))
                     if _monotone(bset.heights) else False)
    q = np.round((curves[..., :coords] - origins[:, None, :coords]) / QUANTUM_MM)
    if np.max(np.abs(q)) > 2 ** 40:
        raise StorageError("curve coordinates are too far from their centroid to be stored")
    q = q.astype(np.int64).transpose(0, 2, 1)                               # (n, coords, M)
    d = q.copy()
    d[..., 1:] = np.diff(q, axis=-1)
    d[..., 2:] = np.diff(d[..., 1:], axis=-1)                               # 2nd differences after the first two
    z = _zigzag(d.ravel())
    planes = max(1, int(np.ceil(int(z.max()).bit_length() / 8)))
    body = b"".join(((z >> np.uint64(8 * b)) & np.uint64(255)).astype(np.uint8).tobytes() for b in range(planes))
    meta = dict(bset.meta)
    meta.pop("pde_settings", None)
    header = {
        "curves": int(n), "samples": int(M), "quantum_mm": QUANTUM_MM, "planar_z": planar,
        "coords": coords, "byte_planes": planes, "knots_from_heights": derived_knots, "pde_settings": settings,
    }
    header_bytes = json.dumps(header, separators=(",", ":")).encode("utf-8")
    meta_bytes = json.dumps(_json_safe(meta), separators=(",", ":")).encode("utf-8")
    payload = b"".join([struct.pack("<I", len(meta_bytes)), meta_bytes,
                        bset.heights.astype("<f8").tobytes(),
                        b"" if derived_knots else bset.u_knots.astype("<f8").tobytes(),
                        bset.slice_indices.astype("<i4").tobytes(), origin_q.tobytes(),
                        origins[:, 2].astype("<f8").tobytes(), body])
    packed = zlib.compress(payload, 9)
    return b"".join([_FIXED.pack(MAGIC, VERSION, len(header_bytes)), header_bytes,
                     _PAYLOAD.pack(len(packed), zlib.crc32(header_bytes + packed)), packed])


def loads_boundaries(data: bytes, name: str = "<bytes>") -> BoundarySet:
    """Decode bytes written by :func:`dumps_boundaries`.

    Returns a BoundarySet; stored solver settings are in ``meta["pde_settings"]``
    (``{"smoothing": [...], "modes": N, "smoothing_is_default": bool}``).

    Raises
    ------
    StorageError
        ``"<name>: <problem>"`` for a file that is not a boundary file, is
        truncated or corrupt, or has an unknown version.
    """
    def fail(problem: str) -> StorageError:
        return StorageError(f"{name}: {problem}")

    header_bytes, packed = _split_container(bytes(data), fail)
    try:
        header = json.loads(header_bytes.decode("utf-8"))
        n, M = int(header["curves"]), int(header["samples"])
        quantum = float(header["quantum_mm"])
        coords, planes = int(header["coords"]), int(header["byte_planes"])
        derived_knots = bool(header.get("knots_from_heights", False))
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise fail(f"corrupt header ({exc.__class__.__name__}: {exc})") from None
    if not (n >= 4 and M >= 8 and coords in (2, 3) and 1 <= planes <= 8 and quantum > 0):
        raise fail(f"corrupt header (curves={n}, samples={M}, coords={coords}, byte_planes={planes})")
    payload = decompress_bounded(packed, MAX_STORED_BOUNDARY_BYTES.default, name)
    try:
        mlen = struct.unpack_from("<I", payload, 0)[0]
        meta = json.loads(payload[4:4 + mlen].decode("utf-8")) if mlen else {}
    except (zlib.error, struct.error, ValueError, UnicodeDecodeError) as exc:
        raise fail(f"corrupt payload ({exc})") from None
    if not isinstance(meta, dict):
        raise fail("corrupt payload (metadata is not an object)")
    need = 4 + mlen + n * 8 * (1 if derived_knots else 2) + n * 4 + n * 24 + n * coords * M * planes
    if len(payload) != need:
        raise fail(f"corrupt payload: {len(payload)} bytes, expected {need}")
    heights, knots, slices, curves = _decode_curves(payload, 4 + mlen, n, M, coords, planes, quantum,
                                                     derived_knots, fail)
    if header.get("pde_settings") is not None:
        meta["pde_settings"] = header["pde_settings"]
    try:
        return BoundarySet(curves, slices.copy(), heights.copy(), knots.copy(), meta)
    except BoundaryError as exc:
        raise fail(f"invalid boundary curves ({exc})") from None


def _split_container(data: bytes, fail) -> tuple[bytes, bytes]:
    """The JSON header's bytes and the compressed payload of a ``.pdeh`` file, after checking its magic,
    version, lengths and CRC-32 (``fail(problem)`` builds the error to raise)."""
    if len(data) < _FIXED.size:
        raise fail(f"truncated: {len(data)} bytes is shorter than the {_FIXED.size}-byte header")
    magic, version, hlen = _FIXED.unpack_from(data, 0)
    if magic != MAGIC:
        raise fail("not a PDE Head boundary file (bad magic bytes)")
    if version != VERSION:
        raise fail(f"unknown format version {version} (this PDE Head reads version {VERSION})")
    pos = _FIXED.size
    if len(data) < pos + hlen + _PAYLOAD.size:
        raise fail("truncated inside the header")
    header_bytes = data[pos:pos + hlen]
    plen, crc = _PAYLOAD.unpack_from(data, pos + hlen)
    packed = data[pos + hlen + _PAYLOAD.size:pos + hlen + _PAYLOAD.size + plen]
    if len(packed) != plen:
        raise fail(f"truncated: payload has {len(packed)} of {plen} bytes")
    if zlib.crc32(header_bytes + packed) != crc:
        raise fail("corrupt (CRC-32 mismatch)")
    return header_bytes, packed


class _Cursor:
    """Reads consecutive little-endian arrays from a byte string."""

    def __init__(self, payload: bytes, offset: int):
        self.payload, self.offset = payload, offset

    def take(self, dtype, count: int) -> np.ndarray:
        out = np.frombuffer(self.payload, dtype, count, self.offset)
        self.offset += out.nbytes
        return out


def _decode_curves(payload, offset, n, M, coords, planes, quantum, derived_knots, fail):
    """Heights, knots, slice indices and the (n, M, 3) curves from the payload after its metadata."""
    cur = _Cursor(payload, offset)
    heights = cur.take("<f8", n)
    if derived_knots:
        try:
            knots = knots_from_heights(heights)
        except BoundaryError as exc:
            raise fail(f"corrupt heights ({exc})") from None
    else:
        knots = cur.take("<f8", n)
    slices = cur.take("<i4", n)
    origins = np.empty((n, 3))
    origins[:, :2] = cur.take("<i8", 2 * n).reshape(n, 2) * quantum
    origins[:, 2] = cur.take("<f8", n)
    count = n * coords * M
    z = np.zeros(count, np.uint64)
    for b in range(planes):
        z |= cur.take(np.uint8, count).astype(np.uint64) << np.uint64(8 * b)
    d = _unzigzag(z).reshape(n, coords, M)
    d[..., 1:] = np.cumsum(d[..., 1:], axis=-1)                             # undo the 2nd differences
    q = np.cumsum(d, axis=-1)
    curves = np.empty((n, M, 3))
    curves[..., :coords] = origins[:, None, :coords] + q.transpose(0, 2, 1) * quantum
    if coords == 2:
        curves[..., 2] = origins[:, None, 2]
    return heights, knots, slices, curves

def save_boundaries(obj, path: str | os.PathLike) -> int:
    """Write a BoundarySet or a PDEHead (with its smoothing and modes) to ``path``.

    Returns the number of bytes written. See ``docs/boundary_format.md``.
    """
    data = dumps_boundaries(obj)
    try:
        with open(path, "wb") as fh:
            fh.write(data)
    except OSError as exc:
        raise StorageError(f"{os.fspath(path)}: cannot write ({exc.strerror or exc})") from None
    return len(data)


def load_boundaries(path: str | os.PathLike) -> BoundarySet:
    """Read a boundary file; solver settings, if stored, are in ``meta["pde_settings"]``."""
    name = os.fspath(path)
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise StorageError(f"{name}: cannot read ({exc.strerror or exc})") from None
    return loads_boundaries(data, name)
