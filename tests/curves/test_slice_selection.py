"""Automatic slice selection (issue 14): selection="auto" and the tolerance path, on the phantom and CThead."""
from __future__ import annotations

import numpy as np
import pytest

import pdehead_addon as E
from pdehead_addon.core.errors import BoundaryError, PDEError
from pdehead_addon.curves import auto_selection as S


def _positions(cand, bset):
    return np.array([int(np.flatnonzero(cand.slices == k)[0]) for k in bset.slice_indices])


def _on_candidates(cand, pos, meta):
    """The set of the candidates at ``pos`` (same spine as the automatic set): a like-for-like comparison."""
    h = cand.heights[pos]
    return E.BoundarySet(cand.curves[pos], cand.slices[pos], h, E.knots_from_heights(h), dict(meta))


@pytest.fixture(scope="module")
def phantom_auto(phantom_seg):
    return {t: E.extract_boundaries(phantom_seg, patches=t, selection="auto") for t in (3, 5)}


@pytest.mark.parametrize("t", [3, 5])
def test_auto_beats_uniform_on_all_outlines_phantom(phantom_seg, phantom_auto, t):
    auto = phantom_auto[t]
    cand = S.candidates_of(auto)
    n = 3 * t + 1
    assert auto.curves.shape[0] == n and auto.meta["selection"] == "auto"
    idx = auto.slice_indices
    assert np.unique(idx).size == n and np.all(np.diff(cand.heights[_positions(cand, auto)]) > 0)
    # the end slices (lowest and highest usable) are always kept: the covered height is unchanged
    assert idx[0] == cand.slices[0] and idx[-1] == cand.slices[-1]
    uniform = E.extract_boundaries(phantom_seg, patches=t, selection="uniform")
    assert uniform.slice_indices[0] == idx[0] and uniform.slice_indices[-1] == idx[-1]
    e_uni = S.surface_error(_on_candidates(cand, _positions(cand, uniform), auto.meta), cand)["mean_mm"]
    e_auto = auto.meta["selection_mean_mm"]
    assert e_auto <= 0.97 * e_uni, (e_auto, e_uni)
    # the recorded error is that of the real surface through the chosen curves
    assert abs(S.surface_error(auto, cand)["mean_mm"] - e_auto) < 1e-3
    for key in ("selection_curves", "selection_candidates", "selection_mean_mm", "selection_max_mm",
                "selection_p95_mm", "selection_tolerance_mm", "selection_tolerance_met"):
        assert key in auto.meta
    assert auto.meta["selection_curves"] == n and auto.meta["selection_candidates"] == cand.count
    assert auto.meta["selection_max_mm"] >= auto.meta["selection_p95_mm"] >= 0.0


def test_proxy_tracks_the_real_surface(phantom_auto):
    auto = phantom_auto[3]
    cand = S.candidates_of(auto)
    proxy, _ = S.proxy_errors(cand, _positions(cand, auto))
    real = np.asarray(auto.meta["selection_per_slice_mm"])
    assert real.shape == (cand.count,)
    assert np.corrcoef(proxy, real)[0, 1] > 0.9
    assert 0.8 < real.mean() / proxy.mean() < 1.25
    # chosen slices sit (nearly) on the surface, the others do not
    chosen = _positions(cand, auto)
    assert real[chosen].mean() < 0.1 < np.delete(real, chosen).mean()


def test_tolerance_gives_the_fewest_curves(phantom_seg):
    tol = 0.3
    bset = E.extract_boundaries(phantom_seg, tolerance_mm=tol)
    cand = S.candidates_of(bset)
    n = bset.curves.shape[0]
    m = bset.meta
    assert m["selection"] == "auto" and m["selection_tolerance_met"] is True
    assert m["selection_tolerance_mm"] == tol and m["selection_curves"] == n
    assert m["selection_mean_mm"] <= tol
    assert 4 < n < cand.count
    # one curve fewer (the same search's choice) misses the tolerance on the real surface
    fewer = _on_candidates(cand, S.select_curves(cand, n - 1), bset.meta)
    assert S.surface_error(fewer, cand)["mean_mm"] > tol
    # the default C2 surface takes any count (here not necessarily 3t+1)
    head = E.solve_pde(bset)
    assert head.spans == n                              # n - 1 spans between the curves + the crown dome
    # uniform with the same count is farther from the outlines
    uni = E.extract_boundaries(phantom_seg, curves=n, selection="uniform")
    e_uni = S.surface_error(_on_candidates(cand, _positions(cand, uni), bset.meta), cand)["mean_mm"]
    assert e_uni > m["selection_mean_mm"]


def test_max_tolerance_bounds_the_largest_distance(phantom_seg):
    bset = E.extract_boundaries(phantom_seg, tolerance_mm=0.5, max_tolerance_mm=4.0)
    m = bset.meta
    assert m["selection_tolerance_met"] is True
    assert m["selection_max_mm"] <= 4.0 and m["selection_mean_mm"] <= 0.5
    loose = E.extract_boundaries(phantom_seg, tolerance_mm=0.5)
    assert m["selection_curves"] > loose.meta["selection_curves"]   # the max bound needs more curves here


def test_unreachable_tolerance_warns_and_uses_every_slice(phantom_seg):
    with pytest.warns(S.SelectionWarning, match=r"tolerance not reachable: even all \d+ usable slices .* mean "
                                                r"\d+\.\d+ mm"):
        bset = E.extract_boundaries(phantom_seg, tolerance_mm=0.001)
    cand = S.candidates_of(bset)
    assert bset.curves.shape[0] == cand.count
    assert bset.meta["selection_tolerance_met"] is False
    assert bset.meta["selection_mean_mm"] > 0.001


def test_bad_requests_raise(phantom_seg):
    with pytest.raises(BoundaryError, match="use fewer patches"):
        E.extract_boundaries(phantom_seg, patches=E.max_patches(phantom_seg) + 1, selection="auto")
    with pytest.raises(BoundaryError, match="selection 'auto'"):
        E.extract_boundaries(phantom_seg, tolerance_mm=0.5, selection="shape-change")
    with pytest.raises(BoundaryError, match="parameterisation='angular'"):
        E.extract_boundaries(phantom_seg, selection="auto", parameterisation="aligned")
    with pytest.raises(BoundaryError, match="tolerance_mm must be a distance > 0"):
        E.extract_boundaries(phantom_seg, tolerance_mm=-1.0)
    with pytest.raises(BoundaryError, match="curves must be an integer >= 4"):
        E.extract_boundaries(phantom_seg, curves=3)


def test_any_count_solves_c2_and_round_trips_storage(phantom_seg):
    bset = E.extract_boundaries(phantom_seg, curves=8, selection="auto")
    assert bset.curves.shape[0] == 8 and bset.patches == 3 and not bset.is_3t_plus_1
    head = E.solve_pde(bset)
    assert head.curve_deviation < 2.0
    with pytest.raises(PDEError, match="needs 3t\\+1 curves"):
        E.solve_pde(bset, continuity="paper")
    back = E.loads_boundaries(E.dumps_boundaries(bset))
    assert back.curves.shape == bset.curves.shape
    assert np.abs(back.curves - bset.curves).max() < 0.01
    for key in ("selection", "selection_curves", "selection_mean_mm", "selection_max_mm", "selection_tolerance_mm"):
        assert back.meta[key] == bset.meta[key]
    assert np.allclose(back.u_knots, bset.u_knots)


def test_auto_beats_uniform_on_cthead(cthead_seg):
    t = 5
    auto = E.extract_boundaries(cthead_seg, patches=t, selection="auto")
    cand = S.candidates_of(auto)
    uniform = E.extract_boundaries(cthead_seg, patches=t, selection="uniform")
    e_uni = S.surface_error(_on_candidates(cand, _positions(cand, uniform), auto.meta), cand)["mean_mm"]
    e_auto = auto.meta["selection_mean_mm"]
    # measured: 0.461 mm against 0.478 mm (uniform on the same spine); 0.443 before the star hull's sharp
    # concave corners (where a web meets the outline) became 3 mm arcs
    assert e_auto <= 0.97 * e_uni, (e_auto, e_uni)
    assert auto.slice_indices[0] == cand.slices[0] and auto.slice_indices[-1] == cand.slices[-1]
    assert cand.count >= 100                            # every usable CThead slice is a candidate


def test_thin_slice_scans_trace_an_even_subset_of_the_candidates(phantom_seg, monkeypatch):
    """Past MAX_CANDIDATES usable slices only an even subset is traced (ends kept), at least 2n."""
    idx = np.arange(10, 310)
    thin = S.thin_candidates(idx, n_curves=31, most=128)
    assert len(thin) == 128 and thin[0] == 10 and thin[-1] == 309 and np.all(np.diff(thin) >= 2)
    assert np.ptp(np.diff(thin)) <= 1                                  # evenly spread
    assert len(S.thin_candidates(idx, n_curves=100, most=128)) == 200   # never fewer than 2n
    assert S.thin_candidates(idx[:50]) is not None and len(S.thin_candidates(idx[:50])) == 50
    full = E.extract_boundaries(phantom_seg, patches=4, selection="auto")
    monkeypatch.setattr(S, "MAX_CANDIDATES", 40)
    monkeypatch.setattr(S.thin_candidates, "__defaults__", (0, 40))
    few = E.extract_boundaries(phantom_seg, patches=4, selection="auto")
    assert full.meta["selection_candidates"] > 40 == few.meta["selection_candidates"]
    assert few.slice_indices[0] == full.slice_indices[0] and few.slice_indices[-1] == full.slice_indices[-1]
    # chosen from fewer outlines, the surface is nearly as close to all of them (within 15 %; measured
    # 0.392 against 0.356 mm, 1.10x, since issue 21's lighter envelope lets neighbouring outlines differ more)
    on_all = S.surface_error(few, S.candidates_of(full))["mean_mm"]
    assert on_all < 1.15 * full.meta["selection_mean_mm"], (on_all, full.meta["selection_mean_mm"])
