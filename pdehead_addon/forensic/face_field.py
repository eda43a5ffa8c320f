"""The tissue-depth field of the face from the skull: the radial offset over the bone's closed profile that passes
through every peg's tip (:class:`DepthField`, a base of :class:`.face_from_skull.FaceModel`).

Over the whole head a wide normalised Gaussian average of the pegs' offsets (Shepard's method: a partition of unity
of radius ``spread_mm``) with the rule depth where no peg stands (:data:`RULE_DEPTH_MM`), plus a narrow Gaussian
radial-basis correction (lightly regularised, :meth:`DepthField.correction_weights`) that makes the field pass through
every tip, except a peg that disagrees with its neighbours (:meth:`DepthField.site_damping`); kept from overshooting
between the pegs (:meth:`DepthField.limited_field`).

References
----------
.. [1] Shepard D. A two-dimensional interpolation function for irregularly-spaced data. Proc. 23rd ACM National
       Conference, 1968, 517-524.
.. [2] Buhmann MD. Radial Basis Functions: Theory and Implementations. Cambridge University Press, 2003.
.. [3] Rasmussen CE, Williams CKI. Gaussian Processes for Machine Learning. MIT Press, 2006, section 2.2 (eq. 2.25:
       the posterior mean with the observations' noise variance added to the kernel's diagonal).
"""
from __future__ import annotations

import numpy as np

from .face_profile import smooth_max, smooth_min

#: Depth (mm) where no peg stands: the vault and the back of the head. The T-Table 2023 grand means at vertex (5.0 mm)
#: and opisthocranion (6.0 mm) (Hona & Stephan 2024, Int J Legal Med 138(2):519-535, doi:10.1007/s00414-023-03087-x,
#: values as printed in esomjai/Forensic-Craniofacial-Approximation- Validation-Tool, "FSTT/Generating FSTT cylinders in
#: Slicer.md"), rounded to their mean.
RULE_DEPTH_MM = 5.5
#: Weight of the rule depth in the Shepard average (a peg at distance ``spread_mm`` weighs e^-1 = 0.37).
RULE_WEIGHT = 0.04
#: Width of the exact correction's Gaussians, as a fraction of ``spread_mm``.
NARROW_FRACTION = 0.5
#: Regularisation of the exact peg interpolation (relative to the kernel's unit diagonal).
RBF_REGULARISATION = 0.05
#: A peg whose offset disagrees with what its neighbours give there (the wide field without it) by more than
#: :data:`DAMP_FREE_MM` is followed less closely by the exact correction: its regularisation grows by ((disagreement -
#: DAMP_FREE_MM) / DAMP_SCALE_MM)^2 (:meth:`FaceModel.site_damping`; the T-Table's 26 mm supra-M2 and 22 mm sub-M2
#: pegs beside 8-13 mm ones made the jaw's border lumpy). Fixed at the table's means from the skull and the table
#: alone; the mid-sagittal pegs (within :data:`DAMP_MIDLINE_DEG` of straight ahead) stay exact: the nose and the lips
#: stand on them. It scores better on CThead, GE unchanged (docs/benchmarks.md).
DAMP_FREE_MM = 4.0
DAMP_SCALE_MM = 5.0
DAMP_MIDLINE_DEG = 10.0
#: A peg the practitioner holds (moved, or its depth set: the Blender layer holds it; headless, ``held=`` of
#: :meth:`FaceModel.solve`) is never damped: its regularisation is this, the field passes through its tip to a few
#: hundredths of a mm (the hand overrides the automatic rule; the shape rules and the surface between the rows remain).
HELD_REGULARISATION = 1e-3
#: No overshoot between the pegs (:meth:`FaceModel.limited_field`): the field stays between the lowest and the highest
#: blend base + k_i (target_i - base) of the wide field with each site's offset (k_i = exp(-(d / R)^4) along the
#: height times the same around, R = LIMIT_RADIUS_FRACTION x ``spread_mm``; a smooth min / max LIMIT_SOFT_MM wide).
#: The Gaussians' exact correction swings beyond two close sites of very different offsets (CThead:
#: subspinale 3.8 and mid-philtrum 14.8 mm, 3.4 mm apart: 19.7 mm above them, 16.6 over the incisors where
#: the pegs are 12-13). At a site the bound is its own offset: the field still passes through every tip.
LIMIT_RADIUS_FRACTION = 1.0
LIMIT_SOFT_MM = 1.0
#: A site's blend weight below which the limiter leaves it out (its term is then below 1e-12 x its offset).
LIMIT_WEIGHT_FLOOR = 1e-12


def site_windows(rows_on: np.ndarray, cols_on: np.ndarray):
    """For each site i (the columns of ``rows_on`` (K, n) and ``cols_on`` (M, n)): ``(i, rows, cols)`` as
    basic slices (views) covering its rows and columns; a run of columns across the seam (column 0) gives
    two windows. Rows and columns of one site are one run each (the weights fall off with distance)."""
    M = len(cols_on)
    for i in range(rows_on.shape[1]):
        r, c = np.flatnonzero(rows_on[:, i]), np.flatnonzero(cols_on[:, i])
        if not r.size or not c.size:
            continue
        rows = slice(r[0], r[-1] + 1)
        if c[-1] - c[0] + 1 == c.size or c.size == M:
            yield i, rows, slice(c[0], c[-1] + 1)
        else:                                            # wraps: [gap end .. M) and [0 .. gap start)
            gap = int(np.flatnonzero(np.diff(c) > 1)[0])
            yield i, rows, slice(c[gap + 1], M)
            yield i, rows, slice(0, c[gap] + 1)


def peg_kernel(a: np.ndarray, b: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian kernel exp(-|a_i - b_j|^2 / sigma^2), (len(a), len(b)), float32-free but allocation-light."""
    d2 = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * (a @ b.T)
    np.maximum(d2, 0.0, out=d2)
    d2 *= -1.0 / (sigma * sigma)
    return np.exp(d2, out=d2)


class DepthField:
    """The tissue-depth field's methods of :class:`.face_from_skull.FaceModel` (they read its ``grid``,
    ``profile``, ``options``, ``peg_names``, ``rule_sites``, ``default_depths`` and its cylinder)."""

    def _offset_field(self, tips: np.ndarray, held=None) -> np.ndarray:
        """(K, M) radial offset over the profile that passes through every tip (and rule site); the pegs
        ``held`` (see :meth:`held_sites`) are never damped."""
        g = self.grid
        z, th, r = g.polar(self.field_sites(tips))
        target = r - g.sample(self.profile, z, th)                    # offset each site needs
        xs = self.cylinder_points(z, th)
        sigma = self.options["spread_mm"]
        # wide Shepard average with the rule depth
        Wg = peg_kernel(self._grid_xyz, xs, sigma)                        # (G, n)
        Ws = peg_kernel(xs, xs, sigma)
        base_g = (Wg @ target + RULE_WEIGHT * RULE_DEPTH_MM) / (Wg.sum(1) + RULE_WEIGHT)
        base_s = (Ws @ target + RULE_WEIGHT * RULE_DEPTH_MM) / (Ws.sum(1) + RULE_WEIGHT)
        # narrow exact correction
        s2 = NARROW_FRACTION * sigma
        w = self.correction_weights(xs, target - base_s, self.held_sites(held))
        corr = peg_kernel(self._grid_xyz, xs, s2) @ w
        shape = self.profile.shape
        return self.limited_field((base_g + corr).reshape(shape), base_g.reshape(shape), xs, target)

    def through_sites(self, radius: np.ndarray, tips: np.ndarray, held=None, slack=None) -> np.ndarray:
        """``radius`` (K, M) put back through the field sites at ``tips`` by the field's own narrow correction
        (:meth:`correction_weights`: damped and held as the field is): what a smoothing of the face took off a tip,
        a bump as wide as the field's, is put back; ``slack`` (per site, :meth:`tip_slack`) regularises each site
        further (a held peg is still followed exactly)."""
        g = self.grid
        z, th, r = g.polar(self.field_sites(tips))
        xs = self.cylinder_points(z, th)
        w = self.correction_weights(xs, r - g.sample(radius, z, th), self.held_sites(held), extra=slack)
        along, around = self.site_distances(xs)
        s2 = (NARROW_FRACTION * float(self.options["spread_mm"])) ** 2
        return radius + (np.exp(-along / s2) * w) @ np.exp(-around / s2).T

    def tip_slack(self, smooth) -> np.ndarray:
        """Per field site, how loosely :meth:`through_sites` puts a smoothed face back through it.

        A Gaussian-process reading of the narrow correction [3]_: each tip an observation of the skin whose noise is
        the T-Table's SD at its landmark, the correction's prior SD the RMS of what ``smooth`` (a function of a radius
        map) took off the pegs' tips at the table's means. Returns (SD_i / RMS)^2, added to each site's
        regularisation; 0 at the rule sites and at a peg without an SD. Where the table is sure (glabella 1.0 mm,
        nasion 1.5) the face keeps to the tip; where it is not (supra M2 7.0 mm, gonion 6.0) it keeps the smoothed
        shape instead of a lump 11 mm wide (CThead: tips 5-7 mm off the smoothed face at the jaw). The mid-sagittal
        pegs too (unlike :meth:`site_damping`, which spares them): their SDs are small (glabella 1.0, menton 2.5 mm),
        and sparing them scored lower (dev runs: CThead 1600 51.2 against 53.0 %, GE 55.4 / 55.0, the phantom
        42.2 / 43.2). Fixed by the skull and the table, computed once."""
        if "_tip_slack" not in self.__dict__:
            shift = self.__dict__.get("_last_limit_shift")            # the pegs' report reads the last solve's
            tips = self.tips_for(self.default_depths)
            radius = smooth(self.profile + self._offset_field(tips))
            self.__dict__["_last_limit_shift"] = shift
            g = self.grid
            z, th, r = g.polar(self.field_sites(tips))
            residual = r - g.sample(radius, z, th)
            sd = np.nan_to_num(np.asarray(self.depth_sd, float), nan=0.0)
            sd = sd[self.in_rows] if self.in_rows is not None else sd
            sd = np.concatenate([sd, np.zeros(len(residual) - len(sd))])               # the rule sites: none
            rms = float(np.sqrt(np.mean(residual[sd > 0] ** 2))) if np.any(sd > 0) else 0.0
            self.__dict__["_tip_slack"] = (sd / rms) ** 2 if rms > 1e-9 else np.zeros_like(sd)
        return self.__dict__["_tip_slack"]

    def site_distances(self, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Squared distances (mm^2) from the grid to the sites ``xs`` on the field's cylinder, separated: along the
        height (K, n: rows x sites) and around (M, n: columns' chords x sites). A Gaussian of their sum is the product
        of a Gaussian of each (one place for :meth:`through_sites` and the live face's field)."""
        g = self.grid
        ring = self.cylinder_points(np.zeros(len(g.theta)), g.theta)[:, :2]
        return (g.z[:, None] - xs[None, :, 2]) ** 2, ((ring[:, None, :] - xs[None, :, :2]) ** 2).sum(-1)

    def limited_field(self, field: np.ndarray, base: np.ndarray, xs: np.ndarray, target: np.ndarray) -> np.ndarray:
        """The field (K, M) kept within the blends of ``base`` with the sites' ``target``
        (:data:`LIMIT_RADIUS_FRACTION`); one place for :meth:`_offset_field` and the live path (sites ``xs`` on the
        model's cylinder)."""
        if LIMIT_RADIUS_FRACTION <= 0 or not len(target):
            return field
        g, R = self.grid, LIMIT_RADIUS_FRACTION * float(self.options["spread_mm"])
        ring = self.cylinder_points(np.zeros(len(g.theta)), g.theta)[:, :2]
        kz = np.exp(-((g.z[:, None] - xs[None, :, 2]) / R) ** 4)                                   # (K, n)
        kt = np.exp(-(((ring[:, None, :] - xs[None, :, :2]) ** 2).sum(-1) / (R * R)) ** 2)       # (M, n)
        target = np.asarray(target, float)
        # max / min over the sites of kz kt (target - base), each site on the rows and columns where its weight
        # exceeds LIMIT_WEIGHT_FLOOR (about 2 R around it: a few % of the grid): the dense (K, M, n) product
        # cost 13 ms of the live face's ~100 ms; elsewhere a site's term is 0 to within 1e-12 x its offset
        hi, lo = np.zeros_like(base), np.zeros_like(base)
        for i, rows, cols in site_windows(kz > LIMIT_WEIGHT_FLOOR, kt > LIMIT_WEIGHT_FLOOR):
            dev = np.multiply.outer(kz[rows, i], kt[cols, i])
            dev *= target[i] - base[rows, cols]
            np.maximum(hi[rows, cols], dev, out=hi[rows, cols])
            np.minimum(lo[rows, cols], dev, out=lo[rows, cols])
        hi += base
        lo += base
        out = smooth_max(smooth_min(field, hi, LIMIT_SOFT_MM), lo, LIMIT_SOFT_MM)
        self._last_limit_shift = out - field        # what the limiter did, for the pegs' report (.face_pegs)
        return out

    def correction_weights(self, xs: np.ndarray, residual: np.ndarray, held: np.ndarray | None = None,
                           extra: np.ndarray | None = None) -> np.ndarray:
        """Weights of the narrow Gaussians of the exact correction at the field sites ``xs`` for the
        ``residual`` (offset minus the wide field at each site), regularised per site
        (:meth:`site_damping`, plus ``extra`` per site; the ``held`` sites (bool) at :data:`HELD_REGULARISATION`).
        One place for :meth:`_offset_field`, :meth:`through_sites` and the live path."""
        Phi = peg_kernel(xs, xs, NARROW_FRACTION * self.options["spread_mm"])
        lam = self.__dict__.get("_damping")
        lam = RBF_REGULARISATION * np.ones(len(xs)) if lam is None or len(lam) != len(xs) else lam
        if extra is not None and len(extra) == len(lam):
            lam = lam + extra
        if held is not None and len(held) == len(lam):
            lam = np.where(held, HELD_REGULARISATION, lam)
        Phi[np.diag_indices_from(Phi)] += lam
        return np.linalg.solve(Phi, residual)

    def site_damping(self) -> np.ndarray:
        """Per field site, the exact correction's regularisation: :data:`RBF_REGULARISATION`, plus
        ((|disagreement| - :data:`DAMP_FREE_MM`) / :data:`DAMP_SCALE_MM`)^2 where a site's offset at the table's
        means disagrees with the wide field of the other sites (leave-one-out Shepard average) by more than
        :data:`DAMP_FREE_MM`; the mid-sagittal pegs are not damped. A robust-interpolation rule (an outlying
        peg pulls the face less than its neighbours agree on), fixed by the skull and the table."""
        return RBF_REGULARISATION + self.site_extra_damping()

    def site_disagreement(self) -> np.ndarray:
        """Per field site (:meth:`field_sites` at the table's means), how far (mm) its offset disagrees with the
        wide field of the other sites (leave-one-out Shepard average, with the rule depth)."""
        return self._disagreement()[0]

    def site_extra_damping(self) -> np.ndarray:
        """Per field site, the regularisation added to :data:`RBF_REGULARISATION` by the damping (0: followed
        exactly): ((disagreement - :data:`DAMP_FREE_MM`) / :data:`DAMP_SCALE_MM`)^2 off the midline."""
        off, midline = self._disagreement()
        excess = np.where(midline, 0.0, np.maximum(off - DAMP_FREE_MM, 0.0))
        return (excess / DAMP_SCALE_MM) ** 2

    def _disagreement(self) -> tuple[np.ndarray, np.ndarray]:
        """(disagreement per field site (mm), whether each site is mid-sagittal): fixed by the skull and the
        table, computed once."""
        if "_site_disagreement" not in self.__dict__:
            g = self.grid
            z, th, r = g.polar(self.field_sites(self.tips_for(self.default_depths)))
            target = r - g.sample(self.profile, z, th)
            xs = self.cylinder_points(z, th)
            W = peg_kernel(xs, xs, self.options["spread_mm"])
            np.fill_diagonal(W, 0.0)
            others = (W @ target + RULE_WEIGHT * RULE_DEPTH_MM) / (W.sum(1) + RULE_WEIGHT)
            midline = np.abs(np.angle(np.exp(1j * (th - np.pi)))) < np.radians(DAMP_MIDLINE_DEG)
            self.__dict__["_site_disagreement"] = (np.abs(target - others), midline)
        return self.__dict__["_site_disagreement"]
