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
