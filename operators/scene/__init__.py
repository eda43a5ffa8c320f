"""Blender objects and the scene: the study's curves, surface and solid (``objects``), the cutter (``cutter``),
camera, light and framing (``scene``), renders (``render``), the surface's CT detail (``detail_map``).

Registration is in :mod:`operators` (one list of classes)."""
