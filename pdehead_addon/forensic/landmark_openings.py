"""Openings of the bone in the landmark frame's depth images -- the orbits, the nasal aperture, the external
acoustic meatus -- and the Frankfurt landmarks on their margins (orbitale, porion); method in
:mod:`pdehead_addon.forensic.auto_landmarks`."""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from .landmark_frame import DepthViews, LandmarkFrame, disc, pits

#: A pit of a depth image deeper than this (mm) is an opening (orbit, aperture, meatus).
HOLE_DEPTH_MM = 10.0
#: Radius (mm) of the disc that closes the front view (wider than an orbit's half width).
FRONT_CLOSING_MM = 24.0
#: Radius (mm) of the disc that closes the side views (wider than the meatus's half width).
SIDE_CLOSING_MM = 9.0
#: The margin of an opening (supraorbital, lateral orbit): the front-most point of this much bone (mm)
#: next to the opening.
RIM_MM = 3.0
#: An orbit's opening lies on its side of the midline: at most this share of it across (an opening further across is
#: the nasal aperture run on into the mouth).
ORBIT_ACROSS_MID = 0.05
#: Porions (orbitales) farther than this from mirror images of each other are flagged uncertain (mm).
MIRROR_TOLERANCE_MM = 12.0


def orbits_and_aperture(v: DepthViews, mid_x: float):
    """Front-view openings: (left orbit, right orbit, nasal aperture) as pixel masks (nx, nz) or None.

    Orbits: the largest opening whose centre is on each side of the midline (more than 15 mm
    from it) with an area of at least 300 mm^2 that does not cross the midline; the nasal aperture: the largest
    opening crossing the midline whose top is below the orbits' centres.
    """
    fr = v.fr
    px = fr.step
    lab = pits(-v.front_y, v.front_has, FRONT_CLOSING_MM / px, HOLE_DEPTH_MM / px)
    n = lab.max()
    if n == 0:
        return None, None, None, lab
    idx = np.arange(1, n + 1)
    area = ndimage.sum(np.ones_like(lab), lab, idx) * px * px
    com = np.array(ndimage.center_of_mass(np.ones_like(lab), lab, idx))
    cx = fr.coord(0, com[:, 0]) - mid_x
    cz = fr.coord(2, com[:, 1])
    ix_mid = fr.index(0, mid_x)
    crossing = [i for i in range(n) if (lab[max(ix_mid - 1, 0):ix_mid + 2] == i + 1).any(0).sum() >= 5
                and area[i] >= 100]
    orbits = {}
    right_of_mid = np.broadcast_to((fr.coord(0, np.arange(fr.shape[0])) > mid_x)[:, None], lab.shape)
    share_right = ndimage.sum(right_of_mid, lab, idx) * px * px / np.maximum(area, 1e-9)
    for side in (1, -1):
        # an opening across the midline is the nasal aperture (with the mouth where the teeth are blurred or
        # missing), never an orbit: in 5 mm slabs CThead's aperture ran on into the mouth, 1,300 mm^2 with its
        # centre 17 mm to the right, larger than the right orbit (an orbit keeps ORBIT_ACROSS_MID of itself across)
        across = share_right if side < 0 else 1.0 - share_right
        cand = [i for i in range(n) if side * cx[i] > 15 and area[i] >= 300 and i not in crossing
                and across[i] <= ORBIT_ACROSS_MID]
        if cand:
            orbits[side] = max(cand, key=lambda i: area[i])
    mirrored = _mirrored_orbit(v, mid_x, lab, orbits)
    top_z = min((cz[i] for i in orbits.values()), default=np.inf)
    ap = None
    if crossing:
        below = [i for i in crossing if fr.coord(2, np.flatnonzero((lab == i + 1).any(0)).max()) < top_z]
        if below:
            ap = max(below, key=lambda i: area[i])
    get = lambda i: None if i is None else lab == i + 1   # noqa: E731
    aperture = None
    if ap is not None:
        # the opening may run on, beside the maxilla, into the gap between the teeth: keep the rows from
        # its top down to where it stops on the midline (the nasal floor)
        aperture = get(ap)
        col = aperture[ix_mid]
        top = int(np.flatnonzero(col).max())
        bottom = top
        while bottom > 0 and col[bottom - 1]:
            bottom -= 1
        aperture[:, :bottom] = False
    out = {side: get(orbits.get(side)) for side in (1, -1)}
    out.update(mirrored)
    return out[1], out[-1], aperture, lab


#: An orbit whose opening runs into another one (its rim broken in the bone mask, e.g. thick oblique slices
#: at the orbit floor) is cut to the mirror image of the other orbit's opening grown by this much (mm).
ORBIT_MIRROR_GROW_MM = 3.0


class _MirroredOrbit(np.ndarray):
    """An orbit opening cut to the mirror image of the other orbit (a boolean mask; ``evidence`` says why)."""

    evidence = ""


def mirror_fill(fr, pts: dict, fmt: str, orbits: dict) -> None:
    """For an orbit cut to the other's mirror image (:class:`_MirroredOrbit`), keep its landmark ``pts[fmt(tag)]``
    only within ``MIRROR_TOLERANCE_MM`` of the mirror image (x -> -x in the frame) of the other side's; else
    put the mirror image there (its broken rim gave a point inside the orbit)."""
    for tag, other in (("L", "R"), ("R", "L")):
        if not getattr(orbits.get(tag), "evidence", ""):
            continue
        q = pts.get(fmt.format(other))
        if q is None:
            continue
        m = np.asarray(q, float) * np.array([-1.0, 1.0, 1.0])
        p = pts.get(fmt.format(tag))
        if p is None or np.linalg.norm(np.asarray(p) - m) > MIRROR_TOLERANCE_MM:
            pts[fmt.format(tag)] = m


def _mirrored_orbit(v: DepthViews, mid_x: float, lab: np.ndarray, orbits: dict) -> dict:
    """When only one orbit opening is enclosed by bone in the front view, look for the other as the pit
    pixels (before the enclosure test) inside the mirror image of the found one across the mid-sagittal
    plane, grown by ``ORBIT_MIRROR_GROW_MM``; accepted when they cover at least 60 % of the mirror image.
    Returns {side: mask} for the side found this way (empty if none)."""
    if len(orbits) != 1:
        return {}
    fr = v.fr
    (side, i), = orbits.items()
    found = lab == i + 1
    xs = fr.coord(0, np.arange(fr.shape[0]))
    src = np.clip(np.round((2 * mid_x - xs - fr.lo[0]) / fr.step).astype(int), 0, fr.shape[0] - 1)
    mirror = found[src]                                   # mirror[ix] = found at the reflected column
    if not mirror.any():
        return {}
    raw = pits(-v.front_y, v.front_has, FRONT_CLOSING_MM / fr.step, HOLE_DEPTH_MM / fr.step, raw=True)
    grow = ndimage.binary_dilation(mirror, structure=disc(ORBIT_MIRROR_GROW_MM / fr.step))
    cand = raw & grow
    if cand.sum() < 0.6 * mirror.sum():
        return {}
    # the largest connected piece, so that a neighbouring opening's corner does not come along
    cl, n = ndimage.label(cand)
    cand = cl == 1 + int(np.argmax(ndimage.sum(np.ones_like(cl), cl, np.arange(1, n + 1))))
    out = cand.view(_MirroredOrbit)
    out.evidence = ("the orbit's opening runs into another opening in the bone mask (its rim is broken): cut to "
                    "the mirror image of the other orbit")
    return {-side: out}


#: Smallest side-view pit (mm^2) taken for the ear canal (an adult's is 40-50 mm^2 on CThead): the 10-16 mm^2
#: pits beside it (foramina, sutures) were nearer the expected point on a skull mesh of CThead.
MEATUS_MIN_MM2 = 25.0


def _meatus(v: DepthViews, side: int, expect_y: float, expect_z: float):
    """Side-view opening of the external acoustic meatus on ``side`` (+1 left, -1 right) or None.

    The pit of the side view with an area of MEATUS_MIN_MM2-250 mm^2 nearest (expect_y, expect_z), within 30 mm.
    """
    fr = v.fr
    px = fr.step
    has, xs = (v.left_has, v.left_x) if side > 0 else (v.right_has, v.right_x)
    lab = pits(side * xs, has, SIDE_CLOSING_MM / px, 0.6 * HOLE_DEPTH_MM / px)
    n = lab.max()
    best, best_d = None, 30.0
    if n:
        idx = np.arange(1, n + 1)
        area = ndimage.sum(np.ones_like(lab), lab, idx) * px * px
        com = np.array(ndimage.center_of_mass(np.ones_like(lab), lab, idx))
        for i in range(n):
            if not MEATUS_MIN_MM2 <= area[i] <= 250:
                continue
            d = np.hypot(fr.coord(1, com[i, 0]) - expect_y, fr.coord(2, com[i, 1]) - expect_z)
            if d < best_d:
                best, best_d = i, d
    return (None if best is None else lab == best + 1), best_d


def rim_below(v: DepthViews, hole: np.ndarray, ix: int) -> np.ndarray | None:
    """Front-view bone point just below the lowest hole pixel of column ``ix``."""
    col = np.flatnonzero(hole[ix])
    if not len(col):
        return None
    for iz in range(col.min() - 1, max(col.min() - 6, -1), -1):
        p = v.front_point(ix, iz)
        if p is not None:
            return p
    return None


def front_most(v: DepthViews, pixels) -> np.ndarray | None:
    """The most anterior front-view point of the first ``RIM_MM`` of bone along a list of (ix, iz) pixels
    leaving an opening: the margin of the opening, where a steep rim (under a brow ridge, the lateral
    orbital wall) would otherwise put the first bone pixel far behind its front edge."""
    pts = []
    for ix, iz in pixels:
        p = v.front_point(ix, iz)
        if p is not None:
            pts.append(p)
        if pts and len(pts) * v.fr.step >= RIM_MM:
            break
    return min(pts, key=lambda p: p[1]) if pts else None


def rim_above(v: DepthViews, hole: np.ndarray, ix: int) -> np.ndarray | None:
    col = np.flatnonzero(hole[ix])
    if not len(col):
        return None
    return front_most(v, [(ix, iz) for iz in range(col.max() + 1, min(col.max() + 9, hole.shape[1]))])


def orbitale(v: DepthViews, orbit: np.ndarray) -> np.ndarray | None:
    """Orbitale: the lowest point of the infraorbital margin -- over the orbit opening's columns in the
    front view, the bone pixel just below the opening's lowest pixel, the lowest of them (a flat rim:
    the middle of the columns within one grid step of the lowest)."""
    cols = np.flatnonzero(orbit.any(1))
    lows = [(np.flatnonzero(orbit[ix]).min(), ix) for ix in cols]
    lowest = min(low for low, _ in lows)
    ixs = [ix for low, ix in lows if low <= lowest + 1]
    return rim_below(v, orbit, ixs[len(ixs) // 2])


#: The meatus' floor is looked for this far (mm) below the opening's top (for :func:`porion_overhang`).
PORION_FLOOR_MM = 14.0
#: A roof reaching more than this (mm) beyond the canal's floor makes porion ``uncertain``.
PORION_OVERHANG_MM = 3.0


def porion_overhang(v: DepthViews, side: int, meatus: np.ndarray, p: np.ndarray, search_mm: float = 15.0) -> float:
    """How far (mm) the bone above the meatus reaches laterally beyond the canal's floor at porion ``p``.

    Going medially from porion along its row, the canal's lateral end is the first x where there is bone
    within ``PORION_FLOOR_MM`` below the opening's top (a floor). Where the roof overhangs it (the root of
    the zygomatic arch, the supramastoid crest) a reader may put porion on the roof's edge or above the
    canal's end: the rule's point is uncertain by this much; :func:`frankfurt_points` puts it half way (the roof
    above the middle) and :func:`~.auto_landmarks.find_landmarks` flags it ``uncertain`` beyond
    ``PORION_OVERHANG_MM``.
    """
    fr = v.fr
    top = int(np.flatnonzero(meatus.any(0)).max())
    iy, ix0 = fr.index(1, p[1]), fr.index(0, p[0])
    n_floor = max(1, int(round(PORION_FLOOR_MM / fr.step)))
    for k in range(int(round(search_mm / fr.step)) + 1):
        ix = ix0 - side * k
        if not 0 <= ix < fr.shape[0]:
            break
        if fr.bone[ix, iy, max(top - n_floor, 0):max(top - 1, 0)].any():
            return k * fr.step
    return search_mm


def porion(v: DepthViews, side: int, meatus: np.ndarray) -> np.ndarray | None:
    """Porion: the highest point of the upper margin of the external acoustic meatus -- in the side
    view, the bone pixel just above the opening's highest pixel (the outermost bone there); see
    :func:`porion_overhang` for when it is uncertain."""
    rows = np.flatnonzero(meatus.any(0))
    top = rows.max()
    # the middle of the opening's top 2 mm (its top row alone may be a pixel or two: a slightly different
    # frame would move porion along y by the width of the opening)
    iys = np.flatnonzero(meatus[:, max(top - int(round(2.0 / v.fr.step)), 0):top + 1].any(1))
    iy = int(round(0.5 * (iys.min() + iys.max())))
    for iz in range(top + 1, min(top + 6, meatus.shape[1])):
        p = v.side_point(side, iy, iz)
        if p is not None:
            return p
    return None




def frankfurt_points(fr: LandmarkFrame):
    """The views of ``fr``, its openings (left orbit, right orbit, nasal aperture) and the Frankfurt points in
    the frame: ``or_L``/``or_R`` (orbitale), ``po_L``/``po_R`` (porion, None when not found), ``po_*_d`` (the
    meatus' distance from where it was expected) and ``po_*_overhang`` (:func:`porion_overhang`)."""
    v = DepthViews(fr)
    mid_x = 0.0
    orb_l, orb_r, aperture, _ = orbits_and_aperture(v, mid_x)
    out = {}
    for orb, tag in ((orb_l, "L"), (orb_r, "R")):
        out[f"or_{tag}"] = None if orb is None else orbitale(v, orb)
    mirror_fill(fr, out, "or_{}", {"L": orb_l, "R": orb_r})
    skull_front = np.nanmin(np.where(v.front_has, v.front_y, np.nan))
    skull_back = fr.coord(1, np.flatnonzero(fr.bone.any((0, 2))).max())
    ors = [p for p in (out["or_L"], out["or_R"]) if p is not None]
    expect_z = np.mean([p[2] for p in ors]) if ors else fr.coord(2, fr.shape[2] // 2)
    expect_y = skull_front + 0.47 * (skull_back - skull_front)
    for side, tag in ((1, "L"), (-1, "R")):
        m, d = _meatus(v, side, expect_y, expect_z)
        out[f"po_{tag}"] = None if m is None else porion(v, side, m)
        out[f"po_{tag}_d"] = d
        if out[f"po_{tag}"] is not None:
            out[f"po_{tag}_overhang"] = over = porion_overhang(v, side, m, out[f"po_{tag}"])
            if over > 0:
                out[f"po_{tag}"] = _porion_on_roof(fr, side, m, out[f"po_{tag}"], over)
    return v, orb_l, orb_r, aperture, out


def _porion_on_roof(fr: LandmarkFrame, side: int, m: np.ndarray, p: np.ndarray, over: float) -> np.ndarray:
    """Porion moved half way between the roof's edge and the canal's end (the two readings), on the roof
    (always, not only when flagged: a threshold would make porion jump with the grid)."""
    ix, iy = fr.index(0, p[0] - side * 0.5 * over), fr.index(1, p[1])
    top = int(np.flatnonzero(m.any(0)).max())
    roof = np.flatnonzero(fr.bone[ix, iy, top - 1:top + 6])
    z = fr.coord(2, top - 1 + roof[0]) if len(roof) else p[2]
    return np.array([fr.coord(0, ix), p[1], z])
