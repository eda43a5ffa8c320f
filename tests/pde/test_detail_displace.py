"""The CT detail as geometry: the PDE surface displaced along its normals by its detail map, and meshed at
print resolution, on a case whose answer is known (a PDE head through rings of a sphere, a ball's mask)."""
from __future__ import annotations

import numpy as np
import pytest

from pdehead_addon import PDEError, ct_detail_map, detail_surface, print_resolution
from pdehead_addon.pde import detail_displace as DDX, detail_map as DM
from test_ct_detail_map import R, _sphere_head, sphere_mask  # noqa: E402  (tests/pde on sys.path: rootdir-relative imports)


@pytest.fixture(scope="module")
def sphere_head():
    return _sphere_head()


@pytest.fixture(scope="module")
def outer_map(sphere_head):
    """The detail map of the sphere head against a ball 1.5 mm larger."""
    mask, ct = sphere_mask(R + 1.5)
    return ct_detail_map(sphere_head, mask, ct, resolution=256, sigma_mm=1.0, max_mm=3.0)


def test_sample_map_is_bilinear_at_texel_centres():
    res = 16
    yy, xx = np.mgrid[:res, :res].astype(float)
    height = (2.0 * xx - 3.0 * yy).astype(np.float32)          # linear: bilinear sampling is exact
    rng = np.random.default_rng(0)
    uv = rng.uniform(0.5 / res, 1 - 0.5 / res, (500, 2))
    got = DDX.sample_map(height, uv)
    truth = 2.0 * (uv[:, 0] * res - 0.5) - 3.0 * (uv[:, 1] * res - 0.5)
    assert np.abs(got - truth).max() < 1e-4
    # outside the centres it clamps to the border texels
    assert DDX.sample_map(height, np.array([[0.0, 0.0], [1.0, 1.0]])).tolist() == [0.0, 2.0 * 15 - 3.0 * 15]


@pytest.mark.parametrize("strength", [0.5, 1.0])
def test_displacement_moves_the_surface_to_the_skin_by_the_strength(sphere_head, outer_map, strength):
    base = sphere_head.surface(60, 128, caps=True)
    mesh = detail_surface(sphere_head, outer_map.height, strength, 60, 128)
    assert mesh.is_watertight() and mesh.vertices.shape == base.vertices.shape
    assert np.array_equal(mesh.quads, base.quads) and np.array_equal(mesh.triangles, base.triangles)
    normals = DDX.vertex_normals(base)
    moved = ((mesh.vertices - base.vertices) * normals).sum(axis=1)
    # along the normal only
    assert np.abs(np.linalg.norm(mesh.vertices - base.vertices, axis=1) - np.abs(moved)).max() < 1e-9
    r0, r1 = np.linalg.norm(base.vertices, axis=1), np.linalg.norm(mesh.vertices, axis=1)
    z = base.vertices[:, 2]
    side = (z > -40.0) & (z < 30.0) & (np.abs(normals[:, 2]) < DM.UP_FADE[0])   # full height, away from the ends
    assert side.sum() > 2000
    # the ball's skin lies 1.5 mm outside the sphere the curves came from: strength x that, within the map's
    # error (the binary ball's voxel steps, smoothed: test_ct_detail_map)
    reach = (R + 1.5) - r0[side]
    assert np.median(np.abs((r1 - r0)[side] - strength * reach)) < 0.08 * max(strength, 0.5)
    assert abs(np.median((r1 - r0)[side]) - strength * np.median(reach)) < 0.05


def test_strength_zero_is_the_pde_surface_and_the_cap_stays(sphere_head, outer_map):
    base = sphere_head.surface(40, 96, caps=True)
    same = detail_surface(sphere_head, outer_map.height, 0.0, 40, 96)
    assert np.array_equal(same.vertices, base.vertices)
    assert np.array_equal(detail_surface(sphere_head, None, 1.0, 40, 96).vertices, base.vertices)
    moved = detail_surface(sphere_head, outer_map.height, 1.0, 40, 96)
    shift = np.linalg.norm(moved.vertices - base.vertices, axis=1)
    # the bottom cap's inside (vertices after the tube's grid and the dome's pole) does not move; its rim
    # (the tube's first row) moves with the tube
    nu_rows = 39                                                    # the dome drops the pole row
    cap_inside = np.arange(nu_rows * 96, len(base.vertices) - 1)
    assert len(cap_inside) > 50 and shift[cap_inside].max() == 0.0
    assert np.median(shift[:96]) > 0.5


def test_chord_error_falls_with_the_square_of_the_edge(sphere_head):
    coarse = DDX.chord_error(sphere_head, 40, 80)
    fine = DDX.chord_error(sphere_head, 80, 160)
    # a sphere of radius 60 mm: the chord error of an edge h is ~ h^2 / (8 R)
    assert 0.15 < fine["max"] / coarse["max"] < 0.35, (coarse, fine)
    h = 2 * np.pi * R / 80
    assert 0.3 * h * h / (8 * R) < coarse["columns_max"] < 3.0 * h * h / (8 * R)


def test_print_resolution_meets_the_chord_error_within_the_budget(sphere_head):
    rows, nv = print_resolution(sphere_head, window=None)
    nu = len(rows)
    np.testing.assert_allclose(rows, np.linspace(0, 1, nu))            # no window: even rows
    err = DDX.chord_error(sphere_head, nu, nv)
    assert err["max"] <= DDX.PRINT_CHORD_MM, err
    mesh = sphere_head.surface(nu, nv, caps=True, uv=False)
    assert mesh.is_watertight() and 2 * len(mesh.quads) + len(mesh.triangles) <= DDX.PRINT_MAX_TRIANGLES
    # the edges carry a 1 mm feature: at most PRINT_EDGE_MM along the equator
    assert 2 * np.pi * R / nv <= DDX.PRINT_EDGE_MM * 1.01
    # a tight budget is kept (the counts scale down together)
    rows2, nv2 = print_resolution(sphere_head, window=None, max_triangles=100_000)
    small = sphere_head.surface(len(rows2), nv2, caps=True, uv=False)
    assert 80_000 < 2 * len(small.quads) + len(small.triangles) <= 100_000


def test_the_print_window_is_the_visible_face_measures(sphere_head):
    """The add-on does not ship validation/: its face window repeats surface_metrics.face_window's."""
    from pdehead_addon.validation import surface_metrics as SM
    assert (DDX.FACE_HALF_ANGLE_DEG, DDX.FACE_BELOW_MM, DDX.FACE_ABOVE_MM) == \
        (SM.FACE_HALF_ANGLE_DEG, SM.FACE_BELOW_MM, SM.FACE_ABOVE_MM)
    pts = sphere_head.surface(120, 256, caps=False, uv=False).vertices
    centre = pts[:, :2].mean(axis=0)
    tip = SM.pronasale(pts, centre)
    probe = np.random.default_rng(1).uniform(-80, 80, (5000, 3))
    assert np.array_equal(DDX.surface_window(sphere_head)(probe), SM.face_window(probe, centre, tip))


def test_split_quads_takes_the_diagonal_nearer_the_surface(sphere_head):
    """The exports split quads along corners 0-2: after split_quads that diagonal's midpoint is the nearer
    one to the surface, the vertices and the closed topology are kept, and the mesh's true chord error at
    the diagonals is chord_error's."""
    nu, nv = 30, 64
    base = sphere_head.surface(nu, nv, caps=True)
    mesh = DDX.split_quads(sphere_head, base, nu, nv)
    assert np.array_equal(mesh.vertices, base.vertices) and mesh.is_watertight()
    assert np.array_equal(np.sort(mesh.quads, axis=1), np.sort(base.quads, axis=1))
    rows = nu - 2                                            # the dome: the pole row is the fan's vertex
    u = np.linspace(0, 1, nu)[:-1]
    v = 2 * np.pi * np.arange(nv) / nv if sphere_head.v_density() is None else sphere_head.v_columns(nv)
    vm = 0.5 * (v + np.append(v[1:], v[0] + 2 * np.pi))
    centre = sphere_head.grid(0.5 * (u[:-1] + u[1:]), v=vm).reshape(-1, 3)
    q = mesh.quads[: rows * nv]
    p = mesh.vertices
    d02 = np.linalg.norm(0.5 * (p[q[:, 0]] + p[q[:, 2]]) - centre, axis=1)
    d13 = np.linalg.norm(0.5 * (p[q[:, 1]] + p[q[:, 3]]) - centre, axis=1)
    assert np.all(d02 <= d13 + 1e-12)
    assert d02.max() == pytest.approx(DDX.chord_error(sphere_head, nu, nv)["diagonal_max"], rel=1e-9)


def test_print_rows_are_denser_over_the_face_and_the_mesh_stays_closed(sphere_head, outer_map):
    """print_rows: rows evenly spaced over the window's band of u, PRINT_ROWS_OUTSIDE as dense elsewhere;
    the surface at those rows is closed, its UVs the same function of (u, v) (the map's displacement at
    strength 1 reaches the ball as with even rows)."""
    window = DDX.surface_window(sphere_head)
    rows = DDX.print_rows(sphere_head, 120, window)
    assert rows[0] == 0.0 and rows[-1] == 1.0 and np.all(np.diff(rows) > 0)
    step = np.diff(rows)
    assert step.max() / step.min() == pytest.approx(1.0 / DDX.PRINT_ROWS_OUTSIDE, rel=0.05)
    mesh = detail_surface(sphere_head, outer_map.height, 1.0, 120, 128, rows=rows, split=True)
    even = detail_surface(sphere_head, outer_map.height, 1.0, 120, 128)
    assert mesh.is_watertight()
    side = lambda m: np.abs(m.vertices[:, 2]) < 30.0                                  # noqa: E731
    r_rows = np.linalg.norm(mesh.vertices[side(mesh)], axis=1)
    r_even = np.linalg.norm(even.vertices[side(even)], axis=1)
    assert abs(np.median(r_rows) - np.median(r_even)) < 0.02 and abs(np.median(r_rows) - (R + 1.5)) < 0.15
    with pytest.raises(PDEError, match="increasing values"):
        sphere_head.surface(5, 32, rows=np.array([0.0, 0.5, 0.4, 0.8, 1.0]))
    # the chord error over the window at the same counts is smaller with the denser face rows
    assert DDX.chord_error(sphere_head, 60, 128, window, rows=DDX.print_rows(sphere_head, 60, window))["rows_max"] \
        < DDX.chord_error(sphere_head, 60, 128, window)["rows_max"]
