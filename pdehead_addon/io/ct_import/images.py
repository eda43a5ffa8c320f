"""Numbered 2-D images (TIFF through tifffile, PNG/JPEG/BMP/... through Pillow), or one multi-page TIFF."""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ...core.ct_volume import CTVolume
from ...core.errors import CTImportError
from .. import scan_evidence
from .folder_files import IMAGE_EXTENSIONS, has_ext, numbered_files, top_level
from .geometry import headerless_volume
from .limits import check_budget, check_ratio


def _read_tiff(tifffile, f: Path) -> np.ndarray:
    """A TIFF's pixels, its declared size checked first against the file's bytes and the memory budget
    (no pixel buffer is allocated before); tifffile's own log lines are kept off the console."""
    log = logging.getLogger("tifffile")
    level, log.level = log.level, logging.CRITICAL
    try:
        with tifffile.TiffFile(f) as tif:
            page = tif.pages.first if hasattr(tif.pages, "first") else tif.pages[0]
            shape = tuple(int(n) for n in page.shape)
            count = len(tif.pages)
            itemsize = np.dtype(page.dtype).itemsize if page.dtype is not None else 1
            declared = int(np.prod(shape, dtype=np.float64)) * count * itemsize
            check_budget(declared // itemsize * 4, f"a TIFF of {count} page(s) of {' x '.join(map(str, shape))} "
                         "pixels", f)
            stored = f.stat().st_size
            if int(page.compression) == 1 and declared > stored:
                raise CTImportError(f"truncated or corrupt TIFF: its {count} page(s) of "
                                    f"{' x '.join(map(str, shape))} pixels need {declared} bytes, the file has "
                                    f"{stored}", f)
            check_ratio(declared, stored, "this TIFF", f)
            return tif.asarray()
    except CTImportError:
        raise
    except Exception as exc:
        detail = " ".join(str(exc).split())
        raise CTImportError(f"cannot read TIFF image: {type(exc).__name__}: {detail}", f) from None
    finally:
        log.level = level


def _read_image(f: Path) -> tuple[np.ndarray, float | None]:
    """One image as a greyscale numpy array (TIFF through tifffile, others through Pillow), and,
    when it was converted from colour, its mean colour saturation (max - min of R, G, B as a share
    of the value range; 0 for colour files holding grey pixels), else None."""
    arr = None
    if has_ext(f, (".tif", ".tiff")):
        try:
            import tifffile  # deferred: optional, may be missing (Pillow reads TIFF then)
        except ImportError:
            tifffile = None
        if tifffile is not None:
            arr = _read_tiff(tifffile, f)
    if arr is None:
        try:
            from PIL import Image  # deferred: optional, may be missing (an error names it)
        except ImportError:
            raise CTImportError("reading images needs Pillow (or tifffile for TIFF)", f) from None
        try:
            with Image.open(f) as im:
                frames = []
                for index in range(getattr(im, "n_frames", 1)):
                    im.seek(index)
                    frame = im
                    if frame.mode in ("P", "PA", "LA", "1"):
                        frame = frame.convert("L")
                    frames.append(np.asarray(frame))
                arr = frames[0] if len(frames) == 1 else np.stack(frames)
        except Exception as exc:
            raise CTImportError(f"cannot read image: {type(exc).__name__}: {exc}", f) from None
    arr = np.asarray(arr)
    if arr.ndim >= 3 and arr.shape[-1] in (3, 4):
        # colour (RGB/RGBA): luminance, ITU-R 601
        rgb = arr[..., :3]
        full = float(np.iinfo(rgb.dtype).max) if rgb.dtype.kind in "iu" else max(float(np.ptp(rgb)), 1e-6)
        chroma = float(np.mean(rgb[::2, ::2].max(axis=-1) - rgb[::2, ::2].min(axis=-1), dtype=np.float64)) / full
        return rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32), chroma
    return arr, None


def load_images(files, label, spacing, axes, oriented, hu, warns) -> CTVolume:
    top = top_level(files, label)
    images = [f for f in top if has_ext(f, IMAGE_EXTENSIONS)]
    others = [f for f in top if f not in images]
    if not images:
        raise CTImportError("no image files (TIFF/PNG/JPEG/BMP) found", label if len(files) != 1 else files[0])
    if others:
        warns.append(f"skipped {len(others)} non-image file(s): " + ", ".join(f.name for f in others[:5]))
    images = numbered_files(images, label, "image", warns)
    slices = []
    colour, chroma = False, []
    shapes: dict[tuple, Path] = {}
    sample_types: dict[str, Path] = {}
    for f in images:
        arr, saturation = _read_image(f)
        if saturation is not None:
            colour = True
            chroma.append(saturation)
        if arr.ndim == 2:
            slices.append(arr)
        elif arr.ndim == 3 and len(images) == 1:
            slices.extend(arr)                      # one multi-page file = the whole volume
        else:
            raise CTImportError(f"expected a 2-D greyscale image, got shape {arr.shape}", f)
        shapes.setdefault(arr.shape[-2:], f)
        sample_types.setdefault(str(arr.dtype), f)
    if len(shapes) > 1:
        example = "; ".join(f"{s[0]}x{s[1]} in {f.name}" for s, f in shapes.items())
        raise CTImportError(f"mixed image sizes ({example})", label)
    if len(sample_types) > 1:
        example = "; ".join(f"{t} in {f.name}" for t, f in sample_types.items())
        raise CTImportError(f"mixed sample types ({example}): the slices' values would not be comparable", label)
    _refuse_photos(slices, float(np.mean(chroma)) if chroma else 0.0, len(images), label)
    if colour:
        warns.append("colour images converted to grey (luminance)")
    data = np.empty((len(slices),) + slices[0].shape, dtype=np.float32)
    for k, s in enumerate(slices):
        data[k] = s
    del slices
    return headerless_volume(data, label, "image", spacing, axes, oriented, hu, warns,
                              {"files": len(images), "first_file": images[0].name, "last_file": images[-1].name})


def _refuse_photos(slices, chroma: float, files: int, label) -> None:
    """Refuse a stack of ordinary pictures before anything is built from it (``scan_evidence.photo_evidence``)."""
    step = max(1, len(slices) // 12)
    seen = scan_evidence.photo_evidence(slices[::step], chroma)
    if seen:
        ny, nx = slices[0].shape[-2:]
        raise CTImportError(f"does not look like a head CT: {'; '.join(seen)}; {files} image(s) of {nx} x {ny} "
                            "pixels", label)
