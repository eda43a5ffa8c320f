"""The direction a landmark's tissue depth is measured along (landmarks.exposed_normals, issues 22 / 24).

At the rim of an opening the nearest triangle's normal points into the opening; the exposed normal (the mean
normal of the bone within 6 mm whose own normal ray meets no other bone) is the bone's outer face's normal with
the opening bridged. A slab with a round hole: the rim's nearest normal leans 55 deg into the hole, the exposed
normal is the slab's (measured 5 deg on this 1 mm grid; 1.9 deg on a 0.5 mm grid)."""
from __future__ import annotations

import numpy as np
import pytest
from skimage.measure import marching_cubes

from pdehead_addon.core.mesh import Mesh
from pdehead_addon.forensic.landmarks import exposed_normals, snap_to_surface


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
    from pdehead_addon.forensic.landmarks import landmark_depths, marker_pegs
    from pdehead_addon.forensic.tissue_depth import cast_rays

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
    for i, (name, peg_base, peg_dir, _length) in enumerate(pegs):
        assert name == list(lms)[i] and np.allclose(peg_base, depths[name][0])
        assert abs(np.linalg.norm(peg_dir) - 1.0) < 1e-9
        assert _angle(peg_dir, measured_direction[i]) < 1.0, name
        along_peg = cast_rays(peg_base[None], peg_dir[None], skin, 60.0)[0]
        assert abs(along_peg - depths[name][1]) < 0.05, (name, along_peg, depths[name][1])
    # at the rims, the nearest triangle's normal (what the pegs stood on before) is far from the peg
    assert _angle(pegs[0][2], nearest[0]) > 30.0 and _angle(pegs[1][2], nearest[1]) > 30.0


def test_one_depth_function_on_the_ct_with_a_mesh_fallback(holed_slab):
    """measure_landmark_depths (every depth output's: the batch's landmarks.csv, the add-on's Export Landmark
    Depths and Export for Printing) measures on the CT's intensities when it has them, and falls back to the meshes,
    saying so, when it has not. The CT's skin lies 6 mm above the slab's top; the skin mesh 8 mm (a PDE skin that
    smooths over): the CT method gives 6 mm (measured 6.00), the meshes 8 mm."""
    from types import SimpleNamespace

    from scipy.special import erfc

    from pdehead_addon.core.ct_volume import CTVolume
    from pdehead_addon.forensic.depth_on_ct import depth_flags, measure_landmark_depths
    from pdehead_addon.forensic.landmarks import landmark_depths

    ax = np.arange(-40.0, 41.0)
    z, y, x = np.meshgrid(ax, ax, ax, indexing="ij")
    bone = np.minimum.reduce([30 - np.abs(x), 30 - np.abs(y), 4 - np.abs(z), np.hypot(x, y) - 12])  # > 0 inside
    edge = lambda d: 0.5 * erfc(-d / (np.sqrt(2.0) * 0.8))                                      # noqa: E731
    hu = -1000.0 + 1040.0 * edge(10.0 - z) + 1060.0 * edge(bone)
    ct = CTVolume(hu.astype(np.float32), (1.0, 1.0, 1.0), origin=(ax[0], ax[0], ax[0]), direction=np.eye(3))
    seg = SimpleNamespace(hu=ct.data, ct=ct, bone_level=570.0, c2=40.0, meta={"has_skin": True,
                                                                               "histogram": {"bone_mode": 1100.0}})
    gx, gy = np.meshgrid(np.arange(-40.0, 41.0, 4.0), np.arange(-40.0, 41.0, 4.0), indexing="ij")
    verts = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, 12.0)], 1)
    n = gx.shape[0]
    q = np.array([[i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1] for i in range(n - 1) for j in range(n - 1)]
                 + [[i * n + j, (i + 1) * n + j + 1, i * n + j + 1] for i in range(n - 1) for j in range(n - 1)])
    skin = Mesh(vertices=verts, quads=np.zeros((0, 4), np.int64), triangles=q)
    lms = {"Glabella": np.array([22.0, 10.0, 4.0]), "Vertex": np.array([-20.0, -15.0, 4.0])}

    on_ct = measure_landmark_depths(lms, holed_slab, skin, seg)
    on_mesh = measure_landmark_depths(lms, holed_slab, skin, None)
    mesh_only = landmark_depths(lms, holed_slab, skin)
    for name in lms:
        assert on_ct[name].method == "ct" and on_ct[name].trusted, on_ct[name].evidence
        assert on_ct[name].depth == pytest.approx(6.0, abs=0.1)
        assert on_mesh[name].method == "mesh" and on_mesh[name].evidence.startswith("no CT intensities")
        assert on_mesh[name].depth == mesh_only[name][1] == pytest.approx(8.0, abs=0.6)
    seg.meta["has_skin"] = False                        # a dry skull: the CT's skin level means nothing
    assert {m.method for m in measure_landmark_depths(lms, holed_slab, skin, seg).values()} == {"mesh"}
    no_skin = measure_landmark_depths(lms, holed_slab, None, seg)
    assert all(np.isnan(m.depth) and m.evidence.startswith("no skin") for m in no_skin.values())
    # a depth the CT's profile does not support turns an ok landmark uncertain; other flags stay
    on_ct["Vertex"].trusted = False
    assert depth_flags({"Glabella": "ok", "Vertex": "ok"}, on_ct) == {"Glabella": "ok", "Vertex": "uncertain"}
    assert depth_flags({"Vertex": "not_found"}, on_ct) == {"Vertex": "not_found"}
    assert depth_flags({}, on_ct) == {"Vertex": "uncertain"}        # a placed landmark without a flag


@pytest.mark.parametrize("sigma", [0.9, 1.2, 1.6])
def test_slice_edge_spread_is_measured_on_the_skin(sigma):
    """A head-sized ball of soft tissue in air, its edge blurred by a Gaussian of s.d. ``sigma`` and sampled point-
    wise on 4.3 mm slices of 2 mm pixels: the spread across the slices is recovered from the skin alone."""
    from scipy.special import ndtr

    from pdehead_addon.forensic.depth_on_ct import slice_edge_spread

    h, px, radius = 4.3, 2.0, 80.0
    z = (np.arange(48) - 23.7) * h
    y = (np.arange(96) - 47.5) * px
    zz, yy, xx = np.meshgrid(z, y, y, indexing="ij")
    r = np.sqrt(xx ** 2 + yy ** 2 + (zz / 1.1) ** 2)          # a little taller than wide
    vol = -1000.0 + 1040.0 * ndtr((radius - r) / sigma)
    got, n = slice_edge_spread(vol, (h, px, px), -1000.0, 40.0)
    assert n >= 500
    assert got == pytest.approx(sigma, rel=0.12), (sigma, got, n)


def test_step_crossing_locates_an_edge_between_two_slices():
    """An edge blurred by 1.2 mm sampled 4.3 mm apart at every phase: the linear crossing of the half-way level
    between the two slices either side is off by up to ~0.6 mm with the edge's place; the blurred-step model
    with the spread recovers it within 0.05 mm, also for a level off half way (the bone's)."""
    from scipy.special import ndtr, ndtri

    from pdehead_addon.forensic.depth_on_ct import step_crossing

    sigma, h, inside, outside = 1.2, 4.3, 1300.0, 40.0
    worst_linear, worst_model = 0.0, 0.0
    for level in (670.0, 555.0):
        # where the level crosses the blurred profile relative to the edge (s_e - sigma * Phi^-1(f_level))
        fl = (level - outside) / (inside - outside)
        for edge in np.linspace(0.0, h, 23, endpoint=False):
            samples = np.arange(-2, 3) * h
            values = outside + (inside - outside) * ndtr((edge - samples) / sigma)
            truth = edge - sigma * ndtri(fl)
            i = np.flatnonzero((values[:-1] >= level) & (values[1:] < level))[0]
            linear = samples[i] + (values[i] - level) / (values[i] - values[i + 1]) * h
            model = step_crossing(samples[i:i + 2], values[i:i + 2], level, inside, outside, sigma)
            worst_linear = max(worst_linear, abs(linear - truth))
            worst_model = max(worst_model, abs((linear if model is None else model) - truth))
    assert worst_linear > 0.4 and worst_model < 0.05, (worst_linear, worst_model)
    # no sample on the edge's slope: no model answer
    assert step_crossing(np.array([0.0, h]), np.array([1300.0, 40.0]), 555.0, 1300.0, 40.0, 0.3) is None
