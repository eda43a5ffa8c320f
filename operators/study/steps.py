"""The pipeline steps of a study, as methods of :class:`.entity.Study` (this module's mixin).

Between the thin operators (:mod:`operators.ui.ops`, :mod:`operators.ui.forensic_ops`, the update callbacks of
:mod:`.props`) and the engine (:mod:`pdehead_addon`): every step reads the study's settings, calls the
engine's public API, writes the result into Blender objects (:mod:`operators.scene.objects`,
:mod:`operators.volume.volume`, :mod:`operators.scene.scene`) and returns what it did as a value
(:class:`operators.outcome.StepOutcome`, :class:`operators.outcome.BoundaryOutcome`) for the caller to report.
The live updates, the solid and the cutter: :mod:`.live`. Nothing here imports an operator module or the Study
class itself, so the dependency runs one way::

    ui.ops / ui.forensic_ops / ui.panel / props  ->  entity (Study)  ->  steps / live
        ->  state / objects / ...  ->  engine

Use the steps through a study: ``study = Study.import_ct(context, path, options)``,
``study.segment()``, ``study.boundaries()``, ``study.surface()``, ``study.solid()``, ``study.volume(context)``.
"""
from __future__ import annotations

import json
import re
import time
import warnings
from pathlib import Path

import bpy
import numpy as np

from ...pdehead_addon import (
    PDEHeadError,
    SelectionWarning,
    check_bone_level,
    check_head_scan,
    extract_boundaries,
    load_ct,
    make_phantom,
    patches_for_scan,
    segment_head,
)
from .. import prefs, state
from ..outcome import BoundaryOutcome, StepOutcome
from ..scene import detail_map, objects
from ..state import suspended_updates
from ..volume import vdb_files, vdb_grids, volume
from .progress import step_progress


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


def _ct_description(ct) -> tuple[dict, list[str]]:
    """The study settings that describe ``ct`` (dimensions, spacing, value range, series, modality)
    and the loader's warnings."""
    meta = ct.meta or {}
    nz, ny, nx = ct.shape
    hu = meta.get("hu_range") or meta.get("value_range")
    if hu is None:
        hu = (float(np.min(ct.data)), float(np.max(ct.data)))
    series = meta.get("series_description") or meta.get("series") or ""
    if not series and meta.get("series_number") not in (None, ""):
        series = f"#{meta['series_number']}"
    if meta.get("series_uid"):
        series = f"{series} ({meta['series_uid']})" if series else str(meta["series_uid"])
    values = dict(dimensions=(nx, ny, nz), spacing=tuple(float(s) for s in ct.spacing),
                  value_range=(float(hu[0]), float(hu[1])), series=str(series)[:200],
                  modality=str(meta.get("modality") or meta.get("units") or "")[:40])
    warnings = meta.get("warnings") or []
    return values, [warnings] if isinstance(warnings, str) else list(warnings)


def _selection_tolerance(s) -> dict:
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


class PipelineSteps:
    """Mixin of :class:`.entity.Study`: a new study (import, phantom) and the pipeline steps."""

    # --- a new study --------------------------------------------------------------------------

    @classmethod
    def create(cls, context, ct, name: str, source_kind: str, source: str = "", options: dict | None = None):
        """A new study (collection) holding ``ct`` (in memory) and its description; made active."""
        scene = context.scene
        coll = objects.study_collection(_unique_collection_name(name), scene)
        s = state.settings(coll) or state.new_settings_object(coll)
        scene.render.use_lock_interface = True  # the frame handler may rebuild meshes while rendering
        described, warnings = _ct_description(ct)
        with suspended_updates():
            s.is_study = True
            s.study_id = state.new_study_id()
            s.source_kind = source_kind
            s.source = source
            s.source_absolute = str(Path(source).resolve()) if source else ""
            s.load_options = json.dumps(options or {}, default=list)
            s.patches = prefs.default_patches(context)
            for key, value in described.items():
                setattr(s, key, value)
            s.warnings = s.notes = ""
        study = cls.of(coll)
        study.add_warnings(warnings)
        study.cache.ct = ct
        scene.pdehead.active_study = coll
        return study

    @classmethod
    def import_ct(cls, context, path: Path, options: dict):
        """Load a CT from disk into a new study."""
        with state.Timer() as t, warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ct = load_ct(path, **options)
            check_head_scan(ct)                 # portraits, noise: refused before a study is made
        study = cls.create(context, ct, _study_name(ct, path), "FILES", str(path), options)
        # the loader's warnings (single slice, uneven steps, ...) stay visible in the Study panel
        study.add_warnings([str(w.message) for w in caught if issubclass(w.category, UserWarning)])
        study.add_notes(ct.meta.get("info", []))    # the automatic choices: shown as information
        study.settings.timings_json = ""
        study.record_timing("import", t.seconds)
        return study

    @classmethod
    def phantom(cls, context):
        """The built-in synthetic head as a new study."""
        with state.Timer() as t:
            phantom = make_phantom()
        study = cls.create(context, phantom.ct, "Phantom", "PHANTOM")
        study.settings.timings_json = ""
        study.record_timing("import", t.seconds)
        return study

    # --- the steps ----------------------------------------------------------------------------

    def segment(self) -> StepOutcome:
        """Segment the head from the CT (Chan-Vese and clean-up); the study keeps the segmentation. Returns
        the head's fraction of the voxels, the iterations and the two region means (``values``)."""
        warnings_before = self.warnings
        call = self.segment_call()
        with state.Timer() as t:
            seg = call(step_progress("segment"))
        self.keep_segmentation(seg, t.seconds)
        s = self.settings
        return StepOutcome("segment", warnings=tuple(self.warnings[len(warnings_before):]), seconds=t.seconds,
                           values=dict(fraction=s.seg_fraction, iterations=s.seg_iterations, c1=s.seg_c1,
                                       c2=s.seg_c2))

    def segment_call(self):
        """The segmentation's engine call, ``call(progress) -> Segmentation``: it touches no Blender data,
        so the modal pipeline runs it on a worker thread (:class:`.progress.EngineJob`)."""
        ct = self.ct
        if self.settings.use_bone_level and ct.meta.get("format") != "mesh":
            check_bone_level(ct, self.settings.bone_level)    # a level above the scan's bone: refused now
        return lambda progress: segment_head(ct, progress=progress)

    def keep_segmentation(self, seg, seconds: float) -> None:
        """Keep the segmentation :meth:`segment_call` made (on the main thread)."""
        s = self.settings
        cache = self.cache
        cache.drop_from("seg")
        cache.seg = seg
        with suspended_updates():
            s.seg_fraction = float(seg.mask.mean())
            s.seg_iterations = int(seg.iterations)
            s.seg_c1, s.seg_c2 = float(seg.c1), float(seg.c2)
            # head size outside the human range, shoulders cut off: shown with the loader's warnings
            self.add_warnings(seg.meta.get("warnings", []))
        self.record_timing("segment", seconds)

    def boundaries(self) -> BoundaryOutcome:
        """Extract the boundary curves (segmenting first when needed), store them in the .blend and
        build the curves object; returns the effective t, the curves, the new warnings and the seconds."""
        if self.cache.seg is None:
            self.segment()
        warnings_before = self.warnings
        call = self.boundaries_call()
        with state.Timer() as t:
            found = call(step_progress("boundaries"))
        self.keep_boundaries(found, t.seconds)
        s = self.settings
        return BoundaryOutcome(patches=s.patches, curves=s.curve_count,
                               warnings=tuple(self.warnings[len(warnings_before):]), seconds=t.seconds)

    def boundaries_call(self):
        """The boundary curves' engine call, ``call(progress) -> (BoundarySet, warnings)``, for the study's
        segmentation (which must exist): no Blender data inside, so the modal pipeline runs it on a worker
        thread (:class:`.progress.EngineJob`). A patch count the scan cannot give is corrected here."""
        s = self.settings
        seg = self.cache.seg
        tolerance = _selection_tolerance(s)
        if tolerance and not s.align_curves:
            raise PDEHeadError("a tolerance chooses the curves automatically, which needs Align Curves")
        patches, message = (s.patches, None) if tolerance else patches_for_scan(seg, s.patches)
        if message:  # short scans (e.g. the tilted GE slab) cannot give 3t+1 slices
            with suspended_updates():
                s.patches = patches
            self.add_warnings([message])
        options = dict(patches=s.patches, samples=s.samples, selection="auto" if tolerance else s.selection,
                       parameterisation="angular" if s.align_curves else "arc-length", **tolerance)

        def call(progress):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", SelectionWarning)
                bset = extract_boundaries(seg, progress=progress, **options)
            # the tolerance could not be met with every usable slice: said beside the other warnings
            return bset, [str(w.message) for w in caught if issubclass(w.category, SelectionWarning)]
        return call

    def keep_boundaries(self, found, seconds: float) -> None:
        """Store the curves :meth:`boundaries_call` found in the .blend and build the curves object (on the
        main thread)."""
        bset, selection_warnings = found
        s = self.settings
        cache = self.cache
        self.add_warnings(selection_warnings)
        self.store_boundaries(bset)
        cache.drop_from("bset")
        cache.bset = bset
        with suspended_updates():
            _record_selection(s, bset)
        coll = self.collection
        s.curves_object = objects.build_boundary_curves(bset, coll, name=f"{coll.name} Boundary curves",
                                                        obj=s.curves_object)
        self.record_timing("boundaries", seconds)

    def surface(self) -> StepOutcome:
        """Build or rebuild the PDE surface (solving the PDE when its controls changed); returns the surface
        object, its vertex count (``values["vertices"]``) and the seconds of the build."""
        s = self.settings
        head = self.solve()
        coll = self.collection
        with state.Timer() as t:
            s.surface_object = objects.build_surface(head, coll, nu=s.nu, nv=s.nv, caps=s.caps,
                                                     obj=s.surface_object, name=f"{coll.name} Surface")
        self.record_timing("surface", t.seconds)
        return StepOutcome("surface", objects=(s.surface_object,), seconds=t.seconds,
                           values=dict(vertices=len(s.surface_object.data.vertices)))

    def detail_map(self) -> StepOutcome:
        """Build the surface's CT detail map (eyelids, lips and nose wings as bump shading; the
        segmentation is re-run when this session has none, e.g. after reopening the file). Returns the
        surface object, the seconds and the map's size in pixels (``values``: ``resolution``)."""
        progress = step_progress("detail_map")
        for fraction, message in self.detail_map_stages():
            if progress is not None:
                progress(fraction, message)
        return self.detail_outcome()

    def detail_outcome(self) -> StepOutcome:
        """What the last CT detail map build gave (:meth:`detail_map`, or the modal operator's stages)."""
        s = self.settings
        return StepOutcome("detail_map", objects=(s.surface_object,), seconds=self.timings["detail_map"],
                           values=dict(resolution=int(s.detail_resolution)))

    def detail_map_stages(self):
        """:meth:`detail_map` one stage at a time (a generator yielding ``(fraction, message)``): the map, its
        material and ``detail_stale`` change only after the last stage, so stopping early keeps the old map.
        The timing recorded is the stages' own time, not the pauses between them."""
        s = self.settings
        if s.surface_object is None:
            raise PDEHeadError("Build the surface first")
        busy = 0.0
        with state.Timer() as t:
            if self.cache.seg is None:
                self.segment()
            head = self.solve()
        busy += t.seconds
        stages = detail_map.detail_map_stages(s.surface_object, head, self.cache.seg, s.detail_resolution,
                                              s.detail_strength, s.use_detail_map)
        while True:
            start = time.perf_counter()
            try:
                step = next(stages)
            except StopIteration:
                break
            finally:
                busy += time.perf_counter() - start
            yield step
        with suspended_updates():
            s.detail_stale = False
        self.record_timing("detail_map", busy)

    def detail_shading(self) -> None:
        """The sidebar's CT Detail toggle and strength: the bump plugged in or out. Never builds the map (an
        update callback must not block for seconds): without a current map the Surface panel shows
        *Build CT Detail*."""
        s = self.settings
        obj = s.surface_object
        if obj is not None:
            detail_map.set_detail_shading(obj, s.detail_strength, s.use_detail_map and not s.detail_stale)

    def detail_map_current(self) -> bool:
        """Whether the surface has a CT detail map that matches it (built, and no PDE change since)."""
        s = self.settings
        return s.surface_object is not None and detail_map.detail_image(s.surface_object) is not None \
            and not s.detail_stale

    def volume_settings(self) -> dict:
        """The volume material's settings (eq. 24 alphas, density, colour, alpha mode)."""
        s = self.settings
        return dict(low_alpha=s.low_alpha, high_alpha=s.high_alpha, density=s.density,
                    colour_preset=s.colour_preset, alpha_mode=s.alpha_mode)

    def volume(self, context=None) -> StepOutcome:
        """Sample w on a voxel grid, write it with the CT as a .vdb and build the Volume object; returns the
        Volume object, the seconds of both (``values``: ``w_field_s``, ``volume_s``; ``seconds``: their sum),
        the voxel size used (mm; None on the CT's own grid) and the .vdb file."""
        s = self.settings
        head = self.solve()
        # always with the CT (re-read after reopening): a volume without CT intensities is never built
        ct = self.ct
        window = self.ct_window(ct)
        if not s.use_ct_grid and s.voxel_auto:
            size = vdb_grids.auto_voxel_size(ct, head)
            with suspended_updates():
                s.voxel_size = size
        with state.Timer() as t:
            grid = ct if s.use_ct_grid else float(s.voxel_size)
            wfield = head.w_field(grid, ct=ct, progress=step_progress("volume"))
        self.record_timing("w_field", t.seconds)
        w_field_s = t.seconds
        self.cache.wfield = wfield
        coll = self.collection
        with state.Timer() as t:
            vdb_path = vdb_files.vdb_path_for(coll.name, bpy.data.filepath or None, prefs.vdb_prefs_folder(context))
            new = s.volume_object is None
            s.volume_object = volume.build_volume(wfield, coll, vdb_path, name=f"{coll.name} Volume",
                                                  obj=s.volume_object, ct=ct, window=window, **self.volume_settings())
            if new:      # out of F12 until the user shows it (Frame Study > Volume, or the camera icon)
                s.volume_object.hide_render = True
            s.volume_stale = False
        self.record_timing("volume", t.seconds)
        return StepOutcome("volume", objects=(s.volume_object,), seconds=w_field_s + t.seconds,
                           values=dict(w_field_s=w_field_s, volume_s=t.seconds, vdb_path=vdb_path,
                                       voxel_size=None if s.use_ct_grid else float(s.voxel_size)))

    def run_step(self, name: str, context=None) -> None:
        """Run one pipeline step by name: "segment", "boundaries", "surface", "solid" or "volume"."""
        if name == "volume":
            self.volume(context)
        elif name in ("segment", "boundaries", "surface", "solid"):
            getattr(self, name)()
            if name == "surface" and self.settings.use_detail_map:
                self.detail_map()
        else:
            raise ValueError(f"no pipeline step '{name}'")
