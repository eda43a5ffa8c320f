"""A deterministic synthetic head CT with exact ground truth (demo and quick tests)."""
from __future__ import annotations


def make_phantom(**params):
    raise NotImplementedError("being written")
