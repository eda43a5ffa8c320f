"""Mid-sagittal landmarks on the landmark frame's profile: vertex, opisthocranion, the nasal profile (glabella,
nasion, rhinion, mid-nasal), the upper jaw (subspinale, mid-philtrum, supradentale) and the mandible's (infradentale,
supramentale, pogonion, gnathion, menton); rules in :data:`pdehead_addon.forensic.auto_landmarks.RULES`."""
from __future__ import annotations

import numpy as np

from .landmark_frame import NOT_FOUND, OK, UNCERTAIN, first_true, midline_profile
from .mandible_pieces import pieces_nearer_the_mandible

#: Crown heights used where teeth and alveolar bone are one object in a bone mask (mm): upper and
#: lower central incisor crowns (Wheeler's Dental Anatomy, 10th ed., table 1-1: 10.5 and 9.0 mm).
UPPER_INCISOR_CROWN_MM = 10.5
LOWER_INCISOR_CROWN_MM = 9.0
#: Length of the nasal bones, nasion to rhinion (mm; adult means are about 20-25 mm): without them in the
#: bone mask, the maxilla is looked for from this far below nasion.
NASAL_BONE_LENGTH_MM = 20.0
#: Vertex is looked for on the vault's top within this distance (mm) of the mid-sagittal plane.
VERTEX_HALF_WIDTH_MM = 30.0
#: The upper jaw's mid-sagittal profile: rows whose front lies up to this far (mm) behind nasion's depth, down to
#: the first row whose front-most bone is more than OCCLUSAL_GAP_MM behind the last jaw row (below the incisors).
UPPER_JAW_DEPTH_MM = 25.0
OCCLUSAL_GAP_MM = 20.0
#: Supramentale is uncertain where the mandible's profile from pogonion to infradentale misses more than
#: SUPRAMENTALE_GAP_MM of rows, or its deepest point lies more than SUPRAMENTALE_MAX_DEPTH_MM behind the chord
#: (the concavity above an adult chin is a few mm deep; deeper is other bone behind the mandible's front).
SUPRAMENTALE_GAP_MM = 3.0
SUPRAMENTALE_MAX_DEPTH_MM = 8.0
#: The mandible's front, walked up from menton, ends at the first row whose front-most bone lies more than this
#: (mm) behind the row below, as the upper jaw's ends at OCCLUSAL_GAP_MM: bone joined to the mandible behind its
#: front is not its front (the atlas's anterior arch, 43 mm behind the incisors at their height, on CThead
#: resliced to 1.5 mm). Notches of the incisors' edges step back up to 8 mm.
MANDIBLE_FRONT_STEP_MM = OCCLUSAL_GAP_MM
#: The mandible reaches back from its front at least this fraction of the way to the porions (its body runs back to
#: the rami, its condyles sit just in front of the ear canals: CThead's reaches 82 % of the way; the phantom scaled by
#: 1.12, whose rami the threshold splits off, 43 %). The upper teeth and the front of the alveolar process, split from
#: the maxilla by the threshold, reach 29 % (CThead cut at the occlusal plane, where that piece was taken for the
#: mandible and the upper jaw's landmarks moved 9-22 mm up). Half way between those two: the margins are narrow.
MANDIBLE_REACH_FRACTION = 0.36
#: ... and where it crosses the mid-sagittal plane it does so at the face's front (the chin, the incisors): in front of
#: this fraction of the way from the orbitales back to the porions (CThead's chin: in front of the orbitales). The
#: atlas, kept in the bone where a scan cut through the lower teeth leaves the spine too short to be told from the
#: skull, crosses it 73 % of the way back and was taken for the mandible (infradentale 77 mm behind the face).
MANDIBLE_MIDLINE_FRACTION = 0.5
#: Glabella on a forehead without a prominence: the profile's turn is measured over this (mm) either side.
GLABELLA_TURN_MM = 5.0
#: Vertex's x is the middle of the vault's left-right extent this far (mm) below its top.
VERTEX_CHORD_MM = 15.0


def _midline_upper(res, fr, mid_x, skull_ids, mand_ids, orb_z, aperture):
    """Midline landmarks of the skull (rules in :data:`~pdehead_addon.forensic.auto_landmarks.RULES`); returns the upper
    jaw's heights for the other rules ({} when the profile stops before it)."""
    ix = fr.index(0, mid_x)
    slab = fr.bone[max(ix - 1, 0):ix + 2].any(0)                        # (ny, nz)
    skull_slab = slab & np.isin(fr.comp[max(ix - 1, 0):ix + 2], skull_ids).any(0)
    pts = np.argwhere(skull_slab)
    if not len(pts):
        for key in ("v", "op", "g", "n", "mn", "rhi", "ss", "mp", "sd"):
            res[key] = (None, NOT_FOUND, "no skull bone on the mid-sagittal plane")
        return {}
    res["v"] = _vertex(fr, mid_x, skull_ids)
    # a flat back gives a plateau: its middle, from the points within 1.5 mm of the extreme
    back = pts[pts[:, 0] >= pts[:, 0].max() - 1.5 / fr.step]
    iz = int(np.round(np.median(back[:, 1])))
    iy = int(np.flatnonzero(skull_slab[:, iz]).max())
    res["op"] = (np.array([mid_x, fr.coord(1, iy), fr.coord(2, iz)]), OK, "")

    py, has = midline_profile(fr, mid_x, skull_ids)
    nasal = _nasal_profile(res, fr, mid_x, py, has, orb_z)
    if nasal is None:
        return {}
    i_n, i_rhi = nasal
    return _upper_jaw(res, fr, mid_x, slab, skull_ids, mand_ids, py, has, i_n, i_rhi, orb_z, aperture)


def _vertex(fr, mid_x, skull_ids):
    """Vertex: a vault is rarely symmetric about the whole skull's plane (its top may sit several mm to one side),
    and a flat top makes the plane's x decide the point: take the top surface within VERTEX_HALF_WIDTH_MM of the
    plane, the columns within 1.5 mm of its highest, and their middle."""
    ix_lo, ix_hi = fr.index(0, mid_x - VERTEX_HALF_WIDTH_MM), fr.index(0, mid_x + VERTEX_HALF_WIDTH_MM)
    band = fr.bone[ix_lo:ix_hi + 1] & np.isin(fr.comp[ix_lo:ix_hi + 1], skull_ids)
    top_iz, top_has = first_true(band, 2, reverse=True)                 # (nx', ny)
    height = np.where(top_has, top_iz, -1)
    cols = np.argwhere(height >= height.max() - 1.5 / fr.step)
    cx, cy = np.median(cols, axis=0)
    k = int(np.argmin((cols[:, 0] - cx) ** 2 + (cols[:, 1] - cy) ** 2))   # a top column nearest the middle
    ixv, iyv = int(cols[k, 0]), int(cols[k, 1])
    # the vault's own midline at that y: the middle of its left-right extent VERTEX_CHORD_MM below the top (a
    # vault is rarely symmetric about the whole skull's plane; CThead's top sits 2-4 mm beside it)
    iz_c = int(height[ixv, iyv] - round(VERTEX_CHORD_MM / fr.step))
    if iz_c >= 0:
        row = np.flatnonzero(fr.bone[:, iyv, iz_c] & np.isin(fr.comp[:, iyv, iz_c], skull_ids))
        if len(row) >= 2:
            ixm = int(round(0.5 * (row.min() + row.max()))) - ix_lo
            if 0 <= ixm < height.shape[0] and height[ixm, iyv] >= height.max() - 3.0 / fr.step:
                ixv = ixm
    return (np.array([fr.coord(0, ix_lo + ixv), fr.coord(1, iyv), fr.coord(2, height[ixv, iyv])]), OK, "")


def _nasal_profile(res, fr, mid_x, py, has, orb_z):
    """Glabella, nasion, rhinion and mid-nasal on the skull's profile ``py`` (rows with bone: ``has``); returns the
    rows of nasion and rhinion (rhinion's row is nasion's when it is not found), None without a glabella."""
    z = fr.coord(2, np.arange(fr.shape[2]))
    band = has & (z >= orb_z + 25) & (z <= orb_z + 65)
    if not band.any():
        res["g"] = (None, NOT_FOUND, "no frontal bone 25-65 mm above orbitale on the midline")
        return None
    ig = int(np.flatnonzero(band)[np.nanargmin(py[band])])
    res["g"] = (np.array([mid_x, py[ig], z[ig]]), OK, "")
    # walk down the continuous profile from glabella (frontal bone, then the nasal bones)
    walk = [ig]
    for k in range(ig - 1, -1, -1):
        if not has[k] or abs(py[k] - py[walk[-1]]) > 4.0 or z[k] < orb_z - 25:
            break
        walk.append(k)
    walk = np.array(walk)
    nas = walk[z[walk] >= orb_z]
    i_n = int(nas[np.argmax(py[nas])]) if len(nas) else ig
    below = walk[z[walk] < z[i_n]]
    if py[i_n] - py[ig] >= 2.0:
        res["n"] = (np.array([mid_x, py[i_n], z[i_n]]), OK, "")
        if len(below) >= 6 and py[below[-1]] < py[i_n] - 2:
            i_rhi = int(below[-1])
            res["rhi"] = (np.array([mid_x, py[i_rhi], z[i_rhi]]), OK, "")
        else:
            i_rhi = int(below[-1]) if len(below) else i_n
            res["rhi"] = (np.array([mid_x, py[i_rhi], z[i_rhi]]), UNCERTAIN,
                          f"the nasal bones run only {len(below) * fr.step:.0f} mm below nasion in the bone mask")
    else:
        # no concavity: the outline runs on from the forehead; without the nasal bones in the mask the
        # frontal bone's lowest point is where they would join
        i_n = int(walk[-1])
        res["n"] = (np.array([mid_x, py[i_n], z[i_n]]), UNCERTAIN,
                    "no concavity below glabella: nasion taken where the frontal bone's outline ends")
        i_rhi = i_n
        res["rhi"] = (None, NOT_FOUND, "the nasal bones are not in the bone mask below nasion")
    if ig <= int(np.flatnonzero(band).min()) + 1 and z[i_n] < z[ig] and py[i_n] < py[ig] - 2.0:
        _glabella_without_prominence(res, fr, mid_x, py, has, i_n)
    i_mn = int(np.round(0.5 * (i_n + i_rhi)))
    res["mn"] = (None, NOT_FOUND, res["rhi"][2]) if res["rhi"][0] is None else \
        (np.array([mid_x, py[i_mn] if has[i_mn] else py[i_n], z[i_mn]]), res["rhi"][1], res["rhi"][2])
    return i_n, i_rhi


def _glabella_without_prominence(res, fr, mid_x, py, has, i_n):
    """No prominence between the brows: the profile still comes forward below the band, all the way down to
    nasion, which stands more than 2 mm in front of the band's front-most point (a receding forehead). Glabella is
    then where the profile turns from the nasal root up into the forehead: its greatest convexity (the slope's
    largest fall over GLABELLA_TURN_MM either side) between nasion and 25 mm above it."""
    z = fr.coord(2, np.arange(fr.shape[2]))
    w = max(1, int(round(GLABELLA_TURN_MM / fr.step)))
    ks = np.arange(i_n + w, min(fr.index(2, z[i_n] + 25.0), len(z) - 1 - w) + 1)
    ks = ks[has[ks] & has[ks - w] & has[ks + w]]
    if len(ks):
        turn = (py[ks] - py[ks - w]) - (py[ks + w] - py[ks])      # slope below minus slope above
        k = int(ks[np.argmax(turn)])
        res["g"] = (np.array([mid_x, py[k], z[k]]), UNCERTAIN,
                    "the forehead has no prominence (the profile comes forward all the way down to nasion): "
                    "glabella taken where the profile turns from the nasal root into the forehead")


def _upper_jaw(res, fr, mid_x, slab, skull_ids, mand_ids, py, has, i_n, i_rhi, orb_z, aperture):
    """Subspinale, supradentale and mid-philtrum on the upper jaw's profile; returns its heights ({} without a
    maxilla below the nasal aperture)."""
    z = fr.coord(2, np.arange(fr.shape[2]))
    ix = fr.index(0, mid_x)
    # upper jaw: going down the midline profile from rhinion, the nasal aperture is deep (the profile runs
    # back to the septum or finds no bone); the maxilla starts at the first row whose front-most bone is
    # the upper skeleton's and lies within 15 mm of nasion's depth (the anterior nasal spine)
    iy_all, has_all = first_true(slab, 0)
    front_comp = fr.comp[max(ix - 1, 0):ix + 2].max(0)[iy_all, np.arange(fr.shape[2])]
    face_any = has & has_all & np.isin(front_comp, skull_ids) & (np.abs(fr.coord(1, iy_all) - py) < 1.5)
    face = face_any & (py < py[i_n] + 15)
    k = i_rhi - int(round(3 / fr.step))
    if res["rhi"][0] is None:
        # the nasal bones are not in the mask: the bone just below nasion (frontal processes, bits of the
        # nasal bones) would pass for the maxilla; look from one nasal-bone length below nasion
        k = min(k, fr.index(2, z[i_n] - NASAL_BONE_LENGTH_MM))
    while k > 0 and not face[k]:
        k -= 1
    if k <= 0 or z[k] < orb_z - 80:
        for key in ("ss", "mp", "sd"):
            res[key] = (None, NOT_FOUND, "no maxilla below the nasal aperture on the midline")
        return {}
    # the upper jaw's profile: the rows down from the spine until the front-most bone is the mandible's
    # (its teeth) or no bone is met for 10 mm; thin bone (the nasal floor, the spine) leaves shorter gaps
    i_top = k
    # below the spine the maxilla's front may lie deeper than 15 mm behind nasion (the concavity of subspinale
    # on a skull whose nasal root juts forward): the profile rows go UPPER_JAW_DEPTH_MM behind it
    face = face_any & (py < py[i_n] + UPPER_JAW_DEPTH_MM)
    face[i_top + 1:] = False
    i_low = _upper_jaw_bottom(fr, py, face, i_top, iy_all, has_all, front_comp, set(mand_ids))
    rows = np.arange(i_low, i_top + 1)
    rows = rows[face[rows]]
    upper_ev = "" if aperture is not None else "no nasal aperture in the front view"
    i_sd = int(np.argmin(np.abs(z - (z[i_low] + UPPER_INCISOR_CROWN_MM))))
    i_sd = min(max(i_sd, i_low), i_top)
    seg = rows[(rows >= i_sd)]
    i_ss, ss_y = _subspinale(z, py, seg, i_sd, i_top)
    res["ss"] = (np.array([mid_x, ss_y, z[i_ss]]), UNCERTAIN if upper_ev else OK, upper_ev)
    res["sd"] = (np.array([mid_x, py[i_sd], z[i_sd]]), UNCERTAIN,
                 f"teeth and alveolar bone are one in a bone mask: placed {UPPER_INCISOR_CROWN_MM:g} mm "
                 "(an upper incisor crown) above the lowest point of the upper jaw")
    i_mp = int(np.round(0.5 * (i_ss + i_sd)))
    res["mp"] = (np.array([mid_x, py[i_mp] if has[i_mp] else py[i_ss], z[i_mp]]), res["ss"][1], res["ss"][2])
    return {"sd_z": z[i_sd], "low_z": z[i_low], "sd_y": py[i_sd]}


def _upper_jaw_bottom(fr, py, face, i_top, iy_all, has_all, front_comp, mand) -> int:
    """The lowest row of the upper jaw's profile, going down from the spine's row ``i_top``."""
    i_low, gap, j = i_top, 0, i_top - 1
    while j > 0:
        if has_all[j] and front_comp[j] in mand:
            break
        if has_all[j] and fr.coord(1, iy_all[j]) - py[i_low] > OCCLUSAL_GAP_MM:
            # the front-most bone jumps far back: below the upper incisors' edges (the lower teeth behind them
            # are split from the mandible by the threshold and would pass for the upper jaw)
            break
        if face[j]:
            i_low, gap = j, 0
        else:
            gap += 1
            if gap * fr.step > 10.0:
                break
        j -= 1
    return i_low


def _subspinale(z, py, seg, i_sd, i_top):
    """Subspinale: the deepest point of the concavity between the anterior nasal spine and prosthion (row, y)."""
    spine_rows = seg[z[seg] >= z[i_top] - 8.0]          # the anterior nasal spine: the top 8 mm's front-most point
    i_ans = int(spine_rows[np.argmin(py[spine_rows])]) if len(spine_rows) else i_top
    upper = seg[(seg >= i_sd) & (seg <= max(i_ans, i_sd))]
    # deepest relative to the chord from prosthion to the spine
    if len(upper) >= 3 and i_ans != i_sd:
        chord = py[i_sd] + (py[i_ans] - py[i_sd]) * (z[upper] - z[i_sd]) / (z[i_ans] - z[i_sd])
        # the median of three rows: a single row missing the thin cortex in front of the maxilla is a notch of
        # the mask, not of the bone
        smooth = np.array([np.median(py[seg[max(i - 1, 0):i + 2]]) for i in np.searchsorted(seg, upper)])
        i_ss = int(upper[np.argmax(smooth - chord)])
        ss_y = float(smooth[np.argmax(smooth - chord)])
    else:
        top_rows = seg[seg > i_sd]
        i_ss = int(top_rows[np.argmax(py[top_rows])]) if len(top_rows) else i_sd
        ss_y = float(py[i_ss])
    return i_ss, ss_y


def _mandible_midline(res, fr, mid_x, mand_ids):
    z = fr.coord(2, np.arange(fr.shape[2]))
    py, has = midline_profile(fr, mid_x, mand_ids)
    if not has.any():
        for key in ("id", "sm", "pog", "gn", "me"):
            res[key] = (None, NOT_FOUND, "the mandible does not cross the mid-sagittal plane")
        return {}
    rows = np.flatnonzero(has)
    back = np.flatnonzero(np.diff(py[rows]) > MANDIBLE_FRONT_STEP_MM)
    if len(back):
        rows = rows[:back[0] + 1]
    i_bot, i_top = int(rows.min()), int(rows.max())
    ix = fr.index(0, mid_x)
    slab = (fr.bone[max(ix - 1, 0):ix + 2] & np.isin(fr.comp[max(ix - 1, 0):ix + 2], mand_ids)).any(0)
    low = np.argwhere(slab[:, i_bot])[:, 0]
    me = np.array([mid_x, fr.coord(1, np.median(low)), z[i_bot]])
    res["me"] = (me, OK, "")
    mid = 0.5 * (z[i_bot] + z[i_top])
    lower = rows[z[rows] <= mid]
    i_pog = int(lower[np.argmin(py[lower])])
    res["pog"] = (np.array([mid_x, py[i_pog], z[i_pog]]), OK, "")
    i_id = int(rows[np.argmin(np.abs(z[rows] - (z[i_top] - LOWER_INCISOR_CROWN_MM)))])
    i_id = max(min(i_id, i_top), i_pog)
    res["id"] = (np.array([mid_x, py[i_id], z[i_id]]), UNCERTAIN,
                 f"teeth and alveolar bone are one in a bone mask: placed {LOWER_INCISOR_CROWN_MM:g} mm "
                 "(a lower incisor crown) below the highest point of the mandible's front")
    seg = np.arange(i_pog, i_id + 1)
    seg = seg[has[seg]]
    if len(seg) >= 3 and i_id > i_pog:
        chord = py[i_pog] + (py[i_id] - py[i_pog]) * (z[seg] - z[i_pog]) / (z[i_id] - z[i_pog])
        dep = py[seg] - chord
        i_sm = int(seg[np.argmax(dep)])
        gap = float((np.diff(seg).max() - 1) * fr.step) if len(seg) > 1 else 0.0   # rows without the mandible
        if gap > SUPRAMENTALE_GAP_MM:
            flag, ev = UNCERTAIN, (f"the mandible's profile between pogonion and infradentale has a gap of "
                                   f"{gap:.0f} mm: not one anterior surface")
        elif dep.max() > SUPRAMENTALE_MAX_DEPTH_MM:
            flag, ev = UNCERTAIN, (f"the profile runs {dep.max():.0f} mm behind the chord from pogonion to "
                                   f"infradentale (more than {SUPRAMENTALE_MAX_DEPTH_MM:g} mm): bone behind the "
                                   "mandible's front, not its concavity")
        elif dep.max() < 1.0:
            flag, ev = UNCERTAIN, "the mandible's front has no concavity above the chin"
        else:
            flag, ev = OK, ""
        res["sm"] = (np.array([mid_x, py[i_sm], z[i_sm]]), flag, ev)
    else:
        res["sm"] = (None, NOT_FOUND, "no mandible profile between infradentale and pogonion")
    # gnathion: the profile point between pogonion and menton farthest along the anterior-inferior bisector
    pts = np.argwhere(slab[:, i_bot:i_pog + 1])
    cand = np.stack([fr.coord(1, pts[:, 0]), z[i_bot + pts[:, 1]]], 1)
    j = int(np.argmax(-cand[:, 0] - cand[:, 1]))
    res["gn"] = (np.array([mid_x, cand[j, 0], cand[j, 1]]), OK, "")
    return {"id_z": z[i_id], "me": me}


def _lower_teeth_pieces(fr, pieces: list[int], mand_id: int) -> list[int]:
    """Of the bone pieces (components) between the jaws, those of the mandible
    (:func:`~.mandible_pieces.pieces_nearer_the_mandible`): lower teeth split from it by the threshold lie next to
    it, a palate or upper teeth split from the skull lie next to the upper skeleton."""
    return pieces_nearer_the_mandible(fr.comp, fr.bone, fr.step, pieces, fr.comp == mand_id)


def mandible_component(fr, nlab: int, skull_id: int, skull_mm3: float, grid_mm: float, orb_z: float,
                       porion_y: float | None = None, orbitale_y: float | None = None, mid_x: float = 0.0):
    """The mandible: the largest other component (of at least 2000 mm^3) below the orbits that reaches back at
    least :data:`MANDIBLE_REACH_FRACTION` of the way from its front to the porions (``porion_y``, frame mm) and, if
    it crosses the mid-sagittal plane ``mid_x``, does so in front of :data:`MANDIBLE_MIDLINE_FRACTION` of the way from
    the orbitales (``orbitale_y``) to the porions (each not checked without those landmarks); (its label or None,
    the evidence when there is none). ``skull_mm3``: the skull component's volume."""
    mand_id, mand_ev = None, "no mandible: no separate bone component below the maxilla"
    if nlab > 1:
        comp_ids, counts = np.unique(fr.comp[fr.comp > 0], return_counts=True)
        best = 0
        for cid, cnt in zip(comp_ids, counts):
            if cid == skull_id or cnt * grid_mm ** 3 < 2000:
                continue
            where = np.argwhere(fr.comp == cid)
            cz = fr.coord(2, where[:, 2].mean())
            if porion_y is not None:
                front, back = fr.coord(1, where[:, 1].min()), fr.coord(1, where[:, 1].max())
                if back - front < MANDIBLE_REACH_FRACTION * (porion_y - front):
                    continue                 # the upper teeth split from the maxilla: the front of the arch alone
                on_mid = np.abs(fr.coord(0, where[:, 0]) - mid_x) <= 3.0
                if orbitale_y is not None and on_mid.any() and (fr.coord(1, where[on_mid, 1].min()) - orbitale_y
                                                                > MANDIBLE_MIDLINE_FRACTION * (porion_y - orbitale_y)):
                    continue                 # crosses the midline behind the face: a vertebra (the atlas)
            if cz < orb_z - 30 and cnt > best:
                mand_id, best = int(cid), cnt
        if mand_id is None and skull_mm3 > 0:
            mand_ev = ("no mandible: no separate bone component 30 mm below orbitale (missing, or joined to the "
                       "skull at the teeth)")
    return mand_id, mand_ev


def midline_landmarks(found, fr, mid_x, nlab, skull_id, mand_id, mand_ev, orb_z, aperture):
    """Every mid-sagittal landmark into ``found``; returns the upper jaw's and the mandible's heights for the
    bilateral rules (each {} when not found)."""
    # the upper skeleton: every kept component but the mandible (thin bone splits a face into pieces)
    upper_ids = [int(i) for i in range(0, nlab + 1) if i != mand_id]    # 0: thin bone no component reached
    mand_top = None
    if mand_id is not None:
        ixm = fr.index(0, mid_x)
        col = (fr.comp[max(ixm - 1, 0):ixm + 2] == mand_id).any((0, 1))
        mand_top = fr.coord(2, np.flatnonzero(col).max()) if col.any() else None
    up = _midline_upper(found, fr, mid_x, upper_ids, [mand_id] if mand_id else [], orb_z, aperture)
    if mand_id is None:
        for key in ("id", "sm", "pog", "gn", "me"):
            found[key] = (None, NOT_FOUND, mand_ev)
        return up, {}
    # lower teeth split from the mandible by the threshold count as the mandible: the pieces on the
    # midline between the upper jaw and the mandible's top that lie nearer the mandible than the upper
    # skeleton (a palate or upper teeth split from the skull reach down into that window too)
    ids = [mand_id]
    if up and mand_top is not None:
        ixm = fr.index(0, mid_x)
        izs = slice(fr.index(2, mand_top - 15), fr.index(2, up["low_z"] - 1) + 1)
        n_pt = found.get("n", (None,))[0]
        iy_lim = fr.shape[1] if n_pt is None else fr.index(1, n_pt[1] + 40.0)   # the face, not the spine
        pieces = np.unique(fr.comp[max(ixm - 1, 0):ixm + 2, :iy_lim, izs])
        ids += _lower_teeth_pieces(fr, [int(i) for i in pieces if i not in (0, skull_id, mand_id)], mand_id)
    low = _mandible_midline(found, fr, mid_x, ids)
    _infradentale_behind_the_upper_incisors(found)
    return up, low


def _infradentale_behind_the_upper_incisors(found) -> None:
    """Infradentale not found where it lies more than :data:`MANDIBLE_FRONT_STEP_MM` behind supradentale: the lower
    incisors close behind the upper ones, and bone that far back is not their front (CThead cut through the lower
    teeth at 250 HU: 31 mm behind, on bone behind the teeth; whole heads: 3-8 mm)."""
    sd, idn = found.get("sd", (None,))[0], found.get("id", (None,))[0]
    if sd is None or idn is None:
        return
    behind = float(idn[1] - sd[1])
    if behind > MANDIBLE_FRONT_STEP_MM:
        found["id"] = (None, NOT_FOUND, f"the mandible's front at the lower incisors' height lies {behind:.0f} mm "
                                        f"behind supradentale (more than {MANDIBLE_FRONT_STEP_MM:g} mm): not the "
                                        "lower incisors, which close behind the upper ones")
        if found.get("sm", (None,))[0] is not None:          # its rule's chord ends at infradentale
            found["sm"] = (None, NOT_FOUND, "infradentale not found: no chord from pogonion to it")
