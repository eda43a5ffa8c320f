"""One PDE Head study as an object: :class:`Study` wraps a study collection and owns its settings,
in-memory cache, CT, head, stored boundary conditions, CT table and timings.

The pattern is MolecularNodes' entity + session registry: an entity is looked up by a uuid that
lives in the .blend (here the study settings' ``study_id``), and the registry holds one Python object
per uuid for the session. A :class:`Study` keeps no lasting reference to a ``bpy`` datablock (they
become invalid after undo or file load): :meth:`Study.of` refreshes the collection it wraps each time.
What a study saves is unchanged (state.py's custom properties and settings object).
"""
from __future__ import annotations

import json
from pathlib import Path

import bpy

from . import state


class Study:
    """One study (a collection with study settings); get it with :meth:`of` or :meth:`active`."""

    _registry: dict[str, Study] = {}

    def __init__(self, collection):
        self.collection = collection

    # --- registry -----------------------------------------------------------------------------

    @classmethod
    def of(cls, collection) -> Study:
        """The study of ``collection`` (one object per ``study_id`` for the session)."""
        s = state.settings(collection)
        if s is None:
            raise ValueError(f"collection '{getattr(collection, 'name', collection)}' is not a PDE Head study")
        study = cls._registry.get(s.study_id)
        if study is None:
            study = cls._registry[s.study_id] = cls(collection)
        study.collection = collection
        return study

    @classmethod
    def active(cls, context=None, name: str = "") -> Study | None:
        """The study an operator works on (:func:`state.active_study`), or None."""
        coll = state.active_study(context, name)
        return cls.of(coll) if coll is not None else None

    @classmethod
    def forget(cls, study_id: str | None = None) -> None:
        """Drop one study (or all) from the registry (the .blend keeps them)."""
        if study_id is None:
            cls._registry.clear()
        else:
            cls._registry.pop(study_id, None)

    # --- what the study owns --------------------------------------------------------------------

    @property
    def name(self) -> str:
        return self.collection.name

    @property
    def settings(self):
        """The study settings PropertyGroup (on the study's settings object)."""
        return state.settings(self.collection)

    @property
    def study_id(self) -> str:
        return self.settings.study_id

    @property
    def cache(self) -> state.StudyCache:
        """The in-memory results (CT, segmentation, curves, head, ...)."""
        return state.cache_for(self.study_id)

    @property
    def ct(self):
        """The CT volume, re-read from the recorded source when not in memory (study_ct.require_ct)."""
        from . import study_ct
        return study_ct.require_ct(self.collection)

    @property
    def head(self):
        """The solved PDE head in memory, or None (Build Surface solves it)."""
        return self.cache.head

    # --- timings --------------------------------------------------------------------------------

    @property
    def timings(self) -> dict[str, float]:
        """The last run's seconds per step (the Timings panel)."""
        return json.loads(self.settings.timings_json or "{}")

    def record_timing(self, step: str, seconds: float) -> None:
        """Remember how long a step took (shown in the Timings panel; the last run's values)."""
        s = self.settings
        timings = json.loads(s.timings_json or "{}")
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
