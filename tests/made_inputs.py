"""Inputs the tests make that look like what users bring by mistake (not shipped in the add-on)."""
from __future__ import annotations

import numpy as np


def photo(rng, ny=240, nx=320, block=True):
    """A photo-like colour image: a sky-to-ground gradient, texture, and (optionally) a coloured block."""
    yy, xx = np.mgrid[:ny, :nx] / np.array([ny, nx])[:, None, None]
    sky = np.stack([90 + 80 * yy, 140 + 60 * yy, 230 - 120 * yy], axis=-1)
    ground = np.stack([60 + 40 * xx, 120 + 30 * xx, 40 + 20 * xx], axis=-1)
    img = np.where((yy > 0.55 + 0.1 * np.sin(6 * xx))[..., None], ground, sky)
    img = img + rng.normal(0, 12, img.shape)
    if block:
        y0, x0 = rng.integers(20, ny // 2), rng.integers(20, nx // 2)
        img[y0:y0 + 60, x0:x0 + 80] = (220, 40, 30)
    return np.clip(img, 0, 255).astype(np.uint8)


def portrait(rng, ny=240, nx=200):
    """A greyscale portrait-like image: a smooth bright oval (a face lit from the front, its brightness
    falling off smoothly towards the edge) with soft darker eyes and mouth, on a dark background with a
    little sensor noise. Each call differs (size, position, shading)."""
    yy, xx = np.mgrid[:ny, :nx].astype(np.float64)
    cy, cx = ny * rng.uniform(0.45, 0.55), nx * rng.uniform(0.45, 0.55)
    ry, rx = ny * rng.uniform(0.30, 0.38), nx * rng.uniform(0.28, 0.34)
    r = np.hypot((yy - cy) / ry, (xx - cx) / rx)
    face = 200.0 * np.exp(-r ** 4) + 30.0 * np.exp(-(r / 0.5) ** 2)
    for dy, dx, sy, sx, depth in ((-0.25, -0.35, 0.08, 0.12, 60), (-0.25, 0.35, 0.08, 0.12, 60),
                                  (0.45, 0.0, 0.07, 0.25, 50)):
        face -= depth * np.exp(-(((yy - cy) / ry - dy) / sy) ** 2 - (((xx - cx) / rx - dx) / sx) ** 2)
    img = face + 12.0 + rng.normal(0, 2.0, face.shape)
    return np.clip(img, 0, 255).astype(np.uint8)
