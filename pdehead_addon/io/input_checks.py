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
* :func:`wrong_byte_order` - raw samples read in the byte order that turns a CT into noise,
* :func:`photo_evidence` - what says "photographs, not a head CT" about an image stack.

The thresholds are defined here once (module constants) and nowhere else.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy import ndimage as ndi

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
        from skimage.filters import threshold_otsu
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
# Headerless stacks: which end is the crown, is it a head at all, is the byte order right
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


def wrong_byte_order(data: np.ndarray, dtype: np.dtype) -> dict | None:
    """Whether raw samples were read with the wrong byte order (the other order reads as a CT).

    A CT's stored values fit in 12 bits (0..4095, or -1024..3071 in HU; 16 bits at most for
    calibrated floats), so a 2-byte reading that spans more than 60,000 values while the
    byte-swapped reading spans fewer than 4,096 is the wrong order. Floats: the swapped reading
    is finite and within -5,000..70,000 while this one is not. Sampled (up to 16 slices).

    Parameters
    ----------
    data : the samples as read (any float/int array whose values are exactly the file's samples)
    dtype : the numpy dtype they were read with (its byte order)

    Returns
    -------
    None when this order is plausible (or the other is not either), else dict(read=(lo, hi),
    swapped=(lo, hi), swapped_dtype=the dtype string of the other order).
    """
    dt = np.dtype(dtype)
    if dt.itemsize < 2 or data.size == 0:
        return None
    step = max(1, data.shape[0] // 16) if data.ndim == 3 else 1
    sample = np.asarray(data[::step]).astype(dt)
    swapped = sample.byteswap().astype(np.float64)      # the same bytes read in the other order
    read = sample.astype(np.float64)
    if dt.kind in "iu":
        span_read = float(read.max() - read.min())
        span_swapped = float(swapped.max() - swapped.min())
        bad = span_read > 60_000 and span_swapped < 4_096
    else:
        ok = (np.isfinite(swapped).all() and swapped.min() >= -5_000 and swapped.max() <= 70_000
              and swapped.max() - swapped.min() > 1.0)
        finite = np.isfinite(read)
        bad = bool(ok and (finite.mean() < 0.99 or (finite.any() and np.abs(read[finite]).max() > 1e6)))
    if not bad:
        return None
    finite = read[np.isfinite(read)]
    return dict(read=(float(finite.min()), float(finite.max())) if finite.size else (float("nan"),) * 2,
                swapped=(float(swapped.min()), float(swapped.max())),
                swapped_dtype=np.dtype(dtype).newbyteorder("S").str)


#: Raw slices read with a wrong row length: the row-to-row correlation is under this share of the
#: column-to-column one (CThead's 256 x 256 slices read as 512 x 128: -0.14 against 0.98; right: 0.98 and 0.98).
ROWS_JOIN_SHARE = 0.5


def wrong_row_length(data: np.ndarray) -> dict | None:
    """Whether raw slices were read with a wrong row length (a shape with the right byte count).

    Along a row the samples of a wrongly shaped slice still follow each other as in the file (the
    column-to-column correlation stays high), but the next row does not continue the anatomy where the
    row above it lies (the row-to-row correlation collapses). The row length the samples do join up in is
    the divisor of the slice's sample count (between 16 and the count / 16) at which the samples of
    the flat slice correlate best with those that far ahead.

    Returns
    -------
    None when the rows join up (or nothing can be said: noise, fewer than 16 rows), else
    dict(rows=row-to-row correlation, columns=column-to-column correlation, row_length=the row length the
    samples join up in, or None).
    """
    data = np.asarray(data)
    if data.ndim != 3 or min(data.shape[1:]) < 2:
        return None
    rows, cols = neighbour_correlation(data)
    if cols < HEAD_MIN_NEIGHBOUR_CORRELATION or rows >= ROWS_JOIN_SHARE * cols:
        return None
    ks = np.unique(np.linspace(0, data.shape[0] - 1, min(data.shape[0], _HEAD_LOOK_SLICES)).round().astype(int))
    flat = np.asarray(data[ks], np.float32).reshape(len(ks), -1)
    count = flat.shape[1]
    lengths = [n for n in range(16, count // 16 + 1) if count % n == 0]
    best = max(lengths, key=lambda n: _correlation(flat[:, :-n], flat[:, n:]), default=None)
    return dict(rows=round(rows, 3), columns=round(cols, 3), row_length=best)


#: Image stacks: mean colour saturation (share of the value range) above which the images are colour.
PHOTO_MAX_CHROMA = 0.04
#: ... and the least share of air (darkest tenth of the range) and of tissue a head CT slice stack has.
PHOTO_MIN_AIR = 0.10
PHOTO_MIN_TISSUE = 0.05


def photo_evidence(slices: Sequence[np.ndarray], colour_chroma: float) -> list[str]:
    """What in an image stack says "photographs, not a head CT" (empty: nothing).

    A CT slice is greyscale and mostly air around one bright object: a large share of its
    pixels sits at the dark end of the value range (air) and most of the rest in a second,
    brighter mode (soft tissue). Photographs are colour, or spread their values over the whole
    range with no dark air mode.

    Parameters
    ----------
    slices : the images (greyscale values), a sample of the stack is enough
    colour_chroma : mean over the pixels of (max - min) of R, G, B as a share of the value range
        (0 for greyscale files and for colour files whose channels are equal)

    Returns
    -------
    The observations that failed, as phrases for the message.
    """
    seen = []
    if colour_chroma > PHOTO_MAX_CHROMA:
        seen.append(f"colour images (mean colour saturation {100 * colour_chroma:.0f} % of the value range; "
                    "CT slices are grey)")
    values = np.concatenate([np.asarray(s, np.float32)[::2, ::2].ravel() for s in slices])
    lo, hi = np.percentile(values, [0.5, 99.5]) if values.size else (0.0, 0.0)
    if hi <= lo:
        seen.append("every pixel has the same value")
        return seen
    air = float(np.mean(values <= lo + 0.1 * (hi - lo)))
    tissue = float(np.mean(values >= lo + 0.25 * (hi - lo)))
    if air < PHOTO_MIN_AIR or tissue < PHOTO_MIN_TISSUE:
        seen.append(f"no air/soft-tissue histogram ({100 * air:.0f} % of the pixels in the darkest tenth of the "
                    f"value range, {100 * tissue:.0f} % above its first quarter; a head CT has air around the "
                    f"head, at least {100 * PHOTO_MIN_AIR:.0f} %, and tissue)")
    return seen



# ----------------------------------------------------------------------------------------------
# Is it a head scan at all (CT or MRI), whatever the format
# ----------------------------------------------------------------------------------------------

#: Neighbouring pixels of a scan correlate (anatomy is larger than a pixel): CThead, GE, the phantom and the
#: Colin27 MRI give 0.95 to 0.997, CThead block-averaged 4 x 0.95; uniform noise 0.00.
HEAD_MIN_NEIGHBOUR_CORRELATION = 0.5
#: The object's outline is a step (skin against air, scalp against the MRI background), a few pixels wide:
#: the median gradient on the outline times the object's diameter over the object-to-background contrast is
#: 21 to 74 on the real scans (cropped, resampled 0.25x to 3x included), 4 on smooth-shaded ovals (portraits).
HEAD_MIN_EDGE_SHARPNESS = 10.0
#: Inside the outline a scan shows anatomy (skull tables, sinuses, brain, grey/white matter): the detail left
#: after a blur of 2 % of the diameter, as a share of the contrast, is 0.09 to 0.24 on the real scans, 0.01 to
#: 0.02 on uniform or smooth-shaded ovals.
HEAD_MIN_INTERIOR_DETAIL = 0.04
#: Slices looked at (evenly spaced through the stack).
_HEAD_LOOK_SLICES = 16
#: ... at most this many pixels across (a strided copy: the measures are relative to the object's size).
_HEAD_LOOK_PIXELS = 256


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two equally shaped arrays (0 when either is constant)."""
    a = np.asarray(a, np.float64) - float(np.mean(a))
    b = np.asarray(b, np.float64) - float(np.mean(b))
    den = math.sqrt(float(np.sum(a * a)) * float(np.sum(b * b)))
    return float(np.sum(a * b) / den) if den > 0 else 0.0


def neighbour_correlation(data: np.ndarray, max_slices: int = _HEAD_LOOK_SLICES) -> tuple[float, float]:
    """(row-to-row, column-to-column) correlation of neighbouring pixels over up to ``max_slices`` slices.

    The correlation of every pixel with the one below it (the next row) and with the one to its right (the
    next column). In any image of anatomy both are high and about equal; noise gives 0; a raw stack read with
    the wrong row length gives a row-to-row correlation far below the column-to-column one (rows that do not
    join up).
    """
    data = np.asarray(data)
    ks = np.unique(np.linspace(0, data.shape[0] - 1, min(data.shape[0], max_slices)).round().astype(int))
    s = np.asarray(data[ks], np.float32)
    return _correlation(s[:, :-1, :], s[:, 1:, :]), _correlation(s[:, :, :-1], s[:, :, 1:])


def head_scan_evidence(data: np.ndarray) -> dict:
    """What says whether a volume is a scan of a head (CT or MRI) or something else (portraits, noise).

    Three properties every head scan has, whatever its scanner, units, cropping and resolution, measured on up
    to 16 evenly spaced slices:

    1. *coherence*: neighbouring pixels correlate (:func:`neighbour_correlation`, the smaller of the two);
    2. *a sharp outline*: the largest bright object (Otsu's threshold [1]_, holes filled) meets the
       background in a step: the median gradient magnitude on its outline, times its equivalent diameter,
       over the contrast (median of the object's values minus median of the background's) - a
       dimensionless number, independent of the pixel size and of the units (about diameter / edge width);
    3. *interior detail*: inside the outline (eroded by 5 % of the diameter) the standard deviation of the
       image minus its Gaussian blur of 2 % of the diameter, over the contrast.

    Parameters
    ----------
    data : [z, y, x] volume

    Returns
    -------
    dict(correlation, edge_sharpness, interior_detail (floats, None where not measurable), failed (the
    observations below :data:`HEAD_MIN_NEIGHBOUR_CORRELATION`, :data:`HEAD_MIN_EDGE_SHARPNESS`,
    :data:`HEAD_MIN_INTERIOR_DETAIL`, as phrases for a message; empty for a head scan))

    References
    ----------
    .. [1] N. Otsu, "A threshold selection method from gray-level histograms", IEEE Trans. Syst. Man
       Cybern. 9(1):62-66, 1979.
    """
    data = np.asarray(data)
    out = dict(correlation=None, edge_sharpness=None, interior_detail=None, failed=[])
    if data.ndim != 3 or min(data.shape[1:]) < 16:
        return out
    ks = np.unique(np.linspace(0, data.shape[0] - 1, min(data.shape[0], _HEAD_LOOK_SLICES)).round().astype(int))
    s = np.asarray(data[ks], np.float32)
    finite = s[np.isfinite(s)]
    if finite.size == 0 or finite.min() == finite.max():
        return out
    step = max(1, math.ceil(max(s.shape[1:]) / _HEAD_LOOK_PIXELS))    # the measures are size-relative
    s = s[:, ::step, ::step]
    corr = min(neighbour_correlation(s))
    out["correlation"] = round(corr, 3)
    if corr < HEAD_MIN_NEIGHBOUR_CORRELATION:
        out["failed"].append(f"no coherent structure (neighbouring pixels correlate {corr:.2f}; a scan of anatomy "
                             f"more than {HEAD_MIN_NEIGHBOUR_CORRELATION:g}: noise?)")
        return out
    from skimage.filters import threshold_otsu
    level = float(threshold_otsu(finite[:: max(1, finite.size // 500_000)]))
    back, obj = float(np.median(finite[finite <= level])), float(np.median(finite[finite > level]))
    contrast = obj - back
    if not contrast > 0:
        return out
    sharp, detail, areas = [], [], []
    for sl in s:
        m = sl > level
        labels, n = ndi.label(m)
        if n == 0:
            continue
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        m = ndi.binary_fill_holes(labels == int(np.argmax(sizes)))
        area = int(np.count_nonzero(m))
        diameter = 2.0 * math.sqrt(area / math.pi)
        outline = m & ~ndi.binary_erosion(m)
        gy, gx = np.gradient(sl)
        grad = np.hypot(gx, gy)[outline]
        inner = ndi.distance_transform_edt(m) > max(1.0, 0.05 * diameter)
        if grad.size == 0 or np.count_nonzero(inner) < 50:
            continue
        areas.append(area)
        sharp.append(float(np.median(grad)) * diameter / contrast)
        residual = (sl - ndi.gaussian_filter(sl, 0.02 * diameter))[inner]
        detail.append(float(np.std(residual)) / contrast)
    if not areas:
        return out
    keep = np.asarray(areas) >= 0.25 * max(areas)          # the slices through the head, not its ends
    out["edge_sharpness"] = edge = round(float(np.median(np.asarray(sharp)[keep])), 1)
    out["interior_detail"] = inside = round(float(np.median(np.asarray(detail)[keep])), 3)
    if edge < HEAD_MIN_EDGE_SHARPNESS:
        out["failed"].append(f"no sharp outline (the object's edge is smooth: sharpness {edge:.1f}, a head "
                             f"scan's skin or scalp at least {HEAD_MIN_EDGE_SHARPNESS:g})")
    if inside < HEAD_MIN_INTERIOR_DETAIL:
        out["failed"].append(f"no anatomy inside the outline (detail {inside:.3f} of the contrast, a head scan "
                             f"at least {HEAD_MIN_INTERIOR_DETAIL:g}: bone, brain, cavities)")
    return out
