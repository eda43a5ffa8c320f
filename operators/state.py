"""The study state: what lives in the .blend and what lives only in memory.

A *study* is one collection. Its settings (:class:`~.props.PDEHeadStudySettings`) live on the
study's settings object, an Empty in the collection that Blender can animate (``Object.pdehead``;
the collection points at it, ``Collection.pdehead_settings_object``); :func:`settings` is the one
accessor, and ``collection.pdehead`` reads the same. Files saved by 0.1.0 kept the settings on the
collection: :func:`migrate_legacy_settings` moves them when such a file is loaded. Its PDE boundary conditions
(paper section 5.2: the 3t+1 curves, a few hundred kB) are stored IN the .blend as a
base64 string custom property of the collection, so that a saved and reopened file
rebuilds the meshes from the live parameters without re-segmenting.

The heavy, re-computable objects (CT volume, segmentation, solved PDE head, w-field)
are cached in memory per study, keyed by the study's id (a uuid string kept in the
collection settings; collection names may change). Nothing here holds a reference to a
``bpy`` datablock (they become invalid after undo or file load).

One study as an object (its settings, cache, CT, stored curves and CT table, warnings, timings and
steps): :class:`.entity.Study`, built on the accessors here; code that has a study uses it, and
:func:`settings` is for code that has only a collection (is it a study? which study id?).
"""
from __future__ import annotations

import time
import uuid
from dataclasses import dataclass, field
from typing import Any, Callable

import bpy

from ..pdehead_addon import message_for_cli, message_for_dialog
from .compat import registered_id_properties

NO_STUDY_MESSAGE = "No PDE Head study: import a CT (File > Import > CT Head) or load the phantom"
BOUNDARY_KEY = "pdehead_boundaries"  # collection custom property: base64 of dumps_boundaries()
CT_TABLE_KEY = "pdehead_ct_table"  # collection custom property: base64 of SolidCTTable.to_bytes() (save_pre)
CT_TABLE_FOR = "pdehead_ct_table_for"  # ... and the JSON of the table_key() it was tabulated for
PROP = "pdehead"  # name of the PointerProperty on Object (study settings) / Scene
SETTINGS_OBJECT = "pdehead_settings_object"  # Collection -> its settings object
SETTINGS_KIND = "study_settings"  # Object["pdehead_kind"] of a settings object


@dataclass
class StudyCache:
    """In-memory results of one study (all optional; re-computed on demand where possible)."""

    ct: Any = None            # CTVolume
    seg: Any = None           # Segmentation
    bset: Any = None          # BoundarySet
    head: Any = None          # PDEHead
    head_key: tuple | None = None  # (smoothing, modes) the head was solved with
    wfield: Any = None        # WField of the last volume
    window: tuple | None = None     # the CT's intensity window (ct_volume.intensity_window), per CT
    stored_window: tuple | None = None  # the window of the CT table stored in the .blend (no CT needed)
    ct_table: tuple | None = None   # (table_key, SolidCTTable): the CT in the solid's (u, v, w)
    cutter_signature: tuple | None = None  # the cutter transform last applied (study.pdehead_cutter_update)
    forensic: dict = field(default_factory=dict)  # the skull, bone mesh and depth results (forensic/skull.py)

    def drop_from(self, step: str) -> None:
        """Forget everything that depends on ``step`` ("ct", "seg", "bset", "head")."""
        order = ["ct", "seg", "bset", "head"]
        for name in order[order.index(step):]:
            setattr(self, name, None)
        self.head_key = None
        self.wfield = None


@dataclass
class Registry:
    """What PDE Head keeps in memory while Blender runs, in one place: each study's cache (by study id) and
    the state of the session around the studies. :data:`REGISTRY` is the one instance: ``operators/`` keeps
    no other module-level state that changes (``scripts/study_measures.py`` counts it)."""

    #: study id -> the study entity (:class:`.entity.Study`, one per study for the session; it holds its
    #: forensic side, :class:`operators.forensic.study.ForensicStudy`, as a component) ...
    studies: dict[str, Any] = field(default_factory=dict)
    #: ... and its in-memory results.
    caches: dict[str, StudyCache] = field(default_factory=dict)
    #: Where messages are shown: "dialog" (Blender's UI: field names) or "cli" (scripts/pdehead.py sets it:
    #: flags). The engine names its Python arguments; :func:`user_text` rewrites them
    #: (pdehead_addon.core.wording).
    audience: str = "dialog"
    #: Depth of :class:`suspended_updates`: while above 0, no update callback rebuilds anything.
    suspended: int = 0
    #: ``hook(step, fraction, message)`` called by the long steps while a pipeline or an operator runs; it may
    #: raise :class:`~pdehead_addon.Cancelled` (Esc in Blender, Ctrl-C on the CLI). Set by the runner
    #: (:func:`.progress.step_progress` reads it).
    progress_hook: Callable | None = None
    #: The handlers running now ("animation", "face", "studies"): a handler does not run inside itself.
    running: set[str] = field(default_factory=set)
    #: study id -> {group: values last applied} by the animation handler (:mod:`operators.study.animation`).
    animation_applied: dict[str, dict] = field(default_factory=dict)
    #: study id -> names of objects the animation handler hid because their rebuild failed.
    animation_hidden: dict[str, set] = field(default_factory=dict)
    #: study id -> (time, its live solid) of the solid colours waiting to be refreshed (:mod:`.live`).
    colours_pending: dict[str, tuple] = field(default_factory=dict)
    #: The depth tables read for the face (:mod:`operators.forensic.face`), by source; and how often a face
    #: model was prepared.
    face_tables: dict = field(default_factory=dict)
    face_prepare_calls: int = 0
    #: Names of images whose packed pixels changed since the last save (:mod:`operators.scene.objects`).
    unpacked_changes: set[str] = field(default_factory=set)
    #: .vdb files this session wrote, and those a rebuild made obsolete (removed at the next save,
    #: :mod:`operators.volume.vdb_files`).
    vdb_written: set[str] = field(default_factory=set)
    vdb_superseded: set[str] = field(default_factory=set)


#: The one registry of the session's studies and their state.
REGISTRY = Registry()

# ------------------------------------------------------------------------------------------
# Messages: stored in the engine's words, shown in the words of where they appear


def user_text(message: str) -> str:
    """An engine message in the words of the registry's ``audience``, on one line."""
    return message_for_cli(message) if REGISTRY.audience == "cli" else message_for_dialog(message)


class suspended_updates:
    """``with suspended_updates(): settings.nu = ...`` (no live rebuild while inside): operators writing many
    settings at once."""

    def __enter__(self):
        REGISTRY.suspended += 1

    def __exit__(self, *exc):
        REGISTRY.suspended -= 1
        return False


def updates_suspended() -> bool:
    """True inside :class:`suspended_updates` (the update callbacks of props.py then do nothing)."""
    return REGISTRY.suspended > 0


class running:
    """``with running("animation"):`` marks a handler as running (:meth:`now` then says so), so that
    what it changes does not run it again inside itself."""

    def __init__(self, name: str):
        self.name = name

    def __enter__(self):
        REGISTRY.running.add(self.name)

    def __exit__(self, *exc):
        REGISTRY.running.discard(self.name)
        return False

    @staticmethod
    def now(name: str) -> bool:
        return name in REGISTRY.running


def cache_for(study_id: str) -> StudyCache:
    """The (possibly empty) in-memory cache of a study."""
    return REGISTRY.caches.setdefault(study_id, StudyCache())


def restore_cache(study_id: str, cache: StudyCache) -> None:
    """Put back a study's cache (a snapshot's copy, see pipeline_run.StudySnapshot)."""
    REGISTRY.caches[study_id] = cache


def drop_cache(study_id: str | None = None) -> None:
    """Free one study's cache, or all of them."""
    if study_id is None:
        REGISTRY.caches.clear()
    else:
        REGISTRY.caches.pop(study_id, None)


def cached_study_ids() -> list[str]:
    return list(REGISTRY.caches)


def new_study_id() -> str:
    return uuid.uuid4().hex


# --- which study ----------------------------------------------------------------------------

def _settings_object(collection):
    """The Empty that holds a study's settings (animatable), or None for a collection that is no study."""
    obj = getattr(collection, SETTINGS_OBJECT, None) if collection is not None else None
    if obj is not None and collection in obj.users_collection:
        return obj
    if collection is None or not hasattr(collection, "objects"):
        return None
    for candidate in collection.objects:  # the pointer lost (e.g. a collection appended without it)
        if candidate.get("pdehead_kind") == SETTINGS_KIND:
            return candidate
    return None


def settings(collection: bpy.types.Collection):
    """The study settings PropertyGroup of a study collection (None for other collections).

    They live on the study's settings object, so ``settings(coll).keyframe_insert("v_range")``
    keyframes them like any Blender property.
    """
    obj = _settings_object(collection)
    return getattr(obj, PROP, None) if obj is not None else None


def study_of_settings(study_settings):
    """The study collection whose settings these are (the inverse of :func:`settings`), or None."""
    obj = study_settings.id_data
    for coll in getattr(obj, "users_collection", ()):
        if _settings_object(coll) == obj:
            return coll
    return None


def new_settings_object(collection):
    """A new settings object (an Empty at the origin, named after the study) in ``collection``;
    returns its settings."""
    obj = bpy.data.objects.new(f"{collection.name} Settings", None)
    obj["pdehead_kind"] = SETTINGS_KIND
    obj.empty_display_type = "PLAIN_AXES"
    obj.empty_display_size = 0.02
    collection.objects.link(obj)
    setattr(collection, SETTINGS_OBJECT, obj)
    return getattr(obj, PROP)


def _legacy_value(prop, value):
    """A 0.1.0 ID-property value as the RNA property wants it (enums were stored as their index)."""
    if prop.type == "ENUM":
        if isinstance(value, str):
            return value
        items = list(prop.enum_items)
        for item in items:
            if item.value == int(value):
                return item.identifier
        return None
    if prop.type == "POINTER":
        return value if isinstance(value, bpy.types.ID) else None
    if getattr(prop, "array_length", 0):
        return tuple(value)
    return value


def migrate_legacy_settings() -> list[str]:
    """Move the settings of studies saved by 0.1.0 (on the collection) to a settings object.

    Returns the names of the migrated study collections. Idempotent: a collection whose
    settings were moved has no legacy group any more.
    """
    migrated = []
    for coll in bpy.data.collections:
        stored = registered_id_properties(coll)
        legacy = stored.get(PROP)
        if legacy is None or not hasattr(legacy, "keys") or not legacy.get("is_study"):
            continue
        s = settings(coll) or new_settings_object(coll)
        with suspended_updates():
            for prop in s.bl_rna.properties:
                if prop.identifier in ("rna_type", "name") or prop.identifier not in legacy.keys():
                    continue
                value = _legacy_value(prop, legacy[prop.identifier])
                if value is None:
                    continue
                try:
                    setattr(s, prop.identifier, value)
                except (TypeError, ValueError, AttributeError) as exc:
                    print(f"PDE Head: study '{coll.name}': setting {prop.identifier} not migrated ({exc})")
        for storage in (stored, coll):  # files of 4.x read by 5.x hold the group in both
            if storage.get(PROP) is not None:
                del storage[PROP]
        migrated.append(coll.name)
    return migrated


def is_study(collection) -> bool:
    return bool(getattr(settings(collection), "is_study", False))


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


class Timer:
    """``with Timer() as t: ...; t.seconds``."""

    def __enter__(self):
        self.start = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self.start
        return False


def remove_depsgraph_handler(handler) -> None:
    """Remove ``handler`` from ``depsgraph_update_post``, every copy of it.

    Matched by name and module, not identity: after a reload of the add-on the module's function is a
    new object, and the old one must not stay registered beside it.
    """
    handlers = bpy.app.handlers.depsgraph_update_post
    for h in list(handlers):
        if getattr(h, "__name__", "") == handler.__name__ and \
                getattr(h, "__module__", "") == handler.__module__:
            handlers.remove(h)


def install_depsgraph_handler(handler) -> None:
    """Register ``handler`` on ``depsgraph_update_post`` exactly once (also after a re-register)."""
    remove_depsgraph_handler(handler)
    bpy.app.handlers.depsgraph_update_post.append(handler)
