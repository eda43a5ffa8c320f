"""The solved PDE head (:class:`PDEHead`): X(u, v, w) evaluated as points, grids, meshes and UVs.

:func:`~.pde_surface.solve_pde` returns one; it holds the per-span exponents and coefficients of eq. 7-13
and evaluates the surface (:meth:`PDEHead.evaluate`, :meth:`PDEHead.grid`), its spine, the tube mesh with
caps (:meth:`PDEHead.surface`, :mod:`.surface_mesh`), its UV layout and the solid (:mod:`.pde_solid`).
"""
from __future__ import annotations

import numpy as np

from ..core.boundary_set import BoundarySet
from ..core.errors import PDEError
from ..core.mesh import Mesh
from .pde_basis import basis, basis_grid, small_matmul
from .pde_smoothing import lebesgue_constant
from .pde_solid import solid_mesh, w_field
from .pde_spline import dome_height, fade_dome_amplitudes
from .surface_columns import bend_column_density, bend_rows, column_density, column_v, surface_turning
from .surface_mesh import check_count, disc_caps, fan_caps, fan_indices, signed_volume, tube_mesh
from .surface_uv_map import uv_map_grid, uv_shear, uv_tube_map

__all__ = ["PDEHead", "curve_positions", "derived_once", "fold_harmonics", "ring_points", "TWO_PI"]

TWO_PI = 2.0 * np.pi


def derived_once(bset: BoundarySet, name: str, compute):
    """A quantity derived from the curves alone, computed once per boundary set.

    The live sliders re-solve the same curves many times; their harmonics, positions and
    radius do not change. A BoundarySet's curves are not modified after it is made (every
    step returns a new set), and the cache sits on the object, so it goes with it.
    """
    cache = bset.__dict__.setdefault("derived_once", {})
    key = (name, bset.curves.ctypes.data, bset.curves.shape)
    if key not in cache:
        cache[key] = compute()
    return cache[key]


def curve_positions(bset: BoundarySet) -> np.ndarray:
    """Positions (mm) of the curves along the surface: cumulative mean distance between equal-v points
    of consecutive curves (chord length). The C2 spline's parameter: near the crown, where the
    rings shrink fast over little height, the spans are as long as the surface is, so neither the
    interpolation nor the approximating mode is stiffer there than on the sides of the head."""
    def compute():
        step = np.linalg.norm(np.diff(bset.curves, axis=0), axis=2).mean(axis=1)
        return np.concatenate([[0.0], np.cumsum(np.maximum(step, 1e-6))])
    return derived_once(bset, "positions", compute)


# ----------------------------------------------------------------------------- the solved head


class PDEHead:
    """A solved PDE head: Bloor-Wilson spans along u, evaluable anywhere in (u, v, w).

    Do not construct directly; use :func:`solve_pde`.

    Attributes
    ----------
    bset : BoundarySet
        The boundary conditions solved for (not copied).
    continuity : {"c2", "paper"}
        ``"c2"``: one span between each pair of consecutive curves, position and
        derivative conditions, C2 across every curve (:mod:`.pde_spline`).
        ``"paper"``: t patches of four position curves each (eq. 3-6), C0 at the joints.
    smoothing : ndarray
        The smoothing parameter a of eq. 1: one per patch (``"paper"``, local u of the
        patch) or a single global value (``"c2"``, global u).
    modes : int
        N of eq. 11: harmonics with their own exponent ``a n``; the rest is R.
    span_edges : ndarray, shape (S + 1,)
        u where each span starts and ends (``k / t`` for the paper's patches; the
        curves' u and, with a dome, 1.0 for the vertex).
    curve_u : ndarray, shape (3t+1,)
        u of each boundary curve.
    knots : ndarray, shape (t, 4)
        Paper patches only: local knots ``(0, p1, p2, 1)`` of each patch.
    exponents : ndarray, shape (S, H)
        Exponent of every harmonic h = 0 .. M//2 on each span (in the span's local s).
    coefficients : ndarray of complex, shape (S, H, 4, 3)
        Basis coefficients: ``A_h(s) = basis(k_h, s) @ coefficients[i, h]`` and
        ``X(s, v) = Re sum_h A_h(s) e^{i h v}`` (so ``A_h - i B_h`` of eq. 9-10).
    condition : ndarray, shape (S,)
        Largest 1-norm condition number of the per-harmonic 4x4 systems.
    approximation_mm : float
        Smoothing length along u (``"c2"``; 0: the surface passes through every curve).
    vertex : ndarray or None
        The crown's pole (LPS mm) when the surface closes in a dome, else None.
    smoothing_is_default : bool
        True when ``smoothing`` was chosen by :func:`solve_pde` (stored as such by storage).
    remainder : bool
        False when the harmonics above ``modes`` were dropped (eq. 13's F, see :func:`solve_pde`).
    planar_z : bool
        Every curve lies in a plane z = const; then ``z(u, v, w) = A0_z(u)`` exactly.
    orientation : int
        +1 if the quads ``(u,v) -> (u,v+1) -> (u+1,v+1) -> (u+1,v)`` face outward, else -1.
    """

    def __init__(self, bset: BoundarySet, smoothing: np.ndarray, modes: int, knots: np.ndarray | None,
                 exponents: np.ndarray, coefficients: np.ndarray, condition: np.ndarray,
                 planar_z: bool, span_edges: np.ndarray | None = None, curve_u: np.ndarray | None = None,
                 continuity: str = "paper", approximation_mm: float = 0.0, vertex: np.ndarray | None = None):
        self.bset = bset
        self.smoothing = smoothing
        self.modes = modes
        self.knots = knots
        self.exponents = exponents
        self.coefficients = coefficients
        self.condition = condition
        self.planar_z = planar_z
        self.continuity = continuity
        self.approximation_mm = float(approximation_mm)
        self.vertex = vertex
        S = coefficients.shape[0]
        self.span_edges = np.linspace(0.0, 1.0, S + 1) if span_edges is None else np.asarray(span_edges, float)
        self.curve_u = np.asarray(bset.u_knots if curve_u is None else curve_u, float)
        self.smoothing_is_default = False
        self.remainder = True
        self._coef_real = np.ascontiguousarray(
            np.concatenate([coefficients.real, coefficients.imag], axis=-1))   # (S, H, 4, 6)
        self._uniform_spans = bool(np.allclose(self.span_edges, np.linspace(0.0, 1.0, S + 1), atol=1e-12))
        self._cubic_spans = ~np.any(exponents, axis=1)
        S_, H_ = coefficients.shape[:2]
        self._coef_flat = np.ascontiguousarray(self._coef_real.transpose(0, 2, 1, 3)).reshape(S_ * 4, H_ * 6)
        # the crown's dome (last span): which rotating part of the top ring's harmonic 1 is its ellipticity
        self._dome_minor = 0
        if vertex is not None and S > 0 and H_ > 1:
            a1 = basis(exponents[-1, 1], 0.0) @ coefficients[-1, 1]
            self._dome_minor = -1 if abs(a1[0] + 1j * a1[1]) >= abs(a1[0] - 1j * a1[1]) else 1
            self._cubic_spans[-1] = False                                      # evaluated with its fade
        self.orientation = 1
        self.orientation = self._measure_orientation()
        self._deviation = None

    def storage_settings(self) -> dict:
        """The solver settings a boundary file stores beside the curves (:func:`.head_files.load_head`
        solves the curves with them again): smoothing, modes, continuity and, for the C2 surface, the
        approximation length and whether the crown is a dome."""
        settings = {"smoothing": [float(a) for a in self.smoothing], "modes": int(self.modes),
                    "smoothing_is_default": bool(getattr(self, "smoothing_is_default", False)),
                    "continuity": self.continuity, "remainder": bool(getattr(self, "remainder", True))}
        if self.continuity == "c2":
            settings.update(approximation_mm=float(self.approximation_mm), dome=self.vertex is not None)
        return settings

    # -- basic properties
    @property
    def lebesgue(self) -> np.ndarray:
        """Paper patches: the Lebesgue constant of each patch's largest exponent (overshoot factor)."""
        if self.knots is None:
            raise PDEError("the Lebesgue constant is defined for the paper's four-curve patches only")
        return lebesgue_constant(self.exponents.max(axis=1), self.knots)

    @property
    def patches(self) -> int:
        """t, the user's patch count (3t+1 curves), whatever the continuity."""
        return self.bset.patches

    @property
    def spans(self) -> int:
        """Number S of pieces along u (t paper patches, or the spans between curves)."""
        return self.coefficients.shape[0]

    @property
    def harmonics(self) -> int:
        """Number of harmonics h = 0 .. M//2 carried."""
        return self.coefficients.shape[1]

    @property
    def curve_deviation(self) -> float:
        """Largest distance (mm) between a boundary curve and the surface row at its u (0 when exact)."""
        if self._deviation is None:
            rows = self.surface_points(self.curve_u, self.bset.samples)
            self._deviation = float(np.linalg.norm(rows - self.bset.curves, axis=-1).max())
        return self._deviation

    def _patch_of(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Span index and local s in [0, 1] of each u."""
        u = np.asarray(u, dtype=np.float64)
        S = self.spans
        if self._uniform_spans:
            scaled = u * S
            patch = np.clip(np.floor(scaled).astype(np.int64), 0, S - 1)
            return patch, scaled - patch
        e = self.span_edges
        patch = np.clip(np.searchsorted(e, u, side="right") - 1, 0, S - 1)
        return patch, (u - e[patch]) / (e[patch + 1] - e[patch])

    @staticmethod
    def _check_u(u: np.ndarray) -> None:
        if not np.all(np.isfinite(u)) or np.any(u < -1e-12) or np.any(u > 1 + 1e-12):
            raise PDEError("u must lie in [0, 1]")

    # -- harmonic amplitudes
    def amplitudes(self, u: np.ndarray, harmonics: int | None = None) -> np.ndarray:
        """Complex harmonic amplitudes ``A_h(u) - i B_h(u)`` (eq. 7-8, weighted), shape (len(u), H, 3).

        ``harmonics`` limits the computation to h < harmonics (1: the spine only); the
        arithmetic per harmonic is the same either way.
        """
        u = np.clip(np.asarray(u, dtype=np.float64).ravel(), 0.0, 1.0)
        patch, s = self._patch_of(u)
        H = self.harmonics if harmonics is None else int(harmonics)
        out = np.empty((u.size, H, 3), dtype=np.complex128)
        cubic = self._cubic_spans[patch]                                      # a = 0 there: one basis for all h
        if np.any(cubic):
            # one product: rows x (span, basis) weights (4 per row) times (span, basis) x (h, re/im xyz)
            rows = np.flatnonzero(cubic)
            g = basis(np.zeros(1), s[rows, None])[:, 0]                       # (n, 4)
            S = self.spans
            flat = self._coef_flat if H == self.harmonics else \
                np.ascontiguousarray(self._coef_flat.reshape(S * 4, -1, 6)[:, :H]).reshape(S * 4, H * 6)
            for start in range(0, rows.size, 512):
                sl = rows[start:start + 512]
                W = np.zeros((len(sl), S * 4))
                W[np.arange(len(sl))[:, None], 4 * patch[sl, None] + np.arange(4)] = g[start:start + 512]
                prod = small_matmul(W, flat).reshape(len(sl), H, 6)
                out[sl] = prod[..., :3] + 1j * prod[..., 3:]
        for k in np.unique(patch[~cubic]):
            sel = np.nonzero(patch == k)[0]
            g = basis_grid(self.exponents[k, :H], s[sel])                    # (n, H, 4)
            # batched over h: (H, n, 4) @ (H, 4, 6 = re xyz, im xyz)
            prod = np.einsum("hnb,hbc->nhc", g.transpose(1, 0, 2), self._coef_real[k, :H])
            amp = prod[..., :3] + 1j * prod[..., 3:]
            if self._dome_minor and k == self.spans - 1:                     # the crown's dome span
                amp = fade_dome_amplitudes(amp, s[sel], self.vertex, self._dome_minor)
            out[sel] = amp
        return out

    def spine(self, u: np.ndarray | float) -> np.ndarray:
        """The spine ``A_0(u)`` (eq. 8): the centre line, shape ``u.shape + (3,)``."""
        u = np.asarray(u, dtype=np.float64)
        self._check_u(u)
        return self.amplitudes(u.ravel(), harmonics=1)[:, 0].real.reshape(u.shape + (3,))

    # -- evaluation
    def evaluate(self, u: np.ndarray | float, v: np.ndarray | float, w: np.ndarray | float = 1.0,
                 chunk: int = 8192) -> np.ndarray:
        """Points ``X(u, v, w) = A0(u) + w (X(u, v) - A0(u))`` (eq. 11 and 23) in LPS mm.

        Parameters
        ----------
        u, v, w : array_like
            Broadcast together; ``u in [0, 1]``, v in radians (periodic), ``w`` usually in [0, 1].

        Returns
        -------
        ndarray, shape ``broadcast(u, v, w).shape + (3,)``
        """
        u, v, w = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float), np.asarray(w, float))
        self._check_u(u)
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(w))):
            raise PDEError("v and w must be finite")
        shape = u.shape
        uf, vf, wf = u.ravel(), v.ravel(), w.ravel()
        out = np.empty((uf.size, 3))
        h = np.arange(self.harmonics)
        for start in range(0, uf.size, chunk):
            sl = slice(start, start + chunk)
            amp = self.amplitudes(uf[sl])                                    # (n, H, 3)
            phase = np.exp(1j * np.outer(vf[sl], h))                          # (n, H)
            radial = np.einsum("nhc,nh->nc", amp[:, 1:], phase[:, 1:]).real
            out[sl] = amp[:, 0].real + wf[sl, None] * radial
        return out.reshape(shape + (3,))

    def surface_points(self, u: np.ndarray, nv: int | None = None, v: np.ndarray | None = None) -> np.ndarray:
        """Surface points on the grid u x v (eq. 11 at w = 1), shape (len(u), nv, 3), freshly computed.

        Parameters
        ----------
        u : array_like, shape (nu,)
            Rows, in [0, 1] (clipped).
        nv : int, optional
            Columns ``v_j = 2 pi j / nv``: the synthesis is an inverse real FFT (harmonics above nv/2
            are folded, which is exact at the sample points).
        v : array_like, optional
            Explicit columns (radians) instead of ``nv``: a direct cosine/sine sum.

        Returns
        -------
        ndarray, shape (nu, nv, 3)
            LPS mm. :meth:`grid` is the same, remembered for the last few samplings (read-only).
        """
        H = self.harmonics
        if v is not None:
            amp = self.amplitudes(u)                                         # (nu, H, 3)
            phase = np.exp(1j * np.outer(np.arange(H), np.asarray(v, float)))   # (H, nv)
            a = amp.transpose(0, 2, 1).reshape(-1, H)                          # (nu*3, H)
            # contiguous real and imaginary parts: strided views would miss BLAS (~10x slower)
            pts = (np.ascontiguousarray(a.real) @ np.ascontiguousarray(phase.real)
                   - np.ascontiguousarray(a.imag) @ np.ascontiguousarray(phase.imag))
            return pts.reshape(len(u), 3, -1).transpose(0, 2, 1)
        u = np.clip(np.asarray(u, dtype=np.float64).ravel(), 0.0, 1.0)
        nb = nv // 2 + 1
        spec = np.empty((u.size, 3, nb), np.complex128)
        patch, s = self._patch_of(u)
        cubic = self._cubic_spans[patch]
        if np.any(cubic):
            rows = np.flatnonzero(cubic)
            g = basis(np.zeros(1), s[rows, None])[:, 0]                        # (n, 4)
            # each row has four basis weights on its span's four coefficient rows: gathered, not a dense
            # (rows x 4 spans) product. With no harmonic above nv/2 the coefficients are the spectrum's first
            # H bins as they are (a new head each live drag needs no per-nv table); otherwise the
            # harmonics are folded once per nv (cached) and gathered the same way.
            H_bins = H if H <= (nv + 1) // 2 else nb
            F = self._coef_flat if H_bins == H else self._folded(nv)
            first = 4 * patch[rows]
            folded = g[:, :1] * F[first]
            for b in range(1, 4):
                folded += g[:, b:b + 1] * F[first + b]
            folded = folded.reshape(rows.size, H_bins, 6)
            spec[rows] = 0.0
            spec[rows, :, :H_bins] = (folded[..., :3] + 1j * folded[..., 3:]).transpose(0, 2, 1)
        if not np.all(cubic):
            rows = np.flatnonzero(~cubic)
            spec[rows] = fold_harmonics(self.amplitudes(u[rows]).transpose(0, 2, 1), nv)
        return ring_points(spec, nv)

    def grid(self, u: np.ndarray, nv: int | None = None, v: np.ndarray | None = None) -> np.ndarray:
        """:meth:`surface_points`, remembered per head for its last four samplings (read-only arrays).

        A live change rebuilds the surface and then the solid on the same (nu, nv) grid: the solid
        reads the surface's points instead of synthesising them again, and a w-range or nw change
        reuses them too. Rows do not depend on each other (``surface_points(u)[:-1]`` is ``surface_points(u[:-1])``
        bit for bit: ``tests/segment/test_speed_identities.py``), so the dome's surface takes the first rows.
        """
        u = np.asarray(u, dtype=np.float64)
        key = (u.tobytes(), None if nv is not None else np.asarray(v, float).tobytes(), nv)
        entries = self.__dict__.setdefault("_grid_cache", {})
        pts = entries.get(key)
        if pts is None:
            pts = self.surface_points(u, nv) if nv is not None else self.surface_points(u, None, v=v)
            pts.flags.writeable = False
            if len(entries) >= 4:
                entries.pop(next(iter(entries)))
            entries[key] = pts
        return pts

    def _folded(self, nv: int) -> np.ndarray:
        """The (span, basis) x (bin, re/im xyz) coefficients with the harmonics folded onto the nv//2 + 1
        bins of an nv-point ring (cached per nv: the sliders rebuild at a few resolutions)."""
        cache = self.__dict__.setdefault("_folded_cache", {})
        if nv not in cache:
            H, nb = self.harmonics, nv // 2 + 1
            h = np.arange(H)
            m = h % nv
            conj = m > nv // 2
            b = np.where(conj, nv - m, m)
            c = self._coef_flat.reshape(-1, H, 6)
            k = c.shape[0]
            if H <= nv:
                # each harmonic lands on one bin, and the unfolded ones (h <= nv / 2) and the folded ones
                # (conjugated, nv - h) each on distinct bins: two scatters instead of a (H x bins) product
                out = np.zeros((k, nb, 6))
                out[:, b[~conj]] = c[:, ~conj]
                folded = c[:, conj] * np.array([1.0, 1.0, 1.0, -1.0, -1.0, -1.0])   # conjugates flip im
                out[:, b[conj]] += folded
            else:
                F_re = np.zeros((H, nb))
                np.add.at(F_re, (h, b), 1.0)
                F_im = F_re * np.where(conj, -1.0, 1.0)[:, None]            # conjugates flip the imaginary part
                ct = np.ascontiguousarray(c.transpose(0, 2, 1))                # (k, 6, H)
                re = small_matmul(ct[:, :3].reshape(-1, H), F_re).reshape(k, 3, nb)
                im = small_matmul(ct[:, 3:].reshape(-1, H), F_im).reshape(k, 3, nb)
                out = np.concatenate([re, im], axis=1).transpose(0, 2, 1)      # (k, nb, 6)
            if len(cache) > 8:
                cache.clear()
            cache[nv] = np.ascontiguousarray(out).reshape(k, nb * 6)
        return cache[nv]

    def _measure_orientation(self) -> int:
        """Sign of the volume enclosed by the polyhedral tube through the curves, default winding.

        The surface passes through (or, approximating, next to) the curves, so the
        coarse tube whose rings are the curves has the orientation of the surface.
        For curves stacked along z that all wind the same way (every set
        :func:`extract_boundaries` makes) that sign is the winding times the
        stacking direction, without building the tube.
        """
        c = self.bset.curves
        xy = c[..., :2]
        area = (xy[..., 0] * np.roll(xy[..., 1], -1, axis=1) - np.roll(xy[..., 0], -1, axis=1) * xy[..., 1]).sum(1)
        dz = np.diff(self.bset.heights)
        if (np.all(area > 0) or np.all(area < 0)) and (np.all(dz > 0) or np.all(dz < 0)):
            return 1 if area[0] * dz[0] > 0 else -1
        rings = c[:, ::max(1, self.bset.samples // 64)]
        mesh = tube_mesh(rings, orientation=1, caps=fan_caps(rings, rings[[0, -1]].mean(axis=1), fan_only=True))
        return 1 if signed_volume(mesh) >= 0 else -1

    def surface(self, nu: int, nv: int, caps: bool = False, uv: bool = True, rows: np.ndarray | None = None,
                fit_bends: bool = False) -> Mesh:
        """The head surface as a tube of quads (paper Fig. 4, 5, 13).

        Parameters
        ----------
        nu : int
            Rows along u, including u = 0 and u = 1 (>= 2). With a dome the row
            u = 1 is the single vertex of the crown, joined by a triangle fan.
        nv : int
            Columns along v (>= 3), the seam stitched; ``v_j = 2 pi j / nv``, closer in v where an outline
            runs nearly radially (:meth:`v_columns`: no ring edge much longer than the curves' mean step).
        caps : bool
            Close the bottom (and, without a dome, the top) with triangles: a flat disc
            triangulated ring by ring (:class:`.surface_mesh.DiscCap`, no triangle much
            longer than the tube's edges) when the end curve is star-shaped around its
            spine point, else a triangulation of the ring; watertight for 3-D printing.
        uv : bool
            Per-corner UVs (:meth:`uv_layout`, computed once per boundary set: ~0.65 s CPU on a head).
            False for a mesh only measured (the slice selection's verification).
        rows : ndarray, optional
            The rows' u (increasing from 0 to 1, ``nu`` of them) instead of ``nu`` evenly spaced (a print
            mesh denser over the face: :func:`.detail_displace.print_rows`).
        fit_bends : bool
            Rows (unless ``rows``) and columns closer where the surface bends tightly (:meth:`bend_layout`).

        Returns
        -------
        Mesh
            Quads wound outward; per-corner UVs in islands that are functions of (u, v)
            (:meth:`uv_layout`: the tube, the crown's dome and the cap, none mirrored),
            vertex attributes ``u`` and ``v`` (cap points: the end's u and their v).
        """
        nu, nv = check_count(nu, "nu", 2), check_count(nv, "nv", 3)
        if self.vertex is not None:
            nu = max(nu, 3)
        fitted, density = self.bend_layout(nu) if fit_bends else (np.linspace(0.0, 1.0, nu), self.v_density())
        u = np.asarray(fitted if rows is None else rows, float)
        if len(u) != nu or u[0] != 0.0 or u[-1] != 1.0 or np.any(np.diff(u) <= 0):
            raise PDEError(f"rows: {nu} increasing values from 0 to 1 expected")
        ends = self.spine(np.array([0.0, 1.0]))
        columns = None if density is None else column_v(density, nv)
        reference = (self.cap_reference(nu, nv, True) if fit_bends else self.cap_reference(nu, nv)) if caps else None
        if self.vertex is not None:
            # the solid's grid too (it has the pole row; pde_solid takes the same columns)
            pts = (self.grid(u, nv) if density is None else self.grid(u, v=columns))[:-1]
            bottom = disc_caps(pts, ends, ends=(0,), reference=reference)[0] if caps else None
            top = (np.asarray(self.vertex, float), fan_indices(nv))
            return tube_mesh(pts, self.orientation, [bottom, top], uv=uv, u=u[:-1], top_u=1.0,
                              uv_layout=self.uv_layout() if uv else None, v_density=density)
        pts = self.grid(u, nv) if density is None else self.grid(u, v=columns)
        cap_tris = disc_caps(pts, ends, reference=reference) if caps else None
        return tube_mesh(pts, self.orientation, cap_tris, uv=uv, u=u, uv_layout=self.uv_layout() if uv else None,
                          v_density=density)

    def v_density(self) -> np.ndarray | None:
        """How densely the surface's columns sample each of the curves' v steps
        (:func:`.surface_columns.column_density` of the end curves the caps close: the bottom one, and the top
        one without a dome), None for equal steps. From the boundary curves alone: one per study.

        Only the capped ends: the same density from every curve would also even the ears, but it moves
        faces into them and the UVs' area stretch and angle distortion there grow past their limits; the
        end curves alone shorten the long edges of the caps' rings and keep the UVs within them."""
        ends = [0] if self.vertex is not None else [0, -1]
        return derived_once(self.bset, f"v_density{len(ends)}", lambda: column_density(self.bset.curves[ends]))

    def v_columns(self, nv: int) -> np.ndarray:
        """The v (radians) of the surface's nv columns (:func:`.surface_columns.column_v`): ``2 pi j / nv``
        where the end curve's samples are about evenly spaced, closer where its outline runs nearly
        radially (there equal steps of v would give the end ring and its cap long edges)."""
        return column_v(self.v_density(), int(nv))

    def bend_layout(self, nu: int) -> tuple[np.ndarray, np.ndarray | None]:
        """A bend-fitted mesh's nu rows and column density (:mod:`.surface_columns`) from the turning of
        ``reference_solve()`` (set by ``solve_pde``: the head it makes of these curves at its defaults; else
        this head): one per boundary set (~0.35 s), kept by sliders and files."""
        dome = self.vertex is not None
        def compute():
            reference = getattr(self, "reference_solve", None)
            fine_u, turn_u, turn_v = surface_turning(self if reference is None else reference())
            return fine_u, turn_u, bend_column_density(turn_v, self.v_density())
        fine_u, turn_u, density = derived_once(self.bset, f"bend_layout{dome}", compute)
        return bend_rows(turn_u, fine_u, nu), density

    def cap_reference(self, nu: int, nv: int, bends: bool = False) -> dict:
        """What fixes the disc caps' vertex counts (:func:`.surface_mesh.disc_caps`): the tube's mean edge
        at (nu, nv) and the end curves' perimeters and largest radii, from the boundary curves alone, so
        the shape sliders rebuild the surface with the same topology (``bends``: :meth:`bend_layout`'s)."""
        def compute():
            c = self.bset.curves
            perimeter = np.linalg.norm(np.roll(c, -1, axis=1) - c, axis=2).sum(axis=1)
            radius = np.linalg.norm(c - c.mean(axis=1, keepdims=True), axis=2).max(axis=1)
            span = float(curve_positions(self.bset)[-1])
            if self.vertex is not None:
                span += float(np.linalg.norm(c[-1] - c[-1].mean(axis=0), axis=1).mean())
            density = self.bend_layout(3)[1] if bends else self.v_density()

            def arc_fraction(ring):
                """Cumulative length at the column fraction k / K, k = 0 .. K (with equal v steps: at
                v = 2 pi k / M), the abscissa of the cap's ring points (:class:`.surface_mesh.DiscCap`)."""
                closed = np.vstack([ring, ring[:1]])
                arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
                if density is None:
                    return arc / arc[-1]
                K = 4 * len(ring)
                v = column_v(density, K)
                return np.append(np.interp(v, TWO_PI * np.arange(len(ring) + 1) / len(ring), arc), arc[-1]) / arc[-1]
            return span, float(perimeter.mean()), ((perimeter[0], radius[0], arc_fraction(c[0])),
                                                   (perimeter[-1], radius[-1], arc_fraction(c[-1])))
        span, mean_perimeter, end_rings = derived_once(self.bset, f"cap_ref{self.vertex is not None}{bends}", compute)
        edge = 0.5 * (span / max(nu - 1, 1) + mean_perimeter / nv)
        return {"edge": edge, "ends": end_rings}

    def uv_layout(self) -> dict:
        """The surface's UV islands (:func:`.surface_uv_map.uv_islands`), from the boundary curves alone, so
        the UVs are one function of (u, v) for a study: nu, nv and the shape sliders do not move a
        painted texture. ``u_top``: where the dome starts in u; ``aspect``: the tube island's height over
        its width; ``tube_map``: :func:`.surface_uv_map.uv_tube_map` of the curves (U, V in mm at the
        samples of :func:`.surface_uv_map.uv_map_grid`, rows ``map_u``) and ``tube_box`` its extent; with a
        single curve ``shear`` (:func:`.surface_uv_map.uv_shear`) instead."""
        def compute():
            c = self.bset.curves
            perimeter = np.linalg.norm(np.roll(c, -1, axis=1) - c, axis=2).sum(axis=1)
            steps = np.diff(curve_positions(self.bset))
            length = float(steps.sum())
            tube = float((0.5 * (perimeter[1:] + perimeter[:-1]) * steps).sum())

            def flat_area(ring):
                d = ring - ring.mean(axis=0)
                return 0.5 * float(np.linalg.norm(np.cross(d, np.roll(d, -1, axis=0)).sum(axis=0)))
            # a spherical cap's area is pi times the squared chord from its pole to its rim
            r_top = float(np.linalg.norm(c[-1] - c[-1].mean(axis=0), axis=1).mean())
            h = dome_height(c, self.bset.heights, self.bset.meta.get("vertex_z"))
            top = np.pi * (r_top ** 2 + h ** 2) if self.vertex is not None else flat_area(c[-1])
            return (length / max(float(perimeter.mean()), 1e-9), top / max(tube, 1e-9),
                    flat_area(c[0]) / max(tube, 1e-9))
        aspect, dome_ratio, cap_ratio = derived_once(self.bset, f"uv_areas{self.vertex is not None}", compute)
        u_top = float(self.curve_u[-1]) if self.vertex is not None else 1.0
        curve_u = np.asarray(self.curve_u, float)
        if len(curve_u) < 2:
            shear = derived_once(self.bset, "uv_shear", lambda: uv_shear(self.bset.curves, curve_u))
            return {"u_top": u_top, "aspect": aspect, "curve_u": curve_u, "shear": shear,
                    "dome_ratio": dome_ratio, "cap_ratio": cap_ratio}

        # The map is a function of the curves' u up to scale (the spline through the curves and the
        # tangents' directions do not change when u is scaled), and the dome's tip rescales u at every
        # approximation or smoothing change: solved on u / u[-1] (rounded to 12 digits, so the key and
        # the result do not depend on the last bits of the scale), its rows scaled back to u.
        span = float(curve_u[-1] - curve_u[0])
        unit_u = np.round((curve_u - curve_u[0]) / span, 12) if span > 0 else curve_u

        density = self.v_density()

        def tube_map():                 # near-conformal, even-scale UVs of the tube (mm)
            rings, map_u = uv_map_grid(self.bset.curves, unit_u, v_density=density)
            U, V, W = uv_tube_map(rings, map_u)
            box = (float(U.min()), float(max(U.max(), (U[:, 0] + W).max())), float(V.min()), float(V.max()))
            return (U, V, W), box, map_u
        # keyed by the curves' u too: the paper's patches and the C2 spline place the same curves at other u
        table, box, unit_map_u = derived_once(self.bset, f"uv_tube_map{hash(unit_u.tobytes())}", tube_map)
        map_u = curve_u[0] + unit_map_u * span if span > 0 else unit_map_u
        return {"u_top": u_top, "aspect": (box[3] - box[2]) / (box[1] - box[0]), "curve_u": curve_u, "map_u": map_u,
                "shear": None, "tube_map": table, "tube_box": box, "dome_ratio": dome_ratio,
                "cap_ratio": cap_ratio, "v_density": density}

    def solid(self, nu: int, nv: int, nw: int, u_range: tuple[float, float] = (0.0, 1.0),
              v_range: tuple[float, float] = (0.0, TWO_PI), w_range: tuple[float, float] = (0.0, 1.0)) -> Mesh:
        """The boundary of the parametric box of the solid (eq. 23), see :func:`pde_solid.solid_mesh`."""
        return solid_mesh(self, nu, nv, nw, u_range, v_range, w_range)

    def w_field(self, grid, ct=None, progress=None):
        """The w-field and masked intensity on a voxel grid, see :func:`pde_solid.w_field`."""
        return w_field(self, grid, ct, progress=progress)

    def __repr__(self) -> str:
        return (f"PDEHead(continuity={self.continuity!r}, patches={self.patches}, spans={self.spans}, "
                f"samples={self.bset.samples}, modes={self.modes}, "
                f"smoothing={np.round(self.smoothing, 4).tolist()}, approximation_mm={self.approximation_mm:g})")


def fold_harmonics(a: np.ndarray, nv: int) -> np.ndarray:
    """Complex harmonics (..., H) folded onto the nv//2 + 1 bins of an nv-point real signal (exact at the samples)."""
    H = a.shape[-1]
    nb = nv // 2 + 1
    spec = np.zeros(a.shape[:-1] + (nb,), np.complex128)
    if H <= (nv + 1) // 2:                                                     # no folding, no Nyquist clash
        spec[..., :H] = a
        return spec
    h = np.arange(H)
    m = h % nv
    conj = m > nv // 2
    b = np.where(conj, nv - m, m)
    np.add.at(spec, (Ellipsis, b[~conj]), a[..., ~conj])
    if np.any(conj):
        np.add.at(spec, (Ellipsis, b[conj]), np.conj(a[..., conj]))
    return spec


def ring_points(spec: np.ndarray, nv: int) -> np.ndarray:
    """The rings' points (rows, nv, 3) from their folded Fourier amplitudes ``spec`` (rows, 3, nv//2 + 1):
    ``x_j = a_0 + sum_b (a_b cos + b_b sin)``, as one inverse real FFT (``spec`` is scaled in place)."""
    # irfft weights: x_j = (1/nv)[Y_0 + 2 Re sum Y_b w^bj + Y_{nv/2} (-1)^j]
    spec *= nv / 2.0
    spec[..., 0] *= 2.0
    if nv % 2 == 0:
        spec[..., -1] *= 2.0
    return np.fft.irfft(spec, n=nv, axis=-1).transpose(0, 2, 1)
