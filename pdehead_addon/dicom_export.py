"""Write a CTVolume as a DICOM CT series (one file per slice) with pydicom."""
from __future__ import annotations


def write_dicom_series(ct, folder, **options):
    raise NotImplementedError("being written")
