"""Step 1: CT import (DICOM series, numbered 2-D image stacks, headerless raw) into a CTVolume."""
from __future__ import annotations

from .ct_volume import CTVolume
from .errors import CTImportError


def list_series(path):
    raise NotImplementedError("being written")


def load_ct(path, **options) -> CTVolume:
    raise NotImplementedError("being written")
