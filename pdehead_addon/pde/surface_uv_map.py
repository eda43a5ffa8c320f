"""The UV map of the head's tube: a least-squares map of the boundary curves, and the UV islands.

The tube is one island (v across, u up: :func:`uv_tube_map`, a map of the boundary curves,
refined between them by :func:`uv_map_grid`, that keeps the cells' angles and texel size, with the seam's
shear :func:`uv_shear`), the crown's dome and each cap a disc (:func:`uv_islands`). All of it is a function
of the boundary curves alone, computed once per study (:meth:`~.pde_head.PDEHead.uv_layout`);
:mod:`.surface_mesh` gives each face corner its UV from it.
"""
from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix

from .pde_spline import natural_spline_matrix
from .surface_columns import column_v

__all__ = ["uv_islands", "uv_shear", "uv_tube_map", "uv_map_grid", "UV_MARGIN", "UV_SCALE_WEIGHT",
           "UV_FOLD_MARGIN", "UV_FOLD_GROW", "UV_MAP_SUBROWS", "UV_MAP_SAMPLES"]

TWO_PI = 2.0 * np.pi


#: Gap (fraction of the texture) around every UV island: texture painting bleeds into it, not across the seam.
UV_MARGIN = 0.02


def uv_islands(aspect: float, dome_ratio: float | None = None, cap_ratio: float | None = None) -> dict:
    """Where the surface's UV islands lie in [0, 1]^2 (one layout per study: a function of (u, v) only).

    The tube (curves' u range x v) is a rectangle across the bottom of the texture, as wide as the
    margins allow and as high as ``aspect`` (the tube's length over its mean circumference) makes
    it; the crown's dome and the bottom cap are discs side by side above it, each as large as the
    space allows but no larger than the tube's texel density gives its 3-D area (``dome_ratio`` /
    ``cap_ratio``: its area over the tube's), so the islands' texels are about the same size.
    """
    m = UV_MARGIN
    width = 1.0 - 2.0 * m
    height = float(np.clip(width * aspect, 0.2, 1.0 - 3.0 * m - 0.3))
    room = min(0.5 * (1.0 - 3.0 * m - height), 0.25 * (1.0 - 3.0 * m))
    top = 1.0 - m - room

    def disc(ratio):
        if ratio is None or not np.isfinite(ratio) or ratio <= 0:
            return room
        return float(min(room, np.sqrt(width * height * ratio / np.pi) / 0.9))
    return {"tube": (m, m, width, height), "radius": room, "dome_radius": disc(dome_ratio),
            "cap_radius": disc(cap_ratio), "dome": (0.25 + 0.25 * m, top), "cap": (0.75 - 0.25 * m, top)}


#: The shear correction of the tube's UVs keeps the harmonics up to this order around the ring (no UV folds).
UV_SHEAR_HARMONICS = 3


def uv_shear(curves: np.ndarray, curve_u: np.ndarray) -> np.ndarray:
    """Sideways drift phi(u, v) (radians of v) of the v = const lines, at the curves, shape (n, M).

    Along u the line v = const moves along the ring by ``X_u . X_v / |X_v|^2`` radians per unit u
    (curves: the boundary curves, equal v = corresponding points; ``X_u`` by differences between
    curves, ``X_v`` around each curve). Integrated over u (zero mean over the curves) and low-passed
    around the ring (:data:`UV_SHEAR_HARMONICS`; scaled down if needed so ``v - phi`` stays increasing),
    ``U ~ v - phi`` is constant along the curves' orthogonal trajectories.
    """
    c = np.asarray(curves, float)
    n, M, _ = c.shape
    if n < 2:
        return np.zeros((n, M))
    xv = (np.roll(c, -1, axis=1) - np.roll(c, 1, axis=1)) * (M / (2.0 * TWO_PI))
    xu = np.gradient(c, np.asarray(curve_u, float), axis=0)
    rate = -np.einsum("ijk,ijk->ij", xu, xv) / np.maximum(np.einsum("ijk,ijk->ij", xv, xv), 1e-12)
    du = np.diff(curve_u)[:, None]
    phi = np.concatenate([np.zeros((1, M)), np.cumsum(0.5 * (rate[1:] + rate[:-1]) * du, axis=0)])
    phi -= phi.mean(axis=0, keepdims=True)
    spec = np.fft.rfft(phi, axis=1)
    spec[:, UV_SHEAR_HARMONICS + 1:] = 0.0
    phi = np.fft.irfft(spec, n=M, axis=1)
    slope = (np.roll(phi, -1, axis=1) - phi) * (M / TWO_PI)
    worst = slope.max()
    if worst > 0.7:                                                     # keep dU/dv >= 0.3 of the unsheared
        phi *= 0.7 / worst
    return phi


#: Weight of the even-scale term against the conformal term in :func:`uv_tube_map` (mm-normalised). The
#: conformal term alone keeps the angles but lets the texel size follow the neck's and the face's shape;
#: the scale term alone keeps the texel size but not the angles. 0.8 keeps both the area stretch
#: (p99 / p1) and the angle distortion (p95) within their limits at the defaults (the measures:
#: docs/benchmarks.md, the face up close).
UV_SCALE_WEIGHT = 0.8


def uv_tube_map(curves: np.ndarray, curve_u: np.ndarray, scale_weight: float = UV_SCALE_WEIGHT
                ) -> tuple[np.ndarray, np.ndarray, float]:
    """The tube's UVs (mm) at the boundary curves' samples: a least-squares map that is nearly conformal
    and nearly of one scale, shape ``(n, M)`` each, and the wrap ``W`` (mm) of U around the ring.

    Each cell between curves ``k, k+1`` and samples ``j, j+1`` gives, at each of two opposite corners
    ((k, j) and (k+1, j+1): both of the cell's triangles), the corner's two edges in the surface's local
    frame there (along the ring, across it), ``z_v`` and ``z_u`` (complex numbers, mm). The map
    ``w = U + iV`` should take them to ``w_v, w_u`` with

    * ``w_v z_u - w_u z_v = 0`` (the cell's corner angles kept: a discrete Cauchy-Riemann condition, as
      in least-squares conformal maps: B. Levy, S. Petitjean, N. Ray, J. Maillot, "Least squares conformal
      maps for automatic texture atlas generation", ACM Trans. Graph. 21(3), 362-371 (SIGGRAPH 2002);
      cited from the literature, not re-read here), weighted by the cell's sine over ``|z_u||z_v|^1.5``;
    * ``w_v = z_v``, ``w_u = z_u`` weighted by ``sqrt(scale_weight)`` (one texel size, the rings' direction
      along U).

    U wraps by ``W`` (the curves' mean perimeter) around the ring, V is periodic: the seam is a cut of
    one island. Both are fixed by the curves alone (one layout per study).

    Least squares does not promise a map without folds, so it is solved twice: with one V per ring
    (straight rows: with U increasing along every ring, which a last step enforces, no cell can fold)
    and with V free (better angles). The map is the free one, blended back toward the straight one
    around every cell that is folded or not convex (``UV_FOLD_MARGIN``; within ``UV_FOLD_GROW``
    samples and a one-sample taper, the free share halved up to six times, then straight there), so no
    mesh face inside it folds at any nu, nv (checked on CThead and GE from 40 x 60 to 300 x 480). CPU ~0.4 s once per
    study on CThead at t = 15 (91 x 128 samples: :func:`uv_map_grid`), ~0.15 s on GE (t = 8).
    """
    from scipy.sparse.linalg import splu  # deferred: ~10 ms at `import pdehead_addon`
    R = np.asarray(curves, float)
    k, M, _ = R.shape
    xv = np.roll(R, -1, axis=1) - np.roll(R, 1, axis=1)
    xu = np.gradient(R, np.asarray(curve_u, float), axis=0) if k > 1 else np.zeros_like(R)
    normal = np.cross(xv, xu)
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
    t1 = xv / np.maximum(np.linalg.norm(xv, axis=-1, keepdims=True), 1e-12)
    t2 = np.cross(normal, t1)
    if np.mean(np.einsum("ijk,ijk->ij", t2, xu)) < 0:
        t2 = -t2
    W = float(np.linalg.norm(np.roll(R, -1, axis=1) - R, axis=-1).sum(axis=1).mean())
    N = k * M
    i2, j2 = np.meshgrid(np.arange(k - 1), np.arange(M), indexing="ij")
    o = (i2 * M + j2).ravel()
    pv = (i2 * M + (j2 + 1) % M).ravel()
    pu = ((i2 + 1) * M + j2).ravel()
    wrap = (j2 == M - 1).ravel() * W
    Rf, T1, T2 = R.reshape(-1, 3), t1.reshape(-1, 3), t2.reshape(-1, 3)
    pvu = ((i2 + 1) * M + (j2 + 1) % M).ravel()
    m = len(o)

    def corner(c0, cv, cu, wrap_v):
        """A cell's corner ``c0`` with its neighbours along v (``cv``) and u (``cu``), and U's wrap on the way
        to ``cv``: the two edges in ``c0``'s frame, ``z_v`` and ``z_u``, and the conformal weight."""
        ev, eu = Rf[cv] - Rf[c0], Rf[cu] - Rf[c0]
        zv = np.einsum("ij,ij->i", ev, T1[c0]) + 1j * np.einsum("ij,ij->i", ev, T2[c0])
        zu = np.einsum("ij,ij->i", eu, T1[c0]) + 1j * np.einsum("ij,ij->i", eu, T2[c0])
        # scale-free, and weighted by the cell's sine: a sliver cell (its edges nearly parallel, where rows
        # crowd under the nose) cannot say which way its angles go
        s = np.abs((zu * np.conj(zv)).imag) / np.maximum(np.abs(zu) * np.abs(zv), 1e-12) ** 1.5
        return c0, cv, cu, wrap_v, zv, zu, s
    # Both triangles of every cell: the corner o (edges to pv and pu) and the opposite corner pvu (edges
    # back to pu and pv). With o alone the triangle (pv, pvu, pu) of each cell would be in no equation and
    # its angles free to distort.
    corners = [corner(o, pv, pu, wrap), corner(pvu, pu, pv, -wrap)]
    area3 = (corners[0][5] * np.conj(corners[0][4])).imag                    # > 0: the frame's orientation
    floor = 0.2 * np.linalg.norm(np.roll(R, -1, axis=1) - R, axis=-1)

    def solve(straight_rows: bool):
        """U (k, M) increasing along every ring, V (k, M); ``straight_rows``: one V per ring."""
        rows, cols, vals, rhs = [], [], [], []
        count = 0
        unknowns = N + (k if straight_rows else N)

        def add(index, coefs, rhs_part):
            nonlocal count
            for ix, cf in zip(index, coefs):
                rows.append(count + np.arange(m))
                cols.append(ix)
                vals.append(cf)
            rhs.append(rhs_part)
            count += m
        L = np.full(m, np.sqrt(float(scale_weight)))
        for c0, cv, cu, wv, zv, zu, s in corners:
            a, b, c, d = zu.real * s, zu.imag * s, zv.real * s, zv.imag * s
            Vv, V0, Vu = (N + cv // M, N + c0 // M, N + cu // M) if straight_rows else (N + cv, N + c0, N + cu)
            add([cv, c0, Vv, V0, cu, c0, Vu, V0], [a, -a, -b, b, -c, c, d, -d], -a * wv)
            add([cv, c0, Vv, V0, cu, c0, Vu, V0], [b, -b, a, -a, -d, d, -c, c], -b * wv)
            add([cv, c0], [L, -L], L * (zv.real - wv))
            add([cu, c0], [L, -L], L * zu.real)
            add([Vu, V0], [L, -L], L * zu.imag)
            if not straight_rows:
                add([Vv, V0], [L, -L], L * zv.imag)
        A = csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(count, unknowns))
        gauge = csr_matrix((np.ones(2), ([0, 1], [0, N])), shape=(2, unknowns))  # U = V = 0 at the first sample
        # the normal matrix is symmetric positive definite: no pivoting (SuperLU's symmetric mode) factors
        # it in less CPU time than pivoting, the map within 2e-10 mm of pivoting's
        x = splu((A.T @ A + gauge.T @ gauge).tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                 options={"SymmetricMode": True}).solve(A.T @ np.concatenate(rhs))
        U = x[:N].reshape(k, M)
        V = (np.broadcast_to(np.maximum.accumulate(x[N:])[:, None], (k, M)).copy() if straight_rows
             else x[N:].reshape(k, M))
        # where U steps back along a ring (a cell folded beside the nose or an ear), give each step at
        # least a fifth of its 3-D length and take the excess from the ring's other steps (each row spans W)
        step = np.diff(np.concatenate([U, U[:, :1] + W], axis=1), axis=1)
        low = step < floor
        if np.any(low):
            lifted = np.where(low, floor, step)
            spare = np.where(low, 0.0, step - floor)
            excess = lifted.sum(axis=1, keepdims=True) - W
            lifted -= spare * (excess / np.maximum(spare.sum(axis=1, keepdims=True), 1e-12))
            U = U[:, :1] + np.concatenate([np.zeros((k, 1)), np.cumsum(lifted, axis=1)[:, :-1]], axis=1)
        return U, V

    def folded(U, V):
        """Cells with a corner whose UV triangle (the corner and its two cell neighbours) is under
        ``UV_FOLD_MARGIN`` of the cell's 3-D area: folded or not convex, so a finer mesh inside the cell
        (bilinear in it) could fold; shape (k - 1, M)."""
        w = U.ravel() + 1j * V.ravel()
        a, b, c, d = w[o], w[pv] + wrap, w[pvu] + wrap, w[pu]                 # counter-clockwise
        corner = np.min([((b - a).conjugate() * (d - a)).imag, ((c - b).conjugate() * (a - b)).imag,
                         ((d - c).conjugate() * (b - c)).imag, ((a - d).conjugate() * (c - d)).imag], axis=0)
        return (corner <= UV_FOLD_MARGIN * area3).reshape(k - 1, M)

    # Straight rows (one V per ring) cannot fold once U increases along each ring; free rows keep the
    # angles better (CThead: angle p95 10 deg against 13.5) but least squares may fold a few cells (GE's
    # lowest rings). The map is the free one, blended back to the straight one around any fold.
    Us, Vs = solve(True)
    Uf, Vf = solve(False)
    keep = np.ones((k, M))
    ever = np.zeros((k, M), bool)
    for _ in range(6):
        U, V = Us + keep * (Uf - Us), Vs + keep * (Vf - Vs)
        bad = folded(U, V)
        if not bad.any():
            break
        near = np.zeros((k, M), bool)
        near[:-1] |= bad
        near[1:] |= bad
        for _ in range(UV_FOLD_GROW):                                         # and a few samples around
            near = near | np.roll(near, 1, axis=1) | np.roll(near, -1, axis=1)
            near[1:] |= near[:-1].copy()
            near[:-1] |= near[1:].copy()
        keep = np.where(near, 0.5 * keep, keep)
        ever |= near
        # a gentle rim: a step in keep folds the cells at its edge (the fold walked outward, and after
        # six halvings the whole map fell back to straight rows)
        ext = np.concatenate([keep[:1], keep, keep[-1:]])
        keep = np.minimum(keep, (ext[:-2] + ext[1:-1] + ext[2:] + np.roll(keep, 1, axis=1)
                                 + np.roll(keep, -1, axis=1)) / 5.0)
    else:
        # not mended by halving: straight rows on every cell flagged so far (and around), else everywhere
        keep = np.where(ever, 0.0, keep)
        U, V = Us + keep * (Uf - Us), Vs + keep * (Vf - Vs)
        if folded(U, V).any():
            U, V = Us, Vs
    return U, V, W


#: A cell of :func:`uv_tube_map` with a corner whose UV triangle is under this share of the cell's 3-D
#: area counts as folded (not convex: a finer mesh inside it could fold; 0.1 also straightens good rows).
UV_FOLD_MARGIN = 0.02

#: Samples around a flagged cell that :func:`uv_tube_map` blends toward straight rows (then a one-sample
#: taper). Four (before) took the angle-keeping map off ~4 % of CThead's samples (angle p95 10.5 deg at
#: the defaults); one takes it off ~1.7 % (9.8 deg).
UV_FOLD_GROW = 1

#: Rows of :func:`uv_tube_map` between consecutive curves (a cubic spline through the curves along u)
#: and the curves' samples it uses around the ring: cells close to square, as the conformal term needs.
UV_MAP_SUBROWS = 2
UV_MAP_SAMPLES = 128


def uv_map_grid(curves: np.ndarray, curve_u: np.ndarray, subrows: int = UV_MAP_SUBROWS,
                samples: int = UV_MAP_SAMPLES, v_density: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The grid :func:`uv_tube_map` is solved on: the curves (every ``M // samples``-th sample; with
    ``v_density``, :func:`column_density`, ``samples`` points at :func:`column_v` from their harmonics, so
    the map is as fine along the ring where the surface's columns crowd) and ``subrows - 1`` rows between
    each pair from a natural cubic spline through them along u (its own matrix,
    :func:`.pde_spline.natural_spline_matrix`: scipy's CubicSpline gave the same rows to ~1e-13 mm, and
    importing ``scipy.interpolate`` cost a first surface ~0.2 s CPU)."""
    c = np.asarray(curves, float)
    if v_density is None:
        c = c[:, ::max(1, c.shape[1] // samples)]
    else:
        M = c.shape[1]
        spec = np.fft.rfft(c, axis=1) / M                                   # (n, H, 3)
        h = np.arange(spec.shape[1])
        weight = np.where((h == 0) | (2 * h == M), 1.0, 2.0)
        phase = np.exp(1j * np.outer(column_v(v_density, samples), h)) * weight     # (samples, H)
        c = np.einsum("sh,nhc->nsc", phase, spec).real
    cu = np.asarray(curve_u, float)
    if len(cu) < 3 or subrows <= 1:
        return c, cu
    t = np.linspace(0.0, 1.0, subrows + 1)[:-1]
    u = np.concatenate([cu[:-1, None] + t[None] * np.diff(cu)[:, None], cu[-1:, None]], axis=None)
    return np.tensordot(natural_spline_matrix(cu, u), c, axes=(1, 0)), u
