"""Blender objects and the scene: the study's curves, surface and solid (``objects``), the cutter (``cutter``),
camera, light and framing (``scene``), renders (``render``), animation (``animation``), coordinates (``coords``).

Registration is in :mod:`operators` (one list of classes)."""
