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
   (:func:`~.parameterisation.align_parameterisation`).

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
(:mod:`.slice_selection`) traces every usable slice and keeps the curves whose
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
from dataclasses import dataclass
from numbers import Integral
from typing import Sequence, Union

import numpy as np

from .. import defaults as D
from ..core.boundary_set import MIN_CURVES, BoundarySet, knots_from_heights
from ..core.errors import BoundaryError, report_progress
from .curve_sampling import STAR_MAX_SLOPE, angular_curves, check_samples, orient_and_resample, star_hull
from .envelope import ENVELOPE_CLOSING_MM, ENVELOPE_SIGMA_MM, head_envelope
from .parameterisation import PARAMETERISATIONS, align_parameterisation
from .slice_outlines import contour_from_field, outer_contour
from .slice_selection import MIN_AREA_FRACTION, SELECTION_STRATEGIES, SelectionFunc, scan_edge_slices, usable_slices

__all__ = [
    "extract_boundaries", "BoundaryOptions", "choose_slices", "trace_outlines", "sample_curves",
    "record_metadata", "max_patches", "patches_for_scan", "LEVEL_FIELDS",
]

Selection = Union[str, SelectionFunc, Sequence[int], np.ndarray]

#: Default closing radius (mm) of each slice's outline: bridges nostrils, mouth slit, ear canal.
CLOSING_MM = 3.0
#: Default low-pass along each curve (Gaussian sigma, pixels) against the pixel-grid ripple.
CURVE_SIGMA_PX = 1.0
#: The same for the envelope's curves: its 3-D smoothing makes neighbouring outlines agree, so what
#: is left of the CT noise on the outline repeats from curve to curve as vertical wrinkles. 0.5 px
#: (was 1.5, lowered for the closed eyes): on top of the envelope's Gaussian a 1.5 px low-pass only took
#: the face off.
ENVELOPE_CURVE_SIGMA_PX = 0.5
#: Sources of the level line traced per slice.
LEVEL_FIELDS = ("envelope", "mask", "probability")


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


def _check_curves(curves) -> int:
    if isinstance(curves, bool) or not isinstance(curves, Integral) or curves < MIN_CURVES:
        raise BoundaryError(f"curves must be an integer >= {MIN_CURVES}, got {curves!r}")
    return int(curves)


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


# --------------------------------------------------------------------------- the options
@dataclass(frozen=True)
class BoundaryOptions:
    """Every parameter of :func:`extract_boundaries`, with its default.

    Parameters
    ----------
    patches : int
        Number t >= 1 of PDE patches; 3t+1 slices are used (default ``defaults.PATCHES``).
    samples : int
        Number M >= 8 of points per curve (default ``defaults.SAMPLES``).
    selection : str, callable or sequence of int
        How the 3t+1 slices are chosen: ``"auto"`` (the curves whose surface best
        follows *every* usable slice's outline, :mod:`.slice_selection`; ``meta``
        records the achieved error), a name in :data:`~.slice_selection.SELECTION_STRATEGIES`
        (``"uniform"``, the engine's default: evenly spaced in height; ``"shape-change"``: denser
        where the cross-section changes fast), a callable
        ``f(mask, n, heights) -> indices`` (``heights`` = patient z of each
        slice centre), or the slice indices themselves. Indices from a callable
        or given explicitly must be 3t+1 unique, in range, non-empty slices
        sorted inferior -> superior. (The add-on's default, ``defaults.SELECTION``, is "auto".)
    min_area_fraction : float
        Named strategies only use slices whose mask area is at least this
        fraction of the largest slice area (leaves out the degenerate vertex
        cap and stray voxels at the ends of the head).
    sigma, band : float, int
        Sub-pixel contour smoothing and probability band, see :func:`~.slice_outlines.outer_contour`.
    level_field : {"envelope", "mask", "probability"}
        ``"envelope"`` (default): trace the 0.5 level of the head's 3-D envelope
        (:func:`~.envelope.head_envelope`: the mask closed in 3-D by a ball of
        ``closing_mm`` and smoothed by a 3-D Gaussian of ``envelope_sigma_mm``),
        so that neighbouring curves agree and inlets are bridged consistently.
        ``"mask"``: the 0.5 level of each slice's cleaned mask (2-D closing by
        ``closing_mm``, Gaussian of ``sigma`` pixels); ``"probability"``: of the
        soft probability clamped to the cleaned mask's boundary band.
    parameterisation : {"angular", "arc-length", "aligned"}
        Where the M samples sit on each curve. ``"angular"`` (default): at the same
        M directions from a smooth spine through the outlines' centroids, on each
        outline's star hull (:func:`~.curve_sampling.angular_curves`; equal v is the
        same direction on every curve). ``"arc-length"``: equally spaced in arc length
        from the seam. ``"aligned"``: first that, then :func:`align_parameterisation`
        moves the samples along each curve so that equal v means corresponding points
        on neighbouring curves.
    curve_sigma : float, optional
        Default ``ENVELOPE_CURVE_SIGMA_PX`` (0.5) for the envelope, ``CURVE_SIGMA_PX`` (1) else.
        Gaussian low-pass along each curve, standard deviation in pixels
        (converted with the mean in-plane spacing): removes the pixel-grid
        ripple that repeats on every slice (vertical streaks on the surface).
        0 disables it.
    max_stretch : float
        Bound on the local stretch of the sample spacing of the alignment ("aligned" only).
    closing_mm : float, optional
        Default: ``ENVELOPE_CLOSING_MM`` for the envelope, ``CLOSING_MM`` (3 mm) for the others.
        Radius (mm) of the envelope's 3-D ball closing, or (``"mask"``,
        ``"probability"``) of a disk closing of each slice's outer region before the
        contour is traced (:func:`~.slice_outlines.close_region`): inlets narrower than about
        twice that (nostrils, a slightly open mouth, ear canal, the gap behind
        an ear flap) are bridged. Such inlets exist on one curve and not on
        its neighbours 5-10 mm away, so the PDE would fold there. 0 disables it.
    envelope_sigma_mm : float
        Standard deviation (mm) of the envelope's 3-D Gaussian (``"envelope"`` only).
    star_shaped : bool
        Replace each outline by its :func:`~.curve_sampling.star_hull` around its centre: inlets
        whose walls face the centre (behind the ears, nostrils) are filled, so the
        surface has no notches there and the ears are smooth bumps.
    star_slope : float
        The hull's bound on ``|d ln r / d theta|`` (:func:`~.curve_sampling.star_hull`'s ``max_slope``).
    curves : int, optional
        Number of curves instead of 3t+1 (any n >= 4: the default C2 surface takes
        any count; the paper's patches need 3t+1).
    tolerance_mm, max_tolerance_mm : float, optional
        Instead of a count: the fewest curves whose default surface (``solve_pde``)
        keeps a mean (and/or largest) distance from every usable slice's outline
        within these bounds (:func:`~.slice_selection.select_for_tolerance`); implies
        ``selection="auto"`` and ignores ``patches``/``curves``. If even every usable
        slice misses the bound, all of them are used and a
        :class:`~.slice_selection.SelectionWarning` names the achieved error.
    """

    patches: int = D.PATCHES.default
    samples: int = D.SAMPLES.default
    selection: Selection = "uniform"
    min_area_fraction: float = MIN_AREA_FRACTION
    sigma: float = 0.7
    level_field: str = "envelope"
    band: int = 1
    parameterisation: str = "angular"
    curve_sigma: float | None = None
    max_stretch: float = 8.0
    closing_mm: float | None = None
    envelope_sigma_mm: float = ENVELOPE_SIGMA_MM
    star_shaped: bool = True
    star_slope: float = STAR_MAX_SLOPE
    curves: int | None = None
    tolerance_mm: float | None = None
    max_tolerance_mm: float | None = None

    @property
    def auto(self) -> bool:
        """The slices are chosen by :mod:`.slice_selection` (``"auto"`` or a tolerance)."""
        return self.selection == "auto" or self.has_tolerance

    @property
    def has_tolerance(self) -> bool:
        return self.tolerance_mm is not None or self.max_tolerance_mm is not None

    def checked(self) -> "BoundaryOptions":
        """These options with ``samples`` an int and the level field's ``curve_sigma`` and ``closing_mm``
        filled in; ``BoundaryError`` for a bad value (the mask-independent checks)."""
        p = self.patches
        if isinstance(p, bool) or not isinstance(p, Integral) or p < 1:
            raise BoundaryError(f"patches must be an integer >= 1, got {p!r}")
        samples = check_samples(self.samples)
        if self.level_field not in LEVEL_FIELDS:
            raise BoundaryError(f"level_field must be one of {list(LEVEL_FIELDS)}, got {self.level_field!r}")
        if self.parameterisation not in PARAMETERISATIONS + ("angular",):
            raise BoundaryError(f"parameterisation must be one of {list(PARAMETERISATIONS) + ['angular']}, "
                                f"got {self.parameterisation!r}")
        envelope = self.level_field == "envelope"
        curve_sigma = self.curve_sigma
        if curve_sigma is None:
            curve_sigma = ENVELOPE_CURVE_SIGMA_PX if envelope else CURVE_SIGMA_PX
        if not (np.isfinite(curve_sigma) and curve_sigma >= 0):
            raise BoundaryError(f"curve_sigma must be >= 0 (pixels), got {curve_sigma!r}")
        closing_mm = self.closing_mm
        if closing_mm is None:
            closing_mm = ENVELOPE_CLOSING_MM if envelope else CLOSING_MM
        if not (np.isfinite(closing_mm) and closing_mm >= 0):
            raise BoundaryError(f"closing_mm must be >= 0, got {closing_mm!r}")
        if not (np.isfinite(self.max_stretch) and self.max_stretch > 1):
            raise BoundaryError(f"max_stretch must be > 1, got {self.max_stretch!r}")
        if not 0.0 <= float(self.min_area_fraction) < 1.0:
            raise BoundaryError(f"min_area_fraction must be in [0, 1), got {self.min_area_fraction!r}")
        return dataclasses.replace(self, samples=samples, curve_sigma=curve_sigma, closing_mm=closing_mm)

    def curve_count(self) -> int:
        """The number n of curves asked for: 3t+1, or ``curves``."""
        return 3 * int(self.patches) + 1 if self.curves is None else _check_curves(self.curves)

    def check_auto(self) -> None:
        """``BoundaryError`` if the automatic selection cannot run with these options."""
        selection = self.selection
        if self.auto and not (isinstance(selection, str) and selection in ("auto", "uniform")):
            raise BoundaryError("a tolerance chooses the slices itself (selection 'auto'), "
                                f"got selection {selection!r}")
        if self.auto and self.parameterisation != "angular":
            raise BoundaryError("selection 'auto' needs parameterisation='angular' (its candidates share one spine)")


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
    from . import slice_selection as S
    chosen = usable_slices(selectable, slice_z, opts.min_area_fraction)        # every candidate, traced below
    chosen = S.thin_candidates(chosen) if opts.has_tolerance else S.thin_candidates(chosen, n)
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
    """The automatic selection (:mod:`.slice_selection`) among the traced candidates, its record in ``meta``."""
    from . import slice_selection as S
    cand = S.Candidates(np.asarray(chosen), curves_out, meta)
    if not opts.has_tolerance:
        pos = S.select_curves(cand, n)
        bset = make_bset(pos)
        err, met = S.surface_error(bset, cand), None
    else:
        pos, bset, err, met = S.select_for_tolerance(cand, make_bset, opts.tolerance_mm, opts.max_tolerance_mm)
    bset.meta.update(S.selection_record(err, len(pos), opts.tolerance_mm, opts.max_tolerance_mm, met, cand.count))
    bset.meta["selection_per_slice_mm"] = [round(float(e), 4) for e in err["per_slice_mm"]]
    S.attach_candidates(bset, cand)
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
