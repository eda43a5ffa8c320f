"""Issue 20's shortcuts give the same numbers as the slow paths they replace (bit for bit).

Each shortcut was also checked on the 512 x 512 x 300 clinical scan and on CThead (mask and curves
identical, docs/benchmarks.md, section clinical-scan-speed); these tests keep them honest on small
synthetic volumes in a fraction of a second.
"""
from __future__ import annotations

import sys

import numpy as np
import pytest
from scipy import ndimage as ndi

from pdehead_addon.curves.envelope import head_envelope
from pdehead_addon.segment import mask_cleanup as C


def _blobs(shape, seed, fraction=0.35, sigma=2.0):
    rng = np.random.default_rng(seed)
    return ndi.gaussian_filter(rng.random(shape), sigma) > np.quantile(
        ndi.gaussian_filter(rng.random(shape), sigma), 1.0 - fraction)


def test_the_thin_parts_joined_by_adjacency_are_the_largest_component():
    """_core_with_kept == largest_component(core | keep[labels]), with and without its fallback."""
    shape = (10, 40, 50)
    work = _blobs(shape, 1, 0.45)
    opened = C.open_disk(work, (1.0, 1.0), 1.5)
    core = C.largest_component(opened)
    thin = work & ~opened
    labels, n = ndi.label(thin)
    assert n > 20                                            # many thin components, some touching the core
    flat = np.flatnonzero(thin)
    thin_labels = labels.reshape(-1)[flat]
    total = np.bincount(thin_labels, minlength=n + 1)
    rng = np.random.default_rng(2)
    for trial in range(5):
        keep = rng.random(n + 1) < 0.6
        keep[0] = False
        got = C._core_with_kept(core, labels, keep, flat, thin_labels, total)
        assert np.array_equal(got, C.largest_component(core | keep[labels])), trial
    # a kept component far bigger than the core's: the fallback labels the volume
    small_core = np.zeros(shape, bool)
    small_core[0, 0, :3] = True
    big = np.zeros(shape, bool)
    big[5:9, 10:30, 10:40] = True
    labels, n = ndi.label(big)
    flat = np.flatnonzero(big)
    thin_labels = labels.reshape(-1)[flat]
    keep = np.array([False, True])
    got = C._core_with_kept(small_core, labels, keep, flat, thin_labels, np.bincount(thin_labels, minlength=2))
    assert np.array_equal(got, big)


@pytest.mark.parametrize("seed", [3, 4])
def test_per_slice_hole_filling_equals_the_in_slice_labelling(seed):
    m = _blobs((6, 50, 70), seed, 0.55, 1.5)
    m[2] = False                                             # an empty slice
    m[3, 0, :] = True                                        # a slice touching its border
    labels, _ = ndi.label(~m, structure=C._IN_SLICE)
    border = np.unique(np.concatenate([labels[:, [0, -1], :].ravel(), labels[:, :, [0, -1]].ravel()]))
    ref = ~np.isin(labels, border[border > 0])
    out = C.fill_holes_per_slice(m)
    assert np.count_nonzero(out & ~m) > 50                   # holes were filled
    assert np.array_equal(out, ref)
    assert np.array_equal(C.fill_holes_per_slice(m[4]), ref[4])          # a 2-D slice


def test_envelope_on_wanted_slices_is_the_whole_envelope_there():
    """head_envelope(slices=...) gives the same float32 field on those slices as the whole Gaussian."""
    z, y, x = np.mgrid[0:40, 0:60, 0:64]
    mask = ((z - 20) / 18.0) ** 2 + ((y - 30) / 22.0) ** 2 + ((x - 32) / 25.0) ** 2 < 1.0
    mask[:, 28:32, 5:12] = False                             # a notch for the closing
    spacing = (1.5, 0.8, 0.8)
    full, window = head_envelope(mask, spacing)
    wanted = np.array([window[0].start, 4, 10, 21, 22, 30, window[0].stop - 1])
    part, window2 = head_envelope(mask, spacing, slices=wanted)
    assert window2 == window
    k = wanted - window[0].start
    assert np.array_equal(part[k], full[k])
    assert part[k].max() > 0.99 and part[k].min() == 0.0
    others = np.setdiff1d(np.arange(len(part)), k)
    assert not part[others].any()


@pytest.mark.parametrize("sigma", [0.4, 1.328, 2.9, 4.5])
def test_binary_gaussian_z_is_the_float_gaussian_on_the_wanted_slices(sigma):
    """The table lookup gives gaussian_filter1d's float32 values to the bit (the filter itself near the
    array's ends and for kernels too long for a table: sigma 4.5 -> 37 taps)."""
    binary_gaussian_z = sys.modules[head_envelope.__module__].binary_gaussian_z   # wherever the module sits
    rng = np.random.default_rng(3)
    region = ndi.binary_opening(rng.random((50, 30, 45)) < 0.55)
    for wanted_at in ([20, 21, 24, 33], [0, 12, 49], []):
        wanted = np.zeros(len(region), bool)
        wanted[wanted_at] = True
        ref = ndi.gaussian_filter1d(region.astype(np.float32), sigma, axis=0, mode="nearest")
        ref[~wanted] = 0.0
        out = binary_gaussian_z(region, sigma, wanted)
        assert out.dtype == np.float32
        assert np.array_equal(out, ref)
        if wanted_at:
            assert 0.0 < out[wanted].mean() < 1.0


def test_slice_regions_on_bounding_boxes_equal_the_whole_slices():
    envelope = sys.modules[head_envelope.__module__]                          # wherever the module sits
    _slice_regions, outer_region = envelope._slice_regions, envelope.outer_region
    rng = np.random.default_rng(4)
    mask = ndi.binary_dilation(rng.random((12, 40, 50)) < 0.05)
    mask[3] = False
    mask[5, 0, :] = True                                     # touching the edge
    out = _slice_regions(mask)
    ref = np.stack([outer_region(m) if m.any() else np.zeros_like(m) for m in mask])
    assert np.array_equal(out, ref)
    assert np.count_nonzero(out & ~mask) > 0 and np.count_nonzero(mask & ~out) > 0   # filled and dropped


@pytest.mark.parametrize("continuity, smoothing", [("c2", None), ("c2", 0.0), ("paper", None)])
def test_surface_and_solid_share_one_grid_and_its_rows_are_independent(continuity, smoothing):
    """The dome surface's rows are the solid's grid without its pole row, bit for bit, and a live change
    synthesises that grid once for both (the surface's points are what the solid reads)."""
    from pde_synthetic import head_bset
    from pdehead_addon.pde.pde_surface import solve_pde
    head = solve_pde(head_bset(patches=4, samples=128), continuity=continuity, smoothing=smoothing)
    for nu, nv in ((40, 60), (41, 97), (3, 3)):
        u = np.linspace(0.0, 1.0, nu)
        assert np.array_equal(head.surface_points(u, nv)[:-1], head.surface_points(u[:-1], nv))
    calls = []
    synth = head.surface_points
    head.surface_points = lambda *a, **k: calls.append(1) or synth(*a, **k)
    surf = head.surface(40, 60)
    solid = head.solid(40, 60, 5)
    assert len(calls) == 1
    grid = head.grid(np.linspace(0.0, 1.0, 40), 60)
    tube = grid[:-1] if head.vertex is not None else grid
    assert np.array_equal(surf.vertices[:tube.shape[0] * 60], tube.reshape(-1, 3))
    assert len(solid.vertices) > len(surf.vertices)
    assert grid.flags.writeable is False


def _dense_smoother(x, length):
    """The Reinsch smoother as a dense solve (what pde_spline did before session 5), written with
    difference operators: ``Q^T`` is the second divided difference, ``W`` the knots' half spacings."""
    h = np.diff(x)
    w = np.convolve(h, [0.5, 0.5])
    Qt = np.diff(np.diff(np.eye(len(x)), axis=0) / h[:, None], axis=0)
    R = np.diag((h[:-1] + h[1:]) / 3.0) + np.diag(h[1:-1] / 6.0, 1) + np.diag(h[1:-1] / 6.0, -1)
    lam = float(length) ** 4
    return np.eye(len(x)) - lam * (Qt.T / w[:, None]) @ np.linalg.solve(R + lam * (Qt / w) @ Qt.T, Qt)


def test_banded_smoother_is_the_dense_solve_without_dense_lapack(monkeypatch):
    """The smoothing spline's matrix from the banded Cholesky equals the dense solve's to ~1e-12, and
    no dense (OpenBLAS-threaded) solve is called: the selection's ~800 small solves stay on one thread.

    Not bit-identical: on CThead, GE (t = 4, 6), the phantom and the 512 x 512 x 300 scan the automatic
    selection chose the same slices and the curves moved at most 1.3e-12 mm (docs/benchmarks.md)."""
    from pdehead_addon.pde import pde_spline as P
    rng = np.random.default_rng(7)
    cases = [(np.cumsum(rng.uniform(0.3, 9.0, m)), float(rng.uniform(0.5, 40.0))) for m in (3, 4, 5, 31, 128)]
    expected = [_dense_smoother(x, L) for x, L in cases]

    def no_dense(*a, **k):
        raise AssertionError("dense np.linalg.solve called")
    monkeypatch.setattr(np.linalg, "solve", no_dense)
    P._smoother.cache_clear()
    for (x, L), ref in zip(cases, expected):
        S = P._smoother(x.tobytes(), L)
        assert S.shape == ref.shape
        assert np.abs(S - ref).max() <= 1e-11 * max(1.0, np.abs(ref).max())
        assert np.abs(S @ (3.0 * x - 7.0) - (3.0 * x - 7.0)).max() < 1e-9       # lines are kept
        assert np.abs(S.sum(axis=1) - 1.0).max() < 1e-12                       # constants too
    P._smoother.cache_clear()


def test_approximation_change_reuses_the_tube_uv_map(monkeypatch):
    """The dome's tip moves with the approximation slider and rescales the curves' u; the tube's UV map
    (:func:`.surface_uv_map.uv_tube_map`, ~0.5 s CPU on a head) is a function of u up to scale, so it is
    solved once for all approximation values (the map was re-solved at every change before session 6),
    and the surface's UVs and vertices are those of the map solved on each change's own u to ~1e-9."""
    from pde_synthetic import head_bset
    from pdehead_addon.pde import pde_head as PH, surface_mesh as SM, surface_uv_map as UV
    from pdehead_addon.pde.pde_surface import solve_with_controls
    bset = head_bset(patches=4, samples=128)
    calls = []
    solve_map = UV.uv_tube_map
    monkeypatch.setattr(PH, "uv_tube_map", lambda *a, **k: calls.append(1) or solve_map(*a, **k))  # its one caller
    heads = [solve_with_controls(bset, "c2", approximation=f, dome=True) for f in (0.30, 0.313, 0.326, 0.9)]
    assert len({float(h.curve_u[-1]) for h in heads}) == len(heads)          # u is rescaled at every change
    meshes = [h.surface(40, 60) for h in heads]
    assert len(calls) == 1
    for head, mesh in zip(heads, meshes):
        rings, map_u = UV.uv_map_grid(bset.curves, head.curve_u)             # solved on this change's own u
        U, V, W = solve_map(rings, map_u)
        layout = head.uv_layout()
        assert np.abs(layout["map_u"] - map_u).max() < 1e-12
        for got, want in zip(layout["tube_map"], (U, V, W)):
            assert np.abs(np.asarray(got) - want).max() < 1e-9
        own = dict(layout, tube_map=(U, V, W), map_u=map_u,
                   tube_box=(float(U.min()), float(max(U.max(), (U[:, 0] + W).max())), float(V.min()), float(V.max())))
        own["aspect"] = (own["tube_box"][3] - own["tube_box"][2]) / (own["tube_box"][1] - own["tube_box"][0])
        SM._QUAD_UV_CACHE.clear()
        monkeypatch.setattr(head, "uv_layout", lambda own=own: own)
        reference = head.surface(40, 60)
        assert np.array_equal(mesh.vertices, reference.vertices)
        assert np.abs(mesh.loop_uv() - reference.loop_uv()).max() < 1e-9


@pytest.mark.parametrize("seed", range(6))
def test_run_labels_equal_ndi_label(seed):
    """The labelling on runs along x numbers, counts and boxes the components exactly as ndi.label."""
    from pdehead_addon.segment import run_labels as RL
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(1, 12)), int(rng.integers(2, 40)), int(rng.integers(2, 50)))
    m = _blobs(shape, seed, float(rng.uniform(0.1, 0.4)), float(rng.uniform(0.6, 2.0)))
    m[0, :, -1] = True                                       # runs that end at the row's end
    ref, n = ndi.label(m)
    got, n2, runs, run_labels = RL.label(m)
    assert n > 1 and n2 == n and np.array_equal(got, ref)
    assert runs.objects(run_labels, n) == ndi.find_objects(ref)
    ref_in, n_in = ndi.label(m, structure=C._IN_SLICE)
    got_in, n2_in, _, _ = RL.label(m, in_slice=True)
    assert n2_in == n_in and np.array_equal(got_in, ref_in)
    counts = np.bincount(ref.reshape(-1), minlength=n + 1)
    counts[0] = 0
    assert np.array_equal(RL.largest_component(m), ref == np.argmax(counts))
    pick = rng.random(run_labels.size) < 0.5
    for which in (None, pick, ~pick):                        # both ways of painting runs
        want = np.zeros(m.size, dtype=bool)
        want[runs.voxels(which)] = True
        assert np.array_equal(runs.paint(which).reshape(-1), want)
    assert np.array_equal(runs.paint(), m)


def test_largest_component_on_runs_with_a_tie_takes_the_first():
    m = np.zeros((3, 8, 9), dtype=bool)
    m[2, 1:3, 1:3] = True                                    # later in raster order
    m[0, 5:7, 5:7] = True                                    # first, same size
    m[1, 0, 0] = True
    out = C.largest_component(m)
    assert np.count_nonzero(out) == 4 and out[0, 5, 5] and not out[2, 1, 1]


@pytest.mark.parametrize("dtype", [np.int16, np.uint8, np.float32])
def test_windowed_ranges_equal_the_float_volume(dtype):
    """_windowed_range's comparisons of the raw values give the float volume's tests voxel for voxel."""
    rng = np.random.default_rng(5)
    if dtype == np.float32:
        raw = np.concatenate([rng.normal(0, 1500, 4000), rng.uniform(-1100, 200, 4000),
                              [np.inf, -np.inf, np.nan, -0.0, 0.0, 3e38, -3e38]]).astype(np.float32)
        # every float32 within a few ulps of the bounds' crossings
        for window in ((-1000.0, 40.0), (0.5, 200.25)):
            for level in (0.85, 0.4):
                x = np.float32(window[0] + level * (window[1] - window[0]))
                raw = np.concatenate([raw, x + np.arange(-40, 41, dtype=np.float32) * np.spacing(x)])
        raw = raw.astype(np.float32)
    else:
        info = np.iinfo(dtype)
        raw = rng.integers(info.min, info.max, size=8000, endpoint=True).astype(dtype)
    raw = raw.reshape(1, 1, -1)
    for window in ((-1000.0, 40.0), (0.5, 200.25), (-30000.0, 30000.0)):
        w = np.subtract(raw, np.float32(window[0]), dtype=np.float32)
        w *= np.float32(1.0 / (window[1] - window[0]))
        for above, below, want in (((0.85, False), None, w >= np.float32(0.85)),
                                   ((0.4, True), 0.85, (w > np.float32(0.4)) & (w < np.float32(0.85))),
                                   ((1e9, False), None, w >= np.float32(1e9)),
                                   (None, -1e9, w < np.float32(-1e9)), (None, 1e9, w < np.float32(1e9))):
            got = C._windowed_range(raw, window, above, below)
            assert np.array_equal(got, want), (window, above, below)
        if window[0] == 0.5:                                 # not all on one side
            assert 100 < np.count_nonzero(C._windowed_range(raw, window, (0.85, False), None)) < raw.size - 100
    assert C._windowed_range(raw.astype(np.float64), (0.0, 1.0), (0.5, False), None) is None


def test_clean_up_without_the_float_volume_equals_it(phantom_seg, phantom):
    """The clean-up of 16-bit and float32 intensities thresholds the raw values (no float volume): the
    same mask and statistics as float64 data, which takes the float volume; with and without the
    noise's smoothing (which needs the float volume)."""
    mask = phantom_seg.probability > np.float32(0.5)
    window = phantom_seg.meta["window"]
    raw = np.rint(phantom.ct.data).astype(np.int16)
    for noise in (None, 0.0, 0.2):
        for data in (raw, raw.astype(np.float32), phantom.ct.data.astype(np.float32)):
            got, got_stats = C.clean_head_mask(mask.copy(), data, window, phantom.ct.spacing, noise=noise)
            ref, ref_stats = C.clean_head_mask(mask.copy(), data.astype(np.float64), window, phantom.ct.spacing,
                                               noise=noise)
            assert np.array_equal(got, ref) and got_stats == ref_stats, (noise, data.dtype)
            assert ref_stats["cushion_voxels"] > 0
    assert got_stats["smoothing_sigma"] > 0


def test_natural_spline_matrix_equals_scipys_banded_solve_bit_for_bit():
    """The spline's second derivatives go to LAPACK's gtsv directly (scipy's ``solve_banded`` calls the
    same routine after checks that cost more than these small solves): the same matrix, bit for bit."""
    from scipy.linalg import solve_banded

    from pdehead_addon.pde.pde_spline import natural_spline_matrix
    rng = np.random.default_rng(11)
    for m in (2, 3, 4, 17, 47):
        x = np.cumsum(rng.uniform(0.2, 6.0, m))
        s = np.sort(rng.uniform(x[0] - 1.0, x[-1] + 1.0, 90))
        A = natural_spline_matrix(x, s)
        h = np.diff(x)
        span = np.clip(np.searchsorted(x, s, side="right") - 1, 0, m - 2)
        t = (s - x[span]) / h[span]
        ref = np.zeros((len(s), m))
        ref[np.arange(len(s)), span] += 1.0 - t
        ref[np.arange(len(s)), span + 1] += t
        if m > 2:
            k = m - 2
            band = np.zeros((3, k))
            band[0, 1:], band[1], band[2, :-1] = h[1:-1], 2.0 * (h[:-1] + h[1:]), h[1:-1]
            D = np.zeros((k, m))
            i = np.arange(k)
            D[i, i], D[i, i + 1], D[i, i + 2] = 6.0 / h[:-1], -6.0 / h[:-1] - 6.0 / h[1:], 6.0 / h[1:]
            Mpp = np.zeros((m, m))
            Mpp[1:-1] = solve_banded((1, 1), band, D, check_finite=False)
            hs = h[span]
            ref += (hs ** 2 / 6.0 * ((1.0 - t) ** 3 - (1.0 - t)))[:, None] * Mpp[span] \
                + (hs ** 2 / 6.0 * (t ** 3 - t))[:, None] * Mpp[span + 1]
        assert np.array_equal(A, ref), m
        assert np.abs(A @ (2.0 * x + 1.0) - (2.0 * s + 1.0)).max() < 1e-9          # lines are kept


def test_planar_proxy_equals_the_interleaved_one():
    """The selection's proxy on planar rows (x, y, z planes; each sample's own normal offset once) gives
    the per-slice errors of the interleaved (sample, coordinate) layout it replaced to ~1e-12 mm."""
    from pde_synthetic import head_bset
    from pdehead_addon.curves import auto_selection as S
    from pdehead_addon.pde.pde_spline import dome_height, natural_spline_matrix, smoothing_spline_values
    bset = head_bset(patches=12, samples=192)
    cand = S.Candidates(np.arange(len(bset.curves)), bset.curves, dict(bset.meta))
    rng = np.random.default_rng(3)
    for _ in range(5):
        idx = np.unique(np.concatenate([[0, cand.count - 1], rng.choice(cand.count, 9, replace=False)]))
        mean, peak = S.proxy_errors(cand, idx)
        # the interleaved computation, written out as it was before
        sub = cand.sub
        m = sub.shape[1]
        Y = sub[idx]
        steps = np.linalg.norm(np.diff(Y, axis=0), axis=2).mean(axis=1)
        pos = np.concatenate([[0.0], np.cumsum(np.maximum(steps, 1e-6))])
        L = S._approximation(cand, cand.heights[idx])
        Ys = Y.reshape(len(idx), -1)
        if L > 0 and len(idx) >= 3:
            Ys = smoothing_spline_values(pos, Ys, float(L))
        top = cand.curves[idx[-1]]
        height = dome_height(cand.curves[idx[-3:]], cand.heights[idx[-3:]], cand.meta.get("vertex_z"))
        ring = Ys[-1].reshape(m, 3)
        vertex = np.array([ring[:, 0].mean(), ring[:, 1].mean(), top[:, 2].mean() + height])
        knots = np.concatenate([pos, [pos[-1] + np.linalg.norm(top - vertex, axis=1).mean()]])
        data = np.concatenate([Ys, np.tile(vertex, m)[None]])
        j = np.clip(np.searchsorted(idx, np.arange(cand.count), side="right") - 1, 0, len(idx) - 2)
        f0, f1 = cand.chord[idx[j]], cand.chord[idx[j + 1]]
        s = pos[j] + (cand.chord - f0) / (f1 - f0) * (pos[j + 1] - pos[j])
        pred = (natural_spline_matrix(knots, s) @ data).reshape(cand.count, m, 3)
        off = np.abs(np.einsum("kmc,kmc->km", pred - sub, cand.normals))
        assert np.abs(mean - off.mean(axis=1)).max() < 1e-11
        assert np.abs(peak - off.max(axis=1)).max() < 1e-11
        assert mean[idx].max() < mean.max()                     # the chosen curves are followed best
