"""Step 2: head segmentation with the 3D Chan-Vese soft model (paper eq. 16-21) and clean-up."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .ct_volume import CTVolume


@dataclass
class Segmentation:
    """Result of :func:`segment_head`.

    Attributes
    ----------
    mask : ndarray of bool, shape (nz, ny, nx)
        The cleaned head mask.
    probability : ndarray of float32, shape (nz, ny, nx)
        The soft membership p of eq. 16 before clean-up.
    c1, c2 : float
        Mean windowed intensity inside (head) and outside (air), eq. 17.
    iterations : int
        Outer iterations run.
    ct : CTVolume
        The volume segmented (for its geometry and intensities); not copied.
    meta : dict
        Parameters used and clean-up statistics.
    """

    mask: np.ndarray
    probability: np.ndarray
    c1: float
    c2: float
    iterations: int
    ct: CTVolume
    meta: dict[str, Any] = field(default_factory=dict)


def segment_head(ct: CTVolume, **params) -> Segmentation:
    raise NotImplementedError("being written")
