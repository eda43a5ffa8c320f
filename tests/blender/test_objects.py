"""Blender objects of a study: boundary curves, PDE surface and PDE solid (operators/scene/objects.py).

Runs the real engine on the phantom (segment_head -> extract_boundaries -> solve_pde) and checks
the Blender data against the engine's numbers: counts, world coordinates (= LPS mm x 0.001),
UVs, attributes, in-place rebuilds and the front-view orientation.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

import blender_inspect  # tests/blender/blender_inspect.py

MM = 0.001


@pytest.fixture(scope="module")
def phantom_bset(phantom_seg):
    from pdehead_addon import extract_boundaries
    return extract_boundaries(phantom_seg, patches=10, samples=128)


@pytest.fixture(scope="module")
def phantom_head(phantom_bset):
    from pdehead_addon import solve_pde
    return solve_pde(phantom_bset)


def test_grid_matrix_maps_voxel_index_to_patient_metres(ext):
    """grid_affine_world: (i, j, k) -> CTVolume.index_to_patient((k, j, i)) * 0.001 for an oblique grid."""
    from pdehead_addon import CTVolume
    a = math.radians(18.5)
    direction = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ct = CTVolume(np.zeros((5, 6, 7), np.float32), spacing=(4.0, 1.08, 0.9), origin=(-120.0, 30.0, 55.0),
                  direction=direction)
    m = ext.coords.grid_affine_world(ct.spacing, ct.origin, ct.direction)
    kji = np.array([[0, 0, 0], [4, 5, 6], [2, 1, 3], [1, 4, 0]], float)
    ijk1 = np.c_[kji[:, ::-1], np.ones(len(kji))]
    np.testing.assert_allclose((ijk1 @ m.T)[:, :3], ct.index_to_patient(kji) * MM, atol=1e-12)


def test_study_collection_created_once_and_linked(ext):
    import bpy
    a = ext.scene.objects.study_collection("Study A")
    b = ext.scene.objects.study_collection("Study A")
    assert a == b and a.name == "Study A"
    assert a in bpy.context.scene.collection.children_recursive
    assert len([c for c in bpy.data.collections if c.name.startswith("Study A")]) == 1


def test_boundary_curves_one_object_of_closed_splines(ext, phantom_bset):
    coll = ext.scene.objects.study_collection("Phantom")
    obj = ext.scene.objects.build_boundary_curves(phantom_bset, coll)
    assert obj.type == "CURVE" and obj.name in coll.objects
    splines = obj.data.splines
    assert len(splines) == 3 * phantom_bset.patches + 1 == 31
    assert all(s.use_cyclic_u and s.type == "POLY" and len(s.points) == 128 for s in splines)
    m = np.array(obj.matrix_world)
    np.testing.assert_allclose(m[:3, :3], np.eye(3))
    for c in (0, 15, 30):
        co = np.empty(128 * 4, np.float32)
        splines[c].points.foreach_get("co", co)
        world = co.reshape(-1, 4)[:, :3] @ m[:3, :3].T + m[:3, 3]
        np.testing.assert_allclose(world, phantom_bset.curves[c] * MM, atol=1e-6)
    # the origin is the study centre (shared with later objects), not the LPS origin
    centre = 0.5 * (phantom_bset.curves.reshape(-1, 3).min(0) + phantom_bset.curves.reshape(-1, 3).max(0)) * MM
    np.testing.assert_allclose(np.array(obj.location), centre, atol=1e-6)
    np.testing.assert_allclose(coll["pdehead_origin_m"], centre, atol=1e-9)
    # rebuilt in place: same object, same data, new content
    data = obj.data
    again = ext.scene.objects.build_boundary_curves(phantom_bset, coll, obj=obj)
    assert again == obj and again.data == data and len(data.splines) == 31


def test_surface_mesh_matches_engine(ext, phantom_head):
    import bpy
    coll = ext.scene.objects.study_collection("Phantom")
    mesh = phantom_head.surface(40, 60, caps=True, fit_bends=True)        # the viewport places rows at bends
    obj = ext.scene.objects.build_surface(phantom_head, coll, nu=40, nv=60, caps=True)
    me = obj.data
    assert len(me.vertices) == len(mesh.vertices)
    assert len(me.polygons) == mesh.face_count and len(me.loops) == mesh.loop_vertex_indices().size
    # float32 in Blender
    np.testing.assert_allclose(blender_inspect.mesh_world_vertices(obj), mesh.vertices * MM, atol=2e-6)
    corners = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", corners)
    np.testing.assert_array_equal(corners, mesh.loop_vertex_indices())
    # UV map from the per-corner (u, v)
    assert [uv.name for uv in me.uv_layers] == ["UVMap"]
    uv = np.empty(len(me.loops) * 2, np.float32)
    me.uv_layers["UVMap"].data.foreach_get("uv", uv)
    np.testing.assert_allclose(uv.reshape(-1, 2), mesh.loop_uv(), atol=1e-6)
    assert 0.0 <= uv.min() and uv.max() <= 1.0 + 1e-6
    # smooth shaded, closed, skin material
    smooth = np.empty(len(me.polygons), bool)
    me.polygons.foreach_get("use_smooth", smooth)
    assert smooth.all()
    corner_edges = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("edge_index", corner_edges)
    assert np.all(np.bincount(corner_edges, minlength=len(me.edges)) == 2)  # closed: 2 faces per edge
    assert me.validate(verbose=False) is False  # nothing to fix
    mat = obj.material_slots[0].material
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    r, g, b, _ = bsdf.inputs["Base Color"].default_value
    assert r > g > b > 0.2  # skin-like
    # the mesh encloses the engine's volume: outward normals (positive signed volume in Blender too)
    bm_volume = _signed_volume(blender_inspect.mesh_world_vertices(obj), me)
    assert bm_volume > 0.5 * 4 / 3 * math.pi * 0.06 * 0.08 * 0.09
    assert bpy.data.meshes[me.name] == me


def _signed_volume(world, me) -> float:
    me.calc_loop_triangles()
    tris = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("vertices", tris)
    p = world[tris.reshape(-1, 3)]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)


def test_surface_rebuilt_in_place_keeps_object_material_modifier(ext, phantom_head):
    import bpy
    coll = ext.scene.objects.study_collection("Phantom")
    obj = ext.scene.objects.build_surface(phantom_head, coll, nu=20, nv=30)
    custom = bpy.data.materials.new("user material")
    obj.material_slots[0].material = custom
    obj.modifiers.new("Subdivision", "SUBSURF")
    meshes_before = len(bpy.data.meshes)
    data = obj.data
    timings = []
    for nu, nv in ((200, 400), (200, 400), (35, 50)):
        t = time.perf_counter()
        same = ext.scene.objects.build_surface(phantom_head, coll, nu=nu, nv=nv, obj=obj)
        timings.append(time.perf_counter() - t)
        assert same == obj and obj.data == data
        assert len(obj.data.vertices) == len(phantom_head.surface(nu, nv, caps=True).vertices)
    print(f"surface rebuild 200x400 (incl. engine evaluation): {timings[0]:.3f}, {timings[1]:.3f} s")
    assert len(bpy.data.meshes) == meshes_before  # no orphan meshes
    assert obj.material_slots[0].material == custom
    assert [m.type for m in obj.modifiers] == ["SUBSURF"]
    assert "UVMap" in obj.data.uv_layers and len(obj.data.uv_layers) == 1


def test_build_mesh_object_large_mesh_and_attributes(ext, phantom_head):
    """The bulk path at 200x400 (~80k vertices) with every attribute kind; time is printed, not asserted."""
    coll = ext.scene.objects.study_collection("Phantom")
    mesh = phantom_head.surface(200, 400, caps=True)
    n = len(mesh.vertices)
    mesh.vertex_attributes = {"scalar": np.linspace(0, 1, n), "vec": np.tile([1.0, 2.0, 3.0], (n, 1)),
                              "rgba": np.tile([0.1, 0.2, 0.3, 1.0], (n, 1)), "label": np.arange(n) % 7}
    t = time.perf_counter()
    obj = ext.scene.objects.build_mesh_object(mesh, coll, "Big")
    elapsed = time.perf_counter() - t
    print(f"build_mesh_object {n} vertices, {mesh.face_count} faces: {elapsed * 1000:.1f} ms")
    me = obj.data
    assert len(me.vertices) == n > 199 * 400 + 1             # the dome's crown, the bottom's disc rings
    kinds = {a.name: (a.data_type, a.domain) for a in me.attributes}
    assert kinds["scalar"] == ("FLOAT", "POINT") and kinds["vec"] == ("FLOAT_VECTOR", "POINT")
    assert kinds["rgba"] == ("FLOAT_COLOR", "POINT") and kinds["label"] == ("INT", "POINT")
    np.testing.assert_allclose(blender_inspect.mesh_attribute(obj, "scalar"), np.linspace(0, 1, n), atol=1e-6)
    np.testing.assert_array_equal(blender_inspect.mesh_attribute(obj, "label"), np.arange(n) % 7)
    np.testing.assert_allclose(blender_inspect.mesh_attribute(obj, "vec")[123], [1, 2, 3])


def test_front_view_sees_the_face_with_patient_left_on_the_right(ext, phantom, phantom_head):
    """World = LPS x 0.001: the nose tip is the most anterior point (-Y, what numpad 1 sees first),
    and a marker on the patient's left ends up at +X (screen right in the front view)."""
    from pdehead_addon import Mesh
    coll = ext.scene.objects.study_collection("Phantom")
    surface = ext.scene.objects.build_surface(phantom_head, coll, nu=80, nv=120)
    world = blender_inspect.mesh_world_vertices(surface)
    nose = world[np.argmin(world[:, 1])]
    np.testing.assert_allclose(nose / MM, phantom.params["nose_tip"], atol=8.0)
    left_eye = np.asarray(phantom.params["eye_centres"][1])  # the patient's left eye: LPS x > 0
    assert left_eye[0] > 0
    cube = np.array([[x, y, z] for x in (-3, 3) for y in (-3, 3) for z in (-3, 3)], float) + left_eye + [50, 0, 0]
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    marker = ext.scene.objects.build_mesh_object(Mesh(cube, quads), coll, "Left marker")
    mw = blender_inspect.mesh_world_vertices(marker).mean(axis=0)
    assert mw[0] > world[:, 0].mean() + 0.06  # patient's left = Blender +X
    np.testing.assert_allclose(mw, (left_eye + [50, 0, 0]) * MM, atol=1e-6)
    # all study objects share the origin
    np.testing.assert_allclose(np.array(marker.location), np.array(surface.location))


def _check_texture_matches_ct(obj, image, mesh, head, ct, window):
    """The atlas colour at each face's UV centre is the windowed CT at the face's parametric centre."""
    from scipy.ndimage import map_coordinates
    w_img, h_img = image.size
    pix = np.empty(w_img * h_img * 4, np.float32)
    image.pixels.foreach_get(pix)
    pix = pix.reshape(h_img, w_img, 4)[..., 0]
    me = obj.data
    uv = np.empty(len(me.loops) * 2, np.float32)
    me.uv_layers["CT texture"].data.foreach_get("uv", uv)
    uv = uv.reshape(-1, 2)
    starts, totals = mesh.loop_starts_and_totals()
    material = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("material_index", material)
    quads = np.flatnonzero((totals == 4) & (material == 0))        # slot 1 is the skin: no CT there (issue 21)
    corner = starts[quads][:, None] + np.arange(4)
    centre_uv = uv[corner].mean(axis=1)
    # parametric centre of each quad: (u, v) from the engine's corner UVs, w from the vertices
    loop_uv = mesh.loop_uv()
    w = np.asarray(mesh.vertex_attributes["w"])[mesh.loop_vertex_indices()]
    u_c = loop_uv[corner, 0].mean(axis=1)
    v_c = loop_uv[corner, 1].mean(axis=1) * 2 * math.pi
    w_c = w[corner].mean(axis=1)
    pts = head.spine(u_c) + w_c[:, None] * (head.evaluate(u_c, v_c, 1.0) - head.spine(u_c))
    raw = map_coordinates(ct.data, ct.patient_to_index(pts).T, order=1, mode="nearest")
    expected = np.clip((raw - window[0]) / (window[1] - window[0]), 0, 1)
    x = np.clip(np.round(centre_uv[:, 0] * w_img - 0.5).astype(int), 0, w_img - 1)
    y = np.clip(np.round(centre_uv[:, 1] * h_img - 0.5).astype(int), 0, h_img - 1)
    err = np.abs(pix[y, x] - expected)
    assert np.median(err) < 0.02 and np.percentile(err, 90) < 0.1, (np.median(err), np.percentile(err, 90))
    assert np.ptp(expected) > 0.3  # the faces cross bone, brain and air: a real check


def test_solid_w_attribute_and_ct_colour(ext, phantom, phantom_head):
    from scipy.ndimage import map_coordinates
    coll = ext.scene.objects.study_collection("Phantom")
    ct = phantom.ct
    u_range, v_range, w_range = (0.0, 1.0), (math.pi / 2, 2 * math.pi), (0.0, 1.0)
    mesh = phantom_head.solid(40, 60, 5, u_range, v_range, w_range)
    obj = ext.scene.objects.build_solid(phantom_head, coll, nu=40, nv=60, nw=5, u_range=u_range, v_range=v_range,
                                w_range=w_range, ct=ct)
    me = obj.data
    assert len(me.vertices) == len(mesh.vertices) and len(me.polygons) == mesh.face_count
    w = blender_inspect.mesh_attribute(obj, "w")
    assert me.attributes["w"].domain == "POINT" and me.attributes["w"].data_type == "FLOAT"
    assert w.min() == pytest.approx(0.0, abs=1e-6) and w.max() == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(w, mesh.vertex_attributes["w"], atol=1e-6)
    # ct_intensity: trilinear CT at the vertices' patient positions, windowed to [0, 1]
    attr = me.color_attributes["ct_intensity"]
    assert attr.domain == "POINT" and attr.data_type == "FLOAT_COLOR"
    assert me.color_attributes.active_color.name == "ct_intensity"
    rgba = blender_inspect.mesh_attribute(obj, "ct_intensity")
    np.testing.assert_allclose(rgba[:, 0], rgba[:, 1])
    lo, hi = obj["pdehead_window"]
    raw = map_coordinates(ct.data, ct.patient_to_index(blender_inspect.mesh_world_vertices(obj) / MM).T, order=1,
                          mode="nearest")
    expected = np.clip((raw - lo) / (hi - lo), 0, 1)
    np.testing.assert_allclose(rgba[:, 0], expected, atol=2e-3)
    assert 0.0 <= rgba[:, :3].min() and rgba[:, :3].max() <= 1.0
    assert np.ptp(rgba[:, 0]) > 0.3  # the cut faces reach bone and brain: not one flat colour
    # the material shows the CT texture atlas (the CT sampled finely over every face of the parametric box)
    mat = obj.material_slots[0].material
    tex = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeTexImage")
    base = [lk for lk in mat.node_tree.links if lk.to_socket.name == "Base Color"]
    assert len(base) == 1 and base[0].from_node == tex
    image = tex.image
    assert image is not None and image.packed_file is not None  # survives saving the .blend
    uv_node = next(lk.from_node for lk in mat.node_tree.links if lk.to_node == tex)
    assert uv_node.bl_idname == "ShaderNodeUVMap" and uv_node.uv_map == "CT texture"
    assert "CT texture" in me.uv_layers and "UVMap" in me.uv_layers
    _check_texture_matches_ct(obj, image, mesh, phantom_head, ct, (lo, hi))
    # shells smooth, cut faces (u ends, v cuts) flat: no normals smeared over the 90 degree edges
    smooth = np.empty(len(me.polygons), bool)
    me.polygons.foreach_get("use_smooth", smooth)
    assert smooth.sum() == 39 * 59  # the outer shell w = 1 (the inner one, w = 0, collapses onto the spine)
    # float32 round-off from Blender properties (2 pi -> 6.2831855) is accepted, not a bad range
    f32 = tuple(float(np.float32(x)) for x in (0.0, 2 * math.pi))
    assert f32[1] > 2 * math.pi
    full = ext.scene.objects.build_solid(phantom_head, coll, nu=10, nv=12, nw=3, v_range=f32,
                                 w_range=(0.0, float(np.float32(1.0))), name="float32 ranges")
    assert len(full.data.vertices) == len(phantom_head.solid(10, 12, 3).vertices)
    # a thinner shell (Fig. 14c): w in [0.8, 1], rebuilt in place
    thin = ext.scene.objects.build_solid(phantom_head, coll, nu=40, nv=60, nw=5, v_range=v_range, w_range=(0.8, 1.0),
                                 ct=ct, obj=obj)
    w = blender_inspect.mesh_attribute(thin, "w")
    assert thin == obj and w.min() == pytest.approx(0.8, abs=1e-6) and w.max() == pytest.approx(1.0, abs=1e-6)


def test_solid_texture_is_packed_and_survives_save_and_reopen(ext, phantom, phantom_head, tmp_path):
    import bpy
    coll = ext.scene.objects.study_collection("Phantom")
    obj = ext.scene.objects.build_solid(phantom_head, coll, nu=12, nv=16, nw=3, v_range=(math.pi, 2 * math.pi),
                                ct=phantom.ct, texture_size=32, name="Small solid")
    image = obj.material_slots[0].material.node_tree.nodes["CT texture"].image
    before = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(before)
    assert image.size[0] == 3 * 32 and image.size[1] == 2 * 32 and np.ptp(before[0::4]) > 0.3
    blend = tmp_path / "solid.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    obj = bpy.data.objects["Small solid"]
    image = obj.material_slots[0].material.node_tree.nodes["CT texture"].image
    after = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(after)
    np.testing.assert_allclose(after, before, atol=1.5 / 255)  # packed as 8-bit PNG
    w = blender_inspect.mesh_attribute(obj, "w")
    assert w.min() == pytest.approx(0.0, abs=1e-6) and w.max() == pytest.approx(1.0, abs=1e-6)


def test_live_solid_uses_the_ct_table_and_rewrites_a_same_topology_mesh_in_place(ext, phantom, phantom_head,
                                                                                   monkeypatch):
    """The live path: CT from the (u, v, w) table; a cutaway at the same resolution only moves vertices."""
    from scipy.ndimage import map_coordinates

    from pdehead_addon.pde.solid_ct_table import SolidCTTable
    coll = ext.scene.objects.study_collection("Phantom")
    ct = phantom.ct
    table = SolidCTTable(phantom_head, ct)
    ranges = dict(u_range=(0.0, 1.0), v_range=(math.pi / 2, 2 * math.pi), w_range=(0.0, 1.0))
    obj = ext.scene.objects.build_solid(phantom_head, coll, nu=40, nv=60, nw=5, ct=ct, ct_table=table, **ranges)
    lo, hi = obj["pdehead_window"]
    rgba = blender_inspect.mesh_attribute(obj, "ct_intensity")
    raw = map_coordinates(ct.data, ct.patient_to_index(blender_inspect.mesh_world_vertices(obj) / MM).T, order=1,
                          mode="nearest")
    err = np.abs(rgba[:, 0] - np.clip((raw - lo) / (hi - lo), 0, 1))
    assert np.median(err) < 0.01 and np.percentile(err, 95) < 0.1 and np.ptp(rgba[:, 0]) > 0.3
    image = obj.material_slots[0].material.node_tree.nodes["CT texture"].image
    _check_texture_matches_ct(obj, image, phantom_head.solid(40, 60, 5, **ranges), phantom_head, ct, (lo, hi))

    me = obj.data
    corners_before = blender_inspect.mesh_attribute(obj, ".corner_vert").copy()

    def no_refill(*args, **kwargs):
        raise AssertionError("same topology: the mesh must be updated in place")
    monkeypatch.setattr(ext.scene.objects, "_fill_mesh", no_refill)
    cut = dict(ranges, v_range=(math.pi / 3, 2 * math.pi), w_range=(0.0, 0.8))  # w0 = 0: still on the spine
    again = ext.scene.objects.build_solid(phantom_head, coll, nu=40, nv=60, nw=5, ct=ct, ct_table=table, obj=obj, **cut)
    assert again == obj and again.data == me
    expected = phantom_head.solid(40, 60, 5, **cut)
    np.testing.assert_allclose(blender_inspect.mesh_world_vertices(obj) / MM, expected.vertices, atol=0.05)
    np.testing.assert_array_equal(blender_inspect.mesh_attribute(obj, ".corner_vert"), corners_before)
    w = blender_inspect.mesh_attribute(obj, "w")
    assert w.max() == pytest.approx(0.8, abs=1e-6)
    _check_texture_matches_ct(obj, image, expected, phantom_head, ct, (lo, hi))
    # a live change's quick 128-pixel tiles go into the corner of the larger image, the UVs scaled to it:
    # no Image.scale (it resamples the old pixels, ~9 ms on GE) and the texture still shows the CT
    size = tuple(image.size)
    ext.scene.objects.build_solid(phantom_head, coll, nu=40, nv=60, nw=5, ct=ct, ct_table=table, obj=obj,
                            texture_size=128, **cut)
    assert obj.material_slots[0].material.node_tree.nodes["CT texture"].image == image
    quick_w, quick_h = 3 * 128, 2 * 128                        # six 128-pixel tiles, three a row
    assert tuple(image.size) == size and size[0] * size[1] > quick_w * quick_h, size
    uv = np.empty(len(me.loops) * 2, np.float32).reshape(-1, 2)
    me.uv_layers["CT texture"].data.foreach_get("uv", uv.ravel())
    # only the image's corner is used
    assert uv[:, 0].max() <= quick_w / size[0] + 1e-6 and uv[:, 1].max() <= quick_h / size[1] + 1e-6
    _check_texture_matches_ct(obj, image, expected, phantom_head, ct, (lo, hi))
    # another resolution is another topology: rebuilt (here refused by the patched refill)
    with pytest.raises(AssertionError, match="in place"):
        ext.scene.objects.build_solid(phantom_head, coll, nu=40, nv=60, nw=6, ct=ct, ct_table=table, obj=obj, **cut)


def test_solid_shows_skin_outside_and_the_ct_at_its_own_resolution_on_the_cut_faces(ext, phantom, phantom_head):
    """Issue 21 item 3: the outside (w = 1) is the skin material; on every cut face a texel's world
    footprint (3-D edge length over its length in texels) is at most one CT voxel at the default budget;
    the CT image interpolates linearly. Before: one 128 x 128 tile per face, CT on the skin."""
    import bpy
    coll = ext.scene.objects.study_collection("Phantom")
    ranges = dict(u_range=(0.15, 0.85), v_range=(math.pi / 2, 2 * math.pi), w_range=(0.0, 1.0))
    obj = ext.scene.objects.build_solid(phantom_head, coll, nu=40, nv=60, nw=5, ct=phantom.ct, name="Cut solid",
                                        **ranges)
    me = obj.data
    material = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("material_index", material)
    skin, ct_mat = me.materials[1], me.materials[0]
    assert skin == ext.scene.objects.ensure_skin_material() and ct_mat.get("pdehead_ct_material") == 1
    tex = ct_mat.node_tree.nodes["CT texture"]
    assert tex.interpolation == "Linear"
    mesh = phantom_head.solid(40, 60, 5, **ranges)
    _, family = ext.volume.ct_texture.box_faces(mesh, tuple(ranges.values()))
    np.testing.assert_array_equal(material, (family == 0).astype(int))        # outer shell: skin; cut faces: CT
    width, height = tex.image.size
    uv = np.empty(len(me.loops) * 2, np.float32)
    me.uv_layers["CT texture"].data.foreach_get("uv", uv)
    texel = uv.reshape(-1, 2) * (width, height)
    pos = blender_inspect.mesh_world_vertices(obj) / MM
    corner_vert = blender_inspect.mesh_attribute(obj, ".corner_vert")
    starts, totals = mesh.loop_starts_and_totals()
    nxt = np.arange(len(corner_vert)) + 1
    nxt[starts + totals - 1] = starts
    cut = np.repeat(family >= 2, totals)
    d3 = np.linalg.norm(pos[corner_vert[nxt]] - pos[corner_vert], axis=1)
    dt = np.linalg.norm(texel[nxt] - texel, axis=1)
    ok = cut & (dt > 1e-3)
    footprint = d3[ok] / dt[ok]
    voxel = float(min(phantom.ct.spacing))
    # measured: largest 1.00 voxel (median 0.76; a 220 x 172 atlas); before (one 128-pixel tile a face) 1.73 voxels
    assert footprint.max() <= 1.02 * voxel, footprint.max() / voxel
    assert width * height <= ext.scene.objects.D.CT_TEXTURE_BUDGET.default * 1e6
    again = ext.scene.objects.build_solid(phantom_head, coll, nu=40, nv=60, nw=5, ct=phantom.ct, obj=obj, skin="ct",
                                          **ranges)
    me.polygons.foreach_get("material_index", material)
    assert again == obj and not material.any()                                 # the option: the CT everywhere
    bpy.data.objects.remove(obj)


def test_material_indices_through_the_face_attribute_only_when_they_change(ext):
    """compat.set_material_indices (the attribute, not 7-8 ms of ``polygons.foreach_set``): the slots read
    back through RNA, all-zero needs no attribute, the same index again and back to zero work."""
    import bpy
    me = bpy.data.meshes.new("material index test")
    verts = np.array([[x, y, 0.0] for y in range(4) for x in range(4)], float)
    me.vertices.add(16)
    me.vertices.foreach_set("co", verts.ravel())
    quads = [(y * 4 + x, y * 4 + x + 1, y * 4 + x + 5, y * 4 + x + 4) for y in range(3) for x in range(3)]
    me.loops.add(36)
    me.loops.foreach_set("vertex_index", np.array(quads, np.int32).ravel())
    me.polygons.add(9)
    me.polygons.foreach_set("loop_start", np.arange(0, 36, 4, dtype=np.int32))
    me.update(calc_edges=True)

    def slots():
        out = np.empty(9, np.int32)
        me.polygons.foreach_get("material_index", out)
        return out.tolist()
    ext.compat.set_material_indices(me, np.zeros(9, int))
    assert me.attributes.get("material_index") is None and slots() == [0] * 9
    index = np.array([1, 0, 1, 0, 1, 0, 1, 0, 1])
    ext.compat.set_material_indices(me, index)
    assert slots() == index.tolist()
    ext.compat.set_material_indices(me, index)                 # unchanged: read, compared, not rewritten
    assert slots() == index.tolist()
    ext.compat.set_material_indices(me, np.zeros(9, int))
    assert slots() == [0] * 9
    bpy.data.meshes.remove(me)
