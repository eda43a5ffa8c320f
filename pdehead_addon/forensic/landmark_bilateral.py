"""Bilateral landmarks in the landmark frame, each side by the same rule: the orbit margins (supraorbital,
suborbital, lateral orbit, frontal eminence, inferior malar), zygion and supraglenoid, alare curvature, the canine
points and the mandible's (gonion, occlusal line, sub/supra M2, mid-ramus, mid-mandibular border); rules in
:data:`pdehead_addon.forensic.auto_landmarks.RULES`."""
from __future__ import annotations

import numpy as np

from .landmark_frame import NOT_FOUND, OK, UNCERTAIN, box_mask, nearest_surface, side_extreme
from .landmark_openings import MIRROR_TOLERANCE_MM, front_most, mirror_fill, rim_above, rim_below

#: Supra canine is not found when the front-most bone above the canine lies this far (mm) behind supradentale:
#: that bone is not the maxilla (CThead and the phantom: 4-16 mm behind).
SUPRA_CANINE_BEHIND_MM = 25.0

TAGS = {1: "L", -1: "R"}
ORBIT_MARGINS = ("so", "sbo", "lo", "fe", "im")


def _pt(p, missing: str, flag: str = OK, evidence: str = ""):
    return (p, flag, evidence) if p is not None else (None, NOT_FOUND, missing)


# ------------------------------------------------------------------------------------- orbit margins
def orbit_margins(found, fr, v, orbits) -> None:
    """The orbit margins of both sides into ``found``; an orbit cut to the other's mirror image (its rim broken
    in the mask) then has its margins checked against the mirror images of the other side's."""
    for side in (1, -1):
        t = TAGS[side].lower()
        orb = orbits[side]
        if orb is None:
            for key in ORBIT_MARGINS:
                found[f"{key}_{t}"] = (None, NOT_FOUND, "no orbit opening in the front view")
            continue
        _orbit_margins(found, fr, v, side, t, orb)
    for side in (1, -1):
        if getattr(orbits[side], "evidence", ""):
            _mirrored_margins(found, fr, orbits, side)


def _orbit_margins(found, fr, v, side, t, orb) -> None:
    cols = np.flatnonzero(orb.any(1))
    rows = np.flatnonzero(orb.any(0))
    ixc = int(round(np.mean(cols)))
    found[f"so_{t}"] = _pt(rim_above(v, orb, ixc), "no bone above the orbit's centre")
    found[f"sbo_{t}"] = _pt(rim_below(v, orb, ixc), "no bone below the orbit's centre")
    izl = int(round(rows.min() + 0.7 * (rows.max() - rows.min())))
    row = np.flatnonzero(orb[:, izl])
    p = None
    if len(row):
        edge = row.max() if side > 0 else row.min()
        p = front_most(v, [(ix, izl) for ix in range(edge + side, edge + 9 * side, side) if 0 <= ix < fr.shape[0]])
    found[f"lo_{t}"] = _pt(p, "no bone lateral to the orbit")
    fe = _frontal_eminence(fr, v, found[f"so_{t}"][0], ixc)
    found[f"fe_{t}"] = fe if fe is not None else (None, NOT_FOUND, "no frontal bone above the orbit")
    found[f"im_{t}"] = _inferior_malar(fr, v, side, cols, rows)


def _frontal_eminence(fr, v, so, ixc):
    """Frontal eminence: most prominent point above the orbit's centre, relative to the chord (None: no bone)."""
    if so is None:
        return None
    iz0, iz1 = fr.index(2, so[2] + 10), fr.index(2, so[2] + 60)
    zs = np.arange(iz0, iz1 + 1)
    ok = v.front_has[ixc, zs]
    if ok.sum() <= 10:
        return None
    zs = zs[ok]
    y = v.front_y[ixc, zs]
    chord = y[0] + (y[-1] - y[0]) * (zs - zs[0]) / max(zs[-1] - zs[0], 1)
    k = int(np.argmin(y - chord))
    return (v.front_point(ixc, zs[k]), OK if (chord - y)[k] >= 1.0 else UNCERTAIN,
            "" if (chord - y)[k] >= 1.0 else "the forehead has no boss above the orbit")


def _inferior_malar(fr, v, side, cols, rows):
    """Inferior malar: down the front view from the orbit's lateral third, the last bone row before the view
    jumps back (the lower edge of the zygomatic body)."""
    ixm = int(round(np.mean(cols) + side * 0.25 * (cols.max() - cols.min())))
    iz = rows.min() - 1
    while iz > 0 and fr.coord(2, iz) > fr.coord(2, rows.min()) - 45:
        if v.front_has[ixm, iz] and (not v.front_has[ixm, iz - 1] or v.front_y[ixm, iz - 1] - v.front_y[ixm, iz] > 8):
            return (v.front_point(ixm, iz), OK, "")
        iz -= 1
    return (None, NOT_FOUND, "no lower edge of the zygomatic bone within 45 mm below the orbit")


def _mirrored_margins(found, fr, orbits, side) -> None:
    """An orbit cut to the other's mirror image: its margins are replaced by the mirror images of the other
    side's (snapped to the bone) where they are not there; all uncertain, with the orbit's evidence."""
    orb, t = orbits[side], TAGS[side].lower()
    for key in ORBIT_MARGINS:
        pts = {f"{key}_L": found[f"{key}_l"][0], f"{key}_R": found[f"{key}_r"][0]}
        mirror_fill(fr, pts, key + "_{}", {"L": orbits[1], "R": orbits[-1]})
        p = pts[f"{key}_{TAGS[side]}"]
        if p is not None and found[f"{key}_{t}"][0] is not p:
            p = nearest_surface(fr, p, None, 6.0)
        found[f"{key}_{t}"] = (p, UNCERTAIN, orb.evidence) if p is not None else \
            (None, NOT_FOUND, orb.evidence + "; no bone near the mirror image of the other side's")
    found[f"or_{t}"] = (found[f"or_{t}"][0], UNCERTAIN, orb.evidence) if found[f"or_{t}"][0] is not None \
        else found[f"or_{t}"]


# ------------------------------------------------------------------------------------- side views
def zygion_supraglenoid(found, fr, v) -> None:
    """Zygion and supraglenoid from the side views."""
    for side in (1, -1):
        t = TAGS[side].lower()
        po, orr = found[f"po_{t}"][0], found[f"or_{t}"][0]
        if po is None or orr is None:
            found[f"za_{t}"] = (None, NOT_FOUND, "needs porion and orbitale")
            found[f"sg_{t}"] = (None, NOT_FOUND, "needs porion")
            continue
        box = box_mask(fr, (0, side * 200), (orr[1] + 8, po[1] - 12), (orr[2] - 15, po[2] + 5))
        p = side_extreme(fr, side, fr.bone & box)
        found[f"za_{t}"] = _pt(p, "no bone between orbit and meatus")
        iy, iz = fr.index(1, po[1] - 10), fr.index(2, po[2] + 8)
        found[f"sg_{t}"] = _pt(v.side_point(side, iy, iz), "no bone above the glenoid fossa")


def alare(found, fr, v, aperture, mid_x) -> None:
    """Alare curvature (bony proxy): the outermost point of the nasal aperture's margin."""
    for side in (1, -1):
        t = TAGS[side].lower()
        if aperture is None:
            found[f"ac_{t}"] = (None, NOT_FOUND, "no nasal aperture in the front view")
            continue
        half = aperture & ((side * (fr.coord(0, np.arange(fr.shape[0])) - mid_x)) > 0)[:, None]
        cols = np.flatnonzero(half.any(1))
        if not len(cols):
            found[f"ac_{t}"] = (None, NOT_FOUND, "the nasal aperture does not reach this side")
            continue
        edge = cols.max() if side > 0 else cols.min()
        izs = np.flatnonzero(half[edge])
        iz = int(izs[len(izs) // 2])
        p = None
        for ix in range(edge + side, edge + 6 * side, side):
            if 0 <= ix < fr.shape[0] and v.front_has[ix, iz]:
                p = v.front_point(ix, iz)
                break
        found[f"ac_{t}"] = (p, UNCERTAIN, "bony proxy of a soft-tissue landmark (the aperture's widest point)") \
            if p is not None else (None, NOT_FOUND, "no bone lateral to the nasal aperture")


# ------------------------------------------------------------------------------------- teeth and mandible
def canine_points(found, fr, v, mid_x, up, low, mand_id, mand_ev) -> None:
    """Supra and infra canine, 13 % of the bizygomatic breadth from the midline."""
    zy = [found[f"za_{s}"][0] for s in "lr"]
    breadth = abs(zy[0][0] - zy[1][0]) if zy[0] is not None and zy[1] is not None else 130.0
    for side in (1, -1):
        t = TAGS[side].lower()
        ixc = fr.index(0, mid_x + side * 0.13 * breadth)
        found[f"sc_{t}"] = _supra_canine(fr, v, up, ixc)
        if low:
            iz = fr.index(2, low["id_z"] - 10)
            col = fr.bone[ixc, :, iz] & (fr.comp[ixc, :, iz] == mand_id)
            p = None if not col.any() else np.array([fr.coord(0, ixc), fr.coord(1, np.argmax(col)), fr.coord(2, iz)])
            found[f"ic_{t}"] = _pt(p, "no mandible below the canine", UNCERTAIN,
                                   "the canine's place is taken 13 % of the bizygomatic breadth from the midline")
        else:
            found[f"ic_{t}"] = (None, NOT_FOUND, mand_ev if mand_id is None else "no mandible profile")


def _supra_canine(fr, v, up, ixc):
    if not up:
        return (None, NOT_FOUND, "no upper jaw found on the midline")
    iz = fr.index(2, up["sd_z"] + 10)
    p = v.front_point(ixc, iz)
    if p is not None and p[1] - up["sd_y"] > SUPRA_CANINE_BEHIND_MM:
        # the maxilla above the canine is not in the mask: the column's front-most bone is the skull
        # base or the occiput, not the canine's (seen on a voxelised skull mesh: 190 mm behind)
        return (None, NOT_FOUND, f"no maxilla above the canine (the front-most bone there is "
                                 f"{p[1] - up['sd_y']:.0f} mm behind supradentale)")
    return _pt(p, "no maxilla above the canine", UNCERTAIN,
               "the canine's place is taken 13 % of the bizygomatic breadth from the midline")


MANDIBLE_BILATERAL = ("go", "ocl", "subm2", "mr", "mmb")
#: Without the mandible's menton and gonion (a scan cut at the teeth, or no mandible), supra M2 is placed at sub M2's
#: usual place: this fraction of the way from prosthion to porion (front to back). Chosen on CThead (sub M2 at 0.56
#: of the way at its own level, 0.58 at 1500) and checked on the phantom (0.63; its supra M2 without the mandible
#: lands 5.0 / 5.8 mm from where the mandible puts it); uncertain.
SUPRA_M2_PORION_FRACTION = 0.56


def mandible_bilateral(found, fr, v, mid_x, up, low, mand_id, mand_ev) -> None:
    """Gonion, occlusal line, sub M2, mid-ramus, mid-mandibular border, and supra M2 on the maxilla."""
    for side in (1, -1):
        t = TAGS[side].lower()
        if mand_id is None or not low:
            for key in MANDIBLE_BILATERAL:
                found[f"{key}_{t}"] = (None, NOT_FOUND, mand_ev)
            _supra_m2_without_mandible(found, fr, v, side, t, up, mid_x)
            continue
        xs = fr.coord(0, np.arange(fr.shape[0])) - mid_x
        halfm = (fr.comp == mand_id) & (side * xs > 5)[:, None, None]
        w = np.argwhere(halfm)
        if not len(w):
            for key in MANDIBLE_BILATERAL:
                found[f"{key}_{t}"] = (None, NOT_FOUND, "no mandible on this side")
            continue
        y2 = _mandible_side(found, fr, side, t, fr.lo + fr.step * w, up, low)
        # supra M2 on the maxilla, same y as sub M2, 10 mm above prosthion's height
        if up:
            iy, iz = fr.index(1, y2), fr.index(2, up["sd_z"] + 8)
            p = v.side_point(side, iy, iz)
            found[f"supm2_{t}"] = _pt(p, "no maxilla above the second molar")
        else:
            found[f"supm2_{t}"] = (None, NOT_FOUND, "no upper jaw found on the midline")
    for side in (1, -1):
        t = TAGS[side].lower()
        if f"supm2_{t}" not in found:
            found[f"supm2_{t}"] = (None, NOT_FOUND, mand_ev)
    if mand_id is None or not low:
        _supra_m2_mirrored(found, fr)


def _supra_m2_without_mandible(found, fr, v, side, t, up, mid_x) -> None:
    """Supra M2 on the maxilla where the mandible gives no sub M2 (:data:`SUPRA_M2_PORION_FRACTION`): the outermost
    bone 8 mm above prosthion's height, as with the mandible."""
    po = found.get(f"po_{t}", (None,))[0]
    if not up or po is None:
        return
    y2 = up["sd_y"] + SUPRA_M2_PORION_FRACTION * (po[1] - up["sd_y"])
    iy, iz = fr.index(1, y2), fr.index(2, up["sd_z"] + 8)
    p = None
    for dz in sorted(range(-3, 4), key=abs):     # the maxilla's thin wall: the nearest row with bone within 3 mm
        p = v.side_point(side, iy, int(np.clip(iz + dz, 0, fr.shape[2] - 1)))
        if p is not None and side * (p[0] - mid_x) > 5.0:    # on its own side (the view sees across the midline)
            break
        p = None
    found[f"supm2_{t}"] = _pt(p, "no maxilla above the second molar", UNCERTAIN,
                              f"no mandible to place it by: taken {100 * SUPRA_M2_PORION_FRACTION:.0f} % of the way "
                              "from prosthion to porion")


def _supra_m2_mirrored(found, fr) -> None:
    """Supra M2 placed without the mandible lies on the outermost bone of its side. Where one side's lies more than
    :data:`~.landmark_openings.MIRROR_TOLERANCE_MM` nearer the midline than the other's, its maxilla's thin outer
    wall is not in the bone (slabs averaged over it, or its molars' fillings' streaks removed) and the point is on
    the palate or the teeth within (CThead resliced to 1.5 mm and cut through the lower teeth: 12 mm from the midline
    against 46 mm on the other side, and the face's cheek pulled in 20 mm to its tip): it is replaced by the other
    side's mirror image, on the nearest bone within 6 mm of it, or not found; so is a side with no bone on its row."""
    pts = {t: found.get(f"supm2_{t}", (None,))[0] for t in ("l", "r")}
    if pts["l"] is None and pts["r"] is None:
        return
    wide = {t: (abs(float(p[0])) if p is not None else 0.0) for t, p in pts.items()}
    narrow, other = ("l", "r") if wide["l"] < wide["r"] else ("r", "l")
    if wide[other] - wide[narrow] <= MIRROR_TOLERANCE_MM:
        return
    m = np.asarray(pts[other], float) * np.array([-1.0, 1.0, 1.0])
    q = nearest_surface(fr, m, radius=6.0)
    ev = ("no bone on this side's row" if pts[narrow] is None else
          f"its outermost bone lies {wide[narrow]:.0f} mm from the midline, the other side's {wide[other]:.0f} mm")
    ev += ": the maxilla's outer wall is missing here; taken at the mirror image of the other side's"
    found[f"supm2_{narrow}"] = _pt(q, "no bone near the mirror image of the other side's supra M2", UNCERTAIN, ev)


#: A ramus of a partial mandible (:func:`mid_ramus_on_rami`): its points lie at least this far (mm) from the midline
#: and span at least RAMUS_MIN_HEIGHT_MM in height.
RAMUS_SIDE_MM = 20.0
RAMUS_MIN_HEIGHT_MM = 15.0


def mid_ramus_on_rami(found, rami: np.ndarray) -> None:
    """Mid-ramus on the rami of a mandible whose body is outside the scan (a scan cut through the lower teeth):
    ``rami`` the segmentation's mandible voxels (frame mm, the midline at x = 0). Each side's: the outermost point
    half way up the ramus in the scan, in the middle of its front-to-back extent there, as :func:`_mandible_side`
    puts it half way from gonion to the condyle; gonion is below the scan, so the point lies above the true one by
    half the part cut off: uncertain. The rules without the mandible leave it not found (later "outside the
    scan"), though the ramus is in the scan."""
    for side in (1, -1):
        t = TAGS[side].lower()
        if found.get(f"mr_{t}", (None,))[0] is not None:
            continue
        P = rami[side * rami[:, 0] > RAMUS_SIDE_MM]
        if len(P) == 0 or np.ptp(P[:, 2]) < RAMUS_MIN_HEIGHT_MM:
            continue
        z0, z1 = float(P[:, 2].min()), float(P[:, 2].max())
        zr = 0.5 * (z0 + z1)
        ram = P[np.abs(P[:, 2] - zr) <= 1.5]
        band = _mid_ramus_band(ram)
        found[f"mr_{t}"] = (band[np.argmax(side * band[:, 0])], UNCERTAIN,
                            f"the mandible's body is outside the scan: half way up the ramus in it ({z1 - z0:.0f} mm "
                            "high), above the mid-ramus by half the part cut off")


def _mid_ramus_band(ram: np.ndarray) -> np.ndarray:
    """The ramus's points (frame mm, one height) within 3 mm of its middle front to back, or, where none lie there
    (its front and back edges apart with nothing between: thick slices, a thin ramus), those nearest the middle."""
    yc = 0.5 * (ram[:, 1].min() + ram[:, 1].max())
    off = np.abs(ram[:, 1] - yc)
    return ram[off <= max(3.0, float(off.min()))]


def _mandible_side(found, fr, side, t, P, up, low) -> float:
    """The mandible's bilateral landmarks on one side from its points ``P`` (frame mm); returns sub M2's y."""
    # gonion: the outermost point of the angle -- the farthest back-and-down point, then laterally
    k = int(np.argmax(P[:, 1] - P[:, 2]))
    near = P[np.linalg.norm(P[:, 1:] - P[k, 1:], axis=1) < 4.0]
    go = near[np.argmax(side * near[:, 0])]
    found[f"go_{t}"] = (go, OK, "")
    me = low["me"]
    top_z = P[:, 2].max()
    z_occ = 0.5 * (up["sd_z"] + low["id_z"]) if up else low["id_z"] + 3
    # occlusal line on the ramus: outermost mandible point at the occlusal plane, behind the molars
    ram = P[(np.abs(P[:, 2] - z_occ) <= 1.5) & (P[:, 1] > me[1] + 0.6 * (go[1] - me[1]))]
    found[f"ocl_{t}"] = (ram[np.argmax(side * ram[:, 0])], OK, "") if len(ram) else \
        (None, NOT_FOUND, "the ramus does not reach the occlusal plane")
    # sub M2: body below the second molar -- 60 % of the way from menton to gonion, mid-height of the body
    y2 = me[1] + 0.6 * (go[1] - me[1])
    col = P[np.abs(P[:, 1] - y2) <= 1.5]
    found[f"subm2_{t}"] = (None, NOT_FOUND, "no mandibular body at the second molar")
    if len(col):
        zmid = 0.5 * (col[:, 2].min() + min(col[:, 2].max(), low["id_z"]))
        ring = col[np.abs(col[:, 2] - zmid) <= 1.5]
        if len(ring):
            found[f"subm2_{t}"] = (ring[np.argmax(side * ring[:, 0])], OK, "")
    # mid-ramus: outermost point of the ramus half way up from gonion to the condyle's top
    zr = 0.5 * (go[2] + top_z)
    ram = P[(np.abs(P[:, 2] - zr) <= 1.5) & (P[:, 1] > me[1] + 0.6 * (go[1] - me[1]))]
    if len(ram):
        band = _mid_ramus_band(ram)
        found[f"mr_{t}"] = (band[np.argmax(side * band[:, 0])], OK, "")
    else:
        found[f"mr_{t}"] = (None, NOT_FOUND, "no ramus above gonion")
    # mid-mandibular border: the lowest point of the body half way from menton to gonion
    ym = 0.5 * (me[1] + go[1])
    col = P[np.abs(P[:, 1] - ym) <= 1.0]
    found[f"mmb_{t}"] = (col[np.argmin(col[:, 2])], OK, "") if len(col) else \
        (None, NOT_FOUND, "no mandibular border half way to gonion")
    return y2
