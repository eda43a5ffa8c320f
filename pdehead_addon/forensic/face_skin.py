"""The skin over the face from the skull smoothed as a whole: the bone's closed profile plus the tissue-depth field
(:meth:`.face_from_skull.FaceModel.shaped_radius`, before the nose, the lips, the eyes and the ears are added).

Each part is smooth alone, but the profile steps where a row meets or leaves a bone edge (the zygoma's lower border,
the alveolar ridge; :func:`.face_profile.bone_profile` closes each row on its own) and the field changes by 15-20 mm
between neighbouring pegs (supra M2's 26 mm beside zygomatic arch's 7.5 mm in the T-Table), and their sum printed
shelves under the cheekbones and lumps over the cheeks and the jaw, which a skin over fat and muscle does not have.
:func:`smooth_skin` smooths it over the surface below the brows with a twiced Gaussian [1]_ (the kernel 2G - G*G,
which flattens the broad shape of brows and cheekbones far less than G alone), and lifts it back over a bone crest
the smoothing lowered onto the bone floor. What the smoothing took off the peg tips is then put back by the depth
field's own narrow correction (:meth:`.face_from_skull.FaceModel._smooth_face`): the face still passes through the
tips as the field did (a damped peg as near as before), with bumps of the few millimetres the smoothing moved a tip
instead of the field's swings of 15-20 mm.

References
----------
.. [1] Tukey JW. Exploratory Data Analysis. Addison-Wesley, 1977 ("twicing": a smoother's residual smoothed again
       and added back).
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from .face_profile import FLOOR_ROUND_MM, FaceGrid, round_floor, row_and_column_mm, surface_smooth

#: The smoothing's length over the surface (mm, :func:`.face_profile.surface_smooth`): the width of the depth field's
#: own narrow Gaussians (:data:`.face_field.NARROW_FRACTION` x the default spread, 0.5 x 22 mm), the finest thing the
#: field can place between the pegs. Checked on renders of the phantom, GE and CThead (8 / 12 / 16 / 20 mm: from 16
#: the face turns to a flat mask with bands at the jaw) and on scores (within +-2.5 mm, off -> 11 mm: GE 54.4 -> 54.8,
#: the phantom 42.5 -> 42.4, CThead stripped at 1500 / 1600 53.1 / 53.6 -> 53.0 / 53.7 %); GE's and the phantom's
#: scores alone would have taken 20 mm (57.2 / 44.1 %), CThead's 8-12. (The figures are without the tips put back.)
FACE_SMOOTH_MM = 11.0
#: Above the brows (the highest of glabella and the supraorbitals) the smoothing fades out over this height (mm): the
#: vault is smooth bone under an even scalp, and the dome's closing rows must not be pulled out.
FACE_SMOOTH_TOP_MM = 15.0
BROW_LANDMARKS = ("Glabella", "Supraorbital L", "Supraorbital R")


def brow_weight(z: np.ndarray, landmarks: dict, top_mm: float = FACE_SMOOTH_TOP_MM) -> np.ndarray:
    """Per row height ``z`` (mm), the smoothing's weight (0-1): 1 up to the brows (the highest of
    :data:`BROW_LANDMARKS` in ``landmarks``; without any, two thirds of the way up the rows), 0 from ``top_mm`` above
    them, linear between."""
    z = np.asarray(z, float)
    brows = [float(landmarks[n][2]) for n in BROW_LANDMARKS if landmarks.get(n) is not None]
    top = max(brows) if brows else float(z[0] + (z[-1] - z[0]) * 2.0 / 3.0)
    return np.clip(1.0 - (z - top) / max(float(top_mm), 1e-6), 0.0, 1.0)


def smooth_skin(radius: np.ndarray, grid: FaceGrid, weight: np.ndarray, floor: np.ndarray | None = None,
                length_mm: float | None = None, rho: np.ndarray | None = None) -> np.ndarray:
    """The skin's radius map (K, M) on ``grid`` smoothed over the surface by a twiced Gaussian of ``length_mm``,
    blended in per row by ``weight`` (K,) (:func:`brow_weight`).

    Where the smoothing lowered the skin onto the bone ``floor`` (K, M; the outermost bone plus the least tissue,
    :func:`.face_profile.bone_floor`) further than it was, a mound rounded as the floor is
    (:func:`.face_profile.round_floor`, :data:`.face_profile.FLOOR_ROUND_MM`) lifts it back: the floor applied last
    would otherwise print a button over a cheekbone's crest. ``length_mm``: default :data:`FACE_SMOOTH_MM`; <= 0:
    ``radius`` unchanged. ``rho`` (K,): each row's radius that turns the length into columns (default each row's
    median of ``radius``); pass one fixed by the skull (the bone's profile) so that a peg moved at the chin does not
    change how wide every row is smoothed, and with it the face far from the peg.
    """
    radius = np.asarray(radius, float)
    length_mm = FACE_SMOOTH_MM if length_mm is None else float(length_mm)
    if length_mm <= 0:
        return radius
    rho = np.median(radius, axis=1) if rho is None else np.asarray(rho, float)
    smooth = surface_smooth(radius, grid, length_mm, rho=rho)
    smooth = 2.0 * smooth - surface_smooth(smooth, grid, length_mm, rho=rho)          # twicing: 2G - G*G
    out = radius + np.asarray(weight, float)[:, None] * (smooth - radius)
    if floor is not None:
        sunk = np.maximum(floor - out, 0.0) - np.maximum(floor - radius, 0.0)
        if np.any(sunk > 0.0):
            scale = np.broadcast_to(rho[:, None], radius.shape)                 # round_floor reads its median
            out = out + round_floor(np.maximum(sunk, 0.0), grid, scale, FLOOR_ROUND_MM)
    return out


#: How far (mm, over the surface) the bone floor's lift spreads into the face around it (:func:`lift_onto_floor`).
#: Chosen on CThead's renders (the plates under the eyes), checked on GE, GE stripped at 250 HU and the phantom
#: (docs/benchmarks.md): 4 mm softens them further but thins CThead's cheeks by 2 points more.
FLOOR_LIFT_SPREAD_MM = 2.0


def lift_onto_floor(radius: np.ndarray, floor: np.ndarray, grid: FaceGrid, rho: np.ndarray,
                    spread_mm: float = FLOOR_LIFT_SPREAD_MM) -> np.ndarray:
    """``radius`` lifted by a smooth envelope of how far it lies under the bone ``floor``: the lift's grey dilation over
    +- ``spread_mm`` (height and arc at the median of ``rho``, each row's radius), then a Gaussian of ``spread_mm``
    over the surface. Never below ``radius``; the hard floor (:func:`.face_profile.smooth_max`) is applied after it.

    Why: the floor (the outermost bone plus the least tissue, and in the cheeks the smallest of their pegs' means) is
    higher than the depth field only over the bone's crests (the infraorbital margin, the zygoma's body), and held up
    there alone, the face took the crests' outline: a plate under each eye, bounded by creases where the floor met the
    field. Lifted by the envelope the plate's edges run out over a few millimetres, as a skin over a crest does."""
    lift = np.clip(np.asarray(floor, float) - radius, 0.0, None)
    if spread_mm <= 0 or not np.any(lift > 0):
        return radius
    dz, per_col = row_and_column_mm(grid, rho)
    kz, kt = max(1, round(spread_mm / dz)), max(1, round(spread_mm / per_col))
    spread = ndimage.maximum_filter(lift, size=(2 * kz + 1, 2 * kt + 1), mode=("nearest", "wrap"))
    return radius + surface_smooth(spread, grid, spread_mm, rho=rho)
