"""PDE Head engine: head CT slices to a smooth parametric Bloor-Wilson PDE head.

Blender-free (numpy, scipy, scikit-image, pydicom). The subpackages read as the pipeline of
the paper "A PDE-based head visualization method with CT data" (Computer Animation and
Virtual Worlds, 2015); each one's docstring lists its modules:

1. :mod:`.io`        - CT slices to a :class:`CTVolume` in patient LPS mm (:mod:`.io.ct_import`, one
                       module per format), the phantom, the boundary file (section 5.2), mesh export
2. :mod:`.segment`   - 3D Chan-Vese soft segmentation (eq. 16-21) and clean-up
3. :mod:`.curves`    - eq. 22 boundary curves, 3t+1 of them as a :class:`BoundarySet`, and the
                       automatic choice of the slices (:mod:`.curves.slice_selection`)
4. :mod:`.pde`       - t Bloor-Wilson PDE patches (eq. 1-13), the surface mesh, the solid (eq. 23)
                       with its w-field and eq. 24 opacity
5. :mod:`.forensic`  - the skull, skin-skull tissue depth, landmarks, depth tables, the face from the skull

:mod:`.core` holds what every stage shares (CTVolume, Mesh and the mesh routines, BoundarySet,
the errors); :mod:`.defaults` is the one table of user-facing defaults and ranges.
:mod:`.validation` (Jaccard, surface quality and distances, the DICOM writer) serves the tests
and benchmarks only: it is not imported here and not shipped in the extension zip
(``pdehead_addon.validation`` is imported on first use).

``__all__`` is the public API; the operators and scripts use these names (or a module of a
subpackage where they need more).
"""
from .core.errors import PDEHeadError, CTImportError, SegmentationError, BoundaryError, PDEError, StorageError, Cancelled
from .core.ct_volume import CTVolume
from .core.mesh import Mesh
from .io.ct_import import load_ct, list_series, SeriesInfo, CTImportWarning
from .io.input_checks import HeadSizeWarning
from .io.phantom import make_phantom, Phantom
from .segment.segmentation import Segmentation, segment_head
from .core.boundary_set import BoundarySet, knots_from_heights
from .curves.boundaries import extract_boundaries, BoundaryOptions, max_patches, patches_for_scan
from .curves.slice_outlines import boundary_ring
from .curves.curve_sampling import contour_from_mask, parameter_offsets
from .curves import slice_selection
from .curves.slice_selection import SelectionWarning, select_for_tolerance, scan_edge_slices, register_selection, SELECTION_STRATEGIES
from .pde.pde_surface import solve_pde, control_ranges, solve_with_controls
from .pde.pde_head import PDEHead
from .pde.pde_smoothing import smoothing_bounds
from .curves.parameterisation import align_parameterisation, smooth_closed_curve, correspondence_error
from .pde.pde_solid import alpha_from_w, w_field, solid_mesh, WField, OUTSIDE_W
from .io.storage import save_boundaries, load_boundaries, dumps_boundaries, loads_boundaries, load_head, loads_head
from .forensic.skull import SkullSegmentation, segment_skull, skull_mesh
from .forensic.tissue_depth import TissueDepth, tissue_depth, write_depth_csv
from .io.export import export_mesh
from .forensic.depth_table import DepthTable, DepthEntry, read_depth_table, default_table, write_landmark_csv

from .core.provenance import SOFTWARE_VERSION as __version__  # noqa: E402


__all__ = [  # the public API
    "PDEHeadError", "CTImportError", "SegmentationError", "BoundaryError", "PDEError", "StorageError",
    "Cancelled", "CTVolume", "Mesh", "load_ct", "list_series", "SeriesInfo", "CTImportWarning",
    "HeadSizeWarning", "make_phantom", "Phantom", "Segmentation", "segment_head", "BoundarySet",
    "knots_from_heights", "extract_boundaries", "BoundaryOptions", "max_patches", "patches_for_scan", "boundary_ring",
    "contour_from_mask", "parameter_offsets", "scan_edge_slices", "register_selection",
    "SELECTION_STRATEGIES", "slice_selection", "SelectionWarning", "select_for_tolerance", "solve_pde",
    "PDEHead", "smoothing_bounds", "control_ranges", "solve_with_controls", "align_parameterisation",
    "smooth_closed_curve", "correspondence_error", "alpha_from_w", "w_field", "solid_mesh", "WField",
    "OUTSIDE_W", "save_boundaries", "load_boundaries", "dumps_boundaries", "loads_boundaries", "load_head",
    "loads_head", "SkullSegmentation", "segment_skull", "skull_mesh", "TissueDepth", "tissue_depth",
    "write_depth_csv", "export_mesh", "DepthTable", "DepthEntry", "read_depth_table", "default_table",
    "write_landmark_csv",
    "__version__",
]


def __getattr__(name: str):
    """``pdehead_addon.validation`` on first use (tests, benchmarks); it is not shipped in the zip."""
    if name == "validation":
        import importlib
        return importlib.import_module(".validation", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
