"""PDE Head engine: head CT slices to a smooth parametric Bloor-Wilson PDE head.

Blender-free (numpy, scipy, scikit-image, pydicom). The subpackages read as the pipeline of
the paper "A PDE-based head visualization method with CT data" (Computer Animation and
Virtual Worlds, 2015); each one's docstring lists its modules:

1. :mod:`.io`        - CT slices to a :class:`CTVolume` in patient LPS mm (:mod:`.io.ct_import`, one
                       module per format), the phantom, the boundary file (section 5.2), mesh export
2. :mod:`.segment`   - 3D Chan-Vese soft segmentation (eq. 16-21) and clean-up
3. :mod:`.curves`    - eq. 22 boundary curves, 3t+1 of them as a :class:`BoundarySet`, and the
                       choice of the slices (:mod:`.curves.slice_selection`, :mod:`.curves.auto_selection`)
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
import importlib

from .core.boundary_set import BoundarySet, knots_from_heights
from .core.ct_volume import CTVolume
from .core.curve_alignment import align_parameterisation, correspondence_error
from .core.errors import (
    BoundaryError,
    Cancelled,
    CTImportError,
    PDEError,
    PDEHeadError,
    SegmentationError,
    StorageError,
)
from .core.mesh import Mesh
from .core.provenance import SOFTWARE_VERSION as __version__  # noqa: E402
from .curves import auto_selection, slice_selection
from .curves.auto_selection import SelectionWarning, select_for_tolerance
from .curves.boundaries import BoundaryOptions, extract_boundaries, max_patches, patches_for_scan
from .curves.curve_sampling import contour_from_mask, parameter_offsets
from .curves.parameterisation import smooth_closed_curve
from .curves.slice_outlines import boundary_ring
from .curves.slice_selection import SELECTION_STRATEGIES, register_selection, scan_edge_slices
from .forensic.bone_levels import bone_level_range, check_bone_level
from .forensic.depth_table import DepthEntry, DepthTable, default_table, read_depth_table, write_landmark_csv
from .forensic.skull import SkullSegmentation, segment_skull, skull_mesh
from .forensic.tissue_depth import TissueDepth, tissue_depth, write_depth_csv
from .io.ct_import import CTImportWarning, SeriesInfo, check_head_scan, list_series, load_ct
from .io.export import export_mesh
from .io.input_checks import HeadSizeWarning
from .io.phantom import Phantom, make_phantom
from .io.safe_io import WriteError, check_size, checked_output, copy_checked, disk_full
from .io.storage import dumps_boundaries, load_boundaries, loads_boundaries, save_boundaries
from .pde.head_files import load_head, loads_head
from .pde.pde_head import PDEHead
from .pde.pde_smoothing import smoothing_bounds
from .pde.pde_solid import OUTSIDE_W, WField, alpha_from_w, solid_mesh, w_field
from .pde.pde_surface import control_ranges, solve_pde, solve_with_controls
from .segment.segmentation import Segmentation, segment_head

#: Public names loaded on first use (PEP 562), so importing the package stays light: the Blender
#: layer and the scripts take them from here, not from the modules that define them.
_LAZY = {
    "ct_detail_map": (".pde.detail_map", "ct_detail_map"),
    "detail_map_stages": (".pde.detail_map", "detail_map_stages"),
    "detail_surface": (".pde.detail_displace", "detail_surface"),
    "print_resolution": (".pde.detail_displace", "print_resolution"),
    "print_mesh": (".pde.detail_displace", "print_mesh"),
    "apply_window": (".core.ct_volume", "apply_window"),
    "ct_grid_for": (".core.ct_volume", "ct_grid_for"),
    "grid_affine": (".core.ct_volume", "grid_affine"),
    "head_mask_on_grid": (".core.ct_volume", "head_mask_on_grid"),
    "intensity_window": (".core.ct_volume", "intensity_window"),
    "sample_ct": (".core.ct_volume", "sample_ct"),
    "trilinear": (".core.ct_volume", "trilinear"),
    "provenance": (".core.provenance", "provenance"),
    "message_for_cli": (".core.wording", "for_cli"),
    "message_for_dialog": (".core.wording", "for_dialog"),
    "find_landmarks": (".forensic.auto_landmarks", "find_landmarks"),
    "depth_flags": (".forensic.depth_on_ct", "depth_flags"),
    "measure_landmark_depths": (".forensic.depth_on_ct", "measure_landmark_depths"),
    "APPROXIMATION_LABEL": (".forensic.face_from_skull", "APPROXIMATION_LABEL"),
    "FaceModel": (".forensic.face_from_skull", "FaceModel"),
    "LiveFace": (".forensic.face_live", "LiveFace"),
    "face_model_from_state": (".forensic.face_live", "model_from_state"),
    "face_model_state": (".forensic.face_live", "model_state"),
    "STANDARD_LANDMARKS": (".forensic.landmarks", "STANDARD_LANDMARKS"),
    "bilateral_pairs": (".forensic.landmarks", "bilateral_pairs"),
    "frankfurt_transform": (".forensic.landmarks", "frankfurt_transform"),
    "landmark": (".forensic.landmarks", "landmark"),
    "marker_pegs": (".forensic.landmarks", "marker_pegs"),
    "midsagittal_plane": (".forensic.landmarks", "midsagittal_plane"),
    "mirror_matrix": (".forensic.landmarks", "mirror_matrix"),
    "snap_to_surface": (".forensic.landmarks", "snap_to_surface"),
    "symmetry_plane": (".forensic.landmarks", "symmetry_plane"),
    "series_of_file": (".io.ct_import.discovery", "series_of_file"),
    "EXPORT_FORMATS": (".io.export", "FORMATS"),
    "input_folder_conflict": (".io.export", "input_folder_conflict"),
    "surface_grid_cached": (".pde.pde_solid", "surface_grid_cached"),
    "SolidCTTable": (".pde.solid_ct_table", "SolidCTTable"),
}

__all__ = [  # the public API
    "WriteError", "check_size", "checked_output", "copy_checked", "disk_full",
    "PDEHeadError", "CTImportError", "SegmentationError", "BoundaryError", "PDEError", "StorageError",
    "Cancelled", "CTVolume", "Mesh", "load_ct", "check_head_scan", "list_series", "SeriesInfo", "CTImportWarning",
    "HeadSizeWarning", "make_phantom", "Phantom", "Segmentation", "segment_head", "BoundarySet",
    "knots_from_heights", "extract_boundaries", "BoundaryOptions", "max_patches", "patches_for_scan", "boundary_ring",
    "contour_from_mask", "parameter_offsets", "scan_edge_slices", "register_selection", "auto_selection",
    "SELECTION_STRATEGIES", "slice_selection", "SelectionWarning", "select_for_tolerance", "solve_pde",
    "PDEHead", "smoothing_bounds", "control_ranges", "solve_with_controls", "align_parameterisation",
    "smooth_closed_curve", "correspondence_error", "alpha_from_w", "w_field", "solid_mesh", "WField",
    "OUTSIDE_W", "save_boundaries", "load_boundaries", "dumps_boundaries", "loads_boundaries", "load_head",
    "loads_head", "SkullSegmentation", "bone_level_range", "check_bone_level", "segment_skull", "skull_mesh",
    "TissueDepth", "tissue_depth",
    "write_depth_csv", "export_mesh", "DepthTable", "DepthEntry", "read_depth_table", "default_table",
    "write_landmark_csv",
    "__version__",
    *_LAZY,
]


def __getattr__(name: str):
    """The names of :data:`_LAZY`, and ``pdehead_addon.validation`` (tests, benchmarks; not shipped in the zip),
    on first use."""
    if name == "validation":
        return importlib.import_module(".validation", __name__)
    if name in _LAZY:
        module, attribute = _LAZY[name]
        value = getattr(importlib.import_module(module, __name__), attribute)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
