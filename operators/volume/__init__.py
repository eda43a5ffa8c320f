"""The volume and the CT on the surfaces: the Volume object (``volume``), its .vdb files and grids (``vdb_files``,
``vdb_grids``, ``vdb_writer``), the eq. 24 material (``material``), the solid's CT texture (``ct_texture``) and the
surface's CT detail (``detail_map``).

Registration is in :mod:`operators` (one list of classes)."""
