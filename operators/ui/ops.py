"""All ``pdehead.*`` operators of the pipeline: import, the steps, the one-click pipeline.

Thin: an operator reads its properties, calls the study (:class:`operators.study.entity.Study`'s steps) and
reports, in its ``run``; the one ``execute`` (fetch the study or cancel, run, report any failure
and undo what the step created) is :mod:`.base`'s. Defaults and ranges come from
``pdehead_addon/defaults.py``.
"""
from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty
from bpy.types import Operator

from ...pdehead_addon import PDEHeadError, defaults as D
from .. import state
from ..scene import scene
from ..study import animation, pipeline_run, progress, props
from ..study.entity import Study
from .base import GuardedOperator, StudyOperator, report_exception, set_status
from .import_options import LoaderOptions, PDEHEAD_FH_import_ct, dropped_file_options


class PDEHEAD_OT_import_ct(Operator, GuardedOperator, LoaderOptions):
    """Import head CT slices (DICOM series, numbered TIFF/PNG images or headerless raw) as a PDE Head study"""

    bl_idname = "pdehead.import_ct"
    bl_label = "Import CT Head"
    bl_description = ("Import head CT slices (DICOM series, numbered TIFF/PNG images or headerless raw) "
                      "as a new PDE Head study collection")
    bl_options = {'REGISTER', 'UNDO'}

    run_pipeline: BoolProperty(name=D.RUN_PIPELINE.label, **D.RUN_PIPELINE.limits(),
                               description=D.RUN_PIPELINE.description)

    def invoke(self, context, event):
        if self.directory and len(self.files):  # dropped on the 3D View (PDEHEAD_FH_import_ct)
            for name, value in dropped_file_options(self.directory, [f.name for f in self.files]).items():
                setattr(self, name, value)
            return context.window_manager.invoke_props_dialog(self, width=420)
        context.window_manager.fileselect_add(self)
        return {'RUNNING_MODAL'}

    def draw(self, context):
        if self.directory and len(self.files):  # what was dropped
            self.layout.label(text=self.filepath if self.single_file else self.directory, icon='FILE_FOLDER')
        self.draw_loader_options(self.layout)
        self.layout.prop(self, "run_pipeline")

    def run(self, context):
        path = self.input_path()
        study = Study.import_ct(context, path, self.loader_options())
        self.apply_study_options(study.collection)
        if self.run_pipeline:
            for step in ("segment", "boundaries", "surface", "solid"):
                study.run_step(step)
            scene.frame_study(context, study.collection)  # ends as Run Pipeline does: camera, light, cube hidden
        self.report({'INFO'}, import_report(study))
        for warning in study.warnings:  # one report per warning, in the dialog's words
            self.report({'WARNING'}, state.user_text(warning))


def import_report(study) -> str:
    """The Import CT Head operator's INFO report of the study ``Study.import_ct`` made (the CLI prints it too)."""
    nx, ny, nz = study.settings.dimensions
    return (f"Imported '{study.name}': {nx}x{ny}x{nz} voxels, spacing "
            f"{', '.join(f'{v:g}' for v in study.settings.spacing)} mm")


def phantom_report(study) -> str:
    """The Load Phantom operator's INFO report of the study ``Study.phantom`` made."""
    nx, ny, nz = study.settings.dimensions
    return f"Phantom loaded: {nx}x{ny}x{nz} voxels"


def detail_report(study, outcome) -> str:
    """The Build CT Detail operator's INFO report of ``study.detail_map()``'s outcome."""
    return f"CT detail map of '{study.name}': {outcome.values['resolution']} px ({outcome.seconds:.2f} s)"


def turntable_report(study, pivot, frames: int) -> str:
    """The Turntable operator's INFO report of the pivot :func:`operators.study.animation.turntable` made."""
    return f"'{study.name}': turntable of {frames} frames around '{pivot.name}' (Render > Render Animation)"


def segment_report(study, outcome) -> str:
    """The Segment Head operator's INFO report of ``study.segment()``'s outcome (the CLI prints it too)."""
    v = outcome.values
    return (f"Segmented '{study.name}': head = {100 * v['fraction']:.1f} % of the voxels ({v['iterations']} "
            f"iterations, {outcome.seconds:.2f} s)")


def boundaries_report(study, outcome) -> str:
    """The Extract Boundaries operator's INFO report of ``study.boundaries()``'s outcome."""
    s = study.settings
    achieved = (f"; surface from all {abs(s.outline_candidates)} usable outlines: mean "
                f"{s.outline_mean_mm:.2f} mm, max {s.outline_max_mm:.2f} mm" if s.outline_candidates else "")
    return (f"{outcome.curves} boundary curves of {s.samples} points extracted from '{study.name}' "
            f"({outcome.seconds:.2f} s){achieved}")


def surface_report(study, outcome) -> str:
    """The Reconstruct Surface operator's INFO report of ``study.surface()``'s outcome."""
    return f"PDE surface of '{study.name}': {outcome.values['vertices']} vertices ({outcome.seconds:.2f} s)"


def solid_report(study, outcome) -> str:
    """The Build Solid operator's INFO report of ``study.solid()``'s outcome."""
    return f"PDE solid of '{study.name}': {outcome.values['vertices']} vertices ({study.timings['solid']:.2f} s)"


def volume_report(study, outcome) -> str:
    """The Build Volume operator's INFO report of ``study.volume()``'s outcome."""
    t = outcome.values
    return (f"Volume of '{study.name}' built (w-field {t['w_field_s']:.2f} s, VDB + material "
            f"{t['volume_s']:.2f} s)")


class PDEHEAD_OT_load_phantom(Operator, GuardedOperator):
    bl_idname = "pdehead.load_phantom"
    bl_label = "Load Phantom"
    bl_description = "Create a study from the built-in synthetic head CT (try PDE Head without data)"
    bl_options = {'REGISTER', 'UNDO'}

    def run(self, context):
        self.report({'INFO'}, phantom_report(Study.phantom(context)))


class PDEHEAD_OT_segment(Operator, StudyOperator):
    bl_idname = "pdehead.segment"
    bl_label = "Segment Head"
    bl_description = "Segment the head from the CT with the 3D Chan-Vese soft model (eq. 16-21) and clean-up"
    bl_options = {'REGISTER', 'UNDO'}

    def run(self, context, study):
        self.report({'INFO'}, segment_report(study, study.segment()))


@props.settings_options("patches", "samples", "selection", "align_curves", "use_tolerance", "tolerance_mm",
                        "max_tolerance_mm")
class PDEHEAD_OT_extract_boundaries(Operator, StudyOperator):
    bl_idname = "pdehead.extract_boundaries"
    bl_label = "Extract Boundaries"
    bl_description = "Extract the 3t+1 boundary curves (eq. 22) of t PDE patches from the segmentation"
    bl_options = {'REGISTER', 'UNDO'}

    def run(self, context, study):
        s = study.settings
        self.store_settings(s)
        outcome = study.boundaries()
        self.patches = outcome.patches  # may have been reduced to what the scan allows
        self.report({'INFO'}, boundaries_report(study, outcome))
        for warning in outcome.warnings:
            self.report({'WARNING'}, state.user_text(warning))


@props.settings_options("nu", "nv", "caps", "continuity", "dome", "smoothing_auto", "smoothing", "approximation_auto",
                        "approximation", "modes")
class PDEHEAD_OT_reconstruct_surface(Operator, StudyOperator):
    bl_idname = "pdehead.reconstruct_surface"
    bl_label = "Reconstruct Surface"
    bl_description = "Solve the Bloor-Wilson PDEs (eq. 1-13) on the boundary curves and build the head surface"
    bl_options = {'REGISTER', 'UNDO'}

    def run(self, context, study):
        s = study.settings
        self.store_settings(s)
        if study.boundary_set() is None:
            study.boundaries()
        self.report({'INFO'}, surface_report(study, study.surface()))


@props.settings_options("nu", "nv", "nw", "u_range", "v_range", "w_range", "ct_texture_budget", "solid_skin",
                        "solid_skin_depth")
class PDEHEAD_OT_build_solid(Operator, StudyOperator):
    bl_idname = "pdehead.build_solid"
    bl_label = "Build Solid"
    bl_description = "Build the PDE solid (eq. 23): the head sampled in u, v and w from the spine to the surface"
    bl_options = {'REGISTER', 'UNDO'}

    def run(self, context, study):
        s = study.settings
        for name, lo_hi in (("u", self.u_range), ("v", self.v_range), ("w", self.w_range)):
            if lo_hi[0] >= lo_hi[1]:
                raise PDEHeadError(f"{name} range must have its start below its end, got "
                                   f"{lo_hi[0]:g}..{lo_hi[1]:g}")
        self.store_settings(s)
        if study.boundary_set() is None:
            study.boundaries()
        outcome = study.solid()
        self.report({'INFO'}, solid_report(study, outcome))
        if outcome.values["notice"]:
            self.report({'WARNING'}, outcome.values["notice"][:300])


@props.settings_options("use_ct_grid", "voxel_auto", "voxel_size", "low_alpha", "high_alpha", "density",
                        "colour_preset", "alpha_mode")
class PDEHEAD_OT_build_volume(Operator, StudyOperator):
    bl_idname = "pdehead.build_volume"
    bl_label = "Build Volume"
    bl_description = ("Sample the PDE solid's w on a voxel grid, write it with the CT intensities as a .vdb "
                      "and render it as a volume with eq. 24 opacity")
    bl_options = {'REGISTER', 'UNDO'}

    def run(self, context, study):
        s = study.settings
        if self.properties.is_property_set("voxel_size") and not self.properties.is_property_set("voxel_auto"):
            self.voxel_auto = False  # a size given by the caller is meant
        self.store_settings(s)
        if study.boundary_set() is None:
            study.boundaries()
        self.report({'INFO'}, volume_report(study, study.volume(context)))


class TimerModal:
    """Mixin: a modal operator that does one stage of its work per timer tick, with the progress
    indicator and the status bar meanwhile (Esc is seen between two ticks)."""

    def start_ui(self, context, total: int, text: str) -> None:
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.progress_begin(0, total)
        set_status(context, text)
        wm.modal_handler_add(self)

    #: The warning Esc reports.
    cancelled_message = "PDE Head: cancelled"

    def tick(self, context) -> bool:
        """One stage; True when the work is done."""
        raise NotImplementedError(type(self).__name__)

    def finished(self) -> None:
        """Report what was done."""

    def modal(self, context, event):
        if event.type == 'ESC':
            self.cancel(context)
            self.report({'WARNING'}, self.cancelled_message)
            return {'CANCELLED'}
        if event.type != 'TIMER':
            return {'PASS_THROUGH'}
        try:
            done = self.tick(context)
        except Exception as exc:  # noqa: BLE001
            self.cancel(context)
            report_exception(self, exc)
            return {'CANCELLED'}
        if done:
            self._end_ui(context)
            self.finished()
            return {'FINISHED'}
        return {'RUNNING_MODAL'}

    def _end_ui(self, context) -> None:
        progress.set_hook(None)
        wm = context.window_manager
        timer = getattr(self, "_timer", None)
        if timer is not None and wm is not None:
            wm.event_timer_remove(timer)
            self._timer = None
        if wm is not None:
            wm.progress_end()
        set_status(context, None)


class PDEHEAD_OT_build_detail_map(Operator, StudyOperator, TimerModal):
    bl_idname = "pdehead.build_detail_map"
    bl_label = "Build CT Detail"
    bl_description = ("Build (or rebuild) the surface's CT detail map: the CT's fine relief (eyelids, lips, nose "
                      "wings) as a bump map in the surface's UVs (seconds; Esc cancels and keeps the old map; the "
                      "geometry stays the smooth PDE surface)")
    bl_options = {'REGISTER', 'UNDO'}

    def run(self, context, study):
        """Synchronous (scripts, headless, redo)."""
        self.report({'INFO'}, detail_report(study, study.detail_map()))

    def invoke(self, context, event):
        """With a UI: one stage per timer tick (:meth:`.Study.detail_map_stages`), the progress indicator
        between them, Esc cancels with the old map kept."""
        if context.window is None:
            return self.execute(context)
        study = Study.active(context, self.study)
        try:
            if study is None:
                raise PDEHeadError("No PDE Head study: import a CT first")
            self._study, self._stages = study, study.detail_map_stages()
        except Exception as exc:  # noqa: BLE001
            report_exception(self, exc)
            return {'CANCELLED'}
        self.start_ui(context, 1, f"PDE Head: {self.bl_label}... (Esc to cancel)")
        return {'RUNNING_MODAL'}

    cancelled_message = "PDE Head: CT detail cancelled; the old map is kept"

    def tick(self, context) -> bool:
        try:
            fraction, message = next(self._stages)
        except StopIteration:
            return True
        context.window_manager.progress_update(fraction)
        set_status(context, f"PDE Head: CT detail: {message}... (Esc to cancel)")
        return False

    def finished(self) -> None:
        self.report({'INFO'}, detail_report(self._study, self._study.detail_outcome()))

    def cancel(self, context):
        """Esc, an error or Blender closing the operator: the stages stop before anything is written."""
        stages = getattr(self, "_stages", None)
        if stages is not None:
            stages.close()
        self._end_ui(context)


# ------------------------------------------------------------------------------------------
# The one-click pipeline: synchronous from scripts, modal (one step per timer tick, Esc cancels) from the UI

SOURCE_ITEMS = [
    ("AUTO", "Auto", "The given file/folder if any, else the active study"),
    ("ACTIVE", "Active Study", "Re-run every step on the active study's CT"),
    ("PHANTOM", "Phantom", "A new study from the built-in synthetic head"),
    ("FILES", "Files", "A new study from the given file or folder"),
]


@props.settings_options("patches", "samples", "nu", "nv", "nw", "voxel_size", mirrored=False)
class PDEHEAD_OT_run_pipeline(Operator, GuardedOperator, LoaderOptions, TimerModal):
    bl_idname = "pdehead.run_pipeline"
    bl_label = "Run PDE Head Pipeline"
    bl_description = ("One click: segment, extract boundaries, reconstruct the PDE surface and solid and "
                      "build the volume (Esc cancels and removes what this run created)")
    bl_options = {'REGISTER', 'UNDO'}

    source: EnumProperty(name="Source", items=SOURCE_ITEMS, default="AUTO")
    study: StringProperty(name="Study", default="", options={'SKIP_SAVE'})
    build_volume: BoolProperty(name=D.BUILD_VOLUME.label, **D.BUILD_VOLUME.limits(),
                               description=D.BUILD_VOLUME.description)

    def _resolved_source(self, context) -> str:
        if self.source != "AUTO":
            return self.source
        if self.directory or self.filepath:
            return "FILES"
        return "ACTIVE"

    def make_run(self, context) -> pipeline_run.PipelineRun:
        source = self._resolved_source(context)
        path = self.input_path() if source == "FILES" else None
        options = self.loader_options() if source == "FILES" else None
        settings = dict(patches=self.patches, samples=self.samples, nu=self.nu, nv=self.nv, nw=self.nw)
        if self.properties.is_property_set("voxel_size"):  # else the study's automatic size from the CT
            settings.update(voxel_size=self.voxel_size, voxel_auto=False)
        return pipeline_run.PipelineRun(context, source, path, options, settings, self.study, self.build_volume)

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "source")
        if self.source in ("FILES", "AUTO") and (self.directory or self.filepath):
            self.draw_loader_options(layout)
        for name in ("patches", "samples", "nu", "nv", "nw", "build_volume", "voxel_size"):
            layout.prop(self, name)

    def run(self, context):
        """Synchronous (scripts, the CLI, redo)."""
        run = self.make_run(context)
        try:
            run.run_all()
        except BaseException:
            run.cancel()
            raise
        self._report_done(run)

    def _report_done(self, run) -> None:
        study = run.study
        t = study.timings
        total = sum(t.values())
        self.report({'INFO'}, f"PDE Head '{study.name}' built in {total:.1f} s (" +
                    ", ".join(f"{k} {v:.2f} s" for k, v in t.items()) + ")")

    def invoke(self, context, event):
        if context.window is None:  # no UI (background): nothing to keep responsive
            return self.execute(context)
        try:
            self._run = self.make_run(context)
        except Exception as exc:  # noqa: BLE001
            report_exception(self, exc)
            return {'CANCELLED'}
        wm = context.window_manager
        run = self._run
        self.start_ui(context, len(run.steps), f"PDE Head: {run.next_label}... (Esc to cancel)")
        # within a step: the engine's progress moves the progress indicator between the step marks
        progress.set_hook(lambda _step, fraction, _message="": wm.progress_update(run.index + fraction))
        return {'RUNNING_MODAL'}

    cancelled_message = "PDE Head pipeline cancelled: nothing was kept"

    def tick(self, context) -> bool:
        run = self._run
        run.step(on_thread=True)   # segment and boundaries work on a thread: Esc stops them mid-step
        wm = context.window_manager
        if wm is not None:
            wm.progress_update(run.index + (run.job.fraction if run.job is not None else 0.0))
        if run.job is None and not run.done:
            set_status(context, f"PDE Head: {run.next_label}... (Esc to cancel)")
        return run.done

    def finished(self) -> None:
        self._report_done(self._run)

    def cancel(self, context):
        """Esc, an error or Blender closing the operator: undo everything this run created."""
        run = getattr(self, "_run", None)
        if run is not None:
            run.cancel()
        self._end_ui(context)


#: The views Frame Study offers: every named view (defaults.VIEWS) but TOP.
FRAME_VIEW_ITEMS = [(name, *D.VIEWS[name]) for name in D.VIEWS if name != "TOP"]


class PDEHEAD_OT_frame_study(Operator, StudyOperator):
    bl_idname = "pdehead.frame_study"
    bl_label = "Frame Study"
    bl_description = ("Set the scene up to render the study: a camera and a key light in front of the head, "
                      "the chosen object shown and the overlapping ones hidden, the untouched startup cube "
                      "hidden, the 3D views framed on the head")
    bl_options = {'REGISTER', 'UNDO'}

    show: EnumProperty(name=D.SHOW.label, items=scene.SHOW_ITEMS, default=D.SHOW.default)
    view: EnumProperty(name=D.VIEW.label, items=FRAME_VIEW_ITEMS, default=D.VIEW.default)

    def run(self, context, study):
        done = scene.frame_study(context, study.collection, show=self.show, view=self.view)
        extra = "; startup cube hidden" if done["hidden_cube"] else ""
        self.report({'INFO'}, f"'{study.name}': camera and light set, showing {done['shown']}{extra}")


class PDEHEAD_OT_turntable(Operator, StudyOperator):
    bl_idname = "pdehead.turntable"
    bl_label = "Turntable"
    bl_description = ("A camera orbit around the study: its camera turns once around the head in the given "
                      "number of frames (the scene's frame range); Render Animation renders it")
    bl_options = {'REGISTER', 'UNDO'}

    frames: IntProperty(name=D.TURNTABLE_FRAMES.label, **D.TURNTABLE_FRAMES.limits(),
                        description=D.TURNTABLE_FRAMES.description)

    def run(self, context, study):
        pivot = animation.turntable(context, study.collection, self.frames, start=context.scene.frame_start)
        self.report({'INFO'}, turntable_report(study, pivot, self.frames))


class PDEHEAD_OT_add_cutter(Operator, StudyOperator):
    bl_idname = "pdehead.add_cutter"
    bl_label = "Add Cutter"
    bl_description = ("Add a box cutter (an empty) to the study: move, rotate or scale it and the solid is cut "
                      "away where it is (a wedge in v or a slab in u)")
    bl_options = {'REGISTER', 'UNDO'}

    def run(self, context, study):
        obj, kind = study.add_cutter(context)
        self.report({'INFO'}, f"Cutter '{obj.name}' added ({kind} cut): move it to cut the solid elsewhere")


class PDEHEAD_OT_remove_study(Operator, StudyOperator):
    bl_idname = "pdehead.remove_study"
    bl_label = "Remove Study"
    bl_description = "Delete the study's collection, its objects and its in-memory data"
    bl_options = {'REGISTER', 'UNDO'}

    def run(self, context, study):
        name = study.name
        study.remove()
        self.report({'INFO'}, f"Removed study '{name}'")


def menu_import(self, context):
    self.layout.operator(PDEHEAD_OT_import_ct.bl_idname, text="CT Head (DICOM, TIFF, raw)")


CLASSES = (
    PDEHEAD_OT_import_ct,
    PDEHEAD_FH_import_ct,
    PDEHEAD_OT_load_phantom,
    PDEHEAD_OT_segment,
    PDEHEAD_OT_extract_boundaries,
    PDEHEAD_OT_reconstruct_surface,
    PDEHEAD_OT_build_solid,
    PDEHEAD_OT_build_volume,
    PDEHEAD_OT_build_detail_map,
    PDEHEAD_OT_run_pipeline,
    PDEHEAD_OT_frame_study,
    PDEHEAD_OT_add_cutter,
    PDEHEAD_OT_turntable,
    PDEHEAD_OT_remove_study,
)


def add_menu() -> None:
    """File > Import > CT for PDE Head (after :data:`CLASSES` are registered)."""
    bpy.types.TOPBAR_MT_file_import.append(menu_import)


def remove_menu() -> None:
    bpy.types.TOPBAR_MT_file_import.remove(menu_import)
