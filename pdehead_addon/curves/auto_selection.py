"""The automatic slice selection, ``"auto"``: the boundary curves whose PDE surface best follows every
slice (paper sections 4.1 and 6).

The paper picks the 3t+1 slices of section 4.1 by hand and leaves "an automatic
scheme enabling intelligent selection of the medical slice images for PDE
boundary extraction" open (section 6). Every usable slice of the scan has an
outline, so the error of a surface at the slices it was *not* built from is
measurable; this module chooses the curves that minimise it.

Candidates
    The outlines of all usable slices, traced exactly as the chosen ones are
    (same 3-D envelope, same star hulls, angular samples around ONE spine
    through all of them, :func:`~.curve_sampling.angular_curves`): the chosen
    curves are a subset of the candidates, unchanged.

Proxy of the surface (fast, vectorised)
    The default surface (:func:`~.pde_surface.solve_pde`, ``continuity="c2"``,
    a = 0) is, per harmonic and hence per sample point, the natural cubic spline
    through the chosen curves over their chord-length positions
    (``curve_positions``: cumulative mean distance of equal-v points), after the
    Reinsch smoothing of length :func:`~.pde_surface.default_approximation`
    along it, closed by the crown's pole (:func:`~.pde_spline.dome_height`). The
    proxy builds exactly that spline as a matrix in point space (the pole's
    derivative clamps of the real solver are left out) and evaluates it at
    every candidate slice, placed between its chosen neighbours by the
    candidates' own chord length. A slice's error is the mean over its samples
    of ``|(X(u_k, v) - C_k(v)) . n_k(v)|``, the offset along the normal ``n_k``
    of the tube through all candidates (first-order point-to-surface distance).

Search
    The two end candidates (bottom and top usable slice) are always chosen, so
    the covered height does not change. Greedy insertion adds the candidate
    with the largest error until n are chosen; then exchange passes move every
    interior choice to nearby candidates (between its neighbours) while the
    total error drops, and relocations move one to the worst slice elsewhere; the
    same refinement also starts from the uniform choice, and the better of the two
    wins. For a tolerance (:func:`select_for_tolerance`) the count
    is searched on the proxy (bisection over n) and verified on the real surface.

    Measured, not adopted (the closed eyes; CThead, t = 15, visible-face score mean / p95
    mm, now 0.243 / 0.76): the face's samples (+-60 deg of -y) weighted 3x in the search's error
    0.237 / 0.74, 6x or more 0.251 / 0.81 (the curves spread over the whole face, 4-6 mm apart at the
    eyes either way); squared offsets 0.236 / 0.74. Marching cubes' eyelid line is the upper lid's
    edge: the mask's outline steps out 1.5-3 mm between two neighbouring slices (z 132 -> 134, 20-30
    deg left of straight ahead), a one-slice feature; marching cubes of the mask smoothed by 1.2 mm
    shows it too. Renders (Cycles, front and three-quarter, looked at) of the PDE surface show it
    only with every slice chosen there (124-136, four cranium curves given up) AND no u smoothing AND
    a 1.5 mm closing ball with a 0.6 mm envelope Gaussian, no curve low-pass (0.250 / 0.84: p95 over
    its target). Left a soft socket: that with the default u smoothing (0.259 / 0.89), or with the
    default envelope (0.232 / 0.71), or with the automatic slices (0.248 / 0.79); every slice there
    alone 0.248 / 0.81, no curve low-pass alone 0.237 / 0.74. No choice of slices brings it alone.

Real error
    :func:`surface_error` solves the real surface through a chosen set and
    measures the distance (:func:`~.surface_metrics.point_surface_distance`) of
    every candidate curve's samples to its mesh: the "mean / max distance from
    the outlines" that the tolerance is about and that ``bset.meta`` records.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..core.errors import BoundaryError
from ..core.mesh_geometry import mesh_triangles, point_surface_distance
from ..pde.pde_basis import small_matmul
from ..pde.pde_spline import dome_height, natural_spline_matrix, smoothing_spline_values
from ..pde.pde_surface import default_approximation, solve_pde

#: Angular samples per curve that the proxy uses (every k-th of the curves' M): the mean over them
#: tracks the mean over all M (a slice's error varies smoothly around it).
PROXY_ANGLES = 64
#: How far (in candidates) an exchange step moves one chosen curve.
EXCHANGE_REACH = 3
#: Upper bound on exchange passes (each pass tries every interior choice once).
EXCHANGE_PASSES = 6
#: Rows per candidate gap of the mesh the real error is measured on (the surface between two slices).
REAL_ROWS_PER_GAP = 3
#: Surface samples of that mesh's distance query (:func:`~.surface_metrics.point_surface_distance`).
REAL_DENSE_SAMPLES = 200_000
#: Default tolerance (mm) on the mean distance of the surface from every slice's outline.
DEFAULT_TOLERANCE_MM = 0.5
#: At most this many candidate slices (or twice the curves asked for) are traced: thin-slice scans
#: (300 slices of 0.7 mm) keep every ~2nd slice, still under 2 mm apart, instead of tracing all
#: (8.8 s for the boundaries of a 512 x 512 x 300 scan with every slice, measured).
MAX_CANDIDATES = 128


def thin_candidates(indices: np.ndarray, n_curves: int = 0, most: int = MAX_CANDIDATES) -> np.ndarray:
    """Evenly spread subset (ends kept) of the usable slice ``indices`` when there are more than
    ``max(most, 2 n_curves)``; else ``indices`` unchanged."""
    indices = np.asarray(indices)
    keep = max(int(most), 2 * int(n_curves))
    if len(indices) <= keep:
        return indices
    return indices[np.unique(np.round(np.linspace(0, len(indices) - 1, keep)).astype(int))]


class SelectionWarning(UserWarning):
    """A tolerance could not be met: the result uses every usable slice (the achieved error is named)."""


@dataclass
class Candidates:
    """Every usable slice's boundary curve, around one spine: what the automatic selection chooses from.

    Attributes
    ----------
    slices : ndarray of int, shape (N,)
        Slice index of each candidate, sorted inferior -> superior.
    curves : ndarray, shape (N, M, 3)
        The candidates' angular curves (LPS mm), as :func:`~.curve_sampling.angular_curves` makes them.
    meta : dict
        What the real solver's defaults read from a boundary set (``source_slice_step_mm``,
        ``spacing``, ``source_slice_thickness_mm``, ``gantry_tilt_deg``, ``vertex_z``).
    """

    slices: np.ndarray
    curves: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.slices = np.asarray(self.slices, np.int64)
        self.curves = np.asarray(self.curves, np.float64)
        if self.curves.ndim != 3 or self.curves.shape[0] != self.slices.size or self.curves.shape[2] != 3:
            raise BoundaryError(f"candidates: curves {self.curves.shape} do not match {self.slices.size} slices")
        if self.slices.size < 2:
            raise BoundaryError("automatic selection needs at least 2 usable slices")
        step = max(1, self.curves.shape[1] // PROXY_ANGLES)
        sub = self.curves[:, ::step]
        self.sub = sub                                                   # (N, m, 3) proxy samples
        self.heights = self.curves[:, :, 2].mean(axis=1)
        # chord length between neighbouring candidates (the solver's positions, on all slices)
        gap = np.linalg.norm(np.diff(sub, axis=0), axis=2).mean(axis=1)
        self.chord = np.concatenate([[0.0], np.cumsum(np.maximum(gap, 1e-6))])
        # unit normals of the tube through all candidates: dX/dv x dX/du (either sign; |.| is used)
        dv = np.roll(sub, -1, axis=1) - np.roll(sub, 1, axis=1)
        du = np.gradient(sub, self.chord, axis=0) if len(sub) > 1 else np.zeros_like(sub)
        n = np.cross(dv, du)
        self.normals = n / np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-12)
        # the proxy works on planar rows (x of every sample, then y, then z): each coordinate's plane of
        # a prediction is a contiguous block, and the samples' own offset along the normal is computed once
        self.planar = np.ascontiguousarray(sub.transpose(0, 2, 1)).reshape(len(sub), -1)     # (N, 3m)
        self.planar_normals = np.ascontiguousarray(self.normals.transpose(2, 0, 1))         # (3, N, m)
        self.sample_offsets = np.einsum("kmc,kmc->km", sub, self.normals)                   # (N, m)

    @property
    def count(self) -> int:
        return int(self.slices.size)

    def pair_gaps(self) -> np.ndarray:
        """(N, N): the mean distance of equal-v proxy samples between candidates a < b (upper triangle).

        The proxy's chord positions of every chosen set, read off one table (computed once per
        candidate set, row by row: the same numbers as the differences of each set's curves).
        """
        table = self.__dict__.get("_pair_gaps")
        if table is None:
            sub, N = self.sub, self.count
            table = np.zeros((N, N))
            for a in range(N - 1):       # a loop over the ~100 candidates, each row one vectorised step
                table[a, a + 1:] = np.linalg.norm(sub[a + 1:] - sub[a], axis=2).mean(axis=1)
            self.__dict__["_pair_gaps"] = table
        return table


def attach_candidates(bset, cand: Candidates) -> None:
    """Keep the candidates with the boundary set they were chosen from (not stored in files)."""
    bset.__dict__["_selection_candidates"] = cand


def candidates_of(bset) -> Candidates | None:
    """The :class:`Candidates` an automatic selection chose ``bset`` from (None otherwise, or after loading)."""
    return bset.__dict__.get("_selection_candidates")


# --------------------------------------------------------------------------- the proxy surface
def _approximation(cand: Candidates, heights: np.ndarray) -> float:
    """The real solver's default smoothing length for curves at ``heights`` (its own function)."""
    return default_approximation(SimpleNamespace(meta=cand.meta, heights=heights))


def proxy_errors(cand: Candidates, chosen: np.ndarray, dome: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Per-candidate error of the proxy surface through the candidates ``chosen`` (sorted positions).

    Returns
    -------
    mean : ndarray, shape (N,)
        Mean normal offset (mm) of each candidate's samples from the proxy surface.
    peak : ndarray, shape (N,)
        Largest offset per candidate.
    """
    idx = np.asarray(chosen, np.int64)
    # the searches come back to sets they tried before (~11 % of the calls on a 128-candidate scan)
    key = (idx.tobytes(), bool(dome))
    memo = cand.__dict__.setdefault("_proxy_memo", {})
    if key not in memo:
        memo[key] = _proxy_errors(cand, idx, dome)
    mean, peak = memo[key]
    return mean.copy(), peak.copy()


def _proxy_errors(cand: Candidates, idx: np.ndarray, dome: bool) -> tuple[np.ndarray, np.ndarray]:
    n, m = idx.size, cand.sub.shape[1]
    gap = cand.pair_gaps()[idx[:-1], idx[1:]]
    pos = np.concatenate([[0.0], np.cumsum(np.maximum(gap, 1e-6))])
    L = _approximation(cand, cand.heights[idx])
    Ys = cand.planar[idx]                                                # (n, 3m): x, y, z planes
    if L > 0 and n >= 3:
        Ys = smoothing_spline_values(pos, Ys, float(L))
    knots, data = pos, Ys
    if dome:
        top = cand.curves[idx[-1]]
        zt = float(top[:, 2].mean())
        # dome_height reads the top three curves only (their areas): the same height, 10x less work;
        # the searches keep the top three for most of their sets (one height per top three)
        domes = cand.__dict__.setdefault("_dome_memo", {})
        top3 = idx[-3:].tobytes()
        if top3 not in domes:
            domes[top3] = dome_height(cand.curves[idx[-3:]], cand.heights[idx[-3:]], cand.meta.get("vertex_z"))
        height = domes[top3]
        sign = 1.0 if cand.heights[-1] >= cand.heights[0] else -1.0
        vertex = np.array([Ys[-1, :m].mean(), Ys[-1, m:2 * m].mean(), zt + sign * height])
        tip = pos[-1] + float(np.linalg.norm(top - vertex, axis=1).mean())
        knots = np.concatenate([pos, [tip]])
        data = np.concatenate([Ys, np.repeat(vertex, m)[None]])
    # each candidate's position: between its chosen neighbours, by the candidates' own chord length
    j = np.clip(np.searchsorted(idx, np.arange(cand.count), side="right") - 1, 0, n - 2)
    f0, f1 = cand.chord[idx[j]], cand.chord[idx[j + 1]]
    s = pos[j] + (cand.chord - f0) / (f1 - f0) * (pos[j + 1] - pos[j])
    # in column blocks that stay single-threaded in BLAS (OpenBLAS's threads made this 128 x 32 by 32 x 192
    # product 4-5 x slower on 2 busy cores)
    pred = small_matmul(natural_spline_matrix(knots, s), data)          # (N, 3m)
    nx, ny, nz = cand.planar_normals
    off = pred[:, :m] * nx
    off += pred[:, m:2 * m] * ny
    off += pred[:, 2 * m:] * nz
    off -= cand.sample_offsets
    np.abs(off, out=off)
    return off.mean(axis=1), off.max(axis=1)


def _total(cand: Candidates, chosen: np.ndarray) -> float:
    return float(proxy_errors(cand, chosen)[0].sum())


# --------------------------------------------------------------------------- search
def greedy_sequence(cand: Candidates, n_max: int) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Greedy insertion from the two end candidates.

    Returns
    -------
    sets : list of ndarray
        ``sets[i]`` is the chosen set of ``i + 2`` curves (each the previous one plus its worst slice).
    mean, peak : ndarray
        The proxy's mean error over all candidates and its largest offset, per set.
    """
    N = cand.count
    chosen = np.array([0, N - 1], np.int64)
    sets, means, peaks = [], [], []
    while True:
        err, peak = proxy_errors(cand, chosen)
        sets.append(chosen)
        means.append(float(err.mean()))
        peaks.append(float(peak.max()))
        if chosen.size >= min(n_max, N):
            break
        err[chosen] = -np.inf
        chosen = np.sort(np.append(chosen, int(np.argmax(err))))
    return sets, np.array(means), np.array(peaks)


def exchange(cand: Candidates, chosen: np.ndarray, reach: int = EXCHANGE_REACH,
             passes: int = EXCHANGE_PASSES) -> tuple[np.ndarray, float]:
    """Move interior choices to nearby candidates (between their neighbours) while the total error drops.

    Each choice tries one step up and one step down and keeps walking (up to ``reach``
    steps) in the direction that helps: about three proxy evaluations per curve and pass.
    """
    chosen = np.array(chosen, np.int64)
    best = _total(cand, chosen)
    for _ in range(passes):
        improved = False
        for p in range(1, chosen.size - 1):
            for step in (1, -1):
                moved = False
                for _k in range(reach):
                    k = chosen[p] + step
                    if not chosen[p - 1] < k < chosen[p + 1]:
                        break
                    trial = chosen.copy()
                    trial[p] = k
                    e = _total(cand, trial)
                    if e >= best - 1e-9:
                        break
                    chosen, best, moved, improved = trial, e, True, True
                if moved:
                    break
        if not improved:
            break
    return chosen, best


def relocate(cand: Candidates, chosen: np.ndarray) -> tuple[np.ndarray, float]:
    """Non-local moves: drop one interior choice and insert the worst slice of the rest instead, if better.

    Exchange only moves a curve between its neighbours; a curve that is worth more at
    the other end of the head (the face against the smooth cranium) gets there this way.
    """
    chosen = np.array(chosen, np.int64)
    best = _total(cand, chosen)
    p = 1
    while p < chosen.size - 1:
        reduced = np.delete(chosen, p)
        err, _ = proxy_errors(cand, reduced)
        err[reduced] = -np.inf
        trial = np.sort(np.append(reduced, int(np.argmax(err))))
        e = _total(cand, trial)
        if e < best - 1e-9 and not np.array_equal(trial, chosen):
            chosen, best = trial, e
        p += 1
    return chosen, best


def _uniform_start(cand: Candidates, n: int) -> np.ndarray:
    """n candidates evenly spaced in height (the paper's choice), both ends included."""
    h = cand.heights
    N, ramp = cand.count, np.arange(n)
    near = np.clip(np.searchsorted(h, np.linspace(h[0], h[-1], n)), 1, N - 1)
    near -= (np.abs(h[near - 1] - np.linspace(h[0], h[-1], n)) < np.abs(h[near] - np.linspace(h[0], h[-1], n)))
    # strictly increasing with both ends kept: push up from the bottom, then down from the top
    idx = np.maximum.accumulate(np.maximum(near, 0) - ramp) + ramp
    idx = (np.minimum.accumulate((np.minimum(idx, N - 1) - ramp - (N - n))[::-1]))[::-1] + ramp + (N - n)
    idx[0], idx[-1] = 0, N - 1
    return idx.astype(np.int64)


def refine(cand: Candidates, chosen: np.ndarray, rounds: int = 1) -> tuple[np.ndarray, float]:
    """Exchange passes, then relocations and exchange again while they help (at most ``rounds`` times)."""
    chosen, best = exchange(cand, chosen)
    for _ in range(rounds):
        moved, e = relocate(cand, chosen)
        if e >= best - 1e-9:
            break
        chosen, best = exchange(cand, moved)
    return chosen, best


def select_curves(cand: Candidates, n: int, starts: tuple[str, ...] = ("greedy", "uniform")) -> np.ndarray:
    """The n candidates (positions, sorted, both ends included) whose proxy surface best follows all slices.

    Each start (greedy insertion of the worst slice; the uniform choice) is refined by
    :func:`refine`; the set with the lowest total proxy error wins. Measured (proxy mean over
    all slices, phantom t = 10): uniform 0.115 mm, greedy + exchange 0.118, uniform + exchange
    0.107: neither start alone is best everywhere.
    """
    n = int(n)
    if n < 2:
        raise BoundaryError(f"automatic selection needs at least 2 curves, got {n}")
    if n > cand.count:
        raise BoundaryError(f"only {cand.count} slices have a usable head cross-section, but {n} curves "
                            "are asked for")
    if n == cand.count:
        return np.arange(cand.count)
    best, best_e = None, np.inf
    for start in starts:
        first = greedy_sequence(cand, n)[0][-1] if start == "greedy" else _uniform_start(cand, n)
        chosen, e = refine(cand, first)
        if e < best_e:
            best, best_e = chosen, e
    return best


# --------------------------------------------------------------------------- the real surface's error
def surface_error(bset, cand: Candidates, head=None) -> dict[str, Any]:
    """Distance of every candidate's curve samples to the real default surface through ``bset``.

    Parameters
    ----------
    bset : BoundarySet
        A subset of the candidates' curves.
    cand : Candidates
    head : PDEHead, optional
        The solved surface (default: :func:`~.pde_surface.solve_pde` with its defaults).

    Returns
    -------
    dict
        ``mean_mm`` (over every sample of every usable slice), ``max_mm``, ``p95_mm`` and
        ``per_slice_mm`` (mean per candidate slice).
    """
    head = solve_pde(bset) if head is None else head
    nu = max(8, REAL_ROWS_PER_GAP * cand.count + 2)
    mesh = head.surface(nu, cand.curves.shape[1], uv=False)      # measured only: no UV map per candidate
    verts, tris = mesh_triangles(mesh)
    pts = cand.curves.reshape(-1, 3)
    d = point_surface_distance(pts, verts, tris, dense=REAL_DENSE_SAMPLES).reshape(cand.count, -1)
    return dict(mean_mm=float(d.mean()), max_mm=float(d.max()), p95_mm=float(np.percentile(d, 95)),
                per_slice_mm=d.mean(axis=1))


def selection_record(err: dict, n: int, tolerance_mm=None, max_tolerance_mm=None, met=None,
                     candidates: int | None = None) -> dict[str, Any]:
    """The ``bset.meta`` entries of an automatic selection (JSON-safe; see the module docstring)."""
    rec = dict(selection_curves=int(n), selection_candidates=None if candidates is None else int(candidates),
               selection_mean_mm=round(float(err["mean_mm"]), 4), selection_max_mm=round(float(err["max_mm"]), 4),
               selection_p95_mm=round(float(err["p95_mm"]), 4),
               selection_tolerance_mm=None if tolerance_mm is None else float(tolerance_mm),
               selection_max_tolerance_mm=None if max_tolerance_mm is None else float(max_tolerance_mm),
               selection_tolerance_met=met)
    return rec


def _meets(err: dict, tol: float | None, max_tol: float | None) -> bool:
    return (tol is None or err["mean_mm"] <= tol) and (max_tol is None or err["max_mm"] <= max_tol)


def select_for_tolerance(cand: Candidates, make_bset, tolerance_mm: float | None = DEFAULT_TOLERANCE_MM,
                         max_tolerance_mm: float | None = None, min_curves: int = 4):
    """The fewest curves whose real surface keeps within the tolerance of every slice's outline.

    Parameters
    ----------
    cand : Candidates
    make_bset : callable
        ``make_bset(positions) -> BoundarySet`` of the chosen candidates (the caller's meta).
    tolerance_mm : float or None
        Bound on the mean distance (mm) of the real surface from all candidates' curves.
    max_tolerance_mm : float or None
        Bound on the largest such distance.
    min_curves : int
        Fewest curves tried (4: the smallest boundary set).

    Returns
    -------
    positions : ndarray of int
        Chosen candidate positions.
    bset : BoundarySet
    err : dict
        :func:`surface_error` of that set.
    met : bool
        False when even every usable slice does not meet the tolerance (a
        :class:`SelectionWarning` names the achieved error).

    Notes
    -----
    Greedy insertion gives nested sets of every count with their proxy errors in
    one sweep; the first count the proxy accepts is lowered while exchange finds
    a set of one curve fewer that the proxy accepts; the real surface then
    decides: counts are raised until the real surface meets the tolerance and
    lowered while a count one less still does, so the count returned is the
    fewest for which the search's choice passes on the real surface (n - 1
    verified to fail, unless n is ``min_curves``).
    """
    for name, value in (("tolerance_mm", tolerance_mm), ("max_tolerance_mm", max_tolerance_mm)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise BoundaryError(f"{name} must be a distance > 0 (mm), got {value!r}")
    if tolerance_mm is None and max_tolerance_mm is None:
        raise BoundaryError("select_for_tolerance needs tolerance_mm or max_tolerance_mm")
    N = cand.count
    lo_n = min(max(int(min_curves), 2), N)
    sets, g_mean, g_peak = greedy_sequence(cand, N)                      # nested greedy sets, 2 .. N curves
    cache: dict[int, tuple[np.ndarray, float, float]] = {}

    def proxy_at(n: int):
        if n not in cache:
            pos = np.arange(N) if n >= N else select_curves(cand, n)
            mean, peak = proxy_errors(cand, pos)
            cache[n] = (pos, float(mean.mean()), float(peak.max()))
        return cache[n]

    def proxy_ok(n: int) -> bool:
        _, mean, peak = proxy_at(n)
        return _meets({"mean_mm": mean, "max_mm": peak}, tolerance_mm, max_tolerance_mm)

    # the greedy sets' errors come with the sequence: the first count they accept bounds the answer;
    # exchange (which only lowers the error) then tries fewer curves while the proxy still accepts them
    ok = [_meets({"mean_mm": m, "max_mm": p}, tolerance_mm, max_tolerance_mm) for m, p in zip(g_mean, g_peak)]
    first = next((i + 2 for i, good in enumerate(ok) if good and i + 2 >= lo_n), N)
    n = first
    while n > lo_n and proxy_ok(n - 1):
        n -= 1
    real: dict[int, tuple[np.ndarray, Any, dict]] = {}

    def real_at(k: int):
        if k not in real:
            pos = proxy_at(k)[0]
            bs = make_bset(pos)
            real[k] = (pos, bs, surface_error(bs, cand))
        return real[k]

    while n < N and not _meets(real_at(n)[2], tolerance_mm, max_tolerance_mm):
        # step by the proxy's view of how far off the real error is (at least one curve)
        n = min(N, n + max(1, int(np.ceil(0.1 * n))))
    if n >= N and not _meets(real_at(N)[2], tolerance_mm, max_tolerance_mm):
        pos, bs, err = real_at(N)
        warnings.warn(f"tolerance not reachable: even all {N} usable slices give a surface at mean "
                      f"{err['mean_mm']:.3f} mm / max {err['max_mm']:.3f} mm from the slices' outlines "
                      f"(asked: mean <= {tolerance_mm} mm, max <= {max_tolerance_mm} mm); using all of them",
                      SelectionWarning, stacklevel=3)
        return pos, bs, err, False
    while n > lo_n and _meets(real_at(n - 1)[2], tolerance_mm, max_tolerance_mm):
        n -= 1
    pos, bs, err = real_at(n)
    return pos, bs, err, True
