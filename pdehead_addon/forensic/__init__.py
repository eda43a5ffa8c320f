"""The forensic toolkit: the skull as a second surface, skin-skull tissue depth, landmarks (manual and
automatic), the depth tables and the face approximated from the skull.

Modules:

- :mod:`.auto_landmarks`      Automatic craniometric landmarks on the bone, each by a written rule, with a confidence flag
- ``data/``               data files: t_table_2023.csv
- :mod:`.depth_on_ct`         Landmark tissue depths measured on the CT's intensities: the bone and skin points at the level crossings of the
- :mod:`.depth_table`         Soft-tissue depth tables: the shipped default (T-Table 2023), CSV reading, and ``landmarks.csv``
- :mod:`.face_features`       Face from the skull (issue 23): what a tissue-depth field cannot make, from published prediction rules
- :mod:`.face_from_skull`     Face from the skull (issue 23): a closed PDE face solved through the tissue-depth pegs
- :mod:`.face_live`           The live face (issue 23, point 2): a dragged peg's fast path, and a prepared face model kept in a file
- :mod:`.landmark_bilateral`  Bilateral landmarks in the landmark frame, each side by the same rule: the orbit margins (supraorbital,
- :mod:`.landmark_frame`      The landmark frame: the bone mask resampled on a grid of a rigid frame, its depth images (views) and the
- :mod:`.landmark_midline`    Mid-sagittal landmarks on the landmark frame's profile: vertex, opisthocranion, the nasal profile (glabella,
- :mod:`.landmark_openings`   Openings of the bone in the landmark frame's depth images -- the orbits, the nasal aperture, the external
- :mod:`.landmarks`           Craniometric landmarks on the skull, depth-table markers, Frankfurt horizontal and the mid-sagittal mirror
- :mod:`.skull`               The skull from the same CT: bone segmentation, the skull envelope for the PDE path, a bone mesh
- :mod:`.tissue_depth`        Soft-tissue depth between the skin and the skull, per skin vertex (forensic facial reconstruction)
"""
