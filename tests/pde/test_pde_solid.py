"""The PDE solid (eq. 23): box-boundary meshes (Fig. 14), the w-field (section 4.3.1) and eq. 24."""
from __future__ import annotations

import numpy as np
import pytest
from skimage.draw import polygon2mask

from pde_synthetic import head_bset, resample_arc_length
from pdehead_addon import BoundarySet, CTVolume, PDEError, knots_from_heights
from pdehead_addon.pde.pde_solid import OUTSIDE_W, WField, alpha_from_w, w_field
from pdehead_addon.pde.pde_surface import solve_pde
from pdehead_addon.pde.surface_mesh import signed_volume

TWO_PI = 2 * np.pi


@pytest.fixture(scope="module", params=["c2", "paper"])
def head(request):
    """The default C2 surface (crown closed by a dome: its last row is one vertex) and the paper's patches."""
    return solve_pde(head_bset(patches=4, samples=128), continuity=request.param)


def face_areas(mesh):
    v = mesh.vertices
    q, t = mesh.quads, mesh.triangles
    qa = 0.5 * np.linalg.norm(np.cross(v[q[:, 2]] - v[q[:, 0]], v[q[:, 3]] - v[q[:, 1]]), axis=1)
    ta = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1)
    return np.concatenate([qa, ta])


# ----------------------------------------------------------------------------- solid meshes


def test_outer_face_is_the_surface(head):
    nu, nv, nw = 40, 60, 5
    solid = head.solid(nu, nv, nw)
    surf = head.surface(nu, nv)
    outer = solid.vertex_attributes["w"] == 1.0
    dome = head.vertex is not None
    assert outer.sum() == (nu - 1) * nv + 1 if dome else nu * nv
    assert len(surf.vertices) == outer.sum()
    a = np.round(solid.vertices[outer], 9)
    b = np.round(surf.vertices, 9)
    assert np.array_equal(a[np.lexsort(a.T)], b[np.lexsort(b.T)])
    # vertices are X(u, v, w) = A0 + w (X - A0)
    att = solid.vertex_attributes
    assert np.allclose(solid.vertices, head.evaluate(att["u"], att["v"], att["w"]), atol=1e-9)


@pytest.mark.parametrize("kwargs, fraction", [
    (dict(), 1.0),
    (dict(v_range=(np.pi / 2, TWO_PI)), 0.75),                               # Fig. 14 b
    (dict(v_range=(np.pi / 2, TWO_PI), w_range=(0.8, 1.0)), 0.75 * (1 - 0.64)),  # Fig. 14 c
    (dict(w_range=(0.5, 1.0)), 0.75),
    (dict(u_range=(0.25, 0.5), w_range=(0.2, 0.9)), None),
])
def test_cutaways_are_closed_and_outward(head, kwargs, fraction):
    m = head.solid(40, 60, 5, **kwargs)
    assert m.is_watertight()
    vol = signed_volume(m)
    assert vol > 0
    assert face_areas(m).min() > 1e-6                                       # no zero-area faces
    w = m.vertex_attributes["w"]
    w_range = kwargs.get("w_range", (0.0, 1.0))
    assert np.isclose(w.min(), w_range[0]) and np.isclose(w.max(), w_range[1])
    if fraction is not None:  # areas scale with w^2 around the spine; v by its span
        full = signed_volume(head.surface(40, 60, caps=True))
        assert abs(vol / full - fraction) < 0.02


def test_spine_degenerate_inner_face_is_merged(head):
    m = head.solid(20, 30, 4)                                               # w from 0: inner face on the spine
    w = m.vertex_attributes["w"]
    dome = head.vertex is not None                                          # the crown's pole is one vertex (w = 1)
    assert np.count_nonzero(w == 0) == (1 if dome else 2)                   # only the u-end fan centres
    if not dome:
        assert len(m.triangles) == 2 * 30                                   # u-end fans
    assert m.is_watertight() and face_areas(m).min() > 1e-6
    cut = head.solid(20, 30, 4, v_range=(1.0, 5.0))                         # the v cuts meet on the spine
    w = cut.vertex_attributes["w"]
    assert np.count_nonzero(w == 0) == (19 if dome else 20)                 # one spine vertex per u
    assert cut.is_watertight() and face_areas(cut).min() > 1e-6
    assert np.allclose(cut.vertices[w == 0], head.spine(cut.vertex_attributes["u"][w == 0]))


def test_solid_uv_and_seam(head):
    m = head.solid(10, 12, 3)
    assert m.quad_uv.shape == (len(m.quads), 4, 2)
    assert np.isclose(m.quad_uv[..., 1].max(), 1.0)
    assert m.triangle_uv.shape == (len(m.triangles), 3, 2)


@pytest.mark.parametrize("kwargs", [dict(nw=1), dict(u_range=(0.5, 0.5)), dict(w_range=(0.2, 1.5)),
                                    dict(v_range=(0, 7.0)), dict(nv=2)])
def test_solid_bad_ranges(head, kwargs):
    args = dict(nu=5, nv=8, nw=3)
    args.update({k: v for k, v in kwargs.items() if k in args})
    rest = {k: v for k, v in kwargs.items() if k not in args}
    with pytest.raises(PDEError):
        head.solid(args["nu"], args["nv"], args["nw"], **rest)


# ----------------------------------------------------------------------------- alpha (eq. 24)


def test_alpha_from_w_is_eq24():
    w = np.array([0.0, 0.5, 1.0, OUTSIDE_W, 1.0001])
    assert np.allclose(alpha_from_w(w), [0.9, 0.5, 0.1, 0.0, 0.0])
    assert np.allclose(alpha_from_w(w, low=0.2, high=0.6), [0.6, 0.4, 0.2, 0, 0])
    assert alpha_from_w(w).dtype == np.float32
    with pytest.raises(PDEError):
        alpha_from_w(w, low=-0.1)


# ----------------------------------------------------------------------------- w-field


def grid_volume(head, spacing=(1.0, 1.0, 1.0), margin=4.0):
    pts = head.surface_points(np.linspace(0, 1, 41), 256).reshape(-1, 3)
    lo = pts.min(axis=0) - margin
    hi = pts.max(axis=0) + margin
    dz, dy, dx = spacing
    shape = (int((hi[2] - lo[2]) / dz) + 1, int((hi[1] - lo[1]) / dy) + 1, int((hi[0] - lo[0]) / dx) + 1)
    data = np.arange(np.prod(shape), dtype=np.float32).reshape(shape) % 1000
    return CTVolume(data, spacing, lo, np.eye(3))


def section_mask(head, grid: CTVolume, k: int, n: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """Independent inside test of one voxel plane: skimage polygon2mask of the cross-section."""
    z = grid.origin[2] + k * grid.spacing[0]
    uu = np.linspace(0.0, 1.0, 20001)                                        # invert the spine's z densely
    zz = head.spine(uu)[:, 2]
    u = float(np.interp(z, zz, uu)) if zz[-1] > zz[0] else float(np.interp(z, zz[::-1], uu[::-1]))
    sec = head.surface_points(np.array([u]), n)[0]
    ij = (sec[:, :2] - grid.origin[:2]) / np.array([grid.spacing[2], grid.spacing[1]])
    mask = polygon2mask(grid.shape[1:], ij[:, ::-1])                        # (row=j, col=i)
    # distance of every voxel centre to the polygon, for "boundary voxel" tolerance
    jj, ii = np.mgrid[0:grid.shape[1], 0:grid.shape[2]]
    from scipy.spatial import cKDTree
    dense = head.surface_points(np.array([u]), 4 * n)[0, :, :2]
    d, _ = cKDTree((dense - grid.origin[:2]) / np.array([grid.spacing[2], grid.spacing[1]])).query(
        np.stack([ii.ravel(), jj.ravel()], 1))
    return mask, d.reshape(mask.shape)


def test_w_field_on_a_ct_grid_matches_the_surface(head):
    grid = grid_volume(head)
    wf = head.w_field(grid)
    assert isinstance(wf, WField) and wf.w.dtype == np.float32 and wf.intensity.dtype == np.float32
    inside = wf.w <= 1
    assert wf.w[inside].min() >= 0 and wf.w[inside].max() <= 1
    assert np.all(wf.w[~inside] == OUTSIDE_W)
    # intensity: the CT inside, 0 outside (CT grid == w grid: copied, not interpolated)
    assert np.array_equal(wf.intensity[inside], grid.data[inside])
    assert np.all(wf.intensity[~inside] == 0)
    # inside set == independent polygon rasterisation, except voxels within half a voxel of the boundary
    z = grid.origin[2] + grid.spacing[0] * np.arange(grid.shape[0])
    planes = np.nonzero((z >= head.bset.heights.min()) & (z <= head.bset.heights.max()))[0]
    for k in planes[np.linspace(0, len(planes) - 1, 6).astype(int)]:
        mask, dist = section_mask(head, grid, k)
        differ = mask != inside[k]
        assert np.all(dist[differ] < 0.5), (k, differ.sum())
    # volume == the closed capped surface's volume
    vol = inside.sum() * np.prod(grid.spacing)
    assert abs(vol / signed_volume(head.surface(200, 400, caps=True)) - 1) < 0.01
    # nothing outside the head's z range: the curves', up to the crown's pole with a dome
    top = head.vertex[2] if head.vertex is not None else head.bset.heights.max()
    if head.vertex is not None:
        assert top > head.bset.heights.max() + 1.0 and inside[z > head.bset.heights.max() + 1e-9].any()
    outside_planes = (z < head.bset.heights.min() - 1e-9) | (z > top + 1e-9)
    assert not inside[outside_planes].any()


def test_w_field_is_the_parametric_w_for_star_shaped_sections(head):
    grid = grid_volume(head)
    wf = w_field(head, grid)
    rng = np.random.default_rng(5)
    u = rng.uniform(0.05, 0.95, 200)
    v = rng.uniform(0, TWO_PI, 200)
    w = rng.uniform(0.05, 0.98, 200)
    # put the sample points on voxel planes, then find the voxel whose centre is nearest in-plane
    z = head.evaluate(u, v, w)[:, 2]
    k = np.round((z - grid.origin[2]) / grid.spacing[0]).astype(int)
    zk = grid.origin[2] + k * grid.spacing[0]
    uu = np.linspace(0.0, 1.0, 20001)                                        # invert the spine's z densely
    uk = np.interp(zk, head.spine(uu)[:, 2], uu)
    p = head.evaluate(uk, v, w)
    ij = np.round((p[:, :2] - grid.origin[:2]) / np.array(grid.spacing[2:0:-1])).astype(int)
    centre = grid.origin[:2] + ij * np.array(grid.spacing[2:0:-1])
    # exact parametric w of the voxel centre: along the ray from the spine, through the dense section
    S = head.spine(uk)[:, :2]
    exact = []
    for i in range(200):
        sec = head.surface_points(uk[i:i + 1], 8192)[0, :, :2] - S[i]
        d = centre[i] - S[i]
        ang = np.mod(np.arctan2(sec[:, 1], sec[:, 0]) - np.arctan2(d[1], d[0]) + np.pi, TWO_PI) - np.pi
        j = np.argmin(np.abs(ang))
        exact.append(np.linalg.norm(d) / np.linalg.norm(sec[j]))
    got = wf.w[k, ij[:, 1], ij[:, 0]]
    ok = np.array(exact) < 0.99
    assert np.abs(got[ok] - np.array(exact)[ok]).max() < 2e-3


def ear_section(samples: int = 256) -> np.ndarray:
    """A circle of radius 60 with an ear flap that hooks upward (+y): not star-shaped around the centre."""
    th0 = np.arcsin(5 / 60)
    th = np.linspace(th0, TWO_PI - th0, 2000)
    circle = np.stack([60 * np.cos(th), 60 * np.sin(th)], 1)
    flap = np.array([[75, -5], [75, 40], [70, 40], [70, 5]], float)
    flap_dense = np.concatenate([np.linspace(circle[-1], flap[0], 40)[1:]] +
                                [np.linspace(flap[i], flap[i + 1], 80)[1:] for i in range(3)] +
                                [np.linspace(flap[3], circle[0], 40)[1:-1]])
    poly = np.concatenate([circle, flap_dense])
    start = np.argmin(np.abs(poly[:, 0]) + (poly[:, 1] < 0) * 1e3)        # the +y point: the seam
    return resample_arc_length(np.roll(poly, -start, axis=0), samples)


def test_w_field_non_star_shaped_section_has_no_holes():
    M = 512
    section = ear_section(M) + np.array([100.0, 100.0])
    z = np.arange(4) * 10.0
    curves = np.empty((4, M, 3))
    curves[..., :2] = section
    curves[..., 2] = z[:, None]
    head = solve_pde(BoundarySet(curves, np.arange(4), z, knots_from_heights(z), {}), smoothing=0.0)
    grid = CTVolume(np.zeros((31, 150, 170), np.float32), (1.0, 1.0, 1.0), (20.0, 20.0, 0.0), np.eye(3))
    wf = w_field(head, grid)
    inside = wf.w <= 1
    assert wf.w[inside].max() <= 1.0
    for k in (0, 10, 15, 30):
        mask, dist = section_mask(head, grid, k, n=2048)
        differ = mask != inside[k]
        assert np.all(dist[differ] < 0.5)                                    # only boundary voxels differ
        # the flap's interior (x in (170, 175), y in (105, 140) -> i = x - 20, j = y - 20) is filled
        assert inside[k, 86:120, 151:155].all()
        assert not inside[k, 86:120, 142:149].any()                          # the gap between ear and head
    # monotone along rays from the spine (checked away from the flap, where the farthest-crossing
    # distance jumps between neighbouring directions and voxel rounding changes the direction)
    S = head.spine(np.array([0.5]))[0, :2] - np.array([20.0, 20.0])
    for ang in np.linspace(np.pi / 2, 1.75 * np.pi, 48):
        r = np.arange(0, 80, 0.5)
        i = np.round(S[0] + r * np.cos(ang)).astype(int)
        j = np.round(S[1] + r * np.sin(ang)).astype(int)
        ok = (i >= 0) & (i < 170) & (j >= 0) & (j < 150)
        w = wf.w[15, j[ok], i[ok]]
        first_out = np.argmax(w > 1) if np.any(w > 1) else len(w)
        assert np.all(np.diff(w[:first_out]) >= -2e-2)                      # nondecreasing (voxel rounding)


def test_w_field_voxel_size_grid_and_intensity_sampling(head):
    ct = grid_volume(head, spacing=(2.0, 1.0, 1.0))
    wf = w_field(head, 1.5, ct=ct)
    assert np.allclose(wf.spacing, 1.5) and np.allclose(wf.direction, np.eye(3))
    inside = wf.w <= 1
    vol = inside.sum() * 1.5 ** 3
    assert abs(vol / signed_volume(head.surface(200, 400, caps=True)) - 1) < 0.02
    assert np.any(wf.intensity[inside] != 0) and np.all(wf.intensity[~inside] == 0)
    # trilinear: a linear CT is reproduced exactly
    kk, jj, ii = np.meshgrid(*[np.arange(n) for n in ct.shape], indexing="ij")
    lin = CTVolume((3 * kk + 2 * jj + ii).astype(np.float32), ct.spacing, ct.origin, ct.direction)
    wf2 = w_field(head, 1.5, ct=lin)
    k, j, i = np.nonzero(wf2.w <= 1)
    grid = CTVolume(np.zeros((1, 1, 1), np.float32), wf2.spacing, wf2.origin, wf2.direction)
    idx = lin.patient_to_index(grid.index_to_patient(np.stack([k, j, i], 1).astype(float)))
    assert np.allclose(wf2.intensity[k, j, i], 3 * idx[:, 0] + 2 * idx[:, 1] + idx[:, 2], atol=1e-2)
    # ... also from a CT turned 30 degrees about z and tilted 10 about x (the index map's off-diagonal terms)
    a, b = np.radians(30.0), np.radians(10.0)
    turn = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    tilt = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    centre = lin.index_to_patient(np.array(lin.shape, float) / 2)
    direction = tilt @ turn
    origin = centre - CTVolume(lin.data, lin.spacing, np.zeros(3), direction).index_to_patient(
        np.array(lin.shape, float) / 2)
    turned = CTVolume(lin.data, lin.spacing, origin, direction)
    wf3 = w_field(head, 1.5, ct=turned)
    k, j, i = np.nonzero(wf3.w <= 1)
    idx = turned.patient_to_index(grid.index_to_patient(np.stack([k, j, i], 1).astype(float)))
    within = np.all((idx >= 0) & (idx <= np.array(lin.shape) - 1), axis=1)
    assert within.mean() > 0.5
    assert np.allclose(wf3.intensity[k, j, i][within], (3 * idx[:, 0] + 2 * idx[:, 1] + idx[:, 2])[within],
                       atol=1e-2)
    vol_ct = wf.to_ctvolume("alpha")
    assert vol_ct.data.max() <= 0.9 + 1e-6 and vol_ct.spacing == wf.spacing


def test_w_field_separable_intensity_equals_map_coordinates_with_the_ct_cropped(head):
    """The axis-aligned grid's plane-by-plane interpolation gives map_coordinates' trilinear values (to
    float32 rounding), and its lowest CT value outside the CT, here a CT cropped to half the head."""
    from scipy.ndimage import map_coordinates
    ct = grid_volume(head, spacing=(2.0, 1.0, 1.0))
    rng = np.random.default_rng(2)
    data = rng.normal(100.0, 40.0, ct.shape).astype(np.float32)
    half = CTVolume(data[:, :, : ct.shape[2] // 2], ct.spacing, ct.origin, ct.direction)
    wf = w_field(head, 1.3, ct=half)
    k, j, i = np.nonzero(wf.w <= 1)
    grid = CTVolume(np.zeros((1, 1, 1), np.float32), wf.spacing, wf.origin, wf.direction)
    idx = half.patient_to_index(grid.index_to_patient(np.stack([k, j, i], 1).astype(float)))
    want = map_coordinates(half.data, idx.T, order=1, mode="constant", cval=float(half.data.min()))
    assert np.abs(wf.intensity[k, j, i] - want).max() < 1e-3
    outside = np.any((idx < 0) | (idx > np.array(half.shape) - 1), axis=1)
    assert 0.3 < outside.mean() < 0.7 and np.all(wf.intensity[k, j, i][outside] == half.data.min())


def test_w_field_refuses_non_axial_input(head):
    c, s = np.cos(0.3), np.sin(0.3)
    tilted = CTVolume(np.zeros((4, 4, 4), np.float32), (1, 1, 1), (0, 0, 0), [[1, 0, 0], [0, c, -s], [0, s, c]])
    with pytest.raises(PDEError, match="axial"):
        w_field(head, tilted)
    curves = head.bset.curves.copy()
    curves[:, :, 2] += np.sin(np.linspace(0, TWO_PI, curves.shape[1], endpoint=False))
    bent = solve_pde(BoundarySet(curves, head.bset.slice_indices, head.bset.heights, head.bset.u_knots, {}))
    with pytest.raises(PDEError, match="axial-planar"):
        w_field(bent, 2.0)
    with pytest.raises(PDEError):
        w_field(head, -1.0)


# ----------------------------------------------------------------------------- real data


def test_w_field_cthead(cthead_bset, cthead_ct, cthead_seg):
    head = solve_pde(cthead_bset)
    wf = head.w_field(cthead_ct)
    inside = wf.w <= 1
    assert wf.w.shape == cthead_ct.shape
    assert wf.w[inside].min() >= 0 and wf.w[inside].max() <= 1 and np.all(wf.w[~inside] == OUTSIDE_W)
    z = cthead_bset.curves[:, 0, 2]
    kz = np.round((z - cthead_ct.origin[2]) / cthead_ct.spacing[0]).astype(int)
    m = cthead_seg.mask[kz.min():kz.max() + 1]
    i = inside[kz.min():kz.max() + 1]
    jaccard = (m & i).sum() / (m | i).sum()
    print(f"CThead w-field inside vs segmentation mask (curves' z range): Jaccard {jaccard:.4f}")
    assert jaccard > 0.95
    assert np.array_equal(wf.intensity[inside], cthead_ct.data[inside])


def test_trilinear_matches_map_coordinates_inside_and_cval_outside():
    from scipy.ndimage import map_coordinates

    from pdehead_addon.core.ct_volume import trilinear
    rng = np.random.default_rng(3)
    data = rng.random((7, 9, 11)).astype(np.float32)
    pts = rng.random((5000, 3)) * (np.array(data.shape) + 1.0) - 1.0   # some outside the box
    got = trilinear(data, pts, cval=-2.0)
    want = map_coordinates(data, pts.T, order=1, mode="constant", cval=-2.0, prefilter=False)
    shape = np.array(data.shape)
    inside = np.all((pts >= 0) & (pts <= shape - 1), axis=1)
    rim = ~inside & np.all((pts >= -0.5) & (pts <= shape - 0.5), axis=1)   # the outer half voxel
    beyond = ~inside & ~rim
    assert 0.2 < inside.mean() < 0.9 and rim.any() and beyond.any()
    np.testing.assert_allclose(got[inside], want[inside], atol=1e-5)
    nearest = map_coordinates(data, np.clip(pts, 0, shape - 1).T, order=1, prefilter=False)
    np.testing.assert_allclose(got[rim], nearest[rim], atol=1e-5)          # the edge value, not cval
    assert np.all(got[beyond] == -2.0)
    corner = trilinear(data, np.array([[6.0, 8.0, 10.0], [0.0, 0.0, 0.0]]))
    np.testing.assert_allclose(corner, [data[6, 8, 10], data[0, 0, 0]], atol=1e-6)


def test_solid_ct_table_is_the_ct_at_the_solid_points(phantom):
    """The (u, v, w) table gives the CT at X(u, v, w) (eq. 23) within interpolation error, periodic in v."""
    from scipy.ndimage import map_coordinates

    from pdehead_addon import extract_boundaries, segment_head
    from pdehead_addon.pde.solid_ct_table import SolidCTTable
    ct = phantom.ct
    head = solve_pde(extract_boundaries(segment_head(ct), patches=6, samples=128))
    table = SolidCTTable(head, ct)
    assert all(16 <= n <= m for n, m in zip(table.shape, SolidCTTable.MAX_SHAPE))
    rng = np.random.default_rng(1)
    u, v, w = rng.random(4000), rng.random(4000) * 2 * np.pi, rng.random(4000)
    pts = head.spine(u) + w[:, None] * (head.evaluate(u, v, 1.0) - head.spine(u))
    direct = map_coordinates(ct.data, ct.patient_to_index(pts).T, order=1, mode="nearest")
    err = np.abs(table.sample(u, v, w) - direct) / np.ptp(ct.data)
    assert np.median(err) < 0.01 and np.percentile(err, 90) < 0.06, (np.median(err), np.percentile(err, 90))
    np.testing.assert_allclose(table.sample(u, v + 2 * np.pi, w), table.sample(u, v, w), atol=1e-4)
    # the separable grid look-up equals the point look-up on the grid's points
    us, vs, ws = np.linspace(0.1, 0.9, 7), np.linspace(0.0, 2 * np.pi, 11), np.array([0.0, 0.5, 1.0])
    grid = table.sample_grid(us, vs, ws)
    U, V, W = np.meshgrid(us, vs, ws, indexing="ij")
    assert grid.shape == (7, 11, 3)
    np.testing.assert_allclose(grid, table.sample(U, V, W), atol=1e-3)
    assert np.ptp(grid) > 0.3 * np.ptp(ct.data)  # crosses skin, bone and brain: a real check
    # 8-bit packing (what the .blend keeps): every displayed (windowed) value within half a grey level
    from pdehead_addon.core.ct_volume import apply_window, intensity_window
    window = intensity_window(ct)
    raw = table.to_bytes(window)
    assert len(raw) < table.table.size  # fewer bytes than one per value (compressed)
    back, back_window = SolidCTTable.from_bytes(raw)
    assert back.shape == table.shape and back_window == tuple(window)
    import json
    a, b = json.loads(raw[4:4 + int.from_bytes(raw[:4], "little")])["range"]  # the span of the 256 levels
    step = (b - a) / 255
    assert a <= window[0] and b >= window[1] and b - a <= 3 * (window[1] - window[0]) + 1e-3
    kept = (table.table >= a) & (table.table <= b)
    assert kept.mean() > 0.99 and np.abs(back.table - table.table)[kept].max() <= 0.5 * step * 1.001
    shown, shown_back = (apply_window(t.sample(u, v, w), window) for t in (table, back))
    assert np.abs(shown_back - shown).max() <= 0.5 * step / (window[1] - window[0]) * 1.001 + 1e-6
    assert np.ptp(shown_back) > 0.5
    with pytest.raises(PDEError, match="cannot be read"):
        SolidCTTable.from_bytes(raw[:40])


def test_solid_ct_table_planar_fill_is_the_trilinear_ct(phantom, monkeypatch):
    """The axial fast fill (the slices interpolated at the pixels the samples need) gives the general path's
    trilinear CT at every table point, to float32 rounding, on a CT whose slices are not the solid's planes."""
    from pdehead_addon import extract_boundaries, segment_head
    from pdehead_addon.pde.solid_ct_table import SolidCTTable
    ct = phantom.ct
    head = solve_pde(extract_boundaries(segment_head(ct), patches=6, samples=128))
    fast = SolidCTTable(head, ct, nu=40, nv=64, nw=12)
    monkeypatch.setattr(SolidCTTable, "_fill_planar", lambda *args, **kwargs: False)
    general = SolidCTTable(head, ct, nu=40, nv=64, nw=12)
    assert fast.table.shape == general.table.shape == (12, 40, 65)
    assert np.ptp(general.table) > 0.5 * np.ptp(ct.data)  # air, skin and bone: a real check
    np.testing.assert_allclose(fast.table, general.table, rtol=0, atol=1e-5 * np.ptp(ct.data))
