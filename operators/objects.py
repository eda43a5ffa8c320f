"""Blender objects of a PDE head study: boundary curves, surface and solid meshes.

One collection per study holds its objects. World coordinates are patient LPS
mm x 0.001 exactly (see :mod:`.coords`); every object of a study has its origin
at the study's centre, stored on the collection, and its data relative to it.
Meshes are filled with vectorised ``foreach_set`` calls so that the sidebar's
resolution sliders can rebuild an 80k-vertex surface live.
"""
from __future__ import annotations

import math

import numpy as np

from .coords import MM_TO_M

ORIGIN_KEY = "pdehead_origin_m"
STUDY_KEY = "pdehead_study"
SKIN_MATERIAL = "PDE Head Skin"
CT_MATERIAL = "PDE Head CT Intensity"
CURVE_MATERIAL = "PDE Head Boundary"
CT_COLOUR_ATTRIBUTE = "ct_intensity"
UV_NAME = "UVMap"
_RESERVED = {"position", "sharp_face", "material_index", UV_NAME, CT_COLOUR_ATTRIBUTE}


# ----------------------------------------------------------------------------- collections
def study_collection(name: str, scene=None):
    """The collection of study `name` (created and linked under the scene's collection if needed)."""
    import bpy

    scene = scene or bpy.context.scene
    coll = bpy.data.collections.get(name)
    if coll is None:
        coll = bpy.data.collections.new(name)
    coll[STUDY_KEY] = name
    if coll not in scene.collection.children_recursive:
        scene.collection.children.link(coll)
    return coll


def study_origin(collection, points_m: np.ndarray | None = None):
    """World origin (metres, ``mathutils.Vector``) shared by the study's objects.

    The first call with points stores the centre of their bounding box on the
    collection; later calls return the stored value, so every object of the
    study pivots about the same point and rebuilding never moves it.
    """
    from mathutils import Vector

    if ORIGIN_KEY in collection.keys():
        return Vector(tuple(collection[ORIGIN_KEY]))
    if points_m is None or len(points_m) == 0:
        return Vector((0.0, 0.0, 0.0))
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    collection[ORIGIN_KEY] = [float(c) for c in centre]
    return Vector(tuple(float(c) for c in centre))


def _place(obj, origin) -> None:
    """Put the object's origin at `origin` with no rotation or scale (keeps world = LPS * 0.001)."""
    from mathutils import Matrix

    obj.matrix_world = Matrix.Translation(origin)


def _link(obj, collection) -> None:
    if obj.name not in collection.objects:
        collection.objects.link(obj)


# ----------------------------------------------------------------------------- materials
def _material(name: str):
    import bpy

    mat = bpy.data.materials.get(name)
    created = mat is None
    if created:
        mat = bpy.data.materials.new(name)
        if mat.node_tree is None:
            mat.use_nodes = True
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


def ensure_ct_material():
    """Material showing the ``ct_intensity`` colour attribute, so cutaways reveal the interior."""
    mat, created = _material(CT_MATERIAL)
    if created:
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        bsdf = nodes.get("Principled BSDF")
        bsdf.inputs["Roughness"].default_value = 0.7
        attr = nodes.new("ShaderNodeVertexColor")
        attr.layer_name = CT_COLOUR_ATTRIBUTE
        attr.name = attr.label = "CT intensity"
        attr.location = (-400, 250)
        links.new(attr.outputs["Color"], bsdf.inputs["Base Color"])
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
    import bpy

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
    corner_vert = me.attributes.get(".corner_vert")  # Blender >= 4.0: direct attribute, much faster
    if corner_vert is not None:
        corner_vert.data.foreach_set("value", corner_verts)
    else:
        me.loops.foreach_set("vertex_index", corner_verts)
    me.polygons.add(len(starts))
    me.polygons.foreach_set("loop_start", starts.astype(np.int32))
    me.update(calc_edges=True)

    uv = mesh.loop_uv()
    if uv is not None:
        layer = me.attributes.new(UV_NAME, "FLOAT2", "CORNER")  # a FLOAT2 corner attribute is a UV map
        layer.data.foreach_set("vector", np.ascontiguousarray(uv, np.float32).ravel())
        me.uv_layers.active = me.uv_layers[UV_NAME]
    for key, values in mesh.vertex_attributes.items():
        if key in _RESERVED or key.startswith("."):
            continue
        if np.shape(values)[0] != n:
            raise ValueError(f"vertex attribute {key!r} has {np.shape(values)[0]} values for {n} vertices")
        kind, field, flat = _attribute_spec(values)
        me.attributes.new(key, kind, "POINT").data.foreach_set(field, flat)
    if smooth:
        if hasattr(me, "shade_smooth"):
            me.shade_smooth()
        else:  # Blender < 4.1
            me.polygons.foreach_set("use_smooth", np.ones(len(me.polygons), bool))


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
    the UV map ``"UVMap"``.
    """
    import bpy

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
        me.clear_geometry()  # keeps the mesh's materials; modifiers live on the object
    _fill_mesh(me, local, mesh, smooth)
    _place(obj, origin)
    return obj


def _mesh_attribute(obj, key):
    attr = obj.data.attributes[key]
    n = len(attr.data)
    width = {"FLOAT": 1, "INT": 1, "FLOAT2": 2, "FLOAT_VECTOR": 3, "FLOAT_COLOR": 4}[attr.data_type]
    field = {"FLOAT": "value", "INT": "value", "FLOAT2": "vector", "FLOAT_VECTOR": "vector",
             "FLOAT_COLOR": "color"}[attr.data_type]
    out = np.empty(n * width, np.float32 if attr.data_type != "INT" else np.int32)
    attr.data.foreach_get(field, out)
    return out.reshape(n, width) if width > 1 else out


def mesh_attribute(obj, key: str) -> np.ndarray:
    """An attribute of a mesh object as a numpy array (float32, (n,) or (n, c))."""
    return _mesh_attribute(obj, key)


def mesh_world_vertices(obj) -> np.ndarray:
    """World coordinates (metres) of a mesh object's vertices, (n, 3) float64."""
    me = obj.data
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    m = np.array(obj.matrix_world)
    return co.reshape(-1, 3).astype(np.float64) @ m[:3, :3].T + m[:3, 3]


def build_surface(head, collection, nu: int = 40, nv: int = 60, caps: bool = True, obj=None,
                  name: str = "Surface"):
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
    """
    mesh = head.surface(int(nu), int(nv), caps=bool(caps))
    obj = build_mesh_object(mesh, collection, name, obj=obj, smooth=True)
    _ensure_material(obj, ensure_skin_material())
    obj["pdehead_kind"] = "surface"
    obj["pdehead_resolution"] = [int(nu), int(nv)]
    return obj


def _set_ct_colour(obj, values01: np.ndarray) -> None:
    me = obj.data
    if CT_COLOUR_ATTRIBUTE in me.attributes:
        me.attributes.remove(me.attributes[CT_COLOUR_ATTRIBUTE])
    rgba = np.ones((len(values01), 4), np.float32)
    rgba[:, :3] = np.asarray(values01, np.float32)[:, None]
    attr = me.color_attributes.new(CT_COLOUR_ATTRIBUTE, "FLOAT_COLOR", "POINT")
    attr.data.foreach_set("color", rgba.ravel())
    me.color_attributes.active_color = me.color_attributes[CT_COLOUR_ATTRIBUTE]
    me.color_attributes.render_color_index = me.color_attributes.active_color_index


def build_solid(head, collection, nu: int = 40, nv: int = 60, nw: int = 5, u_range=(0.0, 1.0),
                v_range=(0.0, 2.0 * math.pi), w_range=(0.0, 1.0), ct=None, obj=None, name: str = "Solid",
                window=None):
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
    """
    from .volume import apply_window, intensity_window, sample_ct

    mesh = head.solid(int(nu), int(nv), int(nw), tuple(u_range), tuple(v_range), tuple(w_range))
    obj = build_mesh_object(mesh, collection, name, obj=obj, smooth=True)
    if ct is not None:
        window = intensity_window(ct) if window is None else window
        _set_ct_colour(obj, apply_window(sample_ct(ct, mesh.vertices), window))
        obj["pdehead_window"] = [float(window[0]), float(window[1])]
    elif "intensity" in mesh.vertex_attributes:
        values = np.asarray(mesh.vertex_attributes["intensity"], np.float32)
        window = intensity_window(values) if window is None else window
        _set_ct_colour(obj, apply_window(values, window))
    _ensure_material(obj, ensure_ct_material())
    obj["pdehead_kind"] = "solid"
    obj["pdehead_resolution"] = [int(nu), int(nv), int(nw)]
    obj["pdehead_ranges"] = [float(x) for x in (*u_range, *v_range, *w_range)]
    return obj
