"""A skull given as a mesh (a surface scan: STL / PLY / OBJ in mm) in place of a CT.

:func:`load_skull_mesh` reads the mesh, repairs what can be repaired (duplicate vertices of STL files,
degenerate and duplicate triangles, small holes filled by a fan) or refuses it with a message that says
where it is open, and turns it into a CT-like volume (inside the mesh: bone, 1500 HU; outside: air)
so that every later step works unchanged. The skull itself (``skull.<fmt>``) stays the given mesh:
:func:`~.skull.segment_skull` keeps it (``meta["skull_mesh"]``) and :func:`~.skull.skull_mesh` returns it.

Coordinates are taken as patient LPS millimetres (the scan's own frame): x to the skull's left, y
posterior, z superior, as the CT convention. A surface scan in another frame must be oriented first.
"""
from __future__ import annotations

import os
import re
import struct
from pathlib import Path

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import ConvexHull, QhullError

from ..core.ct_volume import CTVolume
from ..core.errors import CTImportError
from ..core.mesh import Mesh
from ..core.mesh_geometry import signed_volume

MESH_EXTENSIONS = (".stl", ".ply", ".obj")
#: Holes up to this many boundary edges are filled; larger openings are refused (a surface scan's small
#: gaps are repaired, a missing skull base is not invented).
MAX_HOLE_EDGES = 60
#: Voxel size (mm) of the volume made from the mesh, coarsened when it would exceed MAX_MESH_VOXELS.
#: Half a millimetre: the voxel centres must catch the thin bone of the mesh (the tympanic plate under the
#: ear canal, under 1 mm in a smoothed bone surface); at 1 mm most of it is lost, an ear canal opens into
#: the bone below it and porion lands far from where the CT path puts it.
MESH_VOXEL_MM = 0.5
MAX_MESH_VOXELS = 40_000_000
BONE_VALUE_HU, AIR_VALUE_HU = 1500.0, -1000.0


# --------------------------------------------------------------------------- reading
def read_mesh(path: str | os.PathLike) -> Mesh:
    """Triangles of an STL (binary or ASCII), PLY (ASCII or binary little/big endian) or OBJ file."""
    path = os.fspath(path)
    ext = Path(path).suffix.lower()
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise CTImportError(f"cannot read the mesh ({exc.strerror})", path) from None
    try:
        if ext == ".stl":
            v, t = _read_stl(raw)
        elif ext == ".ply":
            v, t = _read_ply(raw)
        elif ext == ".obj":
            v, t = _read_obj(raw.decode("utf-8", "replace"))
        else:
            raise CTImportError(f"not a mesh file (use {', '.join(MESH_EXTENSIONS)})", path)
    except CTImportError:
        raise
    except (ValueError, IndexError, struct.error, UnicodeDecodeError) as exc:
        raise CTImportError(f"cannot parse the {ext[1:].upper()} mesh ({exc})", path) from None
    if len(t) == 0:
        raise CTImportError("the mesh has no triangles", path)
    if not np.isfinite(v).all():
        raise CTImportError("the mesh has non-finite vertex coordinates", path)
    if t.min() < 0 or t.max() >= len(v):
        raise CTImportError("the mesh has faces that point at missing vertices", path)
    return Mesh(vertices=v, quads=np.zeros((0, 4), np.int64), triangles=t)


def _merge(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shared vertices of STL triangle corners (exactly equal coordinates merged)."""
    c = np.ascontiguousarray(corners, np.float32)
    keys = c.view(np.dtype((np.void, c.dtype.itemsize * 3))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    return c[first].astype(np.float64), inverse.reshape(-1, 3).astype(np.int64)


def _keys(rows: np.ndarray, n: int) -> np.ndarray:
    """One int64 per row of 2 or 3 vertex indices below ``n`` (fast unique)."""
    out = rows[:, 0].astype(np.int64)
    for c in range(1, rows.shape[1]):
        out = out * n + rows[:, c]
    return out


def _read_stl(raw: bytes):
    if len(raw) >= 84:
        (count,) = struct.unpack_from("<I", raw, 80)
        if len(raw) == 84 + 50 * count:
            rec = np.frombuffer(raw, dtype=[("n", "<f4", 3), ("p", "<f4", (3, 3)), ("a", "<u2")], count=count,
                                offset=84)
            return _merge(rec["p"].reshape(-1, 3))
    text = raw.decode("ascii", "replace")
    nums = re.findall(r"vertex\s+(\S+)\s+(\S+)\s+(\S+)", text)
    if not nums or len(nums) % 3:
        raise ValueError("neither a binary STL nor ASCII STL facets")
    return _merge(np.array(nums, float).astype(np.float32))


def _read_ply(raw: bytes):
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise ValueError("no PLY header")
    header = raw[:end].decode("ascii", "replace").splitlines()
    body = raw[raw.index(b"\n", end) + 1:]
    fmt = next(line.split()[1] for line in header if line.startswith("format"))
    elements, cur = [], None
    for line in header:
        parts = line.split()
        if parts[:1] == ["element"]:
            cur = [parts[1], int(parts[2]), []]
            elements.append(cur)
        elif parts[:1] == ["property"] and cur is not None:
            cur[2].append(parts[1:])
    types = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
             "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2",
             "int32": "i4", "uint32": "u4", "float32": "f4", "float64": "f8"}
    verts = faces = None
    if fmt == "ascii":
        tokens = body.decode("ascii", "replace").split()
        pos = 0
        for name, count, props in elements:
            if name == "vertex":
                n = len(props)
                vals = np.array(tokens[pos:pos + n * count], float).reshape(count, n)
                names = [p[-1] for p in props]
                verts = vals[:, [names.index(c) for c in "xyz"]]
                pos += n * count
            elif name == "face":
                rows = []
                for _ in range(count):
                    k = int(tokens[pos])
                    rows.append([int(x) for x in tokens[pos + 1:pos + 1 + k]])
                    pos += 1 + k
                faces = rows
        return verts, _fan(faces)
    order = "<" if fmt == "binary_little_endian" else ">"
    pos = 0
    for name, count, props in elements:
        if name == "face" and props and props[0][0] == "list":
            ct, it = types[props[0][1]], types[props[0][2]]
            first = np.frombuffer(body, order + ct, 1, pos)[0]
            if len(props) == 1:
                dt = np.dtype([("n", order + ct), ("i", order + it, (int(first),))])
                arr = np.frombuffer(body, dt, count, pos)
                if np.all(arr["n"] == first):
                    faces = arr["i"].astype(np.int64)
                    pos += dt.itemsize * count
                    continue
            raise ValueError("binary PLY faces of mixed sizes or with extra properties are not supported")
        dt = np.dtype([(p[-1], order + types[p[0]]) for p in props])
        arr = np.frombuffer(body, dt, count, pos)
        pos += dt.itemsize * count
        if name == "vertex":
            verts = np.stack([arr[c] for c in "xyz"], 1).astype(np.float64)
    return verts, _fan(faces)


def _fan(faces) -> np.ndarray:
    """Polygons (rows of vertex indices) as triangles (fans from the first corner)."""
    if isinstance(faces, np.ndarray):
        if faces.shape[1] == 3:
            return faces.astype(np.int64)
        return np.concatenate([faces[:, [0, k, k + 1]] for k in range(1, faces.shape[1] - 1)]).astype(np.int64)
    out = [(f[0], f[k], f[k + 1]) for f in faces for k in range(1, len(f) - 1)]
    return np.array(out, np.int64).reshape(-1, 3)


def _read_obj(text: str):
    verts, faces = [], []
    for line in text.splitlines():
        if line.startswith("v "):
            verts.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            idx = [int(tok.split("/")[0]) for tok in line.split()[1:]]
            faces.append([i - 1 if i > 0 else len(verts) + i for i in idx])
    return np.array(verts, float).reshape(-1, 3), _fan(faces)


# --------------------------------------------------------------------------- repair
def _edge_table(t: np.ndarray):
    directed = np.stack([t, np.roll(t, -1, axis=1)], axis=-1).reshape(-1, 2)
    key = np.sort(directed, axis=1)
    n = int(t.max()) + 1
    _, first, inverse, counts = np.unique(_keys(key, n), return_index=True, return_inverse=True,
                                          return_counts=True)
    return directed, key[first], inverse.ravel(), counts


def repair_mesh(mesh: Mesh, source: str = "the mesh", max_hole_edges: int = MAX_HOLE_EDGES) -> tuple[Mesh, dict]:
    """A closed, consistently wound, outward mesh from ``mesh``, or a CTImportError saying where it is open.

    Repairs: degenerate and duplicate triangles dropped; holes of at most ``max_hole_edges`` boundary
    edges filled by a fan to their centre; winding flipped to outward. Refused: larger holes (each
    named by its centre in mm and its size), edges shared by more than two triangles, inconsistent
    winding.
    """
    v = np.asarray(mesh.vertices, np.float64)
    t = np.asarray(mesh.triangles, np.int64)
    report: dict = {"degenerate": 0, "duplicates": 0, "holes_filled": 0}
    good = (t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2])
    report["degenerate"] = int(np.count_nonzero(~good))
    t = t[good]
    _, first = np.unique(_keys(np.sort(t, axis=1), len(v)), return_index=True)
    report["duplicates"] = int(len(t) - len(first))
    t = t[np.sort(first)]
    directed, und, inverse, counts = _edge_table(t)
    if np.any(counts > 2):
        bad = und[counts > 2]
        where = np.round(v[bad].mean(axis=1)[:3], 1).tolist()
        raise CTImportError(f"the mesh is not a closed surface: {len(bad)} edges are shared by more than two "
                            f"triangles, e.g. at {where} mm", source)
    open_edges = directed[counts[inverse] == 1]
    if len(open_edges):
        from scipy.sparse.csgraph import connected_components  # deferred: ~8 ms at `import pdehead_addon`
        n = len(v)
        graph = csr_matrix((np.ones(len(open_edges)), (open_edges[:, 0], open_edges[:, 1])), shape=(n, n))
        _, comp = connected_components(graph, directed=False)
        loops = comp[open_edges[:, 0]]
        ids, sizes = np.unique(loops, return_counts=True)
        too_big = ids[sizes > max_hole_edges]
        if too_big.size:
            parts = []
            for i in too_big[np.argsort(-sizes[np.isin(ids, too_big)])][:3]:
                e = open_edges[loops == i]
                p = v[np.unique(e)]
                parts.append(f"{len(e)} open edges around ({', '.join(f'{c:.0f}' for c in p.mean(0))}) mm, "
                             f"{np.ptp(p, axis=0).max():.0f} mm across")
            raise CTImportError(f"the mesh is open: {len(ids)} hole(s), {too_big.size} too large to fill "
                                f"(more than {max_hole_edges} edges): " + "; ".join(parts)
                                + "; close it in the scanning software", source)
        new_v, new_t = [v], [t]
        nxt = len(v)
        for i in ids:
            e = open_edges[loops == i]
            centre = v[np.unique(e)].mean(0)
            new_v.append(centre[None])
            # the hole's triangles run each open edge backwards (b, a) so the winding continues
            new_t.append(np.column_stack([e[:, 1], e[:, 0], np.full(len(e), nxt)]))
            nxt += 1
        v, t = np.concatenate(new_v), np.concatenate(new_t)
        report["holes_filled"] = int(len(ids))
    out = Mesh(vertices=v, quads=np.zeros((0, 4), np.int64), triangles=t)
    directed, _, _, counts = _edge_table(t)
    if np.any(counts != 2) or len(np.unique(_keys(directed, len(v)))) != len(directed):
        raise CTImportError("the mesh's triangles are not wound consistently (some face inward); re-export "
                            "it with consistent normals", source)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() < 0:
        out.triangles = t[:, ::-1].copy()
        report["flipped"] = True
    return out, report


# --------------------------------------------------------------------------- to a volume
def voxelize(mesh: Mesh, voxel_mm: float, pad: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Inside of a closed mesh on an axis-aligned grid: (inside[k, j, i], origin xyz of voxel 0).

    Ray parity along z per (x, y) column: each triangle crossing a column toggles every voxel centre
    above the crossing; a voxel is inside after an odd number of toggles. The grid is offset by a tiny
    irrational fraction of a voxel so no column runs exactly through an edge or a vertex.
    """
    v = np.asarray(mesh.vertices, np.float64)
    t = np.asarray(mesh.triangles, np.int64)
    lo = v.min(0) - pad * voxel_mm + 1e-3 * np.sqrt(2) * voxel_mm
    shape_xyz = np.ceil((v.max(0) + pad * voxel_mm - lo) / voxel_mm).astype(int) + 1
    nx, ny, nz = shape_xyz
    toggles = np.zeros((nz + 1, ny, nx), np.int32)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    for s in range(0, len(t), 200_000):
        pa, pb, pc = a[s:s + 200_000], b[s:s + 200_000], c[s:s + 200_000]
        xs = np.stack([pa[:, 0], pb[:, 0], pc[:, 0]], 1)
        ys = np.stack([pa[:, 1], pb[:, 1], pc[:, 1]], 1)
        i0 = np.ceil((xs.min(1) - lo[0]) / voxel_mm).astype(np.int64)
        i1 = np.floor((xs.max(1) - lo[0]) / voxel_mm).astype(np.int64)
        j0 = np.ceil((ys.min(1) - lo[1]) / voxel_mm).astype(np.int64)
        j1 = np.floor((ys.max(1) - lo[1]) / voxel_mm).astype(np.int64)
        wi, wj = np.maximum(i1 - i0 + 1, 0), np.maximum(j1 - j0 + 1, 0)
        count = wi * wj
        tri = np.repeat(np.arange(len(pa)), count)
        if tri.size == 0:
            continue
        local = np.arange(tri.size) - np.repeat(np.cumsum(count) - count, count)
        ii = i0[tri] + local % wi[tri]
        jj = j0[tri] + local // wi[tri]
        px, py = lo[0] + ii * voxel_mm, lo[1] + jj * voxel_mm
        ax, ay, bx, by, cx, cy = xs[tri, 0], ys[tri, 0], xs[tri, 1], ys[tri, 1], xs[tri, 2], ys[tri, 2]
        det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
        ok = np.abs(det) > 1e-12
        det = np.where(ok, det, 1.0)
        l1 = ((bx - px) * (cy - py) - (cx - px) * (by - py)) / det
        l2 = ((cx - px) * (ay - py) - (ax - px) * (cy - py)) / det
        l3 = 1.0 - l1 - l2
        hit = ok & (l1 >= 0) & (l2 >= 0) & (l3 >= 0)
        z = l1 * pa[tri, 2] + l2 * pb[tri, 2] + l3 * pc[tri, 2]
        k = np.clip(np.ceil((z - lo[2]) / voxel_mm).astype(np.int64), 0, nz)
        np.add.at(toggles, (k[hit], jj[hit], ii[hit]), 1)
    inside = (np.cumsum(toggles, axis=0, dtype=np.int32)[:nz] & 1).astype(bool)
    return inside, lo


#: A skull fills a small share of its convex hull (its orbits, nasal aperture, temporal fossae, the space under
#: the zygomatic arches and between the mandible and the cranium, and, for a bone mesh, the braincase): the bone
#: meshes of CThead and the phantom fill 18 % and 22 %. A mesh filling more than this share is a convex solid
#: (a cube or a sphere fill 98-100 %, an ellipsoid or an envelope nearly as much), not a skull.
MAX_SKULL_HULL_FILL = 0.92


def hull_fill(mesh: Mesh) -> float:
    """The share of its convex hull (Qhull [1]_, through SciPy) that a closed mesh encloses.

    Raises
    ------
    ValueError
        When the vertices span no volume (all in one plane or on one line).

    References
    ----------
    .. [1] C. B. Barber, D. P. Dobkin, H. Huhdanpaa, "The Quickhull algorithm for convex hulls", ACM Trans.
       Math. Softw. 22(4):469-483, 1996.
    """
    try:
        hull = ConvexHull(np.asarray(mesh.vertices, np.float64))
    except (QhullError, ValueError):
        raise ValueError("its vertices span no volume (all in one plane or on one line)") from None
    if not hull.volume > 0:
        raise ValueError("its vertices span no volume")
    return float(abs(signed_volume(mesh)) / hull.volume)


def _refuse_convex(mesh: Mesh, path) -> None:
    """A cube, a sphere or an envelope as the skull: refused at once, before any work (and without a library's
    dump in the message)."""
    try:
        fill = hull_fill(mesh)
    except ValueError as exc:
        raise CTImportError(f"does not look like a skull: {exc}", path) from None
    if fill > MAX_SKULL_HULL_FILL:
        raise CTImportError(f"does not look like a skull: the mesh is convex (it fills {100 * fill:.0f} % of its "
                            f"convex hull; a skull, with its orbits, nasal aperture and fossae, fills less than "
                            f"{100 * MAX_SKULL_HULL_FILL:.0f} %): a cube, a sphere or an envelope?", path)


def load_skull_mesh(path: str | os.PathLike, voxel_mm: float | None = None) -> CTVolume:
    """A skull mesh file (STL / PLY / OBJ, mm) as a CT-like volume (bone inside, air outside).

    The repaired mesh travels in ``meta["skull_mesh"]`` (with ``meta["skull_mesh_repair"]``) so the skull
    is the mesh itself, not its voxelisation.
    """
    path = os.fspath(path)
    mesh, report = repair_mesh(read_mesh(path), path)
    size = np.ptp(mesh.vertices, axis=0)
    if size.max() < 50 or size.max() > 400:
        raise CTImportError(f"the mesh is {size.max():.1f} units across: a skull in mm is 120-250 mm "
                            "(metres or inches? scale it to mm)", path)
    _refuse_convex(mesh, path)
    step = float(voxel_mm or MESH_VOXEL_MM)
    while np.prod(size / step + 7) > MAX_MESH_VOXELS:
        step *= 1.25
    inside, lo = voxelize(mesh, step)
    if not inside.any():
        raise CTImportError("the mesh encloses no volume", path)
    data = np.where(inside, np.float32(BONE_VALUE_HU), np.float32(AIR_VALUE_HU)).astype(np.float32)
    meta = dict(source=path, format="mesh", modality="CT", units="HU", series_description="skull mesh",
                skull_mesh=mesh, skull_mesh_file=os.path.basename(path), skull_mesh_repair=report,
                warnings=([f"{path}: mesh repaired: {report['holes_filled']} small hole(s) filled"]
                          if report["holes_filled"] else []), hu_range=(AIR_VALUE_HU, BONE_VALUE_HU))
    return CTVolume(data, (step, step, step), origin=lo, meta=meta)
