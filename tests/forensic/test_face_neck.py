"""The neck below the skull (pdehead_addon.forensic.face_neck): the skin under the chin runs back to the throat at
the published lower face-throat angle, not down in a straight apron from the chin."""
import numpy as np

from pdehead_addon.forensic import face_neck as N
from pdehead_addon.forensic.face_profile import FaceGrid


def _grid(k=40, m=72, dz=2.0):
    return FaceGrid(np.zeros(2), np.arange(k) * dz, np.arange(m) * 2 * np.pi / m)


def test_the_submental_slope_is_the_published_lower_face_throat_angle():
    # Celebi et al. 2013, Table 2: 105.1 (men) and 106.2 deg (women); the submental line 15.6 deg below the rows
    assert N.LOWER_FACE_THROAT_DEG == 105.6
    assert abs(np.degrees(np.arctan(1.0 / N.SUBMENTAL_SLOPE)) - 15.6) < 1e-9
    th = np.array([np.pi, np.pi / 2, 0.0, 3 * np.pi / 4])
    s = N.neck_slope(th)
    np.testing.assert_allclose(s[:3], [N.SUBMENTAL_SLOPE, N.NECK_SLOPE, N.NECK_SLOPE], rtol=1e-12)
    assert N.NECK_SLOPE < s[3] < N.SUBMENTAL_SLOPE                              # the submandibular skin between


def test_below_the_bone_the_front_recedes_to_the_throat_and_the_back_to_the_nape():
    g = _grid()
    raw = np.full((len(g.z), len(g.theta)), np.nan)
    raw[20:] = 90.0                                                               # bone from row 20 up, radius 90
    out = N.neck_fill(raw, g, base_z=float(g.z[20]))
    front, back = len(g.theta) // 2, 0
    dz = g.z[1] - g.z[0]
    np.testing.assert_allclose(out[20:, front], 90.0)
    # straight ahead: 3.6 mm per mm of height (7.2 mm a row) down to the neck's front, 45 mm from the axis
    np.testing.assert_allclose(out[19, front], 90.0 - N.SUBMENTAL_SLOPE * dz)
    neck_front = N.NECK_RADIUS_MM - N.NECK_BEHIND_MM
    assert out[20 - 7, front] == neck_front and out[0, front] == neck_front
    # behind: 0.8 mm per mm, the nape's slower curve down to the neck's back (69 mm)
    np.testing.assert_allclose(out[19, back], 90.0 - N.NECK_SLOPE * dz)
    np.testing.assert_allclose(out[10, back], max(90.0 - 10 * N.NECK_SLOPE * dz, N.NECK_RADIUS_MM + N.NECK_BEHIND_MM))
    # no column rises again below the bone
    assert np.all(np.diff(out[:21], axis=0) >= -1e-9)
