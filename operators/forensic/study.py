"""The forensic toolkit's application layer: :class:`ForensicStudy`, one study's forensic side.

The steps behind the operators of :mod:`.ops` (which only read options, call these and
report), over the engine (:mod:`pdehead_addon.forensic.skull`, :mod:`~pdehead_addon.forensic.tissue_depth`,
:mod:`~pdehead_addon.forensic.landmarks`, :mod:`~pdehead_addon.io.export`), as :class:`operators.study.entity.Study`
is for the skin. ``ForensicStudy.of(study)`` (``study``: a :class:`operators.study.entity.Study`) gives one object
per study for the session; its methods come in parts:

* the skull and the depth map (:class:`.skull.Skull`, a component: ``fs.skull``): the bone segmented from the CT, the
  skull as a PDE surface and the marching-cubes bone mesh, the per-vertex tissue depth of the skin;
* landmarks, Frankfurt horizontal and mirror (here): landmarks are empties snapped to the skull; Frankfurt
  horizontal and mirror are object transforms -- the meshes keep patient coordinates (world = LPS x 0.001
  before the transform), and each landmark keeps its patient mm;
* marker pegs, provenance and Export for Printing (the component ``fs.outputs``, :class:`.export.Outputs`);
* the face from the skull (:class:`.face.Face`, a component: ``fs.face``).

Its settings and landmark flags are a PropertyGroup on the collection (:mod:`.props`). The
:class:`operators.study.entity.Study` holds it as its ``forensic`` component.
"""
from __future__ import annotations

import json
import time

import bpy
import numpy as np
from mathutils import Matrix, Vector

from ...pdehead_addon import (
    PDEHeadError,
    bilateral_pairs,
    defaults as D,
    frankfurt_transform,
    landmark,
    midsagittal_plane,
    mirror_matrix,
    snap_to_surface,
    symmetry_plane,
)
from ..coords import MM_TO_M
from ..outcome import StepOutcome
from .export import Outputs
from .face import PROVENANCE_PROP, Face
from .props import FORMAT_VERSION, forensic_settings, migrate, set_flags
from .skull import SKULL_BOUNDARY_KEY, Skull

FRANKFURT_KEY = "pdehead_frankfurt"         # 16 floats: the Blender-space transform applied
BASE_MATRIX_KEY = "pdehead_base_matrix"     # per object: its matrix before the Frankfurt transform
LANDMARK_KEY = "pdehead_landmark"
LANDMARK_FLAG = "pdehead_flag"              # per landmark empty: ok / uncertain / not_found
LANDMARK_EVIDENCE = "pdehead_evidence"
MOVED_BY_HAND = "moved by hand and snapped to the bone"
PLACED_BY_HAND = "placed by hand"
_BY_HAND = (MOVED_BY_HAND, PLACED_BY_HAND)

#: Where the mirror's mid-sagittal plane comes from.
MIRROR_PLANES = [
    ('AUTO', "Auto", "The bilateral landmark pairs if any are placed, else the skull's symmetry plane"),
    ('LANDMARKS', "Landmark Pairs", "Fitted to the bilateral landmark pairs (e.g. Porion L and Porion R)"),
    ('SKULL', "Skull Symmetry", "The skull's own plane of reflective symmetry (mirror ICP on the bone mesh)"),
]


def blender_matrix(m_mm: np.ndarray):
    """A patient-mm 4x4 transform as a Blender world (metre) ``mathutils.Matrix``."""
    m = np.array(m_mm, float).copy()
    m[:3, 3] *= MM_TO_M
    return Matrix(m.tolist())


class ForensicStudy:
    """One study's forensic side, a component of its :class:`operators.study.entity.Study` (``study.forensic``;
    get it with ``ForensicStudy.of(study)``, which also migrates an older file's forensic settings): its
    collection, settings, forensic PropertyGroup (:mod:`.props`), in-memory cache and sub-collections;
    landmarks, Frankfurt and mirror; the skull and depth map, the pegs and outputs and the face from the skull
    are its components :attr:`skull` (:class:`.skull.Skull`), :attr:`outputs` (:class:`.export.Outputs`) and
    :attr:`face` (:class:`.face.Face`)."""

    def __init__(self, study):
        self.study = study
        self.skull = Skull(self)
        self.face = Face(self)
        self.outputs = Outputs(self)

    @staticmethod
    def of(study):
        """The forensic side of ``study`` (a :class:`operators.study.entity.Study`, which holds it as its
        ``forensic`` component), its settings of an older file format migrated first."""
        entity = study.forensic
        if entity.props.format_version < FORMAT_VERSION:
            entity.migrate()
        return entity

    def migrate(self) -> None:
        """The study's forensic state of an older file format into the PropertyGroup (:func:`.props.migrate`;
        not possible while Blender draws: then after the next file load or step)."""
        try:
            migrate(self.collection)
        except AttributeError:     # "Writing to ID classes in this context is not allowed" (a panel's draw)
            pass

    @property
    def collection(self):
        return self.study.collection

    @property
    def name(self) -> str:
        return self.collection.name

    @property
    def settings(self):
        """The study settings (:class:`operators.study.props.PDEHeadStudySettings`)."""
        return self.study.settings

    @property
    def props(self):
        """The forensic settings and state (:class:`.props.PDEHeadForensicSettings`)."""
        return forensic_settings(self.collection)

    @property
    def cache(self) -> dict:
        """The in-memory forensic results: skull segmentation, meshes, depth result, face model."""
        return self.study.cache.forensic

    def sub_collection(self, suffix: str):
        """The study's child collection ``"<study> <suffix>"`` (made when missing)."""
        coll = self.collection
        name = f"{coll.name} {suffix}"
        sub = bpy.data.collections.get(name)
        if sub is None:
            sub = bpy.data.collections.new(name)
        if sub.name not in coll.children:
            coll.children.link(sub)
        return sub

    def linked_object(self, key: str):
        """The object the study collection's custom property ``key`` points at (None when gone)."""
        obj = self.collection.get(key)
        return obj if isinstance(obj, bpy.types.Object) and obj.name in bpy.data.objects else None

    # -------------------------------------------------------------------------------------- frame
    def frankfurt_matrix(self):
        values = self.collection.get(FRANKFURT_KEY)
        return Matrix(np.array(values, float).reshape(4, 4).tolist()) if values else Matrix.Identity(4)

    def world_to_patient(self, world) -> np.ndarray:
        """Patient LPS mm of a Blender world point (undoing the study's Frankfurt transform)."""
        p = self.frankfurt_matrix().inverted() @ world
        return np.array(p, float) / MM_TO_M

    # -------------------------------------------------------------------------------------- landmarks
    def landmarks(self) -> dict[str, np.ndarray]:
        """Placed landmarks of the study: name -> patient mm."""
        out = {}
        for obj in self.collection.all_objects:
            name = obj.get(LANDMARK_KEY)
            if name:
                out[str(name)] = np.array(obj["patient_mm"], float)
        return out

    def place_landmark(self, name: str, patient_mm, target: str = D.DEPTH_TARGET.default):
        snapped, normal = snap_to_surface(np.asarray(patient_mm, float)[None], self.skull.skull_engine_mesh(target))
        obj = self._landmark_empty(name, snapped, normal)
        obj[LANDMARK_FLAG] = "ok"
        obj[LANDMARK_EVIDENCE] = PLACED_BY_HAND
        return obj

    def _landmark_empty(self, name: str, snapped: np.ndarray, normal: np.ndarray):
        """The study's empty of landmark ``name`` (made if missing) at a snapped point (patient mm, shape (1, 3))."""
        d = landmark(name)
        sub = self.sub_collection("Landmarks")
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
        obj.matrix_world = self.frankfurt_matrix() @ Matrix.Translation(Vector(snapped[0] * MM_TO_M))
        return obj

    def find_landmarks(self, target: str = D.DEPTH_TARGET.default,
                       keep_edited: bool = D.KEEP_EDITED.default) -> StepOutcome:
        """Every standard landmark found automatically on the study's bone mask, snapped to the skull.

        Landmarks found (``ok`` or ``uncertain``) become (or move) the study's landmark empties with
        their flag and evidence as custom properties; ``not_found`` ones remove an earlier automatic
        empty (a landmark placed or moved by hand stays). The flags of all are kept on the study
        (the forensic settings' ``landmark_flags``) for the outputs. With ``keep_edited``, landmarks placed
        or moved by hand are left where they are. Returns the empties placed or moved, the seconds and
        (``values``) each landmark's ``flags`` and ``evidence`` and the engine's ``LandmarkSearch`` (``search``).
        """
        from ...pdehead_addon import find_landmarks as engine_find  # deferred: ~15 ms at add-on enable

        coll = self.collection
        t0 = time.perf_counter()
        sk = self.skull.skull_segmentation()
        search = engine_find(self.study.ct, sk.bone, mandible=sk.mandible)
        edited = {str(o.get(LANDMARK_KEY)) for o in coll.all_objects
                  if o.get(LANDMARK_KEY) and o.get(LANDMARK_EVIDENCE) in _BY_HAND} if keep_edited else set()
        found = {n: lm for n, lm in search.landmarks.items() if lm.point is not None and n not in edited}
        placed = []
        if found:
            snapped, normal = snap_to_surface(np.array([lm.point for lm in found.values()]),
                                              self.skull.skull_engine_mesh(target))
            for i, (name, lm) in enumerate(found.items()):
                obj = self._landmark_empty(name, snapped[i:i + 1], normal[i:i + 1])
                obj[LANDMARK_FLAG] = lm.flag
                obj[LANDMARK_EVIDENCE] = lm.evidence
                placed.append(obj)
        for obj in list(coll.all_objects):
            name = obj.get(LANDMARK_KEY)
            if name and name not in found and obj.get(LANDMARK_EVIDENCE) not in _BY_HAND:
                bpy.data.objects.remove(obj)
        set_flags(self.props.landmark_flags, {n: (lm.flag, lm.evidence) for n, lm in search.landmarks.items()
                                              if n not in edited})
        seconds = time.perf_counter() - t0
        self.study.record_timing("landmarks", seconds)
        return StepOutcome("landmarks", objects=tuple(placed), seconds=seconds,
                           values=dict(flags={n: lm.flag for n, lm in search.landmarks.items()},
                                       evidence={n: lm.evidence for n, lm in search.landmarks.items()},
                                       search=search))

    def adopt_export_flags(self, flags: dict[str, str]) -> None:
        """After an export, the study says what its files say: a landmark the export turned ``uncertain`` (its
        depth not supported by the CT's profile) is ``uncertain`` on its empty and in the study's landmark flags
        (its evidence says why), and the face object's provenance (the panel's source) lists the written flags.
        Before, the panel kept Find Landmarks' flags until the next Find Landmarks, which
        confused a tester."""
        why = "the CT's depth profile does not support it (Export for Printing)"
        current = self.landmark_flags()
        turned = {n for n, f in flags.items() if f == "uncertain" and current.get(n, ("ok", ""))[0] == "ok"}
        if turned:
            for obj in self.collection.all_objects:
                name = obj.get(LANDMARK_KEY)
                if name in turned:
                    obj[LANDMARK_FLAG] = "uncertain"
                    obj[LANDMARK_EVIDENCE] = "; ".join(e for e in (str(obj.get(LANDMARK_EVIDENCE, "")), why) if e)
            stored = {f.name: (f.flag, f.evidence) for f in self.props.landmark_flags}
            for n in turned & set(stored):
                stored[n] = ("uncertain", "; ".join(e for e in (stored[n][1], why) if e))
            set_flags(self.props.landmark_flags, stored)
        face = self.face.face_object()
        if face is not None and face.get(PROVENANCE_PROP):
            prov = json.loads(face[PROVENANCE_PROP])
            prov["landmark_flags"] = dict(flags)
            if "landmarks" in prov:
                prov["landmarks"] = {n: flags.get(n, f) for n, f in prov["landmarks"].items()}
            face[PROVENANCE_PROP] = json.dumps(prov)

    def landmark_flags(self) -> dict[str, tuple[str, str]]:
        """name -> (flag, evidence): of the last Find Landmarks, updated by hand edits; placed by hand: ``ok``."""
        flags = {f.name: (f.flag, f.evidence) for f in self.props.landmark_flags}
        for obj in self.collection.all_objects:
            name = obj.get(LANDMARK_KEY)
            if name:
                flags[str(name)] = (str(obj.get(LANDMARK_FLAG, "ok")),
                                    str(obj.get(LANDMARK_EVIDENCE, PLACED_BY_HAND)))
        return flags

    def flag_names(self) -> dict[str, str]:
        """name -> flag (``ok`` / ``uncertain`` / ``not_found``) for ``landmarks.csv``: :meth:`landmark_flags`
        without the evidence."""
        return {name: flag for name, (flag, _evidence) in self.landmark_flags().items()}

    def snap_moved_landmarks(self, target: str = D.DEPTH_TARGET.default,
                             tolerance_mm: float = 0.01) -> StepOutcome:
        """Landmarks whose empty was moved in the viewport go back onto the bone at the nearest point;
        their flag becomes ``ok`` (a person placed them). Returns the empties snapped and their names
        (``values``: ``names``)."""
        moved, snapped_objects = [], []
        for obj in list(self.collection.all_objects):
            name = obj.get(LANDMARK_KEY)
            if not name or "patient_mm" not in obj:
                continue
            p = self.world_to_patient(obj.matrix_world.translation)
            if np.linalg.norm(p - np.array(obj["patient_mm"], float)) > tolerance_mm:
                moved.append((obj, str(name), p))
        if moved:
            snapped, normal = snap_to_surface(np.array([p for _, _, p in moved]), self.skull.skull_engine_mesh(target))
            for i, (obj, name, _) in enumerate(moved):
                obj = self._landmark_empty(name, snapped[i:i + 1], normal[i:i + 1])
                obj[LANDMARK_FLAG] = "ok"
                obj[LANDMARK_EVIDENCE] = MOVED_BY_HAND
                snapped_objects.append(obj)
        return StepOutcome("snap_landmarks", objects=tuple(snapped_objects),
                           values=dict(names=[name for _, name, _ in moved]))

    # -------------------------------------------------------------------------------------- orientation
    def apply_frankfurt(self, reset: bool = False):
        """Transform every object of the study into the Frankfurt horizontal (or back)."""

        if reset:
            m = Matrix.Identity(4)
        else:
            lms = self.landmarks()
            need = ["Porion L", "Porion R", "Orbitale L", "Orbitale R"]
            missing = [n for n in need if n not in lms]
            if missing:
                raise PDEHeadError(f"the Frankfurt horizontal needs the landmarks {', '.join(missing)}")
            m = blender_matrix(frankfurt_transform(*(lms[n] for n in need)))
        for obj in self.collection.all_objects:
            if BASE_MATRIX_KEY not in obj.keys():
                obj[BASE_MATRIX_KEY] = [v for row in obj.matrix_world for v in row]
            base = Matrix(np.array(obj[BASE_MATRIX_KEY], float).reshape(4, 4).tolist())
            obj.matrix_world = m @ base
        self.collection[FRANKFURT_KEY] = [v for row in m for v in row]
        return m

    def frankfurt_applied(self) -> bool:
        return bool(self.collection.get(FRANKFURT_KEY))

    def to_frankfurt(self, obj) -> None:
        """A new object of the study into the study's Frankfurt frame (its patient-frame matrix kept)."""
        if self.frankfurt_applied():
            obj[BASE_MATRIX_KEY] = [v for row in obj.matrix_world for v in row]
            obj.matrix_world = self.frankfurt_matrix() @ obj.matrix_world

    def mirror_plane(self, source: str = D.MIRROR_PLANE.default) -> tuple[np.ndarray, np.ndarray, str]:
        """The mid-sagittal plane (point, normal in patient mm) and a sentence saying where it came from."""
        coll = self.collection
        lms = self.landmarks()
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
        point, normal, info = symmetry_plane(self.skull.skull_engine_mesh("BONE" if coll.get("pdehead_bone_object")
                                                                    else "PDE").vertices)
        if not info["converged"]:
            raise PDEHeadError("the skull's symmetry plane did not converge: place bilateral landmarks instead")
        return point, normal, f"skull symmetry (median mirror residual {info['residual_mm']:.1f} mm)"

    def mirror_object(self, obj, source: str = D.MIRROR_PLANE.default) -> StepOutcome:
        """A linked copy of ``obj`` mirrored across the mid-sagittal plane (:meth:`mirror_plane`): the copy, and
        the plane (``values``: ``point`` and ``normal`` in patient mm, ``how``: where it came from)."""
        point, normal, how = self.mirror_plane(source)
        frank = self.frankfurt_matrix()
        m = frank @ blender_matrix(mirror_matrix(point, normal)) @ frank.inverted()
        copy = obj.copy()
        copy.name = f"{obj.name} Mirrored"
        for c in obj.users_collection[:1]:
            c.objects.link(copy)
        copy.matrix_world = m @ obj.matrix_world
        copy.pop(BASE_MATRIX_KEY, None)
        return StepOutcome("mirror", objects=(copy,), values=dict(point=point, normal=normal, how=how))
