"""Marker pegs, provenance and Export for Printing of a study (part of :class:`.study.ForensicStudy`).

A depth table CSV (or the shipped T-Table 2023) makes marker pegs along the skull normal at the placed
landmarks; Export for Printing writes the skull, the skull envelope, the skin, tissue_depth.csv,
landmarks.csv and provenance.json (the skin and tissue_depth.csv only when the study has a skin; what is
left out is named in provenance.json), all built and checked before the first file is written.
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix, Vector

from ...pdehead_addon import (
    EXPORT_FORMATS as FORMATS,
    DepthEntry,
    DepthTable,
    PDEHeadError,
    default_table,
    defaults as D,
    depth_flags,
    export_mesh,
    input_folder_conflict,
    marker_pegs,
    measure_landmark_depths,
    print_mesh,
    provenance,
    tissue_depth,
    write_depth_csv,
    write_landmark_csv,
)
from .. import state
from ..coords import MM_TO_M
from ..outcome import StepOutcome
from ..scene import detail_map
from .objects import plain_material, set_material

PEG_MATERIAL = "PDE Head Depth Peg"
#: Radius of a marker peg (mm).
PEG_RADIUS_MM = D.PEG_RADIUS.default
#: The custom property of a peg that holds its length (mm); a driver makes it the object's Z scale.
PEG_DEPTH_PROP = "depth_mm"


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


def _peg_matrix(base_mm: np.ndarray, normal: np.ndarray):
    """Patient-space (Blender metres) matrix: origin at ``base_mm``, local +Z along ``normal``."""
    rot = Vector(normal.tolist()).to_track_quat('Z', 'Y').to_matrix().to_4x4()
    return Matrix.Translation(Vector((base_mm * MM_TO_M).tolist())) @ rot


def _peg_object(name: str, entry, table, length: float, mat):
    """One peg object (not yet linked): its length the custom property ``depth_mm`` (mean +- 2 SD), driving Z scale."""
    obj = bpy.data.objects.new(f"Peg {name}", _unit_peg_mesh(f"Peg {name}", PEG_RADIUS_MM))
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
    return obj


def _drive_scale_by_depth(obj) -> None:
    drv = obj.driver_add("scale", 2).driver
    drv.type = 'SCRIPTED'
    var = drv.variables.new()
    var.name = "depth"
    var.type = 'SINGLE_PROP'
    var.targets[0].id = obj
    var.targets[0].data_path = f'["{PEG_DEPTH_PROP}"]'
    drv.expression = "depth"              # a simple expression: evaluated without Python scripts enabled


def set_peg_depth(peg, depth_mm: float) -> float:
    """Set a peg's length (mm), limited to its table's mean +- 2 SD; returns the length set."""
    mean = float(peg.get("table_mean_mm", peg[PEG_DEPTH_PROP]))
    sd = peg.get("table_sd_mm")
    lo, hi = (mean, mean) if sd is None else (max(0.0, mean - 2 * float(sd)), mean + 2 * float(sd))
    value = float(min(max(float(depth_mm), lo), hi))
    peg[PEG_DEPTH_PROP] = value
    peg.scale[2] = value
    return value


def print_face(head):
    """The face's closed mesh for Export for Printing: its PDE surface at print resolution
    (:func:`pdehead_addon.print_mesh`, the skin's path). A solved face's head keeps the cap vertex counts of
    its viewport mesh (so a dragged peg keeps the topology); the print mesh takes its own."""
    head.__dict__.pop("cap_reference", None)
    return print_mesh(head)


class Outputs:
    """The pegs, provenance and export of a study: a component of its :class:`.study.ForensicStudy`
    (``fs.outputs``); its state is in the study's collection, settings and cache."""

    def __init__(self, forensic):
        self.forensic = forensic

    def make_pegs(self, table, target: str = D.DEPTH_TARGET.default, pegs=None) -> list:
        """Marker pegs on the skull at the placed landmarks that ``table`` has.

        Each peg stands on the bone along the bone normal (the depth table's convention) with the table's
        mean as its length. The length is the peg's custom property ``depth_mm`` (animatable; its slider
        is limited to the table's mean +- 2 SD), which drives the object's Z scale. ``pegs``: the pegs'
        (name, base mm, unit normal, length mm) when they come from elsewhere (the face model of
        :mod:`.face`) instead of the landmarks snapped to ``target``.
        """
        if not isinstance(table, DepthTable):     # a plain {name: depth} mapping (no SDs)
            table = DepthTable(entries={k: DepthEntry(k, float(v)) for k, v in table.items()}, name="imported table")
        lms = self.forensic.landmarks()
        if pegs is None:
            pegs = marker_pegs(lms, self.forensic.skull.skull_engine_mesh(target), table)
        if not pegs:
            raise PDEHeadError(f"none of the placed landmarks ({', '.join(lms) or 'none'}) is in the depth table "
                               f"'{table.label}'")
        sub = self.forensic.sub_collection("Pegs")
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
        frank = self.forensic.frankfurt_matrix()
        for name, base, normal, length in pegs:
            obj = _peg_object(name, table.entries[name], table, length, mat)
            sub.objects.link(obj)
            obj.matrix_world = frank @ _peg_matrix(base, normal)
            obj.scale[2] = float(length)
            _drive_scale_by_depth(obj)
            made.append(obj)
        self.forensic.props.depth_table = table.to_json()
        self.forensic.props.depth_table_name = table.label
        return made

    def peg_objects_all(self) -> list:
        """Every marker peg of the study (with a length property)."""
        return [o for o in self.forensic.collection.all_objects if "pdehead_peg" in o and PEG_DEPTH_PROP in o]

    # -------------------------------------------------------------------------------------- provenance
    def depth_table(self):
        """The study's depth table: the one its pegs came from, else the shipped T-Table 2023."""
        text = self.forensic.props.depth_table
        return DepthTable.from_json(text) if text else default_table()

    def provenance(self, table=None) -> dict:
        """Provenance of the study's forensic outputs: software, CT, bone level, depth table, frame."""
        s = self.forensic.settings
        sk = self.forensic.skull.skull_segmentation()
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
            rec.update(table.provenance_record() if hasattr(table, "provenance_record")
                       else {"table": "imported table"})
        return provenance(**rec)

    def measured_landmark_depths(self, skull, skin) -> tuple[dict, dict[str, str], str]:
        """The placed landmarks' depths for landmarks.csv, measured as the batch measures them
        (:func:`~pdehead_addon.forensic.depth_on_ct.measure_landmark_depths`: on the CT's intensities along the bone's
        exposed normal; on the meshes only when the study's skull carries no CT intensities). Returns the rows
        (name -> (bone point, depth mm)), the flags (an ``ok`` landmark whose depth the CT's profile does not
        support turns ``uncertain``) and the method's description for the provenance."""
        lms = self.forensic.landmarks()
        sk = self.forensic.skull.skull_segmentation()
        head = self.forensic.study.cache.seg
        measured = measure_landmark_depths(lms, skull, skin, sk, head_mask=None if head is None else head.mask,
                                           table=self.depth_table())
        flags = depth_flags(self.forensic.flag_names(), measured)
        rows = {n: (m.point, m.depth) for n, m in measured.items()}
        why = next((m.evidence for m in measured.values() if m.method == "mesh"), "")
        if skin is None:
            method = "not measured (no skin)"
        elif why:
            method = f"bone mesh to skin mesh along the bone's exposed normal ({why})"
        else:
            method = "bone level to skin level in the CT along the bone's exposed normal"
        return rows, flags, method

    def has_skin(self) -> bool:
        """False when the study's CT has no soft tissue to make a skin of (a dry skull, soft tissue removed)."""
        return bool(self.forensic.skull.skull_segmentation().meta.get("has_skin", True))

    # -------------------------------------------------------------------------------------- export
    def _export_folder(self, directory: str) -> Path:
        """The export folder (absolute); never the input folder or one inside it, nor a file input's own folder
        (:func:`~pdehead_addon.io.export.input_folder_conflict`)."""
        out = Path(bpy.path.abspath(directory)).resolve()
        s = self.forensic.settings
        if s.source_kind == "FILES" and s.source:
            why = input_folder_conflict(out, bpy.path.abspath(s.source))
            if why:
                raise PDEHeadError(why)
        return out

    def _skin_missing(self) -> str:
        """Why the export has no skin (and so no tissue_depth.csv), or "" when it has one."""
        if not self.has_skin():
            return "the CT shows no soft tissue to make a skin of"
        if self.forensic.study.boundary_set() is None:          # a face-from-skull study: the head pipeline never ran
            return "run the head pipeline (Segment, Extract Boundaries, Reconstruct Surface) for them"
        return ""

    def _export_meshes(self, depth_target: str):
        """The meshes to export (name, Mesh), each checked watertight, the bone skull, the skin (None: none), the
        depth result (None: no skin) and why the skin is missing ("" when it is there).

        The skull and its PDE envelope come from the skull segmentation (built here when missing); the skin is
        the head pipeline's PDE surface, so a study without boundary curves (Build Skull, Find Landmarks and
        Build Face only) exports no skin and no tissue_depth.csv instead of failing."""
        s = self.forensic.settings
        skull = self.forensic.skull.skull_engine_mesh("BONE")
        envelope = self.forensic.skull.skull_engine_mesh("PDE")
        meshes = [("skull", skull), ("skull_envelope", envelope)]
        skin = None
        no_skin = self._skin_missing()
        if not no_skin:
            # the depth map's vertices stay the viewport's surface; skin.<fmt> is meshed at print resolution
            # with the CT detail at the study's strength (:func:`operators.scene.detail_map.print_skin`)
            skin = self.forensic.study.head.surface(int(s.nu), int(s.nv), caps=True)
            meshes.insert(0, ("skin", detail_map.print_skin(self.forensic.study)))
        for name, mesh in meshes:
            if mesh.face_count == 0 or not mesh.is_watertight():
                raise PDEHeadError(f"study '{self.forensic.name}': the {name} mesh is not watertight; "
                                   "nothing was written")
        res = None
        if skin is not None:
            res = self.forensic.cache.get("depth")
            if res is None or res.points.shape != skin.vertices.shape or not np.allclose(res.points, skin.vertices):
                res = tissue_depth(skin, self.forensic.skull.skull_engine_mesh(depth_target),
                                   envelope=self.forensic.skull.skull_segmentation())
        return meshes, skull, skin, res, no_skin

    def export(self, directory: str, fmt: str = D.EXPORT_FORMAT.default,
               depth_target: str = D.DEPTH_TARGET.default, face=None) -> StepOutcome:
        """Export for printing: skull.<fmt> (the bone), skull_envelope.<fmt> (the PDE skull envelope), skin.<fmt>
        (when the CT has skin), face.<fmt> (the face from the skull, when the study has one or ``face`` = (its
        solved PDE head, provenance) is given; both meshed at print resolution), tissue_depth.csv, landmarks.csv and
        provenance.json. Without a skin (a CT without soft tissue, or a face-from-skull study where the head
        pipeline never ran) skin.<fmt> and tissue_depth.csv are left out: provenance.json's ``not_written`` (file ->
        why) and the study's cache (``export_not_written``) say so.

        The landmarks' flags are decided once here (Find Landmarks' flags, an ``ok`` landmark whose depth the
        CT does not support turned ``uncertain``, ``not_found`` ones kept): landmarks.csv, the face's
        provenance (its file's comments and ``provenance.json``'s ``face``) list every landmark with the
        same flag. Everything is built and checked (watertight, in mm) before the first file is written,
        into a hidden folder inside ``directory`` whose files are then moved into place: a failure leaves no
        partial set. The flags written are kept in the study's cache (``export_flags``).

        Returns the seconds and (``values``) the paths written (``files``, provenance.json last), the files
        left out (``not_written``: name -> why) and the landmarks' flags written (``flags``).
        """
        if fmt not in FORMATS:
            raise PDEHeadError(f"unknown mesh format {fmt!r}; use one of {', '.join(FORMATS)}")
        with state.Timer() as timer:
            out = self._export_folder(directory)
            # ---- build everything first
            meshes, skull, skin, res, no_skin = self._export_meshes(depth_target)
            not_written = {f"skin.{fmt}": no_skin, "tissue_depth.csv": no_skin} if no_skin else {}
            depths, flags, method = self.measured_landmark_depths(skull, skin)
            # a landmark Find Landmarks did not find keeps its row (flag, no coordinates), as the batch's
            # landmarks.csv does
            for name, flag in flags.items():
                if flag == "not_found" and name not in depths:
                    depths[name] = (np.full(3, np.nan), float("nan"))
            flags = {name: flags.get(name, "ok") for name in depths}      # every row's flag: the one source
            table = self.depth_table()
            prov = self.provenance(table)
            prov_lm = dict(prov, depth=method)
            face = self.forensic.face.face_for_export() if face is None else face
            face_prov = None
            if face is not None:
                face_head, face_prov = face
                face_mesh = print_face(face_head)
                if face_mesh.face_count == 0 or not face_mesh.is_watertight():
                    raise PDEHeadError(f"study '{self.forensic.name}': the face mesh is not watertight; "
                                       "nothing was written")
                face_prov = {k: v for k, v in dict(face_prov).items() if k != "landmarks"}
                face_prov["landmark_flags"] = dict(flags)
                meshes.append(("face", face_mesh))
            names = self._write_export(out, fmt, meshes, res, depths, table, flags, prov, prov_lm, face_prov,
                                       not_written)
        self.forensic.cache["export_flags"] = dict(flags)
        self.forensic.cache["export_not_written"] = dict(not_written)
        self.forensic.adopt_export_flags(flags)
        self.forensic.study.record_timing("export", timer.seconds)
        return StepOutcome("export", seconds=timer.seconds,
                           values=dict(files=[str(out / n) for n in names], not_written=dict(not_written),
                                       flags=dict(flags)))

    def _write_export(self, out: Path, fmt: str, meshes, res, depths, table, flags, prov, prov_lm, face_prov,
                      not_written=None):
        """Write the export's files into a hidden folder in ``out``, then move them into place; their names.
        ``not_written``: the files left out (name -> why), recorded in provenance.json."""

        # ---- then write: into a hidden folder in the target, moved into place when all are written
        out.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=".pdehead-export-", dir=out))
        try:
            names = []
            for name, mesh in meshes:
                export_mesh(mesh, tmp / f"{name}.{fmt}", name=name, provenance=face_prov if name == "face" else prov)
                names.append(f"{name}.{fmt}")
            if res is not None:
                write_depth_csv(res, tmp / "tissue_depth.csv", provenance=prov)
                names.append("tissue_depth.csv")
            write_landmark_csv(tmp / "landmarks.csv", depths, table, flags, provenance=prov_lm)
            names.append("landmarks.csv")
            record = dict(prov, files=names, **({"face": face_prov} if face_prov is not None else {}),
                          **({"not_written": dict(not_written)} if not_written else {}))
            (tmp / "provenance.json").write_text(json.dumps(record, indent=2) + "\n")
            names.append("provenance.json")
            for name in names:
                os.replace(tmp / name, out / name)
        except OSError as exc:  # named as the file in `out` that could not be written (a full disk: no partial)
            where = out / Path(exc.filename).name if getattr(exc, "filename", None) else out
            raise PDEHeadError(f"{where}: cannot write the export ({exc.strerror or exc})") from None
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return names
