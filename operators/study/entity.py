"""One PDE Head study as an object: :class:`Study` wraps a study collection and owns its settings,
in-memory cache, CT, head, stored boundary conditions, CT table, warnings and timings, and runs its
pipeline steps (:class:`.steps.PipelineSteps`: ``Study.import_ct``, ``segment``, ``boundaries``,
``surface``, ``volume``) and live updates (:class:`.live.LiveSolid`: ``solid``, ``live_update``,
``apply_cutter``, ``add_cutter``); the steps return their outcomes (:class:`operators.outcome.StepOutcome`,
:class:`operators.outcome.BoundaryOutcome`). Its forensic side is a component it holds (``study.forensic``, a
:class:`operators.forensic.study.ForensicStudy`).

The pattern is MolecularNodes' entity + session registry: an entity is looked up by a uuid that
lives in the .blend (here the study settings' ``study_id``), and the registry holds one Python object
per uuid for the session. A :class:`Study` keeps no lasting reference to a ``bpy`` datablock (they
become invalid after undo or file load): :meth:`Study.of` refreshes the collection it wraps each time.
What a study saves is unchanged (state.py's custom properties and settings object).
"""
from __future__ import annotations

import base64
import hashlib
import json
import math
from pathlib import Path

import bpy
import numpy as np

from ...pdehead_addon import (
    PDEHeadError,
    SolidCTTable,
    StorageError,
    control_ranges,
    dumps_boundaries,
    intensity_window,
    load_ct,
    loads_boundaries,
    make_phantom,
    solve_with_controls,
)
from .. import state
from ..forensic.study import ForensicStudy
from ..scene import scene
from ..state import BOUNDARY_KEY, CT_TABLE_FOR, CT_TABLE_KEY
from .live import LiveSolid
from .progress import step_progress
from .steps import PipelineSteps

#: A study's warnings are one string property, one warning per line (a warning may contain "; ").
WARNING_SEPARATOR = "\n"
_MAX_WARNINGS_CHARS = 4000


#: At most this many characters of a stored timings table are parsed (a handful of steps: ~300).
MAX_TIMINGS_JSON_CHARS = 65536


def parse_timings(text) -> dict[str, float]:
    """``{step: seconds}`` from the stored JSON, or {} for anything else (the .blend's state is data)."""
    if not text or not isinstance(text, str) or len(text) > MAX_TIMINGS_JSON_CHARS:
        return {}
    try:
        data = json.loads(text)
    except (ValueError, RecursionError):
        return {}
    if not isinstance(data, dict):
        return {}
    out = {}
    for step, seconds in data.items():
        if isinstance(seconds, (int, float)) and not isinstance(seconds, bool) and math.isfinite(seconds):
            out[str(step)] = float(seconds)
    return out


class Study(PipelineSteps, LiveSolid):
    """One study (a collection with study settings); get it with :meth:`of`, :meth:`active` or
    :meth:`of_settings`, make one with :meth:`import_ct`, :meth:`phantom` or :meth:`create`."""

    def __init__(self, collection):
        self.collection = collection
        self._forensic = None

    # --- registry -----------------------------------------------------------------------------

    @classmethod
    def of(cls, collection) -> Study:
        """The study of ``collection`` (one object per ``study_id`` for the session, in ``state.REGISTRY``)."""
        s = state.settings(collection)
        if s is None:
            raise ValueError(f"collection '{getattr(collection, 'name', collection)}' is not a PDE Head study")
        studies = state.REGISTRY.studies
        study = studies.get(s.study_id)
        if study is None:
            study = studies[s.study_id] = cls(collection)
        study.collection = collection
        return study

    @classmethod
    def active(cls, context=None, name: str = "") -> Study | None:
        """The study an operator works on (:func:`state.active_study`), or None."""
        coll = state.active_study(context, name)
        return cls.of(coll) if coll is not None else None

    @classmethod
    def of_settings(cls, study_settings) -> Study | None:
        """The study whose settings these are (an update callback's ``self``), or None."""
        coll = state.study_of_settings(study_settings)
        return cls.of(coll) if coll is not None else None

    @classmethod
    def forget(cls, study_id: str | None = None) -> None:
        """Drop one study (or all) from the registry (the .blend keeps them)."""
        if study_id is None:
            state.REGISTRY.studies.clear()
        else:
            state.REGISTRY.studies.pop(study_id, None)

    # --- what the study owns --------------------------------------------------------------------

    @property
    def forensic(self) -> ForensicStudy:
        """The study's forensic side (skull, landmarks, pegs, export, face): a component this study holds,
        made on first use (its state lives in the collection's forensic settings and :attr:`cache`)."""
        if self._forensic is None:
            self._forensic = ForensicStudy(self)
        return self._forensic

    @property
    def name(self) -> str:
        return self.collection.name

    @property
    def settings(self):
        """The study settings PropertyGroup (on the study's settings object)."""
        return state.settings(self.collection)

    @property
    def settings_object(self):
        """The Empty that holds the settings (what Blender animates)."""
        return self.settings.id_data

    @property
    def study_id(self) -> str:
        return self.settings.study_id

    @property
    def warnings(self) -> list[str]:
        """The study's warnings (loader, segmentation, curves), one per item, in the engine's words."""
        text = self.settings.warnings or ""
        return [p for p in text.split(WARNING_SEPARATOR) if p.strip()]

    def add_warnings(self, messages) -> list[str]:
        """Append the messages not yet among the study's warnings; returns those added."""
        known = self.warnings
        new = [str(m).strip() for m in dict.fromkeys(messages)
               if str(m).strip() and not any(k in str(m) or str(m) in k for k in known)]
        if new:
            self.settings.warnings = WARNING_SEPARATOR.join(known + new)[:_MAX_WARNINGS_CHARS]
        return new

    @property
    def notes(self) -> list[str]:
        """The automatic choices the import made for a correct input (information, not warnings)."""
        text = self.settings.notes or ""
        return [p for p in text.split(WARNING_SEPARATOR) if p.strip()]

    def add_notes(self, messages) -> None:
        """Append the messages not yet among the study's notes."""
        known = self.notes
        new = [str(m).strip() for m in dict.fromkeys(messages) if str(m).strip() and str(m).strip() not in known]
        if new:
            self.settings.notes = WARNING_SEPARATOR.join(known + new)[:_MAX_WARNINGS_CHARS]

    @property
    def cache(self) -> state.StudyCache:
        """The in-memory results (CT, segmentation, curves, head, ...)."""
        return state.cache_for(self.study_id)

    @property
    def head(self):
        """The solved PDE head for the study's current controls (cached, re-solved on change)."""
        cache = self.cache
        key = self.pde_key()
        if cache.head is None or cache.head_key != key:
            bset = self.boundary_set()
            if bset is None:
                raise PDEHeadError(f"study '{self.name}' has no boundary curves yet: run Extract Boundaries")
            cont, smoothing, approximation, modes, dome = key
            cache.head = solve_with_controls(bset, cont, smoothing=smoothing, approximation=approximation,
                                             modes=modes, dome=dome)
            cache.head_key = key
            cache.wfield = None
        return cache.head

    def solve(self):
        """:attr:`head`, recording the solve time (``pde_solve``) when it was solved afresh."""
        with state.Timer() as t:
            cache = self.cache
            fresh = cache.head is None or cache.head_key != self.pde_key()
            head = self.head
        if fresh:
            self.record_timing("pde_solve", t.seconds)
        return head

    # --- timings --------------------------------------------------------------------------------

    @property
    def timings(self) -> dict[str, float]:
        """The last run's seconds per step (the Timings panel); a stored value that is no such table
        (a damaged or tampered .blend) reads as none, and so do entries that are no finite numbers."""
        return parse_timings(self.settings.timings_json)

    def record_timing(self, step: str, seconds: float) -> None:
        """Remember how long a step took (shown in the Timings panel; the last run's values)."""
        s = self.settings
        timings = parse_timings(s.timings_json)
        timings[step] = round(float(seconds), 4)
        s.timings_json = json.dumps(timings)

    # --- where the CT comes from ----------------------------------------------------------------

    def source_candidates(self) -> list[Path]:
        """Where the study's CT may be, best first.

        The recorded ``source`` (``//``-relative to the .blend after a save, so a project folder
        moved as a whole still finds its CT), then the absolute path recorded at the last save
        (the .blend alone moved).
        """
        s = self.settings
        out: list[Path] = []
        for text in (s.source, s.source_absolute):
            if not text:
                continue
            if text.startswith("//") and not bpy.data.filepath:
                continue  # relative to a file that is not saved: meaningless
            path = Path(bpy.path.abspath(text))
            if path not in out:
                out.append(path)
        return out

    def resolve_source(self) -> Path | None:
        """The first existing :meth:`source_candidates` path, or None (source gone)."""
        for path in self.source_candidates():
            if path.exists():
                return path
        return None

    def ct_status(self) -> tuple[str, str]:
        """(text, icon) for the Study panel: CT in memory, re-readable from a path, or missing."""
        s = self.settings
        if self.cache.ct is not None:
            return "CT in memory", "CHECKMARK"
        if s.source_kind == "PHANTOM":
            return "CT re-made on demand (phantom)", "FILE_REFRESH"
        path = self.resolve_source() if s.source_kind == "FILES" else None
        if path is not None:
            return f"CT re-read on demand from {path}", "FILE_REFRESH"
        where = ", ".join(str(p) for p in self.source_candidates()) or "(no source recorded)"
        return f"CT source missing: {where}", "ERROR"

    def source_missing_message(self) -> str:
        where = " or ".join(str(p) for p in self.source_candidates()) or "(no source recorded)"
        return (f"study '{self.name}': the CT is not in memory and its source is gone: {where} not found. "
                "Point Source (Study panel) at the CT folder to re-read it; nothing was changed")

    # --- the PDE boundary conditions and the CT table stored in the .blend ---------------------

    def store_boundaries(self, bset_or_head) -> int:
        """Store the boundary conditions in the collection (base64 custom property); returns bytes."""
        raw = dumps_boundaries(bset_or_head)
        self.collection[BOUNDARY_KEY] = base64.b64encode(raw).decode("ascii")
        return len(raw)

    def has_stored_boundaries(self) -> bool:
        return bool(self.collection.get(BOUNDARY_KEY))

    def load_stored_boundaries(self):
        """The BoundarySet stored in the collection, or None."""
        text = self.collection.get(BOUNDARY_KEY)
        if not text:
            return None
        try:
            raw = base64.b64decode(text.encode("ascii"), validate=True)
        except (ValueError, TypeError) as exc:
            raise StorageError(f"study '{self.name}': stored boundary data is corrupt ({exc})") from None
        return loads_boundaries(raw, f"study '{self.name}': the boundary curves stored in the .blend")

    def boundary_set(self):
        """The study's BoundarySet: from memory, else from the .blend, else None."""
        cache = self.cache
        if cache.bset is None:
            cache.bset = self.load_stored_boundaries()
        return cache.bset

    def boundary_digest(self) -> str:
        """A short digest of the stored boundary conditions (which curves a CT table belongs to)."""
        return hashlib.sha1(str(self.collection.get(BOUNDARY_KEY, "")).encode("ascii", "replace")).hexdigest()[:16]

    def table_key(self) -> str:
        """What the solid's CT table depends on, as JSON: the PDE controls, the curves and the CT's size.

        The same key after reopening the file means the same PDE solution (it is solved again from
        the same stored curves with the same controls), so a table stored in the .blend is reused.
        """
        s = self.settings
        return json.dumps([list(self.pde_key()), self.boundary_digest(), [int(n) for n in s.dimensions]])

    def store_ct_table(self, key: str, table, window) -> int:
        """Keep the solid's CT table in the .blend (8-bit, compressed; :meth:`SolidCTTable.to_bytes`); returns bytes."""
        raw = table.to_bytes(window)
        self.collection[CT_TABLE_KEY] = base64.b64encode(raw).decode("ascii")
        self.collection[CT_TABLE_FOR] = key
        return len(raw)

    def stored_ct_table_key(self) -> str:
        return str(self.collection.get(CT_TABLE_FOR, ""))

    def load_stored_ct_table(self):
        """``(key, table, window)`` of the CT table stored in the .blend, or None (none stored / unreadable)."""
        text = self.collection.get(CT_TABLE_KEY)
        if not text:
            return None
        try:
            table, window = SolidCTTable.from_bytes(base64.b64decode(str(text).encode("ascii"), validate=True))
        except Exception as exc:  # noqa: BLE001 - a damaged table is as good as none; the CT can re-make it
            print(f"PDE Head: study '{self.name}': the stored CT table is unreadable ({exc})")
            return None
        return self.stored_ct_table_key(), table, window

    def continuity(self) -> str:
        """The study's surface continuity: the property once the user set it, else what the stored
        boundary conditions were made for."""
        s = self.settings
        if s.is_property_set("continuity"):
            return s.continuity
        bset = self.boundary_set()
        stored = bset.meta.get("pde_settings") if bset is not None else None
        if not isinstance(stored, dict):              # curves extracted in this session: today's default
            return s.continuity
        return stored.get("continuity", s.continuity)

    def pde_key(self) -> tuple:
        """The controls the solved head depends on: (continuity, smoothing, approximation, modes, dome)."""
        s = self.settings
        smoothing = None if s.smoothing_auto else float(s.smoothing)
        approximation = None if s.approximation_auto else float(s.approximation)
        modes = None if s.modes <= 0 else int(s.modes)
        return self.continuity(), smoothing, approximation, modes, bool(s.dome)

    # --- the CT and the CT table of the solid (in memory, re-read or from the .blend) -------------

    @property
    def ct(self):
        """The study's CT volume from memory, else re-read from its recorded source (:meth:`reload_ct`).

        Raises a :class:`PDEHeadError` that names the missing source when it cannot be re-read,
        so a step that needs the CT (solid colours, volume, segmentation) never runs without it.
        """
        ct = self.cache.ct
        if ct is None:
            ct = self.reload_ct()
        return ct

    def reload_ct(self):
        """Load the CT again from the recorded source (phantom or path + the recorded loader options).

        The re-read CT must have the recorded dimensions; a different CT at that path is refused
        (its colours would not belong to this study's head).
        """
        s = self.settings
        cache = self.cache
        if s.source_kind == "PHANTOM":
            ct = make_phantom().ct
        elif s.source_kind == "FILES":
            path = self.resolve_source()
            if path is None:
                raise PDEHeadError(self.source_missing_message())
            options = json.loads(s.load_options or "{}")
            for key in ("shape", "spacing", "resample_spacing"):
                if isinstance(options.get(key), list):
                    options[key] = tuple(options[key])
            ct = load_ct(path, **options)
        else:
            raise PDEHeadError(f"study '{self.name}': the CT is not in memory and has no source to reload")
        nz, ny, nx = ct.shape
        expected = tuple(int(n) for n in s.dimensions)
        if any(expected) and (nx, ny, nz) != expected:
            raise PDEHeadError(f"study '{self.name}': the CT re-read from {s.source or 'the phantom'} has "
                               f"{nx} x {ny} x {nz} voxels, the study was built from {' x '.join(map(str, expected))}; "
                               "refusing to mix them (point Source at the original CT)")
        cache.ct = ct
        cache.window = None
        cache.ct_table = None
        return ct

    def current_ct_table(self):
        """The solid's CT table for the study's current PDE solution, from memory or from the .blend, or None.

        A table saved in the .blend (:meth:`store_ct_table_for_save`) is used when it was tabulated
        for the same curves and controls: a reopened file, or one sent without its CT, keeps live
        cutaways and nw without reading the CT. Its window becomes the study's window when none is known.
        """
        cache = self.cache
        key = self.table_key()
        if cache.ct_table is not None and cache.ct_table[0] == key:
            return cache.ct_table[1]
        if self.stored_ct_table_key() == key:
            stored = self.load_stored_ct_table()
            if stored is not None:
                cache.ct_table = (key, stored[1])
                if cache.window is None:
                    cache.window = stored[2]
                cache.stored_window = stored[2]
                return stored[1]
        return None

    def previous_ct_table(self):
        """``(table, window)`` of an earlier PDE solution of this study (memory, else the .blend), or None.

        Looked up in (u, v, w), it gives the new solid nearly the right colours at once (the
        parameterisation moves little with a control); :meth:`refresh_solid_colours` replaces them.
        """
        cache = self.cache
        if cache.ct_table is not None:
            window = cache.window or cache.stored_window
            if window is not None:
                return cache.ct_table[1], window
        stored = self.load_stored_ct_table()
        if stored is not None:
            cache.stored_window = stored[2]
            return stored[1], (cache.window or stored[2])
        return None

    def ct_table(self, head, ct):
        """The CT tabulated in the solid's (u, v, w) for this PDE solution (built once, ~0.5-1.3 s on CThead).

        Kept until the PDE is re-solved with other controls or curves, or the CT is re-read, so
        cutaway and resolution sliders only look values up.
        """
        table = self.current_ct_table()
        if table is None:
            table = SolidCTTable(head, ct, progress=step_progress("solid"))
            self.cache.ct_table = (self.table_key(), table)
        return table

    def store_ct_table_for_save(self) -> int:
        """Put the current CT table into the .blend unless it is there already (save_pre); returns bytes written."""
        s = self.settings
        if s.solid_object is None:
            return 0
        cache = self.cache
        key = self.table_key()
        if cache.ct_table is None or cache.ct_table[0] != key or self.stored_ct_table_key() == key:
            return 0
        window = cache.window or cache.stored_window
        if window is None:
            return 0
        return self.store_ct_table(key, cache.ct_table[1], window)

    def ct_window(self, ct=None) -> tuple[float, float]:
        """The study's CT intensity window (:func:`ct_volume.intensity_window`), computed once per CT."""
        cache = self.cache
        if cache.window is None:
            cache.window = intensity_window(ct if ct is not None else self.ct)
        return cache.window

    # --- controls and removal ---------------------------------------------------------------------

    def default_controls(self) -> tuple[float, float]:
        """The solver's default smoothing and approximation as fractions of the study's maxima (the
        values a slider starts from when its Auto box is cleared)."""
        s = self.settings
        modes = None if s.modes <= 0 else s.modes
        ranges = control_ranges(self.boundary_set(), self.continuity(), modes)

        def fraction(pair):
            d, m = (np.asarray(x, float) for x in pair)
            with np.errstate(invalid="ignore", divide="ignore"):
                f = np.where(m > 0, d / m, 0.0)
            return float(np.clip(np.mean(f), 0.0, 1.0))
        return fraction(ranges["smoothing"]), fraction(ranges["approximation_mm"])

    def remove(self) -> None:
        """Delete a study's objects, data and collection; a scene left without a camera (or active study)
        falls back to another study's."""
        coll = self.collection
        state.drop_cache(self.study_id)
        Study.forget(self.study_id)
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
        _fall_back_to_other_studies()


def _fall_back_to_other_studies() -> None:
    for sc in bpy.data.scenes:
        inside = {c.name for c in sc.collection.children_recursive}
        others = [c for c in state.studies() if c.name in inside]
        if not others:
            continue
        if sc.pdehead.active_study is None:
            sc.pdehead.active_study = others[0]
        if sc.camera is None:
            order = [sc.pdehead.active_study] + [c for c in others if c != sc.pdehead.active_study]
            sc.camera = next((cam for cam in (scene.study_object(c, scene.CAMERA_KIND) for c in order)
                              if cam is not None), None)
