"""A plain polygon mesh in patient LPS mm: what the engine hands to the Blender layer."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Mesh:
    """Quads (and optional triangles) with per-corner UVs and per-vertex attributes.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
        Positions in patient LPS millimetres.
    quads : ndarray of int, shape (m, 4)
        Quad faces, counter-clockwise seen from outside (normals point outward).
    triangles : ndarray of int, shape (k, 3)
        Triangle faces (e.g. the caps that close a tube), same winding rule.
    quad_uv, triangle_uv : ndarray, shape (m, 4, 2) / (k, 3, 2), optional
        UV of each face corner (per corner, because the v seam is stitched).
    vertex_attributes : dict of str to ndarray
        Per-vertex data, shape (n,) or (n, c), e.g. ``"w"`` or ``"intensity"``.
    """

    vertices: np.ndarray
    quads: np.ndarray
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    quad_uv: np.ndarray | None = None
    triangle_uv: np.ndarray | None = None
    vertex_attributes: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.quads = np.asarray(self.quads, dtype=np.int64).reshape(-1, 4)
        self.triangles = np.asarray(self.triangles, dtype=np.int64).reshape(-1, 3)

    @property
    def face_count(self) -> int:
        return len(self.quads) + len(self.triangles)

    def loop_vertex_indices(self) -> np.ndarray:
        """Vertex index of every face corner: quads first, then triangles (Blender loop order)."""
        return np.concatenate([self.quads.ravel(), self.triangles.ravel()])

    def loop_starts_and_totals(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-face first-loop index and corner count, in the order of :meth:`loop_vertex_indices`."""
        totals = np.concatenate([np.full(len(self.quads), 4), np.full(len(self.triangles), 3)])
        starts = np.concatenate([[0], np.cumsum(totals)[:-1]]) if totals.size else totals
        return starts.astype(np.int64), totals.astype(np.int64)

    def loop_uv(self) -> np.ndarray | None:
        """UV of every face corner in loop order, or None if the mesh has no UVs."""
        if self.quad_uv is None:
            return None
        parts = [np.asarray(self.quad_uv, float).reshape(-1, 2)]
        if len(self.triangles):
            tri = self.triangle_uv if self.triangle_uv is not None else np.zeros((len(self.triangles), 3, 2))
            parts.append(np.asarray(tri, float).reshape(-1, 2))
        return np.concatenate(parts)

    def _directed_edges(self) -> np.ndarray:
        """Every face's edges in its winding order, shape (e, 2)."""
        rings = [np.stack([self.quads, np.roll(self.quads, -1, axis=1)], axis=-1).reshape(-1, 2),
                 np.stack([self.triangles, np.roll(self.triangles, -1, axis=1)], axis=-1).reshape(-1, 2)]
        return np.concatenate(rings).astype(np.int64)

    def edges(self) -> np.ndarray:
        """Unique undirected edges, shape (e, 2), sorted per row and by rows."""
        keys, n = self._edge_keys(np.sort(self._directed_edges(), axis=1))
        keys = np.unique(keys)
        return np.column_stack([keys // n, keys % n])

    def is_watertight(self) -> bool:
        """True if every edge is shared by exactly two faces with opposite directions (closed, oriented)."""
        directed = self._directed_edges()
        keys = np.sort(self._edge_keys(directed)[0])
        if np.any(keys[1:] == keys[:-1]):
            return False  # the same directed edge twice: inconsistent winding or non-manifold
        _, counts = np.unique(self._edge_keys(np.sort(directed, axis=1))[0], return_counts=True)
        return bool(np.all(counts == 2))

    @staticmethod
    def _edge_keys(edges: np.ndarray) -> tuple[np.ndarray, int]:
        """Each edge (a, b) as the one integer a * n + b, and n. A 1-D sort of these is many times faster than
        np.unique(axis=0)'s row-wise one (28 s of a 77 s phantom face export went to it)."""
        n = int(edges.max()) + 1 if len(edges) else 1
        return edges[:, 0] * n + edges[:, 1], n
