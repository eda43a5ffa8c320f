"""The one-click pipeline run, step by step, and the undo of a failed or cancelled step or run.

:class:`Rollback` removes every datablock created since it was made (each operator's guard,
:func:`operators.ui.base.guarded`, and the run use it); :class:`StudySnapshot` keeps a study's settings, stored
curves and in-memory results before a run to put back on cancel; :class:`PipelineRun` runs the
steps of a :class:`.entity.Study` one at a time (the modal operator: one per timer tick).
"""
from __future__ import annotations

import copy
from pathlib import Path

import bpy

from ...pdehead_addon import PDEHeadError
from .. import state
from ..scene import detail_map, objects, scene
from ..state import suspended_updates
from .entity import Study
from .progress import EngineJob

STEP_LABELS = {
    "import": "Import CT",
    "segment": "Segmentation",
    "boundaries": "Boundary curves",
    "surface": "PDE surface",
    "solid": "PDE solid",
    "volume": "Volume",
    "scene": "Camera and light",
}


# Undo of a failed/cancelled step: remove every datablock created since the snapshot


_ROLLBACK_KINDS = ("objects", "collections", "meshes", "curves", "volumes", "materials", "node_groups",
                   "images", "texts", "cameras", "lights")


class Rollback:
    """Snapshot of the datablocks; :meth:`undo` removes all created after it."""

    def __init__(self):
        self.before = {kind: {id_.as_pointer() for id_ in getattr(bpy.data, kind)} for kind in _ROLLBACK_KINDS}
        self.study_ids = set(state.cached_study_ids())

    def created(self, kind: str) -> list:
        return [id_ for id_ in getattr(bpy.data, kind) if id_.as_pointer() not in self.before[kind]]

    def undo(self) -> None:
        for coll in self.created("collections"):
            if state.is_study(coll):
                state.drop_cache(state.settings(coll).study_id)
        for kind in _ROLLBACK_KINDS:  # objects first, then their data
            for id_ in self.created(kind):
                try:
                    getattr(bpy.data, kind).remove(id_)
                except (ReferenceError, RuntimeError):
                    pass
        for study_id in set(state.cached_study_ids()) - self.study_ids:
            state.drop_cache(study_id)


class StudySnapshot:
    """A study's settings, stored curves and in-memory results before a run, to put back on cancel.

    Objects the run created are removed by :class:`Rollback`; objects it rebuilt in place
    (curves, surface, solid) are rebuilt again from the restored state.
    """

    def __init__(self, study: Study):
        s = study.settings
        coll = study.collection
        self.collection_name = coll.name
        self.study_id = s.study_id
        self.values = {}
        for prop in s.bl_rna.properties:
            if prop.identifier == "rna_type" or prop.is_readonly or prop.type in ("POINTER", "COLLECTION"):
                continue
            value = getattr(s, prop.identifier)
            self.values[prop.identifier] = tuple(value) if getattr(prop, "is_array", False) else value
        self.boundaries = coll.get(state.BOUNDARY_KEY)
        self.cache = copy.copy(study.cache)
        self.detail = detail_map.packed_state(s.surface_object)      # the surface's CT detail map (~1 MB)

    def restore(self, rebuilt: set) -> None:
        coll = bpy.data.collections.get(self.collection_name)
        if coll is None:
            return
        study = Study.of(coll)
        s = study.settings
        with suspended_updates():
            for name, value in self.values.items():
                now = getattr(s, name)
                if (tuple(now) if isinstance(value, tuple) else now) == value:
                    continue  # unchanged: not even marked as set (continuity, smoothing read is_property_set)
                try:
                    setattr(s, name, value)
                except (AttributeError, TypeError, ValueError):
                    pass
        if self.boundaries is None:
            coll.pop(state.BOUNDARY_KEY, None)
        else:
            coll[state.BOUNDARY_KEY] = self.boundaries
        state.restore_cache(self.study_id, copy.copy(self.cache))
        bset = study.boundary_set() if "boundaries" in rebuilt else None
        if s.curves_object is not None and bset is not None:
            objects.build_boundary_curves(bset, coll, name=s.curves_object.name,
                                          obj=s.curves_object)
        if rebuilt & {"boundaries", "surface"} and s.surface_object is not None:
            study.surface()
            detail_map.restore_packed(s.surface_object, self.detail)
            detail_map.set_detail_shading(s.surface_object, s.detail_strength, s.use_detail_map and not s.detail_stale)
        if rebuilt & {"boundaries", "surface", "solid"} and s.solid_object is not None:
            study.solid()


class PipelineRun:
    """One run of the pipeline, step by step; :meth:`cancel` removes everything it created.

    Parameters
    ----------
    context : bpy.types.Context
    source : "ACTIVE" | "PHANTOM" | "FILES"
    path, options : the input and loader options when ``source == "FILES"``
    settings : study settings to apply before running (patches, nu, ...)
    study : collection name of the study for "ACTIVE" ("" = active)
    volume : also build the volume
    """

    def __init__(self, context, source: str, path: Path | None = None, options: dict | None = None,
                 settings: dict | None = None, study: str = "", volume: bool = True):
        self.context = context
        self.source = source
        self.path, self.options = path, options or {}
        self.settings = settings or {}
        self.study_name = study
        self.collection_name: str | None = None
        self.steps = (["import"] if source in ("PHANTOM", "FILES") else []) + \
            ["segment", "boundaries", "surface", "solid"] + (["volume"] if volume else []) + ["scene"]
        self.index = 0
        self.started: set[str] = set()
        self.rollback = Rollback()
        if source == "ACTIVE":
            active = Study.active(context, study)
            if active is None:
                raise PDEHeadError("No PDE Head study to run on: import a CT or load the phantom first")
            self.snapshot = StudySnapshot(active)
            self.collection_name = active.name
            self._apply_settings(active)
            active.settings.timings_json = ""

    snapshot: StudySnapshot | None = None

    @property
    def collection(self):
        return bpy.data.collections.get(self.collection_name) if self.collection_name else None

    @property
    def study(self) -> Study | None:
        """The study the run works on (None before the import step of a new one)."""
        coll = self.collection
        return Study.of(coll) if coll is not None else None

    @property
    def done(self) -> bool:
        return self.index >= len(self.steps)

    @property
    def next_label(self) -> str:
        return STEP_LABELS[self.steps[self.index]] if not self.done else "done"

    def _apply_settings(self, study: Study) -> None:
        s = study.settings
        with suspended_updates():
            for name, value in self.settings.items():
                setattr(s, name, value)

    #: Steps whose engine call the modal run puts on a worker thread (:meth:`step` with ``on_thread``),
    #: so that Esc stops them within a progress report: the two that take seconds on a clinical scan.
    THREADED_STEPS = ("segment", "boundaries")
    job = None  # the running :class:`.progress.EngineJob` of a threaded step

    def step(self, on_thread: bool = False) -> bool:
        """Run the next step; True when the pipeline is complete.

        With ``on_thread`` (the modal operator, one call per timer tick) a step of :attr:`THREADED_STEPS`
        starts its engine call on a worker thread and returns at once; later calls return False while it
        runs, and the call after it ended keeps its result (on the main thread) and moves on."""
        name = self.steps[self.index]
        self.started.add(name)
        if self.job is not None:
            if not self.job.done:
                return False
            job, self.job = self.job, None
            result = job.finish()
            study = self.study
            if name == "segment":
                study.keep_segmentation(result, job.seconds)
            else:
                study.keep_boundaries(result, job.seconds)
        elif on_thread and name in self.THREADED_STEPS and not (name == "boundaries" and self.study.cache.seg is None):
            study = self.study
            self.job = EngineJob(study.segment_call() if name == "segment" else study.boundaries_call())
            return False
        elif name == "import":
            if self.source == "PHANTOM":
                study = Study.phantom(self.context)
            else:
                study = Study.import_ct(self.context, self.path, self.options)
            self.collection_name = study.name
            self._apply_settings(study)
        elif name == "scene":
            coll = self.collection
            # a new study, or one never framed: camera, light, the surface shown, the startup cube hidden
            if self.source != "ACTIVE" or scene.study_object(coll, scene.CAMERA_KIND) is None:
                scene.frame_study(self.context, coll)
        else:
            self.study.run_step(name, self.context)
        self.index += 1
        return self.done

    def run_all(self) -> None:
        while not self.done:
            self.step()

    def cancel(self) -> None:
        """Remove every object, collection and datablock this run created; a study the run worked on
        gets its settings, curves and meshes back as they were before the run."""
        if self.job is not None:  # a step on its worker thread stops at its next progress report
            self.job.cancel()
            self.job = None
        self.rollback.undo()
        if self.snapshot is not None:
            self.snapshot.restore(self.started)
        self.index = len(self.steps)
