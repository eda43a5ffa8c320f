"""Step 3: per-slice boundary curves (paper eq. 22) and the choice of 3t+1 of them (section 4.1).

The paper extracts the head boundary of a segmented slice ``I`` with the
morphological boundary operator

    beta(I) = I - (I erode S)                                     (eq. 22)

and feeds 3t+1 such boundaries, one per chosen axial slice, to t fourth-order
PDE patches that share their end curves (section 4.1). A pixel ring is not
yet a PDE boundary condition: the PDE needs each boundary as a closed curve
P(v), v in [0, 2 pi), sampled the same way on every slice. This module turns the
eq. 22 ring into such a curve:

1. the main (largest) connected component of the cleaned mask slice, with its
   holes filled and inlets narrower than ~2 x ``closing_mm`` bridged
   (:func:`close_region`), is the head's *outer region*; its eq. 22 ring
   (:func:`boundary_ring`) is the outer head boundary in pixels;
2. the returned curve is the sub-pixel refinement of that ring: the 0.5 level
   line (marching squares, :func:`skimage.measure.find_contours`) of the outer
   region smoothed by a Gaussian of ``sigma`` pixels (or, with
   ``level_field="probability"``, of the soft segmentation probability clamped
   to a ``band`` of pixels around the ring). With the default 4-connected
   structuring element, the pixels the unsmoothed level line passes are exactly
   the eq. 22 ring pixels; the ring is used to validate the curve (every curve
   point lies within ``band + 1`` pixel of a ring pixel) and to report how much
   of the ring the curve follows (``meta["ring_coverage"]``);
3. the curve is mapped to patient LPS mm, oriented counter-clockwise seen from
   above (from +z, superior), low-passed along its arc length (Gaussian of
   ``curve_sigma`` pixels: the pixel-grid ripple repeats on every slice and
   would streak the surface), started at its posterior midline point (the seam
   v = 0, at the back of the head, so the face is seam-free) and resampled at M
   points uniformly in arc length;
4. by default (``parameterisation="angular"``) each outline is replaced by its
   star hull around a smooth spine through the outlines' centroids and sampled
   at the same M directions from the spine on every curve
   (:func:`~.curve_sampling.angular_curves`); ``"arc-length"`` keeps the equal
   arc-length samples of step 3 and ``"aligned"`` then moves them along each
   curve so that equal v means corresponding points on neighbouring curves
   (:func:`~pdehead_addon.core.curve_alignment.align_parameterisation`).

The stages are one function each: :func:`choose_slices`, :func:`trace_outlines`
(:mod:`.slice_outlines`), :func:`sample_curves` (:mod:`.curve_sampling`) and
:func:`record_metadata`; their parameters are one :class:`BoundaryOptions`.

Conventions of every curve returned (shared with :class:`BoundarySet`):

* orientation: counter-clockwise in the patient (x, y) plane seen from +z,
  i.e. positive signed (shoelace) area in (x, y). In LPS, starting at the back
  (+y), v runs back -> patient right (-x) -> face (-y) -> patient left (+x) ->
  back. For a surface X(u, v) with u increasing superior (inferior -> superior
  curve order) the OUTWARD normal is ``dX/dv x dX/du``.
* seam: sample 0 is where the curve crosses the ray from its area centroid
  toward +y (posterior) along x = centroid x (the outermost such crossing).
* spacing: with ``parameterisation="arc-length"`` the M samples are equally
  spaced in arc length along the smoothed polyline (periodic linear
  interpolation of cumulative chord length), so the parameterisation of
  neighbouring curves does not twist (:func:`parameter_offsets` measures it),
  but features on one side only (an ear, the nose) move the samples of the
  next curve by a few steps (CThead, t = 10, M = 256: median 0-1, maximum 7).
  ``"aligned"`` keeps the same polylines and the same seam and
  re-spaces the samples by dynamic time warping between neighbours; on CThead
  (t = 10) the mean distance between equal-v samples of neighbouring centred
  curves drops from ~9.3 to ~4.9 mm and the PDE surface's mean distance to
  marching cubes from 0.67 to 0.45 mm.

Choice of slices (section 4.1): the paper picks 3t+1 slices by hand and calls
an automatic choice an open problem (section 6). Here a slice is *usable* if
its mask area is at least ``min_area_fraction`` (5 %) of the largest slice
area, which leaves out the degenerate vertex cap and stray voxels at the ends;
the head's extent runs from the lowest to the highest usable slice. The
strategy is pluggable (:data:`~.slice_selection.SELECTION_STRATEGIES`): ``"uniform"`` (evenly
spaced in height) and ``"shape-change"`` (denser where the cross-section
changes fast: chin, nose, vertex), a callable, or explicit indices. ``"auto"``
(:mod:`.auto_selection`) traces every usable slice and keeps the curves whose
C2 surface is closest to all of their outlines; with ``tolerance_mm`` it also
chooses how many (the default C2 surface takes any count, not only 3t+1).

Limits: one curve per slice, so a part of the head that is a separate
component in a slice (an ear lobe cut off in that plane) is dropped, while an
opening connected to the outside (ear canal, nostril) is followed into the
head. Where the scan does not cover the whole head (the lowest slices of a
tilted series), the curve closes along the edge of the data.
"""
from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from ..core.boundary_set import MIN_CURVES, BoundarySet, knots_from_heights
from ..core.curve_alignment import align_parameterisation
from ..core.errors import BoundaryError, report_progress
from .auto_selection import (
    Candidates,
    attach_candidates,
    select_curves,
    select_for_tolerance,
    selection_record,
    surface_error,
    thin_candidates,
)
from .boundary_options import LEVEL_FIELDS, BoundaryOptions
from .curve_sampling import angular_curves, orient_and_resample, star_hull
from .envelope import head_envelope
from .slice_outlines import contour_from_field, outer_contour
from .slice_selection import MIN_AREA_FRACTION, SELECTION_STRATEGIES, scan_edge_slices, usable_slices

__all__ = [
    "extract_boundaries", "BoundaryOptions", "choose_slices", "trace_outlines", "sample_curves",
    "record_metadata", "max_patches", "patches_for_scan", "LEVEL_FIELDS",
]


# --------------------------------------------------------------------------- checks and scan facts
def _max_thickness(value) -> float | None:
    """The largest slice thickness (mm) a source recorded (a number or a list), or None."""
    try:
        arr = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        return None
    arr = arr[np.isfinite(arr) & (arr > 0)]
    return float(arr.max()) if arr.size else None


def _head_top(mask: np.ndarray, slice_z: np.ndarray, dz: float) -> float | None:
    """Patient z of the crown (the top face of the most superior head slice), if the head ends in the scan."""
    occupied = np.flatnonzero(mask.reshape(len(mask), -1).any(axis=1))
    if occupied.size == 0:
        return None
    superior_is_last = slice_z[-1] >= slice_z[0]
    top = occupied[-1] if superior_is_last else occupied[0]
    if top in (0, len(mask) - 1):                      # cut off by the scan: the crown is not known
        return None
    return float(slice_z[top] + 0.5 * abs(dz))


def _validate_indices(indices, n: int, mask: np.ndarray, heights: np.ndarray, what: str) -> np.ndarray:
    try:
        raw = np.asarray(indices)
    except Exception as exc:  # noqa: BLE001 - anything unusable is a user error here
        raise BoundaryError(f"{what}: slice indices are not an array of integers ({exc})") from None
    if raw.ndim != 1 or raw.size == 0 or not (np.issubdtype(raw.dtype, np.integer)
                                              or (np.issubdtype(raw.dtype, np.floating)
                                                  and np.all(np.isfinite(raw)) and np.all(raw == np.round(raw)))):
        raise BoundaryError(f"{what}: slice indices must be a 1-D sequence of integers, got {indices!r}")
    idx = raw.astype(np.int64)
    if idx.size != n:
        raise BoundaryError(f"{what}: {idx.size} slices given, but 3t+1 = {n} are needed")
    nz = mask.shape[0]
    bad = idx[(idx < 0) | (idx >= nz)]
    if bad.size:
        raise BoundaryError(f"{what}: slice indices {bad.tolist()} out of range 0..{nz - 1}")
    if np.unique(idx).size != idx.size:
        raise BoundaryError(f"{what}: slice indices repeat: {idx.tolist()}")
    empty = [int(k) for k in idx if not mask[k].any()]
    if empty:
        raise BoundaryError(f"{what}: slices {empty} have an empty head mask")
    if not np.all(np.diff(heights[idx]) > 0):
        raise BoundaryError(f"{what}: slices must be sorted inferior -> superior (increasing height), "
                            f"got indices {idx.tolist()} at heights {np.round(heights[idx], 2).tolist()}")
    return idx


def _checked_mask(seg) -> tuple[np.ndarray, object]:
    """The segmentation's mask as bool [z, y, x] and its CT, or ``BoundaryError``."""
    mask = np.asarray(getattr(seg, "mask", None))
    ct = getattr(seg, "ct", None)
    if mask.ndim != 3 or ct is None or tuple(mask.shape) != tuple(ct.shape):
        raise BoundaryError(f"segmentation mask must be 3-D with the CT's shape, got {mask.shape}")
    if mask.dtype != bool:
        mask = mask.astype(bool)
    if not mask.any():
        raise BoundaryError("the segmentation mask is empty: no head to extract boundaries from")
    return mask, ct


def slice_heights(mask: np.ndarray, ct) -> np.ndarray:
    """Patient z (mm) of the centre of each axial slice of ``mask``'s grid."""
    nz, ny, nx = mask.shape
    centre = np.column_stack([np.arange(nz, dtype=float), np.full(nz, (ny - 1) / 2), np.full(nz, (nx - 1) / 2)])
    return ct.index_to_patient(centre)[:, 2]


# --------------------------------------------------------------------------- stage 1: choose slices
def _auto_candidates(selectable: np.ndarray, slice_z: np.ndarray, opts: BoundaryOptions, n: int) -> np.ndarray:
    """Every usable slice (thinned): the candidates the automatic selection chooses from."""
    chosen = usable_slices(selectable, slice_z, opts.min_area_fraction)        # every candidate, traced below
    chosen = thin_candidates(chosen) if opts.has_tolerance else thin_candidates(chosen, n)
    if len(chosen) < MIN_CURVES:
        raise BoundaryError(f"only {len(chosen)} slices have a usable head cross-section; a PDE head "
                            f"needs at least {MIN_CURVES}")
    if not opts.has_tolerance and n > len(chosen):
        most = (len(chosen) - 1) // 3
        raise BoundaryError(f"only {len(chosen)} slices have a usable head cross-section, but {n} curves "
                            f"are needed; use fewer patches (t <= {most})")
    return chosen


def choose_slices(mask: np.ndarray, slice_z: np.ndarray, opts: BoundaryOptions, n: int,
                  coverage: np.ndarray | None = None) -> tuple[np.ndarray, str, np.ndarray]:
    """Stage 1: the slices to trace (the n chosen ones, or every candidate of ``"auto"``).

    Returns
    -------
    chosen : ndarray of int
        Slice indices, inferior -> superior.
    selection_name : str
        ``"auto"``, the strategy's name, ``"callable:<name>"`` or ``"explicit"``.
    cut_off : ndarray of bool, shape (nz,)
        The slices whose outline is the edge of the scan (:func:`~.slice_selection.scan_edge_slices`);
        no named strategy picks them.
    """
    cut_off = scan_edge_slices(mask, coverage)
    selectable = mask
    if cut_off.any():  # named strategies never pick a slice whose outline is the edge of the scan
        selectable = mask.copy()
        selectable[cut_off] = False
    selection = opts.selection
    if opts.auto:
        return _auto_candidates(selectable, slice_z, opts, n), "auto", cut_off
    if isinstance(selection, str):
        strategy = SELECTION_STRATEGIES.get(selection)
        if strategy is None:
            raise BoundaryError(f"unknown selection {selection!r}; known: {sorted(SELECTION_STRATEGIES) + ['auto']}")
        chosen = _validate_indices(strategy(selectable, n, slice_z, min_area_fraction=opts.min_area_fraction),
                                   n, mask, slice_z, f"selection {selection!r}")
        return chosen, selection, cut_off
    if callable(selection):
        name = f"callable:{getattr(selection, '__name__', type(selection).__name__)}"
        return _validate_indices(selection(mask, n, slice_z), n, mask, slice_z, name), name, cut_off
    return _validate_indices(selection, n, mask, slice_z, "explicit selection"), "explicit", cut_off


# --------------------------------------------------------------------------- stage 2: trace outlines
def trace_outlines(seg, mask: np.ndarray, chosen: np.ndarray, opts: BoundaryOptions,
                   progress=None) -> tuple[list[np.ndarray], list[float], list[float]]:
    """Stage 2: each chosen slice's outline in patient LPS mm, with its area (mm^2) and ring coverage.

    ``opts`` must be :meth:`BoundaryOptions.checked` (``closing_mm`` filled in). The level field is
    ``opts.level_field``: the head's 3-D envelope (computed once for the chosen slices), the mask or
    the probability (:func:`~.slice_outlines.outer_contour` per slice).
    """
    ct = seg.ct
    probability = None
    if opts.level_field == "probability":
        probability = np.asarray(getattr(seg, "probability", None))
        if probability.shape != mask.shape:
            raise BoundaryError(f"segmentation probability shape {probability.shape} != mask shape {mask.shape}")
    dz, dy, dx = ct.spacing
    closing_px = float(opts.closing_mm) / (0.5 * (dy + dx))
    envelope = opts.level_field == "envelope"
    if envelope:
        if not (np.isfinite(opts.envelope_sigma_mm) and opts.envelope_sigma_mm >= 0):
            raise BoundaryError(f"envelope_sigma_mm must be >= 0, got {opts.envelope_sigma_mm!r}")
        report_progress(progress, 0.0, "the head's envelope")
        field, window = head_envelope(mask, (dz, dy, dx), closing_mm=float(opts.closing_mm),
                                      sigma_mm=float(opts.envelope_sigma_mm), slices=chosen)
    outlines, areas, coverage = [], [], []
    for c, k in enumerate(chosen):
        if c % 8 == 0:
            report_progress(progress, 0.3 + 0.3 * c / len(chosen), f"tracing slice {c + 1} of {len(chosen)}")
        try:
            if envelope:
                rc, info = contour_from_field(field[k - window[0].start], origin=(window[1].start, window[2].start))
            else:
                rc, info = outer_contour(mask[k], sigma=opts.sigma, band=opts.band, return_info=True,
                                         closing=closing_px,
                                         probability=None if probability is None else probability[k])
        except BoundaryError as exc:
            raise BoundaryError(f"slice {int(k)}: {exc}") from None
        kji = np.column_stack([np.full(len(rc), float(k)), rc])
        outlines.append(ct.index_to_patient(kji))
        areas.append(info["area_px"] * dy * dx)
        coverage.append(info["ring_coverage"])
    return outlines, areas, coverage


# --------------------------------------------------------------------------- stage 3: sample curves
def sample_curves(outlines: Sequence[np.ndarray], opts: BoundaryOptions, spacing) -> np.ndarray:
    """Stage 3: the outlines as curves of ``opts.samples`` points, shape (n, M, 3) in LPS mm.

    ``"angular"``: :func:`~.curve_sampling.angular_curves` around one spine; else each outline (its star
    hull if ``opts.star_shaped``) oriented, started at the posterior seam and resampled in arc length
    (:func:`~.curve_sampling.orient_and_resample`). ``curve_sigma`` (pixels) is converted to mm with the
    mean in-plane ``spacing``; ``opts`` must be :meth:`BoundaryOptions.checked`.
    """
    _, dy, dx = spacing
    smooth_mm = float(opts.curve_sigma) * 0.5 * (dy + dx)
    if opts.parameterisation == "angular":
        slope = opts.star_slope if opts.star_shaped else None
        return angular_curves(outlines, opts.samples, smooth=smooth_mm, max_slope=slope)
    return np.stack([orient_and_resample(star_hull(o, max_slope=opts.star_slope) if opts.star_shaped else o,
                                         opts.samples, smooth=smooth_mm)
                     for o in outlines])


# --------------------------------------------------------------------------- stage 4: record metadata
def record_metadata(ct, mask: np.ndarray, slice_z: np.ndarray, opts: BoundaryOptions, selection_name: str,
                    cut_off: np.ndarray) -> dict:
    """Stage 4: the ``meta`` shared by every curve set of one extraction (how it was made, the scan's
    slice step, thickness and tilt, the crown's height); ``opts`` must be :meth:`BoundaryOptions.checked`."""
    dz = ct.spacing[0]
    envelope = opts.level_field == "envelope"
    meta = dict(
        source=ct.meta.get("source", ct.meta.get("path")),
        selection=selection_name, patches=int(opts.patches), samples=opts.samples,
        spacing=[float(s) for s in ct.spacing], min_area_fraction=float(opts.min_area_fraction),
        sigma=float(opts.sigma), level_field=opts.level_field, band=int(opts.band),
        scan_edge_slices=np.flatnonzero(cut_off).tolist(),
        orientation="ccw seen from +z (superior); outward normal = dX/dv x dX/du",
        seam="posterior midline (+y ray from each curve's area centroid)",
        curve_sigma=float(opts.curve_sigma), closing_mm=float(opts.closing_mm),
        parameterisation="angular" if opts.parameterisation == "angular" else "arc-length",
        envelope_sigma_mm=float(opts.envelope_sigma_mm) if envelope else None,
        star_shaped=bool(opts.star_shaped), star_slope=float(opts.star_slope) if opts.star_shaped else None,
        source_slice_step_mm=float(ct.meta.get("source_slice_step_mm") or dz),
        source_slice_thickness_mm=_max_thickness(ct.meta.get("slice_thickness_mm")),
        gantry_tilt_deg=float(ct.meta.get("gantry_tilt_deg") or 0.0),
    )
    top = _head_top(mask, slice_z, dz)
    if top is not None:
        meta["vertex_z"] = top
    return meta


# --------------------------------------------------------------------------- the curve set
def _curve_set(chosen, curves_out, areas, coverage, meta, opts: BoundaryOptions):
    """``make_bset(positions)``: the BoundarySet of the traced curves at ``positions`` of ``chosen``."""
    def make_bset(pos) -> BoundarySet:
        pos = np.asarray(pos, np.int64)
        cv = curves_out[pos]
        h = cv[:, :, 2].mean(axis=1)
        m = dict(meta, slice_areas_mm2=[float(areas[p]) for p in pos],
                 ring_coverage=[float(coverage[p]) for p in pos])
        if opts.curves is not None or len(pos) != 3 * int(opts.patches) + 1:
            m["patches"] = BoundarySet.patches_for(len(pos))
        return BoundarySet(cv, np.asarray(chosen)[pos], h, knots_from_heights(h), m)
    return make_bset


def _select_automatically(chosen, curves_out, meta, make_bset, opts: BoundaryOptions, n: int) -> BoundarySet:
    """The automatic selection (:mod:`.auto_selection`) among the traced candidates, its record in ``meta``."""
    cand = Candidates(np.asarray(chosen), curves_out, meta)
    if not opts.has_tolerance:
        pos = select_curves(cand, n)
        bset = make_bset(pos)
        err, met = surface_error(bset, cand), None
    else:
        pos, bset, err, met = select_for_tolerance(cand, make_bset, opts.tolerance_mm, opts.max_tolerance_mm)
    bset.meta.update(selection_record(err, len(pos), opts.tolerance_mm, opts.max_tolerance_mm, met, cand.count))
    bset.meta["selection_per_slice_mm"] = [round(float(e), 4) for e in err["per_slice_mm"]]
    attach_candidates(bset, cand)
    return bset


# --------------------------------------------------------------------------- the pipeline step
def max_patches(seg, min_area_fraction: float = MIN_AREA_FRACTION) -> int:
    """The largest t for which the named selections find 3t+1 usable slices in ``seg``.

    Usable slices are those :func:`~.slice_selection.usable_slices` keeps, less the slices whose
    outline is the edge of the scan (:func:`~.slice_selection.scan_edge_slices`). Returns 0 when
    not even 4 slices are usable.
    """
    mask = np.asarray(seg.mask, bool)
    ct = seg.ct
    selectable = mask.copy()
    selectable[scan_edge_slices(mask, getattr(ct, "coverage", None))] = False
    if not selectable.any():
        return 0
    usable = usable_slices(selectable, slice_heights(mask, ct), min_area_fraction)
    return max((len(usable) - 1) // 3, 0)


def patches_for_scan(seg, patches: int) -> tuple[int, str | None]:
    """The patches a scan can give: ``patches`` when it has 3t+1 usable slices for them, else the largest t
    it has (:func:`max_patches`, e.g. the tilted GE slab: 28 usable slices, t <= 9), with the message that
    says so. One rule for the add-on and the batch. With not even t = 1 usable, ``patches`` unchanged and
    no message: :func:`extract_boundaries` then says why it cannot."""
    limit = max_patches(seg)
    if 1 <= limit < patches:
        return limit, (f"the scan has usable head outlines for at most {limit} patches "
                       f"({3 * limit + 1} slices): patches reduced from {patches} to {limit}")
    return patches, None


def extract_boundaries(seg, options: BoundaryOptions | None = None, *, progress=None, **overrides) -> BoundarySet:
    """The 3t+1 PDE boundary curves of a segmented head (paper eq. 22, sections 3 and 4.1).

    Four stages: :func:`choose_slices`, :func:`trace_outlines`, :func:`sample_curves` and
    :func:`record_metadata`, then the curve set (and, with ``selection="auto"``, the automatic
    choice among the traced candidates). The default parameterisation is ``"angular"``.

    Parameters
    ----------
    seg : Segmentation
        ``seg.mask`` (bool [z, y, x]) is the cleaned head mask, ``seg.ct`` gives
        the geometry (``index_to_patient``), ``seg.probability`` the soft
        membership (only with ``level_field="probability"``).
    options : BoundaryOptions, optional
        Every parameter (see :class:`BoundaryOptions` for each one and its default).
    progress : callable, optional
        ``progress(fraction, message)``.
    **overrides
        Fields of :class:`BoundaryOptions` by name (``patches=10, selection="auto"``, ...), replacing
        those of ``options``; an unknown name is a ``TypeError``.

    Returns
    -------
    BoundarySet
        Curves (3t+1, M, 3) in patient LPS mm ordered inferior -> superior,
        counter-clockwise seen from +z, sample 0 at the posterior midline,
        angular, uniform in arc length or aligned (``meta["parameterisation"]``);
        ``heights`` = mean patient z of each curve; ``u_knots`` from
        :func:`knots_from_heights`. With ``selection="auto"`` (or a tolerance),
        ``meta`` also holds ``selection_curves``, ``selection_candidates``,
        ``selection_mean_mm``, ``selection_max_mm``, ``selection_p95_mm`` (the real
        surface's distance from all usable slices' outlines), ``selection_tolerance_mm``,
        ``selection_max_tolerance_mm`` and ``selection_tolerance_met`` (None without a tolerance).

    Raises
    ------
    BoundaryError
        Bad parameters, an empty mask, fewer usable slices than 3t+1, a bad
        selection, or a slice without a closed contour.
    """
    if options is None:
        options = BoundaryOptions()
    elif not isinstance(options, BoundaryOptions):
        raise TypeError(f"options must be a BoundaryOptions, got {type(options).__name__} "
                        "(give the other parameters by name)")
    opts = dataclasses.replace(options, **overrides).checked()
    mask, ct = _checked_mask(seg)
    n = opts.curve_count()
    opts.check_auto()
    slice_z = slice_heights(mask, ct)
    chosen, selection_name, cut_off = choose_slices(mask, slice_z, opts, n, getattr(ct, "coverage", None))
    outlines, areas, coverage = trace_outlines(seg, mask, chosen, opts, progress)
    curves_out = sample_curves(outlines, opts, ct.spacing)
    meta = record_metadata(ct, mask, slice_z, opts, selection_name, cut_off)
    make_bset = _curve_set(chosen, curves_out, areas, coverage, meta, opts)
    report_progress(progress, 0.6, "choosing the curves" if opts.auto else "the curves")
    if opts.auto:
        bset = _select_automatically(chosen, curves_out, meta, make_bset, opts, n)
    else:
        bset = make_bset(np.arange(len(chosen)))
    if opts.parameterisation == "aligned":
        bset = align_parameterisation(bset, max_stretch=opts.max_stretch)
    report_progress(progress, 1.0, "boundary curves done")
    return bset
