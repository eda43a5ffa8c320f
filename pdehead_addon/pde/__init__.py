"""Steps 4-5: the Bloor-Wilson PDE patches (eq. 1-13), the C2 spline through them, the surface mesh and
the solid with its w-field and eq. 24 opacity.

Modules:

- :mod:`.head_files`       A PDE head from a boundary file: the stored curves solved with the stored settings
- :mod:`.pde_basis`        The per-harmonic function space of the Bloor-Wilson PDE (paper eq. 1, 7-10) and its numerics
- :mod:`.pde_head`         The solved PDE head (:class:`PDEHead`): X(u, v, w) evaluated as points, grids, meshes and UVs
- :mod:`.pde_smoothing`    The smoothing parameter a of the paper's PDE patches (eq. 1): how large it may be, per patch
- :mod:`.pde_solid`        Step 5: the PDE solid (paper eq. 23), its w-field on a voxel grid and eq. 24 opacity
- :mod:`.pde_spline`       A C2 Bloor-Wilson surface through every boundary curve (eq. 1, 7-12 with derivative
  conditions)
- :mod:`.pde_surface`      Step 4: the Bloor-Wilson PDE surface (paper eq. 1-13), t patches along u: solving it
- :mod:`.solid_ct_table`   The CT in the solid's parameter space (u, v, w): one table per study for live cut-aways
  (section 4.3.1)
- :mod:`.surface_columns`  Where the v columns of the head's tube sit: closer in v where an outline runs
  radially
- :mod:`.surface_mesh`     Tube meshes of a sampled surface grid: quads stitched along the v seam, caps, UVs, signed
  volume
- :mod:`.surface_uv_map`   The UV map of the head's tube: a least-squares map of the boundary curves, and the UV islands
"""
