"""Forensic toolkit in Blender: the operators and the sidebar panel (steps: :class:`.study.ForensicStudy`).

Build Skull, Tissue Depth, Place Landmark, Depth Table, Depths CSV, Frankfurt, Mirror and Export
for Printing: each reads its options, calls one step of the study's :class:`.study.ForensicStudy`
and reports. The skull they measure on (``target``) and the longest depth searched are remembered in the
study's forensic settings (:mod:`.props`) and offered again when an operator is invoked from the UI.
"""
from __future__ import annotations

import json
import os

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, FloatVectorProperty, IntProperty, StringProperty
from bpy.types import Operator, Panel
from mathutils import Vector

from ...pdehead_addon import (
    STANDARD_LANDMARKS,
    PDEHeadError,
    default_table,
    defaults as D,
    read_depth_table,
    write_landmark_csv,
)
from .. import state
from ..forensic.export import PEG_DEPTH_PROP
from ..forensic.face import FACE_KEY, HELD_PROP, LABEL_PROP, PROVENANCE_PROP, table_has_sex
from ..forensic.props import TARGET_ITEMS, max_depth_property
from ..forensic.skull import DEPTH_ATTRIBUTE, DEPTH_MATERIAL
from ..forensic.study import MIRROR_PLANES, ForensicStudy
from ..study.entity import Study
from .base import StudyOperator

_LANDMARK_ITEMS = [(d.name, d.name, d.description) for d in STANDARD_LANDMARKS]
_FORMAT_ITEMS = [('stl', "STL", ""), ('obj', "OBJ", ""), ('ply', "PLY", "")]


# ------------------------------------------------------------------------------------------ reports
# What the operators report of a step's outcome; the CLI (scripts/pdehead.py) prints the same lines.

def skull_report(fs, outcome) -> str:
    """Build Skull's INFO report of ``fs.skull.step_skull()``'s outcome."""
    return f"Skull of '{fs.name}' built"


def depth_report(outcome) -> str:
    """Tissue Depth's INFO report of ``fs.skull.step_depth()``'s outcome."""
    st = outcome.values
    return (f"Tissue depth: {st['measured']} of {st['vertices']} vertices measured, "
            f"median {st.get('median', float('nan')):.1f} mm")


def landmarks_report(outcome) -> tuple[str, str]:
    """Find Landmarks' report of ``fs.find_landmarks()``'s outcome: (level, text), a WARNING naming the first
    landmark not found and why."""
    flags = outcome.values["flags"]
    counts = list(flags.values())
    msg = (f"{counts.count('ok')} landmarks ok, {counts.count('uncertain')} uncertain, "
           f"{counts.count('not_found')} not found")
    missing = [n for n, flag in flags.items() if flag == 'not_found']
    if missing:
        return 'WARNING', f"{msg} (e.g. {missing[0]}: {outcome.values['evidence'][missing[0]]})"
    return 'INFO', msg


def export_report(outcome) -> list[str]:
    """Export for Printing's INFO reports of ``fs.outputs.export()``'s outcome: the files written, and those left out
    and why."""
    lines = ["Wrote " + ", ".join(os.path.basename(f) for f in outcome.values["files"])]
    left = {}                                           # why -> the files left out for it
    for name, why in outcome.values["not_written"].items():
        left.setdefault(why, []).append(name)
    if left:
        lines.append("; ".join(f"{' and '.join(names)} not written: {why}" for why, names in left.items()))
    return lines


# ------------------------------------------------------------------------------------------ operators
def _target_property(label: str = D.DEPTH_TARGET.label):
    return EnumProperty(name=label, items=TARGET_ITEMS, default=D.DEPTH_TARGET.default,
                        description=D.DEPTH_TARGET.description)


class _ForensicOp(StudyOperator):
    """A forensic operator: ``run_forensic(context, fs)`` on the study's :class:`.study.ForensicStudy`.

    Its ``target`` / ``max_depth`` (where it has them) are the study's forensic settings: offered again when
    invoked from the UI, recorded when run."""

    bl_options = {'REGISTER', 'UNDO'}
    #: Operator properties that are forensic settings of the study (:class:`.props.PDEHeadForensicSettings`).
    forensic_settings = ()

    def invoke(self, context, event):
        self.offer_forensic_settings(context)
        return self.execute(context)

    def offer_forensic_settings(self, context) -> None:
        study = Study.active(context, self.study)
        if study is not None and self.forensic_settings:
            p = ForensicStudy.of(study).props
            for name in self.forensic_settings:
                setattr(self, name, getattr(p, name))

    def run(self, context, study):
        fs = ForensicStudy.of(study)
        for name in self.forensic_settings:
            setattr(fs.props, name, getattr(self, name))
        return self.run_forensic(context, fs)

    def run_forensic(self, context, fs: ForensicStudy):
        raise NotImplementedError(type(self).__name__)


class PDEHEAD_OT_build_skull(Operator, _ForensicOp):
    """Segment the skull from the CT and build it as a PDE surface (and a marching-cubes bone mesh)"""

    bl_idname = "pdehead.build_skull"
    bl_label = "Build Skull"
    nu: IntProperty(name=D.SKULL_NU.label, **D.SKULL_NU.limits(), description=D.SKULL_NU.description)
    nv: IntProperty(name=D.SKULL_NV.label, **D.SKULL_NV.limits(), description=D.SKULL_NV.description)
    bone_mesh: BoolProperty(name=D.BONE_MESH.label, **D.BONE_MESH.limits(), description=D.BONE_MESH.description)
    bone_step: IntProperty(name=D.BONE_STEP.label, **D.BONE_STEP.limits(), description=D.BONE_STEP.description)

    def run_forensic(self, context, fs):
        outcome = fs.skull.step_skull(self.nu, self.nv, self.bone_mesh, self.bone_step)
        self.report({'INFO'}, skull_report(fs, outcome))


class PDEHEAD_OT_tissue_depth(Operator, _ForensicOp):
    """Compute the soft-tissue depth of every skin vertex (along the inward normal to the skull) and show it"""

    bl_idname = "pdehead.tissue_depth"
    bl_label = "Tissue Depth"
    target: _target_property()
    max_depth: max_depth_property()
    forensic_settings = ("target", "max_depth")

    def run_forensic(self, context, fs):
        self.report({'INFO'}, depth_report(fs.skull.step_depth(self.target, self.max_depth)))


class PDEHEAD_OT_place_landmark(Operator, _ForensicOp):
    """Place a craniometric landmark at the 3D cursor, snapped to the skull surface"""

    bl_idname = "pdehead.place_landmark"
    bl_label = "Place Landmark"
    name: EnumProperty(name="Landmark", items=_LANDMARK_ITEMS)
    location: FloatVectorProperty(name="Location", size=3, subtype='TRANSLATION', options={'SKIP_SAVE'},
                                  description="World location (default: the 3D cursor)")
    use_location: BoolProperty(default=False, options={'SKIP_SAVE', 'HIDDEN'})
    target: _target_property("Snap To")
    forensic_settings = ("target",)

    def run_forensic(self, context, fs):
        world = Vector(self.location) if self.use_location else context.scene.cursor.location.copy()
        obj = fs.place_landmark(self.name, fs.world_to_patient(world), self.target)
        self.report({'INFO'}, f"{obj.name} at {np.round(obj['patient_mm'], 1).tolist()} mm")


class PDEHEAD_OT_find_landmarks(Operator, _ForensicOp):
    """Find every craniometric landmark on the bone automatically (Frankfurt alignment first), each with a
    flag: ok, uncertain or not found"""

    bl_idname = "pdehead.find_landmarks"
    bl_label = "Find Landmarks"
    target: _target_property("Snap To")
    keep_edited: BoolProperty(name=D.KEEP_EDITED.label, **D.KEEP_EDITED.limits(),
                              description=D.KEEP_EDITED.description)
    forensic_settings = ("target",)

    def run_forensic(self, context, fs):
        level, text = landmarks_report(fs.find_landmarks(self.target, self.keep_edited))
        self.report({level}, text)


class PDEHEAD_OT_snap_landmarks(Operator, _ForensicOp):
    """Put the landmarks moved in the viewport back onto the bone (nearest point); they count as placed by hand"""

    bl_idname = "pdehead.snap_landmarks"
    bl_label = "Snap Moved Landmarks"
    target: _target_property("Snap To")
    forensic_settings = ("target",)

    def run_forensic(self, context, fs):
        names = fs.snap_moved_landmarks(self.target).values["names"]
        self.report({'INFO'}, f"{len(names)} landmark(s) snapped to the bone" +
                    (": " + ", ".join(names[:4]) if names else ""))


class _LandmarkCSVOp(_ForensicOp):
    """A landmark CSV picked in the file browser, measured on the chosen skull."""

    filepath: StringProperty(subtype='FILE_PATH')
    filter_glob: StringProperty(default="*.csv", options={'HIDDEN'})
    target: _target_property()
    forensic_settings = ("target",)
    default_name = ""   # the file name the browser proposes (writers only)

    def invoke(self, context, event):
        self.offer_forensic_settings(context)
        if self.default_name:
            self.filepath = self.default_name
        context.window_manager.fileselect_add(self)
        return {'RUNNING_MODAL'}


class PDEHEAD_OT_import_depth_table(Operator, _LandmarkCSVOp):
    """Put marker pegs on the skull at the placed landmarks, their length the depth table's mean (along the
    bone normal); each peg's length can be set within mean +- 2 SD. The shipped T-Table 2023 or a CSV
    (landmark,mean_mm[,sd_mm,n] or landmark,depth_mm; our names or Caple & Stephan codes)"""

    bl_idname = "pdehead.import_depth_table"
    bl_label = "Import Depth Table"
    default_table: BoolProperty(name="Default Table", default=False,
                                description="Use the shipped T-Table 2023 (Hona & Stephan 2024) instead of a file")

    def invoke(self, context, event):
        if self.default_table:
            return self.execute(context)
        return super().invoke(context, event)

    def run_forensic(self, context, fs):
        if self.default_table or not self.filepath:
            table = default_table()
        else:
            table = read_depth_table(bpy.path.abspath(self.filepath))
        pegs = fs.outputs.make_pegs(table, self.target)
        self.report({'INFO'}, f"{len(pegs)} marker pegs from {table.label}")


class PDEHEAD_OT_export_landmark_depths(Operator, _LandmarkCSVOp):
    """Export landmarks.csv: each placed landmark (patient mm), its measured tissue depth along the bone normal,
    the depth table's mean and SD and the flag, with the provenance (software, table, bone level) in its header"""

    bl_idname = "pdehead.export_landmark_depths"
    bl_label = "Export Landmark Depths"
    default_name = "landmarks.csv"

    def run_forensic(self, context, fs):
        if not fs.landmarks():
            raise PDEHeadError("no landmarks placed yet")
        depths, flags, method = fs.outputs.measured_landmark_depths(fs.skull.skull_engine_mesh(self.target),
                                                            fs.skull.skin_engine_mesh())
        table = fs.outputs.depth_table()
        n = write_landmark_csv(bpy.path.abspath(self.filepath), depths, table, flags,
                               provenance=dict(fs.outputs.provenance(table), depth=method))
        self.report({'INFO'}, f"{n} landmark depths written to {self.filepath} ({method.split(' (')[0]})")


class PDEHEAD_OT_frankfurt(Operator, _ForensicOp):
    ("Align the study's objects to the Frankfurt horizontal (porion and orbitale landmarks); "
     "patient coordinates stay")

    bl_idname = "pdehead.frankfurt"
    bl_label = "Frankfurt Horizontal"
    reset: BoolProperty(name="Reset", default=False, description="Back to patient coordinates")

    def run_forensic(self, context, fs):
        fs.apply_frankfurt(self.reset)


class PDEHEAD_OT_mirror(Operator, _ForensicOp):
    """Mirror the active object across the mid-sagittal plane: from bilateral landmark pairs or the skull's symmetry"""

    bl_idname = "pdehead.mirror"
    bl_label = "Mirror Across Mid-Sagittal Plane"
    plane: EnumProperty(name=D.MIRROR_PLANE.label, items=MIRROR_PLANES, default=D.MIRROR_PLANE.default,
                        description=D.MIRROR_PLANE.description)

    def run_forensic(self, context, fs):
        obj = context.active_object or fs.linked_object("pdehead_skull_object")
        if obj is None:
            raise PDEHeadError("select the object to mirror")
        outcome = fs.mirror_object(obj, self.plane)
        plane = outcome.values
        self.report({'INFO'}, f"{outcome.objects[0].name}: plane from {plane['how']}, through "
                              f"{np.round(plane['point'], 1).tolist()} mm, "
                              f"normal {np.round(plane['normal'], 3).tolist()}")


class PDEHEAD_OT_export_print(Operator, _ForensicOp):
    """Export watertight meshes in mm (STL/OBJ/PLY): skull (the bone), skull_envelope (PDE), skin; tissue_depth.csv,
    landmarks.csv and provenance.json; skin and tissue_depth.csv only after the head pipeline (it says what it left
    out). Builds what it needs first; writes nothing if anything fails"""

    bl_idname = "pdehead.export_print"
    bl_label = "Export for Printing"
    directory: StringProperty(subtype='DIR_PATH')
    format: EnumProperty(name=D.EXPORT_FORMAT.label, items=_FORMAT_ITEMS, default=D.EXPORT_FORMAT.default,
                         description=D.EXPORT_FORMAT.description)

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {'RUNNING_MODAL'}

    def run_forensic(self, context, fs):
        for line in export_report(fs.outputs.export(self.directory, self.format)):
            self.report({'INFO'}, line)


class PDEHEAD_OT_build_face(Operator, _ForensicOp):
    """Build the face from the skull: a smooth face solved through the tissue-depth pegs (the study's table),
    as its own object with the pegs as its children; drag a peg or change its depth and the face follows.
    An approximation, not an identification"""

    bl_idname = "pdehead.build_face"
    bl_label = "Build Face"

    def run_forensic(self, context, fs):
        outcome = fs.face.build_face()
        self.report({'INFO'}, f"{outcome.objects[0].name}: {outcome.values['vertices']} vertices through "
                              f"{outcome.values['pegs']} pegs ({outcome.values['label']})")
        for line in outcome.warnings:
            self.report({'WARNING'}, line + " (hold a peg in the panel to make the face pass through it)")


class PDEHEAD_OT_face_sd_range(Operator, _ForensicOp):
    """Build the faces with every peg at its length - 1 SD and + 1 SD of the table (wire objects beside the
    face): the range the depth table allows"""

    bl_idname = "pdehead.face_sd_range"
    bl_label = "Faces at -1 / +1 SD"

    def run_forensic(self, context, fs):
        made = fs.face.build_sd_faces().objects
        self.report({'INFO'}, "Built " + ", ".join(o.name for o in made))


def draw_face_section(layout, fs) -> None:
    """The panel's Face from Skull section: table (and sex where the table has it), Find Landmarks,
    Build Face, the pegs to drag and their depths, the +-1 SD faces, the label and provenance."""
    box = layout.box()
    box.label(text="Face from Skull", icon='USER')
    s = fs.settings
    box.prop(s, "face_table", text="Table")
    if s.face_table == 'FILE':
        box.prop(s, "face_table_file", text="")
    try:
        table = fs.face.face_table_as_read()
    except PDEHeadError as exc:
        table = None
        box.label(text=str(exc), icon='ERROR')
    if table is not None and table_has_sex(table):
        box.prop(s, "face_sex")
        try:
            fs.face.face_table()                   # the chosen sex's rows: a sex the table lacks says so here
        except PDEHeadError as exc:
            box.label(text=str(exc), icon='ERROR')
    row = box.row(align=True)
    row.operator(PDEHEAD_OT_find_landmarks.bl_idname, icon='VIEWZOOM')
    row.operator(PDEHEAD_OT_build_face.bl_idname, icon='USER')
    obj = fs.face.face_object()
    if obj is None:
        box.label(text="Builds the skull and finds the landmarks first if needed")
        return
    box.label(text=str(obj.get(LABEL_PROP, "")), icon='ERROR')
    prov = json.loads(obj.get(PROVENANCE_PROP, "{}") or "{}")
    col = box.column(align=True)
    if prov.get("table"):
        col.label(text=f"Table: {prov['table']}" + (f", {prov['sex']}" if prov.get("sex") else ""))
    flags = list((prov.get("landmarks") or {}).values())
    if flags:
        col.label(text=f"Landmarks: {flags.count('ok')} ok, {flags.count('uncertain')} uncertain")
    if prov.get("software"):
        col.label(text=str(prov["software"]))
    if "pdehead_face_ms" in obj:
        col.label(text=f"Last solve {obj['pdehead_face_ms']:.0f} ms")
    status = fs.face.live_status()
    if status:
        col.label(text=status)
    names = fs.face.face_peg_names()
    pegs = fs.face.peg_objects(names)
    col = box.column(align=True)
    col.label(text=f"{len(pegs)} pegs: drag one (G) or set its depth (mm); pin: held (the face passes through it)")
    for name in names[:40]:
        peg = pegs.get(name)
        if peg is not None:
            row = col.row(align=True)
            row.prop(peg, f'["{PEG_DEPTH_PROP}"]', text=name)
            if HELD_PROP in peg:
                row.prop(peg, f'["{HELD_PROP}"]', text="", icon='PINNED' if peg[HELD_PROP] else 'UNPINNED')
    _draw_peg_report(box, prov)
    box.operator(PDEHEAD_OT_face_sd_range.bl_idname, icon='MOD_THICKNESS')
    if s.last_error.startswith("face:"):
        box.label(text=s.last_error, icon='ERROR')


def _draw_peg_report(layout, prov: dict) -> None:
    """The pegs whose tip is off the face (distance and why) and the warnings of the last solve (from the face's
    provenance: :meth:`.face.Face._show_report`)."""
    off = prov.get("pegs_off_face") or []
    warnings = prov.get("peg_warnings") or []
    if not off and not warnings:
        return
    col = layout.column(align=True)
    for w in warnings:
        col.label(text=str(w.get("text", "")), icon='ERROR')
    if off:
        col.label(text=f"{len(off)} peg tips more than {D.FACE_PEG_OFF_MM:g} mm from the face "
                       "(hold a peg to make the face pass through it):", icon='INFO')
        for o in off:
            held = " (held)" if o.get("held") else ""
            col.label(text=f"{o['peg']}: {o['tip_to_face_mm']:.1f} mm, {o['why']}" + held)


def _draw_skull(layout, fs) -> None:
    """The bone level, Build Skull and what the last Build Skull recorded."""
    col = layout.column(align=True)
    s = fs.settings
    row = col.row(align=True)
    row.prop(s, "use_bone_level", text="Bone Level")
    sub = row.row(align=True)
    sub.active = s.use_bone_level
    sub.prop(s, "bone_level", text="")
    col.operator(PDEHEAD_OT_build_skull.bl_idname, icon='MESH_UVSPHERE')
    info = fs.skull.skull_info()
    if info:
        stored = info.get("bone_level_stored")
        level = f"{stored:g} {info.get('units', '')}" if stored is not None else f"{info['bone_level']:.0f} HU"
        col.label(text=f"Bone level {level}, {info['components']} parts, {info['bone_cm3']:.0f} cm3")
        mandible = info.get("mandible") or {}
        if not mandible.get("present", True):
            col.label(text="No mandible: the face stops at the maxilla", icon='ERROR')
        elif mandible.get("articulated") is False:
            col.label(text=f"Mandible not articulated ({mandible.get('condyle_gap_mm', 0):.0f} mm gap)",
                      icon='ERROR')


def _draw_depth(layout, fs) -> None:
    """Tissue Depth, its colour legend and the statistics of the last run."""
    box = layout.box()
    box.operator(PDEHEAD_OT_tissue_depth.bl_idname, icon='MOD_THICKNESS')
    stats = fs.skull.depth_stats()
    s = fs.settings
    mat = bpy.data.materials.get(DEPTH_MATERIAL)
    if mat is not None and mat.node_tree.nodes.get("Depth legend") is not None:
        rng = mat.node_tree.nodes["Depth range"].inputs["From Max"].default_value
        box.template_color_ramp(mat.node_tree.nodes["Depth legend"], "color_ramp", expand=False)
        row = box.row()
        row.label(text="0 mm")
        row.label(text=f"{rng / 2:.0f} mm")
        row.label(text=f"{rng:.0f} mm")
        box.label(text="Grey: no value (no bone along the normal, or only", icon='INFO')
        box.label(text="the smoothed envelope: orbits, nasal aperture, neck)")
    if stats:
        stale = s.surface_object is None or DEPTH_ATTRIBUTE not in s.surface_object.data.attributes
        c = box.column(align=True)
        c.label(text=f"Measured {stats['measured']} / {stats['vertices']} vertices ({stats['target']})")
        if "median" in stats:
            c.label(text=f"Median {stats['median']:.1f}  mean {stats['mean']:.1f}  p95 {stats['p95']:.1f} mm")
            c.label(text=f"Min {stats['min']:.1f}  max {stats['max']:.1f} mm")
        c.label(text=f"No bone {stats['no_bone']}, envelope {stats['envelope']}, inside {stats['inside']}")
        if stale:
            c.label(text="Surface rebuilt since: compute again", icon='ERROR')


def _draw_landmarks(layout, fs) -> None:
    """Find / snap / place landmarks, their flags, the pegs, Landmarks CSV, Frankfurt and mirror."""
    box = layout.box()
    box.label(text="Landmarks")
    row = box.row(align=True)
    row.operator(PDEHEAD_OT_find_landmarks.bl_idname, icon='VIEWZOOM')
    row.operator(PDEHEAD_OT_snap_landmarks.bl_idname, text="Snap Moved", icon='SNAP_ON')
    box.label(text="Or click to put the 3D cursor on the skull, then:")
    box.operator_menu_enum(PDEHEAD_OT_place_landmark.bl_idname, "name", text="Place at Cursor",
                           icon='EMPTY_SINGLE_ARROW')
    placed = fs.landmarks()
    box.label(text=f"{len(placed)} placed" + (": " + ", ".join(list(placed)[:4]) if placed else ""))
    flags = fs.landmark_flags()
    if flags:
        counts = {f: sum(1 for v in flags.values() if v[0] == f) for f in ("ok", "uncertain", "not_found")}
        box.label(text=f"{counts['ok']} ok, {counts['uncertain']} uncertain, {counts['not_found']} not found",
                  icon='INFO' if not counts['not_found'] else 'ERROR')
    row = box.row(align=True)
    row.operator(PDEHEAD_OT_import_depth_table.bl_idname, text="Pegs: T-Table 2023",
                 icon='EMPTY_SINGLE_ARROW').default_table = True
    row.operator(PDEHEAD_OT_import_depth_table.bl_idname, text="Depth Table...", icon='IMPORT')
    pegs = fs.outputs.peg_objects_all()
    if pegs and fs.collection.get(FACE_KEY) is None:     # with a face: in its section below
        col = box.column(align=True)
        col.label(text=f"Peg depth (mm), {pegs[0].get('table_name', '')}: mean +- 2 SD")
        for peg in pegs[:40]:
            col.prop(peg, f'["{PEG_DEPTH_PROP}"]', text=str(peg["pdehead_peg"]))
    box.operator(PDEHEAD_OT_export_landmark_depths.bl_idname, text="Landmarks CSV", icon='EXPORT')
    row = box.row(align=True)
    row.operator(PDEHEAD_OT_frankfurt.bl_idname, text="Frankfurt", icon='ORIENTATION_GLOBAL')
    row.operator(PDEHEAD_OT_frankfurt.bl_idname, text="Reset").reset = True
    row = box.row(align=True)
    row.operator(PDEHEAD_OT_mirror.bl_idname, text="Mirror Active", icon='MOD_MIRROR').plane = 'AUTO'
    row.operator(PDEHEAD_OT_mirror.bl_idname, text="By Skull Symmetry").plane = 'SKULL'


class PDEHEAD_PT_forensic(Panel):
    bl_space_type = 'VIEW_3D'
    bl_region_type = 'UI'
    bl_category = "PDE Head"
    bl_idname = "PDEHEAD_PT_forensic"
    bl_label = "Forensic"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll(cls, context):
        return state.active_study(context) is not None

    def draw(self, context):
        layout = self.layout
        fs = ForensicStudy.of(Study.active(context))
        _draw_skull(layout, fs)
        _draw_depth(layout, fs)
        _draw_landmarks(layout, fs)
        draw_face_section(layout, fs)
        layout.operator(PDEHEAD_OT_export_print.bl_idname, icon='EXPORT')


CLASSES = (
    PDEHEAD_OT_build_skull,
    PDEHEAD_OT_tissue_depth,
    PDEHEAD_OT_place_landmark,
    PDEHEAD_OT_find_landmarks,
    PDEHEAD_OT_snap_landmarks,
    PDEHEAD_OT_import_depth_table,
    PDEHEAD_OT_export_landmark_depths,
    PDEHEAD_OT_frankfurt,
    PDEHEAD_OT_mirror,
    PDEHEAD_OT_export_print,
    PDEHEAD_OT_build_face,
    PDEHEAD_OT_face_sd_range,
    PDEHEAD_PT_forensic,
)
