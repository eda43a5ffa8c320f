"""The study state: what lives in the .blend and what lives only in memory.

A *study* is one collection (``Collection.pdehead.is_study``). Its settings are the
collection's :class:`~.props.PDEHeadStudySettings`; its PDE boundary conditions
(paper section 5.2: the 3t+1 curves, a few hundred kB) are stored IN the .blend as a
base64 string custom property of the collection, so that a saved and reopened file
rebuilds the meshes from the live parameters without re-segmenting.

The heavy, re-computable objects (CT volume, segmentation, solved PDE head, w-field)
are cached in memory per study, keyed by the study's id (a uuid string kept in the
collection settings; collection names may change). Nothing here holds a reference to a
``bpy`` datablock (they become invalid after undo or file load).
"""
from __future__ import annotations

import base64
import json
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import bpy

from ..pdehead_addon import PDEHeadError, StorageError

BOUNDARY_KEY = "pdehead_boundaries"  # collection custom property: base64 of dumps_boundaries()
PROP = "pdehead"  # name of the PointerProperty on Collection / Scene


@dataclass
class StudyCache:
    """In-memory results of one study (all optional; re-computed on demand where possible)."""

    ct: Any = None            # CTVolume
    seg: Any = None           # Segmentation
    bset: Any = None          # BoundarySet
    head: Any = None          # PDEHead
    head_key: tuple | None = None  # (smoothing, modes) the head was solved with
    wfield: Any = None        # WField of the last volume
    extra: dict = field(default_factory=dict)

    def drop_from(self, step: str) -> None:
        """Forget everything that depends on ``step`` ("ct", "seg", "bset", "head")."""
        order = ["ct", "seg", "bset", "head"]
        for name in order[order.index(step):]:
            setattr(self, name, None)
        if step in order[:4]:
            self.head_key = None
            self.wfield = None


_CACHE: dict[str, StudyCache] = {}


def cache_for(study_id: str) -> StudyCache:
    """The (possibly empty) in-memory cache of a study."""
    return _CACHE.setdefault(study_id, StudyCache())


def drop_cache(study_id: str | None = None) -> None:
    """Free one study's cache, or all of them."""
    if study_id is None:
        _CACHE.clear()
    else:
        _CACHE.pop(study_id, None)


def cached_study_ids() -> list[str]:
    return list(_CACHE)


def new_study_id() -> str:
    return uuid.uuid4().hex


# --- which study ----------------------------------------------------------------------------

def settings(collection: bpy.types.Collection):
    """The study settings PropertyGroup of a collection."""
    return getattr(collection, PROP)


def is_study(collection) -> bool:
    return collection is not None and getattr(getattr(collection, PROP, None), "is_study", False)


def studies() -> list[bpy.types.Collection]:
    return [c for c in bpy.data.collections if is_study(c)]


def active_study(context=None, name: str = "") -> bpy.types.Collection | None:
    """The study an operator works on.

    ``name`` (a collection name) wins; then the scene's active study; then the study that
    holds the active object; then the only study in the file.
    """
    context = context or bpy.context
    if name:
        coll = bpy.data.collections.get(name)
        return coll if is_study(coll) else None
    scene = getattr(context, "scene", None)
    if scene is not None:
        coll = getattr(scene, PROP).active_study
        if is_study(coll):
            return coll
        obj = getattr(context, "active_object", None)
        if obj is not None:
            for coll in obj.users_collection:
                if is_study(coll):
                    return coll
    all_studies = studies()
    return all_studies[0] if len(all_studies) == 1 else None


def study_objects(collection) -> list[bpy.types.Object]:
    """All objects of a study (including nested collections)."""
    return list(collection.all_objects)


# --- PDE boundary conditions stored in the .blend ----------------------------------------

def store_boundaries(collection, bset_or_head) -> int:
    """Store the boundary conditions in the collection (base64 custom property); returns bytes."""
    from ..pdehead_addon import dumps_boundaries
    raw = dumps_boundaries(bset_or_head)
    collection[BOUNDARY_KEY] = base64.b64encode(raw).decode("ascii")
    return len(raw)


def has_stored_boundaries(collection) -> bool:
    return bool(collection.get(BOUNDARY_KEY))


def load_stored_boundaries(collection):
    """The BoundarySet stored in the collection, or None."""
    text = collection.get(BOUNDARY_KEY)
    if not text:
        return None
    from ..pdehead_addon import loads_boundaries
    try:
        raw = base64.b64decode(text.encode("ascii"), validate=True)
    except (ValueError, TypeError) as exc:
        raise StorageError(f"study '{collection.name}': stored boundary data is corrupt ({exc})") from None
    return loads_boundaries(raw)


def boundary_set(collection):
    """The study's BoundarySet: from memory, else from the .blend, else None."""
    cache = cache_for(settings(collection).study_id)
    if cache.bset is None:
        cache.bset = load_stored_boundaries(collection)
    return cache.bset


def continuity(collection) -> str:
    """The study's surface continuity: the property once the user set it, else what the stored
    boundary conditions were made for (files saved before the C2 surface: the paper's patches)."""
    s = settings(collection)
    if s.is_property_set("continuity"):
        return s.continuity
    bset = boundary_set(collection)
    stored = bset.meta.get("pde_settings") if bset is not None else None
    if not isinstance(stored, dict):              # curves extracted in this session: today's default
        return s.continuity
    return stored.get("continuity", "paper")


def pde_key(collection) -> tuple:
    """The controls the solved head depends on: (continuity, smoothing, approximation, modes, dome)."""
    s = settings(collection)
    smoothing = None if s.smoothing_auto else float(s.smoothing)
    approximation = None if s.approximation_auto else float(s.approximation)
    modes = None if s.modes <= 0 else int(s.modes)
    return continuity(collection), smoothing, approximation, modes, bool(s.dome)


def pde_head(collection):
    """The solved PDE head for the study's current controls (cached, re-solved on change)."""
    from ..pdehead_addon import solve_with_controls
    s = settings(collection)
    cache = cache_for(s.study_id)
    key = pde_key(collection)
    if cache.head is None or cache.head_key != key:
        bset = boundary_set(collection)
        if bset is None:
            raise PDEHeadError(f"study '{collection.name}' has no boundary curves yet: run Extract Boundaries")
        cont, smoothing, approximation, modes, dome = key
        cache.head = solve_with_controls(bset, cont, smoothing=smoothing, approximation=approximation,
                                         modes=modes, dome=dome)
        cache.head_key = key
        cache.wfield = None
    return cache.head


def default_controls(collection) -> tuple[float, float]:
    """The solver's default smoothing and approximation as fractions of the study's maxima (the
    values a slider starts from when its Auto box is cleared)."""
    import numpy as np
    from ..pdehead_addon import control_ranges
    s = settings(collection)
    ranges = control_ranges(boundary_set(collection), continuity(collection), None if s.modes <= 0 else s.modes)

    def fraction(pair):
        d, m = (np.asarray(x, float) for x in pair)
        with np.errstate(invalid="ignore", divide="ignore"):
            f = np.where(m > 0, d / m, 0.0)
        return float(np.clip(np.mean(f), 0.0, 1.0))
    return fraction(ranges["smoothing"]), fraction(ranges["approximation_mm"])


def require_ct(collection):
    """The study's CT volume from memory, else re-read from its recorded source (:func:`reload_ct`).

    Raises a :class:`PDEHeadError` that names the missing source when it cannot be re-read,
    so a step that needs the CT (solid colours, volume, segmentation) never runs without it.
    """
    s = settings(collection)
    ct = cache_for(s.study_id).ct
    if ct is None:
        ct = reload_ct(collection)
    return ct


def source_candidates(collection) -> list[Path]:
    """Where the study's CT may be, best first.

    The recorded ``source`` (``//``-relative to the .blend after a save, so a project folder
    moved as a whole still finds its CT), then the absolute path recorded at the last save
    (the .blend alone moved).
    """
    s = settings(collection)
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


def resolve_source(collection) -> Path | None:
    """The first existing :func:`source_candidates` path, or None (source gone)."""
    for path in source_candidates(collection):
        if path.exists():
            return path
    return None


def ct_status(collection) -> tuple[str, str]:
    """(text, icon) for the Study panel: CT in memory, re-readable from a path, or missing."""
    s = settings(collection)
    if cache_for(s.study_id).ct is not None:
        return "CT in memory", "CHECKMARK"
    if s.source_kind == "PHANTOM":
        return "CT re-made on demand (phantom)", "FILE_REFRESH"
    path = resolve_source(collection) if s.source_kind == "FILES" else None
    if path is not None:
        return f"CT re-read on demand from {path}", "FILE_REFRESH"
    where = ", ".join(str(p) for p in source_candidates(collection)) or "(no source recorded)"
    return f"CT source missing: {where}", "ERROR"


def source_missing_message(collection) -> str:
    where = " or ".join(str(p) for p in source_candidates(collection)) or "(no source recorded)"
    return (f"study '{collection.name}': the CT is not in memory and its source is gone: {where} not found. "
            "Point Source (Study panel) at the CT folder to re-read it; nothing was changed")


def reload_ct(collection):
    """Load the CT again from the recorded source (phantom or path + the recorded loader options).

    The re-read CT must have the recorded dimensions; a different CT at that path is refused
    (its colours would not belong to this study's head).
    """
    s = settings(collection)
    cache = cache_for(s.study_id)
    if s.source_kind == "PHANTOM":
        from ..pdehead_addon import make_phantom
        ct = make_phantom().ct
    elif s.source_kind == "FILES":
        path = resolve_source(collection)
        if path is None:
            raise PDEHeadError(source_missing_message(collection))
        from ..pdehead_addon import load_ct
        options = json.loads(s.load_options or "{}")
        for key in ("shape", "spacing", "resample_spacing"):
            if isinstance(options.get(key), list):
                options[key] = tuple(options[key])
        ct = load_ct(path, **options)
    else:
        raise PDEHeadError(f"study '{collection.name}': the CT is not in memory and has no source to reload")
    nz, ny, nx = ct.shape
    expected = tuple(int(n) for n in s.dimensions)
    if any(expected) and (nx, ny, nz) != expected:
        raise PDEHeadError(f"study '{collection.name}': the CT re-read from {s.source or 'the phantom'} has "
                           f"{nx} x {ny} x {nz} voxels, the study was built from {' x '.join(map(str, expected))}; "
                           "refusing to mix them (point Source at the original CT)")
    cache.ct = ct
    cache.extra.pop("window", None)
    cache.extra.pop("ct_table", None)
    return ct


def ct_table(collection, head, ct):
    """The CT tabulated in the solid's (u, v, w) for this PDE solution (built once, ~0.5 s on CThead).

    Kept until the PDE is re-solved (another head) or the CT is re-read, so cutaway and
    resolution sliders only look values up.
    """
    from ..pdehead_addon.pde_solid import SolidCTTable
    cache = cache_for(settings(collection).study_id)
    entry = cache.extra.get("ct_table")
    if entry is None or entry[0] is not head or entry[1] is not ct:
        entry = (head, ct, SolidCTTable(head, ct))
        cache.extra["ct_table"] = entry
    return entry[2]


def ct_window(collection, ct=None) -> tuple[float, float]:
    """The study's CT intensity window (:func:`volume.intensity_window`), computed once per CT."""
    cache = cache_for(settings(collection).study_id)
    window = cache.extra.get("window")
    if window is None:
        from .volume import intensity_window
        window = intensity_window(ct if ct is not None else require_ct(collection))
        cache.extra["window"] = window
    return window


# --- timings ---------------------------------------------------------------------------------

def record_timing(collection, step: str, seconds: float) -> None:
    """Remember how long a step took (shown in the Timings panel; the last run's values)."""
    s = settings(collection)
    timings = json.loads(s.timings_json or "{}")
    timings[step] = round(float(seconds), 4)
    s.timings_json = json.dumps(timings)


def timings(collection) -> dict[str, float]:
    return json.loads(settings(collection).timings_json or "{}")


class Timer:
    """``with Timer() as t: ...; t.seconds``."""

    def __enter__(self):
        self.start = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self.start
        return False
