"""Blender objects of a PDE head study: boundary curves, surface and solid meshes.

One collection per study holds its objects. World coordinates are patient LPS
mm x 0.001 exactly (see :mod:`.coords`); every object of a study has its origin
at the study's centre, stored on the collection, and its data relative to it.
Meshes are filled with vectorised ``foreach_set`` calls so that the sidebar's
resolution sliders can rebuild an 80k-vertex surface live. The solid's CT texture atlas is
computed in :mod:`operators.volume.ct_texture`.
"""
from __future__ import annotations

import math

import bpy
import numpy as np
from mathutils import Matrix

from ...pdehead_addon import apply_window, defaults as D, intensity_window, sample_ct
from .. import compat, state
from ..coords import MM_TO_M, study_origin
from ..volume.ct_texture import box_face_uv, box_faces, ct_texture_atlas

STUDY_KEY = "pdehead_study"
SKIN_MATERIAL = "PDE Head Skin"
CT_MATERIAL = "PDE Head CT Intensity"
CURVE_MATERIAL = "PDE Head Boundary"
CT_COLOUR_ATTRIBUTE = "ct_intensity"
CT_IMAGE_KEY = "pdehead_ct_image"
UV_NAME = "UVMap"
CT_UV_NAME = "CT texture"
_RESERVED = {"position", "sharp_face", "material_index", UV_NAME, CT_UV_NAME, CT_COLOUR_ATTRIBUTE}


# ----------------------------------------------------------------------------- collections
def study_collection(name: str, scene=None):
    """The collection of study `name` (created and linked under the scene's collection if needed)."""
    scene = scene or bpy.context.scene
    coll = bpy.data.collections.get(name)
    if coll is None:
        coll = bpy.data.collections.new(name)
    coll[STUDY_KEY] = name
    if coll not in scene.collection.children_recursive:
        scene.collection.children.link(coll)
    return coll


def _place(obj, origin) -> None:
    """Put the object's origin at `origin` with no rotation or scale (keeps world = LPS * 0.001)."""
    obj.matrix_world = Matrix.Translation(origin)


def _link(obj, collection) -> None:
    if obj.name not in collection.objects:
        collection.objects.link(obj)


# ----------------------------------------------------------------------------- materials
def _material(name: str):
    mat = bpy.data.materials.get(name)
    created = mat is None
    if created:
        mat = bpy.data.materials.new(name)
        compat.node_tree(mat)  # nodes on where Blender < 5.0 starts without
    return mat, created


def ensure_skin_material():
    """A plain skin-like Principled BSDF material for the surface."""
    mat, created = _material(SKIN_MATERIAL)
    if created:
        bsdf = mat.node_tree.nodes.get("Principled BSDF")
        bsdf.inputs["Base Color"].default_value = (0.80, 0.55, 0.44, 1.0)
        bsdf.inputs["Roughness"].default_value = 0.55
        bsdf.inputs["Subsurface Weight"].default_value = 0.05
        bsdf.inputs["Subsurface Radius"].default_value = (1.0, 0.4, 0.25)
        bsdf.inputs["Subsurface Scale"].default_value = 0.003
        mat.diffuse_color = (0.80, 0.55, 0.44, 1.0)  # solid viewport colour
    return mat


def ensure_ct_material(obj=None, image=None):
    """Material showing the CT on the solid, so cutaways reveal the interior.

    With `image` (the CT texture atlas of :func:`build_solid`) the colour comes
    from that image through the ``CT texture`` UV map: the CT sampled finely
    over every face of the parametric box (the paper's 3-D texture mapping of
    section 4.3.1). Without it, from the per-vertex colour ``ct_intensity``.
    One material per solid object (each has its own image).
    """
    name = CT_MATERIAL if obj is None else f"{CT_MATERIAL} {obj.name}"
    mat = bpy.data.materials.get(name)
    if mat is None:
        mat = bpy.data.materials.new(name)
        compat.node_tree(mat)  # nodes on where Blender < 5.0 starts without
        mat["pdehead_ct_material"] = 1
        nodes = mat.node_tree.nodes
        bsdf = nodes.get("Principled BSDF")
        bsdf.inputs["Roughness"].default_value = 0.7
        attr = nodes.new("ShaderNodeVertexColor")
        attr.layer_name = CT_COLOUR_ATTRIBUTE
        attr.name = attr.label = "CT intensity"
        attr.location = (-400, 250)
        uv = nodes.new("ShaderNodeUVMap")
        uv.uv_map = CT_UV_NAME
        uv.name = uv.label = "CT texture UV"
        uv.location = (-700, -50)
        tex = nodes.new("ShaderNodeTexImage")
        tex.name = tex.label = "CT texture"
        tex.interpolation = "Linear"
        tex.extension = "EXTEND"
        tex.location = (-450, -50)
        mat.node_tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf, tex, attr = nodes.get("Principled BSDF"), nodes.get("CT texture"), nodes.get("CT intensity")
    tex.image = image
    source = tex.outputs["Color"] if image is not None else attr.outputs["Color"]
    links.new(source, bsdf.inputs["Base Color"])
    return mat


def ensure_curve_material():
    mat, created = _material(CURVE_MATERIAL)
    if created:
        bsdf = mat.node_tree.nodes.get("Principled BSDF")
        bsdf.inputs["Base Color"].default_value = (0.05, 0.35, 0.9, 1.0)
        bsdf.inputs["Emission Color"].default_value = (0.05, 0.35, 0.9, 1.0)
        bsdf.inputs["Emission Strength"].default_value = 0.5
        mat.diffuse_color = (0.05, 0.35, 0.9, 1.0)
    return mat


def _ensure_material(obj, mat) -> None:
    """Give `obj` the material unless it already has one (user choices survive rebuilds)."""
    if not obj.data.materials or obj.data.materials[0] is None:
        if obj.data.materials:
            obj.data.materials[0] = mat
        else:
            obj.data.materials.append(mat)


# ----------------------------------------------------------------------------- boundary curves
def build_boundary_curves(bset, collection, name: str = "Boundary curves", obj=None, bevel_mm: float = 0.6):
    """The 3t+1 boundary curves (Fig. 4a) as one curve object of closed POLY splines.

    Parameters
    ----------
    bset : BoundarySet
        ``curves`` (3t+1, M, 3) in LPS mm.
    collection : bpy.types.Collection
    obj : bpy.types.Object, optional
        Existing curve object to refill in place (keeps its settings and materials).
    bevel_mm : float
        Tube radius so that the curves show in renders (0: lines only).
    """
    curves = np.asarray(bset.curves, dtype=np.float64) * MM_TO_M
    origin = study_origin(collection, curves.reshape(-1, 3))
    local = curves - np.asarray(origin)
    if obj is None:
        data = bpy.data.curves.new(name, "CURVE")
        obj = bpy.data.objects.new(name, data)
        _link(obj, collection)
    elif obj.type != "CURVE":
        raise TypeError(f"object {obj.name!r} is not a curve object")
    data = obj.data
    data.splines.clear()
    data.dimensions = "3D"
    data.bevel_depth = max(0.0, float(bevel_mm)) * MM_TO_M
    data.bevel_resolution = 2
    data.fill_mode = "FULL"
    n, m = local.shape[:2]
    co = np.ones((m, 4), np.float32)
    for c in range(n):  # 3t+1 splines (31 for t = 10): the points themselves are set in bulk
        spline = data.splines.new("POLY")
        spline.points.add(m - 1)
        co[:, :3] = local[c]
        spline.points.foreach_set("co", co.ravel())
        spline.use_cyclic_u = True
    _place(obj, origin)
    obj["pdehead_kind"] = "boundary_curves"
    obj["pdehead_patches"] = int(bset.patches)
    _ensure_material(obj, ensure_curve_material())
    return obj


# ----------------------------------------------------------------------------- meshes
def _attribute_spec(values: np.ndarray):
    """(data type, foreach key, flat array) of a per-vertex array for mesh.attributes."""
    a = np.asarray(values)
    if a.ndim == 1:
        if a.dtype == bool:
            return "BOOLEAN", "value", a.astype(bool)
        if np.issubdtype(a.dtype, np.integer):
            return "INT", "value", a.astype(np.int32)
        return "FLOAT", "value", a.astype(np.float32)
    width = a.shape[1]
    kinds = {2: ("FLOAT2", "vector"), 3: ("FLOAT_VECTOR", "vector"), 4: ("FLOAT_COLOR", "color")}
    if a.ndim != 2 or width not in kinds:
        raise ValueError(f"vertex attribute of shape {a.shape} is not supported")
    kind, key = kinds[width]
    return kind, key, np.ascontiguousarray(a, dtype=np.float32).ravel()


def _fill_mesh(me, vertices_local: np.ndarray, mesh, smooth: bool) -> None:
    """Fill an empty Blender mesh from an engine Mesh with bulk foreach_set calls."""
    n = len(vertices_local)
    corner_verts = mesh.loop_vertex_indices().astype(np.int32)
    starts, _totals = mesh.loop_starts_and_totals()
    me.vertices.add(n)
    me.attributes["position"].data.foreach_set("vector", np.ascontiguousarray(vertices_local, np.float32).ravel())
    me.loops.add(len(corner_verts))
    compat.set_corner_vertices(me, corner_verts)
    me.polygons.add(len(starts))
    me.polygons.foreach_set("loop_start", starts.astype(np.int32))
    me.update(calc_edges=True)

    _write_attributes(me, mesh, n)
    if mesh.loop_uv() is not None:
        me.uv_layers.active = me.uv_layers[UV_NAME]
    if smooth:
        compat.shade_smooth(me)


def _same_topology(me, mesh, corner_verts: np.ndarray, n_vertices: int) -> bool:
    """Whether Blender mesh `me` already has the vertex count, faces and corners of engine `mesh`."""
    starts, _totals = mesh.loop_starts_and_totals()
    if len(me.vertices) != n_vertices or len(me.polygons) != len(starts) or len(me.loops) != len(corner_verts):
        return False
    current = np.empty(len(corner_verts), np.int32)
    corner_vert = me.attributes.get(".corner_vert")
    if corner_vert is not None:
        corner_vert.data.foreach_get("value", current)
    else:
        me.loops.foreach_get("vertex_index", current)
    if not np.array_equal(current, corner_verts):
        return False
    current_starts = np.empty(len(starts), np.int32)
    me.polygons.foreach_get("loop_start", current_starts)
    return bool(np.array_equal(current_starts, starts))


def _set_attribute(me, key: str, kind: str, domain: str, field: str, flat: np.ndarray) -> None:
    """Write a mesh attribute in place (created, or re-created when its type or domain differs)."""
    attr = me.attributes.get(key)
    if attr is not None and (attr.data_type != kind or attr.domain != domain):
        me.attributes.remove(attr)
        attr = None
    if attr is None:
        attr = me.attributes.new(key, kind, domain)
    attr.data.foreach_set(field, flat)


def _update_mesh_in_place(me, vertices_local: np.ndarray, mesh) -> None:
    """Same topology: rewrite positions, UVs and vertex attributes only (the fast live path)."""
    me.attributes["position"].data.foreach_set("vector", np.ascontiguousarray(vertices_local, np.float32).ravel())
    _write_attributes(me, mesh, len(vertices_local))
    me.update()


def _write_attributes(me, mesh, n: int) -> None:
    """The engine mesh's UVs (a FLOAT2 corner attribute is a UV map) and vertex attributes, created or
    rewritten in place: one path for a new mesh and for the live update."""
    uv = mesh.loop_uv()
    if uv is not None:
        _set_attribute(me, UV_NAME, "FLOAT2", "CORNER", "vector", np.ascontiguousarray(uv, np.float32).ravel())
    for key, values in mesh.vertex_attributes.items():
        if key in _RESERVED or key.startswith("."):
            continue
        if np.shape(values)[0] != n:
            raise ValueError(f"vertex attribute {key!r} has {np.shape(values)[0]} values for {n} vertices")
        kind, field, flat = _attribute_spec(values)
        _set_attribute(me, key, kind, "POINT", field, flat)


def build_mesh_object(mesh, collection, name: str, obj=None, smooth: bool = True):
    """A mesh object from an engine :class:`~pdehead_addon.Mesh` (LPS mm -> world metres).

    Parameters
    ----------
    mesh : Mesh
        Vertices (n, 3) LPS mm, quads, triangles, per-corner UV, per-vertex attributes.
    collection : bpy.types.Collection
        Study collection; its stored origin becomes the object's origin.
    name : str
        Name of a new object and its mesh.
    obj : bpy.types.Object, optional
        Rebuild this object in place: its mesh data is cleared and refilled, so
        the object, its materials and its modifiers stay.
    smooth : bool
        Smooth shading.

    Notes
    -----
    Every ``vertex_attributes`` entry becomes a POINT attribute (FLOAT for
    (n,), FLOAT2/FLOAT_VECTOR/FLOAT_COLOR for (n, 2/3/4)); per-corner UVs become
    the UV map ``"UVMap"``. When `obj`'s mesh already has this topology (same
    faces, e.g. a cutaway change at the same resolution) only positions and
    attributes are rewritten, in place, with ``foreach_set``.
    """
    world = np.asarray(mesh.vertices, dtype=np.float64) * MM_TO_M
    origin = study_origin(collection, world)
    local = world - np.asarray(origin)
    if obj is None:
        me = bpy.data.meshes.new(name)
        obj = bpy.data.objects.new(name, me)
        _link(obj, collection)
    else:
        if obj.type != "MESH":
            raise TypeError(f"object {obj.name!r} is not a mesh object")
        me = obj.data
        corner_verts = mesh.loop_vertex_indices().astype(np.int32)
        if _same_topology(me, mesh, corner_verts, len(local)):
            _update_mesh_in_place(me, local, mesh)
            _place(obj, origin)
            return obj
        me.clear_geometry()  # keeps the mesh's materials; modifiers live on the object
    _fill_mesh(me, local, mesh, smooth)
    _place(obj, origin)
    return obj


def build_surface(head, collection, nu: int = D.NU.default, nv: int = D.NV.default, caps: bool = D.CAPS.default,
                  obj=None, name: str = "Surface"):
    """The PDE head surface X(u, v) (eq. 7-13; Fig. 4, 11) as a smooth mesh with UVs (u, v).

    Parameters
    ----------
    head : PDEHead
        Solved PDE head; ``head.surface(nu, nv, caps)`` gives the engine Mesh.
    nu, nv : int
        Parametric resolution along u (head axis) and v (around).
    caps : bool
        Close the top and bottom.
    obj : bpy.types.Object, optional
        Rebuild in place (keeps object, materials, modifiers).

    Rows and columns sit closer where the surface bends tightly (``fit_bends``: no slit under the ears at
    the viewport's resolution); the topology is that of ``head.surface(nu, nv, caps)``.
    """
    mesh = head.surface(int(nu), int(nv), caps=bool(caps), fit_bends=True)
    obj = build_mesh_object(mesh, collection, name, obj=obj, smooth=True)
    _ensure_material(obj, ensure_skin_material())
    obj["pdehead_kind"] = "surface"
    obj["pdehead_resolution"] = [int(nu), int(nv)]
    return obj


def _set_ct_colour(obj, values01: np.ndarray) -> None:
    me = obj.data
    rgba = np.ones((len(values01), 4), np.float32)
    rgba[:, :3] = np.asarray(values01, np.float32)[:, None]
    attr = me.color_attributes.get(CT_COLOUR_ATTRIBUTE)
    if attr is None or attr.data_type != "FLOAT_COLOR" or attr.domain != "POINT":
        if attr is not None:
            me.color_attributes.remove(attr)
        attr = me.color_attributes.new(CT_COLOUR_ATTRIBUTE, "FLOAT_COLOR", "POINT")
    attr.data.foreach_set("color", rgba.ravel())
    me.color_attributes.active_color = me.color_attributes[CT_COLOUR_ATTRIBUTE]
    me.color_attributes.render_color_index = me.color_attributes.active_color_index


def _vertex_values_from_table(table, mesh) -> np.ndarray:
    """CT at the solid's vertices from the (u, v, w) table: the vertices lie on the grid of
    their distinct u, v and w values, so the grid is interpolated once and indexed."""
    params = [np.asarray(mesh.vertex_attributes[k], np.float64) for k in ("u", "v", "w")]
    levels, index = zip(*(np.unique(p, return_inverse=True) for p in params))
    grid = table.sample_grid(*levels)
    return grid[index[0], index[1], index[2]]


def _set_ct_texture(obj, atlas: np.ndarray, corner_uv: np.ndarray, budget_px: float = 0.0, transient: bool = False):
    """Store the atlas in the object's CT image (packed into the .blend) and its UV map.

    ``Image.scale`` resamples the old pixels before the new ones are written (~9 ms on GE, most of a live
    change's texture cost), and the atlas's size changes at every change: the quick 128-pixel tiles of a
    live change (``transient``) and the full tiles of the colour refresh right after, whose shelves come
    out in a few shapes as a slider moves the tiles' sizes. So an image that holds the atlas keeps its size
    (the atlas in its corner, the UVs scaled to it): a transient atlas goes into any larger image; a full
    one into an image up to :data:`ATLAS_REUSE_AREA` times its area, which grows to hold both shapes
    while that fits ``budget_px``; else the image takes the atlas's own size.
    """
    me = obj.data
    h, w = atlas.shape[:2]
    name = f"PDE Head CT {obj.name}"
    image = bpy.data.images.get(name)
    if image is None:
        image = bpy.data.images.new(name, w, h, alpha=False)
    else:
        width, height = (int(x) for x in image.size)
        holds = width >= w and height >= h
        if not (holds and (transient or width * height <= ATLAS_REUSE_AREA * w * h)):
            width, height = max(width, w), max(height, h)           # both shapes, within the budget
            if transient or width * height > min(budget_px, ATLAS_REUSE_AREA * w * h):
                width, height = w, h
            image.scale(width, height)
        if (width, height) != (w, h):
            padded = np.ones((height, width, 4), np.float32)
            padded[:h, :w] = atlas
            atlas, corner_uv = padded, np.asarray(corner_uv) * (w / width, h / height)
    _set_box_uv(me, corner_uv)
    image.pixels.foreach_set(np.ascontiguousarray(atlas, np.float32).ravel())
    image.update()
    # generated images are lost on save unless packed; packing (PNG encoding) on every slider step
    # would cost more than the rest of it, so the save handler packs changed ones (pack_ct_images)
    image[CT_IMAGE_KEY] = 1
    if image.packed_file is None:
        image.pack()
    else:
        state.REGISTRY.unpacked_changes.add(image.name)
    return image


def _set_box_uv(me, corner_uv: np.ndarray) -> None:
    """Write the solid's box-face layout (:func:`.ct_texture_atlas`'s tiles) into its ``CT texture``
    UV layer and make that layer the active and the render one: it is the solid's clean layer (no mirrored or
    empty face); its (u, v) layer folds the inner shell and the cut faces over the outer one, so it is not
    what painting or a UV-less texture should use."""
    _set_attribute(me, CT_UV_NAME, "FLOAT2", "CORNER", "vector", np.ascontiguousarray(corner_uv, np.float32).ravel())
    if CT_UV_NAME in me.uv_layers:
        me.uv_layers.active = me.uv_layers[CT_UV_NAME]
        me.uv_layers[CT_UV_NAME].active_render = True


#: A solid's CT image is reused for a smaller atlas (its corner; the UVs scaled) up to this area ratio.
ATLAS_REUSE_AREA = 2.0

def pack_ct_images() -> int:
    """Pack the CT atlas images changed since their last packing (``state.REGISTRY.unpacked_changes``; called
    before saving); returns the count."""
    count = 0
    for name in sorted(state.REGISTRY.unpacked_changes):
        image = bpy.data.images.get(name)
        if image is not None and image.get(CT_IMAGE_KEY) == 1:
            image.pack()
            count += 1
    state.REGISTRY.unpacked_changes.clear()
    return count


def _sharp_cut_faces(obj, family: np.ndarray) -> None:
    """Flat-shade the u-end and v-cut faces (smooth shells): no smeared normals across the 90 degree edges."""
    me = obj.data
    sharp = np.asarray(family) >= 2
    compat.set_sharp_faces(me, sharp)
    me.update()


def _skin_faces(obj, family: np.ndarray, on: bool) -> None:
    """The outer shell (w = 1) in material slot 1, the skin: the surface's material unless the
    user put another there; the cut faces keep slot 0 (the CT). Off: every face shows the CT."""
    me = obj.data
    if on:
        while len(me.materials) < 2:
            me.materials.append(None)
        if me.materials[1] is None:
            me.materials[1] = ensure_skin_material()
    index = np.where(np.asarray(family) == 0, 1, 0) if on else np.zeros(len(family), int)
    compat.set_material_indices(me, index)
    me.update()


def _snap_range(r, top: float, tol: float = 1e-5) -> tuple[float, float]:
    """A parameter range with float32 round-off at 0 and `top` removed (Blender float properties are float32,
    so 2 pi comes back as 6.2831855 > 2 pi, which the engine rightly rejects)."""
    a, b = (float(x) for x in r)
    snap = lambda x: 0.0 if abs(x) <= tol else (top if abs(x - top) <= tol * max(1.0, top) else x)  # noqa: E731
    return snap(a), snap(b)


def build_solid(head, collection, nu: int = D.NU.default, nv: int = D.NV.default, nw: int = D.NW.default,
                u_range=D.U_RANGE.default, v_range=D.V_RANGE.default, w_range=D.W_RANGE.default, ct=None, obj=None,
                name: str = "Solid",
                window=None, texture_size: int | None = None, ct_table=None,
                texture_budget: float = D.CT_TEXTURE_BUDGET.default, skin: str = D.SOLID_SKIN.default,
                skin_depth_mm: float = D.SOLID_SKIN_DEPTH.default, cut_ct=None):
    """The PDE solid X(u, v, w) (eq. 23; Fig. 7, 14) with cutaway ranges, coloured by the CT.

    Parameters
    ----------
    head : PDEHead
        ``head.solid(nu, nv, nw, u_range, v_range, w_range)`` gives the Mesh
        with ``vertex_attributes["w"]``.
    nu, nv, nw : int
        Samples along u, v and w (paper: 40, 60, 5).
    u_range, v_range, w_range : (float, float)
        Parameter ranges; e.g. v in [pi/2, 2 pi] cuts a quarter away (Fig. 14b).
    ct : CTVolume, optional
        The CT, sampled trilinearly at the vertices' patient positions and
        windowed to [0, 1] into the POINT colour attribute ``ct_intensity``.
    window : (lo, hi), optional
        Intensity window (default ``intensity_window(ct)``).
    obj : bpy.types.Object, optional
        Rebuild in place.
    texture_size : int, optional
        Pixels per box face of the CT texture atlas, all faces alike (the older layout;
        0 for vertex colours only). Default: tiles sized from each face's extent in mm
        (:func:`ct_texture_atlas`), about one texel per CT voxel within ``texture_budget``.
    ct_table : SolidCTTable, optional
        The CT tabulated in (u, v, w) for this head (fast atlas for live cutaways).
    texture_budget : float
        Megapixels the atlas may use (``defaults.CT_TEXTURE_BUDGET``).
    skin, skin_depth_mm
        What the outside (w = 1) shows: ``"surface"`` the skin material (slot 1, the surface's
        material), ``"ct"`` the CT ``skin_depth_mm`` inside the skin (``defaults.SOLID_SKIN``).
    cut_ct : CTVolume, optional
        The CT the cut faces are sampled from when ``ct`` is not given (the live path: the CT in
        memory, while the vertex colours come from the table).

    Notes
    -----
    Rebuilding an existing solid with the same topology (a cutaway change at the same
    nu, nv, nw) only rewrites positions and attributes in place (:func:`build_mesh_object`).
    """

    u_range, v_range, w_range = (_snap_range(u_range, 1.0), _snap_range(v_range, 2.0 * math.pi),
                                 _snap_range(w_range, 1.0))
    mesh = head.solid(int(nu), int(nv), int(nw), u_range, v_range, w_range)
    obj = build_mesh_object(mesh, collection, name, obj=obj, smooth=True)
    image = None
    faces = None
    if "w" in mesh.vertex_attributes and mesh.quad_uv is not None:
        faces = box_faces(mesh, (u_range, v_range, w_range))  # once: the atlas and the flat cut faces use it
    if ct is not None or (ct_table is not None and window is not None):  # the table alone serves (no CT)
        window = intensity_window(ct) if window is None else window
        if ct_table is not None and {"u", "v", "w"} <= set(mesh.vertex_attributes):
            raw = _vertex_values_from_table(ct_table, mesh)
        else:
            raw = sample_ct(ct, mesh.vertices)
        _set_ct_colour(obj, apply_window(raw, window))
        obj["pdehead_window"] = [float(window[0]), float(window[1])]
        if texture_size != 0 and mesh.quad_uv is not None and "w" in mesh.vertex_attributes:
            atlas, corner_uv = ct_texture_atlas(head, mesh, ct, window, (u_range, v_range, w_range),
                                                size=None if texture_size is None else int(texture_size),
                                                table=ct_table, faces=faces, budget_mp=float(texture_budget),
                                                skin=skin, skin_depth_mm=float(skin_depth_mm), cut_ct=cut_ct)
            image = _set_ct_texture(obj, atlas, corner_uv, budget_px=float(texture_budget) * 1e6,
                                    transient=texture_size is not None)
    elif "intensity" in mesh.vertex_attributes:
        values = np.asarray(mesh.vertex_attributes["intensity"], np.float32)
        window = intensity_window(values) if window is None else window
        _set_ct_colour(obj, apply_window(values, window))
    if faces is not None and image is None:            # no CT texture: the same clean layout, no image
        _set_box_uv(obj.data, box_face_uv(mesh, (u_range, v_range, w_range), faces))
    if faces is not None:
        _sharp_cut_faces(obj, faces[1])
    mat = ensure_ct_material(obj, image)
    slots = obj.data.materials
    if not slots or slots[0] is None or slots[0].get("pdehead_ct_material") == 1:
        if slots:
            slots[0] = mat
        else:
            slots.append(mat)
    if faces is not None:
        _skin_faces(obj, faces[1], skin == "surface" and w_range[1] >= 1.0 - 1e-9)
    obj["pdehead_kind"] = "solid"
    obj["pdehead_resolution"] = [int(nu), int(nv), int(nw)]
    obj["pdehead_ranges"] = [float(x) for x in (*u_range, *v_range, *w_range)]
    return obj
