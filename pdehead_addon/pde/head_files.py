"""A PDE head from a boundary file: the stored curves solved with the stored settings (paper section 5.2).

:mod:`pdehead_addon.io.storage` reads and writes the file format; solving belongs to this package, so
the file format needs no solver (``io`` imports nothing of ``pde``).
"""
from __future__ import annotations

import os

from ..core.boundary_set import BoundarySet
from ..core.errors import PDEError, StorageError
from ..io.storage import load_boundaries, loads_boundaries
from .pde_surface import solve_pde

__all__ = ["head_from_boundaries", "loads_head", "load_head"]


def head_from_boundaries(bset: BoundarySet, name: str = "<bytes>"):
    """Solve a loaded BoundarySet with its stored settings (defaults when none are stored)."""
    settings = bset.meta.get("pde_settings") or {}
    smoothing = None if settings.get("smoothing_is_default", True) else settings.get("smoothing")
    # files written before the C2 surface existed carry no continuity: they were the paper's patches
    continuity = settings.get("continuity", "paper")
    extra = {}
    if continuity == "c2":
        extra = dict(approximation_mm=settings.get("approximation_mm"), dome=bool(settings.get("dome", True)))
    try:
        return solve_pde(bset, smoothing=smoothing, modes=settings.get("modes"), continuity=continuity,
                         remainder=bool(settings.get("remainder", True)), **extra)
    except PDEError as exc:
        raise StorageError(f"{name}: stored settings cannot be solved ({exc})") from None


def loads_head(data: bytes, name: str = "<bytes>"):
    """Decode bytes and solve the PDE head with the stored settings."""
    return head_from_boundaries(loads_boundaries(data, name), name)


def load_head(path: str | os.PathLike):
    """Read a boundary file and return the solved :class:`PDEHead` (stored settings, else defaults)."""
    return head_from_boundaries(load_boundaries(path), os.fspath(path))
