"""Every difference between the supported Blender versions (4.2 LTS .. 5.3), in one place.

Tested with bpy from PyPI 4.2.23, 4.5.15, 5.0.1 (Python 3.11, numpy 1.26) and 5.3.0
(Python 3.13, numpy 2.5) by ``.ci/run``. The differences that matter to PDE Head:

- ``bpy.utils.expose_bundled_modules()`` (puts Blender's bundled ``openvdb`` on
  ``sys.path``) exists from Blender 4.4; before, the bindings (where there are any) are
  importable directly.
- The OpenVDB Python bindings are ``openvdb`` from 4.4 and ``pyopenvdb`` before (the
  Blender 4.2/4.3 applications are reported to bundle ``pyopenvdb``); the 4.2 ``bpy``
  module from PyPI has neither. Without bindings, .vdb files are written by our own
  :mod:`.volume.vdb_writer` (dense float grids), which every Blender reads.
- The extension's wheels unpack into ``extensions/.local/lib/python3.X/site-packages``
  with the Python of the running Blender.
- Mesh data: the ``.corner_vert`` attribute (4.0), ``sharp_face`` and ``Mesh.shade_smooth`` (4.1);
  Cycles' ``volume_biased`` (5.0); faces' material slots through the ``material_index`` attribute,
  ~400x faster than ``polygons.foreach_set`` (every supported version has it). The functions at the end
  of this module.
"""
from __future__ import annotations

import atexit
import functools
from types import ModuleType

import bpy
import numpy as np


def expose_bundled_modules() -> bool:
    """Put Blender's bundled extra modules (``openvdb``) on ``sys.path`` where Blender can (4.4+).

    Returns False on Blenders without ``bpy.utils.expose_bundled_modules`` (4.2, 4.3).
    """
    expose = getattr(bpy.utils, "expose_bundled_modules", None)
    if expose is None:
        return False
    expose()
    return True


@functools.cache
def openvdb_module() -> ModuleType | None:
    """Blender's OpenVDB Python bindings (``openvdb`` or, before 4.4, ``pyopenvdb``), or None if it has none
    (looked up once)."""
    expose_bundled_modules()
    for name in ("openvdb", "pyopenvdb"):
        try:
            return __import__(name)
        except ImportError:
            continue
    return None


def unregister_at_exit(unregister) -> None:
    """Call ``unregister`` when the Python process exits (for the ``bpy`` module, not the Blender app).

    With add-on classes still registered at interpreter exit, the bpy 4.2 module crashes
    (SIGSEGV) and the 4.5 module hangs; Blender itself unregisters add-ons on quit, but a
    script that imports ``bpy`` and registers PDE Head (the headless CLI, the tests) must.
    """
    def _unregister():
        try:
            unregister()
        except Exception:  # noqa: BLE001 (already unregistered, or Blender half torn down: nothing to do)
            pass

    atexit.register(_unregister)


def blend_relative_path_options() -> set:
    """``options`` of a file-path StringProperty that may be relative to the .blend: the flag
    ``PATH_SUPPORTS_BLEND_RELATIVE`` exists from Blender 4.5 (before, every path property was)."""
    return {'PATH_SUPPORTS_BLEND_RELATIVE'} if bpy.app.version >= (4, 5, 0) else set()


def node_tree(material_or_world):
    """The shader node tree of a material or world, turning nodes on first where needed.

    A new material or world has no node tree before Blender 5.0 (``use_nodes`` False); from
    5.0 it always has one and ``use_nodes`` is deprecated, so it is only set when needed.
    """
    if material_or_world.node_tree is None:
        material_or_world.use_nodes = True
    return material_or_world.node_tree


def animation_fcurves(id_) -> list:
    """The F-Curves of an ID's action (keyframes), on every Blender: ``action.fcurves`` until 4.3, the
    slotted action's channelbag from 4.4 (``action.fcurves`` is gone in 5.0)."""
    anim = getattr(id_, "animation_data", None)
    action = getattr(anim, "action", None)
    if action is None:
        return []
    slot = getattr(anim, "action_slot", None)
    if slot is not None and hasattr(action, "layers"):
        out = []
        for layer in action.layers:
            for strip in layer.strips:
                bag = strip.channelbag(slot)
                if bag is not None:
                    out.extend(bag.fcurves)
        return out
    return list(action.fcurves)


def registered_id_properties(id_):
    """The dict-like storage of an ID's registered (``bpy.props``) properties, readable while no such
    property is registered (to migrate old files): the ID itself until 4.5, its system properties from
    5.0 (``ID.bl_system_properties_get()``; ``id[...]`` there only sees the user's custom properties)."""
    getter = getattr(id_, "bl_system_properties_get", None)
    if getter is None:
        return id_
    return getter() or {}


def set_corner_vertices(mesh, corner_verts) -> None:
    """A new mesh's corner -> vertex indices in bulk: the ``.corner_vert`` attribute from Blender 4.0 (much
    faster), ``loops.vertex_index`` where it does not exist."""
    corner_vert = mesh.attributes.get(".corner_vert")
    if corner_vert is not None:
        corner_vert.data.foreach_set("value", corner_verts)
    else:
        mesh.loops.foreach_set("vertex_index", corner_verts)


def set_sharp_faces(mesh, sharp) -> None:
    """Flat shading per face: the ``sharp_face`` attribute from Blender 4.1 (``Mesh.shade_smooth`` exists),
    ``polygons.use_smooth`` before."""
    if hasattr(mesh, "shade_smooth"):
        attr = mesh.attributes.get("sharp_face") or mesh.attributes.new("sharp_face", "BOOLEAN", "FACE")
        attr.data.foreach_set("value", sharp)
    else:
        mesh.polygons.foreach_set("use_smooth", ~sharp)


def set_material_indices(mesh, index) -> None:
    """Each face's material slot, through the ``material_index`` face attribute (Blender 3.4+): ~0.02 ms
    for 29,000 faces, where ``polygons.foreach_set("material_index")`` takes 7-8 ms (measured in bpy 4.2
    and 5.0); an unchanged index is not rewritten (a live change of the solid's shape keeps its faces)."""
    index = np.ascontiguousarray(index, np.int32)
    attr = mesh.attributes.get("material_index")
    if attr is not None and (attr.data_type != "INT" or attr.domain != "FACE"):
        mesh.polygons.foreach_set("material_index", index)
        return
    if attr is None:
        if not index.any():
            return                                       # no attribute reads as slot 0 everywhere
        attr = mesh.attributes.new("material_index", "INT", "FACE")
    else:
        current = np.empty(len(index), np.int32)
        attr.data.foreach_get("value", current)
        if np.array_equal(current, index):
            return
    attr.data.foreach_set("value", index)


def cycles_volume_biased(cycles_settings):
    """Cycles' biased volume ray marcher setting (``volume_biased``, Blender 5.0+), or None before."""
    return getattr(cycles_settings, "volume_biased", None)


def shade_smooth(mesh) -> None:
    """Smooth shading of every face: ``Mesh.shade_smooth()`` from Blender 4.1, ``polygons.use_smooth`` before."""
    if hasattr(mesh, "shade_smooth"):
        mesh.shade_smooth()
    else:
        mesh.polygons.foreach_set("use_smooth", np.ones(len(mesh.polygons), bool))
