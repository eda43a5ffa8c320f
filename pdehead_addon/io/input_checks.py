"""Checks that turn silently wrong inputs into clear errors or warnings (used by import and segmentation).

Pure numpy/scipy functions, no pipeline state:

* :func:`parse_orientation` - the axis-direction code of headerless stacks (raw, images),
* :func:`repair_non_finite` - NaN / inf voxels,
* :func:`repair_out_of_field` - the scanner's out-of-field value (-3024 HU and the like) when no
  PixelPaddingValue tag says so, found from the histogram and the circular field of view,
* :func:`face_side` - which side of an axial stack carries the face (the nose),
* :func:`check_head_extent` - the head's size against human ranges (child's head to head-and-neck scan),
* :func:`crown_end` - which end of a stack is the crown (its cross-section closes inside the scan) and the
  crown-to-widest-section height (the Auto orientation of headerless stacks, "not a human head"),
* whether the samples are a head scan read right (byte order, row length, photographs, a head at all):
  :mod:`.scan_evidence`.

The thresholds are defined here once (module constants) and nowhere else.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy import ndimage as ndi
from skimage.filters import threshold_otsu

AIR_HU = -1000.0
#: Below this no tissue or air can be (air is -1000 HU): the scanner's out-of-field value.
OUT_OF_FIELD_HU = -1500.0
#: A non-HU spike at the minimum is out-of-field when this share of it lies outside the inscribed circle.
_FOV_OUTSIDE_SHARE = 0.8
_FOV_MIN_FRACTION = 0.005       # ... and it holds at least this share of the volume
_FOV_GAP = 0.2                  # ... and it lies this far (share of the value range) below everything else

#: Human head extents (mm) of the head mask: (warn below, warn above) per patient axis x, y, z.
#: From a small child's head (about 100 mm wide) to a head-and-neck scan with shoulders
#: (about 500 mm wide, 600 mm tall). z has no lower bound: a scan may cover a few slices only.
HEAD_EXTENT_MM = {"x": (80.0, 520.0), "y": (90.0, 330.0), "z": (0.0, 650.0)}
#: Beyond these the spacing (or the data) is wrong, not the patient: refuse.
ABSURD_LARGE_MM = 1000.0        # any in-plane extent in metres
ABSURD_SMALL_MM = 30.0          # the largest in-plane extent only millimetres


class HeadSizeWarning(UserWarning):
    """The head found is outside the human size range (the spacing may be wrong)."""


# ----------------------------------------------------------------------------------------------
# Orientation codes of headerless stacks
# ----------------------------------------------------------------------------------------------

_LETTER_VECTORS = {"L": (1, 0, 0), "R": (-1, 0, 0), "P": (0, 1, 0), "A": (0, -1, 0),
                   "S": (0, 0, 1), "I": (0, 0, -1)}


def parse_orientation(code: str) -> list[np.ndarray]:
    """LPS unit vectors of the file's column, row and slice axes from a 3-letter code.

    The code names, for the column index, the row index and the slice (file) index in
    this order, the patient direction in which that index increases: ``"LPS"`` (the
    default: columns toward the patient's left, rows toward posterior, later files
    superior), ``"LAS"`` (row 0 = the back of the head), ``"RAS"`` (NIfTI-like),
    ``"LPI"`` (first file at the top), ``"PIL"`` (sagittal slices: columns toward
    posterior, rows toward inferior, files toward the left).

    Returns
    -------
    [column, row, slice] vectors (3,) each.

    Raises
    ------
    ValueError
        With a message listing the allowed letters.
    """
    text = str(code).strip().upper()
    if len(text) != 3 or any(c not in _LETTER_VECTORS for c in text):
        raise ValueError(f"orientation must be 3 letters from L/R, A/P, S/I (for columns, rows, slices), "
                         f"e.g. 'LPS' or 'LAS', got {code!r}")
    vecs = [np.array(_LETTER_VECTORS[c], dtype=np.float64) for c in text]
    if len({int(np.argmax(np.abs(v))) for v in vecs}) != 3:
        raise ValueError(f"orientation {code!r} names one patient axis twice; use one of L/R, one of A/P "
                         "and one of S/I")
    return vecs


def orientation_code(col: np.ndarray, row: np.ndarray, sl: np.ndarray) -> str:
    """Inverse of :func:`parse_orientation`."""
    names = {v: k for k, v in _LETTER_VECTORS.items()}
    return "".join(names[tuple(int(round(c)) for c in v)] for v in (col, row, sl))


# ----------------------------------------------------------------------------------------------
# Voxel values
# ----------------------------------------------------------------------------------------------

def _slabs(data: np.ndarray):
    """Views of ``data`` in z-slabs of about 8 M voxels (bounded temporaries at any size)."""
    step = max(1, 8_000_000 // max(1, data.shape[1] * data.shape[2]))
    return (data[k:k + step] for k in range(0, data.shape[0], step))


def count_non_finite(data: np.ndarray) -> int:
    """Number of NaN / inf voxels."""
    return int(sum(np.count_nonzero(~np.isfinite(block)) for block in _slabs(data)))


def repair_non_finite(data: np.ndarray, hu: bool) -> tuple[int, float | None]:
    """Replace NaN/inf voxels in place by air; returns (count, fill value) (count 0: untouched).

    Air is -1000 HU for HU data, else the smallest finite value.

    Raises
    ------
    ValueError
        When no voxel is finite.
    """
    bad = count_non_finite(data)
    if not bad:
        return 0, None
    if bad == data.size:
        raise ValueError(f"all {data.size} voxels are NaN or infinite")
    fill = AIR_HU
    if not hu:
        fill = min(float(block[np.isfinite(block)].min()) for block in _slabs(data) if np.isfinite(block).any())
    for block in _slabs(data):
        block[~np.isfinite(block)] = fill
    return bad, float(fill)


def _inscribed_circle(ny: int, nx: int) -> np.ndarray:
    """Pixels inside the circle inscribed in the slice (the usual reconstruction field of view)."""
    yy, xx = np.ogrid[:ny, :nx]
    ry, rx = (ny - 1) / 2.0, (nx - 1) / 2.0
    return ((yy - ry) / max(ry, 0.5)) ** 2 + ((xx - rx) / max(rx, 0.5)) ** 2 <= 1.0


def repair_out_of_field(data: np.ndarray, hu: bool) -> dict | None:
    """Find the scanner's out-of-field value and set those voxels to air, in place.

    GE and Siemens store the pixels outside the reconstruction circle as -3024 HU
    (or -2048, -2000) and often do not say so in PixelPaddingValue. Left in, the
    intensity window of the segmentation spans [-3000, -1000] and air counts as
    tissue. Detection:

    * HU data: every voxel below :data:`OUT_OF_FIELD_HU` (nothing physical is
      below air at -1000 HU);
    * uncalibrated data: the minimum value is a spike holding at least 0.5 % of
      the voxels, at least 80 % of it outside the circle inscribed in the slice
      (the circular field of view) and well below every other value.

    Returns
    -------
    None when nothing was found, else dict(count, value (the out-of-field value, or
    the range), fill, outside_circle (share of them outside the inscribed circle),
    rule).
    """
    nz, ny, nx = data.shape
    if data.size == 0:
        return None
    lo = float(data.min())
    if hu:
        if lo >= OUT_OF_FIELD_HU:
            return None
        per_pixel = sum(np.count_nonzero(data[k:k + 64] < OUT_OF_FIELD_HU, axis=0) for k in range(0, nz, 64))
        fill, rule = AIR_HU, f"below {OUT_OF_FIELD_HU:g} HU"
        values = (lo, float(data[data < OUT_OF_FIELD_HU].max()))
    else:
        per_pixel = sum(np.count_nonzero(data[k:k + 64] == lo, axis=0) for k in range(0, nz, 64))
        count = int(per_pixel.sum())
        if count < _FOV_MIN_FRACTION * data.size:
            return None
        circle = _inscribed_circle(ny, nx)
        if per_pixel[~circle].sum() < _FOV_OUTSIDE_SHARE * count:
            return None
        # everything else: is the spike far below it? (sampled; the spike itself excluded)
        sample = data[:, circle][:: max(1, nz // 16)].ravel()
        rest = sample[sample > lo]
        if rest.size == 0:
            return None
        r_lo, r_hi = np.percentile(rest, [0.5, 99.5])
        if not r_lo - lo > _FOV_GAP * max(r_hi - lo, 1e-6):
            return None
        # air: the darkest values of the ring just inside the circle (the head does not reach it)
        yy, xx = np.ogrid[:ny, :nx]
        ry, rx = (ny - 1) / 2.0, (nx - 1) / 2.0
        radius = ((yy - ry) / max(ry, 0.5)) ** 2 + ((xx - rx) / max(rx, 0.5)) ** 2
        ring = data[:, (radius <= 1.0) & (radius >= 0.8)].ravel()
        ring = ring[ring > lo]
        fill = float(np.median(ring)) if ring.size else float(r_lo)
        rule, values = "a spike at the minimum, outside the circular field of view", (lo, lo)
    count = int(per_pixel.sum())
    outside = float(per_pixel[~_inscribed_circle(ny, nx)].sum() / max(count, 1))
    for k in range(0, nz, 64):
        block = data[k:k + 64]
        block[(block < OUT_OF_FIELD_HU) if hu else (block == lo)] = fill
    return dict(count=count, value=values[0] if values[0] == values[1] else values, fill=float(fill),
                outside_circle=outside, rule=rule)


# ----------------------------------------------------------------------------------------------
# Geometry: where the face is, how big the head is
# ----------------------------------------------------------------------------------------------

def _subsampled(data: np.ndarray, spacing: Sequence[float], target_mm: float = 2.0, max_voxels: int = 4_000_000):
    """Strided view of ``data`` with about ``target_mm`` voxels (and at most ``max_voxels``), its spacing."""
    # never fewer than ~32 samples per axis, whatever the spacing says (it may be wrong)
    steps = [max(1, min(int(round(target_mm / float(h))), n // 32)) for h, n in zip(spacing, data.shape)]
    while math.prod(math.ceil(n / s) for n, s in zip(data.shape, steps)) > max_voxels:
        steps = [s + 1 for s in steps]
    view = data[::steps[0], ::steps[1], ::steps[2]]
    return view, tuple(float(h) * s for h, s in zip(spacing, steps))


def object_mask(data: np.ndarray, spacing: Sequence[float], level: float | None = None):
    """Coarse mask of the largest bright object (a quick look, not the segmentation).

    Returns (mask on a ~2 mm subsampled grid, its spacing). ``level`` defaults to Otsu's
    threshold of the subsampled values.
    """
    view, sp = _subsampled(data, spacing)
    view = np.asarray(view, dtype=np.float32)
    if level is None:
        finite = view[np.isfinite(view)]
        if finite.size == 0 or finite.min() == finite.max():
            return np.zeros(view.shape, bool), sp
        # float64: the histogram of float32 values spanning +-1e38 would overflow
        level = float(threshold_otsu(finite[:: max(1, finite.size // 500_000)].astype(np.float64)))
    mask = view > level
    labels, n = ndi.label(mask)
    if n > 1:
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        mask = labels == int(np.argmax(sizes))
    return mask, sp


def mask_extent_mm(mask: np.ndarray, spacing: Sequence[float]) -> tuple[float, float, float] | None:
    """(x, y, z) extent in mm of the bounding box of ``mask`` ([z, y, x], voxel-centre box + one voxel)."""
    if not mask.any():
        return None
    out = []
    for axis in (2, 1, 0):
        other = tuple(a for a in range(3) if a != axis)
        hit = np.flatnonzero(mask.any(axis=other))
        out.append(float((hit[-1] - hit[0] + 1) * float(spacing[axis])))
    return tuple(out)


def check_head_extent(extent_xyz: Sequence[float], spacing: Sequence[float], what: str = "head"):
    """Compare a head's extent with human ranges.

    Parameters
    ----------
    extent_xyz : (x width, y depth, z height) in mm
    spacing : (dz, dy, dx) in mm, quoted in the messages

    Returns
    -------
    (refusal, warning) : each a message or None. A refusal means the size is
    absurd (metres, or only millimetres in plane): the spacing is wrong.
    """
    ex, ey, ez = (float(e) for e in extent_xyz)
    dz, dy, dx = (float(h) for h in spacing)
    size = f"{ex:.0f} x {ey:.0f} x {ez:.0f} mm (x width, y depth, z height)"
    used = f"voxel spacing (dz, dy, dx) = ({dz:g}, {dy:g}, {dx:g}) mm"
    if max(ex, ey) > ABSURD_LARGE_MM:
        return (f"the {what} would be {size} with {used}: metres, not a human head; the spacing is wrong "
                "(pass the true spacing in mm)"), None
    if max(ex, ey) < ABSURD_SMALL_MM:
        return (f"the {what} would be only {size} with {used}: no human head is this small; the spacing "
                "is wrong (pass the true spacing in mm) or the volume holds no head"), None
    out = []
    for name, value in zip("xyz", (ex, ey, ez)):
        lo, hi = HEAD_EXTENT_MM[name]
        if value < lo:
            out.append(f"{name} {value:.0f} mm < {lo:g}")
        elif value > hi:
            out.append(f"{name} {value:.0f} mm > {hi:g}")
    if out:
        return None, (f"the {what} is {size} with {used}, outside the human range ({'; '.join(out)}: "
                      "from a small child's head to a head-and-neck scan); check the spacing")
    return None, None


def face_side(data: np.ndarray, spacing: Sequence[float], level: float | None = None,
              depth: float = 0.06, ratio: float = 0.55) -> dict:
    """Which end of the row axis (j) carries the face, judged by the nose.

    In an axial slice through the nose the head's outline is narrow at its front end
    (the nose, 15-35 mm wide 12 mm behind its tip) and wide at its back end (the
    occiput, 80-120 mm there). On a ~2 mm copy, the largest bright object (opened
    by 1.5 % of its size to drop thin holder shells and cloth) is measured in every
    slice holding at least 15 % of the largest cross-section: its width ``depth``
    (a share of the object's front-to-back extent, 0.06 = 12 mm of a 200 mm head)
    inside the low-j end and inside the high-j end. Sizes are relative, so a wrong
    spacing does not change the vote. A slice votes for "face at low j" when the
    low-j width is under ``ratio`` times the high-j width, and the other way round.

    Returns
    -------
    dict(low=votes for the face at j = 0, high=votes for the face at the last row,
    slices=slices measured, side="low" | "high" | "unknown")
    """
    mask, sp = object_mask(data, spacing, level)
    rows_any = np.flatnonzero(mask.any(axis=(0, 2)))
    if rows_any.size < 10:
        return dict(low=0, high=0, slices=0, side="unknown")
    extent = rows_any[-1] - rows_any[0] + 1                  # front-to-back size in pixels
    radius = max(1, int(round(0.015 * extent)))
    disk = np.hypot(*np.mgrid[-radius:radius + 1, -radius:radius + 1]) <= radius
    depth = max(1, int(round(depth * extent)))
    areas = np.count_nonzero(mask, axis=(1, 2))
    low = high = measured = 0
    for k in range(mask.shape[0]):
        m = mask[k]
        if areas[k] < 0.15 * areas.max():     # above the vertex, below the chin
            continue
        m = ndi.binary_opening(m, structure=disk)
        rows = np.flatnonzero(m.any(axis=1))
        if rows.size < 2 * depth + 2:
            continue
        measured += 1
        w_low = np.count_nonzero(m[rows[0] + depth])
        w_high = np.count_nonzero(m[rows[-1] - depth])
        if w_low < ratio * w_high:
            low += 1
        elif w_high < ratio * w_low:
            high += 1
    side = "unknown"
    if max(low, high) >= 3 and max(low, high) >= 2 * min(low, high):
        side = "low" if low > high else "high"
    return dict(low=low, high=high, slices=measured, side=side)


# ----------------------------------------------------------------------------------------------
# Headerless stacks: which end is the crown
# ----------------------------------------------------------------------------------------------

#: A stack end "closes" when the head's cross-section there is under this share of the widest one.
CROWN_CLOSED_SHARE = 0.05
#: The vertex is the first slice (from the crown end) whose cross-section reaches this share of the widest.
CROWN_VERTEX_SHARE = 0.02
#: Fewest slices (on the ~2 mm look-grid) for the crown test: a few slices cannot show an end closing.
CROWN_MIN_SLICES = 8
#: Vertex to widest cross-section: a human head (a child's included) has more than this (mm). CThead: 80 mm,
#: the phantom 85 mm, the GE series 80 mm.
MIN_VERTEX_TO_WIDEST_MM = 60.0


def crown_end(data: np.ndarray, spacing: Sequence[float], level: float | None = None) -> dict:
    """Which end of the slice axis (k) is the crown: the end whose cross-section closes inside the scan.

    On the ~2 mm look-grid of :func:`object_mask` the head's cross-section area is measured per
    slice. An end *closes* when its area is under :data:`CROWN_CLOSED_SHARE` of the widest
    slice: above the vertex the scan holds air, while the cut end (neck, chin) keeps a large
    cross-section. When exactly one end closes it is the crown; when both or neither do (a scan
    cut at both ends, a head inside a larger field) the answer is "unknown". Areas are relative,
    so a wrong spacing does not change the answer.

    Returns
    -------
    dict(end="low" | "high" | "unknown", vertex_to_widest_mm (float, or None when no crown
    closes), areas (relative, per look-grid slice), look_spacing_mm)
    """
    mask, sp = object_mask(data, spacing, level)
    areas = np.count_nonzero(mask, axis=(1, 2)).astype(np.float64)
    out = dict(end="unknown", vertex_to_widest_mm=None, areas=[], look_spacing_mm=float(sp[0]))
    if areas.size < CROWN_MIN_SLICES or areas.max() <= 0:
        return out
    rel = areas / areas.max()
    out["areas"] = [round(float(a), 3) for a in rel]
    low, high = rel[0] < CROWN_CLOSED_SHARE, rel[-1] < CROWN_CLOSED_SHARE
    if low == high:
        return out
    end = "low" if low else "high"
    from_crown = rel if low else rel[::-1]
    vertex = int(np.argmax(from_crown >= CROWN_VERTEX_SHARE))
    widest = int(np.argmax(from_crown))
    out.update(end=end, vertex_to_widest_mm=float((widest - vertex) * sp[0]))
    return out
