"""The skull's closed outer envelope in 3-D (:mod:`pdehead_addon.forensic.face_envelope`), read on the face's grid."""
from __future__ import annotations

import numpy as np
import pytest
from skimage import measure

from pdehead_addon import Mesh
from pdehead_addon.forensic.face_envelope import envelope_radius, surface_points
from pdehead_addon.forensic.face_profile import FaceGrid

RADIUS = 70.0
PIT_MM = 40.0             # a pit about an orbit's width and depth, straight ahead (-y)
PIT_DEPTH_MM = 30.0


def _shell(pit: bool) -> Mesh:
    """A ball (radius 70 mm) about the origin, from a 1 mm marching-cubes grid (its surface lies at 70.5 mm); with
    ``pit`` a round pit PIT_MM wide and PIT_DEPTH_MM deep straight ahead into it (as the orbit is into the face)."""
    ax = np.arange(-80.0, 81.0)
    x, y, z = np.meshgrid(ax, ax, ax, indexing="ij")
    r = np.sqrt(x * x + y * y + z * z)
    solid = r <= RADIUS
    if pit:
        solid &= ~((y < -(RADIUS - PIT_DEPTH_MM)) & (np.hypot(x, z) < 0.5 * PIT_MM))
    verts, faces, _, _ = measure.marching_cubes(solid.astype(np.float32), 0.5)
    return Mesh(vertices=verts + ax[0], quads=np.zeros((0, 4)), triangles=faces)


def _grid() -> FaceGrid:
    return FaceGrid(np.zeros(2), np.arange(-40.0, 41.0, 4.0), np.arange(180) * 2 * np.pi / 180)


def test_surface_points_cover_every_triangle_within_the_spacing():
    """Points on a long thin triangle no farther apart than asked: every point of it lies within the spacing of one."""
    from scipy.spatial import cKDTree
    tri = Mesh(vertices=[[0, 0, 0], [30, 0, 0], [0, 5, 0]], quads=np.zeros((0, 4)), triangles=[[0, 1, 2]])
    pts = surface_points(tri, 1.0)
    u, w = np.random.default_rng(0).random((2, 2000))
    inside = u + w <= 1
    probe = np.column_stack([30 * u[inside], 5 * w[inside], np.zeros(inside.sum())])
    assert cKDTree(pts).query(probe)[0].max() <= 1.0


def test_envelope_of_a_sphere_is_the_sphere():
    """On a closed sphere the envelope's radius is the sphere's at every row (the smoothing's shrink is
    sigma^2 / 2R ~ 0.2 mm), and it does not vary around the head by more than the voxel's steps."""
    g = _grid()
    r = envelope_radius(_shell(False), g, closing_mm=30.0)
    want = np.sqrt((RADIUS + 0.5) ** 2 - g.z ** 2)[:, None]
    assert np.all(np.isfinite(r))
    assert np.abs(r - want).max() < 1.0
    assert np.ptp(r, axis=1).max() < 1.0


@pytest.mark.parametrize("closing", [0.0, 30.0])
def test_closing_bridges_a_pit_as_wide_as_an_orbit(closing):
    """A 40 mm wide, 30 mm deep pit: a 30 mm ball bridges it but for the ball's sagitta over the opening
    (R - sqrt(R^2 - (D/2)^2) = 7.6 mm, less the sphere's own 2.9 mm: ~ 5 mm under the sphere) and the Gaussian's
    rounding of the pit's rim (~ 3 mm more: 62.4-63.0 mm measured); without a closing the rays meet the pit's floor."""
    g = _grid()
    r = envelope_radius(_shell(True), g, closing_mm=closing)
    ahead = np.abs(np.angle(np.exp(1j * (g.theta - np.pi)))) < np.radians(4.0)     # theta = pi: straight ahead (-y)
    mid = np.abs(g.z) < 5.0
    through = r[np.ix_(mid, ahead)]
    assert np.all(np.isfinite(through))
    if closing > 0:
        assert np.all(through > RADIUS - 10.0)
    else:
        assert np.all(through < RADIUS - PIT_DEPTH_MM + 5.0)


def _tilted_plate(base: np.ndarray, tilt_deg: float) -> Mesh:
    """A 10 mm square plate through ``base`` whose normal leans ``tilt_deg`` up from the outward horizontal (-y)."""
    a = np.radians(tilt_deg)
    normal = np.array([0.0, -np.cos(a), np.sin(a)])
    u = np.array([1.0, 0.0, 0.0])
    w = np.cross(normal, u)
    corners = base + 5.0 * np.array([-u - w, u - w, u + w, -u + w])
    return Mesh(vertices=corners, quads=np.zeros((0, 4)), triangles=[[0, 1, 2], [0, 2, 3]])


def test_a_pegs_direction_turns_smoothly_from_the_bones_normal_to_the_profiles():
    """A peg on a plate tilted more and more from a cylinder's outward normal: the bone's normal while it leans
    less than the blend's first angle, the profile's beyond its second, and no jump between (a switch at 45 degrees
    turned GE's pegs by up to 50 degrees for a 1 mm move of their bases)."""
    from pdehead_addon.forensic.face_profile import PEG_NORMAL_BLEND_DEG, peg_normals
    grid = _grid()
    profile = np.full((grid.z.size, grid.theta.size), 80.0)               # a cylinder: its normal is horizontal
    base = np.array([[0.0, -80.0, 0.0]])                                  # straight ahead (theta = pi)
    tilts = np.arange(20.0, 71.0, 0.5)
    dirs = np.array([peg_normals(_tilted_plate(base[0], t), base, grid, profile)[0] for t in tilts])
    outward = np.array([0.0, -1.0, 0.0])
    lean = np.degrees(np.arccos(np.clip(dirs @ outward, -1, 1)))           # the peg's lean from the profile's normal
    lo, hi = PEG_NORMAL_BLEND_DEG
    np.testing.assert_allclose(lean[tilts <= lo], tilts[tilts <= lo], atol=0.5)   # the bone's normal
    assert np.all(lean[tilts >= hi] < 1.0)                                          # the profile's
    steps = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", dirs[1:], dirs[:-1]), -1, 1)))
    assert steps.max() < 3.0, f"the peg's direction jumps by {steps.max():.1f} degrees for a 0.5 degree tilt"
    assert lean.max() < lo + 1.0                     # turned towards the profile, never beyond the blend's start


def test_a_peg_on_a_bone_thinner_than_its_normals_radius_stands_on_the_profiles_normal():
    """Both faces of a 1 mm bone plate lie within the radius the bone's normal is averaged over: their normals cancel
    and what is left is noise (the phantom's nasal bones: the sum 0.00 of the lengths' sum; the mid-nasal peg turned by
    44 degrees under a 15-degree pitch of the head). Such a peg stands on the profile's normal; a one-sided plate
    tilted as much keeps the bone's. (The slab's faces differ by 2 % in area, so what is left points along the plate's
    normal, 30 degrees from the profile's, which the angle's blend alone would keep.)"""
    from pdehead_addon.forensic.face_profile import peg_normals
    grid = _grid()
    profile = np.full((grid.z.size, grid.theta.size), 80.0)
    base = np.array([[0.0, -80.0, 0.0]])
    outer = _tilted_plate(base[0], 30.0)
    inner = _tilted_plate(base[0] + np.array([0.0, 1.0, 0.0]), 30.0)
    centre = inner.vertices.mean(axis=0)
    inner_v = centre + 0.99 * (inner.vertices - centre)          # 2 % less area: the sum is 1 % of the lengths'
    slab = Mesh(vertices=np.concatenate([outer.vertices, inner_v]), quads=np.zeros((0, 4)),
                triangles=np.concatenate([outer.triangles, inner.triangles[:, ::-1] + 4]))   # the inner face inward
    one_sided = peg_normals(outer, base, grid, profile)[0]
    thin = peg_normals(slab, base, grid, profile)[0]
    assert np.degrees(np.arccos(one_sided @ np.array([0.0, -1.0, 0.0]))) == pytest.approx(30.0, abs=0.5)
    np.testing.assert_allclose(thin, [0.0, -1.0, 0.0], atol=1e-6)
