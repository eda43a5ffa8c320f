"""The scan's cut of a skull without a mandible (face_profile.scan_cut_plane, tilted_rows): issue 23, GE."""
import numpy as np

from pdehead_addon.core.mesh import Mesh
from pdehead_addon.forensic.face_profile import FaceGrid, scan_cut_plane, tilted_rows


def _sphere(radius=80.0, n=60):
    """A UV sphere (patient mm) as a triangle mesh."""
    th, ph = np.meshgrid(np.linspace(0, np.pi, n)[1:-1], np.linspace(0, 2 * np.pi, 2 * n, endpoint=False),
                         indexing="ij")
    v = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1).reshape(-1, 3) * radius
    v = np.vstack([v, [[0, 0, radius], [0, 0, -radius]]])
    return v


def _mesh(v):
    from scipy.spatial import ConvexHull
    return Mesh(v, np.zeros((0, 4), np.int64), ConvexHull(v).simplices.astype(np.int64))


def test_a_sphere_cut_by_a_tilted_slab_gives_the_slab_plane():
    tilt = np.radians(18.5)
    normal = np.array([0.0, -np.sin(tilt), -np.cos(tilt)])     # down and forward (-y): GE's slab
    v = _sphere()
    v = v[v @ normal <= 20.0]                                   # the slab's lower edge cuts it 20 mm off the centre
    # the cut's own outline: points on the plane
    ring = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    e1 = np.array([1.0, 0.0, 0.0])
    e2 = np.cross(normal, e1)
    rr = np.sqrt(80.0 ** 2 - 20.0 ** 2)
    v = np.vstack([v, 20.0 * normal + rr * (np.cos(ring)[:, None] * e1 + np.sin(ring)[:, None] * e2)])
    found = scan_cut_plane(_mesh(v))
    assert found is not None
    n, offset = found
    assert np.degrees(np.arccos(np.clip(n @ normal, -1, 1))) < 0.5
    assert abs(offset - 20.0) < 0.1


def test_a_whole_sphere_or_a_steep_cut_is_no_scan_cut():
    assert scan_cut_plane(_mesh(_sphere())) is None              # no flat bottom: nothing cut
    steep = np.array([0.0, -np.sin(np.radians(60)), -np.cos(np.radians(60))])
    v = _sphere()
    assert scan_cut_plane(_mesh(v[v @ steep <= 20.0])) is None   # a 60-degree cut is no slab's lower edge


def test_tilted_rows_end_on_the_lowered_plane_and_keep_the_top():
    grid = FaceGrid(np.zeros(2), np.arange(-60.0, 100.1, 2.5), np.arange(180) * 2 * np.pi / 180)
    zz = grid.z[:, None] + 0 * grid.theta[None, :]
    radius = 80.0 + 5.0 * np.cos(zz / 20.0)                      # a smooth head-like radius map
    tilt = np.radians(18.5)
    normal = np.array([0.0, -np.sin(tilt), -np.cos(tilt)])
    z, r = tilted_rows(grid, radius, (normal, 10.0), margin_mm=7.0)
    pts = grid.point(z, grid.theta[None, :], r)
    bottom = pts[0] @ normal
    assert np.allclose(bottom, 17.0, atol=0.3)                  # the lowest ring on the plane lowered by 7 mm
    assert np.allclose(z[-1], grid.z[-1])                        # the top row where it was
    assert np.all(np.diff(z, axis=0) > 0)                        # every column's rows still ascend
    # the radius is the map's own at the new heights (Catmull-Rom of a smooth map: 0.03 mm at worst, by the
    # top row, where the column's end is repeated)
    assert np.allclose(r, 80.0 + 5.0 * np.cos(z / 20.0), atol=0.05)
