"""Step 3: per-slice boundary curves (paper eq. 22) and the choice of 3t+1 of them."""
from __future__ import annotations

from .boundary_set import BoundarySet


def extract_boundaries(seg, patches: int = 10, samples: int = 256, selection="uniform") -> BoundarySet:
    raise NotImplementedError("being written")
