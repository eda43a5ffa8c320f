"""The surface's CT detail layer in Blender: a float image in the surface's UVs, applied as real
displacement (a subdivision, then a Displace modifier reading the image through the UVs along the normals,
its strength driven by the study's ``detail_strength``), packed into the .blend (a 16-bit PNG), and turned
off when a PDE change moves the surface (out of date) or at strength 0. Off by default: Run Pipeline builds
none, the toggle never builds, *Build CT Detail* (``pdehead.build_detail_map``) does. A file saved with the
earlier bump reopens with the displacement.
"""
from __future__ import annotations

import sys

import numpy as np
import pytest


def _modules(pdehead_ext):
    name = pdehead_ext.__name__
    return (sys.modules[f"{name}.operators.scene.detail_map"], sys.modules[f"{name}.operators.state"],
            sys.modules[f"{name}.operators.study.entity"].Study)


def _open_study(state, path):
    import bpy
    bpy.ops.wm.open_mainfile(filepath=str(path))
    state.drop_cache()
    return [c for c in bpy.data.collections if c.pdehead.is_study][0]


@pytest.fixture(scope="module")
def detail_blend(pdehead_ext, phantom_blend, tmp_path_factory):
    """The phantom's saved pipeline (the defaults: no detail map) with the map turned on and built by the
    operator, as a script would, saved."""
    import bpy
    detail, state, _study = _modules(pdehead_ext)
    coll = _open_study(state, phantom_blend)
    coll.pdehead.use_detail_map = True
    assert bpy.ops.pdehead.build_detail_map(study=coll.name) == {'FINISHED'}
    path = tmp_path_factory.mktemp("detail") / "phantom_detail.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    return path


@pytest.fixture()
def reopened(pdehead_ext, detail_blend):
    """The phantom's saved pipeline with its detail map, reopened: (detail_map module, state, Study, study
    collection)."""
    detail, state, study = _modules(pdehead_ext)
    return detail, state, study, _open_study(state, detail_blend)


def test_run_pipeline_at_the_defaults_builds_no_map_and_the_operator_builds_the_branchs(ext, pdehead_ext,
                                                                                        phantom_blend):
    """Off by default: Run Pipeline (the phantom's, at the defaults) leaves no detail image or material;
    turning it on does not build one (no seconds in an update callback); the operator does, and its values
    are those of sampling every 0.25 mm along the normals (the branch's way, ``coarse_steps=1``)."""
    import bpy
    detail, state, study_cls = _modules(pdehead_ext)
    E = ext.engine
    coll = _open_study(state, phantom_blend)
    s = coll.pdehead
    obj = s.surface_object
    assert s.use_detail_map is False and E.defaults.USE_DETAIL_MAP.default is False
    assert detail.detail_image(obj) is None and detail.detail_material(obj) is None
    assert not [im for im in bpy.data.images if im.get(detail.DETAIL_IMAGE_KEY) == 1]
    s.use_detail_map = True                                      # the toggle alone: nothing built
    assert detail.detail_image(obj) is None and s.last_error == ""
    assert not study_cls.of(coll).detail_map_current()
    assert bpy.ops.pdehead.build_detail_map(study=coll.name) == {'FINISHED'}
    image = detail.detail_image(obj)
    assert image is not None and study_cls.of(coll).detail_map_current()
    assert not _displacement_on(detail, obj)                     # strength 0 (the default): the PDE surface
    s.detail_strength = 1.0
    assert _displacement_on(detail, obj)
    study = study_cls.of(coll)
    branch = E.ct_detail_map(study.solve(), study.cache.seg.mask, study.cache.seg.ct,
                             resolution=s.detail_resolution, coarse_steps=1).height
    got = detail.image_height_mm(image)
    assert got.shape == branch.shape and np.abs(branch).max() > 0.5
    # the 16-bit PNG holds 0.5 + mm / 6: a step of 1e-4 mm
    assert np.abs(got - branch).max() < 1e-3, np.abs(got - branch).max()


def _displacement(detail, obj):
    """The CT detail's subdivision and Displace modifiers, or an assertion naming what is missing."""
    sub, disp = detail.detail_modifiers(obj)
    assert sub is not None and disp is not None, [m.name for m in obj.modifiers]
    return sub, disp


def _displacement_on(detail, obj) -> bool:
    sub, disp = _displacement(detail, obj)
    assert sub.show_viewport == disp.show_viewport == sub.show_render == disp.show_render
    return disp.show_viewport


def _evaluated_vertices(obj) -> np.ndarray:
    import bpy
    dg = bpy.context.evaluated_depsgraph_get()
    dg.update()
    me = obj.evaluated_get(dg).to_mesh()
    co = np.empty(len(me.vertices) * 3)
    me.vertices.foreach_get("co", co)
    obj.evaluated_get(dg).to_mesh_clear()
    return co.reshape(-1, 3)


def _pixels(image) -> np.ndarray:
    w, h = image.size
    px = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(px)
    return px.reshape(h, w, 4)


def test_the_pipeline_gives_the_surface_a_packed_displacement_map(ext, reopened):
    detail, _state, _study, coll = reopened
    s = coll.pdehead
    obj = s.surface_object
    D = ext.engine.defaults
    sub, disp = _displacement(detail, obj)
    assert list(obj.modifiers).index(sub) < list(obj.modifiers).index(disp)       # subdivided, then displaced
    assert sub.subdivision_type == "CATMULL_CLARK" and sub.levels == sub.render_levels == detail.SUBDIV_LEVELS
    assert disp.texture_coords == "UV" and disp.uv_layer == "UVMap" and disp.direction == "NORMAL"
    assert "UVMap" in obj.data.uv_layers
    rng = D.DETAIL_MAX_OFFSET.default
    # the image holds 0.5 + mm / (2 range): midlevel 0.5, and 2 range mm in metres (the object's space)
    assert disp.mid_level == 0.5
    assert D.DETAIL_STRENGTH.default == 0.0 and s.detail_strength == 0.0 and not _displacement_on(detail, obj)
    assert disp.strength == pytest.approx(0.0)
    tex = disp.texture
    assert tex.type == "IMAGE" and tex.extension == "EXTEND" and tex.use_interpolation
    assert tex.image.colorspace_settings.name == "Non-Color"
    # no bump: the material's displacement is not wired
    assert not any(m is not None and m.node_tree is not None and any(
        out.inputs["Displacement"].links for out in m.node_tree.nodes if out.type == "OUTPUT_MATERIAL")
        for m in obj.data.materials)
    image = tex.image
    res = D.DETAIL_RESOLUTION.default
    assert tuple(image.size) == (res, res) and image.is_float    # 16 bits read back as float
    assert image.packed_file is not None and bytes(image.packed_file.data[:8]) == b"\x89PNG\r\n\x1a\n"
    assert image.packed_file.size < res * res                    # compressed: under a byte a texel
    px = _pixels(image)
    h = detail.image_height_mm(image)
    assert np.isfinite(h).all() and np.abs(h).max() <= rng + 1e-3
    assert (np.abs(h) > 0.05).mean() > 0.05                      # relief, not an empty map
    assert np.array_equal(px[..., 0], px[..., 1])
    # real geometry: at strength 1 the subdivided surface moves along its normals by the map (mm), at 0.5
    # by half of it, at 0 not at all
    heights = {}
    for strength in (1.0, 0.5):
        s.detail_strength = strength
        assert _displacement_on(detail, obj)
        moved = _evaluated_vertices(obj)
        disp.show_viewport = False
        sub.show_viewport = True
        smooth = _evaluated_vertices(obj)
        detail.set_detail_shading(obj, s.detail_strength, True)
        assert moved.shape == smooth.shape and len(moved) > 8 * len(obj.data.vertices)
        heights[strength] = np.linalg.norm(moved - smooth, axis=1) * 1000.0
    assert 0.5 < heights[1.0].max() <= rng + 0.01 and np.percentile(heights[1.0], 90) > 0.05
    np.testing.assert_allclose(heights[0.5], 0.5 * heights[1.0], atol=1e-3)
    s.detail_strength = 0.0
    assert not _displacement_on(detail, obj)


def test_the_map_survives_save_and_reopen(ext, reopened, tmp_path):
    import bpy
    detail, _state, _study, coll = reopened
    obj = coll.pdehead.surface_object
    before = detail.image_height_mm(detail.detail_image(obj)).copy()
    path = tmp_path / "again.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=str(path))
    coll = [c for c in bpy.data.collections if c.pdehead.is_study][0]
    assert coll.pdehead.use_detail_map is True and not coll.pdehead.detail_stale   # the on state kept too
    obj = coll.pdehead.surface_object
    image = detail.detail_image(obj)
    assert image is not None and image.packed_file is not None
    after = detail.image_height_mm(image)
    assert after.shape == before.shape
    np.testing.assert_array_equal(after, before)
    _sub, disp = _displacement(detail, obj)
    assert disp.texture.image == image


def test_toggle_and_strength_drive_the_displacement(ext, reopened):
    import bpy
    detail, _state, _study, coll = reopened
    s = coll.pdehead
    obj = s.surface_object
    s.detail_strength = 1.0
    s.use_detail_map = False
    assert not _displacement_on(detail, obj)
    s.use_detail_map = True
    assert _displacement_on(detail, obj)
    s.detail_strength = 2.5
    rng = ext.engine.defaults.DETAIL_MAX_OFFSET.default
    assert _displacement(detail, obj)[1].strength == pytest.approx(2.5 * 2 * rng * 0.001)
    assert s.last_error == ""
    # animatable: keyframes on the settings drive the modifier's strength frame by frame
    s.detail_strength = 0.0
    s.id_data.keyframe_insert("pdehead.detail_strength", frame=1)
    s.detail_strength = 1.0
    s.id_data.keyframe_insert("pdehead.detail_strength", frame=11)
    scene = bpy.context.scene
    got = {}
    for frame in (1, 6, 11):
        scene.frame_set(frame)
        bpy.context.evaluated_depsgraph_get().update()
        ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).modifiers[detail.DISPLACE_MOD]
        got[frame] = ev.strength
    k = 2 * rng * 0.001
    assert got[1] == pytest.approx(0.0, abs=1e-9) and got[11] == pytest.approx(k) and 0.2 * k < got[6] < 0.8 * k
    assert _displacement_on(detail, obj)                          # animated: on even where it is 0


def test_a_pde_change_marks_the_map_out_of_date_and_the_button_rebuilds_it(ext, reopened):
    import bpy
    detail, _state, _study, coll = reopened
    s = coll.pdehead
    obj = s.surface_object
    old = detail.image_height_mm(detail.detail_image(obj)).copy()
    s.modes = 6                                                  # a simpler head: the surface moves
    assert s.detail_stale and s.last_error == ""
    assert not _displacement_on(detail, obj)                     # not silently stale: off
    s.nu = s.nu + 4                                              # nu / nv do not touch the map
    assert s.detail_stale
    assert bpy.ops.pdehead.build_detail_map(study=coll.name) == {'FINISHED'}
    assert not s.detail_stale
    s.detail_strength = 1.0
    assert _displacement_on(detail, obj)
    new = detail.image_height_mm(detail.detail_image(obj))
    assert np.abs(new - old).max() > 0.5                        # the map follows the new surface


def test_the_map_at_each_vertex_uv_is_the_skin_offset_there(ext, reopened):
    """Render-free: the image sampled (bilinear, as the shader does) at every tube vertex's loop UVs gives
    the offset to the smoothed mask's 0.5 level measured directly at the vertex along its normal."""
    detail, _state, study_cls, coll = reopened
    E = ext.engine
    dm = sys.modules[E.__name__ + ".pde.detail_map"]
    study = study_cls.of(coll)
    study.segment()
    seg = study.cache.seg
    obj = coll.pdehead.surface_object
    me = obj.data
    n = len(me.vertices)
    co = np.empty(n * 3)
    me.vertices.foreach_get("co", co)
    nrm = np.empty(n * 3)
    me.vertices.foreach_get("normal", nrm)
    origin = np.asarray(obj.matrix_world.translation)
    pts = (co.reshape(-1, 3) + origin) * 1000.0                  # world metres -> LPS mm
    nrm = nrm.reshape(-1, 3)
    smoothed = dm.smooth_mask(seg.mask, seg.ct.spacing, E.defaults.DETAIL_SIGMA.default)
    to_index = np.linalg.inv(seg.ct.affine)[[2, 1, 0, 3]]
    truth, found = dm.offset_to_level(smoothed, to_index, pts, nrm, E.defaults.DETAIL_MAX_OFFSET.default, 0.25)
    truth = truth * np.clip((dm.UP_FADE[1] - nrm[:, 2]) / (dm.UP_FADE[1] - dm.UP_FADE[0]), 0.0, 1.0)  # the crown fades
    loops = np.empty(len(me.loops), np.int64)
    me.loops.foreach_get("vertex_index", loops)
    uv = np.empty(len(me.loops) * 2)
    me.uv_layers["UVMap"].data.foreach_get("uv", uv)
    uv = uv.reshape(-1, 2)
    h = detail.image_height_mm(detail.detail_image(obj))
    res = h.shape[0]
    x, y = uv[:, 0] * res - 0.5, uv[:, 1] * res - 0.5           # row 0 at v = 0 (Blender's pixel order)
    x0, y0 = np.floor(x).astype(int).clip(0, res - 2), np.floor(y).astype(int).clip(0, res - 2)
    fx, fy = (x - x0).clip(0, 1), (y - y0).clip(0, 1)
    sampled = (h[y0, x0] * (1 - fx) * (1 - fy) + h[y0, x0 + 1] * fx * (1 - fy)
               + h[y0 + 1, x0] * (1 - fx) * fy + h[y0 + 1, x0 + 1] * fx * fy)
    u_attr = np.empty(n)
    me.attributes["u"].data.foreach_get("value", u_attr)
    keep = found[loops] & (u_attr[loops] > 0.02) & (u_attr[loops] < 0.9)   # the tube; not the cap
    assert keep.sum() > 500
    err = np.abs(sampled[keep] - truth[loops][keep])
    assert np.median(err) < 0.1 and np.percentile(err, 90) < 0.4, (np.median(err), np.percentile(err, 90))
    assert np.abs(truth[loops][keep]).max() > 0.5                # the phantom's face has relief to find


def test_a_cancelled_run_puts_the_old_map_back(ext, reopened):
    """Run Pipeline on the study rebuilds the map in the surface step; cancelled in a later step, the
    study's surface and its map are those of before (the image re-packed in place, not lost)."""
    import bpy

    from test_live import _cancel_in, _progress
    detail, state, _study, coll = reopened
    s = coll.pdehead
    obj = s.surface_object
    before = detail.image_height_mm(detail.detail_image(obj)).copy()
    hook, seen = _cancel_in(state, "volume")
    _progress(state).set_hook(hook)
    try:
        result = bpy.ops.pdehead.run_pipeline(source='ACTIVE', patches=s.patches - 1, nu=s.nu, nv=s.nv,
                                              nw=s.nw, build_volume=True)
    finally:
        _progress(state).set_hook(None)
    assert result == {"CANCELLED"} and "solid" in {step for step, _ in seen}   # after the surface step
    image = detail.detail_image(obj)
    assert image is not None and image.name == detail.image_name(obj)
    np.testing.assert_array_equal(detail.image_height_mm(image), before)
    s.detail_strength = 1.0
    assert _displacement_on(detail, obj)


def test_a_file_saved_with_the_bump_reopens_with_the_displacement(ext, reopened, tmp_path):
    """The earlier version's wiring (the map in the skin material's Displacement, no modifiers), saved and
    reopened: the bump is unplugged and the displacement is there."""
    import bpy
    detail, state, _study, coll = reopened
    s = coll.pdehead
    s.detail_strength = 1.0
    obj = s.surface_object
    for mod in list(obj.modifiers):
        if mod.name in (detail.SUBDIV_MOD, detail.DISPLACE_MOD):
            obj.modifiers.remove(mod)
    mat = detail.ensure_detail_material(obj, detail.detail_image(obj))
    out = detail._material_output(mat.node_tree.nodes)
    mat.node_tree.links.new(mat.node_tree.nodes[detail.BUMP_NODE].outputs["Displacement"], out.inputs["Displacement"])
    path = tmp_path / "bump.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    coll = _open_study(state, path)
    obj = coll.pdehead.surface_object
    assert _displacement_on(detail, obj)
    mat = detail.detail_material(obj)
    assert mat is not None and not detail._material_output(mat.node_tree.nodes).inputs["Displacement"].links


def test_the_panel_offers_build_ct_detail_when_on_without_a_current_map(ext, pdehead_ext, phantom_blend):
    """The Surface panel: off, no build button; on without a map, a Build CT Detail box; once built, only
    the rebuild button; after a shape change, the box again (drawn into a recording layout)."""
    from types import SimpleNamespace

    import bpy

    from panel_recorder import RecordingLayout
    detail, state, study_cls = _modules(pdehead_ext)
    panel = sys.modules[f"{pdehead_ext.__name__}.operators.ui.panel"]
    coll = _open_study(state, phantom_blend)
    bpy.context.scene.pdehead.active_study = coll
    s = coll.pdehead

    def drawn():
        log = []
        stand_in = SimpleNamespace(layout=RecordingLayout(log), study=panel.PDEHEAD_PT_surface.study)
        panel.PDEHEAD_PT_surface.draw(stand_in, bpy.context)
        ops = [x[1] for x in log if x[0] == "operator"]
        labels = " ".join(str(x[1]) for x in log if x[0] == "label")
        return ops.count("pdehead.build_detail_map"), labels

    count, labels = drawn()
    assert count == 0 and "CT detail" not in labels                # off (the default): nothing to build
    s.use_detail_map = True
    count, labels = drawn()
    assert count == 1 and "No CT detail map yet" in labels
    assert bpy.ops.pdehead.build_detail_map(study=coll.name) == {'FINISHED'}
    count, labels = drawn()
    assert count == 1 and "CT detail" not in labels
    s.modes = 6                                                  # the surface moves: out of date
    count, labels = drawn()
    assert count == 1 and "rebuild the CT detail" in labels


def test_the_print_skin_carries_the_detail_at_the_strength_set(ext, reopened):
    """Export for Printing's skin (:func:`detail_map.print_skin`): the PDE surface at print resolution
    (chord error within 0.05 mm over the face, at most 2 M triangles, watertight) at strength 0; at strength
    1 the same mesh moved along its normals by the map; off or out of date, the PDE surface again."""
    detail, _state, study_cls, coll = reopened
    E = ext.engine
    DDX = __import__(E.__name__ + ".pde.detail_displace", fromlist=["x"])
    s = coll.pdehead
    study = study_cls.of(coll)
    s.detail_strength = 0.0
    flat = detail.print_skin(study)
    rows, nv = E.print_resolution(study.head)
    nu = len(rows)
    assert flat.is_watertight() and 2 * len(flat.quads) + len(flat.triangles) <= 2_000_000
    window = DDX.surface_window(study.head)
    with DDX.print_columns(study.head, window):          # the print's columns: denser over the face
        np.testing.assert_array_equal(flat.vertices, study.head.surface(nu, nv, caps=True, rows=rows).vertices)
        assert DDX.chord_error(study.head, nu, nv, window, rows=rows)["max"] <= 0.05
    s.detail_strength = 1.0
    moved = detail.print_skin(study)
    assert moved.is_watertight() and np.array_equal(moved.quads, flat.quads)
    shift = ((moved.vertices - flat.vertices) * DDX.vertex_normals(flat)).sum(axis=1)
    rng = E.defaults.DETAIL_MAX_OFFSET.default
    assert np.abs(shift).max() <= rng + 1e-3 and (np.abs(shift) > 0.5).sum() > 100
    height = detail.image_height_mm(detail.detail_image(s.surface_object))
    np.testing.assert_allclose(shift, DDX.vertex_heights(flat, height, DDX.uv_island_layout(study.head)), atol=1e-6)
    s.use_detail_map = False
    np.testing.assert_array_equal(detail.print_skin(study).vertices, flat.vertices)
    s.use_detail_map = True


@pytest.mark.engine_cli
def test_cli_detail_flag(tmp_path):
    """--detail STRENGTH: out of range is a usage error naming the flag; in range the exported skin is at
    print resolution, closed, and the summary's timings hold the detail step."""
    import json

    from file_readers import read_stl
    from test_cli import run_cli
    bad = run_cli("--phantom", "--no-volume", "--detail", -1, tmp_path=tmp_path)
    assert bad.returncode == 2 and "--detail" in bad.stderr
    out, summary = tmp_path / "print", tmp_path / "summary.json"
    result = run_cli("--phantom", "--no-volume", "--patches", 6, "--skull", "--detail", 1, "--export", out,
                     "--summary-json", summary, tmp_path=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    skin = read_stl(out / "skin.stl")
    assert skin.is_watertight() and 300_000 < len(skin.triangles) <= 2_000_000
    assert "detail_map" in json.dumps(json.loads(summary.read_text()))
