"""What keeps a study whole across save and reopen: file handlers for CT sources and .vdb volumes.

- **save_pre** (Blender passes the path being written): the solids' CT atlas images changed by
  live cutaways are packed; every study's CT source is recorded
  relative to that .blend (``//...``, so a project folder moved as a whole still finds its CT)
  and as an absolute path (used when only the .blend moved); every PDE Head volume whose .vdb
  is not yet that .blend's own (built before the first save, in the temp or preference folder,
  or a Save As, to another folder or the same one) is linked or copied into its ``pdehead_vdb/``
  folder under the .blend's name (``<blend>.<study>.vdb``) and the object switched to the copy,
  before Blender writes the file: the original .blend keeps its files untouched.
- **save_post**: .vdb files replaced by a rebuild or left behind by a move are deleted once the
  saved file no longer references them (:func:`vdb_files.purge_superseded`), and only the saved
  file's own (:func:`vdb_files.is_owned`): a file another .blend may use is never touched.
- **save_post** also removes the .vdb files PDE Head wrote for this file (recorded in the file at each
  save, ``Scene.pdehead.vdb_files``) that no saved Volume datablock references any more (a study
  deleted in the outliner): only this file's own ``.vdb`` files in the ``pdehead_vdb/`` folder beside
  it, never anything else, whatever the record says (:func:`remove_orphan_volume_files`).
- **load_post**: a volume whose recorded .vdb is missing but whose file lies in ``pdehead_vdb/``
  beside the opened .blend (an absolute path written with relative paths off) is re-pointed there;
  a PDE Head volume whose path is no ``.vdb`` in that folder is cleared with one report naming the study
  (a path stored in a .blend is data: PDE Head never reads, copies or deletes a file outside it).

The CT itself is never stored in the .blend; :attr:`.entity.Study.ct` re-reads it from these
recorded paths when a step needs it. What the solid shows of it is: save_pre stores the solid's CT
table (the CT tabulated in the solid's (u, v, w), 8-bit over the display window, zlib; at most
4.2 MB before compression, budget 16 MB) in the study collection, so after reopening -- or in a
file sent without its CT -- cutaways and nw are live at once (:meth:`.entity.Study.current_ct_table`).
"""
from __future__ import annotations

import json
import math
import os
import traceback
from pathlib import Path

import bpy

from .. import state
from ..scene import objects
from ..volume import vdb_files
from .entity import Study, parse_timings


def _volume_objects() -> list:
    return [o for o in bpy.data.objects if o.type == "VOLUME" and o.get("pdehead_kind") == "volume"]


def record_sources(blend_path: str) -> None:
    """Record each file-based study's CT source relative to `blend_path` and absolutely."""
    new_dir = Path(blend_path).resolve().parent
    for coll in state.studies():
        study = Study.of(coll)
        s = study.settings
        if s.source_kind != "FILES":
            continue
        path = study.resolve_source()
        if path is None:  # gone: keep what was recorded, the panel says it is missing
            continue
        path = path.resolve()
        try:
            relative = "//" + os.path.relpath(path, new_dir)
        except ValueError:  # another drive (Windows): only the absolute path can work
            relative = str(path)
        s.source_absolute = str(path)
        s.source = relative


def _report(obj, message: str) -> None:
    """One report for the study of the Volume object `obj` (its warnings and the console)."""
    print(f"PDE Head: {message}")
    for coll in state.studies():
        if obj.name in coll.all_objects:
            Study.of(coll).add_warnings([message])


def move_volumes_beside(blend_path: str) -> list[Path]:
    """Link or copy every PDE Head .vdb that is not yet `blend_path`'s own into its ``pdehead_vdb`` folder."""
    moved = []
    unsaved = not bpy.data.filepath
    for obj in _volume_objects():
        src = Path(bpy.path.abspath(obj.data.filepath)).resolve() if obj.data.filepath else None
        try:
            dst = vdb_files.relocate_vdb(obj, blend_path=blend_path)
        except (vdb_files.UnsafeVolumeFile, OSError) as exc:  # this study's volume only: the save goes on
            _report(obj, str(exc))
            continue
        if dst is not None:
            moved.append(dst)
            if unsaved and src is not None:
                vdb_files.supersede(src)  # a temp-folder file of an unsaved session: moved, not copied
    return moved


def _saved_volume_files() -> set[str]:
    """Absolute paths of the .vdb files of the Volume datablocks a save writes (orphans are not written)."""
    out = set()
    for vol in bpy.data.volumes:
        if vol.filepath and (vol.users > 0 or vol.use_fake_user):
            out.add(str(Path(bpy.path.abspath(vol.filepath)).resolve()))
    return out


#: At most this many recorded .vdb files are read from a .blend (a study has one at a time).
MAX_RECORDED_VDB_FILES = 4096


def _recorded_volume_files() -> set[str]:
    """The recorded .vdb files of the open file: only strings naming a ``.vdb`` (the record is data)."""
    out: set[str] = set()
    for scene in bpy.data.scenes:
        try:
            items = json.loads(scene.pdehead.vdb_files or "[]")
        except (ValueError, TypeError, RecursionError):
            continue
        if isinstance(items, list):
            out.update(str(Path(x).resolve()) for x in items[:MAX_RECORDED_VDB_FILES]
                       if isinstance(x, str) and x.endswith(".vdb") and "\0" not in x)
    return out


def _record_volume_files(paths) -> None:
    text = json.dumps(sorted(paths))
    for scene in bpy.data.scenes:
        if scene.pdehead.vdb_files != text:
            scene.pdehead.vdb_files = text


def record_volume_files() -> None:
    """Before a save: remember the .vdb files of this file's PDE Head volumes (with those already recorded)."""
    ours = {str(Path(bpy.path.abspath(o.data.filepath)).resolve()) for o in _volume_objects() if o.data.filepath}
    _record_volume_files(_recorded_volume_files() | ours)


def remove_orphan_volume_files() -> list[Path]:
    """After a save: delete the recorded .vdb files no saved Volume datablock references, when they are
    the saved file's own (:func:`vdb_files.is_owned`: its name, in the ``pdehead_vdb`` folder beside it);
    returns the removed files. Recorded files of another .blend (a Save As) are forgotten, not deleted."""
    if not bpy.data.filepath:
        return []
    recorded = _recorded_volume_files()
    used = _saved_volume_files()
    removed, kept = [], set()
    for text in sorted(recorded):
        path = Path(text)
        if text in used:
            kept.add(text)
            continue
        if not vdb_files.is_owned(path, bpy.data.filepath) or not path.is_file():
            continue  # not ours to touch (another folder, another .blend's file), or already gone
        try:
            path.unlink()
            removed.append(path)
            print(f"PDE Head: removed {path}: no volume of {Path(bpy.data.filepath).name} uses it any more")
        except OSError as exc:
            kept.add(text)
            print(f"PDE Head: could not remove the unused volume file {path}: {exc}")
    _record_volume_files(kept)
    return removed


@bpy.app.handlers.persistent
def pdehead_save_pre(filepath="", *_args) -> None:
    if not filepath:
        return
    try:
        Study.flush_colour_refresh()  # a solid still waiting for its CT colours gets them before the save
        objects.pack_ct_images()  # live cutaways update the CT atlases without re-packing each step
        for coll in state.studies():  # the solid's CT table (8-bit) travels in the file: live without the CT
            Study.of(coll).store_ct_table_for_save()
        record_sources(filepath)
        move_volumes_beside(filepath)
        record_volume_files()
    except Exception as exc:  # noqa: BLE001 - a handler must never stop the save
        traceback.print_exc()
        print(f"PDE Head: could not prepare the study files for saving: {exc}")


@bpy.app.handlers.persistent
def pdehead_save_post(*_args) -> None:
    try:
        vdb_files.purge_superseded()
        remove_orphan_volume_files()
    except Exception as exc:  # noqa: BLE001
        print(f"PDE Head: could not remove replaced volume files: {exc}")


@bpy.app.handlers.persistent
def pdehead_volume_load_post(*_args) -> None:
    if not bpy.data.filepath:
        return
    folder = vdb_files.vdb_folder_for(bpy.data.filepath)
    for obj in _volume_objects():
        data = obj.data
        if not data.filepath:
            continue
        path = bpy.path.abspath(data.filepath)
        inside = vdb_files.in_vdb_folder(path, bpy.data.filepath)
        if inside and os.path.isfile(path):
            continue
        beside = folder / Path(path).name
        if beside.suffix == ".vdb" and beside.is_file():  # an absolute path of the project's old place
            data.filepath = vdb_files.blender_filepath(beside)
            data.grids.unload()
            data.grids.load()
        elif not inside:
            _report(obj, f"volume '{obj.name}': its stored file path {data.filepath!r} is not a .vdb in "
                         f"'//{vdb_files.VDB_FOLDER_NAME}/'; it was cleared (rebuild the volume)")
            data.grids.unload()
            data.filepath = ""


def _clamped(prop, value):
    """`value` of the int/float property `prop` within its limits (NaN: its default), or None if it is."""
    lo, hi = prop.hard_min, prop.hard_max
    if isinstance(value, float) and math.isnan(value):
        return prop.default
    if value < lo:
        return lo
    if value > hi:
        return hi
    return None


def validate_study_settings(coll) -> list[str]:
    """Bring a study's stored settings within their properties' limits (Blender does not check the numbers
    a .blend holds: ``nu = 1e8`` would build a 9 GB mesh); returns what was changed, for the report."""
    settings = state.settings(coll)
    if settings is None:
        return []
    changed = []
    with state.suspended_updates():  # no live rebuild from the repairs
        for prop in settings.bl_rna.properties:
            if prop.type not in {"INT", "FLOAT"} or prop.is_readonly:
                continue
            name = prop.identifier
            value = getattr(settings, name)
            if getattr(prop, "array_length", 0):
                values = list(value)
                fixed = [_clamped(prop, v) for v in values]
                if any(f is not None for f in fixed):
                    setattr(settings, name, [v if f is None else f for v, f in zip(values, fixed)])
                    changed.append(f"{name} {values} -> {list(getattr(settings, name))}")
            else:
                fixed = _clamped(prop, value)
                if fixed is not None:
                    setattr(settings, name, fixed)
                    changed.append(f"{name} {value:g} -> {getattr(settings, name):g}")
        if settings.timings_json and not parse_timings(settings.timings_json) and settings.timings_json != "{}":
            settings.timings_json = ""
            changed.append("timings (not a table of seconds) cleared")
    return changed


@bpy.app.handlers.persistent
def pdehead_validate_load_post(*_args) -> None:
    """The opened file's stored study state is data: numbers outside their limits are clamped, an
    unreadable timings table cleared; one report per study (its warnings and the console)."""
    for coll in state.studies():
        try:
            changed = validate_study_settings(coll)
        except Exception as exc:  # noqa: BLE001 - one study's damage must not stop the file opening
            changed = [f"could not be checked ({exc})"]
        if changed:
            message = (f"study '{coll.name}': the file held values outside their limits; "
                       f"{'; '.join(changed)}")
            print(f"PDE Head: {message}")
            Study.of(coll).add_warnings([message])


_HANDLERS = (("save_pre", pdehead_save_pre), ("save_post", pdehead_save_post),
             ("load_post", pdehead_volume_load_post), ("load_post", pdehead_validate_load_post))


def _remove_handlers() -> list:
    """Drop our handlers (also copies left by a reload of the add-on); returns the handler lists."""
    lists = []
    for kind, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, kind)
        for h in list(handlers):
            if getattr(h, "__name__", "") == fn.__name__ and getattr(h, "__module__", "") == fn.__module__:
                handlers.remove(h)
        lists.append(handlers)
    return lists


def register() -> None:
    for handlers, (_, fn) in zip(_remove_handlers(), _HANDLERS):
        handlers.append(fn)


def unregister() -> None:
    _remove_handlers()
