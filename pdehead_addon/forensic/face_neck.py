"""The neck below the skull of the face from the skull: how the bone's radius map (:mod:`.face_profile`) is continued
below the skull base, where the rays meet the mandible, the mastoids and what is left of the cervical spine, none of
which is the neck's outline.

Each column recedes from the row above by at most :func:`neck_slope` mm per mm of height down to the neck, a circle
of :data:`NECK_RADIUS_MM` about an axis :data:`NECK_BEHIND_MM` behind the skull's. Behind and at the sides the slope
is :data:`NECK_SLOPE` (the occiput's curve into the nape); straight ahead it is :data:`SUBMENTAL_SLOPE`, from a
published lower face-throat angle [1]_: the skin under the chin runs back to the throat, not down in a straight
apron from the chin to the neck.

References
----------
.. [1] Celebi AA, Tan E, Gelgor IE, Colak T, Ayyildiz E. Comparison of soft tissue cephalometric norms between
       Turkish and European-American adults. The Scientific World Journal 2013:806203, doi:10.1155/2013/806203,
       Table 2 (Legan and Burstone's analysis; lower face-throat angle Sn-Gn'-C, 96 adults aged 20-27: men
       105.1 +- 8.1 deg, women 106.2 +- 7.9 deg), read at hindawi.com/journals/tswj/2013/806203/tab2.
"""
from __future__ import annotations

import numpy as np

#: The neck below the skull: radius (mm) of the neck about its axis, which lies this far behind the skull's centroid
#: axis. Adult neck circumference ~ 36-40 cm (anthropometric surveys, e.g. Ben-Noun et al. 2001, Obesity Research
#: 9(8):470-477: men 38.0 cm, women 32.5 cm mean; cited from memory of that survey, not re-read) -> radius ~ 55-60 mm.
#: It shapes only the neck, outside the scored face.
NECK_RADIUS_MM = 57.0
NECK_BEHIND_MM = 12.0
#: How fast the neck recedes below the skull base behind and at the sides (mm per mm of height: 0.8 ~ a 40 degree
#: slope; looked at on renders).
NECK_SLOPE = 0.8
#: The lower face-throat angle (deg) between the lower face's line (subnasale to soft-tissue gnathion) and the
#: submental line (soft-tissue gnathion to the throat's cervical point): the mean of the men's and the women's means
#: in [1]_. The lower face's line is taken parallel to the rows' axis (the scan's head-foot axis), so the submental
#: line falls ANGLE - 90 deg below the rows' plane.
LOWER_FACE_THROAT_DEG = 105.6
#: Straight ahead, how fast the skin under the chin recedes (mm per mm of height): 1 / tan(ANGLE - 90 deg), 3.6.
SUBMENTAL_SLOPE = 1.0 / float(np.tan(np.radians(LOWER_FACE_THROAT_DEG - 90.0)))


def neck_slope(theta: np.ndarray) -> np.ndarray:
    """Per column angle ``theta`` (rad, pi straight ahead: :class:`.face_profile.FaceGrid`), how fast the skin below
    the bone may recede (mm per mm of height): :data:`SUBMENTAL_SLOPE` straight ahead, :data:`NECK_SLOPE` from the
    sides backwards, blended by the square of the cosine from straight ahead (the submandibular skin between)."""
    front = np.maximum(-np.cos(np.asarray(theta, float)), 0.0) ** 2
    return NECK_SLOPE + (SUBMENTAL_SLOPE - NECK_SLOPE) * front


def neck_fill(raw: np.ndarray, grid, base_z: float | None = None) -> np.ndarray:
    """Fill bins that meet no bone, and shape the neck below the skull base.

    Gaps inside a column are interpolated along the height; above the skull's top row the top is
    repeated. Below ``base_z`` (the skull base) each column keeps its bone where the bone lies further out, and
    otherwise recedes from the row above by at most :func:`neck_slope` mm per mm of height (the occiput's curve
    into the nape, the chin's into the throat) down to the neck, a circle of :data:`NECK_RADIUS_MM` about an axis
    :data:`NECK_BEHIND_MM` behind the skull's axis. A rule, not a measurement of this head.
    """
    K, M = raw.shape
    out = raw.copy()
    good = np.isfinite(out)
    rows = np.arange(K)
    for j in np.nonzero(good.sum(0) >= 2)[0]:                 # gaps inside a column (per column: 180 at most)
        gi = np.nonzero(good[:, j])[0]
        inside = (rows >= gi[0]) & (rows <= gi[-1])
        out[inside, j] = np.interp(rows[inside], gi, out[gi, j])
    th = grid.theta
    b = NECK_BEHIND_MM
    neck = b * np.cos(th) + np.sqrt(np.maximum(NECK_RADIUS_MM ** 2 - (b * np.sin(th)) ** 2, 1.0))
    dz = grid.z[1] - grid.z[0]
    recede = neck_slope(th) * dz
    top = int(np.nonzero(np.isfinite(out).any(1))[0].max()) if np.isfinite(out).any() else K - 1
    kb = top if base_z is None else int(np.clip(np.floor((base_z - grid.z[0]) / dz), 0, top))
    for k in range(kb - 1, -1, -1):                           # downward from the skull base
        above = out[k + 1]
        bone = np.where(np.isfinite(out[k]), out[k], -np.inf)
        out[k] = np.maximum(bone, np.maximum(np.minimum(above, neck), above - recede))
    for k in range(1, K):                                     # above the top: repeat
        miss = ~np.isfinite(out[k]) & np.isfinite(out[k - 1])
        out[k, miss] = out[k - 1, miss]
    for k in range(K - 2, -1, -1):
        miss = ~np.isfinite(out[k]) & np.isfinite(out[k + 1])
        out[k, miss] = out[k + 1, miss]
    if not np.all(np.isfinite(out)):
        out[~np.isfinite(out)] = NECK_RADIUS_MM
    return out
