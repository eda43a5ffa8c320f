"""Step 4: the Bloor-Wilson PDE surface (paper eq. 1-13), t patches along u: solving it.

The solved surface is a :class:`~.pde_head.PDEHead` (module :mod:`.pde_head`); the choice of the
paper patches' smoothing a is :mod:`.pde_smoothing`'s.

The head is ``t`` PDE patches stacked along u (paper section 4.1). Patch ``k``
covers the global ``u in [k/t, (k+1)/t]``; inside it a local parameter
``s in [0, 1]`` runs from curve ``3k`` to curve ``3k+3`` and the PDE

    (d^2/ds^2 + a^2 d^2/dv^2)^2 X(s, v) = 0                          (eq. 1)

is solved under the four positional conditions ``X(p_j, v) = P_j(v)`` at
``p = (0, p1, p2, 1)`` (eq. 3-6), with ``p1, p2`` taken from
``BoundarySet.u_knots`` (the curves' heights), not fixed thirds.

Method
------
Each curve is sampled at M points uniformly in v, so its trigonometric
interpolant has the harmonics ``h = 0 .. M//2``. Separation of variables
(eq. 7-10) turns eq. 1 into one ODE per harmonic ``h``,
``(d^2/ds^2 - k_h^2)^2 A_h(s) = 0`` with ``k_h = a*h``; its 4-dimensional
solution space is spanned by ``{e^{ks}, s e^{ks}, e^{-ks}, s e^{-ks}}``
(a cubic for ``h = 0``, eq. 8). The four positional conditions make the
coefficients the solution of a 4x4 interpolation system per harmonic.
Harmonics ``h <= N`` (``modes``) use their own exponent ``a*h``; the
remainder R of eq. 11-12, which carries the difference between the curves
and the truncated series F (eq. 13), uses the single exponent
``omega = a*(N+1)`` for all harmonics ``h > N``. R's functions r_1..r_4(v)
are determined at the M samples and continued between them by trigonometric
interpolation, so the surface passes exactly through every curve (every
harmonic is interpolated at all four knots).

Numerics: for small ``k`` the exponential basis degenerates (``e^{ks}`` and
``e^{-ks}`` both tend to 1), so a basis that tends to the cubic monomials in
``s - 1/2`` is used (``cosh x``, ``s sinhc x``, ``s^2 sinhc x``,
``s^3 psi(x)`` with ``x = k (s - 1/2)``); for larger ``k`` the rescaled
exponentials ``e^{k(s-1)}, s e^{k(s-1)}, e^{-ks}, s e^{-ks}`` (all <= 1 on
[0, 1]). The 4x4 condition numbers (1-norm) stay below ~2e2 in the stable range;
they are kept in ``PDEHead.condition``.

The choice of a, per patch, is :mod:`.pde_smoothing`'s (its docstring gives the measures).

Default N is M//2: all harmonics of the sampled curves carry their own
exponent, R is identically zero and X solves eq. 1 exactly. With N < M//2,
F (eq. 13) solves eq. 1 exactly and every harmonic h > N of R solves
``(d^2/ds^2 - omega^2)^2 R_h = 0`` instead (R is not a solution of eq. 1).

Correspondence of the curves
----------------------------
The PDE joins, for each v, the points ``P_j(v)`` of the four curves. With
curves sampled uniformly in arc length, a feature on one curve only (nose
tip, ear, nostril) shifts the arc length of everything after it and the
surface folds between the curves. :func:`extract_boundaries` therefore
returns, by default (``parameterisation="angular"``), curves sampled at the same
directions from a smooth spine on every curve; ``"aligned"`` re-samples arc-length
curves by :func:`align_parameterisation` (module :mod:`.parameterisation`: same
polylines, same seam, equal v = corresponding points; on CThead (t = 10) it
cuts the mean distance to the marching-cubes surface by about a third).
:func:`solve_pde` itself reproduces the curves it is given exactly
(``align=True`` aligns an arc-length set first).
"""
from __future__ import annotations

from functools import partial
from typing import Sequence

import numpy as np

from ..core.boundary_set import BoundarySet
from ..core.curve_alignment import align_parameterisation
from ..core.errors import PDEError
from .pde_basis import basis, curve_harmonics, inverse_4x4
from .pde_head import PDEHead, curve_positions, derived_once
from .pde_smoothing import (
    MAX_DEVIATION_MM,
    MAX_LEBESGUE_GROWTH,
    check_modes,
    local_knots,
    require_3t_plus_1,
    smoothing_bounds,
    smoothing_limits,
)
from .pde_spline import c2_spans, crown_low_pass, dome_height, smoothing_spline_values

#: The surface's continuity across the curves: the C2 spans (default) or the paper's four-curve patches.
CONTINUITIES = ("c2", "paper")
DEFAULT_CONTINUITY = "c2"
#: Default C2 smoothing a as a fraction of the head's isotropic a = height / radius.
DEFAULT_C2_SMOOTHING = 0.0
#: Default approximation length along u: this many axial slice steps of the scan (0.5, not 1: the
#: envelope's 3-D Gaussian already smooths the slice steps; one step takes the lips and the nose's
#: underside off the face) ...
APPROXIMATION_PER_SLICE = 0.5
#: ... but at most this many mean gaps between the chosen curves.
APPROXIMATION_PER_GAP = 0.5
#: ... and for thick or tilted series at least this many source slice thicknesses along z.
APPROXIMATION_PER_THICKNESS = 0.6
#: The approximation slider's top: this many mean gaps between the curves.
APPROXIMATION_MAX_PER_GAP = 1.5


# ----------------------------------------------------------------------------- solver


def _as_smoothing(smoothing, t: int | None) -> np.ndarray | None:
    """Smoothing as t finite values >= 0 (any 1-D length when t is None)."""
    if smoothing is None:
        return None
    try:
        a = np.asarray(smoothing, dtype=np.float64)
    except (TypeError, ValueError):
        raise PDEError(f"smoothing must be a number or {t} numbers, got {smoothing!r}") from None
    if a.ndim == 0:
        a = np.full(t or 1, float(a))
    if t is None and a.ndim == 1 and a.size >= 1:
        t = a.size
    if a.shape != (t,):
        raise PDEError(f"smoothing must be a number or {t} numbers (one per patch), got shape {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise PDEError(f"smoothing a must be finite and >= 0, got {a.tolist()}")
    return a


def solve_pde(bset: BoundarySet, smoothing: float | Sequence[float] | None = None,
              modes: int | None = None, align: bool = False, continuity: str | None = None,
              approximation_mm: float | None = None, dome: bool = True, remainder: bool = True) -> PDEHead:
    """Solve the Bloor-Wilson PDE surface through the boundary curves (eq. 1-13).

    Parameters
    ----------
    bset : BoundarySet
        3t+1 closed curves, sample m at v = 2 pi m / M (sample 0 = the seam), as
        :func:`extract_boundaries` returns them.
    smoothing : float or sequence of floats, optional
        The smoothing parameter a of eq. 1. ``"c2"``: one value in global u, in
        ``[0, max]`` (:func:`smoothing_range`); default ``DEFAULT_C2_SMOOTHING``
        of the range. ``"paper"``: a number or t numbers (local u of each patch);
        default ``min(H/r, a_stable)`` per patch (module docstring). Values above
        the maximum raise :class:`PDEError`.
    modes : int, optional
        N of eq. 11, in ``[1, M//2]``; default ``M//2`` (R vanishes).
    align : bool
        First re-sample the curves with :func:`align_parameterisation` (same
        polylines, corresponding v); ``head.bset`` is then the aligned set.
    continuity : {"c2", "paper"}, optional
        ``"c2"`` (default): one span per pair of consecutive curves with shared
        u-derivatives, C2 across every curve (:mod:`.pde_spline`). ``"paper"``:
        t patches through four position curves each (eq. 3-6), C0 at the joints.
    approximation_mm : float, optional
        ``"c2"`` only: smoothing length along the head axis (mm) of the
        approximating mode; 0 interpolates every curve exactly. Default:
        :func:`default_approximation` (from the curves' spacing and the scan's
        slice thickness and tilt).
    dome : bool
        ``"c2"`` only: close the crown with a smooth dome through a vertex above
        the top curve (else the surface ends at the top curve).
    remainder : bool
        Keep the remainder R of eq. 11-12 (harmonics above ``modes`` with the
        shared exponent ``omega = a (N+1)``): the surface passes through the curves.
        False drops them: X is the truncated series F of eq. 13, a low-pass around
        every ring (fewer modes: a simpler, smoother head; ``head.curve_deviation``
        says how far it leaves the curves).

    Returns
    -------
    PDEHead

    Raises
    ------
    PDEError
        Bad input (not a BoundarySet, inconsistent knots, out-of-range settings).
    """
    if not isinstance(bset, BoundarySet):
        raise PDEError(f"solve_pde needs a BoundarySet, got {type(bset).__name__}")
    continuity = DEFAULT_CONTINUITY if continuity is None else continuity
    if continuity not in CONTINUITIES:
        raise PDEError(f"continuity must be one of {list(CONTINUITIES)}, got {continuity!r}")
    if align:
        bset = align_parameterisation(bset)                                  # no-op if already aligned
    n_modes = check_modes(modes, bset.samples)
    keep = None if remainder else n_modes
    if continuity == "c2":
        head = _solve_c2(bset, smoothing, n_modes, approximation_mm, bool(dome), keep)
    else:
        if approximation_mm not in (None, 0, 0.0):
            raise PDEError("approximation_mm needs continuity='c2' (the paper's patches interpolate every curve)")
        head = _solve_paper(bset, smoothing, n_modes, keep)
    head.smoothing_is_default = smoothing is None
    head.remainder = bool(remainder)
    # what a bend-fitted mesh measures (PDEHead.bend_layout): these curves at the defaults, so its rows and
    # columns are one function of the curves whatever the sliders (a partial: the head stays picklable)
    head.reference_solve = partial(solve_pde, head.bset, dome=head.vertex is not None)
    return head




def default_approximation(bset: BoundarySet) -> float:
    """Default smoothing length (mm) along u of the approximating mode.

    ``APPROXIMATION_PER_SLICE`` times the scan's axial slice step, but not more than
    ``APPROXIMATION_PER_GAP`` times the mean gap between the chosen curves (few
    curves: keep what they say). Thick or tilted slices step from plane to plane by
    more than the resampled grid's step: there at least ``APPROXIMATION_PER_THICKNESS``
    times the source slices' thickness along z (``thickness / cos(tilt)``), up to one
    gap. The length is measured along the surface (:func:`curve_positions`).
    """
    meta = bset.meta
    spacing = meta.get("source_slice_step_mm") or (meta.get("spacing") or [0.0])[0]
    gaps = np.abs(np.diff(bset.heights))
    gap = float(gaps.mean()) if gaps.size else 0.0
    value = min(APPROXIMATION_PER_SLICE * float(spacing or 0.0), APPROXIMATION_PER_GAP * gap)
    thickness = float(meta.get("source_slice_thickness_mm") or 0.0)
    if thickness > 0:
        tilt = np.radians(float(meta.get("gantry_tilt_deg") or 0.0))
        value = max(value, min(APPROXIMATION_PER_THICKNESS * thickness / max(np.cos(tilt), 0.1), gap))
    return float(max(0.0, value))


def smoothing_range(bset: BoundarySet) -> tuple[float, float]:
    """``(default, maximum)`` of the C2 smoothing parameter a for this head.

    The isotropic value ``a_iso = Z / r`` (height Z of the head over its mean
    radius r: equal physical rates along u and v, the biharmonic in arc length) is
    the top of the range; the default is ``DEFAULT_C2_SMOOTHING * a_iso``. A
    normalised slider ``f in [0, 1]`` maps to ``a = f * maximum``.
    """
    c = bset.curves
    r = derived_once(bset, "radius", lambda: float(np.linalg.norm(c - c.mean(axis=1, keepdims=True), axis=2).mean()))
    z = float(np.ptp(bset.heights)) or 1.0
    a_iso = z / r if r > 0 else 0.0
    return DEFAULT_C2_SMOOTHING * a_iso, a_iso




def _harmonics(bset: BoundarySet, keep: int | None) -> tuple[np.ndarray, bool]:
    """The curves' harmonics (a fresh copy); with ``keep`` only h <= keep (eq. 13's truncated series, no R)."""
    spec, planar = derived_once(bset, "harmonics", lambda: curve_harmonics(bset.curves))
    spec = spec.copy()
    if keep is not None:
        spec[:, keep + 1:] = 0.0
    return spec, planar


def control_ranges(bset: BoundarySet, continuity: str | None = None, modes: int | None = None) -> dict:
    """The study's valid ranges of the user controls, for normalised 0-1 sliders.

    Returns
    -------
    dict
        ``"smoothing"``: ``(default, maximum)`` of a (floats for ``"c2"``, per-patch
        arrays for ``"paper"``, from :func:`smoothing_bounds`); ``"approximation_mm"``:
        ``(default, maximum)`` of the approximation length (``"c2"``; ``(0, 0)`` for
        ``"paper"``). Every value in ``[0, maximum]`` solves (no refused values).
    """
    continuity = DEFAULT_CONTINUITY if continuity is None else continuity
    if continuity == "paper":
        return {"smoothing": smoothing_bounds(bset, modes), "approximation_mm": (0.0, 0.0)}
    gaps = np.abs(np.diff(bset.heights))
    return {"smoothing": smoothing_range(bset),
            "approximation_mm": (default_approximation(bset),
                                 APPROXIMATION_MAX_PER_GAP * float(gaps.mean() if gaps.size else 0.0))}


def solve_with_controls(bset: BoundarySet, continuity: str | None = None, smoothing: float | None = None,
                        approximation: float | None = None, modes: int | None = None,
                        dome: bool = True) -> PDEHead:
    """:func:`solve_pde` from normalised controls (what the add-on's sliders hold).

    Parameters
    ----------
    smoothing, approximation : float in [0, 1] or None
        Fractions of :func:`control_ranges`' maxima; None: the solver's defaults.
    modes : int or None
        None or 0: every harmonic (the curves are passed exactly); N > 0: the
        truncated series of eq. 13 with N modes (``remainder=False``), a visibly
        simpler head.
    """
    continuity = DEFAULT_CONTINUITY if continuity is None else continuity
    for name, f in (("smoothing", smoothing), ("approximation", approximation)):
        if f is not None and not (np.isfinite(f) and 0.0 <= f <= 1.0):
            raise PDEError(f"{name} must be a fraction in [0, 1], got {f!r}")
    n = None if not modes else int(modes)
    if n is not None:
        n = min(n, bset.samples // 2)
    ranges = control_ranges(bset, continuity, n)
    a = None if smoothing is None else np.asarray(ranges["smoothing"][1]) * float(smoothing)
    kwargs = dict(smoothing=a, modes=n, continuity=continuity, remainder=n is None)
    if continuity == "c2":
        kwargs.update(dome=dome, approximation_mm=None if approximation is None
                      else float(approximation) * ranges["approximation_mm"][1])
    return solve_pde(bset, **kwargs)


def _solve_c2(bset: BoundarySet, smoothing, n_modes: int, approximation_mm, dome: bool,
              keep: int | None = None) -> PDEHead:
    spec, planar = _harmonics(bset, keep)                                     # (m, H, 3)
    z = curve_positions(bset)
    default_a, max_a = smoothing_range(bset)
    if smoothing is None:
        a = default_a
    else:
        arr = _as_smoothing(smoothing, None)
        if arr.size != 1 and np.ptp(arr) > 0:
            raise PDEError("continuity='c2' takes one smoothing value for the whole head, "
                           f"got {arr.size} different values")
        a = float(arr.ravel()[0])
        if a > max_a * (1 + 1e-9):
            raise PDEError(f"smoothing a={a:.4g} is above this head's maximum {max_a:.4g} (the isotropic "
                           "height/radius ratio); use a value in [0, that] or the normalised slider")
    L = default_approximation(bset) if approximation_mm is None else approximation_mm
    if not (np.isfinite(L) and L >= 0):
        raise PDEError(f"approximation_mm must be a length >= 0 (mm), got {approximation_mm!r}")
    if L > 0:
        exact_z = spec[:, 0, 2].copy()
        spec = smoothing_spline_values(z, spec, float(L))
        if planar:                                                            # z stays exact per curve
            spec[:, 0, 2] = exact_z
            spec[:, 1:, 2] = 0.0
    vertex = None
    top = z[-1]
    if dome:
        zt = float(bset.curves[-1, :, 2].mean())
        height = dome_height(bset.curves, bset.heights, bset.meta.get("vertex_z"))
        if L > 0:                                     # approximating the curves: the crown's too
            spec = crown_low_pass(bset.curves, bset.heights, spec, height)
        sign = 1.0 if bset.heights[-1] >= bset.heights[0] else -1.0
        vertex = np.array([spec[-1, 0, 0].real, spec[-1, 0, 1].real, zt + sign * height])
        top = z[-1] + float(np.linalg.norm(bset.curves[-1] - vertex, axis=1).mean())
    knots = np.concatenate([z, [top]]) if dome else z
    u = (knots - knots[0]) / (knots[-1] - knots[0])
    exponents, coefficients = c2_spans(spec, u, a, n_modes, pole=vertex)
    if not np.all(np.isfinite(coefficients)):
        raise PDEError("the PDE solution is not finite (degenerate boundary curves or knots?)")
    condition = np.ones(coefficients.shape[0])
    return PDEHead(bset, np.array([a]), n_modes, None, exponents, coefficients, condition, planar,
                   span_edges=u, curve_u=u[:len(z)], continuity="c2", approximation_mm=float(L), vertex=vertex)


def _solve_paper(bset: BoundarySet, smoothing, n_modes: int, keep: int | None = None) -> PDEHead:
    require_3t_plus_1(bset)
    t = bset.patches
    local = local_knots(bset)
    spec, planar = _harmonics(bset, keep)                                     # (3t+1, H, 3)
    a = _as_smoothing(smoothing, t)
    if a is None:
        a, _ = smoothing_limits(bset, n_modes, local, spec, want_max=False)
    else:
        _, maximum = smoothing_limits(bset, n_modes, local, spec, want_default=False)
        over = np.nonzero(a > maximum * (1 + 1e-9))[0]
        if over.size:
            k = int(over[0])
            raise PDEError(
                f"smoothing a={a[k]:.4g} is too large for patch {k} with N={n_modes} modes: the surface "
                f"would bulge between the curves (interpolation growth > {MAX_LEBESGUE_GROWTH:g}x the cubic "
                f"one or a departure > {MAX_DEVIATION_MM:g} mm from the a = 0 surface); the maximum there "
                f"is {maximum[k]:.4g}. Lower the smoothing or change the number of modes.")
    H = spec.shape[1]
    h = np.arange(H, dtype=np.float64)
    exponents = a[:, None] * np.minimum(h, n_modes + 1)[None, :]              # R: omega = a (N+1)
    # patches with the same knots and smoothing share their 4x4 systems (uniform slice selections)
    _, first, which = np.unique(np.round(np.column_stack([local, a]), 12), axis=0, return_index=True,
                                return_inverse=True)
    G = basis(exponents[first][:, :, None], local[first][:, None, :])       # (types, H, 4 nodes, 4 basis)
    G_inv = inverse_4x4(G)[which.ravel()]
    G = G[which.ravel()]
    # rhs: the node curves' harmonics, (t, H, 4 nodes, 3)
    rhs = np.stack([spec[3 * k:3 * k + 4] for k in range(t)]).transpose(0, 2, 1, 3)
    coefficients = np.matmul(G_inv, rhs.real) + 1j * np.matmul(G_inv, rhs.imag)
    norm1 = lambda m: np.abs(m).sum(axis=-2).max(axis=-1)                    # noqa: E731 (1-norm)
    condition = (norm1(G) * norm1(G_inv)).max(axis=1)
    if not (np.all(np.isfinite(coefficients)) and np.all(np.isfinite(condition))):
        raise PDEError("the PDE solution is not finite (degenerate boundary curves or knots?)")
    return PDEHead(bset, a, n_modes, local, exponents, coefficients, condition, planar,
                   span_edges=np.arange(t + 1) / t, curve_u=bset.u_knots, continuity="paper")
