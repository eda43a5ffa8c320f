"""The interactive cutter: moving its box (as the user does in the viewport) cuts the solid where it is."""
from __future__ import annotations

import math

import numpy as np
import pytest

import blender_inspect  # tests/blender/blender_inspect.py


def _inside(cutter, points_world) -> np.ndarray:
    m = np.linalg.inv(np.array(cutter.matrix_world))
    local = points_world @ m[:3, :3].T + m[:3, 3]
    return np.all(np.abs(local) <= cutter.empty_display_size, axis=1)


def _outer_shell(ext, solid):
    w = blender_inspect.mesh_attribute(solid, "w")
    return blender_inspect.mesh_world_vertices(solid)[w >= w.max() - 1e-6]


def test_moving_the_cutter_cuts_the_solid_where_it_is(ext, monkeypatch):
    import bpy
    from mathutils import Matrix
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=6, nu=40, nv=60, nw=4,
                                        build_volume=False) == {'FINISHED'}
    coll = bpy.context.scene.pdehead.active_study
    s = coll.pdehead
    lo, hi = ext.scene.render.world_bounds([s.surface_object])
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)

    assert bpy.ops.pdehead.add_cutter() == {'FINISHED'}
    cutter = ext.scene.cutter.cutter_of(coll)
    assert cutter is not None and cutter.type == 'EMPTY' and s.use_cutter
    # the default box opens the front-left quarter: a wedge in v through the whole height
    assert tuple(s.u_range) == pytest.approx((0.0, 1.0))
    span = s.v_range[1] - s.v_range[0]
    assert 0.4 * 2 * math.pi < span < 0.9 * 2 * math.pi
    shell = _outer_shell(ext, s.solid_object)
    assert _inside(cutter, shell).mean() < 0.02  # what the box covers is gone
    assert (shell[:, 0] > centre[0] + 0.3 * half[0]).any()  # the rest of the head's left side stays

    # the user drags the box over the crown: the top comes off (a slab in u), v is whole again
    top = Matrix.Translation((centre[0], centre[1], hi[2])) @ Matrix.Diagonal((1.5 * half[0], 1.5 * half[1],
                                                                             0.6 * half[2], 1.0))
    cutter.matrix_world = top
    bpy.context.view_layer.update()  # what the viewport does after a move: the depsgraph handler runs
    assert s.last_error == ""
    assert tuple(s.v_range) == pytest.approx((0.0, 2 * math.pi), abs=1e-6) and s.u_range[1] - s.u_range[0] < 0.9
    verts = blender_inspect.mesh_world_vertices(s.solid_object)
    bottom_of_box = hi[2] - 0.6 * half[2]
    assert verts[:, 2].max() <= bottom_of_box + 0.005  # within one sample row (~3 mm) of the box
    assert verts[:, 2].max() > bottom_of_box - 0.02

    # an update that does not move the cutter rebuilds nothing
    calls = []
    monkeypatch.setattr(ext.study.entity.Study, "solid", lambda study, live=False: calls.append(study.name))
    s.surface_object.location.x += 0.0
    bpy.context.view_layer.update()
    assert calls == []
    monkeypatch.undo()

    # away from the head: the whole solid again
    cutter.matrix_world = Matrix.Translation((centre[0] + 1.0, centre[1], centre[2])) @ Matrix.Scale(0.05, 4)
    bpy.context.view_layer.update()
    assert tuple(s.u_range) == pytest.approx((0.0, 1.0)) and tuple(s.v_range) == pytest.approx((0.0, 2 * math.pi))
    head = ext.study.entity.Study.of(coll).head
    assert len(s.solid_object.data.vertices) == len(head.solid(40, 60, 4).vertices)

    # switched off: moving it changes nothing
    s.use_cutter = False
    cutter.matrix_world = top
    bpy.context.view_layer.update()
    assert tuple(s.u_range) == pytest.approx((0.0, 1.0))


def test_cutter_ranges_wedge_slab_and_none(ext, phantom_head):
    """The mapping itself, on the engine head (LPS mm): a side box gives a wedge, a crown box a slab."""
    pts = phantom_head.surface(16, 32).vertices
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)

    def inverse(box_centre, box_half):
        m = np.eye(4)
        m[:3, :3] = np.diag(1.0 / np.asarray(box_half))
        m[:3, 3] = -np.asarray(box_centre) / np.asarray(box_half)
        return m
    u, v, kept, kind = ext.scene.cutter.cutter_ranges(phantom_head, inverse(centre + [half[0], 0, 0],
                                                                          [0.5 * half[0], 2 * half[1], 2 * half[2]]),
                                                 1.0)
    assert kind == "wedge" and u == (0.0, 1.0) and 0.5 < kept < 0.95
    u, v, kept, kind = ext.scene.cutter.cutter_ranges(phantom_head, inverse(centre + [0, 0, half[2]],
                                                                          [2 * half[0], 2 * half[1], 0.3 * half[2]]),
                                                 1.0)
    assert kind == "slab" and v == (0.0, 2 * math.pi) and 0.5 < kept < 0.95
    u, v, kept, kind = ext.scene.cutter.cutter_ranges(phantom_head, inverse(centre + [0, 0, 1e4], half), 1.0)
    assert kind == "none" and kept == 1.0
    with pytest.raises(Exception, match="whole head"):
        ext.scene.cutter.cutter_ranges(phantom_head, inverse(centre, 3 * half), 1.0)
