"""Study settings stored in the .blend, and the live parameters that rebuild the meshes at once.

``Collection.pdehead`` (:class:`PDEHeadStudySettings`) holds one study's settings; the
scene's ``Scene.pdehead.active_study`` points at the study the sidebar shows. Changing a
live parameter in the sidebar (or from Python, as a user would) runs its update callback:

- nu, nv, caps -> surface and solid re-evaluated from the cached PDE solution;
- smoothing / auto, modes -> PDE re-solved from the stored boundary curves (no re-segmenting);
- nw, u/v/w ranges -> solid re-evaluated;
- volume alpha range, density, colour preset, alpha mode -> the volume material updated in place.
"""
from __future__ import annotations

import math

import bpy
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty,
                       IntVectorProperty, PointerProperty, StringProperty)

#: Blender >= 4.5 warns about "//" in path properties unless they declare blend-relative support.
PATH_OPTIONS = {'PATH_SUPPORTS_BLEND_RELATIVE'} if bpy.app.version >= (4, 5, 0) else set()

# Set while operators write many settings at once, so that no update callback rebuilds anything.
_SUSPEND = [0]


class suspended_updates:
    """``with suspended_updates(): settings.nu = ...`` (no live rebuild while inside)."""

    def __enter__(self):
        _SUSPEND[0] += 1

    def __exit__(self, *exc):
        _SUSPEND[0] -= 1
        return False


def _live(what: str):
    """An update callback that rebuilds ``what`` of the study owning the settings."""
    def update(self, context):
        if _SUSPEND[0] or not self.is_study:
            return
        from . import ops
        ops.live_update(self.id_data, what, context)
    return update


#: Default surface/solid resolution: fine enough that a nose (~30 mm wide) gets ~10 samples
#: around v and the lips several along u; surface(120, 240) builds in ~10-20 ms.
DEFAULT_NU = 120
DEFAULT_NV = 240

#: The add-on's default slice choice: the paper's uniform choice loses the nose and lips at t = 10
#: (the interpolation between 4 curves folds where the face changes fast); shape-change keeps them.
DEFAULT_SELECTION = "shape-change"
SELECTION_ITEMS = [
    ("uniform", "Uniform", "Curves evenly spaced along the head axis"),
    ("shape-change", "Shape Change", "Denser curves where the head's cross-section changes fast (face)"),
]
#: The PDE surface's continuity across the curves (engine values "c2" / "paper").
CONTINUITY_ITEMS = [
    ("c2", "Smooth (C2)", "One Bloor-Wilson span between consecutive curves, C2 across every curve"),
    ("paper", "Paper Patches", "The paper's t patches through four curves each; creased where they meet"),
]
DEFAULT_CONTINUITY_ITEM = "c2"
def _colour_items():
    from .volume import COLOUR_LABELS, COLOUR_PRESETS  # the presets' one owner
    return [(key, *COLOUR_LABELS.get(key, (key.title(), ""))) for key in COLOUR_PRESETS]


COLOUR_ITEMS = _colour_items()
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
    """Settings of one study (lives on its collection, saved in the .blend)."""

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

    # Segmentation (results, for the panel)
    seg_fraction: FloatProperty(name="Head Fraction", description="Fraction of voxels inside the head mask")
    seg_iterations: IntProperty(name="Iterations")
    seg_c1: FloatProperty(name="c1 (head)")
    seg_c2: FloatProperty(name="c2 (air)")

    # Boundaries
    patches: IntProperty(name="Patches (t)", default=10, min=1, max=60,
                         description="Number t of PDE patches; 3t+1 boundary curves are extracted")
    samples: IntProperty(name="Samples (M)", default=256, min=16, max=4096,
                         description="Points per boundary curve")
    selection: EnumProperty(name="Selection", items=SELECTION_ITEMS, default=DEFAULT_SELECTION,
                            description="How the 3t+1 slices are chosen")
    align_curves: BoolProperty(name="Align Curves", default=True,
                               description="Sample every curve at the same directions from a smooth spine, so "
                                           "that equal v joins corresponding points (no folds or cheek ripples); "
                                           "off: samples evenly spaced along each curve")

    # Surface (live)
    nu: IntProperty(name="nu", default=DEFAULT_NU, min=4, max=2000, update=_live("surface_solid"),
                    description="Resolution along the head axis (u); rebuilds the meshes at once")
    nv: IntProperty(name="nv", default=DEFAULT_NV, min=4, max=2000, update=_live("surface_solid"),
                    description="Resolution around the head (v); rebuilds the meshes at once")
    caps: BoolProperty(name="Caps", default=True, update=_live("surface"),
                       description="Close the top and bottom of the surface")
    continuity: EnumProperty(
        name="Continuity", items=CONTINUITY_ITEMS, default=DEFAULT_CONTINUITY_ITEM, update=_live("pde"),
        description="Smooth: one Bloor-Wilson span between consecutive curves, C2 across every curve "
                    "(default). Paper: t patches through four curves each (eq. 3-6), creased at the joints")
    dome: BoolProperty(name="Dome", default=True, update=_live("pde"),
                       description="Close the crown with a round dome through the vertex above the top curve "
                                   "(Smooth continuity)")
    smoothing_auto: BoolProperty(name="Auto Smoothing", default=True, update=_live("pde_auto"),
                                 description="Let the solver choose the smoothing parameter a of eq. 1")
    smoothing: FloatProperty(name="Smoothing (a)", default=0.0, min=0.0, max=1.0, subtype='FACTOR',
                             update=_live("pde"),
                             description="Smoothing parameter a of eq. 1 as a fraction of this study's "
                                         "maximum (Smooth: the isotropic height/radius ratio; Paper: the "
                                         "largest stable a of each patch). Every value solves")
    approximation_auto: BoolProperty(name="Auto Approximation", default=True, update=_live("pde_auto"),
                                     description="Smooth along the head axis by the solver's default length "
                                                 "(one slice step of the scan, at most half a curve gap)")
    approximation: FloatProperty(name="Smooth Along Axis", default=0.0, min=0.0, max=1.0, subtype='FACTOR',
                                 update=_live("pde"),
                                 description="Approximating mode: how strongly the surface may leave the curves "
                                             "to smooth slice steps and streaks (0 = through every curve; 1 = "
                                             "a smoothing length of 1.5 curve gaps). Smooth continuity only")
    modes: IntProperty(name="Fourier Modes", default=0, min=0, max=512, update=_live("pde"),
                       description="Harmonics kept around each ring (0 = all: the surface passes through "
                                   "the curves; fewer: eq. 13's truncated series, a simpler head)")

    # Solid (live)
    nw: IntProperty(name="nw", default=5, min=2, max=200, update=_live("solid"),
                    description="w levels from the spine (0) to the surface (1), eq. 23")
    u_range: FloatVectorProperty(name="u Range", size=2, default=(0.0, 1.0), min=0.0, max=1.0,
                                 update=_live("solid"), description="Cutaway: u interval of the solid")
    v_range: FloatVectorProperty(name="v Range", size=2, default=(0.0, 2 * math.pi), min=-2 * math.pi,
                                 max=4 * math.pi, soft_min=0.0, soft_max=2 * math.pi, subtype="NONE",
                                 unit="ROTATION", update=_live("solid"),
                                 description="Cutaway: the angle interval around the head (v) the solid keeps, "
                                             "shown in degrees; may wrap past 360 (at most one turn)")
    w_range: FloatVectorProperty(name="w Range", size=2, default=(0.0, 1.0), min=0.0, max=1.0,
                                 update=_live("solid"), description="Cutaway: w interval of the solid")
    use_cutter: BoolProperty(name="Use Cutter", default=False, update=_live("cutter"),
                             description="The study's cutter box (an empty you move, rotate and scale) sets the "
                                         "u and v ranges: the solid is cut away where the box is")

    # Volume (live: material only)
    use_ct_grid: BoolProperty(name="CT Grid", default=False,
                              description="Sample the w-field on the CT's own voxel grid")
    voxel_auto: BoolProperty(name="Auto Voxel Size", default=True,
                             description="Voxel size from the CT spacing, coarsened only as far as needed to keep "
                                         "the .vdb small and the w-field fast (see volume.auto_voxel_size)")
    voxel_size: FloatProperty(name="Voxel Size", default=2.0, min=0.25, max=20.0,
                              description="Voxel size in mm of the volume grid (when CT Grid and Auto are off; "
                                          "with Auto on, the size the last build used)")
    low_alpha: FloatProperty(name="Low Alpha", default=0.1, min=0.0, max=1.0, update=_live("volume"),
                             description="l_alpha of eq. 24: opacity at the surface (w = 1)")
    high_alpha: FloatProperty(name="High Alpha", default=0.9, min=0.0, max=1.0, update=_live("volume"),
                              description="h_alpha of eq. 24: opacity at the spine (w = 0)")
    density: FloatProperty(name="Density", default=40.0, min=0.0, max=10000.0, update=_live("volume"),
                           description="Volume density scale (per metre)")
    colour_preset: EnumProperty(name="Transfer Function", items=COLOUR_ITEMS, default="grayscale",
                                update=_live("volume"),
                                description="Preset of the volume's colour ramp (colour and opacity over the CT "
                                            "intensity); the ramp itself is editable in the material")
    alpha_mode: EnumProperty(name="Alpha Mode", items=ALPHA_MODE_ITEMS, default="EQ24", update=_live("volume"))

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
                                  poll=lambda self, coll: getattr(coll.pdehead, "is_study", False),
                                  description="The PDE Head study shown in the sidebar")


CLASSES = (PDEHeadStudySettings, PDEHeadSceneSettings)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Collection.pdehead = PointerProperty(type=PDEHeadStudySettings)
    bpy.types.Scene.pdehead = PointerProperty(type=PDEHeadSceneSettings)


def unregister() -> None:
    for owner in (bpy.types.Scene, bpy.types.Collection):
        if hasattr(owner, "pdehead"):
            del owner.pdehead
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
