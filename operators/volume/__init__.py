"""The volume and the CT on the solid: the Volume object (``volume``), its .vdb files and grids (``vdb_files``,
``vdb_grids``, ``vdb_writer``), the eq. 24 material (``material``) and the solid's CT texture (``ct_texture``).

Registration is in :mod:`operators` (one list of classes)."""
