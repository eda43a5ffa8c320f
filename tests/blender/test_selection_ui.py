"""Automatic slice selection and the tolerance in Blender (issue 14): operator, panel, reopen."""
from __future__ import annotations

import base64
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from panel_recorder import RecordingLayout
from test_operators import open_blend


def _stored(ext, coll):
    return ext.engine.loads_boundaries(base64.b64decode(coll[ext.state.BOUNDARY_KEY]))


def _panel_labels(ext, coll) -> str:
    import bpy
    bpy.context.scene.pdehead.active_study = coll
    panel = sys.modules[ext.ui.ops.__name__.rpartition(".")[0] + ".panel"]
    log = []
    panel.PDEHEAD_PT_boundaries.draw(SimpleNamespace(layout=RecordingLayout(log),
                                                     study=panel.PDEHEAD_PT_boundaries.study), bpy.context)
    return log


def test_auto_selection_and_tolerance_from_the_panel(ext, phantom_blend, tmp_path):
    import bpy
    coll = open_blend(phantom_blend)
    s = coll.pdehead
    bpy.context.scene.pdehead.active_study = coll

    # t = 6 by the automatic choice: 19 curves, the achieved distance from every outline shown
    assert bpy.ops.pdehead.extract_boundaries(patches=6, selection='auto') == {'FINISHED'}
    bset = _stored(ext, coll)
    assert bset.meta["selection"] == "auto" and s.curve_count == 19 == len(s.curves_object.data.splines)
    assert s.outline_candidates == bset.meta["selection_candidates"] > 19
    assert s.outline_mean_mm == pytest.approx(bset.meta["selection_mean_mm"], rel=1e-6) and s.outline_mean_mm > 0
    assert s.outline_max_mm >= s.outline_mean_mm
    auto_mean = s.outline_mean_mm
    log = _panel_labels(ext, coll)
    labels = " ".join(str(x[1]) for x in log if x[0] == "label")
    assert f"mean {auto_mean:.2f} mm" in labels and "19 curves stored" in labels
    assert "patches" in {x[1] for x in log if x[0] == "prop"}

    # a tolerance instead of t: the fewest curves within it, any count; the panel hides t
    s.use_tolerance, s.tolerance_mm, s.max_tolerance_mm = True, 0.12, 0.0
    assert bpy.ops.pdehead.extract_boundaries() == {'FINISHED'}   # invoked from the settings (mirrored)
    bset = _stored(ext, coll)
    n = bset.curves.shape[0]
    assert n == s.curve_count == len(s.curves_object.data.splines)
    assert bset.meta["selection_tolerance_met"] is True and s.outline_mean_mm <= 0.12 < auto_mean
    assert n > 19 and s.outline_candidates > 0
    drawn = {x[1] for x in _panel_labels(ext, coll) if x[0] == "prop"}
    assert {"use_tolerance", "tolerance_mm", "max_tolerance_mm"} <= drawn and "patches" not in drawn
    assert bpy.ops.pdehead.reconstruct_surface() == {'FINISHED'}     # the C2 surface takes any count
    head = ext.engine.solve_pde(bset)
    assert len(s.surface_object.data.vertices) == len(head.surface(int(s.nu), int(s.nv), caps=True).vertices)
    if not bset.is_3t_plus_1:   # the paper's patches need 3t+1 curves: said, nothing half-built
        before = len(s.surface_object.data.vertices)
        with pytest.raises(RuntimeError, match="3t\\+1"):
            bpy.ops.pdehead.reconstruct_surface(continuity='paper')
        assert len(s.surface_object.data.vertices) == before

    # saved and reopened: the count and the achieved distance come back with the curves
    path = tmp_path / "tolerance.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    ext.state.drop_cache()
    coll = open_blend(path)
    s = coll.pdehead
    assert s.curve_count == n and s.use_tolerance and s.outline_mean_mm <= 0.12
    assert _stored(ext, coll).curves.shape[0] == n
    assert f"{n} curves stored" in " ".join(str(x[1]) for x in _panel_labels(ext, coll) if x[0] == "label")

    # a tolerance no set of slices meets: every usable slice, and a warning naming what was achieved
    s.tolerance_mm = 0.001
    assert bpy.ops.pdehead.extract_boundaries() == {'FINISHED'}
    assert s.curve_count == abs(s.outline_candidates) and s.outline_candidates < 0
    assert "tolerance" in s.warnings and "mm" in s.warnings
    s.tolerance_mm = s.max_tolerance_mm = 0.0
    with pytest.raises(RuntimeError, match="mean or a max tolerance"):
        bpy.ops.pdehead.extract_boundaries()
    assert np.isfinite(s.outline_mean_mm)
