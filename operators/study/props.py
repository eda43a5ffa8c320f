"""Study settings stored in the .blend, and the live parameters that rebuild the meshes at once.

One study's settings (:class:`PDEHeadStudySettings`) live on the study's settings object, an
Empty in its collection (``Object.pdehead``), so Blender can animate them (a Collection cannot
be keyframed); ``Collection.pdehead`` is a read-only shortcut to them (:func:`state.settings`).
The scene's ``Scene.pdehead.active_study`` points at the study the sidebar shows. Changing a
live parameter in the sidebar (or from Python, as a user would) runs its update callback:

- nu, nv, caps -> surface and solid re-evaluated from the cached PDE solution;
- smoothing / auto, modes -> PDE re-solved from the stored boundary curves (no re-segmenting);
- nw, u/v/w ranges -> solid re-evaluated;
- volume alpha range, density, colour preset, alpha mode -> the volume material updated in place.
"""
from __future__ import annotations

import bpy
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    IntVectorProperty,
    PointerProperty,
    StringProperty,
)

from ...pdehead_addon import defaults as D
from .. import compat, state
from ..forensic import face
from ..volume.material import COLOUR_LABELS, COLOUR_PRESETS  # the presets' one owner
from . import face_handler
from .entity import Study

#: Blender >= 4.5 warns about "//" in path properties unless they declare blend-relative support.
PATH_OPTIONS = compat.blend_relative_path_options()

def _live(what: str):
    """An update callback that rebuilds ``what`` of the study owning the settings (:meth:`.Study.live_update`;
    nothing while :class:`state.suspended_updates` is active)."""
    def update(self, context):
        if state.updates_suspended() or not self.is_study:
            return
        study = Study.of_settings(self)
        if study is not None:
            study.live_update(what)
    return update


def _detail_update(self, context):
    """The CT Detail toggle and strength: the surface's bump plugged in or out (:meth:`.Study.detail_shading`;
    never builds the map: that is *Build CT Detail*'s; errors go to the sidebar, an update callback must not
    raise)."""
    if state.updates_suspended() or not self.is_study:
        return
    study = Study.of_settings(self)
    if study is None:
        return
    try:
        study.detail_shading()
    except Exception as exc:  # noqa: BLE001
        self.last_error = f"the CT detail map could not be updated: {exc}"[:500]


def _face_table_update(self, context):
    """Switching the face's table re-solves the face (nothing while updates are suspended)."""
    if state.updates_suspended() or not self.is_study:
        return
    coll = state.study_of_settings(self)
    if coll is not None:
        face_handler.live_table(coll)


def _face_table_file_update(self, context):
    """A new table file counts only while the face uses a table file (else the pegs keep their depths)."""
    if self.face_table == 'FILE':
        _face_table_update(self, context)


SELECTION_ITEMS = [
    ("uniform", "Uniform", "Curves evenly spaced along the head axis"),
    ("shape-change", "Shape Change", "Denser curves where the head's cross-section changes fast (face)"),
    ("auto", "Automatic", "The curves whose surface is closest to every slice's outline, chosen or not "
                          "(about a second more on a head scan)"),
]
#: The PDE surface's continuity across the curves (engine values "c2" / "paper").
CONTINUITY_ITEMS = [
    ("c2", "Smooth (C2)", "One Bloor-Wilson span between consecutive curves, C2 across every curve"),
    ("paper", "Paper Patches", "The paper's t patches through four curves each; creased where they meet"),
]
def _colour_items():
    return [(key, *COLOUR_LABELS.get(key, (key.title(), ""))) for key in COLOUR_PRESETS]


COLOUR_ITEMS = _colour_items()
#: What the solid's outside shows (engine values of ``defaults.SOLID_SKIN``).
SOLID_SKIN_ITEMS = [
    ("surface", "Skin Material", "The outside shows the surface's skin material (the skin itself is a "
                                 "partial-volume mix of air and tissue in the CT)"),
    ("ct", "CT Inside the Skin", "The outside shows the CT sampled a little inside the skin (Skin Depth)"),
]
ALPHA_MODE_ITEMS = [
    ("EQ24", "Eq. 24 (w)", "Opacity from the PDE parameter w: alpha = (low - high) w + high"),
    ("INTENSITY", "Intensity", "Opacity from the CT intensity inside the PDE solid"),
]
SOURCE_KIND_ITEMS = [
    ("NONE", "None", ""),
    ("PHANTOM", "Phantom", "The built-in synthetic head"),
    ("FILES", "Files", "CT slices on disk"),
]


#: Every study setting of the defaults table, declared once: what Blender adds to the table's default, range,
#: label and description (an enumeration's items, a subtype, unit or display precision, and the live update
#: that rebuilds the study when the setting changes in the sidebar). The study's property group gets all of
#: them (:func:`declare_settings`); an operator takes the ones it offers by name (:func:`settings_options`),
#: the same property without the live update.
SETTINGS: dict[str, dict] = {
    # Forensic: the bone level (also in the import dialog)
    "use_bone_level": {},
    "bone_level": {},
    # Boundaries
    "patches": {},
    "samples": {},
    "selection": dict(items=SELECTION_ITEMS),
    "align_curves": {},
    "use_tolerance": {},
    "tolerance_mm": dict(precision=2),
    "max_tolerance_mm": dict(precision=2),
    # Surface (live)
    "nu": dict(update=_live("surface_solid")),
    "nv": dict(update=_live("surface_solid")),
    "caps": dict(update=_live("surface")),
    "continuity": dict(items=CONTINUITY_ITEMS, update=_live("pde")),
    "dome": dict(update=_live("pde")),
    "smoothing_auto": dict(update=_live("pde_auto")),
    "smoothing": dict(subtype='FACTOR', update=_live("pde")),
    "approximation_auto": dict(update=_live("pde_auto")),
    "approximation": dict(subtype='FACTOR', update=_live("pde")),
    "modes": dict(update=_live("pde")),
    # The surface's CT detail map: bump shading of the CT's fine relief
    "use_detail_map": dict(update=_detail_update),
    "detail_strength": dict(update=_detail_update),
    "detail_resolution": {},
    # Solid (live)
    "nw": dict(update=_live("solid")),
    "u_range": dict(update=_live("solid")),
    "v_range": dict(subtype="NONE", unit="ROTATION", update=_live("solid")),
    "w_range": dict(update=_live("solid")),
    "use_cutter": dict(update=_live("cutter")),
    # The solid's CT texture: atlas budget and what its outside shows
    "ct_texture_budget": dict(description_suffix=" (megapixels)", update=_live("solid")),
    "solid_skin": dict(items=SOLID_SKIN_ITEMS, update=_live("solid")),
    "solid_skin_depth": dict(update=_live("solid")),
    # Volume (live: material only)
    "use_ct_grid": {},
    "voxel_auto": {},
    "voxel_size": {},
    "low_alpha": dict(update=_live("volume")),
    "high_alpha": dict(update=_live("volume")),
    "density": dict(update=_live("volume")),
    "colour_preset": dict(items=COLOUR_ITEMS, update=_live("volume")),
    "alpha_mode": dict(items=ALPHA_MODE_ITEMS, update=_live("volume")),
}


def setting_property(name: str, live: bool = True):
    """The ``bpy.props`` property of study setting ``name``: the defaults table's default, range, label and
    description with :data:`SETTINGS`' Blender specifics; ``live=False`` (an operator's option) leaves the
    live update out."""
    param = D.PARAMS[name]
    spec = dict(SETTINGS[name])
    update = spec.pop("update", None)
    kw = dict(name=param.label, description=param.description + spec.pop("description_suffix", ""), **spec)
    if live and update is not None:
        kw["update"] = update
    value = param.default
    if "items" in kw:
        return EnumProperty(default=value, **kw)
    kw.update(param.limits())
    if isinstance(value, bool):
        return BoolProperty(**kw)
    if isinstance(value, int):
        return IntProperty(**kw)
    if isinstance(value, float):
        return FloatProperty(**kw)
    if isinstance(value, tuple) and all(isinstance(v, int) for v in value):
        return IntVectorProperty(size=len(value), **kw)
    if isinstance(value, tuple):
        return FloatVectorProperty(size=len(value), **kw)
    raise TypeError(f"study setting {name!r}: no Blender property for a default of type {type(value).__name__}")


def declare_settings(cls, names, live: bool = False):
    """Add the properties of the study settings ``names`` (:func:`setting_property`) to class ``cls``'s
    annotations, where Blender reads a class's properties when it is registered; returns ``cls``.

    Each is added as the expression that makes it, as ``from __future__ import annotations`` leaves every
    annotation of this layer: Blender evaluates it when it registers the class, and no property object
    outlives the registration in the class (bpy 4.2 crashes at exit while a class holds one)."""
    annotations = cls.__dict__.get("__annotations__")
    if annotations is None:
        annotations = {}
        cls.__annotations__ = annotations
    for name in names:
        setting_property(name, live=live)  # an unknown name or an unusable default fails here, not at register
        annotations[name] = (f"__import__({__name__!r}, fromlist=['SETTINGS'])"
                             f".setting_property({name!r}, live={live})")
    return cls


def settings_options(*names: str, mirrored: bool = True):
    """Class decorator: the operator offers the study settings ``names`` as its options (the same default,
    range, label and description as the sidebar's). ``mirrored``: they are its ``mirrored_settings``, read
    from the study when invoked and written back when run (:class:`operators.ui.base.StudyOperator`)."""
    def decorate(cls):
        declare_settings(cls, names)
        if mirrored:
            cls.mirrored_settings = names
        return cls
    return decorate


class PDEHeadStudySettings(bpy.types.PropertyGroup):
    """Settings of one study (on its settings object, saved in the .blend, animatable)."""

    is_study: BoolProperty(name="Is PDE Head Study", default=False)
    study_id: StringProperty(name="Study Id", description="Key of the in-memory cache of this study")

    # Study (read-only information, filled on import)
    source_kind: EnumProperty(name="Source Kind", items=SOURCE_KIND_ITEMS, default="NONE")
    source: StringProperty(name="Source", subtype="FILE_PATH", options=PATH_OPTIONS,
                           description="Folder or file the CT was read from (made relative to the .blend when "
                                       "it is saved; point it at the CT again if the CT moved)")
    source_absolute: StringProperty(name="Source (Absolute)", subtype="FILE_PATH",
                                    description="Absolute path of the CT at the last save (used when the "
                                                "relative Source no longer resolves)")
    load_options: StringProperty(name="Load Options", description="JSON of the loader options used")
    series: StringProperty(name="Series", description="Series description / UID")
    modality: StringProperty(name="Modality")
    dimensions: IntVectorProperty(name="Dimensions", size=3, description="Voxels (x, y, z)")
    spacing: FloatVectorProperty(name="Spacing", size=3, unit="NONE", description="Voxel size (dz, dy, dx) in mm")
    value_range: FloatVectorProperty(name="Value Range", size=2, description="Min / max CT value (HU where calibrated)")
    warnings: StringProperty(name="Warnings")
    notes: StringProperty(name="Information", description="Automatic choices the import made (one per line)")

    # Forensic: Face from Skull: the table the face uses; switching it re-solves the face at once
    face_table: EnumProperty(name="Face Table", items=face.FACE_TABLE_ITEMS, default='DEFAULT',
                             update=_face_table_update, description="The depth table the face's pegs stand by")
    face_table_file: StringProperty(name="Table File", subtype="FILE_PATH", options=PATH_OPTIONS,
                                    update=_face_table_file_update,
                                    description="A depth table CSV (landmark,mean_mm[,sd_mm,n])")
    face_sex: EnumProperty(name="Sex", items=face.FACE_SEX_ITEMS, default='POOLED', update=_face_table_update,
                           description="Sex, for tables with separate values: picks the table's rows for it "
                                       "(the face's pegs and the face follow at once)")

    # Segmentation (results, for the panel)
    seg_fraction: FloatProperty(name="Head Fraction", description="Fraction of voxels inside the head mask")
    seg_iterations: IntProperty(name="Iterations")
    seg_c1: FloatProperty(name="c1 (head)")
    seg_c2: FloatProperty(name="c2 (air)")

    # what the last extraction gave (shown in the panel, saved with the file)
    curve_count: IntProperty(name="Curves", description="Boundary curves of the last extraction")
    outline_candidates: IntProperty(name="Usable Slices",
                                    description="Slices the automatic selection measured against (negative: the "
                                                "tolerance was not met with all of them)")
    outline_mean_mm: FloatProperty(name="Mean Distance From Outlines", unit='NONE',
                                   description="The surface's mean distance (mm) from every usable slice's outline")
    outline_max_mm: FloatProperty(name="Max Distance From Outlines",
                                  description="The surface's largest distance (mm) from any usable slice's outline")

    detail_stale: BoolProperty(name="CT Detail Out of Date", default=False,
                               description="The PDE changed since the CT detail map was built: rebuild it")

    # Objects of the study
    curves_object: PointerProperty(name="Boundary Curves", type=bpy.types.Object)
    surface_object: PointerProperty(name="Surface", type=bpy.types.Object)
    solid_object: PointerProperty(name="Solid", type=bpy.types.Object)
    volume_object: PointerProperty(name="Volume", type=bpy.types.Object)

    # The last run's per-step timings (JSON step -> seconds); live-update status
    timings_json: StringProperty(name="Timings")
    last_error: StringProperty(name="Last Error", description="Why the last live update failed")
    volume_stale: BoolProperty(name="Volume Out of Date", default=False,
                               description="The PDE changed since the volume was built: rebuild it")


declare_settings(PDEHeadStudySettings, SETTINGS, live=True)


class PDEHeadSceneSettings(bpy.types.PropertyGroup):
    """Scene-level: which study the sidebar shows."""

    active_study: PointerProperty(name="Study", type=bpy.types.Collection,
                                  poll=lambda self, coll: state.is_study(coll),
                                  description="The PDE Head study shown in the sidebar")
    vdb_files: StringProperty(name="Volume Files", options={'HIDDEN'},
                              description="JSON list of the .vdb files PDE Head wrote for this file's volumes "
                                          "(the ones a save may remove once no volume uses them)")


CLASSES = (PDEHeadStudySettings, PDEHeadSceneSettings)


def _collection_settings(collection):
    """``Collection.pdehead``: the study's settings (on its settings object), None for other collections."""
    return state.settings(collection)


def attach() -> None:
    """The settings on every object and scene (after :data:`CLASSES` are registered); a study collection
    points at its settings object and reads its settings as ``collection.pdehead``."""
    bpy.types.Object.pdehead = PointerProperty(type=PDEHeadStudySettings)
    bpy.types.Scene.pdehead = PointerProperty(type=PDEHeadSceneSettings)
    bpy.types.Collection.pdehead_settings_object = PointerProperty(
        name="Study Settings Object", type=bpy.types.Object,
        description="The Empty of this PDE Head study that holds its (animatable) settings")
    bpy.types.Collection.pdehead = property(_collection_settings)


def detach() -> None:
    for owner, name in ((bpy.types.Collection, "pdehead"), (bpy.types.Collection, "pdehead_settings_object"),
                        (bpy.types.Scene, "pdehead"), (bpy.types.Object, "pdehead")):
        if name in owner.__dict__ or hasattr(owner, name):
            try:
                delattr(owner, name)
            except AttributeError:
                pass
