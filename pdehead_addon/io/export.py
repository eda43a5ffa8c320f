"""Watertight STL / OBJ / PLY of the skin and the skull for 3-D printing, in millimetres.

Every writer triangulates the :class:`~.mesh.Mesh` (quads split along their 0-2
diagonal, the split :func:`~.mesh_geometry.triangulate` uses), keeps the
outward winding and writes patient LPS millimetres (1 unit = 1 mm, the unit
slicers assume for STL).  :func:`export_mesh` refuses a mesh that is not
watertight (every edge shared by exactly two faces with opposite directions),
so a printed part is always closed.
"""
from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from ..core.errors import PDEHeadError
from ..core.mesh import Mesh
from ..core.mesh_geometry import mesh_triangles
from ..core.provenance import ASCII_SPELLING, provenance_lines, short_provenance
from .safe_io import write_with

FORMATS = ("stl", "obj", "ply")


def input_folder_conflict(out: str | os.PathLike, source: str | os.PathLike | None) -> str | None:
    """Why ``out`` may not take an export of the input ``source``, or None.

    Nothing is written into the user's input: for a folder input (a DICOM series, an image stack) not the
    folder or any folder inside it; for a file input (a ``--skull-mesh``, a NIfTI) not the file's own folder,
    where the export's files (``skull.stl``, ...) could overwrite or mix with it, but a new folder beside or
    below it is fine (``--skull-mesh skull.stl --export out/face``). Paths are compared resolved.
    """
    if not source:
        return None
    out_p, src = Path(out).resolve(), Path(source).resolve()
    if src.is_dir():
        if out_p == src or src in out_p.parents:
            return f"{out_p}: will not write into the input folder {src}; choose another folder"
    elif out_p == src.parent:
        return f"{out_p}: will not write beside the input file {src.name}; choose another folder"
    return None


def _triangles(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    v, t = mesh_triangles(mesh)
    return np.asarray(v, np.float64), np.asarray(t, np.int64)


def write_stl(mesh: Mesh, path: str | os.PathLike, name: str = "pdehead", provenance: dict | None = None) -> None:
    """Binary STL (little-endian, float32 mm, facet normals from the winding); the 80-byte ASCII header holds
    the provenance's label first when it has one (a face from the skull: "approximation - not an
    identification"), then the part, the frame and as much of a short provenance (software, bone level,
    table) as fits."""
    v, t = _triangles(mesh)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    n = np.cross(b - a, c - a)
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, ln, out=np.zeros_like(n), where=ln > 0)
    rec = np.zeros(len(t), dtype=[("n", "<f4", 3), ("a", "<f4", 3), ("b", "<f4", 3), ("c", "<f4", 3),
                                  ("attr", "<u2")])
    rec["n"], rec["a"], rec["b"], rec["c"] = n, a, b, c
    part = f"{name} (patient LPS, mm)"
    text = short_provenance(provenance, part=part) if provenance else part
    header = text.encode("ascii", "replace")[:80].ljust(80, b" ")
    if header.startswith(b"solid"):            # an ASCII STL marker would confuse readers
        header = b"_" + header[1:]
    with open(os.fspath(path), "wb") as fh:
        fh.write(header)
        fh.write(struct.pack("<I", len(t)))
        fh.write(rec.tobytes())


def write_obj(mesh: Mesh, path: str | os.PathLike, name: str = "pdehead", provenance: dict | None = None) -> None:
    """Wavefront OBJ (vertices in mm, 1-based faces; quads kept as quads); provenance as comments."""
    v = np.asarray(mesh.vertices, np.float64)
    with open(os.fspath(path), "w") as fh:
        fh.write(f"# {name}: patient LPS millimetres\n")
        fh.write("".join(line + "\n" for line in provenance_lines(provenance)))
        fh.write(f"o {name}\n")
        np.savetxt(fh, v, fmt="v %.5f %.5f %.5f")
        if len(mesh.quads):
            np.savetxt(fh, mesh.quads + 1, fmt="f %d %d %d %d")
        if len(mesh.triangles):
            np.savetxt(fh, mesh.triangles + 1, fmt="f %d %d %d")


def write_ply(mesh: Mesh, path: str | os.PathLike, name: str = "pdehead", provenance: dict | None = None) -> None:
    """Binary little-endian PLY (float32 vertices in mm, triangle faces); provenance as comments."""
    v, t = _triangles(mesh)
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"comment {name}: patient LPS millimetres\n"
              + "".join(line + "\n" for line in provenance_lines(provenance, prefix="comment "))
              + f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(t)}\nproperty list uchar int vertex_indices\nend_header\n")
    faces = np.zeros(len(t), dtype=[("n", "u1"), ("i", "<i4", 3)])
    faces["n"] = 3
    faces["i"] = t
    with open(os.fspath(path), "wb") as fh:
        fh.write(header.translate(ASCII_SPELLING).encode("ascii", "replace"))
        fh.write(v.astype("<f4").tobytes())
        fh.write(faces.tobytes())


_WRITERS = {"stl": write_stl, "obj": write_obj, "ply": write_ply}


def export_mesh(mesh: Mesh, path: str | os.PathLike, fmt: str | None = None, name: str = "pdehead",
                require_watertight: bool = True, provenance: dict | None = None) -> str:
    """Write ``mesh`` as STL, OBJ or PLY (from ``fmt`` or the file extension), in mm.

    Raises
    ------
    PDEHeadError
        Unknown format, a mesh that is not watertight (when required) or a write failure,
        naming the file.
    """
    path = os.fspath(path)
    fmt = (fmt or os.path.splitext(path)[1].lstrip(".")).lower()
    if fmt not in _WRITERS:
        raise PDEHeadError(f"{path}: unknown mesh format {fmt!r}; use one of {', '.join(FORMATS)}")
    if mesh.face_count == 0:
        raise PDEHeadError(f"{path}: the mesh '{name}' has no faces")
    if require_watertight and not mesh.is_watertight():
        raise PDEHeadError(f"{path}: the mesh '{name}' is not watertight (open or inconsistently wound edges); "
                           "build the surface with caps")
    # a temporary name, its size checked, then renamed: a full disk leaves no partial mesh
    write_with(path, lambda tmp: _WRITERS[fmt](mesh, tmp, name, provenance=provenance), minimum=1)
    return path
