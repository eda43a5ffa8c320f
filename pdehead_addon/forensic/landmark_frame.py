"""The landmark frame: the bone mask resampled on a grid of a rigid frame, its depth images (views) and the
pixel tools the landmark rules share (:mod:`pdehead_addon.forensic.auto_landmarks` says the method)."""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from .skull_parts import eroded_components, give_back_rim

OK, UNCERTAIN, NOT_FOUND = "ok", "uncertain", "not_found"
FLAGS = (OK, UNCERTAIN, NOT_FOUND)

#: A flat side (the zygomatic arch): the outermost point is the middle of the bone within this (mm) of it.
SIDE_EXTREME_TOLERANCE_MM = 1.0


# ------------------------------------------------------------------------------------- the frame
class LandmarkFrame:
    """The bone resampled on a grid of a rigid frame: ``bone[ix, iy, iz]``, ``comp[...]`` labels."""

    def __init__(self, ct, bone, labels, rot, centre, step, phase=(0.0, 0.0, 0.0)):
        self.rot, self.centre, self.step = rot, centre, step   # frame = rot @ (patient - centre)
        pts = ct.index_to_patient(np.argwhere(bone)[:: max(1, int(bone.sum() // 200_000))].astype(float))
        f = (pts - centre) @ rot.T
        lo, hi = f.min(0) - 4 * step, f.max(0) + 4 * step
        # the grid's nodes sit at multiples of the step from the centre, shifted by ``phase`` (a fraction of a
        # step per axis): the same bone sampled on another grid (find_landmarks compares several)
        phase = np.asarray(phase, float)
        self.lo = (np.floor(lo / step) - (phase > 0) + phase) * step
        n = np.ceil((hi - self.lo) / step).astype(int) + 1
        self.shape = tuple(int(v) for v in n)
        ax = [self.lo[i] + step * np.arange(n[i]) for i in range(3)]
        self.axes = ax
        bone_f = bone.astype(np.float32)
        out = np.zeros(self.shape, bool)
        gx, gy = np.meshgrid(ax[0], ax[1], indexing="ij")           # (nx, ny), x-major
        to_index = ct.patient_to_index_map()
        for iz, z in enumerate(ax[2]):                                 # one z plane at a time: bounded memory
            fp = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], 1)   # (nx*ny, 3), x-major
            kji = to_index(fp @ rot + centre).T
            out[:, :, iz] = (ndimage.map_coordinates(bone_f, kji, order=1, cval=0.0) > 0.5).reshape(n[0], n[1])
        # the labels only where the bone or a neighbour of it is (all that ``comp`` reads below): most of the grid
        # is air, and the labels' sampling cost as much as the bone's
        lab = np.zeros(self.shape, np.int32)
        near = np.argwhere(ndimage.binary_dilation(out, structure=np.ones((3, 3, 3), bool)))
        for chunk in np.array_split(near, max(1, len(near) // 1_000_000)) if len(near) else ():
            fp = np.stack([ax[0][chunk[:, 0]], ax[1][chunk[:, 1]], ax[2][chunk[:, 2]]], 1)
            lab[tuple(chunk.T)] = ndimage.map_coordinates(labels, to_index(fp @ rot + centre).T, order=0, cval=0)
        self.bone = out
        # bone pixels at the mask's edge may sample label 0 (nearest voxel outside): take a neighbour's label
        filled = np.where(lab > 0, lab, ndimage.grey_dilation(lab, size=(3, 3, 3)))
        self.comp = np.where(out, filled, 0)

    def to_patient(self, f) -> np.ndarray:
        return np.asarray(f, float) @ self.rot + self.centre

    def coord(self, axis: int, index) -> np.ndarray:
        return self.lo[axis] + self.step * np.asarray(index, float)

    def index(self, axis: int, value) -> int:
        return int(np.clip(np.round((value - self.lo[axis]) / self.step), 0, self.shape[axis] - 1))



def first_true(mask: np.ndarray, axis: int, reverse: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Index of the first True along ``axis`` (from the end if ``reverse``) and whether there is one."""
    m = np.flip(mask, axis) if reverse else mask
    idx = np.argmax(m, axis=axis)
    has = m.any(axis=axis)
    if reverse:
        idx = mask.shape[axis] - 1 - idx
    return idx, has


def disc(radius_px: float) -> np.ndarray:
    r = int(np.ceil(radius_px))
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    return xx ** 2 + yy ** 2 <= radius_px ** 2


def pits(height: np.ndarray, valid: np.ndarray, radius_px: float, depth_px: float,
          raw: bool = False) -> np.ndarray:
    """Labelled openings of a height image (larger = nearer the viewer): closing minus image > depth.

    Pixels where no bone is seen (``~valid``) count as infinitely deep; a pit must be enclosed
    by bone seen in the image (a component touching the image border or the outside is dropped).
    With ``raw`` the boolean pit mask before that test is returned.
    """
    low = np.nanmin(np.where(valid, height, np.nan)) - 10 * depth_px
    h = np.where(valid, height, low)
    closed = ndimage.grey_closing(h, footprint=disc(radius_px))
    pits = (closed - h) > depth_px
    if raw:
        return pits
    lab, n = ndimage.label(pits)
    if n == 0:
        return lab
    # outside: background connected to the image border through unseen pixels
    outside_lab, _ = ndimage.label(~valid)
    border = np.unique(np.concatenate([outside_lab[0], outside_lab[-1], outside_lab[:, 0], outside_lab[:, -1]]))
    outside = np.isin(outside_lab, border[border > 0])
    bad = np.unique(lab[outside | np.pad(np.zeros((h.shape[0] - 2, h.shape[1] - 2), bool), 1,
                                         constant_values=True)])
    lab[np.isin(lab, bad[bad > 0])] = 0
    return ndimage.label(lab > 0)[0]


# ------------------------------------------------------------------------------------- views
class DepthViews:
    """Depth images of a :class:`LandmarkFrame` (axes x left, y posterior, z superior)."""

    def __init__(self, fr: LandmarkFrame):
        self.fr = fr
        b = fr.bone
        iy, self.front_has = first_true(b, 1)                       # (nx, nz): first bone from the face
        self.front_y = fr.coord(1, iy)
        il, self.left_has = first_true(b, 0, reverse=True)          # (ny, nz): outermost bone on the left
        self.left_x = fr.coord(0, il)
        ir, self.right_has = first_true(b, 0)
        self.right_x = fr.coord(0, ir)

    def front_point(self, ix: int, iz: int) -> np.ndarray | None:
        if not self.front_has[ix, iz]:
            return None
        return np.array([self.fr.coord(0, ix), self.front_y[ix, iz], self.fr.coord(2, iz)])

    def side_point(self, side: int, iy: int, iz: int) -> np.ndarray | None:
        has, xs = (self.left_has, self.left_x) if side > 0 else (self.right_has, self.right_x)
        if not has[iy, iz]:
            return None
        return np.array([xs[iy, iz], self.fr.coord(1, iy), self.fr.coord(2, iz)])




def nearest_surface(fr: LandmarkFrame, p: np.ndarray, comp_ids=None, radius: float = 6.0) -> np.ndarray | None:
    """The bone voxel of the frame grid nearest ``p`` (restricted to components) within ``radius`` mm."""
    lo = np.array([fr.index(a, p[a] - radius) for a in range(3)])
    hi = np.array([fr.index(a, p[a] + radius) for a in range(3)]) + 1
    sub = fr.bone[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
    if comp_ids is not None:
        sub = sub & np.isin(fr.comp[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]], comp_ids)
    idx = np.argwhere(sub)
    if not len(idx):
        return None
    q = fr.lo + fr.step * (idx + lo)
    return q[int(np.argmin(np.linalg.norm(q - p, axis=1)))]


def midline_profile(fr: LandmarkFrame, mid_x: float, comp_ids) -> tuple[np.ndarray, np.ndarray]:
    """Anterior mid-sagittal profile of the given components: for each z row, min y (NaN: no bone)."""
    ix = fr.index(0, mid_x)
    sl = fr.bone[max(ix - 1, 0):ix + 2] & np.isin(fr.comp[max(ix - 1, 0):ix + 2], comp_ids)
    sl = sl.any(0)                                                      # (ny, nz)
    iy, has = first_true(sl, 0)
    y = np.where(has, fr.coord(1, iy), np.nan)
    return y, has



def side_extreme(fr, side, mask):
    """Outermost (|x|) bone point of ``mask`` (frame grid) on ``side`` (the middle of the bone within
    ``SIDE_EXTREME_TOLERANCE_MM`` of the outermost, snapped to the bone); None if empty."""
    idx = np.argwhere(mask)
    if not len(idx):
        return None
    k = np.argmax(side * idx[:, 0])
    far = idx[side * idx[:, 0] >= side * idx[k, 0] - SIDE_EXTREME_TOLERANCE_MM / fr.step - 0.01]
    p = fr.lo + fr.step * far.mean(0)
    return nearest_surface(fr, p, None, 3.0)


def box_mask(fr, x, y, z):
    """Boolean grid mask of the frame for coordinate ranges (lo, hi) per axis (None: all)."""
    sl = []
    for a, r in enumerate((x, y, z)):
        if r is None:
            sl.append(slice(None))
        else:
            sl.append(slice(fr.index(a, min(r)), fr.index(a, max(r)) + 1))
    m = np.zeros(fr.shape, bool)
    m[tuple(sl)] = True
    return m



def bone_components(bone: np.ndarray) -> tuple[np.ndarray, int]:
    """Connected components of the bone, separated where they touch at partial volume.

    As in :func:`~pdehead_addon.forensic.skull.segment_skull`: the components of the bone eroded by one voxel
    (a closed bite or a joint at partial volume no longer joins the mandible to the skull), then the
    eroded rim given back to the component next to it (three constrained label dilations).
    """
    _, labels, n = eroded_components(bone)
    return give_back_rim(labels, bone).astype(np.int32), int(n)

