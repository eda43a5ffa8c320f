"""Live changes in Blender with a UI: the geometry at once, the solid's CT colours right after.

A PDE change (smoothing, modes, ...) makes a new PDE solution whose CT table (the CT tabulated in the
solid's (u, v, w), ~0.5 s on CThead) does not exist yet. With a UI the update callback rebuilds the
surface and the solid's geometry at once, colours the solid from the previous solution's table and
leaves the exact colours to a timer (``Study.DEFER_CT_COLOURS``; background scripts get them at once).
"""
from __future__ import annotations

import sys

import numpy as np
import pytest

import blender_inspect  # tests/blender/blender_inspect.py


@pytest.fixture()
def live(pdehead_ext, phantom_blend):
    import bpy
    name = pdehead_ext.__name__
    study = sys.modules[f"{name}.operators.study.entity"].Study
    state = sys.modules[f"{name}.operators.state"]
    objects = sys.modules[f"{name}.operators.scene.objects"]
    bpy.ops.wm.open_mainfile(filepath=str(phantom_blend))
    state.drop_cache()
    coll = [c for c in bpy.data.collections if c.pdehead.is_study][0]
    study.DEFER_CT_COLOURS = True
    try:
        yield study, state, objects, coll
    finally:
        study.DEFER_CT_COLOURS = None
        state.REGISTRY.colours_pending.clear()


def _colours(objects, obj):
    return blender_inspect.mesh_attribute(obj, objects.CT_COLOUR_ATTRIBUTE)[:, 0].copy()


def test_a_pde_change_moves_the_geometry_at_once_and_the_colours_follow(live, tmp_path):
    import bpy
    study, state, objects, coll = live
    s = coll.pdehead
    # the reopened file carries the solid's CT table: a cutaway needs no CT
    s.v_range = (1.5, 6.2)
    assert s.last_error == "" and state.cache_for(s.study_id).ct is None
    entity = study.of(coll)
    assert not entity.colours_pending()
    before = blender_inspect.mesh_world_vertices(s.solid_object)

    s.modes = 16  # a new PDE solution: geometry now, colours from the previous table
    assert s.last_error == "" and entity.colours_pending()
    moved = blender_inspect.mesh_world_vertices(s.solid_object)
    assert moved.shape == before.shape and np.abs(moved - before).max() > 1e-4
    # the solid's geometry is the new solution's (world = patient mm x 0.001)
    snap = objects._snap_range
    mesh = entity.head.solid(s.nu, s.nv, s.nw, snap(s.u_range, 1.0), snap(s.v_range, 2 * np.pi),
                             snap(s.w_range, 1.0))
    np.testing.assert_allclose(moved, mesh.vertices * 0.001, atol=1e-6)
    approx = _colours(objects, s.solid_object)

    assert study.flush_colour_refresh() == 1   # what the timer does right after
    assert not entity.colours_pending() and s.last_error == ""
    cache = state.cache_for(s.study_id)
    assert cache.ct_table[0] == entity.table_key() and cache.ct is not None
    np.testing.assert_array_equal(blender_inspect.mesh_world_vertices(s.solid_object), moved)
    exact = _colours(objects, s.solid_object)
    # the previous solution's colours were nearly right (a few % of the grey range where the shape moved),
    # the refresh makes them exact
    assert 0 < np.abs(approx - exact).mean() < 0.05 and exact.std() > 0.05
    cache.ct_table = None
    study.DEFER_CT_COLOURS = False
    entity.solid()                               # colours made at once (background default)
    np.testing.assert_allclose(_colours(objects, s.solid_object), exact, atol=1e-6)

    # a save never keeps approximate colours: save_pre refreshes them and stores the new table
    study.DEFER_CT_COLOURS = True
    s.modes = 6
    assert entity.colours_pending()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "live.blend"))
    assert not entity.colours_pending()
    assert entity.stored_ct_table_key() == entity.table_key()


def test_the_table_in_the_file_serves_a_pde_change_without_the_ct(live):
    """No CT to re-read: the geometry follows, the colours come from the stored table and the sidebar says so."""
    study, state, objects, coll = live
    s = coll.pdehead
    study.DEFER_CT_COLOURS = False
    s.source_kind = "NONE"                      # as if the CT had not travelled with the file
    s.nw = 5
    assert s.last_error == "" and state.cache_for(s.study_id).ct is None
    before = blender_inspect.mesh_world_vertices(s.solid_object)
    s.modes = 5
    assert "previous PDE solution" in s.last_error and "no source to reload" in s.last_error
    assert np.abs(blender_inspect.mesh_world_vertices(s.solid_object) - before).max() > 1e-4
    assert _colours(objects, s.solid_object).std() > 0.05
    s.nu = 24                                   # surface and solid stay consistent
    assert list(s.surface_object["pdehead_resolution"])[0] == 24 == list(s.solid_object["pdehead_resolution"])[0]


# ------------------------------------------------------------------------------------------
# Progress and cancel of a pipeline run (Esc in Blender, Ctrl-C on the CLI raise Cancelled in the hook)


def _cancel_in(module, step_name: str, after_calls: int = 2):
    seen = []

    def hook(step, fraction, message):
        seen.append((step, fraction))
        if step == step_name and sum(1 for s, _ in seen if s == step_name) >= after_calls:
            raise study_cancelled(module)()
    return hook, seen


def _progress(module):
    """The extension's operators.study.progress (the runners' progress hook); ``module``: one of its
    operators modules."""
    return sys.modules[module.__name__.rpartition(".operators.")[0] + ".operators.study.progress"]


def study_cancelled(module):
    """The extension's Cancelled class (the installed package, not the repository's engine)."""
    return sys.modules[module.__name__.rsplit(".operators", 1)[0] + ".pdehead_addon"].Cancelled


def _datablocks(bpy) -> dict:
    kinds = ("objects", "collections", "meshes", "curves", "volumes", "materials", "images", "node_groups")
    return {k: sorted(x.name for x in getattr(bpy.data, k)) for k in kinds}


def test_a_new_study_cancelled_mid_step_leaves_nothing(pdehead_ext):
    import bpy
    state = sys.modules[f"{pdehead_ext.__name__}.operators.state"]
    before = _datablocks(bpy)
    hook, seen = _cancel_in(state, "boundaries")
    _progress(state).set_hook(hook)
    try:
        result = bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=6, nu=32, nv=48, nw=4, build_volume=False)
    finally:
        _progress(state).set_hook(None)
    assert result == {'CANCELLED'}
    steps = [s for s, _ in seen]
    assert "segment" in steps and steps[-1] == "boundaries"   # it ran, reported, and stopped in the middle
    assert _datablocks(bpy) == before


def test_an_existing_study_cancelled_mid_step_is_as_it_was(live):
    import bpy
    study, state, objects, coll = live
    study.DEFER_CT_COLOURS = None
    s = coll.pdehead
    surface = blender_inspect.mesh_world_vertices(s.surface_object).copy()
    solid = blender_inspect.mesh_world_vertices(s.solid_object).copy()
    curves_before = coll[state.BOUNDARY_KEY]
    patches, nu = s.patches, s.nu
    names = _datablocks(bpy)
    for step in ("boundaries", "volume"):   # before the meshes were rebuilt, and after
        hook, seen = _cancel_in(state, step)
        _progress(state).set_hook(hook)
        try:
            result = bpy.ops.pdehead.run_pipeline(source='ACTIVE', patches=patches - 1, nu=nu + 8, nv=s.nv,
                                                  nw=s.nw, build_volume=True)
        finally:
            _progress(state).set_hook(None)
        assert result == {'CANCELLED'} and seen[-1][0] == step
        assert (s.patches, s.nu) == (patches, nu)
        assert coll[state.BOUNDARY_KEY] == curves_before
        # rebuilt from the study's stored curves (the reopened file's head: a few micrometres from the saved mesh;
        # the surface's rows and columns follow its normal's turning, which the curves' 0.01 mm rounding moves
        # by up to ~0.2 mm along the surface)
        assert blender_inspect.mesh_world_vertices(s.surface_object).shape == surface.shape
        np.testing.assert_allclose(blender_inspect.mesh_world_vertices(s.surface_object), surface, atol=3e-4)
        np.testing.assert_allclose(blender_inspect.mesh_world_vertices(s.solid_object), solid, atol=2e-5)
        assert _datablocks(bpy) == names
