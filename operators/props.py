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
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty,
                       IntVectorProperty, PointerProperty, StringProperty)

from ..pdehead_addon import defaults as D
from . import compat, face, state
from .study_entity import Study

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
        face.live_table(coll)


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
    from .volume_material import COLOUR_LABELS, COLOUR_PRESETS  # the presets' one owner
    return [(key, *COLOUR_LABELS.get(key, (key.title(), ""))) for key in COLOUR_PRESETS]


COLOUR_ITEMS = _colour_items()
#: What the solid's outside shows (issue 21; engine values of ``defaults.SOLID_SKIN``).
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

    # Forensic: the bone level (issue 22; also in the import dialog)
    use_bone_level: BoolProperty(name=D.USE_BONE_LEVEL.label, **D.USE_BONE_LEVEL.limits(),
                                 description=D.USE_BONE_LEVEL.description)
    bone_level: FloatProperty(name=D.BONE_LEVEL.label, **D.BONE_LEVEL.limits(), description=D.BONE_LEVEL.description)

    # Forensic: Face from Skull (issue 23): the table the face uses; switching it re-solves the face at once
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

    # Boundaries (defaults, ranges and descriptions: pdehead_addon/defaults.py)
    patches: IntProperty(name=D.PATCHES.label, **D.PATCHES.limits(), description=D.PATCHES.description)
    samples: IntProperty(name=D.SAMPLES.label, **D.SAMPLES.limits(), description=D.SAMPLES.description)
    selection: EnumProperty(name=D.SELECTION.label, items=SELECTION_ITEMS, default=D.SELECTION.default,
                            description=D.SELECTION.description)
    align_curves: BoolProperty(name=D.ALIGN_CURVES.label, **D.ALIGN_CURVES.limits(),
                               description=D.ALIGN_CURVES.description)
    use_tolerance: BoolProperty(name=D.USE_TOLERANCE.label, **D.USE_TOLERANCE.limits(),
                                description=D.USE_TOLERANCE.description)
    tolerance_mm: FloatProperty(name=D.TOLERANCE_MM.label, **D.TOLERANCE_MM.limits(), precision=2,
                                description=D.TOLERANCE_MM.description)
    max_tolerance_mm: FloatProperty(name=D.MAX_TOLERANCE_MM.label, **D.MAX_TOLERANCE_MM.limits(), precision=2,
                                    description=D.MAX_TOLERANCE_MM.description)
    # what the last extraction gave (shown in the panel, saved with the file)
    curve_count: IntProperty(name="Curves", description="Boundary curves of the last extraction")
    outline_candidates: IntProperty(name="Usable Slices",
                                    description="Slices the automatic selection measured against (negative: the "
                                                "tolerance was not met with all of them)")
    outline_mean_mm: FloatProperty(name="Mean Distance From Outlines", unit='NONE',
                                   description="The surface's mean distance (mm) from every usable slice's outline")
    outline_max_mm: FloatProperty(name="Max Distance From Outlines",
                                  description="The surface's largest distance (mm) from any usable slice's outline")

    # Surface (live)
    nu: IntProperty(name=D.NU.label, **D.NU.limits(), update=_live("surface_solid"), description=D.NU.description)
    nv: IntProperty(name=D.NV.label, **D.NV.limits(), update=_live("surface_solid"), description=D.NV.description)
    caps: BoolProperty(name=D.CAPS.label, **D.CAPS.limits(), update=_live("surface"), description=D.CAPS.description)
    continuity: EnumProperty(name=D.CONTINUITY.label, items=CONTINUITY_ITEMS, default=D.CONTINUITY.default,
                             update=_live("pde"), description=D.CONTINUITY.description)
    dome: BoolProperty(name=D.DOME.label, **D.DOME.limits(), update=_live("pde"), description=D.DOME.description)
    smoothing_auto: BoolProperty(name=D.SMOOTHING_AUTO.label, **D.SMOOTHING_AUTO.limits(), update=_live("pde_auto"),
                                 description=D.SMOOTHING_AUTO.description)
    smoothing: FloatProperty(name=D.SMOOTHING.label, **D.SMOOTHING.limits(), subtype='FACTOR', update=_live("pde"),
                             description=D.SMOOTHING.description)
    approximation_auto: BoolProperty(name=D.APPROXIMATION_AUTO.label, **D.APPROXIMATION_AUTO.limits(),
                                     update=_live("pde_auto"), description=D.APPROXIMATION_AUTO.description)
    approximation: FloatProperty(name=D.APPROXIMATION.label, **D.APPROXIMATION.limits(), subtype='FACTOR',
                                 update=_live("pde"), description=D.APPROXIMATION.description)
    modes: IntProperty(name=D.MODES.label, **D.MODES.limits(), update=_live("pde"), description=D.MODES.description)

    # The surface's CT detail map (issue 21): bump shading of the CT's fine relief
    use_detail_map: BoolProperty(name=D.USE_DETAIL_MAP.label, **D.USE_DETAIL_MAP.limits(), update=_detail_update,
                                 description=D.USE_DETAIL_MAP.description)
    detail_strength: FloatProperty(name=D.DETAIL_STRENGTH.label, **D.DETAIL_STRENGTH.limits(), update=_detail_update,
                                   description=D.DETAIL_STRENGTH.description)
    detail_resolution: IntProperty(name=D.DETAIL_RESOLUTION.label, **D.DETAIL_RESOLUTION.limits(),
                                   description=D.DETAIL_RESOLUTION.description)
    detail_stale: BoolProperty(name="CT Detail Out of Date", default=False,
                               description="The PDE changed since the CT detail map was built: rebuild it")

    # Solid (live)
    nw: IntProperty(name=D.NW.label, **D.NW.limits(), update=_live("solid"), description=D.NW.description)
    u_range: FloatVectorProperty(name=D.U_RANGE.label, size=2, **D.U_RANGE.limits(), update=_live("solid"),
                                 description=D.U_RANGE.description)
    v_range: FloatVectorProperty(name=D.V_RANGE.label, size=2, **D.V_RANGE.limits(), subtype="NONE", unit="ROTATION",
                                 update=_live("solid"), description=D.V_RANGE.description)
    w_range: FloatVectorProperty(name=D.W_RANGE.label, size=2, **D.W_RANGE.limits(), update=_live("solid"),
                                 description=D.W_RANGE.description)
    use_cutter: BoolProperty(name=D.USE_CUTTER.label, **D.USE_CUTTER.limits(), update=_live("cutter"),
                             description=D.USE_CUTTER.description)
    # The solid's CT texture (issue 21): atlas budget and what its outside shows
    ct_texture_budget: FloatProperty(name=D.CT_TEXTURE_BUDGET.label, **D.CT_TEXTURE_BUDGET.limits(),
                                     update=_live("solid"), description=D.CT_TEXTURE_BUDGET.description + " (megapixels)")
    solid_skin: EnumProperty(name=D.SOLID_SKIN.label, items=SOLID_SKIN_ITEMS, default=D.SOLID_SKIN.default,
                             update=_live("solid"), description=D.SOLID_SKIN.description)
    solid_skin_depth: FloatProperty(name=D.SOLID_SKIN_DEPTH.label, **D.SOLID_SKIN_DEPTH.limits(), update=_live("solid"),
                                    description=D.SOLID_SKIN_DEPTH.description)

    # Volume (live: material only)
    use_ct_grid: BoolProperty(name=D.USE_CT_GRID.label, **D.USE_CT_GRID.limits(), description=D.USE_CT_GRID.description)
    voxel_auto: BoolProperty(name=D.VOXEL_AUTO.label, **D.VOXEL_AUTO.limits(), description=D.VOXEL_AUTO.description)
    voxel_size: FloatProperty(name=D.VOXEL_SIZE.label, **D.VOXEL_SIZE.limits(), description=D.VOXEL_SIZE.description)
    low_alpha: FloatProperty(name=D.LOW_ALPHA.label, **D.LOW_ALPHA.limits(), update=_live("volume"),
                             description=D.LOW_ALPHA.description)
    high_alpha: FloatProperty(name=D.HIGH_ALPHA.label, **D.HIGH_ALPHA.limits(), update=_live("volume"),
                              description=D.HIGH_ALPHA.description)
    density: FloatProperty(name=D.DENSITY.label, **D.DENSITY.limits(), update=_live("volume"),
                           description=D.DENSITY.description)
    colour_preset: EnumProperty(name=D.COLOUR_PRESET.label, items=COLOUR_ITEMS, default=D.COLOUR_PRESET.default,
                                update=_live("volume"), description=D.COLOUR_PRESET.description)
    alpha_mode: EnumProperty(name=D.ALPHA_MODE.label, items=ALPHA_MODE_ITEMS, default=D.ALPHA_MODE.default,
                             update=_live("volume"))

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
