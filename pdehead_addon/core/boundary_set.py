"""The PDE boundary conditions: 3t+1 (or, for the C2 surface, any n >= 4) closed curves with their u-knots."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import BoundaryError

#: Fewest curves of a boundary set (one paper patch: 3t+1 with t = 1).
MIN_CURVES = 4


def knots_from_heights(heights: np.ndarray) -> np.ndarray:
    """u-knots of 3t+1 curves from their heights along the head axis.

    Patch k spans u in [k/t, (k+1)/t] and uses curves 3k..3k+3, so curve 3k sits
    exactly at u = k/t; the two interior curves of a patch sit where their
    heights put them between the patch's end curves (the paper's p1 and p2,
    eq. 4-5), not at fixed thirds. A count that is not 3t+1 (only the C2 surface
    takes it, which places its curves by chord length itself) gets the heights
    normalised to [0, 1].

    Parameters
    ----------
    heights : ndarray, shape (n,)
        Strictly monotonic heights (mm) of the curves, e.g. their mean patient z.

    Returns
    -------
    ndarray, shape (n,)
        Knots in [0, 1], strictly increasing, with ``knots[3k] == k/t`` for n = 3t+1.
    """
    h = np.asarray(heights, dtype=np.float64)
    n = h.size
    if n < MIN_CURVES:
        raise BoundaryError(f"need at least {MIN_CURVES} curves, got {n}")
    d = np.diff(h)
    if not (np.all(d > 0) or np.all(d < 0)):
        raise BoundaryError("curve heights must be strictly monotonic")
    if (n - 1) % 3:
        return (h - h[0]) / (h[-1] - h[0])
    t = (n - 1) // 3
    knots = np.empty(n)
    for k in range(t):
        h0, h3 = h[3 * k], h[3 * k + 3]
        local = (h[3 * k:3 * k + 4] - h0) / (h3 - h0)
        knots[3 * k:3 * k + 4] = (k + local) / t
    knots[-1] = 1.0
    return knots


@dataclass
class BoundarySet:
    """3t+1 closed boundary curves in patient LPS mm: the PDE's boundary conditions.

    The paper's patches (``continuity="paper"``) need 3t+1 curves; the default C2
    surface takes any n >= 4 (an automatic selection for a tolerance picks any count).

    Parameters
    ----------
    curves : ndarray, shape (3t+1, M, 3)
        Closed curves (the last point is *not* a repeat of the first), ordered
        from inferior to superior, all with the same orientation and with
        sample 0 (v = 0) at the posterior midline; sample m sits at
        v = 2 pi m / M. ``meta["parameterisation"]`` says how the samples are
        spaced along each curve: ``"arc-length"`` (uniformly) or ``"aligned"``
        (equal v = corresponding points of neighbouring curves, see
        :func:`~.curve_alignment.align_parameterisation`); absent for
        synthetic sets, which are taken as given.
    slice_indices : ndarray of int, shape (3t+1,)
        The axial slice index in the source volume of each curve (-1 if synthetic).
    heights : ndarray, shape (3t+1,)
        Height of each curve along the head axis in mm (patient z).
    u_knots : ndarray, shape (3t+1,)
        Parameter u of each curve; see :func:`knots_from_heights`.
    meta : dict
        Provenance: source study, selection strategy, spacing, parameterisation, ...
    """

    curves: np.ndarray
    slice_indices: np.ndarray
    heights: np.ndarray
    u_knots: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.curves = np.asarray(self.curves, dtype=np.float64)
        if self.curves.ndim != 3 or self.curves.shape[2] != 3:
            raise BoundaryError(f"curves must have shape (3t+1, M, 3), got {self.curves.shape}")
        n = self.curves.shape[0]
        if n < MIN_CURVES:
            raise BoundaryError(f"need at least {MIN_CURVES} curves (3t+1 for the paper's patches), got {n}")
        if self.curves.shape[1] < 8:
            raise BoundaryError(f"each curve needs at least 8 samples, got {self.curves.shape[1]}")
        if not np.all(np.isfinite(self.curves)):
            raise BoundaryError("curves contain NaN or infinite coordinates")
        self.slice_indices = np.asarray(self.slice_indices, dtype=np.int64).reshape(n)
        self.heights = np.asarray(self.heights, dtype=np.float64).reshape(n)
        self.u_knots = np.asarray(self.u_knots, dtype=np.float64).reshape(n)
        self.meta = dict(self.meta)

    @property
    def patches(self) -> int:
        """Number t of PDE patches (3t+1 curves); for other counts :meth:`patches_for`."""
        return self.patches_for(self.curves.shape[0])

    @property
    def is_3t_plus_1(self) -> bool:
        """Whether the count is 3t+1 (what the paper's patches need)."""
        return (self.curves.shape[0] - 1) % 3 == 0

    @staticmethod
    def patches_for(n: int) -> int:
        """t for n = 3t+1 curves; otherwise the smallest t with 3t+1 >= n (the row densities
        that scale with t, e.g. ``8t+1`` rows, then still cover every span)."""
        return max(1, -(-(int(n) - 1) // 3))

    @property
    def samples(self) -> int:
        """Number M of samples per curve."""
        return self.curves.shape[1]
