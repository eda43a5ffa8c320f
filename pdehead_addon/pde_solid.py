"""Step 5: the PDE solid (paper eq. 23), its w-field on a voxel grid and eq. 24 opacity."""
from __future__ import annotations


def alpha_from_w(w, low: float = 0.1, high: float = 0.9):
    raise NotImplementedError("being written")
