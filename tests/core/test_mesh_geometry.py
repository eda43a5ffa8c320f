"""pdehead_addon.core.mesh_geometry: the one copy of each mesh routine, on shapes with known answers."""
from __future__ import annotations

import numpy as np
import pytest

from pdehead_addon.core.mesh import Mesh
from pdehead_addon.core.mesh_geometry import (
    MeshDistance,
    closest_point_on_triangle,
    edge_neighbours,
    mesh_triangles,
    point_surface_distance,
    point_triangle_distance,
    points_inside,
    signed_volume,
)

TRI = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 3.0, 0.0]])


@pytest.mark.parametrize("point,closest", [
    ((1.0, 1.0, 2.0), (1.0, 1.0, 0.0)),        # above the interior
    ((2.0, -5.0, 1.0), (2.0, 0.0, 0.0)),       # beside edge ab
    ((-2.0, 1.5, 0.0), (0.0, 1.5, 0.0)),       # beside edge ac
    ((4.0, 3.0, 0.0), (2.56, 1.08, 0.0)),      # beside edge bc (foot of the perpendicular)
    ((-1.0, -1.0, 1.0), (0.0, 0.0, 0.0)),      # vertex a
    ((6.0, -1.0, 0.0), (4.0, 0.0, 0.0)),       # vertex b
    ((-1.0, 5.0, 0.0), (0.0, 3.0, 0.0)),       # vertex c
])
def test_closest_point_in_every_region(point, closest):
    p = np.array(point)
    q = closest_point_on_triangle(p, *TRI)
    np.testing.assert_allclose(q, closest, atol=1e-12)
    assert point_triangle_distance(p, *TRI) == pytest.approx(np.linalg.norm(p - np.array(closest)), abs=1e-12)


def test_closest_point_broadcasts_and_handles_degenerate_triangles():
    """Many points against many triangles at once; a triangle without area gives its nearest edge point."""
    p = np.array([[1.0, 1.0, 2.0], [5.0, 1.0, 0.0]])
    a = np.array([TRI[0], [0.0, 0.0, 0.0]])
    b = np.array([TRI[1], [2.0, 0.0, 0.0]])
    c = np.array([TRI[2], [4.0, 0.0, 0.0]])                                  # collinear: a segment 0..4 on x
    q = closest_point_on_triangle(p, a, b, c)
    np.testing.assert_allclose(q, [[1.0, 1.0, 0.0], [4.0, 0.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(point_triangle_distance(p, a, b, c), [2.0, np.hypot(1.0, 1.0)], atol=1e-12)
    point = np.zeros((1, 3))
    assert np.all(np.isfinite(closest_point_on_triangle(point, point + 1, point + 1, point + 1)))


def cube(size=2.0, quads=True):
    v = np.array([[x, y, z] for z in (0, size) for y in (0, size) for x in (0, size)], float)
    q = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]])
    if quads:
        return Mesh(v, q, np.zeros((0, 3), np.int64))
    return Mesh(v, np.zeros((0, 4), np.int64), np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))


def test_signed_volume_of_a_cube_with_quads_or_triangles_and_reversed():
    assert signed_volume(cube(2.0)) == pytest.approx(8.0, abs=1e-12)
    tri = cube(2.0, quads=False)
    assert signed_volume(tri) == pytest.approx(8.0, abs=1e-12)
    assert signed_volume(Mesh(tri.vertices, tri.quads, tri.triangles[:, ::-1])) == pytest.approx(-8.0, abs=1e-12)


def test_edge_neighbours_of_a_closed_cube():
    _, t = mesh_triangles(cube())
    nb = edge_neighbours(t)
    assert nb.shape == (12, 3) and np.all(nb != np.arange(12)[:, None])      # closed: no edge on a boundary
    for i in range(12):                                                      # each neighbour shares that edge
        for e in range(3):
            edge = {t[i, e], t[i, (e + 1) % 3]}
            assert edge <= set(t[nb[i, e]])


def test_mesh_distance_is_the_exact_distance_to_a_cube():
    """Points outside, inside and on a 2 mm cube: the distance to its surface is known in closed form."""
    v, t = mesh_triangles(cube())
    rng = np.random.default_rng(1)
    p = rng.uniform(-1.0, 3.0, (400, 3))
    outside = np.linalg.norm(np.maximum(0.0, np.maximum(-p, p - 2.0)), axis=1)
    inside = np.minimum(p, 2.0 - p).min(axis=1)
    exact = np.where(outside > 0, outside, inside)
    for dist in (MeshDistance(v, t, dense=20_000), MeshDistance(v, t, dense=20_000, candidates=8, neighbours=False)):
        np.testing.assert_allclose(dist(p, chunk=97), exact, atol=1e-12)
    np.testing.assert_allclose(point_surface_distance(p, v, t, dense=20_000), exact, atol=1e-12)


def test_points_inside_a_cube_and_a_sphere():
    """Ray parity against shapes whose inside is known: a 2 mm cube (rays through its edges and vertices too)
    and a sphere of 30 mm made of triangles (points near it judged against its polyhedron)."""
    v, t = mesh_triangles(cube())
    rng = np.random.default_rng(2)
    p = np.concatenate([rng.uniform(-1.0, 3.0, (2000, 3)), [[1.0, 1.0, 1.0], [0.0, 0.0, 1.0], [2.0, 2.0, -1.0]]])
    expected = np.all((p > 0) & (p < 2), axis=1)
    expected[-2:] = False                                          # on an edge and below a vertex: outside
    got = points_inside(p, v, t, cell_mm=0.7)
    edge = np.any(np.isclose(p, 0.0) | np.isclose(p, 2.0), axis=1)
    assert np.array_equal(got[~edge], expected[~edge]) and got[-3] and not got[-1]
    from skimage import measure
    grid = np.linalg.norm(np.mgrid[-40:41, -40:41, -40:41].astype(float), axis=0)
    sv, st, _, _ = measure.marching_cubes(grid, 30.0)
    sv -= 40.0
    q = rng.normal(size=(3000, 3))
    q *= (rng.uniform(20.0, 40.0, 3000) / np.linalg.norm(q, axis=1))[:, None]
    r = np.linalg.norm(q, axis=1)
    far = np.abs(r - 30.0) > 0.5                                   # the polyhedron is within 0.5 mm of the sphere
    assert np.array_equal(points_inside(q, sv, st)[far], r[far] < 30.0)
