"""The files of a CT source and their format: a folder (recursively), a single file or a list, DICOMDIR
file-sets expanded to the files they index, numbered stacks, and the format detected (DICOM by its preamble
or a leading group 0002/0008 tag, images and NIfTI by extension).
"""
from __future__ import annotations

import os
import re
import warnings
from pathlib import Path
from typing import Iterable

from ...core.errors import CTImportError

__all__ = ["IMAGE_EXTENSIONS", "NIFTI_EXTENSIONS", "TEXT_EXTENSIONS", "import_pydicom", "source_label",
           "gather_files", "expand_dicomdir", "top_level", "has_ext", "numbered_files", "looks_like_dicom",
           "detect_format"]

IMAGE_EXTENSIONS = (".tif", ".tiff", ".png", ".jpg", ".jpeg", ".bmp", ".gif", ".pgm", ".ppm")
NIFTI_EXTENSIONS = (".nii", ".nii.gz")
# Companion files that sit next to slices and are skipped (with a warning) instead of failing a stack.
TEXT_EXTENSIONS = (".txt", ".md", ".json", ".xml", ".csv", ".ini", ".html", ".htm", ".pdf", ".log", ".cfg")


def import_pydicom():
    try:
        import pydicom  # deferred: pydicom adds ~0.12 s to `import pdehead_addon`
    except ImportError as exc:  # pragma: no cover - pydicom is a hard dependency
        raise CTImportError(f"reading DICOM needs the 'pydicom' package ({exc})") from None
    return pydicom



def source_label(path) -> str:
    if isinstance(path, (str, os.PathLike)):
        return os.fspath(path)
    try:
        items = list(path)
    except TypeError:
        return repr(path)
    return f"{os.fspath(items[0])} (+{len(items) - 1} more files)" if items else "(empty file list)"


def gather_files(path) -> tuple[list[Path], str]:
    """All regular files of a folder (recursively, sorted), a single file, or a list of files."""
    if isinstance(path, (str, os.PathLike)):
        p = Path(path)
        label = os.fspath(path)
        if not p.exists():
            raise CTImportError("no such file or folder", label)
        if p.is_file():
            return [p], label
        files = []
        for root, dirs, names in os.walk(p):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            files.extend(Path(root) / n for n in sorted(names) if not n.startswith("."))
        files = [f for f in files if f.is_file()]
        if not files:
            raise CTImportError("the folder is empty (no files in it or its subfolders)", label)
        return files, label
    try:
        items = [Path(f) for f in path]
    except TypeError:
        raise CTImportError(f"expected a folder, a file or a list of files, got {type(path).__name__}") from None
    label = source_label(items)
    if not items:
        raise CTImportError("the list of files is empty")
    for f in items:
        if not f.is_file():
            raise CTImportError("no such file" if not f.exists() else "not a regular file", f)
    return items, label


def _is_dicomdir(f: Path) -> bool:
    return f.name.upper() == "DICOMDIR" and looks_like_dicom(f)


def expand_dicomdir(files: list[Path], label: str, warns: list[str]) -> list[Path]:
    """Add the image files a DICOMDIR (a DICOM file-set's index) refers to.

    A DICOMDIR names its files by ReferencedFileID (path components relative to
    the DICOMDIR's folder, often upper-case without extension, e.g.
    ``DICOM/ST000000/SE000001/IM000003``). Given the DICOMDIR itself, or a folder
    holding one, the referenced files are loaded like any other files of the
    folder; referenced files that are missing are reported in a warning.
    """
    dirs = [f for f in files if _is_dicomdir(f)]
    if not dirs:
        return files
    pydicom = import_pydicom()
    out = list(files)
    seen = {os.path.normcase(os.path.abspath(f)) for f in files}
    for d in dirs:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                index = pydicom.dcmread(d, force=True)
            records = index.get("DirectoryRecordSequence") or []
        except Exception as exc:
            warns.append(f"cannot read DICOMDIR {d} ({type(exc).__name__}: {exc}); its folder is searched instead")
            continue
        missing, outside = [], []
        root = os.path.realpath(d.parent)
        for rec in records:
            try:
                ref = rec.get("ReferencedFileID")
            except Exception:  # noqa: BLE001 - a damaged record: its file is not loaded
                continue
            if ref is None:
                continue
            parts = [str(p) for p in ref] if not isinstance(ref, str) else str(ref).split("\\")
            target = d.parent.joinpath(*parts)
            # a file-set's files lie in its own folder (PS3.10 8.5): never open a file outside it
            if os.path.isabs(os.path.join(*parts)) or os.path.commonpath(
                    [root, os.path.realpath(target)]) != root:
                outside.append("/".join(parts))
                continue
            if not target.is_file():
                # file systems that lost the upper case of ISO 9660 names
                alt = d.parent.joinpath(*(p.lower() for p in parts))
                target = alt if alt.is_file() else target
            if not target.is_file():
                missing.append("/".join(parts))
                continue
            key = os.path.normcase(os.path.abspath(target))
            if key not in seen:
                seen.add(key)
                out.append(target)
        if outside:
            warns.append(f"DICOMDIR {d} refers to {len(outside)} file(s) outside its folder, not opened: "
                         + ", ".join(outside[:3]) + (", ..." if len(outside) > 3 else ""))
        if missing:
            warns.append(f"DICOMDIR {d} refers to {len(missing)} missing file(s): " + ", ".join(missing[:3])
                         + (", ..." if len(missing) > 3 else ""))
    return out


def top_level(files: list[Path], label: str) -> list[Path]:
    """Files directly in the folder (image and raw stacks are not searched recursively)."""
    root = Path(label)
    if root.is_dir():
        return [f for f in files if f.parent == root]
    return files


def has_ext(f: Path, exts: Iterable[str]) -> bool:
    name = f.name.lower()
    return any(name.endswith(e) for e in exts)


_DIGITS = re.compile(r"\d+")


def _numbered_key(f: Path) -> tuple:
    """Sort key ordering ``x2 < x10 < x100`` by the last number in the file name."""
    name = f.name
    runs = list(_DIGITS.finditer(name))
    if not runs:
        return (name, -1, name)
    last = runs[-1]
    template = name[:last.start()] + "#" + name[last.end():]
    return (template, int(last.group()), name)


def numbered_files(files: list[Path], label: str, what: str, warns: list[str]) -> list[Path]:
    ordered = sorted(files, key=_numbered_key)
    templates = {_numbered_key(f)[0] for f in ordered}
    if len(templates) > 1:
        warns.append(f"{what} file names follow {len(templates)} different patterns "
                     f"({', '.join(sorted(templates)[:3])}...); sorted by pattern, then number")
    return ordered


def looks_like_dicom(f: Path) -> bool:
    """'DICM' at byte 128, or a preamble-less file starting with a group 0002/0008 tag."""
    try:
        with open(f, "rb") as fh:
            head = fh.read(132)
    except OSError:
        return False
    if len(head) >= 132 and head[128:132] == b"DICM":
        return True
    return len(head) >= 8 and head[:2] in (b"\x02\x00", b"\x08\x00")


def detect_format(files: list[Path], label: str, shape) -> str:
    if shape is not None:
        return "raw"
    if len(files) == 1 and has_ext(files[0], NIFTI_EXTENSIONS):
        return "nifti"
    if any(looks_like_dicom(f) for f in files if not has_ext(f, IMAGE_EXTENSIONS + NIFTI_EXTENSIONS)):
        return "dicom"
    top = top_level(files, label)
    if any(has_ext(f, IMAGE_EXTENSIONS) for f in top):
        return "image"
    if any(has_ext(f, NIFTI_EXTENSIONS) for f in top):
        raise CTImportError("found NIfTI files; pass one .nii/.nii.gz file, not the folder", label)
    if any(has_ext(f, IMAGE_EXTENSIONS) for f in files):
        raise CTImportError("no slices directly in this folder (images found only in subfolders); "
                            "choose the folder that holds the numbered images", label)
    raise CTImportError(
        "no DICOM, image (TIFF/PNG/...) or NIfTI files found; for headerless raw slices pass "
        "format='raw', shape=(ny, nx) and a dtype such as dtype='>i2'", label)
