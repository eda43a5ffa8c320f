"""The application layer: the pipeline steps on a study, live updates, the pipeline run, undo.

Between the thin operators (:mod:`.ops`, :mod:`.forensic`, the update callbacks of
:mod:`.props`) and the engine (:mod:`pdehead_addon`): every step here reads a study's
settings (:mod:`.state`), calls the engine's public API and writes the result into Blender
objects (:mod:`.objects`, :mod:`.volume`, :mod:`.cutter`, :mod:`.scene`). Nothing here
imports an operator module, so the dependency runs one way::

    ops / forensic / panel / props  ->  study  ->  state / objects / volume / cutter / scene  ->  engine

The step functions (:func:`import_study`, :func:`step_segment`, ...) are plain functions on a
study collection; the operators, :func:`live_update` and :class:`.pipeline_run.PipelineRun` share them.
The study's CT and its (u, v, w) table: :class:`.study_entity.Study`; progress: :mod:`.progress`.
"""
from __future__ import annotations

import json
import re
import traceback
from pathlib import Path

import bpy
import numpy as np

from ..pdehead_addon import PDEHeadError, patches_for_scan
from . import cutter, objects, prefs, state, vdb_files, vdb_grids, volume, volume_material
from .progress import step_progress
from .state import suspended_updates
from .study_entity import Study

STEP_LABELS = {
    "import": "Import CT",
    "segment": "Segmentation",
    "boundaries": "Boundary curves",
    "surface": "PDE surface",
    "solid": "PDE solid",
    "volume": "Volume",
    "scene": "Camera and light",
}


# ------------------------------------------------------------------------------------------
# The steps (plain functions on a study collection; the study's cached results, CT and head: study_entity.Study)


def _unique_collection_name(base: str) -> str:
    base = re.sub(r"\s+", " ", base).strip()[:50] or "CT Head"
    name, i = base, 1
    while name in bpy.data.collections:
        name = f"{base}.{i:03d}"
        i += 1
    return name


_GENERIC_FOLDER_NAMES = {"dicom", "dcm", "raw", "raw16", "raw8", "tiff", "tiff8", "tif", "png", "images",
                         "slices", "data", "ct", "series", "input"}


def _study_name(ct, path: Path | None) -> str:
    """A readable study name: the series description, else the study description (+ series number),
    else the folder name (with its parent's when it is generic, like 'dicom' or 'raw16')."""
    meta = ct.meta or {}
    for key in ("series_description", "patient_name", "name"):
        value = meta.get(key)
        if isinstance(value, str) and value.strip():
            return value.strip()
    study = str(meta.get("study_description") or "").strip()
    if study:
        number = meta.get("series_number")
        return f"{study} {number}" if number not in (None, "") else study
    if path is not None:
        name = path.stem if path.is_file() else path.name
        if name.lower() in _GENERIC_FOLDER_NAMES and path.parent.name:
            return f"{path.parent.name} {name}"
        return name
    return "CT Head"


def _describe_ct(settings, ct) -> None:
    import numpy as np
    meta = ct.meta or {}
    nz, ny, nx = ct.shape
    settings.dimensions = (nx, ny, nz)
    settings.spacing = tuple(float(s) for s in ct.spacing)
    hu = meta.get("hu_range") or meta.get("value_range")
    if hu is None:
        hu = (float(np.min(ct.data)), float(np.max(ct.data)))
    settings.value_range = (float(hu[0]), float(hu[1]))
    series = meta.get("series_description") or meta.get("series") or ""
    if not series and meta.get("series_number") not in (None, ""):
        series = f"#{meta['series_number']}"
    if meta.get("series_uid"):
        series = f"{series} ({meta['series_uid']})" if series else str(meta["series_uid"])
    settings.series = str(series)[:200]
    settings.modality = str(meta.get("modality") or meta.get("units") or "")[:40]
    warnings = meta.get("warnings") or []
    settings.warnings = ""
    state.add_warnings(settings, [warnings] if isinstance(warnings, str) else warnings)


def create_study(context, ct, name: str, source_kind: str, source: str = "", options: dict | None = None):
    """A new study collection holding ``ct`` (in memory) and its description; made active."""
    scene = context.scene
    coll = objects.study_collection(_unique_collection_name(name), scene)
    s = state.settings(coll) or state.new_settings_object(coll)
    scene.render.use_lock_interface = True  # the frame handler may rebuild meshes while rendering
    with suspended_updates():
        s.is_study = True
        s.study_id = state.new_study_id()
        s.source_kind = source_kind
        s.source = source
        s.source_absolute = str(Path(source).resolve()) if source else ""
        s.load_options = json.dumps(options or {}, default=list)
        s.patches = prefs.default_patches(context)
        _describe_ct(s, ct)
    state.cache_for(s.study_id).ct = ct
    scene.pdehead.active_study = coll
    return coll


def import_study(context, path: Path, options: dict):
    """Load a CT from disk into a new study."""
    import warnings
    from ..pdehead_addon import load_ct
    with state.Timer() as t, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ct = load_ct(path, **options)
    coll = create_study(context, ct, _study_name(ct, path), "FILES", str(path), options)
    s = state.settings(coll)
    # the loader's warnings (single slice, uneven steps, ...) stay visible in the Study panel
    state.add_warnings(s, [str(w.message) for w in caught if issubclass(w.category, UserWarning)])
    s.timings_json = ""
    Study.of(coll).record_timing("import", t.seconds)
    return coll


def phantom_study(context):
    """The built-in synthetic head as a new study."""
    from ..pdehead_addon import make_phantom
    with state.Timer() as t:
        phantom = make_phantom()
    coll = create_study(context, phantom.ct, "Phantom", "PHANTOM")
    state.settings(coll).timings_json = ""
    Study.of(coll).record_timing("import", t.seconds)
    return coll


def step_segment(coll) -> None:
    from ..pdehead_addon import segment_head
    s = state.settings(coll)
    ct = Study.of(coll).ct
    cache = state.cache_for(s.study_id)
    with state.Timer() as t:
        seg = segment_head(ct, progress=step_progress("segment"))
    cache.drop_from("seg")
    cache.seg = seg
    with suspended_updates():
        s.seg_fraction = float(seg.mask.mean())
        s.seg_iterations = int(seg.iterations)
        s.seg_c1, s.seg_c2 = float(seg.c1), float(seg.c2)
        # head size outside the human range, shoulders cut off: shown with the loader's warnings
        state.add_warnings(s, seg.meta.get("warnings", []))
    Study.of(coll).record_timing("segment", t.seconds)


def selection_tolerance(s) -> dict:
    """``tolerance_mm`` / ``max_tolerance_mm`` for :func:`extract_boundaries` from the study settings
    (empty when the curves are counted by t)."""
    if not s.use_tolerance:
        return {}
    out = {name: float(getattr(s, name)) for name in ("tolerance_mm", "max_tolerance_mm") if getattr(s, name) > 0}
    if not out:
        raise PDEHeadError("Tolerance Instead of t needs a mean or a max tolerance above 0 mm")
    return out


def _record_selection(s, bset) -> None:
    """The curve count and, for the automatic selection, the achieved distance from all outlines,
    kept in the study settings (saved with the .blend) for the panel."""
    m = bset.meta
    s.curve_count = int(bset.curves.shape[0])
    s.outline_candidates = int(m.get("selection_candidates") or 0)
    s.outline_mean_mm = float(m.get("selection_mean_mm") or 0.0)
    s.outline_max_mm = float(m.get("selection_max_mm") or 0.0)
    if s.use_tolerance and m.get("selection_tolerance_met") is False:
        s.outline_candidates = -s.outline_candidates   # negative: the tolerance was not met


def step_boundaries(coll) -> None:
    from ..pdehead_addon import extract_boundaries
    s = state.settings(coll)
    cache = state.cache_for(s.study_id)
    if cache.seg is None:
        step_segment(coll)
    tolerance = selection_tolerance(s)
    if tolerance and not s.align_curves:
        raise PDEHeadError("a tolerance chooses the curves automatically, which needs Align Curves")
    patches, message = (s.patches, None) if tolerance else patches_for_scan(cache.seg, s.patches)
    if message:  # short scans (e.g. the tilted GE slab) cannot give 3t+1 slices
        with suspended_updates():
            s.patches = patches
        state.add_warnings(s, [message])
    import warnings
    from ..pdehead_addon import SelectionWarning
    with state.Timer() as t, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SelectionWarning)
        bset = extract_boundaries(cache.seg, patches=s.patches, samples=s.samples,
                                  selection="auto" if tolerance else s.selection,
                                  parameterisation="angular" if s.align_curves else "arc-length",
                                  progress=step_progress("boundaries"), **tolerance)
    messages = [str(w.message) for w in caught if issubclass(w.category, SelectionWarning)]
    if messages:  # the tolerance could not be met with every usable slice: said beside the other warnings
        state.add_warnings(s, messages)
    Study.of(coll).store_boundaries(bset)
    cache.drop_from("bset")
    cache.bset = bset
    with suspended_updates():
        _record_selection(s, bset)
    s.curves_object = objects.build_boundary_curves(bset, coll, name=f"{coll.name} Boundary curves",
                                                    obj=s.curves_object)
    Study.of(coll).record_timing("boundaries", t.seconds)


def step_surface(coll) -> None:
    s = state.settings(coll)
    head = Study.of(coll).solve()
    with state.Timer() as t:
        s.surface_object = objects.build_surface(head, coll, nu=s.nu, nv=s.nv, caps=s.caps, obj=s.surface_object,
                                                 name=f"{coll.name} Surface")
    Study.of(coll).record_timing("surface", t.seconds)


#: A live change of the PDE (smoothing, modes, ...) rebuilds the solid's geometry at once with the CT
#: colours of the previous solution's table and re-tabulates the CT in a timer right after
#: (:func:`refresh_solid_colours`). None: when Blender has a UI (in background mode -- scripts, the
#: CLI, tests -- the colours are made at once, as there is no event loop to run the timer).
DEFER_CT_COLOURS: bool | None = None

#: The studies whose solid waits for its CT colours: study id -> time of the last live change.
_COLOURS_PENDING: dict[str, float] = {}
_REFRESH_DELAY_S = 0.15   # a slider still moving within this time keeps postponing the refresh


def defer_ct_colours() -> bool:
    return (not bpy.app.background) if DEFER_CT_COLOURS is None else bool(DEFER_CT_COLOURS)


def colours_pending(coll) -> bool:
    return state.settings(coll).study_id in _COLOURS_PENDING


def step_solid(coll, live: bool = False) -> str:
    """Build or rebuild the solid; returns a notice for the sidebar ('' when the colours are exact).

    With ``live`` and :func:`defer_ct_colours`, a solid whose PDE solution has no CT table yet
    gets the previous table's colours now and the exact ones from :func:`refresh_solid_colours`.
    Without the CT (a file sent without it), the table stored in the .blend serves; when even
    that belongs to another PDE solution, the geometry still follows the surface and the notice
    says the colours are approximate.
    """
    s = state.settings(coll)
    head = Study.of(coll).solve()
    notice = ""
    table = Study.of(coll).current_ct_table()
    cache = state.cache_for(s.study_id)
    window = cache.window or cache.stored_window
    ct = None
    if table is None:
        if live and defer_ct_colours():
            previous = Study.of(coll).previous_ct_table()
            if previous is not None:
                table, window = previous
            _COLOURS_PENDING[s.study_id] = _now()
            _schedule_colour_refresh()
        else:
            try:
                ct = Study.of(coll).ct  # re-read after reopening: a solid without its CT colours is a loss
            except PDEHeadError as exc:
                previous = Study.of(coll).previous_ct_table()
                if previous is None:
                    raise
                table, window = previous
                notice = (f"the solid's CT colours are those of the previous PDE solution (the table saved in "
                          f"the file): {exc}").replace("; nothing was changed", "")
            if ct is not None:
                window = Study.of(coll).ct_window(ct)
                with state.Timer() as t:
                    table = Study.of(coll).ct_table(head, ct)
                Study.of(coll).record_timing("ct_table", t.seconds)   # issue 20: with the w-field <= 1 s
                _COLOURS_PENDING.pop(s.study_id, None)
    elif live and defer_ct_colours() and cache.ct is not None:
        # issue 21: while a slider moves, the cut faces come from the (u, v, w) table in 128-pixel tiles
        # (the geometry step stays within a frame); the timer right after redraws them from the CT itself
        _COLOURS_PENDING[s.study_id] = _now()
        _schedule_colour_refresh()
    else:
        _COLOURS_PENDING.pop(s.study_id, None)
    quick = live and defer_ct_colours()
    cut_ct = None
    if not quick and table is not None:        # the cut faces at the CT's own resolution (issue 21)
        cut_ct = ct if ct is not None else cache.ct
        if cut_ct is None:
            try:
                cut_ct = Study.of(coll).ct
            except PDEHeadError:
                cut_ct = None                  # a file sent without its CT: the table's resolution
    with state.Timer() as t:
        s.solid_object = objects.build_solid(
            head, coll, nu=s.nu, nv=s.nv, nw=s.nw, u_range=tuple(s.u_range), v_range=tuple(s.v_range),
            w_range=tuple(s.w_range), ct=None, obj=s.solid_object, name=f"{coll.name} Solid",
            window=window if table is not None else None, ct_table=table, texture_size=128 if quick else None,
            cut_ct=cut_ct, texture_budget=s.ct_texture_budget, skin=s.solid_skin, skin_depth_mm=s.solid_skin_depth)
    Study.of(coll).record_timing("solid", t.seconds)
    return notice


def _now() -> float:
    import time
    return time.monotonic()


def _schedule_colour_refresh() -> None:
    if not bpy.app.timers.is_registered(_colour_refresh_timer):
        bpy.app.timers.register(_colour_refresh_timer, first_interval=_REFRESH_DELAY_S)


def _colour_refresh_timer():
    """bpy.app.timers callback: the CT colours of every solid left waiting by a live change."""
    now = _now()
    if any(now - t < _REFRESH_DELAY_S for t in _COLOURS_PENDING.values()):
        return _REFRESH_DELAY_S  # still dragging: come back
    flush_colour_refresh()
    return None


def flush_colour_refresh() -> int:
    """Give every waiting solid its exact CT colours now (the timer, and before a save); returns the count."""
    count = 0
    for study_id in list(_COLOURS_PENDING):
        coll = next((c for c in state.studies() if state.settings(c).study_id == study_id), None)
        if coll is None:
            _COLOURS_PENDING.pop(study_id, None)
            continue
        refresh_solid_colours(coll)
        count += 1
    return count


def refresh_solid_colours(coll) -> None:
    """Tabulate the CT for the current PDE solution and rebuild the solid with its exact colours.

    What a live change deferred (:func:`step_solid` with ``live``); errors go to the sidebar.
    """
    s = state.settings(coll)
    _COLOURS_PENDING.pop(s.study_id, None)
    if s.solid_object is None:
        return
    try:
        s.last_error = step_solid(coll)
    except Exception as exc:  # noqa: BLE001 - runs from a timer: never raise into Blender
        if not isinstance(exc, PDEHeadError):
            traceback.print_exc()
        s.last_error = f"the solid's CT colours could not be updated: {exc}"[:500]


def volume_settings(s) -> dict:
    return dict(low_alpha=s.low_alpha, high_alpha=s.high_alpha, density=s.density,
                colour_preset=s.colour_preset, alpha_mode=s.alpha_mode)


def step_volume(coll, context=None) -> None:
    s = state.settings(coll)
    head = Study.of(coll).solve()
    cache = state.cache_for(s.study_id)
    # always with the CT (re-read after reopening): a volume without CT intensities is never built
    ct = Study.of(coll).ct
    window = Study.of(coll).ct_window(ct)
    if not s.use_ct_grid and s.voxel_auto:
        size = vdb_grids.auto_voxel_size(ct, head)
        with suspended_updates():
            s.voxel_size = size
    with state.Timer() as t:
        grid = ct if s.use_ct_grid else float(s.voxel_size)
        wfield = head.w_field(grid, ct=ct, progress=step_progress("volume"))
    Study.of(coll).record_timing("w_field", t.seconds)
    cache.wfield = wfield
    with state.Timer() as t:
        vdb_path = vdb_files.vdb_path_for(coll.name, bpy.data.filepath or None, prefs.vdb_prefs_folder(context))
        s.volume_object = volume.build_volume(wfield, coll, vdb_path, name=f"{coll.name} Volume",
                                              obj=s.volume_object, ct=ct, window=window, **volume_settings(s))
        s.volume_stale = False
    Study.of(coll).record_timing("volume", t.seconds)


STEP_FUNCTIONS = {
    "segment": step_segment,
    "boundaries": step_boundaries,
    "surface": step_surface,
    "solid": step_solid,
    "volume": step_volume,
}
Study.steps.update(STEP_FUNCTIONS)


# ------------------------------------------------------------------------------------------
# Live parameters (called by the update callbacks in props.py) and the cutter


def live_update(coll, what: str, context=None) -> None:
    """Rebuild the study's existing objects after a live parameter changed (no re-segmenting).

    Errors cannot be reported from an update callback: they go to ``settings.last_error``
    (shown in the sidebar) and the console.
    """
    s = state.settings(coll)
    notice = ""
    try:
        if what == "pde_auto":
            what = "pde"
            if Study.of(coll).boundary_set() is not None and not (s.smoothing_auto and s.approximation_auto):
                # start a manual slider from the automatic value (as a fraction of the study's range)
                smoothing, approximation = Study.of(coll).default_controls()
                with suspended_updates():
                    if not s.smoothing_auto and not s.is_property_set("smoothing"):
                        s.smoothing = smoothing
                    if not s.approximation_auto and not s.is_property_set("approximation"):
                        s.approximation = approximation
        if what == "cutter":
            if s.use_cutter and cutter.cutter_of(coll) is not None:
                apply_cutter(coll)
        elif what == "volume":
            if s.volume_object is not None:
                volume_material.set_volume_settings(s.volume_object, **volume_settings(s))
        else:
            if what == "pde" and s.volume_object is not None:
                s.volume_stale = True  # the w-field follows the PDE; rebuilt on request (heavy)
            if what in ("surface", "surface_solid", "pde") and s.surface_object is not None:
                step_surface(coll)
            if what in ("solid", "surface_solid", "pde") and s.solid_object is not None:
                notice = step_solid(coll, live=True)
        s.last_error = notice[:500]
    except Exception as exc:  # noqa: BLE001 - an update callback must never raise into the UI
        if not isinstance(exc, PDEHeadError):
            traceback.print_exc()
        s.last_error = str(exc)[:500]
        print(f"PDE Head: live update of {what} failed: {exc}")


def apply_cutter(coll, matrix=None) -> str:
    """Set the study's u/v ranges from its cutter and rebuild the solid; returns the cut's kind.

    ``matrix``: the cutter's world matrix to cut with (default its own; the frame handler passes
    the one the render's depsgraph evaluated)."""
    from mathutils import Matrix
    s = state.settings(coll)
    box = cutter.cutter_of(coll)
    if box is None:
        raise PDEHeadError(f"study '{coll.name}' has no cutter: add one first")
    matrix = box.matrix_world if matrix is None else matrix
    head = Study.of(coll).head
    # world metres = LPS mm * 0.001, so LPS mm -> cutter local = inverse(matrix_world) @ scale(0.001)
    inverse = np.array(matrix.inverted_safe() @ Matrix.Scale(0.001, 4))
    u_range, v_range, _kept, kind = cutter.cutter_ranges(head, inverse, float(box.empty_display_size))
    with suspended_updates():
        s.u_range, s.v_range = u_range, v_range
    state.cache_for(s.study_id).cutter_signature = cutter.signature(box, matrix)
    s.last_error = step_solid(coll, live=True)[:500] if s.solid_object is not None else ""
    return kind


def add_cutter(context, coll):
    """A cutter box for the study (the solid built first if needed), applied at once: (empty, cut kind)."""
    if state.settings(coll).solid_object is None:
        step_solid(coll)
    obj = cutter.add_cutter(context, coll)
    return obj, apply_cutter(coll)


_BUSY = [False]


@bpy.app.handlers.persistent
def pdehead_cutter_update(_scene, depsgraph=None) -> None:
    """After a depsgraph update: apply each study's cutter whose transform changed.

    Moving the cutter in the viewport, from Python or during playback applies it; an unchanged
    scene costs one comparison per study.
    """
    if _BUSY[0]:
        return
    _BUSY[0] = True
    try:
        for coll in state.studies():
            s = state.settings(coll)
            if not s.use_cutter:
                continue
            box = cutter.cutter_of(coll)
            if box is None:
                continue
            cache = state.cache_for(s.study_id)
            if cache.cutter_signature == cutter.signature(box):
                continue
            try:
                apply_cutter(coll)  # sets last_error ('' or a notice about the colours)
            except Exception as exc:  # noqa: BLE001 - a handler must not raise into Blender
                cache.cutter_signature = cutter.signature(box)  # do not retry every update
                if not isinstance(exc, PDEHeadError):
                    traceback.print_exc()
                s.last_error = f"cutter: {exc}"[:500]
    finally:
        _BUSY[0] = False


# ------------------------------------------------------------------------------------------
# The one-click pipeline and removing a study


def register() -> None:
    state.install_depsgraph_handler(pdehead_cutter_update)


def unregister() -> None:
    state.remove_depsgraph_handler(pdehead_cutter_update)
