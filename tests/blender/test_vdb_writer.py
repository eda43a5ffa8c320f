"""Our own .vdb writer (operators/volume/vdb_writer.py), used where Blender has no OpenVDB bindings (bpy 4.2).

- On Blenders with bindings (4.4+): its files read back with Blender's ``openvdb`` module give the
  same grids as ``FloatGrid.copyFromArray(tolerance=0)``: active voxels, box, values, transform,
  background, class, half floats, metadata.
- On every Blender: Blender itself loads its files as a Volume with the written grids and transforms.
"""
from __future__ import annotations

import gc

import numpy as np
import pytest


def _grids():
    """Two grids: shapes not multiples of 8, spanning several lower nodes, an oblique transform."""
    rng = np.random.default_rng(7)
    w = rng.random((37, 150, 21)).astype(np.float32)
    w[w < 0.5] = 2.0  # background: inactive
    intensity = np.zeros((300, 9, 140), np.float32)
    intensity[100:250, 2:7, 5:139] = rng.random((150, 5, 134))
    matrix = np.array([[0.002, 0.0, 0.0005, 0], [0.0001, 0.003, 0, 0], [0, -0.0002, 0.004, 0], [0.1, -0.2, 0.3, 1]])
    return w, intensity, matrix


def _write(ext, path):
    w, intensity, matrix = _grids()
    DenseGrid = ext.volume.vdb_writer.DenseGrid
    ext.volume.vdb_writer.write_vdb(
        path, (DenseGrid("w", w, 2.0, False, matrix.tolist(), {"pdehead_window": "-5.0 900.0"}),
               DenseGrid("intensity", intensity, 0.0, True, matrix.tolist(), {})))
    return w, intensity, matrix


def test_files_read_back_with_openvdb_equal_copy_from_array(ext, tmp_path):
    import bpy
    openvdb = ext.compat.openvdb_module()
    if openvdb is None:
        pytest.skip(f"bpy {bpy.app.version_string} has no OpenVDB bindings to read the file back "
                    "(checked on the Blenders that have them)")
    path = tmp_path / "own.vdb"
    w, intensity, matrix = _write(ext, path)
    assert not (tmp_path / "own.vdb.partial").exists()
    grids, _meta = openvdb.readAll(str(path))
    try:
        by_name = {g.name: g for g in grids}
        assert set(by_name) == {"w", "intensity"}
        for name, src, background, half, tol in (("w", w, 2.0, False, 0.0), ("intensity", intensity, 0.0, True, 5e-4)):
            g = by_name[name]
            ref = openvdb.FloatGrid(background=background)
            ref.copyFromArray(np.ascontiguousarray(src), tolerance=0.0)
            assert g.background == background
            assert g.activeVoxelCount() == ref.activeVoxelCount() == int(np.count_nonzero(src != background))
            assert g.evalActiveVoxelBoundingBox() == ref.evalActiveVoxelBoundingBox()
            assert g.gridClass == openvdb.GridClass.FOG_VOLUME and g.saveFloatAsHalf == half
            out = np.full(src.shape, -7.0, np.float32)
            g.copyToArray(out)
            assert np.abs(out - src).max() <= tol  # exact floats; half floats to 2^-11 relative
            lo, hi = g.evalMinMax()
            assert lo == pytest.approx(src[src != background].min(), abs=tol)
            assert hi == pytest.approx(src[src != background].max(), abs=tol)
            for ijk in ((0, 0, 0), (5, 7, 3), (36, 149, 20)):
                expected = (np.array([*ijk, 1.0]) @ matrix)[:3]
                np.testing.assert_allclose(g.transform.indexToWorld(ijk), expected, atol=1e-12)
            del ref, g
        assert by_name["w"]["pdehead_window"] == "-5.0 900.0"
    finally:
        del grids, by_name
        gc.collect()


def test_blender_loads_the_files_with_their_grids_and_transforms(ext, tmp_path):
    """On every Blender (4.2 included): a Volume reading our file lists its grids with our transforms."""
    import bpy
    path = tmp_path / "own.vdb"
    w, intensity, matrix = _write(ext, path)
    vol = bpy.data.volumes.new("own")
    vol.filepath = str(path)
    grids = vol.grids
    assert grids.load(), grids.error_message
    assert sorted(g.name for g in grids) == ["intensity", "w"]
    for g in grids:
        assert g.data_type == 'FLOAT' and g.channels == 1
        assert g.load()
        # Blender's matrix_object: column vectors, so the transpose of OpenVDB's row-vector matrix
        np.testing.assert_allclose(np.array(g.matrix_object), matrix.T, atol=1e-7)


def test_bad_grids_are_refused_and_leave_no_file(ext, tmp_path):
    DenseGrid = ext.volume.vdb_writer.DenseGrid
    eye = np.eye(4).tolist()
    path = tmp_path / "bad.vdb"
    with pytest.raises(ValueError, match="used twice"):
        ext.volume.vdb_writer.write_vdb(path, [DenseGrid("a", np.ones((2, 2, 2)), 0.0, False, eye, {}),
                                      DenseGrid("a", np.ones((2, 2, 2)), 0.0, False, eye, {})])
    with pytest.raises(ValueError, match="3-D"):
        ext.volume.vdb_writer.write_vdb(path, [DenseGrid("b", np.ones((4, 4)), 0.0, False, eye, {})])
    assert list(tmp_path.iterdir()) == []
