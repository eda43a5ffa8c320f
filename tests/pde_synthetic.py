"""Synthetic boundary curves for the PDE tests: circles, cones and head-like slices with a nose."""
from __future__ import annotations

import numpy as np

from pdehead_addon.core.boundary_set import BoundarySet, knots_from_heights


def resample_arc_length(xy: np.ndarray, samples: int) -> np.ndarray:
    """Closed polyline (n, 2), counter-clockwise, started at its +y midline point -> M arc-length samples."""
    closed = np.vstack([xy, xy[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    target = s[-1] * np.arange(samples) / samples
    return np.stack([np.interp(target, s, closed[:, 0]), np.interp(target, s, closed[:, 1])], axis=1)


def polar_curve(radius_fn, samples: int, centre=(0.0, 0.0), dense: int = 4096) -> np.ndarray:
    """Star-shaped closed curve r(theta), counter-clockwise in (x, y), sample 0 on the +y ray, arc-length."""
    theta = np.pi / 2 + 2 * np.pi * np.arange(dense) / dense                 # start at +y (posterior)
    r = radius_fn(theta)
    xy = np.stack([centre[0] + r * np.cos(theta), centre[1] + r * np.sin(theta)], axis=1)
    return resample_arc_length(xy, samples)


def head_radius(z: float):
    """A head-like slice at height z in [0, 1]: an ellipse growing then shrinking, a nose at the front (-y)."""
    a = 60 + 25 * np.sin(np.pi * (0.15 + 0.8 * z))                          # left-right semi-axis
    b = 75 + 30 * np.sin(np.pi * (0.15 + 0.8 * z))                          # front-back semi-axis
    nose = 18 * np.exp(-((z - 0.45) / 0.08) ** 2)                          # nose only around mid height

    def r(theta):
        base = a * b / np.sqrt((b * np.cos(theta)) ** 2 + (a * np.sin(theta)) ** 2)
        front = np.exp(-((np.mod(theta - 1.5 * np.pi + np.pi, 2 * np.pi) - np.pi) / 0.18) ** 2)  # theta=-pi/2: -y
        return base + nose * front
    return r


def head_bset(patches: int = 10, samples: int = 256, height: float = 220.0) -> BoundarySet:
    """3t+1 head-like axial curves from z = 0 to ``height`` mm, uniform in arc length."""
    n = 3 * patches + 1
    z = np.linspace(0.0, height, n)
    curves = np.empty((n, samples, 3))
    for j, zj in enumerate(z):
        curves[j, :, :2] = polar_curve(head_radius(zj / height), samples, centre=(128.0, 120.0 + 0.05 * zj))
        curves[j, :, 2] = zj
    return BoundarySet(curves, np.arange(n), z, knots_from_heights(z), {"source": "synthetic head"})


def circles_bset(radii, heights, samples: int = 128, centres=None) -> BoundarySet:
    """Circles (pure harmonic 1 when sampled uniformly in angle = arc length)."""
    radii = np.asarray(radii, float)
    heights = np.asarray(heights, float)
    centres = np.zeros((len(radii), 2)) if centres is None else np.asarray(centres, float)
    v = 2 * np.pi * np.arange(samples) / samples
    curves = np.empty((len(radii), samples, 3))
    # counter-clockwise from +y: (x, y) = (-sin v, cos v) * r
    curves[..., 0] = centres[:, :1] - radii[:, None] * np.sin(v)
    curves[..., 1] = centres[:, 1:] + radii[:, None] * np.cos(v)
    curves[..., 2] = heights[:, None]
    return BoundarySet(curves, np.full(len(radii), -1), heights, knots_from_heights(heights), {})


def radial_excess(head, nper: int = 24, nv: int = 256) -> np.ndarray:
    """Per curve interval: max over (u, v) of |X - A0| minus the larger of the two bracketing curves'
    |X - A0| at the same v (mm). Positive = bulge beyond the bracketing curves."""
    b = head.bset
    v_count = nv
    out = []
    for j in range(len(b.u_knots) - 1):
        u = np.linspace(b.u_knots[j], b.u_knots[j + 1], nper)
        pts = head.surface_points(u, v_count)
        r = np.linalg.norm(pts - head.spine(u)[:, None, :], axis=-1)
        out.append(float((r - np.maximum(r[0], r[-1])[None, :]).max()))
    return np.array(out)
