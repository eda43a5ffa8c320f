"""The live face's engine side (issue 23, point 2): pdehead_addon.forensic.face_live on the phantom's bone skull.

:class:`LiveFace` must give the very face :meth:`FaceModel.solve` gives (it is only faster), and a model
kept as text (:func:`model_state`) must come back as the same model without preparing it again.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from pdehead_addon.forensic.depth_table import default_table
from pdehead_addon.forensic.face_from_skull import FaceModel
from pdehead_addon.forensic.face_live import EXACT_TOLERANCE_MM, LiveFace, model_from_state, model_state


@pytest.fixture(scope="module")
def model(phantom_skull_mesh, phantom_search):
    return FaceModel.prepare(phantom_skull_mesh, phantom_search.points(), default_table(),
                             flags=phantom_search.flags())


def _dragged(model, i, mm):
    tips = model.tips_for(model.default_depths)
    tips[i] = tips[i] + mm * model.peg_normals[i] + np.array([1.5, -1.0, 0.5])
    return tips


def test_live_positions_are_the_models_solve(model):
    live = LiveFace(model)
    assert live.exact and live.max_difference_mm <= EXACT_TOLERANCE_MM     # measured 4e-13 mm (CThead too)
    n = len(model.peg_names)
    worst = 0.0
    for i, mm in ((0, 4.0), (n // 2, -3.0), (n - 1, 6.0)):
        tips = _dragged(model, i, mm)
        ref = model.solve(tips=tips)
        fast = live.positions(tips)
        assert fast is not None and fast.shape == ref.mesh.vertices.shape
        worst = max(worst, float(np.abs(fast - ref.mesh.vertices).max()))
        assert live.provenance(tips, live.report(tips, fast)) == ref.provenance     # with the pegs' report
    assert worst <= EXACT_TOLERANCE_MM, worst
    # a dragged peg moves the face (the check is not vacuous): 4 mm at the peg -> mm near its tip
    a, b = live.positions(_dragged(model, 0, 0.0)), live.positions(_dragged(model, 0, 4.0))
    assert np.abs(b - a).max() > 2.0
    # bad tips: no fast answer (the caller's whole solve raises its own error)
    assert live.positions(np.full((n, 3), np.nan)) is None and live.positions(np.zeros((n - 1, 3))) is None


def test_model_kept_as_text_is_the_same_model(model):
    model.solve()                                           # the first solve fixes the parameter and the caps
    text = model_state(model)
    assert len(text) < 1_000_000                            # budget 1 MB; phantom 0.72 MB with the UV layout
    back = model_from_state(text)
    assert back.restored_seconds < model.prepare_seconds
    assert back.peg_names == model.peg_names and np.array_equal(back.profile, model.profile)
    assert np.array_equal(back._grid_xyz, model._grid_xyz)
    for tips in (_dragged(model, 1, 3.0), _dragged(model, 5, -2.0)):
        assert np.array_equal(back.solve(tips=tips).mesh.vertices, model.solve(tips=tips).mesh.vertices)
    live = LiveFace(back, check=False)                      # a kept model: no reference solve needed
    tips = _dragged(model, 2, 2.5)
    assert np.abs(live.positions(tips) - model.solve(tips=tips).mesh.vertices).max() <= EXACT_TOLERANCE_MM
    # another format or software version is refused (the caller then prepares the model again)
    data = json.loads(text)
    for key, value in (("format", 0), ("software", "PDE Head 0.0.0")):
        with pytest.raises(ValueError):
            model_from_state(json.dumps(dict(data, **{key: value})))
    with pytest.raises(ValueError):
        model_from_state("not json")
