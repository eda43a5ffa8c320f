"""The .vdb files of the volumes: where they go, their names, which .blend owns them, moving them beside
a saved .blend and removing the ones a rebuild replaced.

.vdb files cannot be packed into a .blend, so a study's file lives in ``pdehead_vdb`` beside the
saved file, or, for an unsaved file, in the preference folder or the system temp folder. A file beside
a saved .blend carries that .blend's name: ``//pdehead_vdb/<blend>.<study>.vdb`` (:func:`owner_token`),
and a .blend only ever deletes files carrying its own name, so a Save As (which links or copies the
files to the new name, :func:`relocate_vdb`) or another .blend in the same folder never loses its
volume. A rebuild writes a new file and never overwrites one (:func:`fresh_vdb_path`); the replaced
file is deleted after the next save that no longer references it (:func:`purge_superseded`).
"""
from __future__ import annotations

import filecmp
import hashlib
import os
import tempfile
from pathlib import Path

import bpy

from ...pdehead_addon import copy_checked
from .. import state

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


def _safe_name(text: str, fallback: str) -> str:
    """`text` as a file-name part without dots or separators; a changed name gets a short hash of the
    original, so that "CT head" and "CT_head" never share (and overwrite) one file."""

    safe = bpy.path.clean_name(text) or fallback  # every character but [A-Za-z0-9_-] becomes "_"
    if safe != text:
        safe += "-" + hashlib.sha1(text.encode("utf-8")).hexdigest()[:6]
    return safe


def owner_token(blend_path) -> str:
    """The first part of the names of the .vdb files a saved .blend owns: its file name without
    ``.blend``, made safe (no dots: the owner is everything before the first dot)."""
    return _safe_name(Path(os.fspath(blend_path)).stem, "untitled")


def vdb_path_for(study: str, blend_path=None, prefs_folder=None) -> Path:
    """Absolute path of the .vdb of `study` (see :func:`vdb_folder_for`), file name made safe.

    Beside a saved .blend the name starts with the .blend's :func:`owner_token`
    (``<blend>.<study>.vdb``): the files of two .blend files in one folder never mix.
    """
    safe = _safe_name(study, "study")
    if blend_path:
        return vdb_folder_for(blend_path) / f"{owner_token(blend_path)}.{safe}.vdb"
    return vdb_folder_for(None, prefs_folder) / f"{safe}.vdb"


def is_owned(path, blend_path) -> bool:
    """Whether the .vdb `path` belongs to the saved .blend `blend_path`: a ``.vdb`` in its
    ``pdehead_vdb`` folder whose name starts with its :func:`owner_token` (only such files are ever
    deleted on its behalf)."""
    if not blend_path:
        return False
    path = Path(os.fspath(path))
    return (path.suffix == ".vdb" and path.parent.resolve() == vdb_folder_for(blend_path)
            and path.name.startswith(owner_token(blend_path) + "."))


def in_vdb_folder(path, blend_path) -> bool:
    """Whether `path` is a ``.vdb`` file name directly inside the ``pdehead_vdb`` folder of `blend_path`."""
    if not blend_path:
        return False
    path = Path(os.fspath(path))
    return path.suffix == ".vdb" and path.resolve().parent == vdb_folder_for(blend_path)


#: The first 8 bytes of every OpenVDB file: the magic number 0x56444220 as a little-endian int64.
VDB_MAGIC = (0x56444220).to_bytes(8, "little")


def looks_like_vdb(path) -> bool:
    """Whether `path` is a regular file that starts like an OpenVDB file."""
    try:
        with open(os.fspath(path), "rb") as f:
            return Path(os.fspath(path)).is_file() and f.read(8) == VDB_MAGIC
    except OSError:
        return False


def blender_filepath(path: str | os.PathLike) -> str:
    """Path as Blender should store it: ``//...`` relative to the saved .blend when inside its folder."""
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


def mark_written(path) -> None:
    """Record a .vdb file written in this session (``state.REGISTRY.vdb_written``: :func:`purge_superseded` may
    delete it once replaced)."""
    state.REGISTRY.vdb_written.add(str(Path(os.fspath(path)).resolve()))


def supersede(path) -> None:
    """Mark a replaced .vdb for removal after the next save (``state.REGISTRY.vdb_superseded``, see
    :func:`purge_superseded`): deleting it at once would break undo back to the old file."""
    if path:
        state.REGISTRY.vdb_superseded.add(str(Path(os.fspath(path)).resolve()))


def referenced_vdb_files() -> set[str]:
    """Absolute paths of the .vdb files the Volume datablocks of the open file point at."""
    out = set()
    for vol in bpy.data.volumes:
        if vol.filepath:
            out.add(str(Path(bpy.path.abspath(vol.filepath)).resolve()))
    return out


def purge_superseded() -> list[Path]:
    """Delete the superseded .vdb files no Volume datablock references any more; returns them.

    Only the saved file's own files are ever deleted (:func:`is_owned`), or, outside a ``pdehead_vdb``
    folder, those written by :func:`.vdb_grids.write_vdb` in this session (the preference folder of unsaved
    files).
    """
    used = referenced_vdb_files()
    removed = []
    for text in sorted(state.REGISTRY.vdb_superseded):
        path = Path(text)
        if text in used:
            continue
        state.REGISTRY.vdb_superseded.discard(text)
        # beside a saved file: only the saved file's own (another .blend may use the rest); elsewhere
        # (the temp or preference folder of an unsaved session): only what this session wrote
        ours = is_owned(path, bpy.data.filepath) or (text in state.REGISTRY.vdb_written
                                                     and path.parent.name != VDB_FOLDER_NAME)
        if ours and path.suffix == ".vdb" and path.is_file():
            try:
                path.unlink()
                removed.append(path)
            except OSError as exc:  # read-only folder: keep the file, say so
                print(f"PDE Head: could not remove the replaced volume file {path}: {exc}")
    return removed


class UnsafeVolumeFile(ValueError):
    """A Volume's stored file path that PDE Head refuses to read, copy or delete (not a .vdb of its own)."""


def may_copy(src, blend_path=None) -> bool:
    """Whether PDE Head may copy the .vdb `src` for a save: a file in the ``pdehead_vdb`` folder of the
    open .blend (or of `blend_path`, the one being written), or one this session wrote; always a ``.vdb``
    that starts like an OpenVDB file (a path stored in a .blend is data: never ``/etc/passwd``)."""
    src = Path(os.fspath(src))
    inside = in_vdb_folder(src, bpy.data.filepath) or in_vdb_folder(src, blend_path)
    return src.suffix == ".vdb" and (inside or str(src.resolve()) in state.REGISTRY.vdb_written) and looks_like_vdb(src)


def link_or_copy(src, dst) -> None:
    """Put a copy of `src` at the new name `dst` without ever overwriting: a hard link where the file
    system has them (instant, no space; each name deleted alone), else a checked copy
    (:func:`.safe_io.copy_checked`)."""
    try:
        os.link(src, dst)
        return
    except FileExistsError:
        raise
    except OSError:
        pass
    copy_checked(src, dst)


def relocate_vdb(obj, folder=None, blend_path=None) -> Path | None:
    """Copy a Volume object's .vdb into `folder` and point the object at the copy.

    `folder` defaults to ``pdehead_vdb`` beside `blend_path` (default: the saved .blend), and the copy
    is then named for that .blend (:func:`owner_token`), so a volume built while the file was unsaved (in
    the preference or temp folder) follows the file once it is saved, and a Save As (even into the same
    folder) gives the new file its own copy (a hard link where possible): the original's file is never
    moved nor deleted. The path is then stored relative (``//...``). A different file already at the
    destination is never overwritten (the copy gets a free name). Returns the new path, or None when there
    is nothing to do (no file, no saved .blend, or already there).

    Raises :class:`UnsafeVolumeFile` for a stored path that is not a .vdb of this file's ``pdehead_vdb``
    folder nor one written in this session (:func:`may_copy`).

    ``blend_path`` lets the save_pre handler move files beside the file being written before
    Blender writes it; the stored path is then relative to the *current* .blend, which
    Blender's relative-path remapping turns into ``//pdehead_vdb/...`` of the new one.
    """

    if obj is None or obj.type != "VOLUME" or not obj.data.filepath:
        return None
    blend_path = blend_path or bpy.data.filepath
    owner = None
    if folder is None:
        if not blend_path:
            return None
        folder, owner = vdb_folder_for(blend_path), blend_path
    folder = Path(os.fspath(folder)).resolve()
    src = Path(bpy.path.abspath(obj.data.filepath)).resolve()
    if src.parent == folder and (owner is None or is_owned(src, owner)):
        if bpy.data.filepath and not obj.data.filepath.startswith("//"):
            obj.data.filepath = blender_filepath(src)
        return None
    if not src.is_file():
        return None
    if not may_copy(src, blend_path):
        raise UnsafeVolumeFile(f"volume '{obj.name}': its file {src} is not a .vdb in the '{VDB_FOLDER_NAME}' "
                               "folder beside the .blend; it was not copied (rebuild the volume)")
    name = src.name
    if owner is not None:  # named for the .blend being written: "<blend>.<study>.vdb"
        rest = name.split(".", 1)[1] if name.count(".") >= 2 else name
        name = f"{owner_token(owner)}.{rest}"
    dst = folder / name
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists() and not filecmp.cmp(src, dst, shallow=False):
        dst = fresh_vdb_path(dst)
    if not dst.exists():
        link_or_copy(src, dst)
    obj.data.filepath = bpy.path.relpath(str(dst)) if bpy.data.filepath else str(dst)
    obj.data.grids.unload()
    obj.data.grids.load()
    return dst
