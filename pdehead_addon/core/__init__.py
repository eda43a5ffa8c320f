"""The shared types and geometry of every stage: the CT volume and its one grid affine, the mesh and
the one copy of each mesh routine, the boundary-curve set, the errors, provenance and wording.

Modules:

- :mod:`.boundary_set`   The PDE boundary conditions: 3t+1 (or, for the C2 surface, any n >= 4) closed curves with
  their u-knots
- :mod:`.ct_volume`      The CT volume in patient space: the data type every pipeline step shares, and its numeric
  helpers
- :mod:`.curve_alignment` The correspondence of neighbouring boundary curves: equal v on corresponding points
- :mod:`.errors`         Exceptions raised by the PDE Head engine
- :mod:`.mesh`           A plain polygon mesh in patient LPS mm: what the engine hands to the Blender layer
- :mod:`.mesh_geometry`  Triangle-mesh geometry shared by the pipeline, the forensic tools and the measures: one copy
  of each routine
- :mod:`.provenance`     Provenance of forensic outputs: which software, depth table and bone level made a file
- :mod:`.threads`        Work on two threads: the engine's one thread count, slabs of a volume, chunks in order
- :mod:`.wording`        Messages in the language of where they are shown: Python arguments, CLI flags, dialog fields
"""
