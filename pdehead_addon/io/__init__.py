"""Step 1 of the paper's pipeline and the files: CT slices in (DICOM, images, raw, NIfTI; checks of the
input), the synthetic phantom head, the compact boundary file (section 5.2), mesh import and export.

Modules:

- :mod:`.ct_import`           Step 1: CT import (DICOM series, numbered 2-D image stacks, headerless raw, NIfTI) into
  a CTVolume
- :mod:`.export`              Watertight STL / OBJ / PLY of the skin and the skull for 3-D printing, in millimetres
- :mod:`.input_checks`        Checks that turn silently wrong inputs into clear errors or warnings (used by import and
  segmentation)
- :mod:`.mesh_input`          A skull given as a mesh (a surface scan: STL / PLY / OBJ in mm) in place of a CT
- :mod:`.phantom`             A deterministic synthetic head CT with exact ground truth (the demo data and quick tests)
- :mod:`.phantom_anatomy`     The analytic head of the synthetic CT (:mod:`.phantom`): its geometry, tissues, labels
  and HU
- :mod:`.phantom_primitives`  Signed-distance building blocks of the synthetic head (:mod:`.phantom`): mm, negative
  inside
- :mod:`.scan_evidence`       Whether the samples are a head scan, read right: byte order, row length, photographs
- :mod:`.storage`             Compact storage of the PDE boundary conditions (paper section 5.2)
"""
