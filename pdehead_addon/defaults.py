"""The one table of user-facing defaults and ranges (bpy-free).

Every default a user of PDE Head sees - the add-on's study settings and operator options,
its preferences, the headless CLI (``scripts/pdehead.py``) and the benchmarks that measure
"the add-on's defaults" - is read from here, so a value is changed in one place.

Each entry is a :class:`Param`, registered under the name of the study setting it backs
(``PDEHeadStudySettings.<name>``), e.g. ``PARAMS["patches"]`` or the module attribute
:data:`PATCHES`. Adding a parameter is one line::

    MY_PARAM = _param("my_param", 1.0, min=0.0, max=2.0, unit="mm", description="...")

Notes
-----
The values follow the paper where it gives one (M = 256 samples, eq. 24's alpha range [0.1, 0.9]
of section 5.3; the paper's t = 10 patches became 15 so that the visible face keeps its detail) and
choices of this add-on measured on the data sets elsewhere (docs/benchmarks.md)
(the shape-change slice selection, the C2 surface, 120 x 240 mesh samples, density 40).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Param:
    """One user-facing parameter: its default and range.

    Parameters
    ----------
    name : str
        The study setting / operator option / CLI option (``--name`` with ``-`` for ``_``).
    default : bool, int, float, str or tuple
    min, max : float, optional
        Hard limits (Blender refuses values beyond them; the CLI checks them).
    soft_min, soft_max : float, optional
        The slider's range inside the hard limits (Blender only).
    unit : str
        For help texts ("mm", "deg", ""); angles are stored in radians.
    description : str
        One sentence for tooltips and ``--help``.
    choices : tuple of str
        The allowed values of an enumeration.
    label : str
        The property's name in Blender (sidebar, operator options), the same wherever it is shown.
    """

    name: str
    default: Any
    min: float | None = None
    max: float | None = None
    soft_min: float | None = None
    soft_max: float | None = None
    unit: str = ""
    description: str = ""
    choices: tuple = ()
    label: str = ""

    def limits(self) -> dict:
        """Keyword arguments ``default``, ``min``, ``max`` (and ``soft_min``/``soft_max``) for a
        ``bpy.props`` property; only those that are set."""
        out = {"default": self.default}
        for key in ("min", "max", "soft_min", "soft_max"):
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        return out

    def check(self, value, label: str | None = None):
        """``value`` if it lies within the hard limits / choices, else ``ValueError`` naming it."""
        label = label or self.name
        if self.choices and value not in self.choices:
            raise ValueError(f"{label} must be one of {', '.join(self.choices)}, got {value!r}")
        if self.min is not None and value < self.min:
            raise ValueError(f"{label} must be at least {self.min:g}, got {value}")
        if self.max is not None and value > self.max:
            raise ValueError(f"{label} must be at most {self.max:g}, got {value}")
        return value

    def help(self, text: str | None = None) -> str:
        """A ``--help`` line: ``text`` (else the description) and the default with its unit."""
        default = self.default
        if isinstance(default, float):
            default = f"{default:g}"
        unit = f" {self.unit}" if self.unit else ""
        return f"{text or self.description}; default {default}{unit}"


#: All parameters by name, in the order they were registered.
PARAMS: dict[str, Param] = {}


def _param(name: str, default, **kw) -> Param:
    if name in PARAMS:
        raise ValueError(f"default {name!r} is defined twice")
    PARAMS[name] = Param(name, default, **kw)
    return PARAMS[name]


def default(name: str):
    """The default value of parameter ``name``."""
    return PARAMS[name].default


# ----------------------------------------------------------------------------- boundaries (eq. 22)
#: 15, not the paper's 10: the face's largest distances from the scan come from the curves' spacing in
#: height (the underside of the nose, the mouth, the eyelids run almost horizontally between curves), so
#: closer curves bring the visible face nearer the scan for a somewhat larger boundary file (the
#: measures: docs/benchmarks.md, the face up close).
PATCHES = _param("patches", 15, min=1, max=60,
                 description="Number t of PDE patches; 3t+1 boundary curves are extracted", label="Patches (t)")
SAMPLES = _param("samples", 256, min=16, max=4096, description="Points per boundary curve", label="Samples (M)")
#: The paper's uniform choice loses the nose and lips at t = 10 with the paper's patches (the
#: interpolation between four curves folds where the face changes fast); shape-change keeps them;
#: auto (the default) chooses the curves whose surface is closest to every slice's outline: closer than
#: both to the outlines and to marching cubes on the test data sets at almost every t, for about a second
#: more (docs/benchmarks.md, section selection).
SELECTION = _param("selection", "auto", choices=("uniform", "shape-change", "auto"),
                   description="How the 3t+1 slices are chosen", label="Selection")
#: A tolerance instead of t: the fewest curves whose surface keeps within it of every
#: usable slice's outline (chosen or not), verified on the real surface.
USE_TOLERANCE = _param("use_tolerance", False,
                       description="Choose the number of curves for a tolerance instead of t (automatic selection)",
                       label="Tolerance Instead of t")
TOLERANCE_MM = _param("tolerance_mm", 0.5, min=0.0, max=20.0, soft_max=3.0, unit="mm",
                      description="Largest mean distance (mm) of the surface from every slice's outline; "
                                  "0 = no mean bound (then Max Tolerance)", label="Mean Tolerance")
MAX_TOLERANCE_MM = _param("max_tolerance_mm", 0.0, min=0.0, max=100.0, soft_max=10.0, unit="mm",
                          description="Largest distance (mm) of the surface from any slice's outline; 0 = no bound",
                          label="Max Tolerance")
ALIGN_CURVES = _param("align_curves", True,
                      description="Sample every curve at the same directions from a smooth spine, so that "
                                  "equal v joins corresponding points (no folds or cheek ripples); off: "
                                  "samples evenly spaced along each curve", label="Align Curves")

# ----------------------------------------------------------------------------- surface (eq. 1-13)
#: Fine enough that a nose (~30 mm wide) gets ~10 samples around v and the lips several along u;
#: surface(120, 240) builds in ~10-20 ms.
#: The maxima are what a live change can afford (a couple of seconds and GB per change; the measures:
#: docs/benchmarks.md, live changes); far finer grids take tens of seconds and several GB.
NU = _param("nu", 120, min=4, max=400,
            description="Resolution along the head axis (u); rebuilds the meshes at once", label="nu")
NV = _param("nv", 240, min=4, max=800,
            description="Resolution around the head (v); rebuilds the meshes at once", label="nv")
CAPS = _param("caps", True, description="Close the top and bottom of the surface", label="Caps")
CONTINUITY = _param("continuity", "c2", choices=("c2", "paper"),
                    description="Smooth: one Bloor-Wilson span between consecutive curves, C2 across every "
                                "curve (default). Paper: t patches through four curves each (eq. 3-6), "
                                "creased at the joints", label="Continuity")
DOME = _param("dome", True, description="Close the crown with a round dome through the vertex above the top "
                                        "curve (Smooth continuity)", label="Dome")
SMOOTHING_AUTO = _param("smoothing_auto", True,
                        description="Let the solver choose the smoothing parameter a of eq. 1", label="Auto Smoothing")
SMOOTHING = _param("smoothing", 0.0, min=0.0, max=1.0,
                   description="Smoothing parameter a of eq. 1 as a fraction of this study's maximum (Smooth: "
                               "the isotropic height/radius ratio; Paper: the largest stable a of each patch). "
                               "Every value solves", label="Smoothing (a)")
APPROXIMATION_AUTO = _param("approximation_auto", True,
                            description="Smooth along the head axis by the solver's default length (one slice "
                                        "step of the scan, at most half a curve gap)", label="Auto Approximation")
APPROXIMATION = _param("approximation", 0.0, min=0.0, max=1.0,
                       description="Approximating mode: how strongly the surface may leave the curves to smooth "
                                   "slice steps and streaks (0 = through every curve; 1 = a smoothing length of "
                                   "1.5 curve gaps). Smooth continuity only", label="Smooth Along Axis")
MODES = _param("modes", 0, min=0, max=512,
               description="Harmonics kept around each ring (0 = all: the surface passes through the curves; "
                           "fewer: eq. 13's truncated series, a simpler head)", label="Fourier Modes")

# ----------------------------------------------------------------------------- solid (eq. 23), cutaway
NW = _param("nw", 5, min=2, max=200, description="w levels from the spine (0) to the surface (1), eq. 23", label="nw")
U_RANGE = _param("u_range", (0.0, 1.0), min=0.0, max=1.0, description="Cutaway: u interval of the solid",
                 label="u Range")
V_RANGE = _param("v_range", (0.0, 2 * math.pi), min=-2 * math.pi, max=4 * math.pi, soft_min=0.0,
                 soft_max=2 * math.pi, unit="rad",
                 description="Cutaway: the angle interval around the head (v) the solid keeps, shown in "
                             "degrees; may wrap past 360 (at most one turn)", label="v Range")
W_RANGE = _param("w_range", (0.0, 1.0), min=0.0, max=1.0, description="Cutaway: w interval of the solid",
                 label="w Range")
#: The solid's CT atlas. Its cut faces get tiles sized from their own extent in mm (about one
#: texel per finest CT voxel) within this many pixels; the outside shows the skin (the surface's material)
#: unless ``solid_skin`` is "ct" (the CT ``solid_skin_depth`` mm inside the skin: the skin itself is a
#: partial-volume mix of air and tissue, mottled or banded).
CT_TEXTURE_BUDGET = _param("ct_texture_budget", 4.0, min=0.25, max=64.0, unit="megapixels",
                           description="Pixels of the solid's CT texture: its cut faces at up to one texel per CT "
                                       "voxel within this budget", label="CT Texture (MP)")
SOLID_SKIN = _param("solid_skin", "surface", choices=("surface", "ct"),
                    description="What the solid's outside shows: the surface's skin material, or the CT a little "
                                "inside the skin", label="Outside")
SOLID_SKIN_DEPTH = _param("solid_skin_depth", 2.0, min=0.0, max=20.0, unit="mm",
                          description="With solid_skin 'ct': how far inside the skin the CT is sampled",
                          label="Skin Depth (mm)")
USE_CUTTER = _param("use_cutter", False,
                    description="The study's cutter box (an empty you move, rotate and scale) sets the u and v "
                                "ranges: the solid is cut away where the box is", label="Use Cutter")

# ----------------------------------------------------------------------------- CT detail map
#: The CT detail layer: the CT's fine relief (eyelids, lips, nostrils) as a height map in the surface's
#: UVs (:func:`pdehead_addon.pde.detail_map.ct_detail_map`), applied as real displacement of the smooth PDE
#: surface along its normals (a Displace modifier after a subdivision in Blender,
#: :func:`pdehead_addon.pde.detail_displace.detail_surface` for the exports). 1024 x 1024 is about 0.6 mm a
#: texel on CThead's tube (its eyelid line is ~1 mm high). Off by default: building it costs seconds and
#: ~0.4 GB (CThead, docs/method.md "The closed eyes: a CT detail map"), which Run Pipeline's <= 5 s
#: cannot carry; on, Run Pipeline builds it, and the Surface panel's *Build CT Detail* builds it on
#: request. Strength 0 (the default) is the PDE surface itself.
USE_DETAIL_MAP = _param("use_detail_map", False,
                        description="The CT detail layer: the CT's fine relief (eyelids, lips, nostrils) as a "
                                    "displacement of the smooth PDE surface along its normals, at Detail Strength "
                                    "(the surface and Export for Printing). Built by Build CT Detail (seconds) or by "
                                    "Run Pipeline while on",
                        label="CT Detail")
DETAIL_STRENGTH = _param("detail_strength", 0.0, min=0.0, max=10.0, soft_max=3.0,
                         description="Strength of the CT detail displacement: 0 = the smooth PDE surface, 1 = the "
                                     "CT's skin (its relief at its true height in mm)",
                         label="Detail Strength")
DETAIL_RESOLUTION = _param("detail_resolution", 1024, min=64, max=4096, unit="pixels",
                           description="Side of the square CT detail map (used at its next build; 1024 is about "
                                       "0.6 mm a texel on an adult head)", label="Detail Map Size")
#: The Gaussian of the head mask whose 0.5 level is the skin the map reaches (mm): marching cubes of the
#: mask smoothed by 1.2 mm shows CThead's upper eyelid edge; the slice axis gets at least 0.6 slice steps
#: (``detail_map.SLICE_SIGMA``).
DETAIL_SIGMA = _param("detail_sigma", 1.2, min=0.3, max=5.0, unit="mm",
                      description="Smoothing of the head mask before its skin is found (mm)", label="Detail Smoothing")
#: How far along the surface's normal the skin is looked for, either side (mm); the map's values lie within.
DETAIL_MAX_OFFSET = _param("detail_max_offset", 3.0, min=0.5, max=10.0, unit="mm",
                           description="Largest offset of the CT's skin from the surface the detail map holds (mm)",
                           label="Detail Range")

# ----------------------------------------------------------------------------- volume (eq. 24)
USE_CT_GRID = _param("use_ct_grid", False, description="Sample the w-field on the CT's own voxel grid", label="CT Grid")
VOXEL_AUTO = _param("voxel_auto", True,
                    description="Voxel size from the CT spacing, coarsened only as far as needed to keep the .vdb "
                                "small and the w-field fast (see volume.auto_voxel_size)", label="Auto Voxel Size")
VOXEL_SIZE = _param("voxel_size", 2.0, min=0.25, max=20.0, unit="mm",
                    description="Voxel size in mm of the volume grid (when CT Grid and Auto are off; with Auto "
                                "on, the size the last build used)", label="Voxel Size")
LOW_ALPHA = _param("low_alpha", 0.1, min=0.0, max=1.0,          # section 5.3: alpha in [0.1, 0.9]
                   description="l_alpha of eq. 24: opacity at the surface (w = 1)", label="Low Alpha")
HIGH_ALPHA = _param("high_alpha", 0.9, min=0.0, max=1.0,
                    description="h_alpha of eq. 24: opacity at the spine (w = 0)", label="High Alpha")
#: Cycles extinction per metre at alpha = 1: a ~0.2 m head is translucent, the face still readable.
DENSITY = _param("density", 40.0, min=0.0, max=10000.0, unit="1/m",
                 description="Volume density scale (per metre)", label="Density")
#: Emission per unit density: the alpha-blended texture look of the paper.
EMISSION = _param("emission", 0.7, min=0.0, description="Volume emission per unit density")
COLOUR_PRESET = _param("colour_preset", "grayscale", choices=("grayscale", "skin", "bone", "xray"),
                       description="Preset of the volume's colour ramp (colour and opacity over the CT "
                                   "intensity); the ramp itself is editable in the material", label="Transfer Function")
ALPHA_MODE = _param("alpha_mode", "EQ24", choices=("EQ24", "INTENSITY"),
                    description="Opacity from eq. 24's w, or from the CT intensity (the paper's baseline)",
                    label="Alpha Mode")
#: The budget of the automatic voxel size (operators/volume/vdb_grids.auto_voxel_size): the .vdb stays below
#: this many bytes (the files beside the .blend stay small) ...
MAX_VDB_BYTES = _param("max_vdb_bytes", 64 * 2 ** 20, min=1, unit="bytes",
                       description="Largest .vdb the automatic voxel size allows")
#: ... and the w-field grid below this many voxels (0.15-0.2 us per voxel on CThead, 2 shared cores: ~1 s).
MAX_WFIELD_VOXELS = _param("max_wfield_voxels", 5_000_000, min=1,
                           description="Largest w-field grid the automatic voxel size allows")

# ----------------------------------------------------------------------------- what a .blend may hold
#: Budgets of the data a .blend stores for a study, checked when it is read (a .blend is data: a tampered
#: file must not make PDE Head allocate gigabytes). The boundary curves: a few hundred kB at most (a 3t+1
#: = 151 curves x 1024 samples x 3 coordinates x 8 byte planes is 3.7 MB); the solid's CT table: 8-bit,
#: at most about 4.2 MB at the texture budget's largest solid (persistence.py).
MAX_STORED_BOUNDARY_BYTES = _param("max_stored_boundary_bytes", 16 * 2 ** 20, min=1, unit="bytes",
                                   description="Largest decompressed boundary payload read from a .blend")
MAX_STORED_CT_TABLE_BYTES = _param("max_stored_ct_table_bytes", 64 * 2 ** 20, min=1, unit="bytes",
                                   description="Largest decompressed solid CT table read from a .blend")

# ----------------------------------------------------------------------------- import
DOWNSAMPLE = _param("downsample", 1, min=1, max=8,
                    description="Average blocks of N x N x N voxels on import (for very large scans: 2 needs "
                                "about 1/8 of the memory)", label="Downsample")
#: Headerless stacks (raw slices, numbered images): where the first file lies. "auto" (the default of the
#: engine's ``load_ct``, the import dialog's First Slice and the CLI's ``--first-slice``): the first file is
#: inferior (orientation LPS: row 0 anterior, column 0 the patient's right, later files superior) unless the
#: head's crown - the end whose cross-section closes to nothing inside the scan - lies at the first file; then
#: the stack is read the other way round (first file superior) and a warning says so. An explicit value (or
#: an orientation code) always wins. DICOM and NIfTI carry their own geometry. (Not a Param: the dialog's
#: enumeration spells it in capitals, AUTO / SUPERIOR / INFERIOR.)
FIRST_SLICE = "auto"
FIRST_SLICE_CHOICES = ("auto", "superior", "inferior")
#: Import limits, checked BEFORE anything is allocated or decompressed (not Params: nothing a user sets).
#: The float32 volume (and the source samples) a file's header asks for must fit this many bytes: 8 GB is a
#: 2000-slice 1024 x 1024 scan, four times the largest segment_head takes without downsampling.
IMPORT_MEMORY_BUDGET_BYTES = 8 * 2 ** 30
#: Compressed inputs (.nii.gz, gzipped raw, compressed TIFF or DICOM) may decode to at most this many times
#: their stored bytes once they decode to more than IMPORT_RATIO_FLOOR_BYTES: CT slices compress 2-10 times
#: (an all-air slice a few hundred times, but it is small); deflate's own ceiling is 1032:1.
IMPORT_MAX_COMPRESSION_RATIO = 64
IMPORT_RATIO_FLOOR_BYTES = 64 * 2 ** 20
#: Streams are decompressed in chunks of this many bytes (never more than the header asks for).
IMPORT_CHUNK_BYTES = 8 * 2 ** 20

# ----------------------------------------------------------------------------- animation
#: 120 frames: a 5-second orbit at 24 fps, each frame 3 degrees on.
TURNTABLE_FRAMES = _param("turntable_frames", 120, min=2, max=10000,
                          description="Frames of one camera orbit around the study (the scene's frame range)",
                          label="Frames")

# ----------------------------------------------------------------------------- views
#: The named views of renders, Frame Study and the CLI's ``--view``: name -> (label, description). Each view's
#: camera direction is in operators/scene/render.py (``VIEWS``); Frame Study offers all but TOP.
VIEWS = {"FRONT": ("Front", "The face (Blender's front view)"),
         "RIGHT": ("Right", "The patient's right side"),
         "LEFT": ("Left", "The patient's left side"),
         "BACK": ("Back", "The back of the head"),
         "TOP": ("Top", "From above (Blender's top view)"),
         "THREE_QUARTER": ("Three Quarter", "From front right, above")}
VIEW = _param("view", "FRONT", choices=tuple(VIEWS), description="The view to render or frame", label="View")

# ----------------------------------------------------------------------------- forensic
#: The bone level in the scan's stored units (HU where calibrated). Off: the documented rule of
#: :func:`pdehead_addon.forensic.skull.segment_skull` (HU scans: half way between the soft-tissue and bone modes,
#: 400 HU without them; uncalibrated scans without soft tissue: half way between the air and bone modes).
USE_BONE_LEVEL = _param("use_bone_level", False,
                        description="Set the bone level yourself (in the scan's stored units); off: the "
                                    "documented automatic level", label="Set Bone Level")
BONE_LEVEL = _param("bone_level", 400.0, min=-5000.0, max=100000.0,
                    description="Bone level in the scan's stored units (HU where calibrated): from this level "
                                "on, the skull is the bone mask alone", label="Bone Level")

# ----------------------------------------------------------------------------- face from skull
#: The label every face-from-skull output carries (mesh names, file headers, provenance).
FACE_LABEL = "approximation — not an identification"
FACE_NU = _param("face_nu", 160, min=8, max=400, description="Face from skull: mesh rows (along the head)")
FACE_NV = _param("face_nv", 320, min=16, max=800, description="Face from skull: mesh columns (around the head)")
FACE_DEPTH_SD = _param("face_depth_sd", 2.0, min=0.0, max=4.0,
                       description="Face from skull: how far a peg's depth may be set from the table's mean, "
                                   "in the table's SDs")
FACE_ROW_MM = _param("face_row_mm", 2.5, min=1.0, max=10.0, unit="mm",
                     description="Face from skull: spacing of the boundary curves along the head")
FACE_COLUMNS = _param("face_columns", 360, min=90, max=720,
                      description="Face from skull: samples of each boundary curve around the head (360: 1 degree, "
                                  "~1.7 mm at the face; the nose's alae and the lips' outline need it)")
FACE_SPREAD_MM = _param("face_spread_mm", 22.0, min=5.0, max=80.0, unit="mm",
                        description="Face from skull: how far a peg's depth spreads over the skull (Gaussian radius)")
#: A peg whose tip is farther than this (mm) from the solved face is listed (panel, provenance, CLI warning): the
#: practitioner reads the face as passing through the tips, and the T-Table's SDs are 1-3 mm at most landmarks, so a
#: tip 2 mm off is a visible share of the table's own spread.
FACE_PEG_OFF_MM = 2.0
#: A peg whose depth along its own axis (tip minus base, along the bone normal it stands on) is below this (mm) has
#: its tip in the bone: no soft tissue has a negative thickness. Warned, the face still solves.
FACE_PEG_MIN_DEPTH_MM = 0.0
#: A peg whose tip lies farther than this (mm) from its axis (the line from its landmark along the bone normal) has
#: been moved off its landmark: the automatic landmarks sit within a few mm of an expert's, so
#: 10 mm is a peg that no longer measures the landmark the table's depth is for. Warned, the face still solves.
FACE_PEG_MAX_DRIFT_MM = 10.0
#: A peg deeper than the table's mean + this many SDs is warned: beyond 3 SD lies ~0.1 % of a normal population
#: (and a peg dragged far out by mistake). Pegs whose table has no SD are judged by the drift alone.
FACE_PEG_MAX_DEPTH_SD = 3.0
#: How far below the skull's lowest bone the face ends (its flat neck cap) when the skull has a chin: the neck
#: under the mandible; no measurement of a head, a length that shows a neck. A CT that stops above the chin
#: (GE: at the orbits' floor at the front) holds no neck, and the face then ends :data:`FACE_CUT_MARGIN_MM` beyond
#: the scan's cut.
FACE_NECK_MM = _param("face_neck_mm", 40.0, min=0.0, max=120.0, unit="mm",
                      description="Face from skull: the neck below the skull's lowest bone (a skull with a chin)")
#: ... and without a chin: the least soft tissue (:data:`FACE_MIN_TISSUE_MM`) plus two rows of the face
#: (:data:`FACE_ROW_MM`), rounded up: the lowest bone lies inside the rows that keep it covered, above the cap.
#: The face ends this far beyond the scan's cut (:func:`pdehead_addon.forensic.face_profile.scan_cut_plane`: GE's
#: 18.5-degree slab), along it; where no cut is found, at the lowest row of the whole head's grid within this margin
#: under the lowest bone.
FACE_CUT_MARGIN_MM = _param("face_cut_margin_mm", 7.0, min=0.0, max=40.0, unit="mm",
                            description="Face from skull: how far the face runs beyond the scan's cut when the "
                                        "skull has no mandible (the scan stopped above the chin)")
#: The least soft tissue over the bone anywhere on the face: the T-Table 2023's thinnest landmark, rhinion
#: (3.0 mm, SD 1.0), less one SD. Every row of the face keeps at least this much outside the outermost bone at
#: its height and angle (:func:`pdehead_addon.forensic.face_profile.bone_floor`), so no bone comes through the
#: face, whatever the depth field, the pegs (a dragged peg down to 0 mm) or the features do.
FACE_MIN_TISSUE_MM = _param("face_min_tissue_mm", 2.0, min=0.0, max=10.0, unit="mm",
                            description="Face from skull: least soft tissue over the bone anywhere on the face")

# ----------------------------------------------------------------------------- forensic operators
#: The skull the forensic steps measure on / snap to (operators/forensic/props.py TARGET_ITEMS).
DEPTH_TARGET = _param("depth_target", "BONE", choices=("BONE", "PDE"), label="Skull",
                      description="The skull measured on or snapped to: the bone skull (smoothed marching cubes "
                                  "of the bone) or the smooth PDE skull envelope")
MAX_DEPTH = _param("max_depth", 40.0, min=1.0, max=100.0, unit="mm", label="Max Depth",
                   description="Longest depth searched (mm); deeper: no value")
SKULL_NU = _param("skull_nu", 0, min=0, max=2000, label="u Resolution", description="0: the skin's")
SKULL_NV = _param("skull_nv", 0, min=0, max=4000, label="v Resolution", description="0: the skin's")
BONE_MESH = _param("bone_mesh", True, label="Bone Skull",
                   description="Also build the bone skull (smoothed marching cubes of the bone)")
BONE_STEP = _param("bone_step", 1, min=1, max=4, label="Bone Step", description="Marching-cubes step (voxels)")
KEEP_EDITED = _param("keep_edited", True, label="Keep Edited",
                     description="Leave the landmarks placed or moved by hand where they are")
MIRROR_PLANE = _param("mirror_plane", "AUTO", choices=("AUTO", "LANDMARKS", "SKULL"), label="Plane",
                      description="Where the mid-sagittal plane comes from")
EXPORT_FORMAT = _param("export_format", "stl", choices=("stl", "obj", "ply"), label="Format",
                       description="Mesh format of Export for Printing")
DEPTH_DISPLAY_MAX = _param("depth_display_max", 25.0, min=1.0, max=100.0, unit="mm",
                           description="Tissue depth at the red end of the depth map's colour ramp")
PEG_RADIUS = _param("peg_radius", 1.5, min=0.1, max=10.0, unit="mm", description="Radius of a marker peg")

# ----------------------------------------------------------------------------- renders and the one-click run
#: The CLI's renders (``--render``, ``--render-volume``, ``--render-animation``): Cycles on the CPU, small and quick.
RENDER_RESOLUTION = _param("resolution", 320, min=16, unit="px", description="Render size in pixels (square)",
                           label="Resolution")
RENDER_SAMPLES = _param("render_samples", 16, min=1, description="Cycles samples per pixel", label="Render Samples")
#: What a one-click run builds: *Run Pipeline* builds the volume too (the CLI's ``--no-volume`` skips it);
#: *Import CT* builds the head only when asked (``Build the Head``).
BUILD_VOLUME = _param("build_volume", True, description="Also build the volume", label="Volume")
RUN_PIPELINE = _param("run_pipeline", False,
                      description="Run segmentation, boundaries, surface and solid after importing",
                      label="Build the Head")
#: The study object Frame Study (and the pipeline's last step) shows; the others overlap it and are hidden.
SHOW = _param("show", "SURFACE", choices=("SURFACE", "SOLID", "VOLUME", "CURVES"),
              description="The study object to show (the others are hidden)", label="Show")

# ----------------------------------------------------------------------------- import options
#: What *Import CT* offers for headerless data before the user changes it: CThead's raw slices (256 x 256
#: big-endian int16), 1 mm voxels. The CLI has no such defaults: ``--raw-shape``, ``--dtype`` and
#: ``--spacing`` must be given for raw data.
RAW_SHAPE = _param("raw_shape", (256, 256), min=1, label="Slice Shape",
                   description="Raw slices: rows, columns (ny, nx)")
RAW_DTYPE = _param("raw_dtype", "i2", choices=("i2", "u2", "u1", "i4", "f4"), label="Data Type",
                   description="Raw samples: numpy kind and bytes")
BYTE_ORDER = _param("byte_order", "BIG", choices=("BIG", "LITTLE"), label="Byte Order",
                    description="Raw samples of more than one byte: most significant byte first (BIG) or last")
USE_SPACING = _param("use_spacing", False, label="Set Spacing",
                     description="Give the voxel size (needed for raw and image stacks without headers)")
#: Named apart from the study setting ``spacing`` (the CT's measured voxel size, read-only).
IMPORT_SPACING = _param("import_spacing", (1.0, 1.0, 1.0), min=1e-3, unit="mm", label="Spacing (dz, dy, dx)",
                        description="Voxel size in mm: slice step, row step, column step")
