"""Checked writes and bounded reads (pdehead_addon/io/safe_io.py): a failing write leaves nothing, a stored
payload never decompresses past its budget (pdehead_addon/defaults.py)."""
from __future__ import annotations

import errno
import json
import struct
import zlib

import numpy as np
import pytest

from pde_synthetic import head_bset
from pdehead_addon import StorageError, defaults as D
from pdehead_addon.core.errors import PDEError
from pdehead_addon.io import safe_io
from pdehead_addon.io.export import export_mesh
from pdehead_addon.io.storage import _FIXED, _PAYLOAD, MAGIC, VERSION, dumps_boundaries, loads_boundaries
from pdehead_addon.pde.solid_ct_table import SolidCTTable


class _FailingFile:
    """A file object whose writes fail with ENOSPC once `limit` bytes were written (a disk filling up)."""

    def __init__(self, fh, limit):
        self.fh, self.limit, self.written = fh, limit, 0

    def write(self, data):
        if self.written + len(data) > self.limit:
            self.fh.write(data[: max(0, self.limit - self.written)])
            raise OSError(errno.ENOSPC, "No space left on device")
        self.written += len(data)
        return self.fh.write(data)

    def __getattr__(self, name):
        return getattr(self.fh, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.fh.close()
        return False


def _full_disk_after(monkeypatch, limit):
    import builtins
    real_open = builtins.open

    def fake_open(path, mode="r", *args, **kwargs):
        fh = real_open(path, mode, *args, **kwargs)
        return _FailingFile(fh, limit) if "w" in mode else fh
    monkeypatch.setattr(builtins, "open", fake_open)


def test_a_write_failing_partway_leaves_no_file_and_names_it(tmp_path, monkeypatch):
    target = tmp_path / "table.csv"
    _full_disk_after(monkeypatch, 1000)
    with pytest.raises(safe_io.WriteError) as info:
        safe_io.write_text_checked(target, "x" * 5000)
    assert str(target) in str(info.value) and "No space left" in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_an_existing_file_survives_a_failed_rewrite(tmp_path, monkeypatch):
    target = tmp_path / "landmarks.csv"
    target.write_text("the good one")
    _full_disk_after(monkeypatch, 10)
    with pytest.raises(safe_io.WriteError):
        safe_io.write_text_checked(target, "y" * 100)
    assert target.read_text() == "the good one" and [p.name for p in tmp_path.iterdir()] == ["landmarks.csv"]


def test_a_library_write_that_comes_out_short_is_an_error(tmp_path):
    """A writer that 'succeeds' without writing (OpenVDB on a full disk) is caught by the size check."""
    target = tmp_path / "v.vdb"
    with pytest.raises(safe_io.WriteError) as info:
        safe_io.write_with(target, lambda tmp: open(tmp, "wb").close(), minimum=64)
    assert str(target) in str(info.value) and "0 bytes" in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_a_mesh_export_on_a_full_disk_leaves_no_partial_stl(tmp_path, monkeypatch):
    from pdehead_addon import solve_pde
    from pdehead_addon.io.export import _triangles
    head = solve_pde(head_bset(patches=4, samples=64))
    mesh = head.surface(24, 48, caps=True)
    ok = tmp_path / "ok.stl"
    export_mesh(mesh, ok)
    assert ok.stat().st_size == 84 + 50 * len(_triangles(mesh)[1])
    _full_disk_after(monkeypatch, 4096)
    with pytest.raises(StorageError) as info:
        export_mesh(mesh, tmp_path / "skull.stl")
    assert "skull.stl" in str(info.value) and "No space left" in str(info.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok.stl"]


def _boundary_bomb(payload_bytes: int) -> bytes:
    """A boundary file whose header is valid and whose payload decompresses to `payload_bytes` zeros."""
    good = dumps_boundaries(head_bset(patches=4, samples=64))
    hlen = _FIXED.unpack_from(good, 0)[2]
    header = good[_FIXED.size:_FIXED.size + hlen]
    packed = zlib.compress(b"\0" * payload_bytes, 9)
    return b"".join([_FIXED.pack(MAGIC, VERSION, len(header)), header,
                     _PAYLOAD.pack(len(packed), zlib.crc32(header + packed)), packed])


def test_a_stored_boundary_payload_is_read_within_its_budget():
    budget = D.MAX_STORED_BOUNDARY_BYTES.default
    bomb = _boundary_bomb(budget + 1)
    assert len(bomb) < budget // 500                        # small in the file, large when inflated
    with pytest.raises(StorageError) as info:
        loads_boundaries(bomb, "study 'X' boundaries")
    assert "study 'X' boundaries" in str(info.value) and "budget" in str(info.value)
    with pytest.raises(StorageError) as info:                # within the budget: the usual size check
        loads_boundaries(_boundary_bomb(1000), "b")
    assert "expected" in str(info.value)


def test_a_stored_ct_table_is_read_within_its_budget():
    budget = D.MAX_STORED_CT_TABLE_BYTES.default
    for shape in ([4096, 4096, 4096], [budget + 1, 1, 1], [-1, 2, 2], "x"):
        header = json.dumps({"format": SolidCTTable.PACK_FORMAT, "shape": shape, "window": [0, 1],
                             "range": [0, 1]}).encode()
        raw = struct.pack("<I", len(header)) + header + zlib.compress(b"\0" * 1000)
        with pytest.raises(PDEError) as info:
            SolidCTTable.from_bytes(raw)
        assert "cannot be read" in str(info.value)
    header = json.dumps({"format": SolidCTTable.PACK_FORMAT, "shape": [256, 256, 256], "window": [0, 1],
                         "range": [0, 1]}).encode()                     # 16 MB claimed, 64 MB inflated
    raw = struct.pack("<I", len(header)) + header + zlib.compress(b"\0" * (budget + 1), 9)
    with pytest.raises(PDEError) as info:
        SolidCTTable.from_bytes(raw)
    assert "budget" in str(info.value)


def test_decompress_bounded_passes_what_fits():
    data = np.arange(10000, dtype=np.uint16).tobytes()
    assert safe_io.decompress_bounded(zlib.compress(data), len(data), "x") == data
    with pytest.raises(StorageError):
        safe_io.decompress_bounded(zlib.compress(data), len(data) - 1, "x")
    with pytest.raises(StorageError):
        safe_io.decompress_bounded(zlib.compress(data)[:-10], len(data), "x")
