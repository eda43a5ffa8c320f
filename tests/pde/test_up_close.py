"""Issue 21 ("Up close"): the crown's pole without a star, the neck cap without a fan, UVs an artist can paint."""
from __future__ import annotations

import numpy as np
import pytest

from pdehead_addon import solve_pde
from pdehead_addon.core.boundary_set import BoundarySet, knots_from_heights
from pdehead_addon.validation.surface_quality import pole_ripple

TWO_PI = 2.0 * np.pi


def rippled_bset(samples: int = 256) -> BoundarySet:
    """Elliptic rings (aspect 1.35) shrinking toward the top, each with a 4th and a 5th harmonic of 2 mm
    in its radius (CThead's top curve carries a 4th harmonic of 1.85 mm)."""
    z = np.linspace(0.0, 150.0, 11)
    scale = np.sqrt(np.clip(1.0 - (z / 175.0) ** 2, 0.05, None))
    theta = np.pi / 2 + TWO_PI * np.arange(samples) / samples
    curves = np.empty((len(z), samples, 3))
    for j, (zj, s) in enumerate(zip(z, scale)):
        a, b = 70.0 * s, 92.0 * s
        r = a * b / np.sqrt((b * np.cos(theta)) ** 2 + (a * np.sin(theta)) ** 2)
        r = r + 2.0 * np.cos(4 * theta) + 2.0 * np.sin(5 * theta)
        curves[j, :, 0] = r * np.cos(theta)
        curves[j, :, 1] = 10.0 + r * np.sin(theta)
        curves[j, :, 2] = zj
    return BoundarySet(curves, np.arange(len(z)), z, knots_from_heights(z), {})


@pytest.fixture(scope="module")
def domed():
    head = solve_pde(rippled_bset(), approximation_mm=0)
    old = solve_pde(rippled_bset(), approximation_mm=0)
    old._dome_minor = 0                          # the dome without the fade: the behaviour before issue 21
    return head, old


def test_pole_harmonics_fade_so_the_crown_has_no_star(domed):
    head, old = domed
    before, after = pole_ripple(old), pole_ripple(head)
    assert after["rings"] > 20
    assert before["worst_deg"] > 3.0             # the star: the ripple stays constant into the pole
    assert after["worst_deg"] <= 0.5             # issue 21's target
    # the dome keeps its height and its (horizontal) tangent plane at the pole
    assert np.isclose(after["dome_height_mm"], before["dome_height_mm"], atol=1e-6)
    assert np.allclose(after["normal"], [0.0, 0.0, 1.0], atol=1e-6)
    u = np.linspace(head.curve_u[-1], 1.0, 30)
    assert np.allclose(head.spine(u)[:, 2], old.spine(u)[:, 2], atol=1e-9)   # the crown's height profile


def test_pole_fade_keeps_the_top_curve_and_its_tangent(domed):
    head, old = domed
    u0 = float(head.curve_u[-1])
    v = TWO_PI * np.arange(64) / 64
    # value and u-derivative at the top curve are kept (C1 with the tube): the two differ by O(du^2) above it
    assert np.abs(head.evaluate(u0, v) - old.evaluate(u0, v)).max() < 1e-9
    d1, d2 = (np.abs(head.evaluate(u0 + du, v) - old.evaluate(u0 + du, v)).max() for du in (1e-4, 2e-4))
    assert 3.0 < d2 / d1 < 5.0
    # and the rings shrink monotonically to the pole
    rings = head.evaluate(np.linspace(u0, 1.0, 40)[:, None], v[None, :])
    r = np.linalg.norm(rings[..., :2] - head.vertex[:2], axis=-1).mean(axis=1)
    assert np.all(np.diff(r) < 0) and r[-1] < 1e-6


# ----------------------------------------------------------------------------- the neck's cap, the UVs

@pytest.fixture(scope="module")
def head_like():
    from pde_synthetic import head_bset
    return solve_pde(head_bset(patches=6, samples=256))


def test_bottom_is_a_flat_disc_without_long_triangles(head_like):
    from pdehead_addon.pde.surface_mesh import signed_volume
    from pdehead_addon.validation.surface_quality import cap_edge_ratio
    m = head_like.surface(60, 120, caps=True)
    assert m.is_watertight() and signed_volume(m) > 0
    assert cap_edge_ratio(m) <= 3.0                       # the fan's triangles ran from the centre to the ring
    tube = 59 * 120
    bottom = m.triangles[np.all((m.triangles < 120) | (m.triangles > tube), axis=1)]
    t = m.vertices[bottom]
    assert len(bottom) > 3 * 120                           # ring by ring, not one fan of 120
    nz = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    nz = nz[:, 2] / np.linalg.norm(nz, axis=1)
    assert np.all(nz < -0.999)                             # flat, facing down, nothing folded


def notched_bset(samples: int = 256, depth: float = 25.0, width_deg: float = 4.0) -> BoundarySet:
    """Elliptic rings with a V notch (``depth`` mm deep, ``width_deg`` either side) in the lower curves, fading
    out by 60 mm: there the outline runs nearly radially, as GE's wide neck does."""
    z = np.linspace(0.0, 150.0, 13)
    scale = np.sqrt(np.clip(1.0 - (z / 175.0) ** 2, 0.05, None))
    theta = TWO_PI * np.arange(samples) / samples
    off = np.abs(np.angle(np.exp(1j * (theta - np.radians(250.0)))))
    curves = np.empty((len(z), samples, 3))
    for j, (zj, s) in enumerate(zip(z, scale)):
        a, b = 70.0 * s, 92.0 * s
        r = a * b / np.sqrt((b * np.cos(theta)) ** 2 + (a * np.sin(theta)) ** 2)
        r = r - np.clip(1.0 - off / np.radians(width_deg), 0.0, None) * depth * max(0.0, 1.0 - zj / 60.0)
        curves[j, :, 0] = r * np.cos(theta)
        curves[j, :, 1] = 10.0 + r * np.sin(theta)
        curves[j, :, 2] = zj
    return BoundarySet(curves, np.arange(len(z)), z, knots_from_heights(z), {})


def test_a_radial_neck_outline_gets_closer_columns_not_long_cap_triangles(monkeypatch):
    """Issue 21: where the bottom outline runs radially, equal v steps are long on the surface and so is
    every cap triangle on them (GE: 4.24 mean edges). The columns lie closer in v there, fixed by the curves
    (the same v for every row and for nu, nv: the UVs stay registered). Measured: before 4.93, after 2.59."""
    from pdehead_addon.pde import pde_head as PS, surface_mesh as SM
    from pdehead_addon.validation.surface_quality import cap_edge_ratio, uv_quality
    head = solve_pde(notched_bset(), approximation_mm=0)
    m = head.surface(60, 120, caps=True)
    assert m.is_watertight() and SM.signed_volume(m) > 0
    assert cap_edge_ratio(m) <= 3.0
    q = uv_quality(m)
    assert q["mirrored"] == 0 and q["zero_area"] == 0
    v = head.v_columns(120)
    assert v[0] == 0.0 and np.all(np.diff(v) > 0) and v[-1] < TWO_PI
    assert np.diff(v).max() / np.diff(v).min() > 2.0                     # closer in v at the notch
    assert np.allclose(m.vertex_attributes["v"][:120], v)
    assert np.allclose(head.evaluate(0.0, v), m.vertices[:120])          # the columns lie on the surface
    assert np.allclose(head.v_columns(240)[::2], v, atol=1e-12)          # one warp of v for every nv
    solid = head.solid(60, 120, 5)                                       # the solid's skin: the same columns
    assert np.allclose(np.unique(solid.vertex_attributes["v"]), np.unique(v))
    monkeypatch.setattr(PS, "column_density", lambda curves: None)      # before: equal v steps, the old cap step
    monkeypatch.setattr(SM, "CAP_EDGE", 1.5)
    old = solve_pde(notched_bset(), approximation_mm=0).surface(60, 120, caps=True)
    assert cap_edge_ratio(old) > 4.0


def _loop_pixels(mesh, size):
    uv = mesh.loop_uv()
    return np.clip(np.floor(uv * size).astype(np.int64), 0, size - 1), mesh.loop_vertex_indices()


def test_uvs_are_paintable(head_like):
    from pdehead_addon.validation.surface_quality import uv_quality
    m = head_like.surface(60, 120, caps=True)
    q = uv_quality(m)
    assert q["mirrored"] == 0 and q["zero_area"] == 0     # before: every tube quad mirrored, caps of zero area
    assert q["stretch_p99_p1"] <= 4.0 and q["angle_p95_deg"] <= 10.0
    uv = m.loop_uv()
    assert uv.min() >= 0.0 and uv.max() <= 1.0


@pytest.mark.parametrize("nu2, nv2, step", [(119, 120, (2, 1)), (60, 240, (1, 2))])
def test_a_painted_dot_stays_on_its_vertex_when_the_mesh_is_rebuilt(head_like, nu2, nv2, step):
    size = 2048
    nu, nv = 60, 120
    m = head_like.surface(nu, nv, caps=True)
    i, j = 25, 41                                          # a vertex on the face side, away from seam and caps
    k = i * nv + j
    pix, verts = _loop_pixels(m, size)
    image = np.zeros((size, size), bool)
    px = pix[verts == k]
    assert len(np.unique(px, axis=0)) == 1                 # all of vertex k's loops share one UV
    image[px[0, 1], px[0, 0]] = True                       # the dot
    hit = image[pix[:, 1], pix[:, 0]]
    assert set(verts[hit]) == {k}
    # the same (u, v) after a rebuild at another resolution: found only on that vertex's loops
    m2 = head_like.surface(nu2, nv2, caps=True)
    k2 = (i * step[0]) * nv2 + j * step[1]
    assert np.allclose(m2.vertices[k2], m.vertices[k])
    pix2, verts2 = _loop_pixels(m2, size)
    hit2 = image[pix2[:, 1], pix2[:, 0]]
    assert hit2.any() and set(verts2[hit2]) == {k2}


# ----------------------------------------------------------------------------- the visible-face measure

def _ellipsoid_mc(radii, cavity: bool):
    from skimage import measure
    z, y, x = np.mgrid[-70:71, -60:61, -50:51].astype(float)            # 1 mm voxels, patient mm = index
    inside = (x / radii[0]) ** 2 + (y / radii[1]) ** 2 + (z / radii[2]) ** 2 <= 1.0
    inside &= ~((z < -45) & (np.hypot(x, y) > 25))                           # a neck below
    if cavity:                                                               # an airway the skin does not show
        inside &= ~((x ** 2 + (y + radii[1] - 18) ** 2 + z ** 2) <= 8 ** 2)
    verts, faces, _, _ = measure.marching_cubes(inside.astype(np.float32), 0.5)
    return verts[:, ::-1] + np.array([-50.0, -60.0, -70.0]), faces        # (x, y, z) mm


def test_visible_face_measure_drops_the_inside_and_measures_the_offset():
    from pdehead_addon.validation.surface_metrics import visible_face_distance, visible_face_points
    mask = _ellipsoid_mc((40.0, 50.0, 60.0), cavity=True)
    centroids = mask[0][mask[1]].mean(axis=1)
    kept = visible_face_points(centroids, (0.0, 0.0))
    cavity = np.linalg.norm(centroids - [0.0, -32.0, 0.0], axis=1) < 10
    assert cavity.sum() > 100 and not kept[cavity].any()                    # the airway's walls drop out
    same = visible_face_distance(*_ellipsoid_mc((40.0, 50.0, 60.0), cavity=False), *mask, (0.0, 0.0))
    assert same["score_mean"] < 0.05 and same["score_p95"] < 0.2
    assert abs(same["pronasale"][1] + 50.0) < 1.0                              # the most anterior midline point
    bigger = visible_face_distance(*_ellipsoid_mc((41.5, 51.5, 61.5), cavity=False), *mask, (0.0, 0.0))
    assert 1.2 < bigger["score_mean"] < 1.8                                  # 1.5 mm outward


def test_a_shape_slider_keeps_the_surface_topology():
    """The caps' vertex counts come from the curves, not from the ring of the moment: the add-on rebuilds
    the surface in place while a slider moves (and a painted texture keeps its loops)."""
    from pde_synthetic import head_bset
    b = head_bset(patches=6, samples=256)
    a, c = solve_pde(b, approximation_mm=0), solve_pde(b, approximation_mm=15.0)
    ma, mc = a.surface(60, 120, caps=True), c.surface(60, 120, caps=True)
    assert np.abs(ma.vertices - mc.vertices).max() > 0.5                       # the shape moved ...
    assert np.array_equal(ma.triangles, mc.triangles) and np.array_equal(ma.quads, mc.quads)   # ... not the mesh
    assert np.allclose(ma.loop_uv(), mc.loop_uv())


def _cthead_face(seg, **kw):
    from skimage import measure

    from pdehead_addon import defaults as D, extract_boundaries
    from pdehead_addon.validation.surface_metrics import visible_face_distance
    mask = seg.mask
    mv, mf, _, _ = measure.marching_cubes(mask.astype(np.float32), 0.5)
    mv = seg.ct.index_to_patient(mv)
    centre = seg.ct.index_to_patient(np.argwhere(mask).mean(axis=0)[None])[0][:2]
    bset = extract_boundaries(seg, patches=kw.pop("patches", D.PATCHES.default), samples=D.SAMPLES.default,
                              selection=D.SELECTION.default)
    surf = solve_pde(bset).surface(D.NU.default, D.NV.default, caps=True)
    faces = np.concatenate([surf.quads[:, [0, 1, 2]], surf.quads[:, [0, 2, 3]], surf.triangles])
    return visible_face_distance(surf.vertices, faces, mv, mf, centre)


def test_the_default_surface_keeps_the_face_of_cthead(cthead_seg, monkeypatch):
    """Issue 21 item 1 at the add-on's defaults (t, automatic slices, nu x nv, caps): mean <= 0.33 mm, p95 <=
    0.80 mm on the visible face (`surface_metrics.visible_face_distance`). The envelope's Gaussian (1.5 -> 1
    mm), the low-pass along each curve (1.5 -> 0.5 px) and the star bound (slope 2 -> 3) brought t = 10 to
    0.287 / 0.96; the p95 was the curves' spacing in height (the nose's underside, the mouth, the eyelids
    between curves 6 mm apart) and the u smoothing of one slice step on top of the envelope's 3-D Gaussian.
    Measured: t = 15 with half a slice step 0.243 / 0.76; the old defaults (t = 10, one slice step) 0.287 / 0.96."""
    from pdehead_addon import defaults as D
    from pdehead_addon.pde import pde_surface as PS
    r = _cthead_face(cthead_seg)
    assert r["score_mean"] <= 0.33 and r["score_p95"] <= 0.80, r
    assert D.PATCHES.default == 15 and PS.APPROXIMATION_PER_SLICE == 0.5
    monkeypatch.setattr(PS, "APPROXIMATION_PER_SLICE", 1.0)            # the defaults before: the p95 missed
    old = _cthead_face(cthead_seg, patches=10)
    assert old["score_p95"] > 0.9, old


@pytest.fixture(scope="module")
def cthead_default_bset(cthead_seg):
    """CThead's curves at the add-on's defaults (t, samples, slice selection), as the benchmark takes them."""
    from pdehead_addon import defaults as D, extract_boundaries
    return extract_boundaries(cthead_seg, patches=D.PATCHES.default, samples=D.SAMPLES.default,
                              selection=D.SELECTION.default)


def test_cthead_uvs_keep_texel_size_and_angles(cthead_default_bset):
    """Issue 21 item 4 on CThead at the add-on's defaults (t = 15, nu x nv from defaults.py, caps): no mirrored
    or empty faces, area stretch p99 / p1 over the middle 80 % of the height <= 4, angle distortion p95
    <= 10 deg, also no mirrored face at a finer mesh. Measured (the benchmark's curves): stretch 3.86, angle
    9.6 deg (at 300 x 480: 0 / 0, 4.08, 9.8 deg). Before (`surface_uv_map.uv_tube_map` with one triangle of
    each cell in its equations): 3.94 / 11.4 deg at t = 15 (this test checked t = 10 only: 4.04 / 9.4)."""
    from pdehead_addon import defaults as D
    from pdehead_addon.validation.surface_quality import uv_quality
    assert D.PATCHES.default == 15 and len(cthead_default_bset.curves) == 3 * 15 + 1
    head = solve_pde(cthead_default_bset)
    q = uv_quality(head.surface(D.NU.default, D.NV.default, caps=True))
    assert q["mirrored"] == 0 and q["zero_area"] == 0
    assert q["stretch_p99_p1"] <= 4.0, q
    assert q["angle_p95_deg"] <= 10.0, q
    fine = uv_quality(head.surface(300, 480, caps=True))
    assert fine["mirrored"] == 0 and fine["zero_area"] == 0, fine


def test_uv_map_leaves_the_angle_keeping_map_only_around_folds(cthead_default_bset, monkeypatch):
    """The tube map is the free (angle-keeping) least-squares map, blended toward straight rows only within
    a sample (and a taper) of a folded cell. At the default t = 15 it blended 6.7 % of the map's samples
    with one triangle of each cell in the equations (angle p95 11.4 deg); with both, 1.9 % (9.6 deg)."""
    from pdehead_addon.pde import surface_uv_map as SM
    head = solve_pde(cthead_default_bset)
    rings, map_u = SM.uv_map_grid(cthead_default_bset.curves, np.asarray(head.curve_u, float),
                                  v_density=head.v_density())
    U, V, _ = SM.uv_tube_map(rings, map_u)
    monkeypatch.setattr(SM, "UV_FOLD_MARGIN", -np.inf)                    # nothing counts as folded: the free map
    Uf, Vf, _ = SM.uv_tube_map(rings, map_u)
    blended = np.hypot(U - Uf, V - Vf) > 1e-6
    assert 0 < blended.mean() <= 0.03, blended.mean()


def _crown_against_smoothed_mask(seg, bset):
    """The crown's slope ripple of the 400 x 800 surface and of marching cubes of the mask smoothed by a
    3 mm Gaussian (the head's own large-scale shape, no slice steps), on circles about the pole."""
    from scipy import ndimage
    from skimage import measure

    from pdehead_addon.validation.surface_quality import CROWN_RADII_MM, crown_ripple
    head = solve_pde(bset)
    up = np.array([0.0, 0.0, 1.0 if head.vertex[2] > bset.curves[-1, :, 2].mean() else -1.0])
    mesh = head.surface(400, 800, caps=True)
    faces = np.concatenate([mesh.quads[:, [0, 1, 2]], mesh.quads[:, [0, 2, 3]], mesh.triangles])
    pde = crown_ripple(mesh.vertices, faces, head.vertex, up, radii=(5.0, 10.0) + CROWN_RADII_MM)
    smooth = ndimage.gaussian_filter(seg.mask.astype(np.float32), 3.0 / np.asarray(seg.ct.spacing, float))
    verts, tris, _, _ = measure.marching_cubes(smooth, 0.5)
    mc = crown_ripple(seg.ct.index_to_patient(verts), tris, head.vertex, up)
    return head, pde, mc


@pytest.mark.parametrize("name", ["cthead", "ge", "phantom"])
def test_the_crown_has_no_ridges_the_smoothed_head_lacks(name, cthead_seg, ge_seg, phantom_seg):
    """Issue 41 item 2 at the add-on's defaults (CThead t = 15, GE t = 8): on circles of 20-40 mm about the
    pole the surface's slope ripple (harmonics n >= 3) is at most that of the 3 mm-smoothed mask, at most
    0.5 deg within 10 mm (no nub), the dome's height kept. Measured: CThead 0.72, 0.45, 0.52, 0.72, 1.17 deg
    against 1.90, 2.03, 2.05, 1.82, 1.64 (before `pde_spline.crown_low_pass`: 2.32, 2.47, 3.34, 3.52, 3.88);
    GE 0.01-0.70 against 5.8-8.7 (its scan ends below the crown; unchanged); the phantom (t = 15) 0.14, 0.29,
    0.36, 0.50, 0.48 against 1.28, 1.21, 1.05, 1.23, 1.18 (before 0.34, 2.55, 3.92, 3.96, 4.33). Not met: the
    phantom at t = 8 (its top two curves 39 mm apart), 2.03 / 3.65 deg at 35 / 40 mm against 1.24 / 1.18."""
    from pdehead_addon import defaults as D, extract_boundaries
    from pdehead_addon.pde import pde_spline
    from pdehead_addon.validation.surface_quality import CROWN_RADII_MM
    seg = {"cthead": cthead_seg, "ge": ge_seg, "phantom": phantom_seg}[name]
    bset = extract_boundaries(seg, patches=8 if name == "ge" else D.PATCHES.default,
                              samples=D.SAMPLES.default, selection=D.SELECTION.default)
    head, pde, mc = _crown_against_smoothed_mask(seg, bset)
    for rho in CROWN_RADII_MM:
        assert pde[rho] <= mc[rho], (rho, pde, mc)
    assert pde[5.0] <= 0.5 and pde[10.0] <= 0.5, pde
    height = pde_spline.dome_height(bset.curves, bset.heights, bset.meta.get("vertex_z"))
    assert abs(abs(head.vertex[2] - bset.curves[-1, :, 2].mean()) - height) <= 0.2
    if name == "cthead":                             # the filter is what meets it: without it the ridges come back
        import unittest.mock as mock
        with mock.patch.object(pde_spline, "CROWN_SIGMA_MM", 0.0), \
                mock.patch("pdehead_addon.pde.pde_surface.crown_low_pass",
                           lambda c, h, s, d: pde_spline.crown_low_pass(c, h, s, d, sigma_mm=0.0)):
            _, raw, _ = _crown_against_smoothed_mask(seg, bset)
        assert raw[40.0] > 1.5 * mc[40.0], raw


def test_edge_bends_finds_a_slit_and_skips_the_bottom_ring():
    """`surface_quality.edge_bends` (issue 41 item 4's measure): a smooth rippled head has no edge bending by
    more than 60 deg off its bottom ring; a ring pushed in to a slit between two rows bends edges by > 90."""
    from pdehead_addon.validation.surface_quality import edge_bends
    head = solve_pde(rippled_bset(), approximation_mm=0)
    mesh = head.surface(120, 240, caps=True)
    bends = edge_bends(mesh)
    assert (bends > 60).sum() == 0 and bends.max() > 0.0
    assert edge_bends(mesh, skip_u=None).max() >= bends.max()          # the cap's ring counted too
    u = np.asarray(mesh.vertex_attributes["u"])
    row = np.nonzero(np.isclose(u, np.unique(u)[60]))[0][:8]          # 8 columns of one ring ...
    slit = type(mesh)(vertices=mesh.vertices.copy(), quads=mesh.quads, triangles=mesh.triangles,
                      vertex_attributes=mesh.vertex_attributes)
    centre = slit.vertices[row].mean(axis=0)
    axis = head.spine(np.array([float(u[row[0]])]))[0]
    slit.vertices[row] = axis + 0.2 * (slit.vertices[row] - axis)    # ... pulled in to a slit
    assert (edge_bends(slit) > 90).sum() >= 8, centre


@pytest.mark.parametrize("name", ["cthead", "ge"])
def test_heads_have_no_slit_where_an_ear_meets_the_scalp(name, cthead_seg, ge_seg):
    """Issue 41 item 4 on CThead (t = 15) and GE (t = 8) at the add-on's defaults: edges bending by more than
    60 deg off the bottom ring (`surface_quality.edge_bends`). Where a star hull's web meets the outline behind
    an ear, the outline turned by up to 133 deg at one sample: a slit along the columns under the ears and at
    the jaw. Those corners (concave, turning > 60 deg) are arcs of 3 mm
    (`curve_sampling.round_sharp_polar_corners`). What is left at 120 x 240 is the smooth surface's own tight
    bends (its normal turns by up to 70 deg per mm under the ears, between curves 2 mm apart) that evenly
    spaced rows and columns cut across: the mesh the viewport shows places them where the normal turns
    (``fit_bends``, :func:`.surface_columns.bend_rows`, :func:`.surface_columns.bend_column_density`).
    Measured, fitted: CThead 120 x 240 0 edges > 60 deg (worst 58.8), 400 x 800 0 (19.2); GE 0 (31.8) and 0
    (9.6). Evenly spaced: CThead 72 (4 > 90, worst 98.2) and 0 (46.2), GE 5 (67.7) and 0 (35.6); without the
    fillet CThead 89 (17 > 90, 128.9) and 21 (82.0), GE 29 (4, 101.2) and 0 (51.7)."""
    import unittest.mock as mock

    from pdehead_addon import defaults as D, extract_boundaries
    from pdehead_addon.curves import curve_sampling
    from pdehead_addon.validation.surface_quality import edge_bends
    seg = {"cthead": cthead_seg, "ge": ge_seg}[name]

    def bends(fit_bends):
        bset = extract_boundaries(seg, patches=8 if name == "ge" else D.PATCHES.default,
                                  samples=D.SAMPLES.default, selection=D.SELECTION.default)
        head = solve_pde(bset)
        return [edge_bends(head.surface(nu, nv, caps=True, uv=False, fit_bends=fit_bends))
                for nu, nv in ((120, 240), (400, 800))]

    for fitted in bends(True):
        assert (fitted > 60).sum() == 0, ((fitted > 60).sum(), fitted.max())
    coarse, fine = bends(False)
    assert (fine > 60).sum() == 0 and fine.max() < 55, ((fine > 60).sum(), fine.max())
    with mock.patch.object(curve_sampling, "round_sharp_polar_corners", lambda radius, *a, **k: radius):
        sharp_coarse, sharp_fine = bends(False)
    if name == "cthead":
        assert (coarse > 60).sum() >= 50 and (coarse > 90).sum() >= 1          # even rows cut across the bends
        assert (sharp_fine > 60).sum() >= 10 and (sharp_coarse > 90).sum() >= 15      # the slits without the fillet
    else:
        assert (coarse > 60).sum() >= 1
        assert (sharp_coarse > 60).sum() >= 20 and sharp_coarse.max() > 90


def test_a_bend_fitted_mesh_keeps_its_topology_surface_and_uvs():
    """``PDEHead.surface(fit_bends=True)``: the same vertex and face counts as the evenly spaced mesh (the live
    sliders rebuild it in place), every vertex on the PDE surface at its (u, v), rows and columns closer where
    the normal turns, fixed per boundary set (a re-solved head of the same curves keeps them), clean UVs, and
    watertight with caps."""
    from pdehead_addon.pde.surface_columns import bend_rows, normal_turning
    from pdehead_addon.validation.surface_quality import edge_bends, uv_quality
    bset = rippled_bset()
    head = solve_pde(bset, approximation_mm=0)
    even, fit = head.surface(60, 120, caps=True), head.surface(60, 120, caps=True, fit_bends=True)
    assert len(fit.vertices) == len(even.vertices) and len(fit.quads) == len(even.quads)
    assert len(fit.triangles) == len(even.triangles)
    u, v = (np.asarray(fit.vertex_attributes[k]) for k in ("u", "v"))
    tube = np.arange(len(u)) < (60 - (head.vertex is not None)) * 120            # the tube's rows come first
    assert np.allclose(head.evaluate(u[tube], v[tube]), fit.vertices[tube], atol=1e-9)
    rows = np.unique(u[tube])
    assert rows[0] == 0.0 and np.all(np.diff(rows) > 0) and np.diff(rows).max() / np.diff(rows).min() > 1.2
    q = uv_quality(fit)
    assert q["mirrored"] == 0 and q["zero_area"] == 0
    polys = [np.asarray(fit.quads).reshape(-1, 4), np.asarray(fit.triangles).reshape(-1, 3)]
    a = np.concatenate([p.ravel() for p in polys])
    b = np.concatenate([np.roll(p, -1, 1).ravel() for p in polys])
    _, count = np.unique(np.minimum(a, b) * len(fit.vertices) + np.maximum(a, b), return_counts=True)
    assert np.all(count == 2)                                                   # watertight
    assert (edge_bends(fit) > 60).sum() == 0
    again = solve_pde(bset, approximation_mm=5.0).surface(60, 120, caps=True, fit_bends=True)
    assert np.array_equal(np.asarray(again.vertex_attributes["u"]), u)      # the rows belong to the curves
    # a sharp bend at u = 0.5 on a flat turning profile: the rows gather there
    fine = np.linspace(0.0, 1.0, 1001)
    turn = np.where(np.abs(fine[:-1] - 0.5) < 0.01, 10.0, 0.1)
    r = bend_rows(turn, fine, 41)
    assert r[0] == 0.0 and r[-1] == 1.0 and np.all(np.diff(r) > 0)
    assert ((r > 0.49) & (r < 0.51)).sum() >= 10 and np.diff(r).max() < 1.0 / 40 / 0.3
    # a cylinder's normal turns only around it: 360 deg along v, none along u
    uu = np.linspace(0.0, 1.0, 11)
    ang = 2 * np.pi * np.arange(64) / 64
    cyl = np.stack(np.broadcast_arrays(np.cos(ang)[None], np.sin(ang)[None], uu[:, None]), axis=-1)
    along_u, along_v = normal_turning(cyl, uu)
    assert np.allclose(along_u, 0.0, atol=1e-4) and np.allclose(along_v, 360.0 / 64)
