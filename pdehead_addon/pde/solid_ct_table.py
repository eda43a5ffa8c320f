"""The CT in the solid's parameter space (u, v, w): one table per study for live cut-aways (section 4.3.1).

:class:`SolidCTTable` samples the CT once at ``X(u_i, v_j, w_k)`` of the PDE solid (eq. 23,
:mod:`.pde_solid`) on a regular parameter grid; each later look-up (a cut-away's faces as the sliders
move) is a trilinear interpolation in (u, v, w), periodic in v. It serialises to bytes for the .blend.
"""
from __future__ import annotations

import json
import zlib

import numpy as np

from ..core.ct_volume import CTVolume, trilinear
from ..core.errors import PDEError, PDEHeadError, report_progress
from ..core.threads import map_in_order
from ..defaults import MAX_STORED_CT_TABLE_BYTES
from ..io.safe_io import decompress_bounded
from .pde_solid import TWO_PI, axial_grid

__all__ = ["SolidCTTable"]

def _between_slices(data: np.ndarray, flat: np.ndarray, slab: int, fk: np.ndarray) -> np.ndarray:
    """The CT between slices k0 and k0 + 1 at fraction `fk` (float32), at the flat indices `flat` of slice k0
    (`data` the CT raveled, `slab` voxels per slice): what interpolating the whole plane gives at those pixels."""
    lower = data[flat]
    return lower + fk * (data[flat + slab] - lower)


class SolidCTTable:
    """The CT tabulated once on a regular (u, v, w) grid of the solid (eq. 23), for live cutaways.

    Texturing a cutaway (section 4.3.1) samples the CT at ``X(u, v, w)`` over every face of
    the parametric box. Evaluating the PDE surface and interpolating the CT for each slider
    step costs tens of milliseconds; the positions depend only on the PDE solution, so the CT
    is sampled once at ``X(u_i, v_j, w_k)`` on a fine regular parameter grid and every later
    look-up is a trilinear interpolation in (u, v, w) with the period 2 pi in v.

    Parameters
    ----------
    head : PDEHead
    ct : CTVolume
    nu, nv, nw : int, optional
        Table resolution. Defaults: about one CT voxel per sample along u and around v and
        two voxels along w, capped at 256 x 256 x 64 (~17 MB float32). 256 around v is twice what
        the solid shows by default (its 128-pixel atlas tiles, nv = 240) and halves the time a PDE
        change waits for its colours.
    chunk : int
        u rows sampled together (bounds the temporary position arrays).
    progress : callable, optional
        ``progress(fraction, message)`` per chunk of u rows; it may raise
        :class:`~pdehead_addon.core.errors.Cancelled`.

    Notes
    -----
    Values are raw CT units (window them afterwards). Outside the CT box the lowest CT
    value is used, as :func:`ct_volume.sample_ct` does. ``table`` is stored ``[w, u, v]``
    (v with one closing column at 2 pi).
    """

    MAX_SHAPE = (256, 256, 64)

    def __init__(self, head, ct: CTVolume, nu: int | None = None, nv: int | None = None,
                 nw: int | None = None, chunk: int = 16, progress=None):
        if nu is None or nv is None or nw is None:
            probe_u = np.linspace(0.0, 1.0, 33)
            probe = head.surface_points(probe_u, 64)                                     # (33, 64, 3) mm
            voxel = float(min(ct.spacing))
            height = float(np.linalg.norm(np.diff(head.spine(probe_u), axis=0), axis=1).sum())
            perimeter = float(np.max(np.linalg.norm(np.diff(probe, axis=1, append=probe[:, :1]), axis=2).sum(axis=1)))
            radius = float(np.max(np.linalg.norm(probe - head.spine(probe_u)[:, None, :], axis=2)))
            auto = (height / voxel, perimeter / voxel, radius / (2.0 * voxel))
            nu_a, nv_a, nw_a = (int(np.clip(np.ceil(n), 16, m)) for n, m in zip(auto, self.MAX_SHAPE))
            nu, nv, nw = nu or nu_a, nv or nv_a, nw or nw_a
        self.shape = (int(nu), int(nv), int(nw))
        self.u = np.linspace(0.0, 1.0, self.shape[0])
        self.v = TWO_PI * np.arange(self.shape[1]) / self.shape[1]
        self.w = np.linspace(0.0, 1.0, self.shape[2])
        inv = np.linalg.inv(ct.affine[:3, :3])
        cval = float(np.min(ct.data)) if ct.data.size else 0.0
        table = np.empty((self.shape[0], self.shape[1] + 1, self.shape[2]), np.float32)
        if self._fill_planar(table, head, ct, cval, chunk, progress):
            self.table = np.ascontiguousarray(table.transpose(2, 0, 1))
            return
        for start in range(0, self.shape[0], chunk):
            report_progress(progress, start / self.shape[0], "tabulating the CT in (u, v, w)")
            us = self.u[start:start + chunk]
            surf = head.surface_points(us, self.shape[1])                                # (c, nv, 3)
            spine = head.spine(us)[:, None, None, :]
            pts = spine + self.w[None, None, :, None] * (surf[:, :, None, :] - spine)
            ijk = (pts.reshape(-1, 3) - ct.origin) @ inv.T
            vals = trilinear(ct.data, ijk[:, ::-1], cval=cval)
            table[start:start + len(us), :-1] = vals.reshape(len(us), self.shape[1], self.shape[2])
        table[:, -1] = table[:, 0]                                               # v = 2 pi is v = 0
        # stored w-major, [w, u, v]: a face at one w (the shells, most texels) is one contiguous slab
        self.table = np.ascontiguousarray(table.transpose(2, 0, 1))

    def _fill_planar(self, table: np.ndarray, head, ct: CTVolume, cval: float, chunk: int, progress=None) -> bool:
        """Fill ``table`` ([u, v, w]) when every u is one axial CT plane; False when it is not.

        For a head solved from axial curves (``planar_z``) on an axial CT grid, all the points
        ``X(u, v, w)`` of one u lie in the plane ``z = A0_z(u)``: the CT is interpolated between
        the two slices around it (at the pixels the samples need only) and then bilinearly in that
        plane, in float32: the same values as :func:`ct_volume.trilinear` (edge half-voxels
        included, `cval` beyond), several times faster.
        """
        if not getattr(head, "planar_z", False) or ct.shape[0] < 2 or min(ct.shape[1:]) < 2:
            return False
        try:
            A, oxy, z0, dzk = axial_grid(ct.spacing, ct.origin, ct.direction)
        except PDEError:
            return False
        A_inv = np.linalg.inv(A).astype(np.float32)
        data = ct.data.reshape(-1)
        nz, ny, nx = ct.data.shape
        slab = ny * nx

        w = self.w.astype(np.float32)[None, None, :, None]

        def rows(start):
            """Table rows start .. start + chunk (their own slice of ``table``: the threads never share one)."""
            us = self.u[start:start + chunk]
            c = len(us)
            spine = head.spine(us)                                               # (c, 3)
            kf = (spine[:, 2] - z0) / dzk
            k_ok = (kf >= -0.5) & (kf <= nz - 0.5)
            kc = np.clip(kf, 0.0, nz - 1)
            k0 = np.clip(np.floor(kc), 0, nz - 2).astype(np.int64)
            fk = np.clip(kc - k0, 0.0, 1.0).astype(np.float32)[:, None, None]
            sxy = spine[:, None, None, :2].astype(np.float32)
            surf = head.surface_points(us, self.shape[1])[..., :2].astype(np.float32)      # (c, nv, 2)
            xy = sxy + w * (surf[:, :, None, :] - sxy)                           # (c, nv, nw, 2)
            ij = (xy - oxy.astype(np.float32)) @ A_inv.T                         # (i, j) index coordinates
            fi, fj = ij[..., 0], ij[..., 1]
            inside = (fi >= -0.5) & (fi <= nx - 0.5) & (fj >= -0.5) & (fj <= ny - 0.5) & k_ok[:, None, None]
            fi = np.clip(fi, 0.0, nx - 1)
            fj = np.clip(fj, 0.0, ny - 1)
            i0 = np.minimum(fi.astype(np.int64), nx - 2)
            j0 = np.minimum(fj.astype(np.int64), ny - 2)
            ti = fi - i0
            tj = fj - j0
            idx = (k0.reshape(c, 1, 1) * ny + j0) * nx + i0                     # in slice k0 of the CT
            a = _between_slices(data, idx, slab, fk)
            b = _between_slices(data, idx + 1, slab, fk)
            lo = a + ti * (b - a)
            a = _between_slices(data, idx + nx, slab, fk)
            b = _between_slices(data, idx + nx + 1, slab, fk)
            hi = a + ti * (b - a)
            vals = lo + tj * (hi - lo)
            vals[~inside] = np.float32(cval)
            table[start:start + c, :-1] = vals

        # the chunks of rows are independent and numpy releases the GIL in their large loops: two threads
        map_in_order(rows, list(range(0, self.shape[0], chunk)),
                     lambda n, _: report_progress(progress, (n + 1) * chunk / self.shape[0],
                                                  "tabulating the CT in (u, v, w)"))
        table[:, -1] = table[:, 0]
        return True

    @property
    def nbytes(self) -> int:
        return int(self.table.nbytes)

    @classmethod
    def from_table(cls, table: np.ndarray) -> "SolidCTTable":
        """A table from its stored values ``[w, u, v]`` (v with the closing column), no CT needed."""
        self = cls.__new__(cls)
        table = np.ascontiguousarray(table, np.float32)
        if table.ndim != 3 or min(table.shape) < 2:
            raise PDEError(f"a solid CT table needs a 3-D [w, u, v] array, got shape {table.shape}")
        nw, nu, nv1 = table.shape
        self.shape = (int(nu), int(nv1 - 1), int(nw))
        self.u = np.linspace(0.0, 1.0, self.shape[0])
        self.v = TWO_PI * np.arange(self.shape[1]) / self.shape[1]
        self.w = np.linspace(0.0, 1.0, self.shape[2])
        self.table = table
        return self

    #: Format tag of :meth:`to_bytes` (8-bit levels of the CT values, zlib-compressed).
    PACK_FORMAT = "pdehead-solid-ct-table-u8-v1"

    def to_bytes(self, window: tuple[float, float], level: int = 1) -> bytes:
        """The table as compact bytes: 8-bit levels, zlib-compressed, with the intensity window.

        The 256 levels span the table's values, bounded to one window width beyond each end of
        the window ``(lo, hi)`` the solid is shown through (metal streaks do not spread them).
        Quantising the CT values (not the windowed ones) keeps the interpolation between table
        samples the same as with the float table: every displayed value moves by at most half a
        level (CThead: 0.5 x 12.8 / 2462 of the window = 0.0026). At the largest table
        (:attr:`MAX_SHAPE`) the 8-bit array is 4.2 MB before compression; a head's table (a third
        of it is air) compresses to about 1.5 MB (CThead, 239 x 256 x 62).
        """
        lo, hi = (float(x) for x in window)
        if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
            raise PDEError(f"the table's window must satisfy lo < hi, got ({lo}, {hi})")
        width = hi - lo
        a = max(min(float(self.table.min()), lo), lo - width)
        b = min(max(float(self.table.max()), hi), hi + width)
        q = np.clip(np.rint((self.table - np.float32(a)) * np.float32(255.0 / (b - a))), 0, 255).astype(np.uint8)
        header = json.dumps({"format": self.PACK_FORMAT, "shape": list(q.shape), "window": [lo, hi],
                             "range": [a, b]}).encode()
        return len(header).to_bytes(4, "little") + header + zlib.compress(q.tobytes(), level)

    @classmethod
    def from_bytes(cls, raw: bytes) -> tuple["SolidCTTable", tuple[float, float]]:
        """``(table, window)`` from :meth:`to_bytes`; values in CT units (lo + level (hi - lo) / 255)."""

        try:
            n = int.from_bytes(raw[:4], "little")
            header = json.loads(raw[4:4 + n].decode())
            if header.get("format") != cls.PACK_FORMAT:
                raise ValueError(f"unknown format {header.get('format')!r}")
            shape = tuple(int(x) for x in header["shape"])
            budget = MAX_STORED_CT_TABLE_BYTES.default
            if len(shape) != 3 or min(shape) < 1 or int(np.prod(shape, dtype=np.float64)) > budget:
                raise ValueError(f"shape {shape} is not a table within {budget // 2 ** 20} MB")
            q = np.frombuffer(decompress_bounded(raw[4 + n:], budget, "the stored solid CT table"),
                              np.uint8).reshape(shape)
            lo, hi = (float(x) for x in header["window"])
            a, b = (float(x) for x in header["range"])
        except (ValueError, KeyError, TypeError, AttributeError, zlib.error, PDEHeadError) as exc:
            raise PDEError(f"the stored solid CT table cannot be read ({exc})") from None
        values = q.astype(np.float32) * np.float32((b - a) / 255.0) + np.float32(a)
        return cls.from_table(values), (lo, hi)

    def sample(self, u, v, w) -> np.ndarray:
        """CT values (float32) at parameters (u, v, w), broadcast together; v taken modulo 2 pi."""
        u, v, w = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float), np.asarray(w, float))
        idx = np.empty(u.shape + (3,))                                           # table order [w, u, v]
        idx[..., 0] = np.clip(w, 0.0, 1.0) * (self.shape[2] - 1)
        idx[..., 1] = np.clip(u, 0.0, 1.0) * (self.shape[0] - 1)
        idx[..., 2] = np.mod(v, TWO_PI) * (self.shape[1] / TWO_PI)
        return trilinear(self.table, idx)

    def sample_grid(self, u, v, w) -> np.ndarray:
        """CT values on the outer-product grid of 1-D parameter samples, shape (len(u), len(v), len(w)).

        Separable linear interpolation, one axis at a time starting with the shortest, so a
        face of the parametric box (one parameter fixed) costs a few hundred thousand flops:
        identical to :meth:`sample` on the grid points, ~10x faster.
        """
        u, v, w = (np.atleast_1d(np.asarray(x, float)) for x in (u, v, w))
        idx = [np.clip(w, 0.0, 1.0) * (self.shape[2] - 1),                      # table order [w, u, v]
               np.clip(u, 0.0, 1.0) * (self.shape[0] - 1),
               np.mod(v, TWO_PI) * (self.shape[1] / TWO_PI)]
        out = self.table
        for axis in sorted(range(3), key=lambda a: len(idx[a])):
            n = out.shape[axis]
            i0 = np.clip(np.floor(idx[axis]).astype(np.int64), 0, max(n - 2, 0))
            f = np.clip(idx[axis] - i0, 0.0, 1.0).astype(np.float32)
            i1 = np.minimum(i0 + 1, n - 1)
            shape = [1, 1, 1]
            shape[axis] = len(f)
            f = f.reshape(shape)
            a = np.take(out, i0, axis=axis)
            out = a + f * (np.take(out, i1, axis=axis) - a)
        return np.moveaxis(out, 0, 2).astype(np.float32, copy=False)               # -> [u, v, w]
