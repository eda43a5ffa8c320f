"""Measures for the tests and the benchmarks (Jaccard, surface quality, surface distances) and the
DICOM writer. Not shipped in the extension zip; the engine's own code never imports it.

Modules:

- :mod:`.dicom_export`     Write CT volumes as DICOM CT series (one file per slice) with pydicom
- :mod:`.metrics`          Segmentation accuracy: the Jaccard measure of the paper (section 6) and an independent
  reference
- :mod:`.surface_metrics`  Distances between two surfaces given as vertices and faces (fidelity of the PDE head,
  section 5.2)
- :mod:`.surface_quality`  How smooth a PDE head looks, in numbers: creases, folds, notches and terracing
"""
from .dicom_export import write_dicom_series, write_phantom_series
from .metrics import jaccard, per_slice_jaccard, reference_head_mask
from .surface_metrics import symmetric_surface_distance
from .surface_quality import surface_quality

__all__ = ["write_dicom_series", "write_phantom_series", "jaccard", "per_slice_jaccard", "reference_head_mask",
           "symmetric_surface_distance", "surface_quality"]
