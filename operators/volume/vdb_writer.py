"""A small OpenVDB file writer for dense float grids, for Blenders without OpenVDB Python bindings.

Blender 4.2's ``bpy`` from PyPI ships ``libopenvdb`` but neither ``openvdb`` nor
``pyopenvdb``, yet Blender itself reads .vdb files. This module writes the same file
``openvdb.write`` writes for a ``FloatGrid`` filled with ``copyFromArray(a, tolerance=0)``:
the standard ``Tree_float_5_4_3`` tree (root -> 32^3 -> 16^3 internal nodes -> 8^3 leaves),
file format 224, no compression (Blender reads it; files are larger than zip/blosc ones).

Format (OpenVDB ``io/Archive.cc``, ``tree/RootNode.h``, ``InternalNode.h``, ``LeafNode.h``;
all little-endian): file header (magic, format and library versions, grid-offset flag,
UUID), file metadata, grid count, then per grid its descriptor (name, type, stream
offsets), compression flags, metadata, transform (``AffineMap``: 4x4 doubles, row vectors),
topology (node masks and tile values) and buffers (one per leaf: value mask, then 512 values).

Voxels whose value differs from the background are active, as with
``copyFromArray(tolerance=0)``; a leaf is stored for every 8^3 block holding an active voxel.
No bpy here: it is checked in the tests by reading files back with the ``openvdb`` module
of Blender 4.4+ (``tests/blender/test_vdb_writer.py``).
"""
from __future__ import annotations

import os
import struct
import uuid
from pathlib import Path
from typing import BinaryIO, Iterable, NamedTuple

import numpy as np

from ...pdehead_addon import check_size, checked_output

FILE_FORMAT_VERSION = 224        # OPENVDB_FILE_VERSION_MULTIPASS_IO, what OpenVDB 6 - 12 write
LIBRARY_VERSION = (11, 0)        # informational only; readers check the format version
MAGIC = 0x56444220               # OPENVDB_MAGIC (" BDV")
NO_MASK_AND_ALL_VALS = 6         # per-node value-array flag: every value written, no selection mask
LOG2 = (5, 4, 3)                 # Tree_float_5_4_3: upper, lower internal node, leaf (log2 of side)
LEAF = 1 << LOG2[2]              # 8 voxels
LOWER = LEAF << LOG2[1]          # 128 voxels per lower internal node
UPPER = LOWER << LOG2[0]         # 4096 voxels per upper internal node (a root child)


class DenseGrid(NamedTuple):
    """One float grid to write.

    data : float array [i, j, k] (index x, y, z) of the voxels from index (0, 0, 0)
    background : value of every voxel outside ``data`` and of inactive voxels
    half : store values as 16-bit floats (``saveFloatAsHalf``)
    matrix : 4x4 index-to-world matrix in OpenVDB's row-vector form (translation in the last row)
    metadata : extra string metadata of the grid
    """

    name: str
    data: np.ndarray
    background: float
    half: bool
    matrix: list
    metadata: dict


def _string(s: str) -> bytes:
    b = s.encode("utf-8")
    return struct.pack("<I", len(b)) + b


def _metadata(items: dict) -> bytes:
    """An OpenVDB MetaMap: count, then name, type name, byte size, value of each entry."""
    out = [struct.pack("<I", len(items))]
    for name, value in sorted(items.items()):
        if isinstance(value, bool):
            type_name, raw = "bool", struct.pack("<?", value)
        elif isinstance(value, (int, np.integer)):
            type_name, raw = "int64", struct.pack("<q", int(value))
        elif isinstance(value, str):
            type_name, raw = "string", value.encode("utf-8")
        elif len(value) == 3:
            type_name, raw = "vec3i", struct.pack("<3i", *(int(v) for v in value))
        else:
            raise TypeError(f"metadata {name!r}: unsupported value {value!r}")
        out += [_string(name), _string(type_name), struct.pack("<I", len(raw)), raw]
    return b"".join(out)


def _mask(bits: np.ndarray) -> bytes:
    """A node mask: bit n in 64-bit word n // 64 at position n % 64 (little-endian words)."""
    return np.packbits(bits.reshape(-1).astype(bool), bitorder="little").tobytes()


def _values(values: np.ndarray, half: bool) -> bytes:
    """A node's value array as ``io::writeCompressedValues`` writes it without compression."""
    return bytes([NO_MASK_AND_ALL_VALS]) + np.ascontiguousarray(values, "<f2" if half else "<f4").tobytes()


def _node_offset(coords: np.ndarray, log2_child: int, log2_dim: int) -> np.ndarray:
    """Linear index of child coords inside their parent node: x-major, z fastest (OpenVDB's order)."""
    c = (np.asarray(coords) >> log2_child) & ((1 << log2_dim) - 1)
    return (c[:, 0] << (2 * log2_dim)) + (c[:, 1] << log2_dim) + c[:, 2]


def _leaves(data: np.ndarray, background: float):
    """Origins (n, 3) int, masks (n, 512) bool and values (n, 512) of the leaves, in tree order."""
    pad = [(0, (-s) % LEAF) for s in data.shape]
    padded = np.pad(data, pad, constant_values=background) if any(p[1] for p in pad) else data
    bx, by, bz = (s // LEAF for s in padded.shape)
    blocks = padded.reshape(bx, LEAF, by, LEAF, bz, LEAF).transpose(0, 2, 4, 1, 3, 5)
    active = blocks != np.float32(background)
    keep = active.any(axis=(3, 4, 5))
    origins = np.argwhere(keep) * LEAF
    # tree order: lower node by its place in the (single) upper node, then the leaf in the lower node
    order = np.lexsort((_node_offset(origins, LOG2[2], LOG2[1]), _node_offset(origins, LOG2[2] + LOG2[1], LOG2[0])))
    origins = origins[order]
    idx = tuple((origins // LEAF).T)
    return origins, active[idx].reshape(-1, LEAF ** 3), blocks[idx].reshape(-1, LEAF ** 3)


def _write_grid(f: BinaryIO, grid: DenseGrid) -> None:
    data = np.asarray(grid.data, dtype=np.float32)
    if data.ndim != 3 or min(data.shape) < 1:
        raise ValueError(f"grid {grid.name!r}: need a non-empty 3-D array, got shape {data.shape}")
    if max(data.shape) > UPPER:
        raise ValueError(f"grid {grid.name!r}: at most {UPPER} voxels per axis, got {data.shape}")
    half = bool(grid.half)
    background = np.float32(np.float16(grid.background)) if half else np.float32(grid.background)
    origins, masks, values = _leaves(data, float(background))
    leaf_masks = np.packbits(masks, axis=1, bitorder="little")  # (n, 64) bytes: each leaf's value mask
    active = data != background
    count = int(np.count_nonzero(active))
    bbox_min, bbox_max = [0, 0, 0], [0, 0, 0]
    if count:
        for a in range(3):
            along = np.flatnonzero(active.any(axis=tuple(b for b in range(3) if b != a)))
            bbox_min[a], bbox_max[a] = int(along[0]), int(along[-1])
    del active

    f.write(_string(grid.name))
    f.write(_string("Tree_float_5_4_3" + ("_HalfFloat" if half else "")))
    f.write(_string(""))  # instance parent: none
    offsets_at = f.tell()
    f.write(struct.pack("<3q", 0, 0, 0))  # grid, block and end positions, filled in below
    grid_pos = f.tell()
    f.write(struct.pack("<I", 0))  # compression flags: none
    meta = {"class": "fog volume", "name": grid.name, "is_saved_as_half_float": half,
            "file_bbox_min": tuple(bbox_min), "file_bbox_max": tuple(bbox_max),
            "file_voxel_count": count, **grid.metadata}
    f.write(_metadata(meta))
    matrix = np.asarray(grid.matrix, dtype="<f8").reshape(4, 4)
    f.write(_string("AffineMap") + matrix.tobytes())

    # topology: one buffer per leaf; the root holds no tiles and one child (the upper node at 0, 0, 0)
    f.write(struct.pack("<i", 1))
    f.write(struct.pack("<f", background))
    n_children = 1 if len(origins) else 0
    f.write(struct.pack("<II", 0, n_children))
    if n_children:
        f.write(struct.pack("<3i", 0, 0, 0))
        lower_of_leaf = _node_offset(origins, LOG2[2] + LOG2[1], LOG2[0])
        lowers, first = np.unique(lower_of_leaf, return_index=True)
        upper_children = np.zeros(1 << (3 * LOG2[0]), bool)
        upper_children[lowers] = True
        f.write(_mask(upper_children) + _mask(np.zeros_like(upper_children)))
        f.write(_values(np.where(upper_children, 0.0, background), half))
        bounds = list(first) + [len(origins)]
        for n in range(len(lowers)):
            leaf_offsets = _node_offset(origins[bounds[n]:bounds[n + 1]], LOG2[2], LOG2[1])
            lower_children = np.zeros(1 << (3 * LOG2[1]), bool)
            lower_children[leaf_offsets] = True
            f.write(_mask(lower_children) + _mask(np.zeros_like(lower_children)))
            f.write(_values(np.where(lower_children, 0.0, background), half))
            f.write(leaf_masks[bounds[n]:bounds[n + 1]].tobytes())
    block_pos = f.tell()
    # buffers: every leaf in tree order, its value mask then its 512 values (one array, one write)
    if len(origins):
        raw = np.ascontiguousarray(values, "<f2" if half else "<f4").view(np.uint8).reshape(len(origins), -1)
        f.write(np.concatenate([leaf_masks, np.full((len(origins), 1), NO_MASK_AND_ALL_VALS, np.uint8), raw],
                               axis=1).tobytes())
        del raw
    end_pos = f.tell()
    f.seek(offsets_at)
    f.write(struct.pack("<3q", grid_pos, block_pos, end_pos))
    f.seek(end_pos)


def write_vdb(path: str | os.PathLike, grids: Iterable[DenseGrid]) -> Path:
    """Write float grids to an OpenVDB file, one grid at a time (memory stays one grid).

    Parameters
    ----------
    path : path-like
        Output .vdb file (overwritten; its folder must exist).
    grids : iterable of DenseGrid
        Unique names; each grid's dense data starts at index (0, 0, 0).

    Returns
    -------
    Path of the written file.
    """
    path = Path(os.fspath(path))
    # a temporary name of this write (two processes never share one), its size checked, then renamed:
    # a full disk or a failure never leaves a half file under the real name (nor a partial one)
    with checked_output(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(struct.pack("<qIII", MAGIC, FILE_FORMAT_VERSION, *LIBRARY_VERSION))
            f.write(b"\x01")  # has grid offsets: readers may seek to each grid
            f.write(str(uuid.uuid4()).encode("ascii"))  # 36 characters
            f.write(_metadata({}))
            count_at = f.tell()
            f.write(struct.pack("<i", 0))
            count, names = 0, set()
            for grid in grids:
                if grid.name in names:
                    raise ValueError(f"grid name {grid.name!r} used twice")
                names.add(grid.name)
                _write_grid(f, grid)
                count += 1
            end = f.tell()
            f.seek(count_at)
            f.write(struct.pack("<i", count))
            f.seek(end)
        check_size(tmp, end)
    return path
