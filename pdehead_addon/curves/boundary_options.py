"""The options of the boundary-curve step (:func:`~.boundaries.extract_boundaries`): every parameter,
its default and the checks that need no mask.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from numbers import Integral
from typing import Sequence, Union

import numpy as np

from .. import defaults as D
from ..core.boundary_set import MIN_CURVES
from ..core.errors import BoundaryError
from .curve_sampling import STAR_MAX_SLOPE, check_samples
from .envelope import ENVELOPE_CLOSING_MM, ENVELOPE_SIGMA_MM
from .parameterisation import PARAMETERISATIONS
from .slice_selection import MIN_AREA_FRACTION, SelectionFunc

__all__ = ["BoundaryOptions", "LEVEL_FIELDS", "Selection"]

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


def _check_curves(curves) -> int:
    if isinstance(curves, bool) or not isinstance(curves, Integral) or curves < MIN_CURVES:
        raise BoundaryError(f"curves must be an integer >= {MIN_CURVES}, got {curves!r}")
    return int(curves)


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
        follows *every* usable slice's outline, :mod:`.auto_selection`; ``meta``
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
        within these bounds (:func:`~.auto_selection.select_for_tolerance`); implies
        ``selection="auto"`` and ignores ``patches``/``curves``. If even every usable
        slice misses the bound, all of them are used and a
        :class:`~.auto_selection.SelectionWarning` names the achieved error.
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
        """The slices are chosen by :mod:`.auto_selection` (``"auto"`` or a tolerance)."""
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
