"""The forensic toolkit: the skull as a second surface, skin-skull tissue depth, landmarks (manual and
automatic), the depth tables and the face approximated from the skull.

Modules:

- :mod:`.auto_landmarks`      Automatic craniometric landmarks on the bone, each by a written rule, with a
                              confidence flag
- ``data/``                   data files: t_table_2023.csv
- :mod:`.depth_on_ct`         Landmark tissue depths measured on the CT's intensities, at the bone and skin level
                              crossings along each ray
- :mod:`.depth_table`         Soft-tissue depth tables: the shipped default (T-Table 2023), CSV reading, and
                              ``landmarks.csv``
- :mod:`.face_features`       Face from the skull: what a tissue-depth field cannot make, from published
                              prediction rules
- :mod:`.face_from_skull`     Face from the skull: a closed PDE face solved through the tissue-depth pegs
- :mod:`.face_live`           The live face: a dragged peg's fast path, and a prepared face model kept in a file
- :mod:`.face_pegs`           The pegs of a solved face: how far each tip is from the face, why, and what is
                              implausible
- :mod:`.face_profile`        Face from the skull: the face's grid and the bone's closed outer profile on it
- :mod:`.landmark_bilateral`  Bilateral landmarks in the landmark frame, each side by the same rule (orbit margins,
                              zygion, alare, canines, mandible)
- :mod:`.landmark_frame`      The landmark frame: the bone mask resampled on a rigid frame's grid, its depth images
                              and shared pixel tools
- :mod:`.landmark_midline`    Mid-sagittal landmarks on the frame's profile: vertex, opisthocranion, the nasal
                              profile, the jaws
- :mod:`.landmark_openings`   Openings of the bone in the frame's depth images: orbits, nasal aperture, meatus;
                              orbitale, porion, Frankfurt
- :mod:`.landmarks`           Craniometric landmarks on the skull, depth-table markers, Frankfurt horizontal and
                              the mid-sagittal mirror
- :mod:`.skull`               The skull from the same CT: bone segmentation, the skull envelope for the PDE path, a
                              bone mesh
- :mod:`.skull_parts`         The skull's bone parts: the cranium, the mandible and its rami, and what is not skull
- :mod:`.tissue_depth`        Soft-tissue depth between the skin and the skull, per skin vertex (forensic facial
                              reconstruction)
"""
