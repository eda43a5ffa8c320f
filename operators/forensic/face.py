"""Face from Skull in Blender: the face object, its pegs, and the live re-solve when a peg moves.

The engine (:mod:`pdehead_addon.forensic.face_from_skull`) prepares a :class:`FaceModel` from the skull, the
landmarks and a depth table (seconds), then solves a face through the peg tips (fast). This module is the
Blender side of it: :class:`Face`, a component of :class:`.study.ForensicStudy` (``fs.face``):

* **Build Face** (:meth:`Face.build_face`) prepares the model, builds the face as its own object in the
  study's collection (shaded smooth) and the pegs as child objects of it (one per peg of the model,
  standing on the bone along the bone normal, as long as the table's mean). The label
  :data:`APPROXIMATION_LABEL` and the provenance are custom properties of the face object.
* **Live.** A ``depsgraph_update_post`` handler (:func:`operators.study.face_handler.pdehead_face_update`,
  registered once, guarded against recursion) compares each face's peg tips (a peg's tip: its origin on the bone
  plus its ``depth_mm`` along its own Z axis) with the tips of the last solve; when one moved -- a peg dragged
  with G, moved by a script, or its depth changed -- the model is solved through the new tips and only
  the vertex positions of the same mesh are rewritten (:class:`.face_live.LiveFace`). Switching the
  table (study setting ``face_table``) sets every peg to the new table's mean and re-solves at once.
* **Save and reopen.** Everything the face needs is in the .blend: the bone skull object's mesh, the
  landmarks the face was built from, the table, the options (JSON on the collection) and the tips of
  the last solve (on the face object). The prepared :class:`FaceModel` is kept too (:func:`.face_live.model_state`
  on the collection under :data:`FACE_MODEL_KEY`): after reopening it is rebuilt from there and checked (its solve
  at the saved tips must give the saved face, within :data:`RESTORE_TOLERANCE_MM`), else prepared again.
* **Held pegs.** A peg the practitioner moved or whose depth was set is *held* (its custom property
  :data:`HELD_PROP`, a toggle in the panel; Build Face makes every peg unheld): the engine never damps it, the
  face passes through its tip. After every solve each peg carries its tip's distance to the face
  (:data:`TIP_TO_FACE_PROP`) and the face's provenance lists the pegs more than 2 mm off (and why) and the
  warnings of a peg in the bone or dragged implausibly far (:mod:`pdehead_addon.forensic.face_pegs`).
"""
from __future__ import annotations

import json
import os
import time
import uuid

import bpy
import numpy as np

from ...pdehead_addon import DepthTable, PDEHeadError, default_table, provenance, read_depth_table
from .. import state
from ..coords import MM_TO_M, study_origin
from ..outcome import StepOutcome
from ..scene import objects
from .export import PEG_DEPTH_PROP, set_peg_depth
from .objects import engine_mesh_of, plain_material, set_material
from .props import face_options_of, store_face_options

FACE_KEY = "pdehead_face_object"            # collection -> the face object
SD_FACE_KEYS = {"minus": "pdehead_face_minus_sd_object", "plus": "pdehead_face_plus_sd_object"}
LABEL_PROP = "pdehead_label"                # face object: the approximation label
PROVENANCE_PROP = "pdehead_provenance"      # face object: JSON provenance
TIPS_PROP = "pdehead_face_tips"             # face object: the peg tips (patient mm) of the last solve
HELD_PROP = "pdehead_held"                  # peg: held by the practitioner (moved or its depth set): never damped
TIP_TO_FACE_PROP = "pdehead_tip_to_face_mm" # peg: its tip's distance to the face of the last solve (mm)
FACE_MODEL_KEY = "_pdehead_face_model"      # collection: the prepared FaceModel (face_live.model_state JSON;
                                            # "_": not listed in the Custom Properties panel)
FACE_KIND = "face"
FACE_MATERIAL = "PDE Head Face"
SD_MATERIALS = {"minus": ("PDE Head Face -1 SD", (0.25, 0.45, 0.95, 1.0)),
                "plus": ("PDE Head Face +1 SD", (0.95, 0.3, 0.25, 1.0))}

#: Depth tables the face can use (study setting ``face_table``).
FACE_TABLE_ITEMS = [
    ('DEFAULT', "T-Table 2023", "The shipped T-Table 2023 (Hona & Stephan 2024), pooled grand means and SDs"),
    ('FILE', "Table File", "A depth table CSV (landmark,mean_mm[,sd_mm,n]; our names or Caple & Stephan codes)"),
]
#: Sex for tables that have separate values for it (study setting ``face_sex``).
FACE_SEX_ITEMS = [
    ('POOLED', "Pooled", "Both sexes pooled (every table has it)"),
    ('FEMALE', "Female", "The table's female values, where it has them"),
    ('MALE', "Male", "The table's male values, where it has them"),
]
#: Tips closer than this (mm) to the last solve's count as unchanged.
TIP_TOLERANCE_MM = 1e-4
#: A model rebuilt from the file must give the saved face at the saved tips within this (mm; the mesh keeps
#: float32 metres, ~1e-5 mm at a head's size).
RESTORE_TOLERANCE_MM = 1e-3


def approximation_label() -> str:
    from ...pdehead_addon import APPROXIMATION_LABEL  # deferred: face engine, ~25 ms at add-on enable
    return APPROXIMATION_LABEL


def table_has_sex(table) -> bool:
    """Whether ``table`` holds separate values per sex (the shipped T-Table 2023 is pooled)."""
    return bool(getattr(table, "sexes", None) or getattr(table, "by_sex", None))


def _prepare(skull, lms, table, **kw):
    """A face model prepared from a skull, counted in ``state.REGISTRY.face_prepare_calls`` (Build Face, or a
    kept model that could not be used: a reopened file's first drag must not add one)."""
    state.REGISTRY.face_prepare_calls += 1
    from ...pdehead_addon import FaceModel  # deferred: face engine, ~25 ms at add-on enable
    return FaceModel.prepare(skull, lms, table, **kw)


def _fill_gone(model, raw: np.ndarray) -> np.ndarray:
    """A deleted peg's tip (NaN) back at the table's mean."""
    tips = np.array(raw, float)
    gone = ~np.isfinite(tips).all(axis=1)
    if gone.any():
        tips[gone] = model.peg_bases[gone] + model.peg_normals[gone] * model.default_depths[gone, None]
    return tips


def _stored_tips(obj, model) -> np.ndarray | None:
    stored = obj.get(TIPS_PROP) if obj is not None else None
    if stored is None:
        return None
    tips = np.array(stored, float).reshape(-1, 3)
    if tips.shape != model.peg_bases.shape:
        return None
    return _fill_gone(model, tips)


def _update_peg_table(peg, entry, table) -> None:
    """A peg's length set to ``entry``'s mean (and its slider to mean +- 2 SD) of ``table``."""
    lo, hi = entry.range_mm(2.0)
    peg[PEG_DEPTH_PROP] = float(entry.mean_mm)
    peg.id_properties_ui(PEG_DEPTH_PROP).update(min=lo, max=hi, soft_min=lo, soft_max=hi,
                                                default=float(entry.mean_mm))
    peg["table_mean_mm"] = float(entry.mean_mm)
    if entry.sd_mm is not None:
        peg["table_sd_mm"] = float(entry.sd_mm)
    else:
        peg.pop("table_sd_mm", None)
    peg["table_name"] = table.label
    peg.scale[2] = float(entry.mean_mm)       # what the driver will say; the tip is read from depth_mm


class Face:
    """The face from the skull of a study: a component of its :class:`.study.ForensicStudy` (``fs.face``), which it
    reads the skull, landmarks and pegs from; its state is in the study's collection, settings and cache."""

    def __init__(self, forensic):
        self.forensic = forensic

    def face_object(self):
        return self.forensic.linked_object(FACE_KEY)

    def face_options(self) -> dict:
        """What the face was built from: build id, table JSON, sex, options, flags, landmarks, pegs ({}: none)."""
        return face_options_of(self.forensic.props)

    def face_peg_names(self) -> list[str]:
        """The landmarks the face has a peg at, in the model's order ([] before Build Face)."""
        return [g.name for g in self.forensic.props.face_pegs]

    # -------------------------------------------------------------------------------------- inputs
    def face_skull_mesh(self):
        """The bone skull as an engine Mesh (patient mm): read from the study's bone object (what the .blend
        holds, so a reopened file prepares the same model), else built from the CT."""
        obj = self.forensic.linked_object("pdehead_bone_object")
        if obj is None or obj.type != 'MESH' or len(obj.data.polygons) == 0:
            return self.forensic.skull.skull_engine_mesh("BONE")
        return engine_mesh_of(obj, study_origin(self.forensic.collection))

    def face_for_export(self):
        """The study's face for Export for Printing: (its PDE surface, patient mm; its provenance with the
        label), or None when the study has no face (Build Face not run). The surface is solved again through
        the pegs' tips and held pegs of the face object's last solve (the shape it shows), so the export meshes
        it at print resolution (:func:`.export.print_face`), not at the viewport's resolution."""
        obj = self.face_object()
        if obj is None or obj.type != 'MESH' or len(obj.data.polygons) == 0:
            return None
        prov = json.loads(obj.get(PROVENANCE_PROP) or "{}")
        prov["label"] = approximation_label()
        model = self.face_model()
        held = self.forensic.cache.get("face_held")
        if held is None or len(held) != len(model.peg_names):
            held = self.peg_held(list(model.peg_names))
        return model.solve(tips=_stored_tips(obj, model), held=held).head, prov

    def face_table(self):
        """The depth table the study's face uses (setting ``face_table``): the shipped T-Table 2023 or a CSV, with
        the rows of the chosen sex (setting ``face_sex``) where the table has a ``sex`` column. A table without
        one is used pooled whatever the setting (hidden then, and kept for a table with a sex column); an
        explicit ``--sex`` for a pooled table is refused by the CLI, which calls ``for_sex`` itself."""
        table = self.face_table_as_read()
        return table.for_sex(self.face_sex() if table_has_sex(table) else None)

    def face_table_as_read(self):
        """The study's depth table as read, every sex's rows in it (:meth:`face_table` picks them)."""

        s = self.forensic.settings
        if s.face_table == 'FILE':
            if not s.face_table_file:
                raise PDEHeadError("choose a depth table file (Table File), or the T-Table 2023")
            path = bpy.path.abspath(s.face_table_file)
            if not os.path.isfile(path):
                raise PDEHeadError(f"{path}: no such depth table file")
            key = (path, os.path.getmtime(path))
        else:
            key = ("default",)
        tables = state.REGISTRY.face_tables
        if key not in tables:
            tables[key] = default_table() if key == ("default",) else read_depth_table(path)
        return tables[key]

    def face_sex(self) -> str | None:
        value = self.forensic.settings.face_sex
        return None if value == 'POOLED' else value.lower()

    # -------------------------------------------------------------------------------------- model
    def _mesh_positions(self, obj) -> np.ndarray:
        """The face mesh's vertices in patient mm (the study's frame, before the object's transform)."""
        co = np.empty(len(obj.data.vertices) * 3, np.float32)
        obj.data.attributes["position"].data.foreach_get("vector", co)
        origin = np.asarray(objects.study_origin(self.forensic.collection))
        return (co.reshape(-1, 3).astype(np.float64) + origin) / MM_TO_M

    def _restore_model(self, opts):
        """The model kept in the file, checked against the saved face (None when there is none or it does not
        give the saved face): (model, LiveFace)."""
        from ...pdehead_addon import LiveFace, face_model_from_state  # deferred: face engine, ~25 ms at add-on enable

        text = self.forensic.collection.get(FACE_MODEL_KEY)
        obj = self.face_object()
        if not text or obj is None:
            return None
        try:
            head, _, body = str(text).partition("\n")
            if head != opts["build"]:
                return None
            model = face_model_from_state(body)
            tips = _stored_tips(obj, model)
            if tips is None:
                return None
            live = LiveFace(model, check=False)
            # the saved face was solved with the pegs held then (a dragged peg is held): the same here
            prov = json.loads(obj.get(PROVENANCE_PROP, "{}") or "{}")
            got = live.positions(tips, prov.get("pegs_held") or None)
            saved = self._mesh_positions(obj)
            if got is None or got.shape != saved.shape or not np.abs(got - saved).max() <= RESTORE_TOLERANCE_MM:
                return None
            live.vertex_count = len(got)
            live.max_difference_mm = float(np.abs(got - saved).max())
            return model, live
        except Exception as exc:  # noqa: BLE001 - a kept model that cannot be used: prepare it again
            print(f"PDE Head: the face model kept in the file is not used ({exc}); preparing it again")
            return None

    def _keep_model(self, model, build: str) -> None:
        """The prepared model into the file (the collection), after its first solve fixed its parameter."""
        from ...pdehead_addon import face_model_state  # deferred: face engine, ~25 ms at add-on enable
        try:
            self.forensic.collection[FACE_MODEL_KEY] = build + "\n" + face_model_state(model)
        except (TypeError, ValueError) as exc:     # a model this version cannot keep: prepared again after reopening
            self.forensic.collection.pop(FACE_MODEL_KEY, None)
            print(f"PDE Head: the face model is not kept in the file ({exc}); reopening will prepare it again")

    def face_model(self):
        """The study's prepared FaceModel (runtime cache; when missing, rebuilt from the model kept in the
        .blend, else prepared again from the .blend's skull, landmarks and table)."""
        opts = self.face_options()
        if not opts:
            raise PDEHeadError(f"study '{self.forensic.name}' has no face yet: run Build Face")
        cache = self.forensic.cache
        if cache.get("face_model") is None or cache.get("face_build") != opts["build"]:
            with state.Timer() as t:
                restored = self._restore_model(opts)
            if restored is not None:
                model, live = restored
                cache.update(face_model=model, face_live=live, face_build=opts["build"], face_tips=None,
                             face_model_source="file", face_restore_s=t.seconds)
            else:
                table = DepthTable.from_json(opts["table"])
                lms = {k: np.array(v, float) for k, v in opts["landmarks"].items()}
                with state.Timer() as t:
                    model = _prepare(self.face_skull_mesh(), lms, table, sex=opts.get("sex"),
                                     flags=opts.get("flags"), **opts.get("options", {}))
                cache.update(face_model=model, face_live=None, face_build=opts["build"], face_tips=None,
                             face_prepare_s=t.seconds, face_model_source="prepared")
        return cache["face_model"]

    def face_live(self):
        """The study's :class:`.face_live.LiveFace` (made on first use: it checks itself against the model)."""
        model = self.face_model()
        live = self.forensic.cache.get("face_live")
        if live is None or live.model is not model:
            from ...pdehead_addon import LiveFace  # deferred: face engine, ~25 ms at add-on enable
            live = LiveFace(model)
            self.forensic.cache["face_live"] = live
        return live

    def peg_objects(self, names: list[str]) -> dict:
        """name -> the study's peg object of that landmark (the face's children first)."""
        face = self.face_object()
        found = {}
        if face is not None:
            for o in face.children:
                name = o.get("pdehead_peg")
                if name in names and name not in found:
                    found[name] = o
        if len(found) < len(names):
            for o in self.forensic.collection.all_objects:
                name = o.get("pdehead_peg")
                if name in names and name not in found:
                    found[name] = o
        return found

    def peg_tips(self, names: list[str]) -> np.ndarray:
        """The peg tips (patient mm), in ``names`` order: each peg's origin plus ``depth_mm`` along its Z axis.
        A peg that is gone gives NaN."""
        pegs = self.peg_objects(names)
        tips = np.full((len(names), 3), np.nan)
        rows = [i for i, name in enumerate(names) if name in pegs]
        if not rows:
            return tips
        inverse = np.array(self.forensic.frankfurt_matrix().inverted())
        found = [pegs[names[i]] for i in rows]
        m = np.array([p.matrix_world for p in found], float)                       # (k, 4, 4), one read per peg
        depth = np.array([float(p.get(PEG_DEPTH_PROP, 0.0)) for p in found])
        axis = m[:, :3, 2]
        length = np.linalg.norm(axis, axis=1)
        ok = length > 0
        tip = m[:, :3, 3] + axis / np.where(ok, length, 1.0)[:, None] * (depth * MM_TO_M)[:, None]
        world = (tip @ inverse[:3, :3].T + inverse[:3, 3]) / MM_TO_M
        tips[np.asarray(rows)[ok]] = world[ok]
        return tips

    def peg_held(self, names: list[str]) -> np.ndarray:
        """Whether each peg (in ``names`` order) is held (:data:`HELD_PROP`); a peg that is gone is not."""
        pegs = self.peg_objects(names)
        return np.array([bool(pegs[n].get(HELD_PROP, False)) if n in pegs else False for n in names], bool)

    def _hold_touched(self, names: list[str], raw: np.ndarray) -> None:
        """The pegs whose tip moved since the last solve (dragged, or their depth set) become held."""
        last = self.forensic.cache.get("face_tips")
        if last is None:                   # the model was just rebuilt (reopened file): the tips of the last solve
            stored = self.face_object().get(TIPS_PROP)
            last = np.array(stored, float).reshape(-1, 3) if stored is not None else None
        if last is None or np.shape(last) != raw.shape:
            return
        moved = np.any(np.abs(raw - last) > TIP_TOLERANCE_MM, axis=1)      # NaN (a peg gone): not moved
        if moved.any():
            pegs = self.peg_objects(names)
            for i in np.flatnonzero(moved):
                if names[i] in pegs:
                    pegs[names[i]][HELD_PROP] = True

    def _show_report(self, obj, report) -> None:
        """The pegs' report of a solve onto the pegs (:data:`TIP_TO_FACE_PROP`) and into the face's provenance."""
        pegs = self.peg_objects(report.names)
        for name, gap in zip(report.names, report.tip_to_face_mm):
            if name in pegs:
                pegs[name][TIP_TO_FACE_PROP] = round(float(gap), 2)
        prov = json.loads(obj.get(PROVENANCE_PROP, "{}") or "{}")
        prov.update(report.record())
        obj[PROVENANCE_PROP] = json.dumps(prov)
        self.forensic.cache["face_report"] = report

    def peg_warnings(self) -> list[dict]:
        """The warnings of the face's last solve (a peg in the bone, a peg dragged implausibly far)."""
        obj = self.face_object()
        prov = json.loads(obj.get(PROVENANCE_PROP, "{}") or "{}") if obj is not None else {}
        return list(prov.get("peg_warnings") or [])

    def _write_positions(self, obj, mesh=None, positions=None) -> bool:
        """The face mesh's vertex positions rewritten in place (same topology: the fast path), else the same
        mesh datablock refilled (the face's caps may gain or lose a vertex between two solves). ``positions``
        (patient mm) instead of a ``mesh``: only the positions. Returns whether the mesh was refilled."""
        me, coll = obj.data, self.forensic.collection
        verts = positions if positions is not None else mesh.vertices
        if len(me.vertices) == len(verts) and (positions is not None or len(me.polygons) == mesh.face_count):
            local = np.asarray(verts, np.float64) * MM_TO_M - np.asarray(objects.study_origin(coll))
            me.attributes["position"].data.foreach_set("vector", np.ascontiguousarray(local, np.float32).ravel())
            me.update()
            return False
        if mesh is None:
            raise ValueError("the face's vertex count changed: a whole mesh is needed")
        objects.build_mesh_object(mesh, coll, obj.name, obj=obj, smooth=True)
        return True

    def _face_provenance(self, result_provenance: dict, table) -> dict:
        opts = self.face_options()
        rec = provenance(label=approximation_label(), **(table.provenance_record() if table is not None else {}))
        rec.update({k: v for k, v in dict(result_provenance).items() if k not in rec})
        flags = self.forensic.flag_names()
        rec["landmarks"] = {n: flags.get(n, "ok") for n in opts.get("landmarks", {})}
        # every landmark's flag as the study holds it (not_found ones too; an export's adopted ones), so the face's
        # provenance lists what landmarks.csv lists after a drag or a reopen as well (the tester: it dropped 28)
        rec["landmark_flags"] = dict(sorted(flags.items()))
        rec["sex"] = getattr(table, "sex", "") or opts.get("sex") or "pooled"
        rec["label"] = approximation_label()
        return rec

    def solve_face(self, tips: np.ndarray | None = None, table=None, hold_touched: bool = True) -> dict:
        """Solve the face through ``tips`` (default: the pegs' tips now) and rewrite the face object's vertices.
        The pegs moved since the last solve become held (``hold_touched``; not for a table switch), the held
        pegs are followed exactly, and each peg's distance to the face and the warnings are written
        (:meth:`_show_report`). Returns the timings (seconds): ``solve`` (the engine), ``write`` (Blender) and
        ``total``; ``fast``: whether the positions came from :class:`.face_live.LiveFace` (else the model's
        whole solve); ``warnings``: the pegs' warnings (dicts with ``peg``, ``kind``, ``text``)."""
        t0 = time.perf_counter()
        obj = self.face_object()
        if obj is None:
            raise PDEHeadError(f"study '{self.forensic.name}' has no face: run Build Face")
        model = self.face_model()
        live = self.face_live()
        names = list(model.peg_names)
        if tips is None:
            tips = self.peg_tips(names)
        raw = np.asarray(tips, float)
        tips = _fill_gone(model, raw)     # a deleted peg: its tip back at the table's mean (the raw NaN is compared)
        if hold_touched:
            self._hold_touched(names, raw)
        held = self.peg_held(names)
        t1 = time.perf_counter()
        positions = live.positions(tips, held) if len(obj.data.vertices) == live.vertex_count else None
        result = model.solve(tips=tips, held=held) if positions is None else None
        report = live.report(tips, positions, held) if result is None else result.pegs
        t2 = time.perf_counter()
        refilled = self._write_positions(obj, mesh=result.mesh if result is not None else None, positions=positions)
        obj[TIPS_PROP] = [float(v) for v in raw.ravel()]
        if table is not None:
            prov = live.provenance(tips, report) if result is None else result.provenance
            obj[PROVENANCE_PROP] = json.dumps(self._face_provenance(prov, table))
        self._show_report(obj, report)
        t3 = time.perf_counter()
        self.forensic.cache["face_tips"] = raw
        self.forensic.cache["face_held"] = held
        timings = {"tips": t1 - t0, "solve": t2 - t1, "write": t3 - t2, "total": t3 - t0, "refilled": refilled,
                   "fast": positions is not None, "engine": dict(result.timings) if result is not None else {},
                   "warnings": list(report.warnings)}
        self.forensic.cache["face_timings"] = timings
        obj["pdehead_face_ms"] = round(1000 * timings["total"], 1)
        return timings

    def live_status(self) -> str | None:
        """One line for the panel: how the last change was solved (None before the first change)."""
        timings = self.forensic.cache.get("face_timings")
        if not timings:
            return None
        text = "Live: vertex positions only" if timings.get("fast") else "Live: whole mesh solved (slower)"
        return text + (", model from the file" if self.forensic.cache.get("face_model_source") == "file" else "")

    def face_changed(self) -> bool:
        """Whether a peg tip moved since the last solve (cheap: no model needed)."""
        return self.moved_tips() is not None

    def moved_tips(self) -> np.ndarray | None:
        """The pegs' tips now when one moved since the last solve, else None (read once: the handler solves
        through these same tips)."""
        obj = self.face_object()
        if obj is None:
            return None
        last = self.forensic.cache.get("face_tips")
        if last is None:
            stored = obj.get(TIPS_PROP)
            if stored is not None:
                last = np.array(stored, float).reshape(-1, 3)
                self.forensic.cache["face_tips"] = last
        names = self.face_peg_names()
        now = self.peg_tips(names)
        if last is None or now.shape != last.shape:
            return now
        same = np.abs(now - last) <= TIP_TOLERANCE_MM
        same |= np.isnan(now) & np.isnan(last)             # a peg that is gone stays gone: no new solve
        held = self.forensic.cache.get("face_held")
        if held is None:                   # a reopened file: the pegs held at the last solve, from its provenance
            prov = json.loads(obj.get(PROVENANCE_PROP, "{}") or "{}")
            held = self.forensic.cache["face_held"] = np.isin(names, prov.get("pegs_held") or [])
        if not np.array_equal(held, self.peg_held(names)):
            return now                                     # a peg held or let go in the panel: solve again
        return None if bool(same.all()) else now

    # -------------------------------------------------------------------------------------- build
    def build_face(self) -> StepOutcome:
        """Build the face of the study (skull and landmarks made first when missing); returns the face object then
        its pegs, the pegs' report as its warning (a peg in the bone, a tip far from the face), the seconds of the
        model's preparation (the study's ``face_prepare`` timing) and ``values``: vertices, pegs, label."""
        coll = self.forensic.collection
        s = self.forensic.settings
        if self.forensic.linked_object("pdehead_bone_object") is None:
            self.forensic.skull.step_skull(s.nu, s.nv)
        if not self.forensic.landmarks():
            self.forensic.find_landmarks()
        table = self.face_table()
        lms = self.forensic.landmarks()
        sex = table.sex or None                     # the rows used (a pooled table ignores the Sex setting)
        flags = self.forensic.flag_names()
        with state.Timer() as t:
            model = _prepare(self.face_skull_mesh(), lms, table, sex=sex, flags=flags)
        if not len(model.peg_names):
            raise PDEHeadError(f"none of the landmarks ({', '.join(lms) or 'none'}) is in the depth table "
                               f"'{table.label}': no peg to build the face through")
        build = uuid.uuid4().hex
        store_face_options(self.forensic.props, dict(
            build=build, table=table.to_json(), sex=sex, options={}, flags=flags,
            landmarks={k: [float(c) for c in v] for k, v in lms.items()}, pegs=list(model.peg_names)))
        self.forensic.cache.update(face_model=model, face_live=None, face_build=build, face_tips=None,
                                   face_prepare_s=t.seconds, face_model_source="prepared")
        result = model.solve()
        obj = objects.build_mesh_object(result.mesh, coll, f"{coll.name} Face", obj=self.face_object(), smooth=True)
        obj["pdehead_kind"] = FACE_KIND
        obj[LABEL_PROP] = approximation_label()
        coll[FACE_KEY] = obj
        set_material(obj, plain_material(FACE_MATERIAL, (0.80, 0.62, 0.52, 1.0)))
        self.forensic.to_frankfurt(obj)
        # the pegs: one per peg of the model (old pegs of the study are replaced), children of the face
        pegs = self.forensic.outputs.make_pegs(table, pegs=[(n, model.peg_bases[i], model.peg_normals[i],
                                                     float(model.default_depths[i]))
                                                    for i, n in enumerate(model.peg_names)])
        for peg in pegs:
            world = peg.matrix_world.copy()
            peg.parent = obj
            peg.matrix_parent_inverse = obj.matrix_world.inverted()
            peg.matrix_world = world
        for peg in pegs:                              # Build Face: no peg is held
            peg[HELD_PROP] = False
            peg.id_properties_ui(HELD_PROP).update(description="Held: the face passes through this peg's tip "
                                                   "(set when the peg is moved or its depth set; never damped)")
        tips = model.peg_bases + model.peg_normals * np.asarray(model.default_depths, float)[:, None]
        obj[TIPS_PROP] = [float(v) for v in tips.ravel()]
        obj[PROVENANCE_PROP] = json.dumps(self._face_provenance(result.provenance, table))
        self._show_report(obj, result.pegs)
        self.forensic.cache["face_tips"] = tips
        self.forensic.cache["face_held"] = np.zeros(len(model.peg_names), bool)
        self._keep_model(model, build)
        from ...pdehead_addon import LiveFace  # deferred: face engine, ~25 ms at add-on enable
        self.forensic.cache["face_live"] = LiveFace(model)
        self.forensic.study.record_timing("face_prepare", t.seconds)
        line = result.pegs.summary() if result.pegs is not None else None
        return StepOutcome("face", objects=(obj, *pegs), warnings=(line,) if line else (), seconds=t.seconds,
                           values=dict(vertices=len(obj.data.vertices), pegs=len(pegs), label=obj[LABEL_PROP]))

    def switch_table(self) -> dict | None:
        """The face's pegs set to the mean (and mean +- 2 SD range) of the study's table now, and the face
        re-solved; pegs the new table lacks keep their length. None when the study has no face."""
        if self.face_object() is None:
            return None
        table = self.face_table()
        for name, peg in self.peg_objects(self.face_peg_names()).items():
            entry = table.entries.get(name)
            if entry is not None:
                _update_peg_table(peg, entry, table)
        self.forensic.props.face_table = table.to_json()
        self.forensic.props.face_sex = getattr(table, "sex", "")          # what the face now stands by
        return self.solve_face(table=table, hold_touched=False)     # the table moved the pegs, not the practitioner

    def set_face_peg_depth(self, peg, depth_mm: float) -> float:
        """A face peg's length (limited to its table's mean +- 2 SD) and the face re-solved; returns the length."""
        value = set_peg_depth(peg, depth_mm)
        if self.face_object() is not None:
            self.solve_face()
        return value

    def build_sd_faces(self) -> StepOutcome:
        """The faces with every peg at its length - 1 SD and + 1 SD (pegs without an SD stay), as two objects
        beside the face (wire display): the range the table allows. Returns the objects (minus, plus) and the
        seconds."""
        coll = self.forensic.collection
        face = self.face_object()
        if face is None:
            raise PDEHeadError(f"study '{self.forensic.name}' has no face: run Build Face")
        model = self.face_model()
        tips = self.peg_tips(list(model.peg_names))
        depth = np.einsum("ij,ij->i", tips - model.peg_bases, model.peg_normals)
        sd = np.nan_to_num(np.asarray(model.depth_sd, float), nan=0.0)
        made = []
        start = time.perf_counter()
        for sign, key in ((-1.0, "minus"), (1.0, "plus")):
            result = model.solve(depths=np.maximum(depth + sign * sd, 0.0), held=self.peg_held(list(model.peg_names)))
            label = "-1 SD" if sign < 0 else "+1 SD"
            obj = objects.build_mesh_object(result.mesh, coll, f"{coll.name} Face {label}",
                                            obj=self.forensic.linked_object(SD_FACE_KEYS[key]), smooth=True)
            obj["pdehead_kind"] = f"face_{key}_sd"
            obj[LABEL_PROP] = approximation_label()
            obj[PROVENANCE_PROP] = json.dumps(dict(json.loads(face.get(PROVENANCE_PROP, "{}")),
                                                   depths=f"every peg at its length {label}"))
            obj.display_type = 'WIRE'
            obj.matrix_world = face.matrix_world
            set_material(obj, plain_material(*SD_MATERIALS[key]))
            coll[SD_FACE_KEYS[key]] = obj
            made.append(obj)
        return StepOutcome("face_sd", objects=tuple(made), seconds=time.perf_counter() - start,
                           values=dict(vertices=[len(o.data.vertices) for o in made]))

    def live_table(self) -> None:
        """After ``face_table`` / ``face_table_file`` changed: :meth:`switch_table` (never raises into the UI)."""
        try:
            self.switch_table()
            self.forensic.settings.last_error = ""
        except Exception as exc:  # noqa: BLE001 - an update callback must never raise into the UI
            self.forensic.settings.last_error = f"face: {exc}"[:500]
