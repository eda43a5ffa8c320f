"""Reading Blender results back for the tests: mesh attributes, world vertices, rendered PNGs.

The add-on only writes these (operators/scene/objects.py, operators/scene/render.py); these readers are test tools.
"""
from __future__ import annotations

import os

import numpy as np


def mesh_attribute(obj, key: str) -> np.ndarray:
    """An attribute of a mesh object as a numpy array (float32, (n,) or (n, c))."""
    attr = obj.data.attributes[key]
    n = len(attr.data)
    width = {"FLOAT": 1, "INT": 1, "FLOAT2": 2, "FLOAT_VECTOR": 3, "FLOAT_COLOR": 4}[attr.data_type]
    field = {"FLOAT": "value", "INT": "value", "FLOAT2": "vector", "FLOAT_VECTOR": "vector",
             "FLOAT_COLOR": "color"}[attr.data_type]
    out = np.empty(n * width, np.float32 if attr.data_type != "INT" else np.int32)
    attr.data.foreach_get(field, out)
    return out.reshape(n, width) if width > 1 else out


def mesh_world_vertices(obj) -> np.ndarray:
    """World coordinates (metres) of a mesh object's vertices, (n, 3) float64."""
    me = obj.data
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    m = np.array(obj.matrix_world)
    return co.reshape(-1, 3).astype(np.float64) @ m[:3, :3].T + m[:3, 3]


def read_png(path) -> np.ndarray:
    """A PNG as float32 [rows, cols, channels] in [0, 1], row 0 at the top."""
    from PIL import Image

    with Image.open(os.fspath(path)) as im:
        mode = "RGBA" if im.mode in ("RGBA", "LA", "PA") or "transparency" in im.info else "RGB"
        return np.asarray(im.convert(mode), dtype=np.float32) / 255.0


def image_stats(path, threshold: float = 0.06) -> dict:
    """Foreground/background statistics of a rendered PNG.

    The foreground is where alpha > 0.02 (transparent renders), otherwise
    where any channel differs from the background colour (median of the
    one-pixel image border) by more than `threshold`.

    Returns
    -------
    dict with ``width``, ``height``, ``mean`` and ``std`` (all RGB values),
    ``background`` (RGB), ``foreground_fraction``, ``foreground_mean``,
    ``centroid`` (x, y) in [0, 1] of the foreground (x to the right, y down;
    None if empty), ``bbox`` (x0, y0, x1, y1) pixels or None, and ``mask``.
    """
    img = read_png(path)
    rgb = img[..., :3]
    if img.shape[2] == 4 and img[..., 3].min() < 0.99:
        mask = img[..., 3] > 0.02
        background = np.zeros(3, np.float32)
    else:
        border = np.concatenate([rgb[0], rgb[-1], rgb[:, 0], rgb[:, -1]])
        background = np.median(border, axis=0)
        mask = np.abs(rgb - background).max(axis=2) > threshold
    rows, cols = np.nonzero(mask)
    h, w = mask.shape
    return {
        "width": w,
        "height": h,
        "mean": float(rgb.mean()),
        "std": float(rgb.std()),
        "background": tuple(float(x) for x in background),
        "foreground_fraction": float(mask.mean()),
        "foreground_mean": float(rgb[mask].mean()) if mask.any() else 0.0,
        "centroid": (float((cols.mean() + 0.5) / w), float((rows.mean() + 0.5) / h)) if mask.any() else None,
        "bbox": (int(cols.min()), int(rows.min()), int(cols.max()), int(rows.max())) if mask.any() else None,
        "mask": mask,
    }
