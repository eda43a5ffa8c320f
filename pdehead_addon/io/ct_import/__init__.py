"""Step 1: CT import (DICOM series, numbered 2-D image stacks, headerless raw, NIfTI) into a CTVolume.

The paper (Fig. 1) starts from "a sequence of head cross-sectional slices". This
module turns whatever the slices are stored as into one :class:`CTVolume` in
patient LPS millimetres with a fixed axis convention, so that every later step
(segmentation eq. 16-21, boundary extraction eq. 22, the PDE patches eq. 1-13)
can treat ``data[k]`` as an axial slice at height ``origin[2] + k*dz``:

* k increases toward the patient's SUPERIOR side,
* j increases toward POSTERIOR,
* i increases toward the patient's LEFT,

i.e. ``direction`` is the identity. Axis-aligned sources are only flipped and
transposed (like nibabel's ``as_closest_canonical``); sources whose slices are
tilted (gantry tilt: a sheared grid), oblique or unevenly spaced are resampled
(linear interpolation) onto a regular axis-aligned grid in which every source
pixel keeps its true patient position ``IPP + col*dc*rowdir + row*dr*coldir``.

Nothing is ever written into the input folder.

Modules (one per format, plus discovery and geometry; each imports only the ones
above it in this list):

* :mod:`.folder_files` - the files of a source and their format, DICOMDIR, numbered stacks
* :mod:`.geometry`  - canonical reorientation, resampling, headerless stacks
* :mod:`.discovery` - the DICOM series of a source (:func:`list_series`)
* :mod:`.dicom`     - one DICOM series: sorting, tilt/uneven checks, decoding, HU
* :mod:`.images`    - numbered TIFF/PNG/... images
* :mod:`.raw`       - headerless raw slices
* :mod:`.nifti`     - NIfTI-1 files
* :mod:`.load`      - :func:`load_ct`, the entry point, and the value checks
"""
from .discovery import SeriesInfo, list_series
from .load import CTImportWarning, check_head_scan, load_ct

__all__ = ["load_ct", "check_head_scan", "list_series", "SeriesInfo", "CTImportWarning"]
