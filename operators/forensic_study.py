"""The forensic toolkit's application layer: landmarks, pegs, orientation, export (the skull and the depth
map: :mod:`.forensic_skull`; shared objects and materials: :mod:`.forensic_objects`).

The steps behind the operators of :mod:`.forensic` (which only read options, call these and
report), over the engine (:mod:`pdehead_addon.forensic.skull`, :mod:`~pdehead_addon.forensic.tissue_depth`,
:mod:`~pdehead_addon.forensic.landmarks`, :mod:`~pdehead_addon.io.export`), as :mod:`.study` is for the skin:

* **skull** segments the bone from the study's CT and builds the skull as a PDE surface by the
  skin's path (boundary curves -> PDE), plus the marching-cubes bone mesh beside it. The skull's
  boundary curves are stored in the .blend (like the skin's), the meshes are saved.
* **depth** (on demand, never on a slider step) writes the per-vertex depth into the skin surface
  as the POINT attributes ``tissue_depth`` (mm, -1 = no value) and ``tissue_depth_reason`` and
  gives it a colour-ramp material; the ramp is the legend in the panel.
* landmarks are empties snapped to the skull; a depth table CSV makes marker pegs along the
  skull normal.
* Frankfurt horizontal and mirror are object transforms: the meshes keep patient coordinates
  (world = LPS x 0.001 before the transform), and each landmark keeps its patient mm.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import bpy

from ..pdehead_addon import PDEHeadError
from . import state
from .coords import MM_TO_M
from .forensic_objects import forensic_cache, plain_material, set_material, sub_collection
from .forensic_skull import SKULL_BOUNDARY_KEY, skull_engine_mesh, skull_segmentation
from .study_entity import Study

FRANKFURT_KEY = "pdehead_frankfurt"         # 16 floats: the Blender-space transform applied
BASE_MATRIX_KEY = "pdehead_base_matrix"     # per object: its matrix before the Frankfurt transform
PEG_MATERIAL = "PDE Head Depth Peg"
LANDMARK_KEY = "pdehead_landmark"
LANDMARK_FLAGS_KEY = "pdehead_landmark_flags"   # JSON {name: [flag, evidence]} of the last Find Landmarks
LANDMARK_FLAG = "pdehead_flag"                  # per landmark empty: ok / uncertain / not_found
LANDMARK_EVIDENCE = "pdehead_evidence"
MOVED_BY_HAND = "moved by hand and snapped to the bone"
PLACED_BY_HAND = "placed by hand"
_BY_HAND = (MOVED_BY_HAND, PLACED_BY_HAND)
#: Radius of a marker peg (mm).
PEG_RADIUS_MM = 1.5


# ------------------------------------------------------------------------------------------ landmarks
def blender_matrix(m_mm: np.ndarray):
    """A patient-mm 4x4 transform as a Blender world (metre) ``mathutils.Matrix``."""
    from mathutils import Matrix
    m = np.array(m_mm, float).copy()
    m[:3, 3] *= MM_TO_M
    return Matrix(m.tolist())


def frankfurt_matrix(coll):
    from mathutils import Matrix
    values = coll.get(FRANKFURT_KEY)
    return Matrix(np.array(values, float).reshape(4, 4).tolist()) if values else Matrix.Identity(4)


def world_to_patient(coll, world) -> np.ndarray:
    """Patient LPS mm of a Blender world point (undoing the study's Frankfurt transform)."""
    p = frankfurt_matrix(coll).inverted() @ world
    return np.array(p, float) / MM_TO_M


def landmarks(coll) -> dict[str, np.ndarray]:
    """Placed landmarks of the study: name -> patient mm."""
    out = {}
    for obj in coll.all_objects:
        name = obj.get(LANDMARK_KEY)
        if name:
            out[str(name)] = np.array(obj["patient_mm"], float)
    return out


def place_landmark(coll, name: str, patient_mm, target: str = "BONE"):
    from ..pdehead_addon import snap_to_surface

    snapped, normal = snap_to_surface(np.asarray(patient_mm, float)[None], skull_engine_mesh(coll, target))
    obj = _landmark_empty(coll, name, snapped, normal)
    obj[LANDMARK_FLAG] = "ok"
    obj[LANDMARK_EVIDENCE] = PLACED_BY_HAND
    return obj


def _landmark_empty(coll, name: str, snapped: np.ndarray, normal: np.ndarray):
    """The study's empty of landmark ``name`` (made if missing) at a snapped point (patient mm, shape (1, 3))."""
    from ..pdehead_addon import landmark

    d = landmark(name)
    sub = sub_collection(coll, "Landmarks")
    obj_name = f"LM {d.name}"
    obj = next((o for o in sub.objects if o.get(LANDMARK_KEY) == d.name), None)
    if obj is None:
        obj = bpy.data.objects.new(obj_name, None)
        obj.empty_display_type = 'SPHERE'
        obj.empty_display_size = 2.5 * MM_TO_M
        sub.objects.link(obj)
    obj[LANDMARK_KEY] = d.name
    obj["patient_mm"] = [float(c) for c in snapped[0]]
    obj["normal"] = [float(c) for c in normal[0]]
    from mathutils import Matrix, Vector
    obj.matrix_world = frankfurt_matrix(coll) @ Matrix.Translation(Vector(snapped[0] * MM_TO_M))
    return obj


def find_landmarks(coll, target: str = "BONE", keep_edited: bool = True):
    """Every standard landmark found automatically on the study's bone mask, snapped to the skull.

    Landmarks found (``ok`` or ``uncertain``) become (or move) the study's landmark empties with
    their flag and evidence as custom properties; ``not_found`` ones remove an earlier automatic
    empty (a landmark placed or moved by hand stays). The flags of all are kept on the study
    (``LANDMARK_FLAGS_KEY``) for the outputs. With ``keep_edited``, landmarks placed or moved by
    hand are left where they are. Returns the engine's ``LandmarkSearch``.
    """
    from ..pdehead_addon import find_landmarks as engine_find
    from ..pdehead_addon import snap_to_surface

    sk = skull_segmentation(coll)
    search = engine_find(Study.of(coll).ct, sk.bone)
    edited = {str(o.get(LANDMARK_KEY)) for o in coll.all_objects
              if o.get(LANDMARK_KEY) and o.get(LANDMARK_EVIDENCE) in _BY_HAND} if keep_edited else set()
    found = {n: lm for n, lm in search.landmarks.items() if lm.point is not None and n not in edited}
    if found:
        snapped, normal = snap_to_surface(np.array([lm.point for lm in found.values()]),
                                          skull_engine_mesh(coll, target))
        for i, (name, lm) in enumerate(found.items()):
            obj = _landmark_empty(coll, name, snapped[i:i + 1], normal[i:i + 1])
            obj[LANDMARK_FLAG] = lm.flag
            obj[LANDMARK_EVIDENCE] = lm.evidence
    for obj in list(coll.all_objects):
        name = obj.get(LANDMARK_KEY)
        if name and name not in found and obj.get(LANDMARK_EVIDENCE) not in _BY_HAND:
            bpy.data.objects.remove(obj)
    coll[LANDMARK_FLAGS_KEY] = json.dumps({n: [lm.flag, lm.evidence] for n, lm in search.landmarks.items()
                                           if n not in edited})
    return search


def landmark_flags(coll) -> dict[str, tuple[str, str]]:
    """name -> (flag, evidence): of the last Find Landmarks, updated by hand edits; placed by hand: ``ok``."""
    flags = {n: tuple(v) for n, v in json.loads(coll.get(LANDMARK_FLAGS_KEY, "{}") or "{}").items()}
    for obj in coll.all_objects:
        name = obj.get(LANDMARK_KEY)
        if name:
            flags[str(name)] = (str(obj.get(LANDMARK_FLAG, "ok")), str(obj.get(LANDMARK_EVIDENCE, PLACED_BY_HAND)))
    return flags


def snap_moved_landmarks(coll, target: str = "BONE", tolerance_mm: float = 0.01) -> list[str]:
    """Landmarks whose empty was moved in the viewport go back onto the bone at the nearest point;
    their flag becomes ``ok`` (a person placed them). Returns the names snapped."""
    from ..pdehead_addon import snap_to_surface

    moved = []
    for obj in list(coll.all_objects):
        name = obj.get(LANDMARK_KEY)
        if not name or "patient_mm" not in obj:
            continue
        p = world_to_patient(coll, obj.matrix_world.translation)
        if np.linalg.norm(p - np.array(obj["patient_mm"], float)) > tolerance_mm:
            moved.append((obj, str(name), p))
    if moved:
        snapped, normal = snap_to_surface(np.array([p for _, _, p in moved]), skull_engine_mesh(coll, target))
        for i, (obj, name, _) in enumerate(moved):
            obj = _landmark_empty(coll, name, snapped[i:i + 1], normal[i:i + 1])
            obj[LANDMARK_FLAG] = "ok"
            obj[LANDMARK_EVIDENCE] = MOVED_BY_HAND
    return [name for _, name, _ in moved]


def _unit_peg_mesh(name: str, radius_mm: float, n: int = 12):
    """A closed cylinder mesh of radius ``radius_mm`` and length 1 mm along local +Z (Blender metres).

    The peg object scales it along Z by its depth (mm), so one property sets the length."""
    ang = 2 * np.pi * np.arange(n) / n
    ring = np.stack([np.cos(ang), np.sin(ang)], 1) * radius_mm * MM_TO_M
    verts = [(x, y, 0.0) for x, y in ring] + [(x, y, MM_TO_M) for x, y in ring] + [(0, 0, 0), (0, 0, MM_TO_M)]
    i = np.arange(n)
    j = (i + 1) % n
    faces = [(a, b, n + b, n + a) for a, b in zip(i, j)]
    faces += [(2 * n, b, a) for a, b in zip(i, j)] + [(2 * n + 1, n + a, n + b) for a, b in zip(i, j)]
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], [tuple(int(v) for v in f) for f in faces])
    me.update()
    return me


#: The custom property of a peg that holds its length (mm); a driver makes it the object's Z scale.
PEG_DEPTH_PROP = "depth_mm"


def _peg_matrix(base_mm: np.ndarray, normal: np.ndarray):
    """Patient-space (Blender metres) matrix: origin at ``base_mm``, local +Z along ``normal``."""
    from mathutils import Matrix, Vector
    rot = Vector(normal.tolist()).to_track_quat('Z', 'Y').to_matrix().to_4x4()
    return Matrix.Translation(Vector((base_mm * MM_TO_M).tolist())) @ rot


def make_pegs(coll, table, target: str = "BONE", pegs=None) -> list:
    """Marker pegs on the skull at the placed landmarks that ``table`` has.

    Each peg stands on the bone along the bone normal (the depth table's convention) with the table's
    mean as its length. The length is the peg's custom property ``depth_mm`` (animatable; its slider
    is limited to the table's mean +- 2 SD), which drives the object's Z scale. ``pegs``: the pegs'
    (name, base mm, unit normal, length mm) when they come from elsewhere (the face model of
    :mod:`.face`) instead of the landmarks snapped to ``target``.
    """
    from ..pdehead_addon import DepthEntry, DepthTable
    from ..pdehead_addon import marker_pegs

    if not isinstance(table, DepthTable):     # a plain {name: depth} mapping (no SDs)
        table = DepthTable(entries={k: DepthEntry(k, float(v)) for k, v in table.items()}, name="imported table")
    lms = landmarks(coll)
    if pegs is None:
        pegs = marker_pegs(lms, skull_engine_mesh(coll, target), table)
    if not pegs:
        raise PDEHeadError(f"none of the placed landmarks ({', '.join(lms) or 'none'}) is in the depth table "
                           f"'{table.label}'")
    sub = sub_collection(coll, "Pegs")
    for o in list(sub.objects):
        me = o.data
        bpy.data.objects.remove(o)
        if me is not None and me.users == 0:
            bpy.data.meshes.remove(me)
    mat = plain_material(PEG_MATERIAL, (0.95, 0.45, 0.05, 1.0))
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    bsdf.inputs["Emission Color"].default_value = (0.95, 0.45, 0.05, 1.0)
    bsdf.inputs["Emission Strength"].default_value = 0.6
    made = []
    frank = frankfurt_matrix(coll)
    for name, base, normal, length in pegs:
        entry = table.entries[name]
        obj = bpy.data.objects.new(f"Peg {name}", _unit_peg_mesh(f"Peg {name}", PEG_RADIUS_MM))
        sub.objects.link(obj)
        obj["pdehead_peg"] = name
        lo, hi = entry.range_mm(2.0)
        obj[PEG_DEPTH_PROP] = float(length)
        ui = obj.id_properties_ui(PEG_DEPTH_PROP)
        ui.update(min=lo, max=hi, soft_min=lo, soft_max=hi, default=float(length),
                  description=f"Peg length (mm): {table.label} mean {entry.mean_mm:g} mm"
                              + (f", settable within mean +- 2 SD ({lo:g}-{hi:g} mm)" if entry.sd_mm else ""))
        obj["table_mean_mm"] = float(entry.mean_mm)
        if entry.sd_mm is not None:
            obj["table_sd_mm"] = float(entry.sd_mm)
        obj["table_name"] = table.label
        set_material(obj, mat)
        obj.matrix_world = frank @ _peg_matrix(base, normal)
        obj.scale[2] = float(length)
        drv = obj.driver_add("scale", 2).driver
        drv.type = 'SCRIPTED'
        var = drv.variables.new()
        var.name = "depth"
        var.type = 'SINGLE_PROP'
        var.targets[0].id = obj
        var.targets[0].data_path = f'["{PEG_DEPTH_PROP}"]'
        drv.expression = "depth"              # a simple expression: evaluated without Python scripts enabled
        made.append(obj)
    coll["pdehead_depth_table"] = table.to_json()
    return made


def set_peg_depth(peg, depth_mm: float) -> float:
    """Set a peg's length (mm), limited to its table's mean +- 2 SD; returns the length set."""
    mean = float(peg.get("table_mean_mm", peg[PEG_DEPTH_PROP]))
    sd = peg.get("table_sd_mm")
    lo, hi = (mean, mean) if sd is None else (max(0.0, mean - 2 * float(sd)), mean + 2 * float(sd))
    value = float(min(max(float(depth_mm), lo), hi))
    peg[PEG_DEPTH_PROP] = value
    peg.scale[2] = value
    return value


def apply_frankfurt(coll, reset: bool = False):
    """Transform every object of the study into the Frankfurt horizontal (or back)."""
    from ..pdehead_addon import frankfurt_transform
    from mathutils import Matrix

    if reset:
        m = Matrix.Identity(4)
    else:
        lms = landmarks(coll)
        need = ["Porion L", "Porion R", "Orbitale L", "Orbitale R"]
        missing = [n for n in need if n not in lms]
        if missing:
            raise PDEHeadError(f"the Frankfurt horizontal needs the landmarks {', '.join(missing)}")
        m = blender_matrix(frankfurt_transform(*(lms[n] for n in need)))
    for obj in coll.all_objects:
        if BASE_MATRIX_KEY not in obj.keys():
            obj[BASE_MATRIX_KEY] = [v for row in obj.matrix_world for v in row]
        base = Matrix(np.array(obj[BASE_MATRIX_KEY], float).reshape(4, 4).tolist())
        obj.matrix_world = m @ base
    coll[FRANKFURT_KEY] = [v for row in m for v in row]
    return m


#: Where the mirror's mid-sagittal plane comes from.
MIRROR_PLANES = [
    ('AUTO', "Auto", "The bilateral landmark pairs if any are placed, else the skull's symmetry plane"),
    ('LANDMARKS', "Landmark Pairs", "Fitted to the bilateral landmark pairs (e.g. Porion L and Porion R)"),
    ('SKULL', "Skull Symmetry", "The skull's own plane of reflective symmetry (mirror ICP on the bone mesh)"),
]


def mirror_plane(coll, source: str = "AUTO") -> tuple[np.ndarray, np.ndarray, str]:
    """The mid-sagittal plane (point, normal in patient mm) and a sentence saying where it came from."""
    from ..pdehead_addon import bilateral_pairs, midsagittal_plane, symmetry_plane

    lms = landmarks(coll)
    pairs = bilateral_pairs(list(lms))
    if source == "LANDMARKS" or (source == "AUTO" and pairs):
        if not pairs:
            raise PDEHeadError("mirroring by landmarks needs at least one bilateral landmark pair "
                               "(e.g. Porion L and Porion R); or choose Skull Symmetry")
        point, normal = midsagittal_plane([(lms[a], lms[b]) for a, b in pairs])
        return point, normal, f"{len(pairs)} landmark pair(s)"
    if not coll.get("pdehead_bone_object") and not coll.get(SKULL_BOUNDARY_KEY):
        raise PDEHeadError(f"study '{coll.name}' has neither bilateral landmarks nor a skull: run Build Skull "
                           "or place a landmark pair")
    point, normal, info = symmetry_plane(skull_engine_mesh(coll, "BONE" if coll.get("pdehead_bone_object")
                                                           else "PDE").vertices)
    if not info["converged"]:
        raise PDEHeadError("the skull's symmetry plane did not converge: place bilateral landmarks instead")
    return point, normal, f"skull symmetry (median mirror residual {info['residual_mm']:.1f} mm)"


def mirror_object(coll, obj, source: str = "AUTO"):
    """A linked copy of ``obj`` mirrored across the mid-sagittal plane (:func:`mirror_plane`)."""
    from ..pdehead_addon import mirror_matrix

    point, normal, how = mirror_plane(coll, source)
    m = frankfurt_matrix(coll) @ blender_matrix(mirror_matrix(point, normal)) @ frankfurt_matrix(coll).inverted()
    copy = obj.copy()
    copy.name = f"{obj.name} Mirrored"
    for c in obj.users_collection[:1]:
        c.objects.link(copy)
    copy.matrix_world = m @ obj.matrix_world
    copy.pop(BASE_MATRIX_KEY, None)
    return copy, point, normal, how


# ------------------------------------------------------------------------------------------ provenance
def study_depth_table(coll):
    """The study's depth table: the one its pegs came from, else the shipped T-Table 2023."""
    from ..pdehead_addon import DepthTable, default_table

    text = coll.get("pdehead_depth_table")
    return DepthTable.from_json(text) if text else default_table()


def flag_names(coll) -> dict[str, str]:
    """name -> flag (``ok`` / ``uncertain`` / ``not_found``) for ``landmarks.csv``: :func:`landmark_flags` without
    the evidence."""
    return {name: flag for name, (flag, _evidence) in landmark_flags(coll).items()}


def forensic_provenance(coll, table=None) -> dict:
    """Provenance of the study's forensic outputs: software, CT, bone level, depth table, frame."""
    from ..pdehead_addon import provenance

    s = state.settings(coll)
    sk = skull_segmentation(coll)
    m = sk.meta
    if m.get("skull_mesh_file"):
        level = f"none (skull from the mesh {m['skull_mesh_file']})"
    else:
        stored = m.get("bone_level_stored", sk.bone_level)
        units = m.get("units", "HU" if m.get("calibrated") else "stored")
        level = f"{stored:g} {units}" + ("" if units == "HU" else f" ({sk.bone_level:.0f} HU estimated)") \
            + f", {m.get('bone_level_source', 'histogram rule')}"
    rec = dict(ct=(s.source or "phantom") if s.source_kind != "PHANTOM" else "built-in phantom",
               bone_level=level, frame="patient LPS mm of the CT (not Frankfurt-aligned)")
    if table is not None:
        rec.update(table.provenance_record() if hasattr(table, "provenance_record") else {"table": "imported table"})
    return provenance(**rec)


def measured_landmark_depths(coll, skull, skin) -> tuple[dict, dict[str, str], str]:
    """The placed landmarks' depths for landmarks.csv, measured as the batch measures them
    (:func:`~pdehead_addon.forensic.depth_on_ct.measure_landmark_depths`: on the CT's intensities along the bone's exposed
    normal; on the meshes only when the study's skull carries no CT intensities). Returns the rows
    (name -> (bone point, depth mm)), the flags (an ``ok`` landmark whose depth the CT's profile does not
    support turns ``uncertain``) and the method's description for the provenance."""
    from ..pdehead_addon import depth_flags, measure_landmark_depths

    lms = landmarks(coll)
    sk = skull_segmentation(coll)
    head = state.cache_for(state.settings(coll).study_id).seg
    measured = measure_landmark_depths(lms, skull, skin, sk, head_mask=None if head is None else head.mask)
    flags = depth_flags(flag_names(coll), measured)
    rows = {n: (m.point, m.depth) for n, m in measured.items()}
    why = next((m.evidence for m in measured.values() if m.method == "mesh"), "")
    if skin is None:
        method = "not measured (no skin)"
    elif why:
        method = f"bone mesh to skin mesh along the bone's exposed normal ({why})"
    else:
        method = "bone level to skin level in the CT along the bone's exposed normal"
    return rows, flags, method


def _has_skin(coll) -> bool:
    """False when the study's CT has no soft tissue to make a skin of (a dry skull, soft tissue removed)."""
    return bool(skull_segmentation(coll).meta.get("has_skin", True))


# ------------------------------------------------------------------------------------------ export
def export_study(coll, directory: str, fmt: str = "stl", depth_target: str = "BONE") -> list[str]:
    """Export for printing: skull.<fmt> (the bone), skull_envelope.<fmt> (the PDE skull envelope),
    skin.<fmt> (when the CT has skin), tissue_depth.csv, landmarks.csv and provenance.json.

    Everything is built and checked (watertight, in mm) before the first file is written, into a hidden
    folder inside ``directory`` whose files are then moved into place: a failure leaves no partial set.
    """
    import os
    import shutil
    import tempfile

    from ..pdehead_addon import write_landmark_csv
    from ..pdehead_addon import EXPORT_FORMATS as FORMATS, export_mesh
    from ..pdehead_addon import tissue_depth, write_depth_csv

    if fmt not in FORMATS:
        raise PDEHeadError(f"unknown mesh format {fmt!r}; use one of {', '.join(FORMATS)}")
    out = Path(bpy.path.abspath(directory)).resolve()
    s = state.settings(coll)
    if s.source_kind == "FILES" and s.source:
        src = Path(bpy.path.abspath(s.source)).resolve()
        src_dir = src if src.is_dir() else src.parent
        if out == src_dir or src_dir in out.parents:
            raise PDEHeadError(f"{out}: will not write into the CT's input folder; choose another folder")
    # ---- build everything first
    skull = skull_engine_mesh(coll, "BONE")
    envelope = skull_engine_mesh(coll, "PDE")
    meshes = [("skull", skull), ("skull_envelope", envelope)]
    skin = None
    if _has_skin(coll):
        skin = Study.of(coll).head.surface(int(s.nu), int(s.nv), caps=True)
        meshes.insert(0, ("skin", skin))
    for name, mesh in meshes:
        if mesh.face_count == 0 or not mesh.is_watertight():
            raise PDEHeadError(f"study '{coll.name}': the {name} mesh is not watertight; nothing was written")
    res = None
    if skin is not None:
        res = forensic_cache(coll).get("depth")
        if res is None or res.points.shape != skin.vertices.shape or not np.allclose(res.points, skin.vertices):
            res = tissue_depth(skin, skull_engine_mesh(coll, depth_target), envelope=skull_segmentation(coll))
    depths, flags, method = measured_landmark_depths(coll, skull, skin)
    # a landmark Find Landmarks did not find keeps its row (flag, no coordinates), as the batch's landmarks.csv does
    for name, flag in flags.items():
        if flag == "not_found" and name not in depths:
            depths[name] = (np.full(3, np.nan), float("nan"))
    table = study_depth_table(coll)
    prov = forensic_provenance(coll, table)
    prov_lm = dict(prov, depth=method)
    # ---- then write: into a hidden folder in the target, moved into place when all are written
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".pdehead-export-", dir=out))
    try:
        names = []
        for name, mesh in meshes:
            export_mesh(mesh, tmp / f"{name}.{fmt}", name=name, provenance=prov)
            names.append(f"{name}.{fmt}")
        if res is not None:
            write_depth_csv(res, tmp / "tissue_depth.csv", provenance=prov)
            names.append("tissue_depth.csv")
        write_landmark_csv(tmp / "landmarks.csv", depths, table, flags, provenance=prov_lm)
        names.append("landmarks.csv")
        (tmp / "provenance.json").write_text(json.dumps(dict(prov, files=names), indent=2) + "\n")
        names.append("provenance.json")
        for name in names:
            os.replace(tmp / name, out / name)
    except OSError as exc:
        raise PDEHeadError(f"{out}: cannot write the export ({exc.strerror})") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return [str(out / n) for n in names]
