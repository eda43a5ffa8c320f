"""The CT's detail as geometry: the PDE surface displaced along its normals by its detail map, and the
surface meshed at print resolution.

The detail map (:func:`.detail_map.ct_detail_map`) holds, per texel of the surface's UV layout, the signed
distance (mm) along the PDE surface's outward normal from the surface to the CT's skin. The detail layer
puts it back as geometry: every vertex ``p`` of a mesh of the surface moves to ``p + s h(uv) n(p)``, with
``h`` the map sampled bilinearly at the vertex's UVs, ``n`` the vertex's outward normal and ``s`` the
detail strength (0: the PDE surface itself; 1: the CT's skin as the map holds it). The PDE surface stays
the smooth, compact base; the map is the layer on top of it, as a sculpting program's displacement map.

The vertices of the bottom cap (the neck's cut, not skin) are not displaced: a vertex takes the mean of
the map over its tube and dome corners only, so the cap's rim moves with the tube and the mesh stays
closed (the same vertices, only moved).

Print resolution (:func:`print_resolution`): the rows and columns of the mesh are chosen so that the
largest chord error (the distance from a triangle's edge and diagonal midpoints to the surface at the same
parameters) stays within :data:`PRINT_CHORD_MM`, and the edges are short enough to carry the map's
features (:data:`PRINT_EDGE_MM`), within :data:`PRINT_MAX_TRIANGLES`.

References
----------
R. L. Cook, "Shade trees", Computer Graphics (SIGGRAPH '84) 18(3), 223-231 (1984): displacement maps,
the surface point moved along its normal by a texture's value.
V. Krishnamurthy, M. Levoy, "Fitting smooth surfaces to dense polygon meshes", SIGGRAPH '96, 313-324:
a smooth base surface plus a displacement map along its normals to keep a scan's fine detail.
(Both cited from the literature, not re-read here.)
"""
from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from ..core.mesh import Mesh
from .detail_map import area_vertex_normals
from .surface_uv_map import uv_islands

__all__ = ["sample_map", "vertex_heights", "vertex_normals", "uv_island_layout", "displace_mesh", "detail_surface",
           "chord_error", "print_resolution", "print_rows", "print_columns", "print_mesh", "split_quads",
           "PRINT_CHORD_MM", "PRINT_EDGE_MM", "PRINT_MAX_TRIANGLES"]

#: The largest chord error of an exported skin (mm): a print layer is ~0.05-0.1 mm, so the facets do not
#: show in a print.
PRINT_CHORD_MM = 0.05

#: The longest edge (mm, along the tube's rows and columns) of an export: a 1 mm feature of the detail map
#: (a closed eyelid's line) spans two edges.
PRINT_EDGE_MM = 0.5

#: At most this many triangles in an exported skin (a slicer's comfortable load; ~100 MB of binary STL).
PRINT_MAX_TRIANGLES = 2_000_000


def sample_map(height: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``height`` (rows from UV v = 0, texel centres at ``(i + 0.5) / res``) sampled bilinearly at ``uv``
    (shape (n, 2)), clamped at the borders (the map's gutters hold the islands' edge values)."""
    h = np.asarray(height, np.float32)
    rows, cols = h.shape
    x = np.clip(np.asarray(uv[:, 0], float) * cols - 0.5, 0.0, cols - 1.0)
    y = np.clip(np.asarray(uv[:, 1], float) * rows - 0.5, 0.0, rows - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), cols - 2)
    y0 = np.minimum(np.floor(y).astype(np.int64), rows - 2)
    fx, fy = x - x0, y - y0
    top = h[y0, x0] * (1.0 - fx) + h[y0, x0 + 1] * fx
    bottom = h[y0 + 1, x0] * (1.0 - fx) + h[y0 + 1, x0 + 1] * fx
    return top * (1.0 - fy) + bottom * fy


def _cap_corners(uv: np.ndarray, islands: dict | None) -> np.ndarray:
    """Which corners lie in the bottom cap's UV island (True: not displaced)."""
    if islands is None:
        return np.zeros(len(uv), bool)
    cx, cy = islands["cap"]
    return np.hypot(uv[:, 0] - cx, uv[:, 1] - cy) <= islands["cap_radius"] * 1.0001


def vertex_heights(mesh: Mesh, height: np.ndarray, islands: dict | None = None) -> np.ndarray:
    """Per vertex of ``mesh`` the map's mean over the vertex's corners outside the cap island (0 for a
    vertex with none: the cap's inside).

    Parameters
    ----------
    mesh : Mesh
        With per-corner UVs in the map's layout (:meth:`.pde_head.PDEHead.surface`).
    height : ndarray, shape (res, res)
        The detail map (mm).
    islands : dict, optional
        :func:`.surface_uv_map.uv_islands` of the layout: corners in its cap disc are left out.
    """
    uv = mesh.loop_uv()
    if uv is None:
        raise ValueError("the mesh has no UVs: it cannot take a detail map")
    corner = mesh.loop_vertex_indices()
    keep = ~_cap_corners(uv, islands)
    n = len(mesh.vertices)
    total = np.bincount(corner[keep], sample_map(height, uv[keep]), minlength=n)
    count = np.bincount(corner[keep], minlength=n)
    return np.where(count > 0, total / np.maximum(count, 1), 0.0)


def vertex_normals(mesh: Mesh) -> np.ndarray:
    """Area-weighted unit vertex normals of an outward-wound mesh (quads split along their 0-2 diagonal)."""
    tris = np.concatenate([mesh.quads[:, [0, 1, 2]], mesh.quads[:, [0, 2, 3]], mesh.triangles])
    return area_vertex_normals(mesh.vertices, tris)


def displace_mesh(mesh: Mesh, height: np.ndarray, strength: float, islands: dict | None = None) -> Mesh:
    """``mesh`` with every vertex moved ``strength x`` the map's height along its outward normal (module
    docstring); the faces, UVs and attributes are kept. Strength 0 returns ``mesh`` itself."""
    s = float(strength)
    if s == 0.0:
        return mesh
    h = vertex_heights(mesh, height, islands)
    moved = mesh.vertices + (s * h)[:, None] * vertex_normals(mesh)
    return Mesh(moved, mesh.quads, mesh.triangles, mesh.quad_uv, mesh.triangle_uv, dict(mesh.vertex_attributes))


def uv_island_layout(head) -> dict:
    """Where the head's UV islands lie (:func:`.surface_uv_map.uv_islands` of its layout)."""
    layout = head.uv_layout()
    return uv_islands(float(layout["aspect"]), layout.get("dome_ratio"), layout.get("cap_ratio"))


def detail_surface(head, height: np.ndarray | None, strength: float, nu: int, nv: int, caps: bool = True,
                   split: bool = False, rows=None) -> Mesh:
    """The head's surface at ``nu x nv`` with its detail layer at ``strength`` (:func:`displace_mesh`; the
    plain PDE surface when the strength is 0 or there is no map); ``split``: each quad's corners ordered
    for the split with the smaller chord error (:func:`split_quads`, the exports'); ``rows``: the rows' u
    (:func:`print_rows`)."""
    mesh = head.surface(int(nu), int(nv), caps=caps, rows=rows)
    if split:
        mesh = split_quads(head, mesh, nu, nv, rows)
    if height is None or float(strength) == 0.0:
        return mesh
    return displace_mesh(mesh, height, strength, uv_island_layout(head))


def _half_columns(head, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """The surface's column parameters v (radians) and the midpoints between neighbours (the last wraps)."""
    v = np.asarray(head.v_columns(nv), float) if head.v_density() is not None else 2 * np.pi * np.arange(nv) / nv
    nxt = np.append(v[1:], v[0] + 2 * np.pi)
    return v, 0.5 * (v + nxt)


def chord_error(head, nu: int, nv: int, window=None, rows=None) -> dict:
    """How far the flat triangles of ``head.surface(nu, nv)`` leave the surface (mm).

    Measured on the tube's quads (split along their 0-2 diagonal, as the exports split them): at the
    midpoint of each row edge, column edge and diagonal, the distance from the mesh to the surface at the
    midpoint's parameters. The parametric midpoint is not the nearest surface point, so this bounds the
    geometric chord error from above.

    Parameters
    ----------
    window : callable, optional
        ``window(points) -> bool mask``: only the quads whose centres it keeps (e.g.
        :func:`surface_window`).
    rows : ndarray, optional
        The rows' u (:func:`print_rows`) instead of ``nu`` evenly spaced.

    Returns
    -------
    dict
        ``max`` and ``p99`` over the kept quads (the worst of their three midpoints); ``rows_max`` (the column
        edges' midpoints: the rows' spacing, nu, decides it), ``columns_max`` (the row edges': nv),
        ``diagonal_max``; ``quads``.
    """
    nu, nv = int(nu), int(nv)
    u = np.linspace(0.0, 1.0, max(nu, 3) if head.vertex is not None else nu) if rows is None else np.asarray(rows)
    if head.vertex is not None:
        u = u[:-1]                                     # the pole row is the fan's single vertex
    um = 0.5 * (u[:-1] + u[1:])
    v, vm = _half_columns(head, nv)
    # the uncached synthesis: four large grids would push the viewport's samplings out of the head's cache
    grid = getattr(head, "_grid", head.grid)
    corners = grid(u, v=v)                             # (nu, nv, 3)
    row_mid = grid(um, v=v)                            # midpoints of the column edges (between rows)
    col_mid = grid(u, v=vm)                            # midpoints of the row edges (between columns)
    centre = grid(um, v=vm)                            # the quads' parametric centres
    a, b = corners[:-1], corners[1:]
    b_next = np.roll(b, -1, axis=1)
    a_next = np.roll(a, -1, axis=1)
    e_col = np.linalg.norm(0.5 * (a + b) - row_mid[:, :], axis=-1)
    e_row = np.linalg.norm(0.5 * (a + a_next) - col_mid[:-1], axis=-1)
    # each quad is split along the diagonal whose midpoint lies nearer the surface (:func:`split_quads`)
    e_diag = np.minimum(np.linalg.norm(0.5 * (a + b_next) - centre, axis=-1),
                        np.linalg.norm(0.5 * (b + a_next) - centre, axis=-1))
    along_u = np.maximum(e_col, np.roll(e_col, -1, axis=1))     # the rows' spacing (nu) decides it
    keep = None if window is None else np.asarray(window(centre.reshape(-1, 3)), bool)

    def stats(e):
        e = e.reshape(-1) if keep is None else e.reshape(-1)[keep]
        return (float(e.max()), float(np.percentile(e, 99))) if e.size else (0.0, 0.0)
    worst, p99 = stats(np.maximum(np.maximum(along_u, e_row), e_diag))
    return {"max": worst, "p99": p99, "rows_max": stats(along_u)[0], "columns_max": stats(e_row)[0],
            "diagonal_max": stats(e_diag)[0], "quads": int(e_col.size if keep is None else keep.sum())}


#: The face a print's chord error is held on: +- this of straight ahead (-y), from ``FACE_BELOW_MM`` under
#: to ``FACE_ABOVE_MM`` over the nose tip (the visible-face measure's window,
#: ``validation.surface_metrics.face_window``, which the add-on does not ship).
FACE_HALF_ANGLE_DEG, FACE_BELOW_MM, FACE_ABOVE_MM = 60.0, 70.0, 60.0


def split_quads(head, mesh: Mesh, nu: int, nv: int, rows=None) -> Mesh:
    """``head.surface(nu, nv)``'s mesh with each tube quad's corners rotated so that the exports' split
    along corners 0-2 takes the diagonal whose midpoint lies nearer the surface at the quad's parametric
    centre (the smaller chord error, :func:`chord_error`); the geometry's vertices are unchanged."""
    nu, nv = int(nu), int(nv)
    u = np.linspace(0.0, 1.0, max(nu, 3) if head.vertex is not None else nu) if rows is None else np.asarray(rows)
    if head.vertex is not None:
        u = u[:-1]
    rows = len(u) - 1
    v, vm = _half_columns(head, nv)
    grid = getattr(head, "_grid", head.grid)
    centre = grid(0.5 * (u[:-1] + u[1:]), v=vm).reshape(-1, 3)
    quads = np.array(mesh.quads[: rows * nv])
    p = mesh.vertices
    d02 = np.linalg.norm(0.5 * (p[quads[:, 0]] + p[quads[:, 2]]) - centre, axis=1)
    d13 = np.linalg.norm(0.5 * (p[quads[:, 1]] + p[quads[:, 3]]) - centre, axis=1)
    flip = d13 < d02
    if not flip.any():
        return mesh
    out_quads = np.array(mesh.quads)
    out_quads[: rows * nv][flip] = np.roll(quads[flip], -1, axis=1)
    quad_uv = None
    if mesh.quad_uv is not None:
        quad_uv = np.array(mesh.quad_uv)
        quad_uv[: rows * nv][flip] = np.roll(quad_uv[: rows * nv][flip], -1, axis=1)
    return Mesh(mesh.vertices, out_quads, mesh.triangles, quad_uv, mesh.triangle_uv, dict(mesh.vertex_attributes))


def surface_window(head, nv: int = 256):
    """The face window of the head's own surface (a callable ``points -> bool mask``): within
    :data:`FACE_HALF_ANGLE_DEG` of straight ahead about the vertical through the surface's centroid, from
    :data:`FACE_BELOW_MM` under to :data:`FACE_ABOVE_MM` over its most anterior point within 20 mm of the
    mid-sagittal line (the nose tip)."""
    pts = head.surface(120, nv, caps=False, uv=False).vertices
    centre = pts[:, :2].mean(axis=0)
    near = np.abs(pts[:, 0] - centre[0]) <= 20.0
    tip = (pts[near] if near.any() else pts)[np.argmin((pts[near] if near.any() else pts)[:, 1])]

    def window(p):
        p = np.asarray(p, float)
        angle = np.degrees(np.arctan2(p[:, 0] - centre[0], -(p[:, 1] - centre[1])))
        return (np.abs(angle) <= FACE_HALF_ANGLE_DEG) & (p[:, 2] >= tip[2] - FACE_BELOW_MM) \
            & (p[:, 2] <= tip[2] + FACE_ABOVE_MM)
    return window


#: Rows outside the face's band of u are this much sparser than over the face (:func:`print_rows`).
PRINT_ROWS_OUTSIDE = 0.4


def print_rows(head, nu: int, window=None, outside: float = PRINT_ROWS_OUTSIDE) -> np.ndarray:
    """The u of ``nu`` rows, evenly spaced over the band of u that ``window`` (:func:`surface_window`) keeps
    and ``outside`` times as dense elsewhere (the neck and the crown need fewer rows than the face); evenly
    spaced without a window."""
    nu = max(int(nu), 3)
    if window is None:
        return np.linspace(0.0, 1.0, nu)
    probe = head.surface(120, 256, caps=False, uv=False)
    keep = np.asarray(window(probe.vertices), bool)
    if not keep.any():
        return np.linspace(0.0, 1.0, nu)
    u_kept = probe.vertex_attributes["u"][keep]
    lo, hi = float(u_kept.min()) - 2.0 / 119, float(u_kept.max()) + 2.0 / 119
    fine = np.linspace(0.0, 1.0, 4001)
    weight = np.where((fine >= lo) & (fine <= hi), 1.0, float(outside))
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (weight[1:] + weight[:-1]))])
    rows = np.interp(np.linspace(0.0, 1.0, nu), cdf / cdf[-1], fine)
    rows[0], rows[-1] = 0.0, 1.0
    return rows


#: Columns outside the face's band of v are this much sparser than over it (:func:`print_columns`).
PRINT_COLUMNS_OUTSIDE = 0.4


@contextmanager
def print_columns(head, window=None, outside: float = PRINT_COLUMNS_OUTSIDE):
    """Within the block ``head``'s columns (:meth:`.pde_head.PDEHead.v_columns`: the surface, its caps,
    :func:`chord_error`, :func:`split_quads`) are ``outside`` times as dense outside the band of v that
    ``window`` (:func:`surface_window`) keeps as over it, on top of the head's own column density: a
    print's budget goes to the face. Its UV layout is the head's own (the UVs are a function of (u, v), so
    the texture and a detail map keep their place). Without a window: the head's own columns."""
    if window is None:
        yield head
        return
    own = head.v_density()
    probe = head.surface(120, 256, caps=False, uv=False)
    keep = np.asarray(window(probe.vertices), bool)
    M = int(np.asarray(head.bset.curves).shape[1])
    if not keep.any():
        yield head
        return
    # the curves' v steps (k: 2 pi k / M to 2 pi (k + 1) / M) the window's vertices fall in, the band closed
    # over its gaps (the largest gap around the turn stays outside) and widened by two probe columns
    step = np.floor(np.mod(probe.vertex_attributes["v"][keep], 2 * np.pi) / (2 * np.pi) * M).astype(np.int64) % M
    inside = np.zeros(M, bool)
    inside[step] = True
    out = np.flatnonzero(~inside)
    if out.size:
        gaps = np.split(out, np.flatnonzero(np.diff(out) > 1) + 1)
        if len(gaps) > 1 and gaps[0][0] == 0 and gaps[-1][-1] == M - 1:      # the gap across v = 0
            gaps = [np.concatenate([gaps[-1], gaps[0]])] + gaps[1:-1]
        inside[:] = True
        inside[max(gaps, key=len)] = False
        widen = max(1, int(np.ceil(2 * M / 256)))
        inside = np.convolve(np.concatenate([inside[-widen:], inside, inside[:widen]]).astype(float),
                             np.ones(2 * widen + 1), "valid") > 0
    density = (np.ones(M) if own is None else np.asarray(own, float)) * np.where(inside, 1.0, float(outside))
    layout = head.uv_layout()
    saved = {k: head.__dict__[k] for k in ("v_density", "uv_layout") if k in head.__dict__}
    head.v_density = lambda: density
    head.uv_layout = lambda: layout
    try:
        yield head
    finally:
        for k in ("v_density", "uv_layout"):
            head.__dict__.pop(k, None)
        head.__dict__.update(saved)


def print_resolution(head, chord_mm: float = PRINT_CHORD_MM, edge_mm: float = PRINT_EDGE_MM,
                     max_triangles: int = PRINT_MAX_TRIANGLES, window="face") -> tuple[np.ndarray, int]:
    """Rows and columns of a print-resolution mesh of ``head``'s surface: (the rows' u, nv), for
    ``head.surface(len(rows), nv, rows=rows)``.

    The tube's length along its spine and its largest circumference give the counts for edges of
    ``edge_mm``; the rows are :func:`print_rows` (denser over ``window``'s band: "face" for
    :func:`surface_window`, None for even rows). Then each count grows with the chord error its own edges
    leave (:func:`chord_error`; a chord error falls with the square of the edge: the count times
    ``sqrt(error / chord_mm)``) until the largest is within ``chord_mm`` over ``window`` (everywhere
    without one), and both are scaled down together when the triangles would pass ``max_triangles``; at
    the budget the rows give up what their own error does not need to the columns.
    The columns are :func:`print_columns`' (denser over the window's band of v): measure or mesh the
    result inside ``with print_columns(head):`` (:func:`print_mesh` does).
    """
    if isinstance(window, str):
        window = surface_window(head)
    with print_columns(head, window):
        return _print_resolution(head, chord_mm, edge_mm, max_triangles, window)


def _print_resolution(head, chord_mm, edge_mm, max_triangles, window):
    u = np.linspace(0.0, 1.0, 64)
    length = float(np.linalg.norm(np.diff(head.spine(u), axis=0), axis=1).sum())
    rows_u = np.linspace(0.0, 1.0, 33)[:-1] if head.vertex is not None else np.linspace(0.0, 1.0, 33)
    rings = head.grid(rows_u, nv=256)
    circumference = float(np.linalg.norm(np.roll(rings, -1, axis=1) - rings, axis=-1).sum(axis=1).max())
    nu = int(np.ceil(length / edge_mm)) + 1
    nv = int(np.ceil(circumference / edge_mm))
    budget = max_triangles // 2 - 2 * nv                  # the caps' triangles: counted below

    def fit(a, b):
        if a * b <= budget:
            return a, b
        k = np.sqrt(budget / (a * b))
        return max(3, int(a * k)), max(8, int(b * k))
    nu, nv = fit(nu, nv)
    min_nu = nu
    best = None
    for _ in range(6):
        err = chord_error(head, nu, nv, window, rows=print_rows(head, nu, window))
        if best is None or err["max"] < best[0]:
            best = (err["max"], nu, nv)
        if err["max"] <= chord_mm:
            break
        if nu * nv >= budget * 0.98:
            # at the budget: the rows may be finer than their own error needs (a face's creases run along
            # the rows, so its columns need more): rows down to what their error asks (not below the
            # edge-length count), the columns take the rest of the budget
            spare = np.sqrt(max(err["rows_max"], 1e-9) / chord_mm) * 1.05
            if spare >= 1.0 or nu <= min_nu:
                break
            nu = max(min_nu, int(np.ceil(nu * spare)))
            nv = max(8, int(budget // nu))
            continue
        grow_u = np.sqrt(max(err["rows_max"], err["diagonal_max"]) / chord_mm) * 1.05
        grow_v = np.sqrt(max(err["columns_max"], err["diagonal_max"]) / chord_mm) * 1.05
        nu, nv = fit(int(np.ceil(nu * max(grow_u, 1.0))), int(np.ceil(nv * max(grow_v, 1.0))))
    else:
        err = chord_error(head, nu, nv, window, rows=print_rows(head, nu, window))
        if err["max"] < best[0]:
            best = (err["max"], nu, nv)
    _, nu, nv = best                                     # the grid with the smallest chord error tried
    # the caps' triangles grow with the columns (a disc triangulated ring by ring): counted, not estimated
    for _ in range(8):
        mesh = head.surface(nu, nv, caps=True, uv=False)
        count = 2 * len(mesh.quads) + len(mesh.triangles)
        if count <= max_triangles:
            break
        k = np.sqrt(max_triangles / count) * 0.995
        nu, nv = max(3, int(nu * k)), max(8, int(nv * k))
    return print_rows(head, nu, window), nv


def print_mesh(head, height: np.ndarray | None = None, strength: float = 0.0) -> Mesh:
    """What Export for Printing writes of a PDE surface (the skin, the face from the skull): the closed mesh
    at :func:`print_resolution` (chord error within :data:`PRINT_CHORD_MM` over the face, at most
    :data:`PRINT_MAX_TRIANGLES` triangles), each quad split along its nearer diagonal (:func:`split_quads`),
    displaced by the detail map ``height`` at ``strength`` (:func:`displace_mesh`; none by default)."""
    window = surface_window(head)
    rows, nv = print_resolution(head, window=window)
    with print_columns(head, window):
        return detail_surface(head, height, strength, len(rows), nv, caps=True, split=True, rows=rows)
