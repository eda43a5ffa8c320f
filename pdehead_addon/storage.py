"""Compact storage of the PDE boundary conditions (paper section 5.2)."""
from __future__ import annotations


def save_boundaries(obj, path):
    raise NotImplementedError("being written")


def load_boundaries(path):
    raise NotImplementedError("being written")
