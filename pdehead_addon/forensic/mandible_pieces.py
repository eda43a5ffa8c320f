"""The mandible's pieces on the landmark frame: bone the threshold split from the mandible (lower teeth, a thin ramus,
a coronoid, a condyle's neck) found by its gap to the mandible and to the rest of the skeleton.

A ramus is 1-3 mm of cortex in places. Where it falls below the bone level on a slice or a pixel, the mandible's
component ends there and the rest of the ramus is a separate piece, one sample away. Its landmarks (gonion, mid-ramus,
which is placed from the condyle's top) would then be read off what is left: on CThead at its own level the left ramus
and both coronoids lie in about 30 pieces, and mid-ramus L was placed 24 mm too low.

References
----------
.. [1] Spoor CF, Zonneveld FW, Macho GA (1993). Linear measurements of cortical bone and dental enamel by computed
   tomography: applications and problems. Am J Phys Anthropol 91(4):469-484. (Thin bone below the half-maximum
   level of its own voxels: a plate thinner than about one voxel is lost at a fixed threshold.)
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

#: A piece of bone counts as the mandible's when it lies within this (mm) of it and no farther from it than from the
#: rest of the skeleton (:func:`pieces_nearer_the_mandible`).
PIECE_REACH_MM = 10.0


def pieces_nearer_the_mandible(comp: np.ndarray, bone: np.ndarray, step: float, pieces: list[int],
                               mandible: np.ndarray) -> list[int]:
    """Of the bone ``pieces`` (labels in ``comp``), those of the mandible: a piece counts as the mandible's when its gap
    (mm) to ``mandible`` (a mask) is no larger than its gap to the rest of the bone (every other voxel of ``bone``; the
    pieces themselves left out), both measured within :data:`PIECE_REACH_MM` of it (a piece with neither within reach
    is left out). Lower teeth split from the mandible lie next to it; a palate or upper teeth split from the skull lie
    next to the upper skeleton.

    Parameters
    ----------
    comp, bone : ndarray
        The frame's component labels and bone mask (same shape).
    step : float
        The frame's grid step (mm).
    pieces : list of int
        Candidate labels.
    mandible : ndarray of bool
        The mandible as it stands.
    """
    if not pieces:
        return []
    inside = np.isin(comp, pieces)
    where = np.argwhere(inside)
    reach = int(np.ceil(PIECE_REACH_MM / step))
    lo = np.maximum(where.min(0) - reach, 0)
    hi = np.minimum(where.max(0) + reach + 1, comp.shape)
    box = tuple(slice(a, b) for a, b in zip(lo, hi))
    comp_b, piece, mand = comp[box], inside[box], mandible[box]
    upper = bone[box] & ~mand & ~piece
    far = PIECE_REACH_MM + step
    to_mand = ndimage.distance_transform_edt(~mand, sampling=step) if mand.any() else np.full(mand.shape, far)
    to_upper = ndimage.distance_transform_edt(~upper, sampling=step) if upper.any() else np.full(mand.shape, far)
    labels = np.asarray(pieces)
    gap_m = ndimage.minimum(to_mand, comp_b, labels)
    gap_u = ndimage.minimum(to_upper, comp_b, labels)
    return [int(i) for i, gm, gu in zip(labels, np.atleast_1d(gap_m), np.atleast_1d(gap_u))
            if gm <= min(gu, PIECE_REACH_MM)]


def join_mandible_pieces(comp: np.ndarray, bone: np.ndarray, step: float, mand_id: int, skull_id: int,
                         spacing, top_z_index: int | None = None) -> list[int]:
    """Give the mandible's pieces its label in ``comp`` (in place); returns the labels joined.

    A piece is joined when it lies within one sample of the scan plus one step of the frame of the mandible as it
    stands (the gap thin bone leaves where it falls below the level: one slice or pixel, widened by the resampling),
    reaches no higher than the mandible's top (or ``top_z_index``, the condyles' height, when higher) by that much,
    and is no farther from the mandible than from the rest of the skeleton (:func:`pieces_nearer_the_mandible`). This
    is repeated from the grown mandible until nothing more is joined: a ramus broken into a chain of pieces comes back
    whole. The skull's own component (``skull_id``) and bone no component reached (label 0) are never joined.

    Parameters
    ----------
    comp, bone : ndarray
        The frame's component labels (changed in place) and bone mask, indexed [x, y, z] with z up.
    step : float
        The frame's grid step (mm).
    mand_id, skull_id : int
        The mandible's and the skull's labels.
    spacing : sequence of float
        The scan's voxel spacing (mm): its largest value is the gap a lost slice leaves.
    top_z_index : int, optional
        A frame z index the mandible's top may reach (the porions' height: the condyles sit in front of the ear canals).
    """
    mand = comp == mand_id
    if not mand.any():
        return []
    reach = int(np.ceil((float(max(spacing)) + step) / step))
    objects = ndimage.find_objects(comp)
    piece_top = np.array([-1 if s is None else s[2].stop - 1 for s in objects])      # label i at [i - 1]
    top = int(np.flatnonzero(mand.any((0, 1))).max())
    if top_z_index is not None:
        top = max(top, int(top_z_index))
    joined: list[int] = []
    while True:
        where = np.argwhere(mand)
        lo = np.maximum(where.min(0) - reach, 0)
        hi = np.minimum(where.max(0) + reach + 1, comp.shape)
        box = tuple(slice(a, b) for a, b in zip(lo, hi))
        near = ndimage.maximum_filter(mand[box].view(np.uint8), size=2 * reach + 1).astype(bool)
        touched = np.unique(comp[box][near & ~mand[box]])
        cand = [int(i) for i in touched if i not in (0, skull_id, mand_id) and i not in joined
                and piece_top[i - 1] <= top + reach]
        keep = pieces_nearer_the_mandible(comp, bone, step, cand, mand)
        if not keep:
            break
        joined += keep
        mand |= np.isin(comp, keep)
    if joined:
        comp[np.isin(comp, joined)] = mand_id
    return joined
