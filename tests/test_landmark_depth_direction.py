"""The direction a landmark's tissue depth is measured along (landmarks.exposed_normals, issues 22 / 24).

At the rim of an opening the nearest triangle's normal points into the opening; the exposed normal (the mean
normal of the bone within 6 mm whose own normal ray meets no other bone) is the bone's outer face's normal with
the opening bridged. A slab with a round hole: the rim's nearest normal leans 55 deg into the hole, the exposed
normal is the slab's (measured 5 deg on this 1 mm grid; 1.9 deg on a 0.5 mm grid)."""
from __future__ import annotations

import numpy as np
import pytest
from skimage.measure import marching_cubes

from pdehead_addon.landmarks import exposed_normals, snap_to_surface
from pdehead_addon.mesh import Mesh


@pytest.fixture(scope="module")
def holed_slab() -> Mesh:
    """An 8 mm slab (|z| < 4), 60 x 60 mm, with a round opening of radius 12 mm, meshed on a 1 mm grid."""
    ax = np.arange(-36.0, 37.0)
    x, y, z = np.meshgrid(ax, ax, ax, indexing="ij")
    solid = (np.abs(x) < 30) & (np.abs(y) < 30) & (np.abs(z) < 4) & (x ** 2 + y ** 2 > 12 ** 2)
    verts, faces, _, _ = marching_cubes(solid.astype(np.float32), 0.5)
    return Mesh(vertices=verts + ax[0], quads=np.zeros((0, 4), np.int64), triangles=faces[:, ::-1])


def _angle(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def test_rim_of_an_opening_is_measured_perpendicular_to_the_bone_beside_it(holed_slab):
    up = np.array([0.0, 0.0, 1.0])
    points = np.array([[12.0, 0.0, 4.0], [0.0, -12.0, 4.0], [22.0, 10.0, 4.0]])   # two rim points, one flat
    base, nearest = snap_to_surface(points, holed_slab)
    assert all(n @ up > 0 for n in nearest)                                          # outward winding
    exposed = exposed_normals(base, holed_slab, nearest_normals=nearest)
    # the rim's own triangle leans into the hole (measured 54.7 deg), the exposed normal is the slab's
    assert _angle(nearest[0], up) > 30 and _angle(nearest[1], up) > 30
    for e in exposed:
        assert _angle(e, up) < 10.0, e
    # on flat bone the direction is the local normal
    assert _angle(exposed[2], nearest[2]) < 3.0
