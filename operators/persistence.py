"""What keeps a study whole across save and reopen: file handlers for CT sources and .vdb volumes.

- **save_pre** (Blender passes the path being written): the solids' CT atlas images changed by
  live cutaways are packed; every study's CT source is recorded
  relative to that .blend (``//...``, so a project folder moved as a whole still finds its CT)
  and as an absolute path (used when only the .blend moved); every PDE Head volume whose .vdb
  is not yet beside that .blend (built before the first save, in the temp or preference folder,
  or a Save As to another folder) is copied into its ``pdehead_vdb/`` folder and the object
  switched to the copy, before Blender writes the file.
- **save_post**: .vdb files replaced by a rebuild or left behind by a move are deleted once the
  saved file no longer references them (:func:`vdb_files.purge_superseded`); a file that an older
  .blend beside it still uses is never touched (it is not in the superseded set).
- **save_post** also removes the .vdb files PDE Head wrote for this file (recorded in the file at each
  save, ``Scene.pdehead.vdb_files``) that no saved Volume datablock references any more (a study
  deleted in the outliner): only ``.vdb`` files in the ``pdehead_vdb/`` folder beside the saved file,
  never anything else (:func:`remove_orphan_volume_files`).
- **load_post**: a volume whose recorded .vdb is missing but whose file lies in ``pdehead_vdb/``
  beside the opened .blend (an absolute path written with relative paths off) is re-pointed there.

The CT itself is never stored in the .blend; :attr:`.study_entity.Study.ct` re-reads it from these
recorded paths when a step needs it. What the solid shows of it is: save_pre stores the solid's CT
table (the CT tabulated in the solid's (u, v, w), 8-bit over the display window, zlib; at most
4.2 MB before compression, budget 16 MB) in the study collection, so after reopening -- or in a
file sent without its CT -- cutaways and nw are live at once (:meth:`.study_entity.Study.current_ct_table`).
"""
from __future__ import annotations

import os
from pathlib import Path

import bpy

from . import state, vdb_files
from .study_entity import Study


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


def move_volumes_beside(blend_path: str) -> list[Path]:
    """Copy every PDE Head .vdb that is not beside `blend_path` into its ``pdehead_vdb`` folder."""
    moved = []
    unsaved = not bpy.data.filepath
    for obj in _volume_objects():
        src = Path(bpy.path.abspath(obj.data.filepath)).resolve() if obj.data.filepath else None
        dst = vdb_files.relocate_vdb(obj, blend_path=blend_path)
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


def _recorded_volume_files() -> set[str]:
    import json
    out: set[str] = set()
    for scene in bpy.data.scenes:
        try:
            out.update(json.loads(scene.pdehead.vdb_files or "[]"))
        except (ValueError, TypeError):
            continue
    return out


def _record_volume_files(paths) -> None:
    import json
    text = json.dumps(sorted(paths))
    for scene in bpy.data.scenes:
        if scene.pdehead.vdb_files != text:
            scene.pdehead.vdb_files = text


def record_volume_files() -> None:
    """Before a save: remember the .vdb files of this file's PDE Head volumes (with those already recorded)."""
    ours = {str(Path(bpy.path.abspath(o.data.filepath)).resolve()) for o in _volume_objects() if o.data.filepath}
    _record_volume_files(_recorded_volume_files() | ours)


def remove_orphan_volume_files() -> list[Path]:
    """After a save: delete the recorded .vdb files no saved Volume datablock references, when they lie
    in the ``pdehead_vdb`` folder beside the saved file; returns the removed files."""
    if not bpy.data.filepath:
        return []
    folder = vdb_files.vdb_folder_for(bpy.data.filepath).resolve()
    recorded = _recorded_volume_files()
    used = _saved_volume_files()
    removed, kept = [], set()
    for text in sorted(recorded):
        path = Path(text)
        if text in used:
            kept.add(text)
            continue
        if path.suffix != ".vdb" or path.parent != folder or not path.is_file():
            continue  # not ours to touch (another folder), or already gone
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
        from . import objects
        Study.flush_colour_refresh()  # a solid still waiting for its CT colours gets them before the save
        objects.pack_ct_images()  # live cutaways update the CT atlases without re-packing each step
        for coll in state.studies():  # the solid's CT table (8-bit) travels in the file: live without the CT
            Study.of(coll).store_ct_table_for_save()
        record_sources(filepath)
        move_volumes_beside(filepath)
        record_volume_files()
    except Exception as exc:  # noqa: BLE001 - a handler must never stop the save
        import traceback
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
        if not data.filepath or os.path.isfile(bpy.path.abspath(data.filepath)):
            continue
        beside = folder / Path(bpy.path.abspath(data.filepath)).name
        if beside.is_file():
            data.filepath = vdb_files.blender_filepath(beside)
            data.grids.unload()
            data.grids.load()


_HANDLERS = (("save_pre", pdehead_save_pre), ("save_post", pdehead_save_post),
             ("load_post", pdehead_volume_load_post))


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
