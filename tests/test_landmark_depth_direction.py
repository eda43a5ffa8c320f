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


def test_pegs_stand_along_the_direction_the_depth_is_measured(holed_slab):
    """marker_pegs and landmark_depths share one direction: at a rim the peg does not lean into the opening.

    The skin is a plane tilted 45 deg over the slab, so the measured depth depends on the direction: the depth
    cast along the peg equals landmark_depths' (measured: 21.64 / 10.63 / 32.50 mm both ways, identical), and the peg
    is within 1 deg of the direction landmark_depths uses (measured 0.0 deg) while the nearest triangle's normal, what
    the pegs stood on before, is 51.3 / 50.4 deg off at the two rims (the old code fails here)."""
    from pdehead_addon.landmarks import landmark_depths, marker_pegs
    from pdehead_addon.tissue_depth import cast_rays

    ax = np.arange(-44.0, 45.0, 4.0)                                  # a coarse grid: the field is piecewise linear
    x, y, z = np.meshgrid(ax, ax, ax, indexing="ij")
    inside = np.minimum.reduce([20.0 + 0.5 * x + 0.5 * y - z, 38 - np.abs(x), 38 - np.abs(y), z + 20])
    verts, faces, _, _ = marching_cubes(inside.astype(np.float32), 0.0, spacing=(4.0, 4.0, 4.0))
    skin = Mesh(vertices=verts + ax[0], quads=np.zeros((0, 4), np.int64), triangles=faces)

    lms = {"Nasion": np.array([12.0, 0.0, 4.0]), "Orbitale L": np.array([0.0, -12.0, 4.0]),
           "Glabella": np.array([22.0, 10.0, 4.0])}                      # two rim points, one on flat bone
    pegs = marker_pegs(lms, holed_slab, {"Nasion": 6.0, "Orbitale L": 6.5, "Glabella": 5.5})
    depths = landmark_depths(lms, holed_slab, skin)
    base, nearest = snap_to_surface(np.array(list(lms.values())), holed_slab)
    measured_direction = exposed_normals(base, holed_slab, nearest_normals=nearest)   # as landmark_depths does
    for i, (name, peg_base, peg_dir, length) in enumerate(pegs):
        assert name == list(lms)[i] and np.allclose(peg_base, depths[name][0])
        assert abs(np.linalg.norm(peg_dir) - 1.0) < 1e-9
        assert _angle(peg_dir, measured_direction[i]) < 1.0, name
        along_peg = cast_rays(peg_base[None], peg_dir[None], skin, 60.0)[0]
        assert abs(along_peg - depths[name][1]) < 0.05, (name, along_peg, depths[name][1])
    # at the rims, the nearest triangle's normal (what the pegs stood on before) is far from the peg
    assert _angle(pegs[0][2], nearest[0]) > 30.0 and _angle(pegs[1][2], nearest[1]) > 30.0
