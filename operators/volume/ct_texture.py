"""The CT texture of the PDE solid's faces (paper section 4.3.1): the parametric box's faces, their
tiles in one atlas image and the CT sampled on them; numpy only (:mod:`operators.scene.objects` puts the atlas on
the solid).
"""
from __future__ import annotations

import math

import numpy as np

from ...pdehead_addon import apply_window, defaults as D, sample_ct, trilinear

FAMILIES = ("w1", "w0", "u1", "u0", "v1", "v0")  # the faces of the parametric box (Fig. 14)


def box_faces(mesh, ranges) -> tuple[np.ndarray, np.ndarray]:
    """Per face corner (u, v, w) and per face the index in :data:`FAMILIES` of its box face."""
    (u0, u1), (v0, v1), (w0, w1) = ranges
    uv = mesh.loop_uv()
    w = np.asarray(mesh.vertex_attributes["w"], np.float64)[mesh.loop_vertex_indices()]
    # the engine's corner UVs are (u, v / 2 pi) with the seam unwrapped: exact even where w = 0
    params = np.c_[uv[:, 0], uv[:, 1] * 2.0 * math.pi, w]
    starts, totals = mesh.loop_starts_and_totals()
    family = np.full(len(starts), -1)
    tol = 1e-9
    for f, (axis, value) in enumerate(((2, w1), (2, w0), (0, u1), (0, u0), (1, v1), (1, v0))):
        on = np.abs(params[:, axis] - value) <= tol * max(1.0, abs(value))
        all_on = np.logical_and.reduceat(on, starts) if len(starts) else np.zeros(0, bool)
        family = np.where((family < 0) & all_on, f, family)
    # the faces that close an inner shell (w0 > 0) to the crown's pole vertex lie on no box face: the top u end
    # is that cone (rows w, columns v), so they take its tile instead of a zero-area UV
    return params, np.where(family < 0, 2, family)


def _surface_grid(head, us: np.ndarray, vs: np.ndarray) -> np.ndarray:
    """Surface points X(u, v) (eq. 11) on the grid us x vs, shape (len(us), len(vs), 3).

    Uses the engine's grid synthesis (amplitudes once per u, as its own
    solid_mesh does) when available: ~30x faster than evaluating every point.
    """
    grid = getattr(head, "_grid", None)
    if grid is not None:
        try:
            return np.asarray(grid(np.asarray(us, float), None, v=np.asarray(vs, float)))
        except TypeError:  # a different engine signature: fall back to the public API
            pass
    return head.evaluate(np.asarray(us)[:, None], np.asarray(vs)[None, :], 1.0)


def _tile_speeds(mesh, params, family, axes, need_shells: bool = True) -> list[tuple[float, float]]:
    """Per box face: the largest mm per unit of its row and its column parameter along the mesh's edges.

    A texel spans (parameter extent / pixels) of each; times this speed it is the texel's world
    footprint, so tiles sized from it keep every texel within the CT voxel.
    """
    starts, totals = mesh.loop_starts_and_totals()
    nxt = np.arange(len(params)) + 1
    ends = starts + totals - 1
    nxt[ends] = starts
    corner_family = np.repeat(family, totals)
    keep = np.flatnonzero(corner_family >= (0 if need_shells else 2))        # the shells only when they show CT
    corner_family, nxt = corner_family[keep], nxt[keep]
    vert = mesh.loop_vertex_indices()
    vertices = np.asarray(mesh.vertices, np.float64)
    dp = params[nxt] - params[keep]
    dp[:, 1] = np.abs(dp[:, 1])
    dp[:, 1] = np.minimum(dp[:, 1], 2.0 * math.pi - dp[:, 1])       # the v seam wraps
    length = np.linalg.norm(vertices[vert[nxt]] - vertices[vert[keep]], axis=1)
    scale = np.array([1.0, 2.0 * math.pi, 1.0])
    out = []
    for k, pair in enumerate(axes):
        sel_k = corner_family == k
        speeds = []
        for axis in pair:
            others = [a for a in range(3) if a != axis]
            step = np.abs(dp[:, axis])
            along = sel_k & (step > 1e-9 * scale[axis]) & np.all(np.abs(dp[:, others]) <= 1e-6 * scale[others], axis=1)
            speeds.append(float((length[along] / step[along]).max()) if along.any() else 0.0)
        out.append(tuple(speeds))
    return out


def _pack_tiles(shapes: list[tuple[int, int]], width: int | None = None) -> tuple[list[tuple[int, int]], int, int]:
    """Shelf packing of (rows, cols) tiles: their (row, col) offsets and the atlas height and width."""
    area = sum(r * c for r, c in shapes)
    if width is None:
        width = max(max(c for _, c in shapes), int(math.ceil(math.sqrt(area) * 1.25)))
    order = sorted(range(len(shapes)), key=lambda k: -shapes[k][0])
    offsets = [(0, 0)] * len(shapes)
    y = x = shelf = 0
    for k in order:
        r, c = shapes[k]
        if x + c > width:
            y, x, shelf = y + shelf, 0, 0
        offsets[k] = (y, x)
        x += c
        shelf = max(shelf, r)
    return offsets, y + shelf, width


def ct_texture_atlas(head, mesh, ct, window, ranges, size: int | None = None, pad: int = 2, table=None, faces=None,
                     budget_mp: float = D.CT_TEXTURE_BUDGET.default, voxel_mm: float | None = None,
                     skin: str = D.SOLID_SKIN.default, skin_depth_mm: float = D.SOLID_SKIN_DEPTH.default,
                     cut_ct=None):
    """CT texture of the solid's faces: an atlas image and a UV per corner (paper section 4.3.1).

    Each face of the parametric box (outer/inner w shells, u ends, v cuts) gets a
    tile sampling the windowed CT trilinearly at ``X(u, v, w)`` (eq. 23) on a regular
    parameter grid, so a cutaway shows the CT inside the solid at texture resolution
    instead of at the few w samples of the mesh.

    Tile sizes: with ``size`` every tile is ``size`` x ``size`` (the older layout, all faces
    alike). Without it each tile gets as many texels along its row and column parameter as
    the face's largest extent in mm along them divided by ``voxel_mm`` (default: the CT's finest
    spacing), so a texel's world footprint is at most one CT voxel; if all tiles together need
    more than ``budget_mp`` megapixels they are scaled down together. The cut faces (u ends,
    v cuts) sample the CT itself (``cut_ct``, else ``ct``) at their texels' positions: the CT's
    own resolution, not the (u, v, w) table's. The outer shell (w = 1) is the skin, a
    partial-volume mix of air and tissue: with ``skin="surface"`` it gets a token tile (the solid
    shows the surface's material there); with ``skin="ct"`` its tile samples the CT
    ``skin_depth_mm`` inside the skin.

    With `table` (a :class:`~pdehead_addon.pde.solid_ct_table.SolidCTTable` of this head and CT) the
    shells are looked up in the CT tabulated once in (u, v, w): no PDE evaluation and no CT
    interpolation per step, which keeps cutaway sliders live.

    Returns
    -------
    atlas : ndarray float32 (H, W, 4), row 0 at the bottom (Blender image order)
    corner_uv : ndarray (corners, 2) in the atlas
    """

    (u0, u1), (v0, v1), (w0, w1) = ranges
    params, family = box_faces(mesh, ranges) if faces is None else faces
    # (row, column) parameters of each tile: shells (u, v), u ends (w, v), v cuts (w, u)
    axes = [(0, 1), (0, 1), (2, 1), (2, 1)]
    cuts = bool(np.any(family >= 4))
    if cuts:
        axes += [(2, 0), (2, 0)]
    extent = np.array([u1 - u0, v1 - v0, w1 - w0])
    outer_is_skin = w1 >= 1.0 - 1e-9
    token = skin == "surface" and outer_is_skin
    if size is not None:
        spans = [(int(size) - 2 * pad, int(size) - 2 * pad)] * len(axes)
    else:
        sample = cut_ct if cut_ct is not None else ct
        voxel = float(voxel_mm) if voxel_mm else (float(min(sample.spacing)) if sample is not None
                                                  else float(min(getattr(table, "voxel_mm", 1.0), 1.0)))
        speeds = _tile_speeds(mesh, params, family, axes, need_shells=not token or w0 > 0)
        spans = _texel_spans(speeds, axes, extent, voxel, token, pad, budget_mp)
    shapes = [(r + 2 * pad, c + 2 * pad) for r, c in spans]

    def grid(k, axis):       # pixel centres -> parameter (padding clamps)
        n, span = shapes[k][axes[k].index(axis)], spans[k][axes[k].index(axis)]
        t = np.clip((np.arange(n) + 0.5 - pad) / span, 0.0, 1.0)
        lo = (u0, v0, w0)[axis]
        return lo + t * extent[axis]

    direct = cut_ct if cut_ct is not None else ct
    air = float(direct.data.min()) if direct is not None and bool(np.any(family >= 2)) else 0.0

    def cut_tile(k):       # u ends (rows w, columns v) and v cuts (rows w, columns u) from the CT itself
        ws = grid(k, 2)
        if k in (2, 3):
            u = u1 if k == 2 else u0
            vs = grid(k, 1)
            spine = head.spine(np.array([u]))[0]
            pts = spine + ws[:, None, None] * (_surface_grid(head, np.array([u]), vs)[0][None] - spine)
        else:
            v = v1 if k == 4 else v0
            us = grid(k, 0)
            spine = head.spine(us)[None]
            # the surface along the cut at <= 97 heights, linear between them (its sagitta there is
            # ~0.03 mm): the PDE amplitudes per height are the cost, not the texels
            coarse = np.linspace(us[0], us[-1], min(len(us), 97))
            line = _surface_grid(head, coarse, np.array([v]))[:, 0]
            edge = np.column_stack([np.interp(us, coarse, line[:, i]) for i in range(3)])
            pts = spine + ws[:, None, None] * (edge[None] - spine)
        # trilinear, the lowest CT value outside, the edge value within the outer half voxel (as sample_ct):
        # the bottom u end lies on the scan's first slice, and micrometres below it (a reopened study's
        # curves, stored compact) must not turn that whole face to air
        return trilinear(direct.data, direct.patient_to_index(pts.reshape(-1, 3)), cval=air)

    def shell_w(k):
        if k == 1:
            return w0
        if skin == "ct" and outer_is_skin and skin_depth_mm > 0:
            radius = float(np.mean(np.linalg.norm(head.evaluate(np.full(64, 0.5), np.linspace(0, 2 * math.pi, 64,
                           endpoint=False), 1.0) - head.spine(np.array([0.5])), axis=1)))
            return max(w0, w1 - float(skin_depth_mm) / max(radius, 1e-6))
        return w1

    values = []
    for k in range(len(axes)):
        if k >= 2 and direct is not None:
            values.append(cut_tile(k))
        elif table is not None:
            g = table.sample_grid
            if k < 2:
                values.append(g(grid(k, 0), grid(k, 1), shell_w(k))[:, :, 0])
            elif k in (2, 3):
                values.append(g(u1 if k == 2 else u0, grid(k, 1), grid(k, 2))[0].T)
            else:
                values.append(g(grid(k, 0), v1 if k == 4 else v0, grid(k, 2))[:, 0].T)
        else:
            us, vs = grid(k, 0), grid(k, 1)
            surface = _surface_grid(head, us, vs)
            spine_u = head.spine(us)[:, None, :]
            values.append(sample_ct(ct, (spine_u + shell_w(k) * (surface - spine_u)).reshape(-1, 3)))
    offsets, height, width = _pack_tiles(shapes, None if size is None else 3 * int(size))   # fixed: 3 a row
    corner_uv, flipped = _tile_corner_uv(mesh, params, family, axes, offsets, spans, width, height, pad, ranges)
    atlas = np.ones((height, width, 4), np.float32)
    for k, raw in enumerate(values):
        (r0, c0), (nr, nc) = offsets[k], shapes[k]
        tile = apply_window(raw, window).reshape(nr, nc)
        atlas[r0:r0 + nr, c0:c0 + nc, :3] = (tile[:, ::-1] if flipped[k] else tile)[..., None]
    return atlas, corner_uv


def _texel_spans(speeds, axes, extent, voxel: float, token: bool, pad: int, budget_mp: float) -> list[tuple]:
    """Each tile's (rows, columns) of texels: its parameter extents times its ``speeds`` (mm per unit) over
    ``voxel`` mm, at least 4 (the skin's ``token`` tile 4 x 4); scaled down together until the packed atlas
    holds at most ``budget_mp`` megapixels."""
    spans = [tuple(max(4, int(math.ceil(sp * extent[a] / voxel))) for sp, a in zip(speed, pair))
             for speed, pair in zip(speeds, axes)]
    if token:
        spans[0] = (4, 4)
    need = sum((r + 2 * pad) * (c + 2 * pad) for r, c in spans)
    if need > budget_mp * 1e6:
        full, f = spans, math.sqrt(budget_mp * 1e6 / need)
        # the packed atlas (shelves, padding) is larger than its tiles: shrink until the atlas fits
        for _ in range(20):
            spans = [(max(4, int(r * f)), max(4, int(c * f))) for r, c in full]
            _, h, w = _pack_tiles([(r + 2 * pad, c + 2 * pad) for r, c in spans])
            if h * w <= budget_mp * 1e6:
                break
            f *= 0.97 * math.sqrt(budget_mp * 1e6 / (h * w))
    return spans


def _tile_corner_uv(mesh, params, family, axes, offsets, spans, width, height, pad, ranges):
    """Per corner its UV in the atlas's tiles, and per tile whether its columns run backwards.

    A box face and its opposite (the two u ends, the two v cuts) are wound opposite ways over the same
    (row, column) parameters, so one of them would be mirrored in UV space: that tile's columns are
    reversed (its texels too, by the caller), so no face of the layer is mirrored (painting
    and UV-less textures use the active layer)."""
    (u0, u1), (v0, v1), (w0, w1) = ranges
    extent = np.array([u1 - u0, v1 - v0, w1 - w0])
    lo = np.array([u0, v0, w0])
    norm = (params - lo) / np.where(extent > 0, extent, 1.0)
    starts, totals = mesh.loop_starts_and_totals()
    corner_family = np.repeat(family, totals)
    nxt = np.arange(len(params)) + 1
    nxt[starts + totals - 1] = starts
    corner_uv = np.zeros((len(params), 2))
    flipped = []
    for k, (row_axis, col_axis) in enumerate(axes):
        sel = corner_family == k
        col, row = norm[:, col_axis], norm[:, row_axis]
        # the tile's faces' signed area in (column, row): negative for a face wound against the tile
        cross = np.where(sel, col * row[nxt] - col[nxt] * row, 0.0)
        flip = bool(np.add.reduceat(cross, starts).sum() < 0.0) if len(starts) else False
        flipped.append(flip)
        (r0, c0), (sr, sc) = offsets[k], spans[k]
        corner_uv[sel, 0] = (c0 + pad + ((1.0 - col[sel]) if flip else col[sel]) * sc) / width
        corner_uv[sel, 1] = (r0 + pad + row[sel] * sr) / height
    return corner_uv, flipped


def box_face_uv(mesh, ranges, faces=None, size: int = 64, pad: int = 2) -> np.ndarray:
    """The layout of :func:`ct_texture_atlas` without its image (a tile of ``size`` pixels per box face):
    the solid's clean UV layer when it has no CT texture. Per corner its UV."""
    params, family = box_faces(mesh, ranges) if faces is None else faces
    axes = [(0, 1), (0, 1), (2, 1), (2, 1)] + ([(2, 0), (2, 0)] if bool(np.any(family >= 4)) else [])
    spans = [(int(size) - 2 * pad, int(size) - 2 * pad)] * len(axes)
    offsets, height, width = _pack_tiles([(r + 2 * pad, c + 2 * pad) for r, c in spans], 3 * int(size))
    return _tile_corner_uv(mesh, params, family, axes, offsets, spans, width, height, pad, ranges)[0]
