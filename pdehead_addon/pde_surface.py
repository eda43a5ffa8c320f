"""Step 4: the Bloor-Wilson PDE surface (paper eq. 1-13), t patches along u."""
from __future__ import annotations


def solve_pde(bset, smoothing=None, modes=None):
    raise NotImplementedError("being written")
