"""All ``pdehead.*`` operators: import, the pipeline steps, the one-click pipeline.

Every operator catches the engine's :class:`PDEHeadError` (and, as a last resort, any
other exception), reports it as an ERROR and returns ``{'CANCELLED'}`` after removing
whatever it had created (:class:`Rollback`), so a failed step never leaves half-built
objects behind.

The step functions (``import_study``, ``step_segment``, ...) are plain functions on a study
collection; the operators, the live-parameter callbacks (:func:`live_update`) and the
modal pipeline (:class:`PipelineRun`) share them.
"""
from __future__ import annotations

import json
import os
import re
import traceback
from pathlib import Path

import bpy
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty, FloatVectorProperty,
                       IntProperty, IntVectorProperty, StringProperty)
from bpy.types import Operator, OperatorFileListElement

from ..pdehead_addon import CTImportError, PDEHeadError
from . import prefs, props, scene, state
from .props import DEFAULT_NU, DEFAULT_NV

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


def _report_exception(op, exc: BaseException) -> None:
    if isinstance(exc, PDEHeadError):
        op.report({'ERROR'}, str(exc))
    elif isinstance(exc, NotImplementedError):
        op.report({'ERROR'}, f"PDE Head: this step is not available in this version ({exc})")
    else:  # a bug: keep the details in the console, give the user one clear line
        traceback.print_exc()
        op.report({'ERROR'}, f"PDE Head internal error: {type(exc).__name__}: {exc}")


def _status(context, text: str | None) -> None:
    workspace = getattr(context, "workspace", None)
    if workspace is not None:
        try:
            workspace.status_text_set(text)
        except (AttributeError, RuntimeError):
            pass


def _guarded(op, context, body) -> set:
    """Run ``body()``; on any error report it, undo what it created and cancel.

    With a UI, the wait cursor/progress indicator and the status bar show the step meanwhile.
    """
    rollback = Rollback()
    wm = context.window_manager if getattr(context, "window", None) is not None else None
    if wm is not None:
        wm.progress_begin(0, 1)
        _status(context, f"PDE Head: {op.bl_label}...")
    try:
        result = body()
    except Exception as exc:  # noqa: BLE001 - every failure must reach the user as a report
        rollback.undo()
        _report_exception(op, exc)
        return {'CANCELLED'}
    finally:
        if wm is not None:
            wm.progress_end()
            _status(context, None)
    return result if result is not None else {'FINISHED'}


# ------------------------------------------------------------------------------------------
# Loader options shared by import_ct and run_pipeline (the File > Import options)

FORMAT_ITEMS = [
    ("AUTO", "Auto", "Detect DICOM series or numbered 2-D images (TIFF, PNG)"),
    ("DICOM", "DICOM", "A DICOM series (folder or one of its files)"),
    ("IMAGES", "Image Stack", "Numbered 2-D images, one slice per file"),
    ("RAW", "Raw", "Headerless raw slices (give shape, type, byte order, spacing)"),
]
DTYPE_ITEMS = [
    ("i2", "int16", "Signed 16-bit"),
    ("u2", "uint16", "Unsigned 16-bit"),
    ("u1", "uint8", "Unsigned 8-bit"),
    ("i4", "int32", "Signed 32-bit"),
    ("f4", "float32", "32-bit float"),
]
BYTE_ORDER_ITEMS = [("BIG", "Big Endian", "Most significant byte first ('>')"),
                    ("LITTLE", "Little Endian", "Least significant byte first ('<')")]
FIRST_SLICE_ITEMS = [("AUTO", "Auto", "From the file headers (DICOM); superior for stacks"),
                     ("SUPERIOR", "Superior", "The first file is the top of the head"),
                     ("INFERIOR", "Inferior", "The first file is the bottom (neck)")]


def dtype_string(dtype: str, byte_order: str) -> str:
    """numpy dtype string of the raw options, e.g. ('i2', 'BIG') -> '>i2'."""
    if dtype == "u1":
        return "u1"
    return (">" if byte_order == "BIG" else "<") + dtype


def parse_dtype_string(text: str) -> tuple[str, str]:
    """Inverse of :func:`dtype_string`: '>i2' -> ('i2', 'BIG'); '|u1' / 'uint8' -> ('u1', ...)."""
    import numpy as np
    try:
        dt = np.dtype(text)
    except TypeError:
        raise CTImportError(f"unknown data type '{text}' (use e.g. '>i2', '<u2', 'u1', '<f4')") from None
    code = f"{dt.kind}{dt.itemsize}"
    if code not in {item[0] for item in DTYPE_ITEMS}:
        raise CTImportError(f"unsupported raw data type '{text}'")
    order = "BIG" if dt.byteorder == ">" else "LITTLE"
    return code, order


class LoaderOptions:
    """Operator properties of the CT loaders (mixed into import_ct and run_pipeline)."""

    directory: StringProperty(name="Folder", subtype="DIR_PATH", options={'HIDDEN', 'SKIP_SAVE'})
    filepath: StringProperty(name="File Path", subtype="FILE_PATH", options={'HIDDEN', 'SKIP_SAVE'})
    files: CollectionProperty(type=OperatorFileListElement, options={'HIDDEN', 'SKIP_SAVE'})
    filter_glob: StringProperty(default="*", options={'HIDDEN'})
    single_file: BoolProperty(name="Only the Selected File", default=False,
                              description="Read only the selected file (a single-file volume), "
                                          "not the whole folder")
    format: EnumProperty(name="Format", items=FORMAT_ITEMS, default="AUTO")
    raw_shape: IntVectorProperty(name="Slice Shape", size=2, default=(256, 256), min=1,
                                 description="Raw slices: rows, columns (ny, nx)")
    raw_dtype: EnumProperty(name="Data Type", items=DTYPE_ITEMS, default="i2")
    byte_order: EnumProperty(name="Byte Order", items=BYTE_ORDER_ITEMS, default="BIG")
    use_spacing: BoolProperty(name="Set Spacing", default=False,
                              description="Give the voxel size (needed for raw and image stacks "
                                          "without headers)")
    spacing: FloatVectorProperty(name="Spacing (dz, dy, dx)", size=3, default=(1.0, 1.0, 1.0), min=1e-3,
                                 description="Voxel size in mm: slice step, row step, column step")
    first_slice: EnumProperty(name="First Slice", items=FIRST_SLICE_ITEMS, default="AUTO")
    orientation: StringProperty(name="Orientation", default="",
                                description="Raw and image stacks: 3 letters for the patient directions in "
                                            "which the column, row and file index increase, e.g. LPS (the "
                                            "default), LAS (row 0 = back of the head), RAS, PIL (sagittal). "
                                            "Empty: LPS, or LPI when the first slice is superior")
    units: EnumProperty(name="Units", default="AUTO",
                        items=[("AUTO", "Auto", "DICOM says its units; raw and images are stored values"),
                               ("HU", "HU", "The raw or image samples are Hounsfield units (air -1000)")])
    downsample: IntProperty(name="Downsample", default=1, min=1, max=8,
                            description="Average blocks of N x N x N voxels on import (for very large scans: "
                                        "2 needs about 1/8 of the memory)")
    series_uid: StringProperty(name="Series UID", default="",
                               description="DICOM: the SeriesInstanceUID to load when the folder "
                                           "holds several series (empty: the only/largest one)")

    def input_path(self) -> Path:
        if self.directory and not self.single_file:
            path = bpy.path.abspath(self.directory)
        elif self.filepath:
            path = bpy.path.abspath(self.filepath)
        elif self.directory:
            path = bpy.path.abspath(self.directory)
        else:
            raise CTImportError("no file or folder given")
        path = Path(path)
        if not path.exists():
            raise CTImportError("no such file or folder", path)
        return path

    def loader_options(self) -> dict:
        options: dict = {}
        if self.format == "RAW":
            options.update(format="raw", shape=tuple(int(n) for n in self.raw_shape),
                           dtype=dtype_string(self.raw_dtype, self.byte_order),
                           spacing=tuple(float(s) for s in self.spacing))
            if self.orientation.strip():
                options["orientation"] = self.orientation.strip().upper()
            else:
                options["first_slice"] = "inferior" if self.first_slice == "INFERIOR" else "superior"
            if self.units == "HU":
                options["units"] = "HU"
            if self.downsample > 1:
                options["downsample"] = int(self.downsample)
            return options
        if self.format == "DICOM":
            options["format"] = "dicom"
        elif self.format == "IMAGES":
            options["format"] = "images"
        if self.use_spacing:
            options["spacing"] = tuple(float(s) for s in self.spacing)
        if self.orientation.strip():
            options["orientation"] = self.orientation.strip().upper()
        elif self.first_slice != "AUTO":
            options["first_slice"] = self.first_slice.lower()
        if self.units == "HU":
            options["units"] = "HU"
        if self.downsample > 1:
            options["downsample"] = int(self.downsample)
        if self.series_uid.strip():
            options["series_uid"] = self.series_uid.strip()
        return options

    def draw_loader_options(self, layout) -> None:
        layout.prop(self, "format")
        if self.format == "RAW":
            layout.prop(self, "raw_shape")
            layout.prop(self, "raw_dtype")
            if self.raw_dtype != "u1":
                layout.prop(self, "byte_order")
            layout.prop(self, "spacing")
        else:
            layout.prop(self, "use_spacing")
            if self.use_spacing:
                layout.prop(self, "spacing")
        layout.prop(self, "first_slice")
        if self.format in {"AUTO", "IMAGES", "RAW"}:
            layout.prop(self, "orientation")
            layout.prop(self, "units")
        if self.format in {"AUTO", "DICOM"}:
            layout.prop(self, "series_uid")
        layout.prop(self, "downsample")
        layout.prop(self, "single_file")


# ------------------------------------------------------------------------------------------
# The steps (plain functions on a study collection)


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
    settings.warnings = "; ".join(str(w) for w in warnings)[:1000] if not isinstance(warnings, str) else warnings


def create_study(context, ct, name: str, source_kind: str, source: str = "", options: dict | None = None):
    """A new study collection holding ``ct`` (in memory) and its description; made active."""
    from . import objects
    scene = context.scene
    coll = objects.study_collection(_unique_collection_name(name), scene)
    s = state.settings(coll)
    with props.suspended_updates():
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
    known = [w for w in s.warnings.split("; ") if w]
    messages = [m for m in dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, UserWarning))
                if not any(k in m or m in k for k in known)]
    if messages:  # the loader's warnings (single slice, uneven steps, ...) stay visible in the Study panel
        s.warnings = "; ".join(([s.warnings] if s.warnings else []) + messages)[:1000]
    s.timings_json = ""
    state.record_timing(coll, "import", t.seconds)
    return coll


def phantom_study(context):
    """The built-in synthetic head as a new study."""
    from ..pdehead_addon import make_phantom
    with state.Timer() as t:
        phantom = make_phantom()
    coll = create_study(context, phantom.ct, "Phantom", "PHANTOM")
    state.settings(coll).timings_json = ""
    state.record_timing(coll, "import", t.seconds)
    return coll


def step_segment(coll) -> None:
    from ..pdehead_addon import segment_head
    s = state.settings(coll)
    ct = state.require_ct(coll)
    cache = state.cache_for(s.study_id)
    with state.Timer() as t:
        seg = segment_head(ct)
    cache.drop_from("seg")
    cache.seg = seg
    with props.suspended_updates():
        s.seg_fraction = float(seg.mask.mean())
        s.seg_iterations = int(seg.iterations)
        s.seg_c1, s.seg_c2 = float(seg.c1), float(seg.c2)
        # head size outside the human range, shoulders cut off: shown with the loader's warnings
        known = [w for w in s.warnings.split("; ") if w]
        new = [w for w in seg.meta.get("warnings", []) if w not in known]
        if new:
            s.warnings = "; ".join(known + new)[:1000]
    state.record_timing(coll, "segment", t.seconds)


def step_boundaries(coll) -> None:
    from ..pdehead_addon import extract_boundaries
    from ..pdehead_addon.boundaries import max_patches
    from . import objects
    s = state.settings(coll)
    cache = state.cache_for(s.study_id)
    if cache.seg is None:
        step_segment(coll)
    limit = max_patches(cache.seg)
    if 1 <= limit < s.patches:  # short scans (e.g. the tilted GE slab) cannot give 3t+1 slices for the default t
        message = (f"the scan has usable head outlines for at most {limit} patches "
                   f"({3 * limit + 1} slices): patches reduced from {s.patches} to {limit}")
        with props.suspended_updates():
            s.patches = limit
        s.warnings = "; ".join([w for w in (s.warnings, message) if w])[:1000]
    with state.Timer() as t:
        bset = extract_boundaries(cache.seg, patches=s.patches, samples=s.samples, selection=s.selection,
                                  parameterisation="angular" if s.align_curves else "arc-length")
    state.store_boundaries(coll, bset)
    cache.drop_from("bset")
    cache.bset = bset
    s.curves_object = objects.build_boundary_curves(bset, coll, name=f"{coll.name} Boundary curves",
                                                    obj=s.curves_object)
    state.record_timing(coll, "boundaries", t.seconds)


def _solve(coll) -> object:
    with state.Timer() as t:
        cache = state.cache_for(state.settings(coll).study_id)
        fresh = cache.head is None or cache.head_key != state.pde_key(coll)
        head = state.pde_head(coll)
    if fresh:
        state.record_timing(coll, "pde_solve", t.seconds)
    return head


def step_surface(coll) -> None:
    from . import objects
    s = state.settings(coll)
    head = _solve(coll)
    with state.Timer() as t:
        s.surface_object = objects.build_surface(head, coll, nu=s.nu, nv=s.nv, caps=s.caps, obj=s.surface_object,
                                                 name=f"{coll.name} Surface")
    state.record_timing(coll, "surface", t.seconds)


def step_solid(coll) -> None:
    from . import objects
    s = state.settings(coll)
    head = _solve(coll)
    ct = state.require_ct(coll)  # re-read after reopening: a solid without its CT colours is a loss
    window = state.ct_window(coll, ct)
    with state.Timer() as t:
        s.solid_object = objects.build_solid(
            head, coll, nu=s.nu, nv=s.nv, nw=s.nw, u_range=tuple(s.u_range), v_range=tuple(s.v_range),
            w_range=tuple(s.w_range), ct=ct, obj=s.solid_object, name=f"{coll.name} Solid", window=window,
            ct_table=state.ct_table(coll, head, ct))
    state.record_timing(coll, "solid", t.seconds)


def volume_settings(s) -> dict:
    return dict(low_alpha=s.low_alpha, high_alpha=s.high_alpha, density=s.density,
                colour_preset=s.colour_preset, alpha_mode=s.alpha_mode)


def step_volume(coll, context=None) -> None:
    from . import volume
    s = state.settings(coll)
    head = _solve(coll)
    cache = state.cache_for(s.study_id)
    # always with the CT (re-read after reopening): a volume without CT intensities is never built
    ct = state.require_ct(coll)
    window = state.ct_window(coll, ct)
    if not s.use_ct_grid and s.voxel_auto:
        size = volume.auto_voxel_size(ct, head)
        with props.suspended_updates():
            s.voxel_size = size
    with state.Timer() as t:
        grid = ct if s.use_ct_grid else float(s.voxel_size)
        wfield = head.w_field(grid, ct=ct)
    state.record_timing(coll, "w_field", t.seconds)
    cache.wfield = wfield
    with state.Timer() as t:
        vdb_path = volume.vdb_path_for(coll.name, bpy.data.filepath or None, prefs.vdb_prefs_folder(context))
        s.volume_object = volume.build_volume(wfield, coll, vdb_path, name=f"{coll.name} Volume",
                                              obj=s.volume_object, ct=ct, window=window, **volume_settings(s))
        s.volume_stale = False
    state.record_timing(coll, "volume", t.seconds)


STEP_FUNCTIONS = {
    "segment": step_segment,
    "boundaries": step_boundaries,
    "surface": step_surface,
    "solid": step_solid,
    "volume": step_volume,
}


# ------------------------------------------------------------------------------------------
# Live parameters (called by the update callbacks in props.py)


def live_update(coll, what: str, context=None) -> None:
    """Rebuild the study's existing objects after a live parameter changed (no re-segmenting).

    Errors cannot be reported from an update callback: they go to ``settings.last_error``
    (shown in the sidebar) and the console.
    """
    s = state.settings(coll)
    try:
        if what == "pde_auto":
            what = "pde"
            if state.boundary_set(coll) is not None and not (s.smoothing_auto and s.approximation_auto):
                # start a manual slider from the automatic value (as a fraction of the study's range)
                smoothing, approximation = state.default_controls(coll)
                with props.suspended_updates():
                    if not s.smoothing_auto and not s.is_property_set("smoothing"):
                        s.smoothing = smoothing
                    if not s.approximation_auto and not s.is_property_set("approximation"):
                        s.approximation = approximation
        if what == "cutter":
            from . import cutter
            if s.use_cutter and cutter.cutter_of(coll) is not None:
                cutter.apply_cutter(coll)
        elif what == "volume":
            if s.volume_object is not None:
                from . import volume
                volume.set_volume_settings(s.volume_object, **volume_settings(s))
        else:
            if what == "pde" and s.volume_object is not None:
                s.volume_stale = True  # the w-field follows the PDE; rebuilt on request (heavy)
            if what in ("surface", "surface_solid", "pde") and s.surface_object is not None:
                step_surface(coll)
            if what in ("solid", "surface_solid", "pde") and s.solid_object is not None:
                step_solid(coll)
        s.last_error = ""
    except Exception as exc:  # noqa: BLE001 - an update callback must never raise into the UI
        if not isinstance(exc, PDEHeadError):
            traceback.print_exc()
        s.last_error = str(exc)[:500]
        print(f"PDE Head: live update of {what} failed: {exc}")


# ------------------------------------------------------------------------------------------
# Operators


NO_STUDY_MESSAGE = "No PDE Head study: import a CT (File > Import > CT Head) or load the phantom"


def _active_or_report(op, context):
    coll = state.active_study(context, getattr(op, "study", ""))
    if coll is None:
        op.report({'ERROR'}, NO_STUDY_MESSAGE)
    return coll


class StudyOperator:
    """Mixin: operators that work on the active study (or the one named by ``study``)."""

    study: StringProperty(name="Study", default="", options={'SKIP_SAVE'},
                          description="Collection name of the study (empty: the active study)")

    #: Operator properties that mirror the study's settings: read when invoked, written back when run.
    mirrored_settings = ()

    @classmethod
    def poll(cls, context):
        if state.active_study(context) is not None or state.studies():
            return True
        cls.poll_message_set(NO_STUDY_MESSAGE)
        return False

    def invoke(self, context, event):
        coll = state.active_study(context, self.study)
        if coll is not None:
            s = state.settings(coll)
            for name in self.mirrored_settings:
                setattr(self, name, getattr(s, name))
        return self.execute(context)

    def store_settings(self, s) -> None:
        """Copy the operator's values into the study settings without triggering live rebuilds.

        A value the caller did not set (``bpy.ops.pdehead.build_solid()`` from a script or
        headless, where invoke is not called) is taken from the study instead, so running an
        operator never resets the study's settings to the operator's defaults.
        """
        is_set = getattr(getattr(self, "properties", None), "is_property_set", None)
        with props.suspended_updates():
            for name in self.mirrored_settings:
                if is_set is not None and not is_set(name):
                    setattr(self, name, getattr(s, name))
                else:
                    setattr(s, name, getattr(self, name))


def _finish_report(op, coll, step: str) -> None:
    seconds = state.timings(coll).get(step)
    extra = f" in {seconds:.2f} s" if seconds is not None else ""
    op.report({'INFO'}, f"{STEP_LABELS.get(step, step)} of '{coll.name}' done{extra}")


class PDEHEAD_OT_import_ct(Operator, LoaderOptions):
    """Import head CT slices (DICOM series, numbered TIFF/PNG images or headerless raw) as a PDE Head study"""

    bl_idname = "pdehead.import_ct"
    bl_label = "Import CT Head"
    bl_description = ("Import head CT slices (DICOM series, numbered TIFF/PNG images or headerless raw) "
                      "as a new PDE Head study collection")
    bl_options = {'REGISTER', 'UNDO'}

    run_pipeline: BoolProperty(name="Build the Head", default=False,
                               description="Run segmentation, boundaries, surface and solid after importing")

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {'RUNNING_MODAL'}

    def draw(self, context):
        self.draw_loader_options(self.layout)
        self.layout.prop(self, "run_pipeline")

    def execute(self, context):
        def body():
            path = self.input_path()
            coll = import_study(context, path, self.loader_options())
            s = state.settings(coll)
            if self.run_pipeline:
                for step in ("segment", "boundaries", "surface", "solid"):
                    STEP_FUNCTIONS[step](coll)
            nx, ny, nz = s.dimensions
            self.report({'INFO'}, f"Imported '{coll.name}': {nx}x{ny}x{nz} voxels, spacing "
                        f"{', '.join(f'{v:g}' for v in s.spacing)} mm")
            if s.warnings:
                self.report({'WARNING'}, s.warnings[:300])
        return _guarded(self, context, body)


class PDEHEAD_OT_load_phantom(Operator):
    bl_idname = "pdehead.load_phantom"
    bl_label = "Load Phantom"
    bl_description = "Create a study from the built-in synthetic head CT (try PDE Head without data)"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        def body():
            coll = phantom_study(context)
            nx, ny, nz = state.settings(coll).dimensions
            self.report({'INFO'}, f"Phantom loaded: {nx}x{ny}x{nz} voxels")
        return _guarded(self, context, body)


class PDEHEAD_OT_segment(Operator, StudyOperator):
    bl_idname = "pdehead.segment"
    bl_label = "Segment Head"
    bl_description = "Segment the head from the CT with the 3D Chan-Vese soft model (eq. 16-21) and clean-up"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        coll = _active_or_report(self, context)
        if coll is None:
            return {'CANCELLED'}

        def body():
            step_segment(coll)
            s = state.settings(coll)
            self.report({'INFO'}, f"Segmented '{coll.name}': head = {100 * s.seg_fraction:.1f} % of the "
                        f"voxels ({s.seg_iterations} iterations, {state.timings(coll)['segment']:.2f} s)")
        return _guarded(self, context, body)


class PDEHEAD_OT_extract_boundaries(Operator, StudyOperator):
    bl_idname = "pdehead.extract_boundaries"
    bl_label = "Extract Boundaries"
    bl_description = "Extract the 3t+1 boundary curves (eq. 22) of t PDE patches from the segmentation"
    bl_options = {'REGISTER', 'UNDO'}

    patches: IntProperty(name="Patches (t)", default=10, min=1, max=60)
    samples: IntProperty(name="Samples (M)", default=256, min=16, max=4096)
    selection: EnumProperty(name="Selection", items=props.SELECTION_ITEMS, default=props.DEFAULT_SELECTION)
    align_curves: BoolProperty(name="Align Curves", default=True,  # equal v = the same direction from the spine
                               description="Re-sample the curves so that equal v joins corresponding points "
                                           "(avoids folds where a feature such as the nose is on one curve only)")

    mirrored_settings = ("patches", "samples", "selection", "align_curves")

    def execute(self, context):
        coll = _active_or_report(self, context)
        if coll is None:
            return {'CANCELLED'}

        def body():
            s = state.settings(coll)
            self.store_settings(s)
            warnings_before = s.warnings
            step_boundaries(coll)
            self.patches = s.patches  # may have been reduced to what the scan allows
            self.report({'INFO'}, f"{3 * s.patches + 1} boundary curves of {self.samples} points extracted "
                        f"from '{coll.name}' ({state.timings(coll)['boundaries']:.2f} s)")
            if s.warnings != warnings_before:
                self.report({'WARNING'}, s.warnings[len(warnings_before):].lstrip("; ")[:300])
        return _guarded(self, context, body)


class PDEHEAD_OT_reconstruct_surface(Operator, StudyOperator):
    bl_idname = "pdehead.reconstruct_surface"
    bl_label = "Reconstruct Surface"
    bl_description = "Solve the Bloor-Wilson PDEs (eq. 1-13) on the boundary curves and build the head surface"
    bl_options = {'REGISTER', 'UNDO'}

    nu: IntProperty(name="nu", default=DEFAULT_NU, min=4, max=2000)
    nv: IntProperty(name="nv", default=DEFAULT_NV, min=4, max=2000)
    caps: BoolProperty(name="Caps", default=True)
    continuity: EnumProperty(name="Continuity", items=props.CONTINUITY_ITEMS, default=props.DEFAULT_CONTINUITY_ITEM)
    dome: BoolProperty(name="Dome", default=True)
    smoothing_auto: BoolProperty(name="Auto Smoothing", default=True)
    smoothing: FloatProperty(name="Smoothing (a)", default=0.0, min=0.0, max=1.0, subtype='FACTOR')
    approximation_auto: BoolProperty(name="Auto Approximation", default=True)
    approximation: FloatProperty(name="Smooth Along Axis", default=0.0, min=0.0, max=1.0, subtype='FACTOR')
    modes: IntProperty(name="Fourier Modes", default=0, min=0, max=512, description="0 = all")

    mirrored_settings = ("nu", "nv", "caps", "continuity", "dome", "smoothing_auto", "smoothing",
                         "approximation_auto", "approximation", "modes")

    def execute(self, context):
        coll = _active_or_report(self, context)
        if coll is None:
            return {'CANCELLED'}

        def body():
            s = state.settings(coll)
            self.store_settings(s)
            if state.boundary_set(coll) is None:
                step_boundaries(coll)
            step_surface(coll)
            n = len(s.surface_object.data.vertices)
            self.report({'INFO'}, f"PDE surface of '{coll.name}': {n} vertices "
                        f"({state.timings(coll)['surface']:.2f} s)")
        return _guarded(self, context, body)


class PDEHEAD_OT_build_solid(Operator, StudyOperator):
    bl_idname = "pdehead.build_solid"
    bl_label = "Build Solid"
    bl_description = "Build the PDE solid (eq. 23): the head sampled in u, v and w from the spine to the surface"
    bl_options = {'REGISTER', 'UNDO'}

    nu: IntProperty(name="nu", default=DEFAULT_NU, min=4, max=2000)
    nv: IntProperty(name="nv", default=DEFAULT_NV, min=4, max=2000)
    nw: IntProperty(name="nw", default=5, min=2, max=200)
    u_range: FloatVectorProperty(name="u Range", size=2, default=(0.0, 1.0), min=0.0, max=1.0)
    v_range: FloatVectorProperty(name="v Range", size=2, default=(0.0, 6.283185307179586), min=-6.283185307179586,
                                 max=12.566370614359172, soft_min=0.0, soft_max=6.283185307179586, unit="ROTATION")
    w_range: FloatVectorProperty(name="w Range", size=2, default=(0.0, 1.0), min=0.0, max=1.0)

    mirrored_settings = ("nu", "nv", "nw", "u_range", "v_range", "w_range")

    def execute(self, context):
        coll = _active_or_report(self, context)
        if coll is None:
            return {'CANCELLED'}

        def body():
            s = state.settings(coll)
            for name, lo_hi in (("u", self.u_range), ("v", self.v_range), ("w", self.w_range)):
                if lo_hi[0] >= lo_hi[1]:
                    raise PDEHeadError(f"{name} range must have its start below its end, got "
                                       f"{lo_hi[0]:g}..{lo_hi[1]:g}")
            self.store_settings(s)
            if state.boundary_set(coll) is None:
                step_boundaries(coll)
            step_solid(coll)
            n = len(s.solid_object.data.vertices)
            self.report({'INFO'}, f"PDE solid of '{coll.name}': {n} vertices ({state.timings(coll)['solid']:.2f} s)")
        return _guarded(self, context, body)


class PDEHEAD_OT_build_volume(Operator, StudyOperator):
    bl_idname = "pdehead.build_volume"
    bl_label = "Build Volume"
    bl_description = ("Sample the PDE solid's w on a voxel grid, write it with the CT intensities as a .vdb "
                      "and render it as a volume with eq. 24 opacity")
    bl_options = {'REGISTER', 'UNDO'}

    use_ct_grid: BoolProperty(name="CT Grid", default=False)
    voxel_auto: BoolProperty(name="Auto Voxel Size", default=True)
    voxel_size: FloatProperty(name="Voxel Size (mm)", default=2.0, min=0.25, max=20.0)
    low_alpha: FloatProperty(name="Low Alpha", default=0.1, min=0.0, max=1.0)
    high_alpha: FloatProperty(name="High Alpha", default=0.9, min=0.0, max=1.0)
    density: FloatProperty(name="Density", default=40.0, min=0.0, max=10000.0)
    colour_preset: EnumProperty(name="Colour", items=props.COLOUR_ITEMS, default="grayscale")
    alpha_mode: EnumProperty(name="Alpha Mode", items=props.ALPHA_MODE_ITEMS, default="EQ24")

    mirrored_settings = ("use_ct_grid", "voxel_auto", "voxel_size", "low_alpha", "high_alpha", "density", "colour_preset",
                         "alpha_mode")

    def execute(self, context):
        coll = _active_or_report(self, context)
        if coll is None:
            return {'CANCELLED'}

        def body():
            s = state.settings(coll)
            if self.properties.is_property_set("voxel_size") and not self.properties.is_property_set("voxel_auto"):
                self.voxel_auto = False  # a size given by the caller is meant
            self.store_settings(s)
            if state.boundary_set(coll) is None:
                step_boundaries(coll)
            step_volume(coll, context)
            t = state.timings(coll)
            self.report({'INFO'}, f"Volume of '{coll.name}' built (w-field {t['w_field']:.2f} s, "
                        f"VDB + material {t['volume']:.2f} s)")
        return _guarded(self, context, body)


# ------------------------------------------------------------------------------------------
# The one-click pipeline: synchronous from scripts, modal (one step per timer tick, Esc cancels) from the UI

SOURCE_ITEMS = [
    ("AUTO", "Auto", "The given file/folder if any, else the active study"),
    ("ACTIVE", "Active Study", "Re-run every step on the active study's CT"),
    ("PHANTOM", "Phantom", "A new study from the built-in synthetic head"),
    ("FILES", "Files", "A new study from the given file or folder"),
]


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
        self.rollback = Rollback()
        if source == "ACTIVE":
            coll = state.active_study(context, study)
            if coll is None:
                raise PDEHeadError("No PDE Head study to run on: import a CT or load the phantom first")
            self.collection_name = coll.name
            self._apply_settings(coll)
            state.settings(coll).timings_json = ""

    @property
    def collection(self):
        return bpy.data.collections.get(self.collection_name) if self.collection_name else None

    @property
    def done(self) -> bool:
        return self.index >= len(self.steps)

    @property
    def next_label(self) -> str:
        return STEP_LABELS[self.steps[self.index]] if not self.done else "done"

    def _apply_settings(self, coll) -> None:
        s = state.settings(coll)
        with props.suspended_updates():
            for name, value in self.settings.items():
                setattr(s, name, value)

    def step(self) -> bool:
        """Run the next step; True when the pipeline is complete."""
        name = self.steps[self.index]
        if name == "import":
            if self.source == "PHANTOM":
                coll = phantom_study(self.context)
            else:
                coll = import_study(self.context, self.path, self.options)
            self.collection_name = coll.name
            self._apply_settings(coll)
        elif name == "volume":
            step_volume(self.collection, self.context)
        elif name == "scene":
            coll = self.collection
            # a new study, or one never framed: camera, light, the surface shown, the startup cube hidden
            if self.source != "ACTIVE" or scene._study_object(coll, scene.CAMERA_KIND) is None:
                scene.frame_study(self.context, coll)
        else:
            STEP_FUNCTIONS[name](self.collection)
        self.index += 1
        return self.done

    def run_all(self) -> None:
        while not self.done:
            self.step()

    def cancel(self) -> None:
        """Remove every object, collection and datablock this run created."""
        self.rollback.undo()
        self.index = len(self.steps)


class PDEHEAD_OT_run_pipeline(Operator, LoaderOptions):
    bl_idname = "pdehead.run_pipeline"
    bl_label = "Run PDE Head Pipeline"
    bl_description = ("One click: segment, extract boundaries, reconstruct the PDE surface and solid and "
                      "build the volume (Esc cancels and removes what this run created)")
    bl_options = {'REGISTER', 'UNDO'}

    source: EnumProperty(name="Source", items=SOURCE_ITEMS, default="AUTO")
    study: StringProperty(name="Study", default="", options={'SKIP_SAVE'})
    patches: IntProperty(name="Patches (t)", default=10, min=1, max=60)
    samples: IntProperty(name="Samples (M)", default=256, min=16, max=4096)
    nu: IntProperty(name="nu", default=DEFAULT_NU, min=4, max=2000)
    nv: IntProperty(name="nv", default=DEFAULT_NV, min=4, max=2000)
    nw: IntProperty(name="nw", default=5, min=2, max=200)
    build_volume: BoolProperty(name="Volume", default=True, description="Also build the volume")
    voxel_size: FloatProperty(name="Voxel Size (mm)", default=2.0, min=0.25, max=20.0)

    def _resolved_source(self, context) -> str:
        if self.source != "AUTO":
            return self.source
        if self.directory or self.filepath:
            return "FILES"
        return "ACTIVE"

    def make_run(self, context) -> PipelineRun:
        source = self._resolved_source(context)
        path = self.input_path() if source == "FILES" else None
        options = self.loader_options() if source == "FILES" else None
        settings = dict(patches=self.patches, samples=self.samples, nu=self.nu, nv=self.nv, nw=self.nw)
        if self.properties.is_property_set("voxel_size"):  # else the study's automatic size from the CT
            settings.update(voxel_size=self.voxel_size, voxel_auto=False)
        return PipelineRun(context, source, path, options, settings, self.study, self.build_volume)

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "source")
        if self.source in ("FILES", "AUTO") and (self.directory or self.filepath):
            self.draw_loader_options(layout)
        for name in ("patches", "samples", "nu", "nv", "nw", "build_volume", "voxel_size"):
            layout.prop(self, name)

    def execute(self, context):
        """Synchronous (scripts, the CLI, redo)."""
        def body():
            run = self.make_run(context)
            try:
                run.run_all()
            except BaseException:
                run.cancel()
                raise
            self._report_done(run)
        return _guarded(self, context, body)

    def _report_done(self, run) -> None:
        coll = run.collection
        t = state.timings(coll)
        total = sum(t.values())
        self.report({'INFO'}, f"PDE Head '{coll.name}' built in {total:.1f} s (" +
                    ", ".join(f"{k} {v:.2f} s" for k, v in t.items()) + ")")

    def invoke(self, context, event):
        if context.window is None:  # no UI (background): nothing to keep responsive
            return self.execute(context)
        try:
            self._run = self.make_run(context)
        except Exception as exc:  # noqa: BLE001
            _report_exception(self, exc)
            return {'CANCELLED'}
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.progress_begin(0, len(self._run.steps))
        _status(context, f"PDE Head: {self._run.next_label}... (Esc to cancel)")
        wm.modal_handler_add(self)
        return {'RUNNING_MODAL'}

    def modal(self, context, event):
        run = self._run
        if event.type == 'ESC':
            self.cancel(context)
            self.report({'WARNING'}, "PDE Head pipeline cancelled: nothing was kept")
            return {'CANCELLED'}
        if event.type != 'TIMER':
            return {'PASS_THROUGH'}
        try:
            run.step()
        except Exception as exc:  # noqa: BLE001
            self.cancel(context)
            _report_exception(self, exc)
            return {'CANCELLED'}
        wm = context.window_manager
        if wm is not None:
            wm.progress_update(run.index)
        if run.done:
            self._end_ui(context)
            self._report_done(run)
            return {'FINISHED'}
        _status(context, f"PDE Head: {run.next_label}... (Esc to cancel)")
        return {'RUNNING_MODAL'}

    def _end_ui(self, context) -> None:
        wm = context.window_manager
        timer = getattr(self, "_timer", None)
        if timer is not None and wm is not None:
            wm.event_timer_remove(timer)
            self._timer = None
        if wm is not None:
            wm.progress_end()
        _status(context, None)

    def cancel(self, context):
        """Esc, an error or Blender closing the operator: undo everything this run created."""
        run = getattr(self, "_run", None)
        if run is not None:
            run.cancel()
        self._end_ui(context)


class PDEHEAD_OT_frame_study(Operator, StudyOperator):
    bl_idname = "pdehead.frame_study"
    bl_label = "Frame Study"
    bl_description = ("Set the scene up to render the study: a camera and a key light in front of the head, "
                      "the chosen object shown and the overlapping ones hidden, the untouched startup cube "
                      "hidden, the 3D views framed on the head")
    bl_options = {'REGISTER', 'UNDO'}

    show: EnumProperty(name="Show", items=scene.SHOW_ITEMS, default="SURFACE")
    view: EnumProperty(name="View", items=[("FRONT", "Front", "The face (Blender's front view)"),
                                           ("RIGHT", "Right", "The patient's right side"),
                                           ("LEFT", "Left", "The patient's left side"),
                                           ("BACK", "Back", "The back of the head"),
                                           ("THREE_QUARTER", "Three Quarter", "From front right, above")],
                       default="FRONT")

    def execute(self, context):
        coll = _active_or_report(self, context)
        if coll is None:
            return {'CANCELLED'}

        def body():
            done = scene.frame_study(context, coll, show=self.show, view=self.view)
            extra = "; startup cube hidden" if done["hidden_cube"] else ""
            self.report({'INFO'}, f"'{coll.name}': camera and light set, showing {done['shown']}{extra}")
        return _guarded(self, context, body)


class PDEHEAD_OT_add_cutter(Operator, StudyOperator):
    bl_idname = "pdehead.add_cutter"
    bl_label = "Add Cutter"
    bl_description = ("Add a box cutter (an empty) to the study: move, rotate or scale it and the solid is cut "
                      "away where it is (a wedge in v or a slab in u)")
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        coll = _active_or_report(self, context)
        if coll is None:
            return {'CANCELLED'}

        def body():
            from . import cutter
            if state.settings(coll).solid_object is None:
                step_solid(coll)
            obj = cutter.add_cutter(context, coll)
            kind = cutter.apply_cutter(coll)
            self.report({'INFO'}, f"Cutter '{obj.name}' added ({kind} cut): move it to cut the solid elsewhere")
        return _guarded(self, context, body)


class PDEHEAD_OT_remove_study(Operator, StudyOperator):
    bl_idname = "pdehead.remove_study"
    bl_label = "Remove Study"
    bl_description = "Delete the study's collection, its objects and its in-memory data"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        coll = _active_or_report(self, context)
        if coll is None:
            return {'CANCELLED'}
        name = coll.name
        remove_study(coll)
        self.report({'INFO'}, f"Removed study '{name}'")
        return {'FINISHED'}


def remove_study(coll) -> None:
    state.drop_cache(state.settings(coll).study_id)
    for obj in list(coll.all_objects):
        data = obj.data
        bpy.data.objects.remove(obj)
        if data is not None and data.users == 0:
            for kind in ("meshes", "curves", "volumes", "cameras", "lights"):
                collection = getattr(bpy.data, kind)
                if data.name in collection and collection[data.name] == data:
                    collection.remove(data)
                    break
    for child in list(coll.children_recursive):
        bpy.data.collections.remove(child)
    bpy.data.collections.remove(coll)


def menu_import(self, context):
    self.layout.operator(PDEHEAD_OT_import_ct.bl_idname, text="CT Head (DICOM, TIFF, raw)")


CLASSES = (
    PDEHEAD_OT_import_ct,
    PDEHEAD_OT_load_phantom,
    PDEHEAD_OT_segment,
    PDEHEAD_OT_extract_boundaries,
    PDEHEAD_OT_reconstruct_surface,
    PDEHEAD_OT_build_solid,
    PDEHEAD_OT_build_volume,
    PDEHEAD_OT_run_pipeline,
    PDEHEAD_OT_frame_study,
    PDEHEAD_OT_add_cutter,
    PDEHEAD_OT_remove_study,
)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.TOPBAR_MT_file_import.append(menu_import)


def unregister() -> None:
    bpy.types.TOPBAR_MT_file_import.remove(menu_import)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
