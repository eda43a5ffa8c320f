"""PDE Head engine: head CT slices to a smooth parametric Bloor-Wilson PDE head.

Blender-free (numpy, scipy, scikit-image, pydicom). The modules read as the
pipeline of the paper "A PDE-based head visualization method with CT data"
(Computer Animation and Virtual Worlds, 2015):

1. :mod:`.ct_import`     - CT slices to a :class:`CTVolume` in patient LPS mm (one module per format)
2. :mod:`.segmentation`  - 3D Chan-Vese soft segmentation (eq. 16-21, :mod:`.chan_vese`) and clean-up
                           (:mod:`.mask_cleanup`)
3. :mod:`.boundaries`    - eq. 22 boundary curves, 3t+1 of them as a :class:`BoundarySet`
   (:mod:`.slice_selection`: the choice of the slices, automatic or by a named strategy, the paper's
   open problem; :mod:`.slice_outlines`: each slice's outline; :mod:`.curve_sampling`: the curves' samples)
4. :mod:`.pde_surface`   - t Bloor-Wilson PDE patches (eq. 1-13), solved into a :class:`PDEHead` (:mod:`.pde_head`;
                           the smoothing a of the paper's patches: :mod:`.pde_smoothing`)
5. :mod:`.pde_solid`     - the solid (eq. 23), its w-field and eq. 24 opacity
6. :mod:`.storage`       - the compact boundary file (section 5.2)

Forensic toolkit: :mod:`.skull` (the skull as a second PDE surface and a bone mesh),
:mod:`.tissue_depth` (skin-skull depth per vertex), :mod:`.landmarks` (landmarks, depth
markers, Frankfurt horizontal, mid-sagittal mirror), :mod:`.export` (STL/OBJ/PLY in mm).
"""
from .core.errors import PDEHeadError, CTImportError, SegmentationError, BoundaryError, PDEError, StorageError, Cancelled
from .core.ct_volume import CTVolume
from .core.mesh import Mesh
from .io.ct_import import load_ct, list_series, SeriesInfo, CTImportWarning
from .io.input_checks import HeadSizeWarning
from .io.phantom import make_phantom, Phantom
from .validation.dicom_export import write_dicom_series, write_phantom_series
from .segment.segmentation import Segmentation, segment_head
from .validation.metrics import jaccard, per_slice_jaccard, reference_head_mask
from .core.boundary_set import BoundarySet, knots_from_heights
from .curves.boundaries import extract_boundaries, BoundaryOptions, max_patches, patches_for_scan
from .curves.slice_outlines import boundary_ring
from .curves.curve_sampling import contour_from_mask, parameter_offsets
from .curves import slice_selection
from .curves.slice_selection import SelectionWarning, select_for_tolerance, scan_edge_slices, register_selection, SELECTION_STRATEGIES
from .pde.pde_surface import solve_pde, control_ranges, solve_with_controls
from .pde.pde_head import PDEHead
from .pde.pde_smoothing import smoothing_bounds
from .validation.surface_quality import surface_quality
from .curves.parameterisation import align_parameterisation, smooth_closed_curve, correspondence_error
from .pde.pde_solid import alpha_from_w, w_field, solid_mesh, WField, OUTSIDE_W
from .io.storage import save_boundaries, load_boundaries, dumps_boundaries, loads_boundaries, load_head, loads_head
from .validation.surface_metrics import symmetric_surface_distance
from .forensic.skull import SkullSegmentation, segment_skull, skull_mesh
from .forensic.tissue_depth import TissueDepth, tissue_depth, write_depth_csv
from .io.export import export_mesh
from .forensic.depth_table import DepthTable, DepthEntry, read_depth_table, default_table, write_landmark_csv

from .core.provenance import SOFTWARE_VERSION as __version__  # noqa: E402
