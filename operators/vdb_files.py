"""The .vdb files of the volumes: where they go, their names, moving them beside a saved .blend and
removing the ones a rebuild replaced.

.vdb files cannot be packed into a .blend, so a study's file lives in ``pdehead_vdb`` beside the
saved file (``//pdehead_vdb/<study>.vdb``), or, for an unsaved file, in the preference folder or
the system temp folder. A rebuild writes a new file and never overwrites one (:func:`fresh_vdb_path`);
the replaced file is deleted after the next save that no longer references it (:func:`purge_superseded`).
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

VDB_FOLDER_NAME = "pdehead_vdb"


def vdb_folder_for(blend_path: str | os.PathLike | None, prefs_folder: str | os.PathLike | None = None) -> Path:
    """Folder for a study's .vdb files.

    Beside the saved .blend (``<blend folder>/pdehead_vdb``) when the file is
    saved; otherwise the add-on preference folder, or a ``pdehead_vdb`` folder
    in the system temp directory when that preference is empty.
    """
    if blend_path:
        return Path(os.fspath(blend_path)).resolve().parent / VDB_FOLDER_NAME
    if prefs_folder:
        folder = os.fspath(prefs_folder)
        if folder.startswith("//"):
            raise ValueError("the VDB preference folder must be absolute for unsaved files")
        return Path(folder).expanduser().resolve()
    return Path(tempfile.gettempdir()) / VDB_FOLDER_NAME


def vdb_path_for(study: str, blend_path=None, prefs_folder=None) -> Path:
    """Absolute path of the .vdb of `study` (see :func:`vdb_folder_for`), file name made safe.

    A name changed by the cleaning gets a short hash of the original, so that
    "CT head" and "CT_head" never share (and overwrite) one file.
    """
    import hashlib

    import bpy

    safe = bpy.path.clean_name(study) or "study"
    if safe != study:
        safe += "-" + hashlib.sha1(study.encode("utf-8")).hexdigest()[:6]
    return vdb_folder_for(blend_path, prefs_folder) / f"{safe}.vdb"


def blender_filepath(path: str | os.PathLike) -> str:
    """Path as Blender should store it: ``//...`` relative to the saved .blend when inside its folder."""
    import bpy

    path = Path(os.fspath(path)).resolve()
    if bpy.data.filepath:
        blend_dir = Path(bpy.data.filepath).resolve().parent
        try:
            path.relative_to(blend_dir)
        except ValueError:
            return str(path)
        return bpy.path.relpath(str(path), start=str(blend_dir))
    return str(path)


def fresh_vdb_path(path) -> Path:
    """`path` if no file is there, else the first free ``<stem>-<n>.vdb`` beside it.

    A rebuilt volume is always written to a new file and the object switched to it, so an
    existing (maybe better) file is never overwritten; the old file is removed only when a
    save no longer references it (:func:`purge_superseded`).
    """
    path = Path(os.fspath(path))
    if not path.exists():
        return path
    n = 2
    while True:
        candidate = path.with_name(f"{path.stem}-{n}{path.suffix}")
        if not candidate.exists():
            return candidate
        n += 1


#: Absolute paths of .vdb files that a rebuild or a move replaced; deleted after the next save
#: that no longer references them (deleting at once would break undo back to the old file).
_SUPERSEDED: set[str] = set()


#: Absolute paths of the .vdb files written in this session.
_WRITTEN: set[str] = set()


def mark_written(path) -> None:
    """Record a .vdb file written in this session (:func:`purge_superseded` may delete it once replaced)."""
    _WRITTEN.add(str(Path(os.fspath(path)).resolve()))


def supersede(path) -> None:
    """Mark a replaced .vdb for removal after the next save (see :func:`purge_superseded`)."""
    if path:
        _SUPERSEDED.add(str(Path(os.fspath(path)).resolve()))


def referenced_vdb_files() -> set[str]:
    """Absolute paths of the .vdb files the Volume datablocks of the open file point at."""
    import bpy

    out = set()
    for vol in bpy.data.volumes:
        if vol.filepath:
            out.add(str(Path(bpy.path.abspath(vol.filepath)).resolve()))
    return out


def purge_superseded() -> list[Path]:
    """Delete the superseded .vdb files no Volume datablock references any more; returns them.

    Only the add-on's own files are ever deleted: those in a ``pdehead_vdb`` folder or written
    by :func:`.vdb_grids.write_vdb` in this session (the preference folder of unsaved files).
    """
    used = referenced_vdb_files()
    removed = []
    for text in sorted(_SUPERSEDED):
        path = Path(text)
        if text in used:
            continue
        _SUPERSEDED.discard(text)
        ours = path.parent.name == VDB_FOLDER_NAME or text in _WRITTEN
        if ours and path.suffix == ".vdb" and path.is_file():
            try:
                path.unlink()
                removed.append(path)
            except OSError as exc:  # read-only folder: keep the file, say so
                print(f"PDE Head: could not remove the replaced volume file {path}: {exc}")
    return removed


def relocate_vdb(obj, folder=None, blend_path=None) -> Path | None:
    """Copy a Volume object's .vdb into `folder` and point the object at the copy.

    `folder` defaults to ``pdehead_vdb`` beside `blend_path` (default: the saved .blend),
    so a volume built while the file was unsaved (in the preference or temp folder) follows
    the file once it is saved; the path is then stored relative (``//...``). A different file
    already at the destination is never overwritten (the copy gets a free name). Returns the
    new path, or None when there is nothing to do (no file, no saved .blend, or already there).

    ``blend_path`` lets the save_pre handler move files beside the file being written before
    Blender writes it; the stored path is then relative to the *current* .blend, which
    Blender's relative-path remapping turns into ``//pdehead_vdb/...`` of the new one.
    """
    import filecmp
    import shutil

    import bpy

    if obj is None or obj.type != "VOLUME" or not obj.data.filepath:
        return None
    blend_path = blend_path or bpy.data.filepath
    if folder is None:
        if not blend_path:
            return None
        folder = vdb_folder_for(blend_path)
    src = Path(bpy.path.abspath(obj.data.filepath)).resolve()
    dst = Path(os.fspath(folder)).resolve() / src.name
    if src.parent == dst.parent:
        if bpy.data.filepath and not obj.data.filepath.startswith("//"):
            obj.data.filepath = blender_filepath(dst)
        return None
    if not src.is_file():
        return None
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists() and not filecmp.cmp(src, dst, shallow=False):
        dst = fresh_vdb_path(dst)
    if not dst.exists():
        shutil.copy2(src, dst)
    obj.data.filepath = bpy.path.relpath(str(dst)) if bpy.data.filepath else str(dst)
    obj.data.grids.unload()
    obj.data.grids.load()
    return dst
