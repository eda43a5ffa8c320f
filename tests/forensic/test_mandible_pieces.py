"""The mandible's pieces (pdehead_addon.forensic.mandible_pieces) on a made frame: a ramus broken into a chain of
pieces comes back whole; an upper tooth, a piece above the condyles, a hyoid beyond one sample and the skull stay out;
the reach follows the scan's spacing. CThead's rami: test_auto_landmarks (the hand-placed landmarks)."""
import numpy as np

from pdehead_addon.forensic.mandible_pieces import join_mandible_pieces, pieces_nearer_the_mandible

SKULL, MAND, RAMUS_LOW, RAMUS_MID, CONDYLE, TOOTH, ABOVE, HYOID, FAR_PIECE = range(1, 10)


def _frame():
    """A 64^3 frame at 1 mm, z up: the skull's vault on top with a maxilla hanging down on the midline, the
    mandible's body and right ramus in one component, the left ramus in three pieces one slice apart."""
    comp = np.zeros((64, 64, 64), np.int32)
    comp[:, :, 56:62] = SKULL
    comp[28:34, 10:16, 16:56] = SKULL                # the maxilla, down to z = 16
    comp[10:52, 10:16, 5:11] = MAND                  # the body, z 5..10
    comp[10:13, 10:30, 5:41] = MAND                  # the right ramus up to z = 40
    comp[49:52, 10:30, 12:21] = RAMUS_LOW            # the left ramus: a one-slice gap above the body (z = 11)
    comp[49:52, 10:30, 22:31] = RAMUS_MID
    comp[49:52, 18:28, 32:41] = CONDYLE
    comp[29:33, 11:15, 13:15] = TOOTH                # an upper tooth: one slice below the maxilla, two above the body
    comp[49:52, 18:28, 42:51] = ABOVE                # one slice above the left condyle, up to 10 mm above its top
    comp[25:35, 12:14, 0:1] = HYOID                  # four slices below the body
    comp[56:59, 10:30, 12:20] = FAR_PIECE            # four pixels beside the left ramus
    return comp, comp > 0


def test_a_ramus_in_pieces_is_joined_and_the_rest_stays_out():
    comp, bone = _frame()
    joined = join_mandible_pieces(comp, bone, 1.0, MAND, SKULL, spacing=(1.0, 1.0, 2.0))
    assert sorted(joined) == [RAMUS_LOW, RAMUS_MID, CONDYLE]
    assert (comp == MAND).sum() == ((_frame()[0] == MAND) | np.isin(_frame()[0], joined)).sum()
    # the left ramus now reaches from the body to the condyle's top, as the right one does
    left = np.argwhere(comp[49:52] == MAND)
    assert left[:, 2].min() == 5 and left[:, 2].max() == 40
    for label in (SKULL, TOOTH, ABOVE, HYOID, FAR_PIECE):
        assert (comp == label).any(), label


def test_the_reach_follows_the_scans_spacing():
    """The gap a lost sample leaves is one slice: a piece 5 mm from the ramus is out of reach of 2 mm slices
    (reach 3 mm), within reach of 5 mm ones (reach 6 mm), as is the hyoid 5 mm below the body."""
    comp, bone = _frame()
    joined = join_mandible_pieces(comp, bone, 1.0, MAND, SKULL, spacing=(1.0, 1.0, 5.0))
    assert FAR_PIECE in joined and HYOID in joined
    assert TOOTH not in joined and ABOVE not in joined          # nearer the maxilla; above the condyles


def test_a_higher_top_lets_a_condyle_in():
    """Given the porions' height, a piece up to it (and one sample over) counts as the mandible's."""
    comp, bone = _frame()
    assert ABOVE not in join_mandible_pieces(comp, bone, 1.0, MAND, SKULL, (1.0, 1.0, 2.0), top_z_index=44)
    comp, bone = _frame()
    assert ABOVE in join_mandible_pieces(comp, bone, 1.0, MAND, SKULL, (1.0, 1.0, 2.0), top_z_index=48)


def test_pieces_nearer_the_upper_skeleton_are_not_the_mandibles():
    comp, bone = _frame()
    keep = pieces_nearer_the_mandible(comp, bone, 1.0, [TOOTH, RAMUS_LOW], comp == MAND)
    assert keep == [RAMUS_LOW]
    assert pieces_nearer_the_mandible(comp, bone, 1.0, [], comp == MAND) == []


def test_no_mandible_joins_nothing():
    comp, bone = _frame()
    before = comp.copy()
    assert join_mandible_pieces(comp, bone, 1.0, 99, SKULL, spacing=(1.0, 1.0, 2.0)) == []
    assert np.array_equal(comp, before)
