"""The surface's CT detail map in Blender: a 16-bit height image in the surface's UVs, shaded as bump.

The engine (:func:`pdehead_addon.ct_detail_map`) gives per texel the offset (mm) along the PDE surface's
outward normal from the surface to the CT's skin. Here it becomes the image "PDE Head Detail <surface>"
(non-colour, 0.5 + mm / (2 x range); a 16-bit PNG packed into the .blend, so a saved file reopens with it) and
the surface's own skin material ("PDE Head Skin <surface>": a copy of the shared skin material) reads it
through the UV map ``UVMap`` into a Displacement node (midlevel 0.5, scale = strength x 2 range x 0.001: the
surface's object space is metres, world = LPS mm x 0.001) on the Material Output's Displacement, with the material's
displacement method "Bump only": the shading shows the eyelids, lips and nose wings, the geometry and the
exports stay the smooth PDE surface.

Off by default (``use_detail_map``): Run Pipeline builds it only when it is on, and turning it on never
builds it inside the property's update (that would block the UI for seconds): the Surface panel then
shows *Build CT Detail* (:class:`~.ops.PDEHEAD_OT_build_detail_map`: modal with progress, Esc keeps the old
map; synchronous from scripts). A live change of the PDE moves the surface away from the map's: the map is
then marked out of date and its bump unplugged (not left silently stale) until it is rebuilt (*Rebuild CT
Detail*, or Run Pipeline): rebuilding costs seconds (~2.6 s of CPU at 1024 x 1024 on CThead), far beyond a
slider's 100 ms step. nu, nv and caps do not change the map (the UVs are a function of (u, v)).
"""
from __future__ import annotations

import struct
import zlib

import numpy as np

from . import objects

DETAIL_IMAGE_KEY = "pdehead_detail_image"
DETAIL_MATERIAL_KEY = "pdehead_detail_material"
RANGE_KEY = "pdehead_detail_range_mm"
IMAGE_NODE, UV_NODE, BUMP_NODE = "CT detail", "CT detail UV", "CT detail bump"
#: The surface is in metres (world = LPS mm x 0.001, object scale 1); the map is in mm.
MM_TO_OBJECT = 0.001


def image_name(obj) -> str:
    return f"PDE Head Detail {obj.name}"


def png16(values01: np.ndarray) -> bytes:
    """A 16-bit greyscale PNG of ``values01`` (rows from the bottom, as Blender's pixels), zlib level 6 with
    the Sub filter: the file Blender packs (a float image would be packed as uncompressed OpenEXR, ~12 MB at
    1024 x 1024; this is ~0.7 MB on CThead, to 1e-4 mm)."""
    h, w = values01.shape
    v = np.round(np.clip(values01, 0.0, 1.0) * 65535.0).astype(">u2")[::-1]      # PNG rows run top down
    raw = v.view(np.uint8).reshape(h, 2 * w)
    sub = raw.copy()
    sub[:, 2:] = raw[:, 2:] - raw[:, :-2]                                         # filter 1 (Sub), 2 bytes a pixel
    data = np.concatenate([np.ones((h, 1), np.uint8), sub], axis=1).tobytes()

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(data, 6)) + chunk(b"IEND", b""))


def set_detail_image(obj, height_mm: np.ndarray, range_mm: float):
    """The object's detail image: ``height_mm`` (rows from UV v = 0) stored as ``0.5 + mm / (2 range_mm)`` in a
    16-bit PNG packed into the .blend (Blender reads it back as float); a previous one is replaced."""
    h, w = height_mm.shape
    return _pack_png(obj, png16(np.asarray(height_mm, np.float64) / (2.0 * float(range_mm)) + 0.5), range_mm, (w, h))


def _pack_png(obj, data: bytes, range_mm: float, size):
    """The object's detail image holding the PNG ``data``: the existing one re-packed in place (a cancelled
    Run Pipeline's rollback keeps it, :func:`packed_state`), else a new one."""
    import bpy

    name = image_name(obj)
    image = bpy.data.images.get(name)
    if image is not None and image.get(DETAIL_IMAGE_KEY) == 1 and image.packed_file is not None:
        image.pack(data=data, data_len=len(data))
        image.buffers_free()                      # re-read from the new packed data (reload() logs an error)
    else:
        if image is not None:
            bpy.data.images.remove(image)
        image = bpy.data.images.new(name, int(size[0]), int(size[1]), alpha=False, float_buffer=True, is_data=True)
        image.filepath_raw = f"//{bpy.path.clean_name(name)}.png"     # where Unpack would write it
        image.file_format = "PNG"
        image.pack(data=data, data_len=len(data))
        image.source = "FILE"
        image.colorspace_settings.name = "Non-Color"
        image[DETAIL_IMAGE_KEY] = 1
    image[RANGE_KEY] = float(range_mm)
    return image


def packed_state(obj):
    """What :func:`restore_packed` needs to put the object's detail image back: (PNG bytes, range, size) or None."""
    image = detail_image(obj) if obj is not None else None
    if image is None or image.packed_file is None:
        return None
    return bytes(image.packed_file.data), float(image.get(RANGE_KEY, 1.0)), tuple(image.size)


def restore_packed(obj, state) -> None:
    """Put back the detail image :func:`packed_state` took (a cancelled run rebuilt it)."""
    if obj is not None and state is not None:
        _pack_png(obj, *state)


def image_height_mm(image) -> np.ndarray:
    """The heights (mm, rows from UV v = 0) a detail image holds (R channel)."""
    w, h = image.size
    px = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(px)
    return (px.reshape(h, w, 4)[..., 0] - 0.5) * (2.0 * float(image.get(RANGE_KEY, 1.0)))


def detail_image(obj):
    """The object's detail image, or None."""
    import bpy

    image = bpy.data.images.get(image_name(obj))
    return image if image is not None and image.get(DETAIL_IMAGE_KEY) == 1 else None


def _material_output(nodes):
    return next((n for n in nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output), None) or \
        next((n for n in nodes if n.type == "OUTPUT_MATERIAL"), None)


def ensure_detail_material(obj, image):
    """The surface's own skin material with the detail bump nodes, given to its first slot when that holds
    the shared skin material or this one (a material the user chose stays). Returns the material."""
    import bpy

    name = f"{objects.SKIN_MATERIAL} {obj.name}"
    mat = bpy.data.materials.get(name)
    if mat is None:
        mat = objects.ensure_skin_material().copy()
        mat.name = name
        mat[DETAIL_MATERIAL_KEY] = 1
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    uv = nodes.get(UV_NODE)
    if uv is None:
        uv = nodes.new("ShaderNodeUVMap")
        uv.name = uv.label = UV_NODE
        uv.location = (-800, -450)
    uv.uv_map = objects.UV_NAME
    tex = nodes.get(IMAGE_NODE)
    if tex is None:
        tex = nodes.new("ShaderNodeTexImage")
        tex.name = tex.label = IMAGE_NODE
        tex.location = (-550, -450)
        links.new(uv.outputs["UV"], tex.inputs["Vector"])
    tex.image = image
    tex.interpolation = "Linear"
    tex.extension = "EXTEND"
    bump = nodes.get(BUMP_NODE)
    if bump is None:
        bump = nodes.new("ShaderNodeDisplacement")
        bump.name = bump.label = BUMP_NODE
        bump.location = (-250, -450)
        bump.space = "OBJECT"
        bump.inputs["Midlevel"].default_value = 0.5                    # the image holds 0.5 + mm / (2 range)
        links.new(tex.outputs["Color"], bump.inputs["Height"])
    # shading only: the mesh is not displaced (Cycles' "Bump Only"; EEVEE bumps too)
    mat.displacement_method = "BUMP"
    slots = obj.data.materials
    if not slots:
        slots.append(mat)
    elif slots[0] is None or slots[0].name == objects.SKIN_MATERIAL or slots[0] == mat:
        slots[0] = mat
    return mat


def detail_material(obj):
    """The object's detail material (its first slot's, when it is one), or None."""
    mats = obj.data.materials if obj is not None and obj.type == "MESH" else ()
    mat = mats[0] if len(mats) else None
    return mat if mat is not None and mat.get(DETAIL_MATERIAL_KEY) == 1 else None


def set_detail_shading(obj, strength: float, enabled: bool) -> bool:
    """Plug the bump into the material output (``enabled``) with ``strength`` x the CT's relief, or unplug it.
    False when the object has no detail material."""
    mat = detail_material(obj)
    if mat is None:
        return False
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bump, out = nodes.get(BUMP_NODE), _material_output(nodes)
    if bump is None or out is None:
        return False
    tex = nodes.get(IMAGE_NODE)
    range_mm = float(tex.image.get(RANGE_KEY, 1.0)) if tex is not None and tex.image is not None else 1.0
    bump.inputs["Scale"].default_value = float(strength) * 2.0 * range_mm * MM_TO_OBJECT
    socket = out.inputs["Displacement"]
    for link in list(socket.links):
        links.remove(link)
    if enabled:
        links.new(bump.outputs["Displacement"], socket)
    return True


def detail_height(study):
    """The study's detail layer for an export: its map's heights (mm) and strength, or (None, 0.0) when the
    layer is off, out of date, not built or at strength 0 (the PDE surface)."""
    s = study.settings
    strength = float(s.detail_strength)
    if not s.use_detail_map or s.detail_stale or strength == 0.0 or s.surface_object is None:
        return None, 0.0
    image = detail_image(s.surface_object)
    if image is None:
        return None, 0.0
    return image_height_mm(image), strength


def print_skin(study):
    """The study's skin for Export for Printing: the PDE surface meshed at print resolution
    (:func:`pdehead_addon.print_resolution`: chord error within 0.05 mm over the face, at most 2 M
    triangles), displaced by its CT detail at the study's strength (:func:`pdehead_addon.detail_surface`)."""
    from ..pdehead_addon import detail_surface, print_resolution

    head = study.head
    height, strength = detail_height(study)
    nu, nv = print_resolution(head)
    return detail_surface(head, height, strength, nu, nv, caps=True)


def build_detail_map(obj, head, seg, resolution: int, strength: float, enabled: bool = True) -> dict:
    """Compute the detail map of ``head`` from ``seg`` (its mask and CT geometry) and give it to ``obj``."""
    stages = detail_map_stages(obj, head, seg, resolution, strength, enabled)
    while True:
        try:
            next(stages)
        except StopIteration as done:
            return done.value


def detail_map_stages(obj, head, seg, resolution: int, strength: float, enabled: bool = True):
    """:func:`build_detail_map` one engine stage at a time (a generator yielding ``(fraction, message)``,
    returning the map's meta): the object's image and material change only after the last stage, so a
    caller that stops early (Esc in :class:`~.ops.PDEHEAD_OT_build_detail_map`) keeps the old map."""
    from ..pdehead_addon import detail_map_stages as engine_stages

    dmap = yield from engine_stages(head, seg.mask, seg.ct, resolution=int(resolution))
    image = set_detail_image(obj, dmap.height, dmap.meta["max_mm"])
    ensure_detail_material(obj, image)
    set_detail_shading(obj, strength, enabled)
    return dmap.meta
