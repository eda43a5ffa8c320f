"""The pdehead.* operators in real Blender, with the extension installed from the built zip.

The expensive pipeline runs happen once per session (conftest: ``phantom_blend`` = run_pipeline on the
phantom, ``cthead_blend`` = every operator step by step on CThead raw16); the tests reopen those
files, which also checks that the studies survive save/reopen.
"""
from __future__ import annotations

import base64
import math
import re
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import blender_inspect  # tests/blender/blender_inspect.py
from panel_recorder import RecordingLayout as _Layout  # noqa: E402


def open_blend(path: Path):
    """Open a saved study file; returns its (only) study collection."""
    import bpy
    bpy.ops.wm.open_mainfile(filepath=str(path))
    studies = [c for c in bpy.data.collections if c.pdehead.is_study]
    assert len(studies) == 1, [c.name for c in bpy.data.collections]
    return studies[0]


def stored_head(ext, coll, controls: bool = False, **pde):
    """The PDE head solved independently from the boundary bytes stored in the .blend (``controls``:
    through the engine's mapping of the normalised sliders, ``solve_with_controls``)."""
    raw = base64.b64decode(coll[ext.state.BOUNDARY_KEY])
    bset = ext.engine.loads_boundaries(raw)
    return (ext.engine.solve_with_controls if controls else ext.engine.solve_pde)(bset, **pde)


def world_mm(ext, obj) -> np.ndarray:
    return blender_inspect.mesh_world_vertices(obj) * 1000.0


def check_study(ext, coll, t: int, nu: int, nv: int, nw: int, volume: bool = True):
    """The study's objects agree with the engine's own meshes of the stored boundary curves."""
    import bpy
    s = coll.pdehead
    assert s.curves_object and s.surface_object and s.solid_object
    # Frame Study's camera and lights, the settings Empty
    scene_kinds = {"camera", "key_light", "fill_light", "study_settings"}
    assert {o.name for o in coll.all_objects if o.get("pdehead_kind") not in scene_kinds} == {
        o.name for o in (s.curves_object, s.surface_object, s.solid_object, s.volume_object) if o}
    assert len(s.curves_object.data.splines) == 3 * t + 1
    head = stored_head(ext, coll)
    assert head.bset.patches == t
    assert head.bset.meta.get("parameterisation") == "angular"  # Align Curves is on by default
    surface = head.surface(nu, nv, caps=True, fit_bends=True)      # rows and columns closer at tight bends
    assert len(s.surface_object.data.vertices) == len(surface.vertices)
    assert len(s.surface_object.data.polygons) == surface.face_count
    # built from the curves in memory, which the file stores rounded to its quantum: the fitted rows and
    # columns (a function of the surface's normal turning) sit up to ~0.2 mm along the surface elsewhere
    np.testing.assert_allclose(world_mm(ext, s.surface_object), surface.vertices, atol=0.3)
    solid = head.solid(nu, nv, nw)
    assert len(s.solid_object.data.vertices) == len(solid.vertices)
    if volume:
        vol = s.volume_object
        assert vol is not None and vol.type == 'VOLUME'
        assert vol.data.filepath.startswith("//pdehead_vdb/")
        assert Path(bpy.path.abspath(vol.data.filepath)).is_file()
        assert vol.data.grids.load()
        assert {"w", "intensity"} <= {g.name for g in vol.data.grids}
    timings = ext.study.entity.Study.of(coll).timings
    assert {"segment", "boundaries", "surface", "solid"} <= set(timings)
    assert all(v >= 0 for v in timings.values())
    return head


def test_phantom_pipeline(ext, phantom_blend):
    coll = open_blend(phantom_blend)
    assert coll.name == "Phantom"
    s = coll.pdehead
    assert (s.patches, s.nu, s.nv, s.nw) == (6, 32, 48, 4)
    head = check_study(ext, coll, t=6, nu=32, nv=48, nw=4)
    # the surface spans the phantom head: vertex at z = +98 mm, nose tip near y = -106 mm (LPS)
    v = world_mm(ext, s.surface_object)
    # the top: the crown's dome vertex above the top curve (smooth continuity), else the top curve
    top = head.vertex[2] if getattr(head, "vertex", None) is not None else head.bset.curves[..., 2].max()
    assert abs(v[:, 2].max() - top) < 1.0
    assert -115 < v[:, 1].min() < -95
    assert abs(v[np.argmin(v[:, 1]), 0]) < 10  # the nose is on the midline
    assert {"import", "segment", "boundaries", "pde_solve", "surface", "solid", "w_field", "volume"} \
        <= set(ext.study.entity.Study.of(coll).timings)
    # the Study object: one per study_id for the session, wrapping this collection, sharing its cache
    import bpy
    study = ext.study.entity.Study.of(coll)
    assert ext.study.entity.Study.of(coll) is study and study.collection == coll
    assert ext.study.entity.Study.active(bpy.context) is study
    assert study.settings == s and study.cache is ext.state.cache_for(s.study_id)
    assert study.head is study.cache.head
    ct = study.ct  # from memory, or re-made (phantom) and then kept
    assert ct is study.cache.ct and study.ct_status() == ("CT in memory", "CHECKMARK")


def test_cthead_operators(ext, cthead_blend):
    coll = open_blend(cthead_blend)
    s = coll.pdehead
    assert tuple(s.dimensions) == (256, 256, 113)
    assert tuple(round(x, 3) for x in s.spacing) == (2.0, 1.0, 1.0)
    assert s.source.endswith("raw16") and s.source_kind == "FILES"
    assert 0.05 < s.seg_fraction < 0.6
    check_study(ext, coll, t=10, nu=40, nv=60, nw=5)
    v = world_mm(ext, s.surface_object)
    ct_lo = np.array([-1.0, -1.0, -1.0]) + v.min(axis=0)  # sanity: finite, head-sized
    assert np.all(np.isfinite(v)) and np.all(np.ptp(v, axis=0) > 100) and np.all(np.ptp(v, axis=0) < 300)
    # face toward -y: the most anterior point (nose) lies near the left-right middle of the head
    mid_x = 0.5 * (v[:, 0].min() + v[:, 0].max())
    assert abs(v[np.argmin(v[:, 1]), 0] - mid_x) < 20, ct_lo


def test_live_parameters_after_reopen_without_resegmenting(ext, phantom_blend, monkeypatch):
    """Save -> reopen -> change each live parameter as a user would: the objects follow at once."""
    coll = open_blend(phantom_blend)
    ext.state.drop_cache()  # as in a new Blender session: nothing in memory but the .blend

    def no_segmentation(*args, **kwargs):
        raise AssertionError("live parameters must not re-segment")
    monkeypatch.setattr(ext.study.steps, "segment_head", no_segmentation)
    # (the CT itself is re-read from its source - here the phantom - for the solid's colours)
    s = coll.pdehead
    surf, solid = s.surface_object, s.solid_object

    s.nu = 20
    head = stored_head(ext, coll)
    assert s.last_error == ""
    assert len(surf.data.vertices) == len(head.surface(20, 48, caps=True).vertices)
    assert len(solid.data.vertices) == len(head.solid(20, 48, 4).vertices)
    s.nv = 36
    assert len(surf.data.vertices) == len(head.surface(20, 36, caps=True).vertices)
    np.testing.assert_allclose(world_mm(ext, surf), head.surface(20, 36, caps=True, fit_bends=True).vertices, atol=0.05)
    s.caps = False
    assert len(surf.data.vertices) == len(head.surface(20, 36, caps=False).vertices)
    s.caps = True

    before = world_mm(ext, surf)
    ranges = ext.engine.control_ranges(head.bset)
    s.approximation_auto = False  # the manual slider starts at the automatic value, as a fraction
    assert s.approximation == pytest.approx(ranges["approximation_mm"][0] / ranges["approximation_mm"][1], rel=1e-5)
    np.testing.assert_allclose(world_mm(ext, surf), before, atol=1e-3)
    s.approximation = 1.0  # the top of the study's range: a strongly smoothed head, never refused
    assert s.last_error == ""
    expected = stored_head(ext, coll, controls=True, approximation=1.0).surface(20, 36, caps=True,
                                                                               fit_bends=True).vertices
    np.testing.assert_allclose(world_mm(ext, surf), expected, atol=0.05)
    assert np.abs(world_mm(ext, surf) - before).max() > 1.0  # visibly smoother
    assert s.volume_stale  # the w-field follows the PDE: the sidebar asks for a rebuild
    s.approximation_auto = True

    shown = world_mm(ext, surf)
    s.smoothing_auto = False
    assert s.smoothing == pytest.approx(0.0)       # the C2 default a is 0 (the natural spline)
    s.smoothing = 1.0                              # a = the isotropic height/radius: every value solves
    assert s.last_error == ""
    expected = stored_head(ext, coll, controls=True, smoothing=1.0).surface(20, 36, caps=True,
                                                                               fit_bends=True).vertices
    np.testing.assert_allclose(world_mm(ext, surf), expected, atol=0.05)
    assert np.abs(world_mm(ext, surf) - shown).max() > 1e-3  # measurable (high harmonics damped between curves)
    s.smoothing_auto = True

    s.continuity = "paper"                         # the paper's patches, on the same stored curves
    assert s.last_error == ""
    expected = stored_head(ext, coll, continuity="paper").surface(20, 36, caps=True,
                                                                               fit_bends=True).vertices
    np.testing.assert_allclose(world_mm(ext, surf), expected, atol=0.05)
    s.continuity = "c2"

    s.modes = 3                                    # eq. 13's truncated series: a much simpler head
    assert s.last_error == ""
    expected = stored_head(ext, coll, controls=True, modes=3).surface(20, 36, caps=True,
                                                                               fit_bends=True).vertices
    np.testing.assert_allclose(world_mm(ext, surf), expected, atol=0.05)
    assert np.abs(world_mm(ext, surf) - shown).max() > 3.0
    s.modes = 0

    s.nw = 7
    assert len(solid.data.vertices) == len(head.solid(20, 36, 7).vertices)
    s.w_range = (0.8, 1.0)
    s.v_range = (math.pi / 2, 2 * math.pi)
    cut = head.solid(20, 36, 7, (0.0, 1.0), (math.pi / 2, 2 * math.pi), (0.8, 1.0))
    np.testing.assert_allclose(world_mm(ext, solid), cut.vertices, atol=0.05)
    w = blender_inspect.mesh_attribute(solid, "w")
    assert w.min() >= 0.8 - 1e-6 and w.max() <= 1.0 + 1e-6

    vol = s.volume_object
    s.low_alpha, s.high_alpha, s.density = 0.25, 0.75, 12.5
    s.colour_preset, s.alpha_mode = "skin", "INTENSITY"
    got = ext.volume.material.get_volume_settings(vol)
    assert got["low_alpha"] == pytest.approx(0.25) and got["high_alpha"] == pytest.approx(0.75)
    assert got["density"] == pytest.approx(12.5)
    assert (got["colour_preset"], got["alpha_mode"]) == ("skin", "INTENSITY")
    assert s.last_error == ""


def test_nonexistent_input_is_reported_and_creates_nothing(ext):
    import bpy
    n_obj, n_coll = len(bpy.data.objects), len(bpy.data.collections)
    with pytest.raises(RuntimeError, match=r"/no/such/ct: no such file or folder"):
        bpy.ops.pdehead.import_ct(directory="/no/such/ct")
    with pytest.raises(RuntimeError, match=r"/no/such/ct: no such file or folder"):
        bpy.ops.pdehead.run_pipeline(directory="/no/such/ct")
    with pytest.raises(RuntimeError, match=r"No PDE Head study"):
        bpy.ops.pdehead.segment()
    assert (len(bpy.data.objects), len(bpy.data.collections)) == (n_obj, n_coll)
    assert ext.state.studies() == []


def test_engine_error_mid_pipeline_leaves_nothing(ext, tmp_path, monkeypatch):
    """A bad raw file: the loader's error reaches the user; a later step's error rolls everything back."""
    import bpy
    bad = tmp_path / "slices"
    bad.mkdir()
    (bad / "CThead.1").write_bytes(b"\x00" * 100)  # not 256 x 256 x 2 bytes
    with pytest.raises(RuntimeError, match=re.escape(str(bad))):
        bpy.ops.pdehead.import_ct(directory=str(bad), format='RAW', raw_shape=(256, 256), spacing=(2, 1, 1))
    assert len(bpy.data.collections) == 0 and len(bpy.data.objects) == 0

    def failing(*args, **kwargs):
        raise ext.engine.BoundaryError("no usable slice: the head mask is empty")
    monkeypatch.setattr(ext.study.steps, "extract_boundaries", failing)
    monkeypatch.setattr(ext.study.steps, "segment_head", lambda ct, **kw: ext.engine.Segmentation(
        np.zeros(ct.shape, bool), np.zeros(ct.shape, np.float32), 0.0, 0.0, 0, ct))
    with pytest.raises(RuntimeError, match="no usable slice"):
        bpy.ops.pdehead.run_pipeline(source='PHANTOM')
    assert len(bpy.data.collections) == 0 and len(bpy.data.objects) == 0 and len(bpy.data.meshes) == 0
    assert ext.state.cached_study_ids() == []


def _tick_until_next_step(op_cls, op, context, timer, ticks: int = 500) -> None:
    """Timer ticks until the run moves to its next step (a threaded step takes several)."""
    import time
    index = op._run.index
    for _ in range(ticks):
        assert op_cls.modal(op, context, timer) == {'RUNNING_MODAL'}
        if op._run.index > index:
            return
        time.sleep(0.01)
    raise AssertionError(f"step {op._run.steps[index]} did not end in {ticks} ticks")


def _modal_pipeline_op(ext):
    """The Run Pipeline operator's modal methods on a stand-in operator and context (no window in bpy as a
    module): the progress it reports and the reports it makes are recorded."""
    import bpy
    progress, reports = [], []
    wm = SimpleNamespace(progress_update=progress.append, progress_end=lambda: progress.append("end"),
                         event_timer_remove=lambda timer: progress.append("timer removed"))
    context = SimpleNamespace(window_manager=wm, workspace=None, scene=bpy.context.scene,
                              active_object=None, preferences=bpy.context.preferences)
    op_cls = ext.ui.ops.PDEHEAD_OT_run_pipeline
    run = ext.study.pipeline_run.PipelineRun(bpy.context, "PHANTOM", settings=dict(patches=4, nu=16, nv=24))
    op = SimpleNamespace(_run=run,
                         _timer=object(), report=lambda kind, msg: reports.append((kind, msg)))
    for name in ("_end_ui", "cancel", "tick"):           # the operator's methods, bound to the stand-in
        setattr(op, name, getattr(op_cls, name).__get__(op))
    op.finished = lambda: op_cls.finished(op)
    op.cancelled_message = op_cls.cancelled_message
    return op_cls, op, context, progress, reports


def test_modal_pipeline_esc_stops_a_step_in_the_middle(ext, phantom, monkeypatch):
    """Esc while the segmentation works on its thread: it stops at its next progress report (not at the
    step's end, 10 s away), the thread has ended, and nothing of the run is left."""
    import threading
    import time

    import bpy
    calls, started = [], threading.Event()

    def slow_segmentation(ct, progress=None, **kw):
        for i in range(1000):   # 10 s if nobody stops it
            progress(i / 1000, "Chan-Vese")
            calls.append(i)
            started.set()
            time.sleep(0.01)
        return ext.engine.Segmentation(phantom.head_mask, phantom.head_mask.astype(np.float32), 1.0, 0.0, 1, ct)
    monkeypatch.setattr(ext.study.steps, "segment_head", slow_segmentation)
    op_cls, op, context, progress, reports = _modal_pipeline_op(ext)
    timer, esc = (SimpleNamespace(type=t) for t in ("TIMER", "ESC"))
    _tick_until_next_step(op_cls, op, context, timer)              # import
    assert op_cls.modal(op, context, timer) == {'RUNNING_MODAL'}   # the segmentation starts on its thread
    job = op._run.job
    assert job is not None and started.wait(5)
    time.sleep(0.1)
    assert op_cls.modal(op, context, timer) == {'RUNNING_MODAL'}   # still working: the tick returns at once
    assert 1 < progress[-1] < 2                                     # its fraction between the step marks
    assert op_cls.modal(op, context, esc) == {'CANCELLED'}
    assert job.done and 0 < len(calls) < 200                        # stopped mid-step
    assert len(bpy.data.objects) == 0 and len(bpy.data.collections) == 0 and len(bpy.data.meshes) == 0
    assert ext.state.cached_study_ids() == []
    assert reports and reports[-1][0] == {'WARNING'} and "cancelled" in reports[-1][1]


def test_modal_pipeline_error_on_the_thread_is_reported(ext, phantom, monkeypatch):
    """An engine error on the worker thread reaches the user as the synchronous run's would, and the run is
    undone."""
    import bpy

    def failing_segmentation(ct, progress=None, **kw):
        raise ext.engine.PDEHeadError("no head found in this CT")
    monkeypatch.setattr(ext.study.steps, "segment_head", failing_segmentation)
    op_cls, op, context, progress, reports = _modal_pipeline_op(ext)
    timer = SimpleNamespace(type="TIMER")
    _tick_until_next_step(op_cls, op, context, timer)              # import
    import time
    result = None
    for _ in range(500):
        result = op_cls.modal(op, context, timer)
        if result != {'RUNNING_MODAL'}:
            break
        time.sleep(0.01)   # the worker thread's turn
    assert result == {'CANCELLED'}
    assert any("no head found" in msg for _, msg in reports)
    assert len(bpy.data.objects) == 0 and len(bpy.data.collections) == 0


def test_modal_pipeline_esc_removes_everything(ext, phantom, monkeypatch):
    """The UI path: one step per timer tick, progress, then Esc -> nothing of this run is left."""
    import bpy
    monkeypatch.setattr(ext.study.steps, "segment_head", lambda ct, **kw: ext.engine.Segmentation(
        phantom.head_mask, phantom.head_mask.astype(np.float32), 1.0, 0.0, 1, ct))
    op_cls, op, context, progress, reports = _modal_pipeline_op(ext)
    timer, esc, mouse = (SimpleNamespace(type=t) for t in ("TIMER", "ESC", "MOUSEMOVE"))

    assert op_cls.modal(op, context, mouse) == {'PASS_THROUGH'}
    for expected_step in ("import", "segment", "boundaries", "surface"):
        assert op._run.steps[op._run.index] == expected_step
        _tick_until_next_step(op_cls, op, context, timer)
    # the step marks in order (a step on its worker thread adds its fraction between them)
    assert progress == sorted(progress) and [p for p in progress if p in (1, 2, 3, 4)][-1] == 4
    assert {1, 2, 3, 4} <= set(progress)
    coll = op._run.collection
    assert coll is not None and coll.pdehead.surface_object is not None and coll.pdehead.curves_object
    assert len(bpy.data.objects) == 3 and len(bpy.data.meshes) == 1  # curves, surface, the settings Empty

    assert op_cls.modal(op, context, esc) == {'CANCELLED'}
    assert len(bpy.data.objects) == 0 and len(bpy.data.collections) == 0 and len(bpy.data.meshes) == 0
    assert len(bpy.data.curves) == 0
    assert ext.state.cached_study_ids() == []
    assert progress[-2:] == ["timer removed", "end"]
    assert reports and reports[-1][0] == {'WARNING'} and "cancelled" in reports[-1][1]


def test_two_studies_get_their_own_collections(ext):
    import bpy
    assert bpy.ops.pdehead.load_phantom() == {'FINISHED'}
    assert bpy.ops.pdehead.load_phantom() == {'FINISHED'}
    names = sorted(c.name for c in ext.state.studies())
    assert names == ["Phantom", "Phantom.001"]
    assert bpy.context.scene.pdehead.active_study.name == "Phantom.001"
    ids = {c.pdehead.study_id for c in ext.state.studies()}
    assert len(ids) == 2 and all(ext.state.cache_for(i).ct is not None for i in ids)
    assert bpy.ops.pdehead.remove_study(study="Phantom") == {'FINISHED'}
    assert [c.name for c in ext.state.studies()] == ["Phantom.001"]




def test_panels_draw_every_setting(ext, phantom_blend):
    import bpy
    coll = open_blend(phantom_blend)
    bpy.context.scene.pdehead.active_study = coll
    panel_mod = sys.modules[ext.ui.ops.__name__.rpartition(".")[0] + ".panel"]
    log = []
    for cls in panel_mod.CLASSES:
        assert cls.bl_category == "PDE Head" and cls.bl_region_type == 'UI'
        if "poll" in vars(cls) or any("poll" in vars(b) for b in cls.__mro__[1:] if b.__module__ == cls.__module__):
            assert cls.poll(bpy.context)
        cls.draw(SimpleNamespace(layout=_Layout(log), study=cls.study), bpy.context)
    drawn_ops = {x[1] for x in log if x[0] == "operator"}
    assert {"pdehead.import_ct", "pdehead.load_phantom", "pdehead.run_pipeline", "pdehead.segment",
            "pdehead.extract_boundaries", "pdehead.reconstruct_surface", "pdehead.build_solid",
            "pdehead.build_volume", "pdehead.frame_study", "pdehead.add_cutter"} <= drawn_ops
    drawn_props = {x[1] for x in log if x[0] == "prop"}
    assert {"nu", "nv", "caps", "smoothing_auto", "smoothing", "modes", "nw", "u_range", "v_range", "w_range",
            "low_alpha", "high_alpha", "density", "colour_preset", "alpha_mode", "patches"} <= drawn_props
    labels = " ".join(str(x[1]) for x in log if x[0] == "label")
    assert "Dimensions: 128 x 128 x 100" in labels and "segment" in labels and "total" in labels


def test_ge_tilted_series_one_click_reduces_patches_to_what_the_scan_allows(ext, tmp_path):
    """The real GE series (18.5 deg tilt, uneven steps) in one click: the default t = 10 needs more
    slices than the tilted slab covers, so the pipeline uses the largest t it allows and says so."""
    import bpy

    from datasets import shared_data

    folder = shared_data("ct_head_ge_tilt_dicom", "dicom")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "ge.blend"))  # the VDB goes beside the saved file
    bpy.ops.pdehead.run_pipeline(source='FILES', filepath=str(folder), patches=10, nu=40, nv=60, nw=4,
                                 voxel_size=4.0)
    coll = bpy.context.scene.pdehead.active_study
    s = coll.pdehead
    assert s.source_kind == "FILES"
    limit = ext.engine.max_patches(ext.state.cache_for(s.study_id).seg)
    assert 4 <= limit < 10
    assert s.patches == limit
    assert "patches reduced from 10 to" in s.warnings
    check_study(ext, coll, t=limit, nu=40, nv=60, nw=4)
    # patient geometry survives the tilt correction: the face points to -y and the head is upright
    v = world_mm(ext, s.surface_object)
    mid_x = 0.5 * (v[:, 0].min() + v[:, 0].max())
    front = v[v[:, 1] <= np.percentile(v[:, 1], 3)]          # the most anterior 3 %: the brow (no nose in GE)
    assert abs(front[:, 0].mean() - mid_x) < 15 and front[:, 1].mean() < v[:, 1].mean() - 50
    assert 60 < np.ptp(v[:, 2]) < 200 and 120 < np.ptp(v[:, 0]) < 200


def test_invoking_an_operator_starts_from_the_study_settings_and_running_stores_them(ext, phantom_blend):
    """Redo-panel round trip: invoke copies the study's settings into the operator, execute writes them back.

    Headless Blender never calls invoke (no window), so the mixin's invoke is called as a function."""
    import bpy

    coll = open_blend(phantom_blend)
    s = coll.pdehead
    with ext.state.suspended_updates():
        s.nu, s.nv, s.caps = 24, 36, False
    op_class = ext.ui.ops.PDEHEAD_OT_reconstruct_surface
    fake = SimpleNamespace(study="", nu=0, nv=0, caps=True, continuity="c2", dome=True, smoothing_auto=True,
                           smoothing=0.0, approximation_auto=True, approximation=0.0, modes=0,
                           mirrored_settings=op_class.mirrored_settings, execute=lambda context: {'FINISHED'})
    assert op_class.invoke(fake, bpy.context, None) == {'FINISHED'}
    assert (fake.nu, fake.nv, fake.caps, fake.modes) == (24, 36, False, s.modes)
    assert bpy.ops.pdehead.reconstruct_surface(nu=30, nv=40, caps=False) == {'FINISHED'}
    assert (s.nu, s.nv) == (30, 40)
    assert len(s.surface_object.data.vertices) == 29 * 40 + 1       # the dome's crown is one vertex



def test_the_boundaries_step_returns_the_effective_t_its_warnings_and_seconds(ext, phantom_blend):
    """``Study.boundaries()`` returns what the operators and the CLI report: t reduced to what the scan allows
    (the phantom's 100 slices cannot give 3 x 60 + 1 curves), the curves, the warning it added and the seconds;
    Extract Boundaries reports the same."""
    coll = open_blend(phantom_blend)
    study = ext.study.entity.Study.of(coll)
    s = study.settings
    with ext.state.suspended_updates():
        s.patches, s.use_tolerance, s.selection = 60, False, "uniform"
    outcome = study.boundaries()
    limit = ext.engine.max_patches(study.cache.seg)
    assert outcome.patches == s.patches == limit < 60
    assert outcome.curves == s.curve_count == 3 * limit + 1 == len(study.cache.bset.curves)
    assert len(outcome.warnings) == 1 and "patches reduced from 60 to" in outcome.warnings[0]
    assert outcome.warnings[0] in study.warnings
    assert outcome.seconds > 0 and round(outcome.seconds, 4) == pytest.approx(study.timings["boundaries"])
    again = study.boundaries()                       # the same t again: nothing new to warn about
    assert (again.patches, again.curves, again.warnings) == (limit, 3 * limit + 1, ())


def test_the_segment_surface_and_volume_steps_return_their_outcomes(ext, phantom_blend, tmp_path):
    """``segment()``, ``surface()`` and ``volume()`` return what they built and measured (a ``StepOutcome``):
    the objects, the seconds the study's timings record and the effective values (the head's fraction, the
    vertex count, the voxel size and the .vdb written); the operators report from them."""
    import shutil
    copy = tmp_path / "outcomes.blend"           # a copy: the new .vdb goes beside it, the shared file stays as is
    shutil.copy(phantom_blend, copy)
    coll = open_blend(copy)
    study = ext.study.entity.Study.of(coll)
    s = study.settings
    seg = study.segment()
    assert seg.step == "segment" and seg.objects == ()
    assert seg.values["fraction"] == pytest.approx(float(study.cache.seg.mask.mean()))
    assert 0.05 < seg.values["fraction"] < 0.9
    assert seg.values["iterations"] == int(study.cache.seg.iterations) > 0
    assert round(seg.seconds, 4) == pytest.approx(study.timings["segment"])
    surface = study.surface()
    assert surface.objects == (s.surface_object,)
    assert surface.values["vertices"] == len(s.surface_object.data.vertices) > 1000
    assert round(surface.seconds, 4) == pytest.approx(study.timings["surface"])
    with ext.state.suspended_updates():
        s.use_ct_grid, s.voxel_auto, s.voxel_size = False, False, 4.0
    volume = study.volume()
    assert volume.objects == (s.volume_object,) and volume.values["voxel_size"] == pytest.approx(4.0)
    assert Path(volume.values["vdb_path"]).is_file()
    assert tmp_path.resolve() in Path(volume.values["vdb_path"]).resolve().parents
    assert volume.seconds == pytest.approx(volume.values["w_field_s"] + volume.values["volume_s"])
    assert round(volume.values["volume_s"], 4) == pytest.approx(study.timings["volume"])


def test_the_solid_and_forensic_steps_return_their_outcomes(ext, phantom_blend, tmp_path):
    """``solid()`` and the forensic steps (``step_skull()``, ``step_depth()``, ``build_face()``,
    ``build_sd_faces()``) return what they built and measured (a ``StepOutcome``): the objects, the warnings,
    the seconds the study's timings record and the effective values; the operators report from them."""
    import shutil
    copy = tmp_path / "forensic_outcomes.blend"
    shutil.copy(phantom_blend, copy)
    coll = open_blend(copy)
    study = ext.study.entity.Study.of(coll)
    s = study.settings
    solid = study.solid()
    assert solid.step == "solid" and solid.objects == (s.solid_object,)
    assert solid.values["vertices"] == len(s.solid_object.data.vertices) > 1000
    assert solid.values["notice"] == "" and solid.warnings == ()      # the CT is at hand: exact colours
    assert round(solid.seconds, 4) == pytest.approx(study.timings["solid"])
    fs = study.forensic
    skull = fs.skull.step_skull(24, 40, bone=True, bone_step=4)
    assert skull.step == "skull"
    assert skull.objects == (coll["pdehead_skull_object"], coll["pdehead_bone_object"])
    info = fs.skull.skull_info()
    assert skull.values["patches"] == info["patches"] > 0
    assert skull.values["bone_triangles"] == info["bone_triangles"] == len(coll["pdehead_bone_object"].data.polygons)
    assert skull.warnings == tuple(info.get("warnings", ()))
    assert round(skull.seconds, 4) == pytest.approx(study.timings["skull"])
    depth = fs.skull.step_depth("PDE", 30.0)
    assert depth.step == "depth" and depth.objects == (s.surface_object,)
    assert depth.values["target"] == "PDE" and depth.values["max_depth_mm"] == 30.0
    assert 0 < depth.values["measured"] <= depth.values["vertices"] == len(s.surface_object.data.vertices)
    assert depth.values["measured"] == fs.skull.depth_stats()["measured"]
    assert round(depth.seconds, 4) == pytest.approx(study.timings["depth"])
    face = fs.face.build_face()
    assert face.step == "face" and face.objects[0] == fs.face.face_object()
    assert face.values["pegs"] == len(face.objects) - 1 == len(fs.face.face_peg_names()) > 0
    assert all(p.parent == face.objects[0] for p in face.objects[1:])
    assert face.values["vertices"] == len(fs.face.face_object().data.vertices)
    assert face.values["label"] == ext.forensic.face.approximation_label()
    report = fs.cache.get("face_report")
    assert face.warnings == ((report.summary(),) if report.summary() else ())
    assert round(face.seconds, 4) == pytest.approx(study.timings["face_prepare"])
    sd = fs.face.build_sd_faces()
    assert sd.step == "face_sd" and len(sd.objects) == 2 and sd.seconds > 0
    assert sd.values["vertices"] == [len(o.data.vertices) for o in sd.objects]
    assert [o["pdehead_kind"] for o in sd.objects] == ["face_minus_sd", "face_plus_sd"]


def test_the_forensic_side_is_a_component_the_study_holds(ext, phantom_blend):
    """One registry of study entities: each study holds its forensic side (``study.forensic``), the one
    ``ForensicStudy.of`` gives; forgetting the study forgets it too."""
    coll = open_blend(phantom_blend)
    study = ext.study.entity.Study.of(coll)
    fs = ext.forensic.study.ForensicStudy.of(study)
    assert fs is study.forensic and fs.study is study and fs.collection == coll
    assert ext.forensic.study.ForensicStudy.of(study) is fs and fs.cache is study.cache.forensic
    assert not hasattr(ext.state.REGISTRY, "forensic")
    ext.study.entity.Study.forget(study.study_id)
    again = ext.study.entity.Study.of(coll)
    assert again is not study and again.forensic is not fs and again.forensic.study is again


def test_solid_texture_fields_are_drawn_and_change_the_solid(ext, cthead_blend):
    """Issue 21 item 3: the solid's CT texture budget, what its outside shows and the skin depth are
    sidebar fields (Solid panel), and changing each rebuilds the solid with it (CThead, 1 mm voxels)."""
    import bpy
    coll = open_blend(cthead_blend)
    bpy.context.scene.pdehead.active_study = coll
    panel_mod = sys.modules[ext.ui.ops.__name__.rpartition(".")[0] + ".panel"]
    log = []
    panel_mod.PDEHEAD_PT_solid.draw(SimpleNamespace(layout=_Layout(log), study=panel_mod.PDEHEAD_PT_solid.study),
                                    bpy.context)
    assert {"ct_texture_budget", "solid_skin", "solid_skin_depth"} <= {x[1] for x in log if x[0] == "prop"}
    s = coll.pdehead
    D = sys.modules[ext.engine.__name__ + ".defaults"]
    assert s.solid_skin == D.SOLID_SKIN.default == "surface"
    assert (s.ct_texture_budget, s.solid_skin_depth) == pytest.approx(
        (D.CT_TEXTURE_BUDGET.default, D.SOLID_SKIN_DEPTH.default))
    solid = s.solid_object

    def materials():
        m = np.empty(len(solid.data.polygons), np.int32)
        solid.data.polygons.foreach_get("material_index", m)
        return m

    def atlas():
        image = solid.data.materials[0].node_tree.nodes["CT texture"].image
        w, h = image.size
        px = np.empty(w * h * 4, np.float32)
        image.pixels.foreach_get(px)
        return (w, h), px.reshape(h, w, 4)[..., 0]

    skin_faces = int(np.count_nonzero(materials() == 1))
    assert skin_faces > 1000                    # the outer shell shows the skin material by default
    (w0, h0), _ = atlas()
    s.solid_skin = "ct"
    assert s.last_error == ""
    assert not materials().any()                 # the CT everywhere, the outer shell included
    (w1, h1), ct2 = atlas()
    # measured: 261 x 557 (0.15 MP) with the skin material; the skin's CT tile makes it larger
    assert w1 * h1 > w0 * h0
    s.solid_skin_depth = 8.0
    assert s.last_error == ""
    (w2, h2), ct8 = atlas()
    assert (w2, h2) == (w1, h1)
    changed = np.abs(ct8 - ct2) > 0.05
    assert changed.mean() > 0.05, changed.mean()          # the outer tile samples deeper tissue
    s.ct_texture_budget = D.CT_TEXTURE_BUDGET.min
    assert s.last_error == ""
    (w3, h3), _ = atlas()
    assert w3 * h3 <= D.CT_TEXTURE_BUDGET.min * 1e6 < w1 * h1, (w1, h1, w3, h3)
    s.ct_texture_budget, s.solid_skin = D.CT_TEXTURE_BUDGET.default, "surface"
    assert np.count_nonzero(materials() == 1) == skin_faces
