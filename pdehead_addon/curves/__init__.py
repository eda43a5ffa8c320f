"""Step 3: the eq. 22 boundary curves from the mask (3t+1 of them), the head envelope, their
parameterisation and the automatic choice of the slices.

Modules:

- :mod:`.auto_selection`    The automatic slice selection: the curves whose PDE surface best follows every slice
                            (paper sections 4.1 and 6)
- :mod:`.boundaries`        Step 3: per-slice boundary curves (paper eq. 22) and the choice of 3t+1 of them
                            (section 4.1)
- :mod:`.boundary_options`  The options of the boundary-curve step: every parameter, its default and the checks
                            that need no mask
- :mod:`.curve_sampling`    Boundary curves from outlines: star hulls, the angular samples around a spine,
                            arc-length samples
- :mod:`.envelope`          The head's smooth outer envelope in 3-D: the field whose per-slice 0.5 levels are
                            the PDE curves
- :mod:`.parameterisation`  Where the M samples of each boundary curve sit: low-pass along the curve
- :mod:`.slice_outlines`    Per-slice outlines: the eq. 22 boundary ring and its sub-pixel outer contour
                            (paper section 3)
- :mod:`.slice_selection`   Slice selection: which slices give the boundary curves, the named strategies
"""
