"""Whether the samples are a head scan, read right (used by import): pure numpy/scipy functions.

* :func:`wrong_byte_order` - raw samples read in the byte order that turns a CT into noise,
* :func:`wrong_row_length` - raw slices read with a row length that does not join the anatomy up,
* :func:`photo_evidence` - what says "photographs, not a head CT" about an image stack,
* :func:`head_scan_evidence` - whether a volume is a head scan at all (CT or MRI), whatever the format.

The thresholds are defined here once (module constants) and nowhere else.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy import ndimage as ndi
from skimage.filters import threshold_otsu

__all__ = ["wrong_byte_order", "wrong_row_length", "photo_evidence", "head_scan_evidence", "neighbour_correlation"]


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
