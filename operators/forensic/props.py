"""A study's forensic settings and landmark flags, saved in the .blend as one PropertyGroup.

``Collection.pdehead_forensic`` (:class:`PDEHeadForensicSettings`) holds what the forensic steps are
told and what they record for the outputs: the depth table the pegs came from (its label and JSON),
the skull the last step measured on (``target``), the longest depth searched, the flags of the last
Find Landmarks (one :class:`PDEHeadLandmarkFlag` per landmark) and what the face from the skull was
built from (build id, table, sex, landmarks, flags, pegs). The face's table choice, its table file and
its sex are study settings (:class:`operators.study.props.PDEHeadStudySettings`: ``face_table``, ``face_table_file``,
``face_sex``) because switching them re-solves the face live.

**File format.** ``format_version`` says which layout a study's forensic state has:

* 0 -- a file saved by 0.1.0 (or a study made before its forensic state was first read): the state is
  JSON in the collection's custom properties ``pdehead_depth_table``, ``pdehead_landmark_flags`` and
  ``pdehead_face_options``;
* 1 (:data:`FORMAT_VERSION`) -- this PropertyGroup.

:func:`migrate` reads the custom properties of version 0 into the group and removes them only after
they are read (nothing else changes); it runs for every study after a file is loaded (``load_post``)
and when a step first touches a study.

Derived caches stay custom properties of the collection, as before: the skull's info and boundary
curves, the depth statistics, the Frankfurt transform (16 doubles: a float property would round it
to 32 bits) and the prepared face model (a large state string the live face restores from); the
landmark empties keep their own patient mm, flag and evidence.
"""
from __future__ import annotations

import json
import traceback

import bpy
from bpy.props import CollectionProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from ...pdehead_addon import DepthTable, defaults as D
from .. import state

#: The layout of the forensic state this version writes (see the module docstring).
FORMAT_VERSION = 1
PROP = "pdehead_forensic"                       # Collection -> PDEHeadForensicSettings
#: The custom properties of format 0 (files saved by 0.1.0), read by :func:`migrate`.
LEGACY_DEPTH_TABLE = "pdehead_depth_table"      # JSON of the DepthTable the pegs came from
LEGACY_LANDMARK_FLAGS = "pdehead_landmark_flags"  # JSON {name: [flag, evidence]} of the last Find Landmarks
LEGACY_FACE_OPTIONS = "pdehead_face_options"    # JSON of what the face was built from

TARGET_ITEMS = [('BONE', "Bone skull", "The bone surface: smoothed marching cubes of the bone (skull.<fmt>)"),
                ('PDE', "PDE envelope", "The smooth PDE skull envelope over orbits and nasal aperture "
                                        "(skull_envelope.<fmt>)")]


def max_depth_property():
    """The deepest tissue depth measured (:data:`defaults.MAX_DEPTH`): one declaration for the study's forensic
    settings and the Tissue Depth operator that offers it again."""
    return FloatProperty(name=D.MAX_DEPTH.label, **D.MAX_DEPTH.limits(), subtype='DISTANCE',
                         description=D.MAX_DEPTH.description)


class PDEHeadLandmarkFlag(bpy.types.PropertyGroup):
    """One landmark's flag (``name``: the landmark) and the evidence behind it."""

    flag: StringProperty(name="Flag", description="ok, uncertain or not_found")
    evidence: StringProperty(name="Evidence", description="Why the landmark has this flag")


class PDEHeadForensicSettings(bpy.types.PropertyGroup):
    """A study's forensic settings and state (on its collection; see :mod:`.props`)."""

    format_version: IntProperty(name="Format Version", default=0, min=0,
                                description="Layout of the forensic state (0: custom properties of 0.1.0)")
    depth_table_name: StringProperty(name="Depth Table", description="The table the marker pegs came from")
    depth_table: StringProperty(name="Depth Table (JSON)", options={'HIDDEN'},
                                description="The depth table the marker pegs came from, as JSON")
    target: EnumProperty(name=D.DEPTH_TARGET.label, items=TARGET_ITEMS, default=D.DEPTH_TARGET.default,
                         description=D.DEPTH_TARGET.description)
    max_depth: max_depth_property()
    landmark_flags: CollectionProperty(type=PDEHeadLandmarkFlag, name="Landmark Flags",
                                       description="The flags of the last Find Landmarks")
    # what the face from the skull was built from (Build Face)
    face_build: StringProperty(name="Face Build", options={'HIDDEN'},
                               description="Id of the last Build Face (the kept face model belongs to it)")
    face_table: StringProperty(name="Face Table (JSON)", options={'HIDDEN'},
                               description="The depth table the face's pegs stand by, as JSON")
    face_sex: StringProperty(name="Face Sex", description="female, male or empty (pooled)")
    face_flags: CollectionProperty(type=PDEHeadLandmarkFlag, name="Face Landmark Flags")
    face_pegs: CollectionProperty(type=PDEHeadLandmarkFlag, name="Face Pegs",
                                  description="The landmarks the face has a peg at, in the model's order")
    face_landmarks: StringProperty(name="Face Landmarks (JSON)", options={'HIDDEN'},
                                   description="{name: [x, y, z]} patient mm the face was built from (JSON "
                                               "keeps the float64 coordinates; Blender's float is 32-bit)")
    face_options: StringProperty(name="Face Options (JSON)", options={'HIDDEN'},
                                 description="Extra options of the face model's preparation, as JSON")


CLASSES = (PDEHeadLandmarkFlag, PDEHeadForensicSettings)


def forensic_settings(collection):
    """The forensic PropertyGroup of a study collection."""
    return getattr(collection, PROP)


def set_flags(items, flags: dict) -> None:
    """Fill a collection of :class:`PDEHeadLandmarkFlag` from ``{name: flag}`` or ``{name: (flag, evidence)}``."""
    items.clear()
    for name, value in flags.items():
        item = items.add()
        item.name = str(name)
        flag, evidence = (value, "") if isinstance(value, str) else (value[0], value[1] if len(value) > 1 else "")
        item.flag, item.evidence = str(flag), str(evidence)


def face_options_of(p) -> dict:
    """What the face was built from, as a dict (empty: no face built)."""
    if not p.face_build:
        return {}
    return dict(build=p.face_build, table=p.face_table, sex=p.face_sex or None,
                options=json.loads(p.face_options or "{}"), flags={f.name: f.flag for f in p.face_flags},
                landmarks=json.loads(p.face_landmarks or "{}"), pegs=[g.name for g in p.face_pegs])


def store_face_options(p, opts: dict) -> None:
    """Record what the face was built from (the dict :func:`face_options_of` gives back)."""
    p.face_build = str(opts["build"])
    p.face_table = str(opts["table"])
    p.face_sex = str(opts.get("sex") or "")
    p.face_options = json.dumps(opts.get("options") or {})
    set_flags(p.face_flags, opts.get("flags") or {})
    p.face_landmarks = json.dumps(opts.get("landmarks") or {})
    set_flags(p.face_pegs, {name: "" for name in opts.get("pegs") or []})


def migrate(collection) -> bool:
    """Read a study's forensic state of format 0 (custom properties) into its PropertyGroup; returns whether
    anything was read. Each custom property is removed only after its value is in the group."""
    p = forensic_settings(collection)
    if p.format_version >= FORMAT_VERSION:
        return False
    found = False
    text = collection.get(LEGACY_DEPTH_TABLE)
    if text:
        p.depth_table = str(text)
        p.depth_table_name = DepthTable.from_json(str(text)).label
        found = True
    text = collection.get(LEGACY_LANDMARK_FLAGS)
    if text:
        set_flags(p.landmark_flags, json.loads(str(text)))
        found = True
    text = collection.get(LEGACY_FACE_OPTIONS)
    if text:
        store_face_options(p, json.loads(str(text)))
        found = True
    p.format_version = FORMAT_VERSION
    for key in (LEGACY_DEPTH_TABLE, LEGACY_LANDMARK_FLAGS, LEGACY_FACE_OPTIONS):
        collection.pop(key, None)
    return found


def migrate_all() -> list[str]:
    """:func:`migrate` every study of the file; returns the names of those that had state of format 0."""
    return [c.name for c in state.studies() if migrate(c)]


@bpy.app.handlers.persistent
def pdehead_forensic_load_post(*_args) -> None:
    """After a file is loaded: every study's forensic state in the current format."""
    try:
        migrate_all()
    except Exception:  # noqa: BLE001 - a load handler must never stop the load
        traceback.print_exc()


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    setattr(bpy.types.Collection, PROP, bpy.props.PointerProperty(type=PDEHeadForensicSettings))
    bpy.app.handlers.load_post.append(pdehead_forensic_load_post)


def unregister() -> None:
    for handler in list(bpy.app.handlers.load_post):
        if getattr(handler, "__name__", "") == pdehead_forensic_load_post.__name__:
            bpy.app.handlers.load_post.remove(handler)
    if hasattr(bpy.types.Collection, PROP):
        delattr(bpy.types.Collection, PROP)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
