"""The per-harmonic function space of the Bloor-Wilson PDE (paper eq. 1, 7-10) and its numerics.

Separation of variables turns eq. 1 into one ODE per harmonic h,
``(d^2/ds^2 - k^2)^2 A_h(s) = 0`` with ``k = a h`` (times the span's length in u
when s is a span's local parameter). Its solutions are spanned by
``{e^{ks}, s e^{ks}, e^{-ks}, s e^{-ks}}`` (eq. 9-10; a cubic for k = 0, eq. 8).

For small k that basis degenerates (``e^{ks}`` and ``e^{-ks}`` both tend to 1), so
a basis tending to the cubic monomials in ``c = s - 1/2`` is used below
``K_SWITCH`` (``cosh x``, ``c sinhc x``, ``c^2 sinhc x``, ``c^3 psi(x)`` with
``x = k c``), the rescaled exponentials ``e^{k(s-1)}, s e^{k(s-1)}, e^{-ks},
s e^{-ks}`` (all <= 1 on [0, 1]) above it. :func:`basis_derivatives` gives the
first and second derivatives in the same two regimes (closed forms, no
cancellation), which the C2 spline of :mod:`.pde_spline` needs.
"""
from __future__ import annotations

import numpy as np

#: Below this exponent the cubic-limit basis is used, above it the rescaled exponentials.
K_SWITCH = 2.5

# Taylor coefficients of psi in x^2: 6m/(2m+1)! for m = 1..10 (Horner, highest first)
_PSI_SERIES = np.array([6.0 * m / np.prod(np.arange(1.0, 2 * m + 2)) for m in range(10, 0, -1)])


def _psi(x: np.ndarray) -> np.ndarray:
    """``3 (cosh x - sinh x / x) / x^2``, -> 1 as x -> 0 (series where cancellation would bite)."""
    x = np.asarray(x, dtype=np.float64)
    x2 = x * x
    series = np.zeros_like(x)
    for c in _PSI_SERIES:
        series = series * x2 + c
    small = np.abs(x) < 0.5
    if np.all(small):
        return series
    safe = np.where(small, 1.0, x)
    direct = 3.0 * (np.cosh(safe) - np.sinh(safe) / safe) / (safe * safe)
    return np.where(small, series, direct)


def _sinhc(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    small = np.abs(x) < 1e-3
    safe = np.where(small, 1.0, x)
    x2 = x * x
    return np.where(small, 1.0 + x2 / 6.0 + x2 * x2 / 120.0, np.sinh(safe) / safe)


def basis(k: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The 4 basis functions of ``(d^2/ds^2 - k^2)^2 f = 0`` at local s, shape ``broadcast(k, s) + (4,)``.

    ``k <= K_SWITCH``: ``cosh x, c sinhc x, c^2 sinhc x, c^3 psi(x)`` with ``c = s - 1/2``,
    ``x = k c`` (tends to the cubic monomials in c as k -> 0). Otherwise the rescaled
    exponentials ``e^{k(s-1)}, s e^{k(s-1)}, e^{-ks}, s e^{-ks}``.
    """
    k, s = np.broadcast_arrays(np.asarray(k, dtype=np.float64), np.asarray(s, dtype=np.float64))
    out = np.empty(k.shape + (4,))
    low = k <= K_SWITCH
    if np.any(low):
        _basis_low(k[low], s[low], out_view := np.empty(k[low].shape + (4,)))
        out[low] = out_view
    if not np.all(low):
        _basis_high(k[~low], s[~low], out_view := np.empty(k[~low].shape + (4,)))
        out[~low] = out_view
    return out


def _basis_low(k: np.ndarray, s: np.ndarray, out: np.ndarray) -> None:
    """Cubic-limit basis into ``out[..., 4]`` (k, s already broadcast)."""
    c = s - 0.5
    x = k * c
    sc = _sinhc(x)
    out[..., 0] = np.cosh(x)
    out[..., 1] = c * sc
    out[..., 2] = c * out[..., 1]
    out[..., 3] = c * c * c * _psi(x)


def _basis_high(k: np.ndarray, s: np.ndarray, out: np.ndarray) -> None:
    """Rescaled exponential basis into ``out[..., 4]`` (k, s already broadcast)."""
    out[..., 0] = np.exp(k * (s - 1.0))
    out[..., 1] = s * out[..., 0]
    out[..., 2] = np.exp(-k * s)
    out[..., 3] = s * out[..., 2]


def basis_grid(k: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Basis for every (s, k) pair: shape ``(len(s), len(k), 4)``; k split by regime, not per element."""
    k = np.asarray(k, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    out = np.empty((s.size, k.size, 4))
    low = k <= K_SWITCH
    n_low = int(low.sum())
    if np.all(low[:n_low]) and not np.any(low[n_low:]):       # usual case: k increasing with h
        kk, ss = np.broadcast_arrays(k[None, :n_low], s[:, None])
        _basis_low(kk, ss, out[:, :n_low])
        if n_low < k.size:
            kk, ss = np.broadcast_arrays(k[None, n_low:], s[:, None])
            _basis_high(kk, ss, out[:, n_low:])
        return out
    return basis(k[None, :], s[:, None])



def curve_harmonics(curves: np.ndarray) -> tuple[np.ndarray, bool]:
    """Weighted complex harmonics of each curve: X(v) = Re sum_h C_h e^{i h v}; shape (n, H, 3).

    Curves lying in planes z = const get exactly zero z harmonics above 0, so that
    ``z(u, v, w) = A0_z(u)`` holds exactly.
    """
    n, M, _ = curves.shape
    spec = np.fft.rfft(curves, axis=1) / M
    spec[:, 1:] *= 2.0
    if M % 2 == 0:
        spec[:, -1] *= 0.5                                                  # Nyquist counted once
    planar = bool(np.all(np.ptp(curves[..., 2], axis=1) == 0))
    if planar:
        spec[:, 1:, 2] = 0.0
        spec[:, 0, 2] = curves[:, 0, 2]
    spec[:, 0] = spec[:, 0].real
    return spec, planar


def inverse_4x4(G: np.ndarray) -> np.ndarray:
    """Inverses of a batch of 4x4 matrices (..., 4, 4): closed-form cofactor expansion plus one
    step of iterative refinement, vectorised over the batch (LAPACK's per-call overhead
    dominates for 4x4 systems). The systems here have condition numbers below ~1e3."""
    a = np.moveaxis(G, (-2, -1), (0, 1))                                  # a[i, j] has the batch shape
    s0 = a[0, 0] * a[1, 1] - a[1, 0] * a[0, 1]
    s1 = a[0, 0] * a[1, 2] - a[1, 0] * a[0, 2]
    s2 = a[0, 0] * a[1, 3] - a[1, 0] * a[0, 3]
    s3 = a[0, 1] * a[1, 2] - a[1, 1] * a[0, 2]
    s4 = a[0, 1] * a[1, 3] - a[1, 1] * a[0, 3]
    s5 = a[0, 2] * a[1, 3] - a[1, 2] * a[0, 3]
    c5 = a[2, 2] * a[3, 3] - a[3, 2] * a[2, 3]
    c4 = a[2, 1] * a[3, 3] - a[3, 1] * a[2, 3]
    c3 = a[2, 1] * a[3, 2] - a[3, 1] * a[2, 2]
    c2 = a[2, 0] * a[3, 3] - a[3, 0] * a[2, 3]
    c1 = a[2, 0] * a[3, 2] - a[3, 0] * a[2, 2]
    c0 = a[2, 0] * a[3, 1] - a[3, 0] * a[2, 1]
    with np.errstate(all="ignore"):
        inv_det = 1.0 / (s0 * c5 - s1 * c4 + s2 * c3 + s3 * c2 - s4 * c1 + s5 * c0)
    rows = [
        [a[1, 1] * c5 - a[1, 2] * c4 + a[1, 3] * c3, -a[0, 1] * c5 + a[0, 2] * c4 - a[0, 3] * c3,
         a[3, 1] * s5 - a[3, 2] * s4 + a[3, 3] * s3, -a[2, 1] * s5 + a[2, 2] * s4 - a[2, 3] * s3],
        [-a[1, 0] * c5 + a[1, 2] * c2 - a[1, 3] * c1, a[0, 0] * c5 - a[0, 2] * c2 + a[0, 3] * c1,
         -a[3, 0] * s5 + a[3, 2] * s2 - a[3, 3] * s1, a[2, 0] * s5 - a[2, 2] * s2 + a[2, 3] * s1],
        [a[1, 0] * c4 - a[1, 1] * c2 + a[1, 3] * c0, -a[0, 0] * c4 + a[0, 1] * c2 - a[0, 3] * c0,
         a[3, 0] * s4 - a[3, 1] * s2 + a[3, 3] * s0, -a[2, 0] * s4 + a[2, 1] * s2 - a[2, 3] * s0],
        [-a[1, 0] * c3 + a[1, 1] * c1 - a[1, 2] * c0, a[0, 0] * c3 - a[0, 1] * c1 + a[0, 2] * c0,
         -a[3, 0] * s3 + a[3, 1] * s1 - a[3, 2] * s0, a[2, 0] * s3 - a[2, 1] * s1 + a[2, 2] * s0],
    ]
    with np.errstate(all="ignore"):
        X = np.moveaxis(np.array(rows) * inv_det, (0, 1), (-2, -1))
        X = X + X @ (np.eye(4) - G @ X)                                      # one refinement step
    return X


def basis_derivatives(k: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Values, first and second s-derivatives of :func:`basis`: shape ``broadcast(k, s) + (3, 4)``.

    Closed forms in both regimes (``c = s - 1/2``, ``x = k c``): below ``K_SWITCH``
    ``(cosh x)' = k^2 c sinhc x``, ``(c sinhc x)' = cosh x``,
    ``(c^2 sinhc x)' = c (sinhc x + cosh x)``, ``(c^3 psi x)' = 3 c^2 sinhc x`` and
    ``'' = k^2 cosh x, k^2 c sinhc x, 2 cosh x + k^2 c^2 sinhc x, 3 c (sinhc x + cosh x)``;
    above it the derivatives of the rescaled exponentials.
    """
    k, s = np.broadcast_arrays(np.asarray(k, dtype=np.float64), np.asarray(s, dtype=np.float64))
    out = np.empty(k.shape + (3, 4))
    low = k <= K_SWITCH
    if np.any(low):
        kl = k[low]
        c = s[low] - 0.5
        x = kl * c
        sc, ch = _sinhc(x), np.cosh(x)
        k2 = kl * kl
        o = np.empty(kl.shape + (3, 4))
        o[..., 0, 0], o[..., 0, 1], o[..., 0, 2], o[..., 0, 3] = ch, c * sc, c * c * sc, c ** 3 * _psi(x)
        o[..., 1, 0], o[..., 1, 1], o[..., 1, 2], o[..., 1, 3] = k2 * c * sc, ch, c * (sc + ch), 3 * c * c * sc
        o[..., 2, 0], o[..., 2, 1] = k2 * ch, k2 * c * sc
        o[..., 2, 2], o[..., 2, 3] = 2 * ch + k2 * c * c * sc, 3 * c * (sc + ch)
        out[low] = o
    if not np.all(low):
        kh, sh = k[~low], s[~low]
        e0, e2 = np.exp(kh * (sh - 1.0)), np.exp(-kh * sh)
        o = np.empty(kh.shape + (3, 4))
        o[..., 0, 0], o[..., 0, 1], o[..., 0, 2], o[..., 0, 3] = e0, sh * e0, e2, sh * e2
        o[..., 1, 0], o[..., 1, 1] = kh * e0, e0 * (1 + kh * sh)
        o[..., 1, 2], o[..., 1, 3] = -kh * e2, e2 * (1 - kh * sh)
        o[..., 2, 0], o[..., 2, 1] = kh * kh * e0, e0 * (2 * kh + kh * kh * sh)
        o[..., 2, 2], o[..., 2, 3] = kh * kh * e2, e2 * (kh * kh * sh - 2 * kh)
        out[~low] = o
    return out


#: OpenBLAS runs a matrix product on several threads when m * n * k reaches 4 * 65536; for the
#: small products of a solve the threads cost far more than the arithmetic (4 ms against 0.14 ms
#: for a 124 x 32 by 32 x 774 product on 2 busy cores), so such products are split below it.
_BLAS_THREAD_THRESHOLD = 4 * 65536


def small_matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for 2-D real arrays, in column blocks that each stay single-threaded in BLAS."""
    m, k = a.shape
    n = b.shape[1]
    block = max(1, (_BLAS_THREAD_THRESHOLD - 1) // max(1, m * k))
    if n <= block:
        return a @ b
    out = np.empty((m, n), dtype=np.result_type(a, b))
    for start in range(0, n, block):
        np.matmul(a, b[:, start:start + block], out=out[:, start:start + block])
    return out
