"""Compact boundary storage (section 5.2): round trip, size, settings, errors."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from pde_synthetic import head_bset
from pdehead_addon import BoundarySet, PDEHead, StorageError
from pdehead_addon.io.storage import (
    MAGIC,
    QUANTUM_MM,
    dumps_boundaries,
    load_boundaries,
    loads_boundaries,
    save_boundaries,
)
from pdehead_addon.pde.head_files import load_head, loads_head
from pdehead_addon.pde.pde_surface import solve_pde


@pytest.fixture(scope="module")
def bset():
    return head_bset(patches=10, samples=256)


def max_vertex_distance(h1: PDEHead, h2: PDEHead) -> float:
    return float(np.linalg.norm(h1.surface(100, 200).vertices - h2.surface(100, 200).vertices, axis=1).max())


def test_round_trip_boundary_set(bset, tmp_path):
    path = tmp_path / "head.pdeh"
    size = save_boundaries(bset, path)
    assert size == path.stat().st_size
    back = load_boundaries(path)
    assert isinstance(back, BoundarySet)
    assert np.abs(back.curves - bset.curves).max() <= QUANTUM_MM / 2 + 1e-12
    assert np.array_equal(back.curves[..., 2], bset.curves[..., 2])          # z of axial curves: exact
    assert np.array_equal(back.u_knots, bset.u_knots) and np.array_equal(back.heights, bset.heights)
    assert np.array_equal(back.slice_indices, bset.slice_indices)
    assert back.meta["source"] == "synthetic head"
    assert back.meta["pde_settings"] == {"smoothing_is_default": True, "continuity": "c2"}   # made for today's surface
    assert max_vertex_distance(solve_pde(bset), solve_pde(back)) <= 0.05


def test_round_trip_head_keeps_settings(bset, tmp_path):
    head = solve_pde(bset, smoothing=0.08, modes=40)
    path = tmp_path / "head.pdeh"
    save_boundaries(head, path)
    settings = load_boundaries(path).meta["pde_settings"]
    assert settings["modes"] == 40 and np.allclose(settings["smoothing"], 0.08)
    assert settings["smoothing_is_default"] is False
    again = load_head(path)
    assert again.modes == 40 and np.allclose(again.smoothing, 0.08)
    assert max_vertex_distance(head, again) <= 0.05
    # default settings stay "default" (recomputed from the knots on load)
    default = loads_head(dumps_boundaries(solve_pde(bset)))
    assert np.allclose(default.smoothing, solve_pde(bset).smoothing)
    # bytes and file forms are the same
    assert dumps_boundaries(head) == path.read_bytes()
    assert np.array_equal(loads_boundaries(path.read_bytes()).curves, load_boundaries(path).curves)


def test_size_t10_m256(bset):
    data = dumps_boundaries(solve_pde(bset))
    print(f"t=10, M=256 boundary file: {len(data)} bytes")
    assert len(data) <= 16_000
    assert data[:8] == MAGIC


def test_non_planar_curves_and_odd_metadata(bset):
    curves = bset.curves.copy()
    curves[..., 2] += 0.7 * np.sin(np.linspace(0, 2 * np.pi, bset.samples, endpoint=False))
    meta = {"array": np.arange(3), "scalar": np.float32(1.5), "path": __import__("pathlib").Path("/x/y"),
            "object": object(), "nested": {"t": np.int64(4)}}
    b = BoundarySet(curves, bset.slice_indices, bset.heights, bset.u_knots, meta)
    back = loads_boundaries(dumps_boundaries(b))
    assert np.abs(back.curves - curves).max() <= QUANTUM_MM / 2 + 1e-12
    assert back.meta["array"] == [0, 1, 2] and back.meta["scalar"] == 1.5 and back.meta["path"] == "/x/y"
    assert "object" not in back.meta and back.meta["nested"] == {"t": 4}


def test_custom_knots_are_stored(bset):
    knots = bset.u_knots.copy()
    knots[1] += 0.01                                                          # not derived from heights
    b = BoundarySet(bset.curves, bset.slice_indices, bset.heights, knots, {})
    assert np.array_equal(loads_boundaries(dumps_boundaries(b)).u_knots, knots)


def corrupt(data: bytes, offset: int) -> bytes:
    b = bytearray(data)
    b[offset] ^= 0x10
    return bytes(b)


def test_bad_files_raise_storage_error_naming_the_file(bset, tmp_path):
    data = dumps_boundaries(bset)
    version_bumped = data[:8] + struct.pack("<H", 99) + data[10:]
    cases = {
        "empty.pdeh": (b"", "truncated"),
        "short.pdeh": (data[:11], "truncated"),
        "cut_header.pdeh": (data[:30], "truncated"),
        "cut_payload.pdeh": (data[:-100], "truncated"),
        "magic.pdeh": (b"NOTAFILE" + data[8:], "not a PDE Head boundary file"),
        "version.pdeh": (version_bumped, "unknown format version 99"),
        "flip_header.pdeh": (corrupt(data, 20), "corrupt"),
        "flip_payload.pdeh": (corrupt(data, len(data) - 50), "corrupt"),
    }
    for name, (content, problem) in cases.items():
        path = tmp_path / name
        path.write_bytes(content)
        with pytest.raises(StorageError) as info:
            load_boundaries(path)
        assert str(path) in str(info.value) and problem in str(info.value), str(info.value)
    with pytest.raises(StorageError, match="missing.pdeh: cannot read"):
        load_boundaries(tmp_path / "missing.pdeh")
    with pytest.raises(StorageError, match="<bytes>: not a PDE Head"):
        loads_boundaries(b"x" * 64)
    with pytest.raises(StorageError, match="BoundarySet or a PDEHead"):
        dumps_boundaries(bset.curves)
    # random bit flips anywhere are detected (CRC over header and payload)
    rng = np.random.default_rng(0)
    for offset in rng.integers(0, len(data), 40):
        with pytest.raises(StorageError):
            loads_boundaries(corrupt(data, int(offset)))


def test_cthead_file_size_and_fidelity(cthead_bset):
    head = solve_pde(cthead_bset)
    data = dumps_boundaries(head)
    print(f"CThead t={cthead_bset.patches}, M={cthead_bset.samples}: {len(data)} bytes")
    assert len(data) <= 16_000
    assert max_vertex_distance(head, loads_head(data)) <= 0.05
