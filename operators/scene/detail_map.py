"""The surface's CT detail layer in Blender: a 16-bit height image in the surface's UVs, applied as real
displacement of the PDE surface along its normals.

The engine (:func:`pdehead_addon.ct_detail_map`) gives per texel the offset (mm) along the PDE surface's
outward normal from the surface to the CT's skin. Here it becomes the image "PDE Head Detail <surface>"
(non-colour, 0.5 + mm / (2 x range); a 16-bit PNG packed into the .blend, so a saved file reopens with it),
an image texture of the same name, and two modifiers on the surface: a Catmull-Clark subdivision
(:data:`SUBDIV_LEVELS`: the viewport's 2 mm rows become 0.5 mm, dense enough for a 1 mm eyelid line) and
a Displace modifier reading the texture through the UV map ``UVMap`` along the normals (midlevel 0.5,
strength = detail strength x 2 range x 0.001: the surface's object space is metres, world = LPS mm x
0.001). The strength follows the study's ``detail_strength`` through a driver, so it animates like the
other settings (keyframes on the settings object, Render Animation). At strength 0 (the default) and while
the layer is off or out of date both modifiers are off: the surface is the PDE surface and the live
sliders pay nothing for the layer. Export for Printing displaces its print-resolution skin by the same map
and strength in the engine (:func:`print_skin`).

A file saved with the earlier bump (the map wired into the skin material's Displacement, "Bump only")
reopens with the displacement: :func:`set_detail_shading` unplugs the bump and adds the modifiers.

Off by default (``use_detail_map``): Run Pipeline builds it only when it is on, and turning it on never
builds it inside the property's update (that would block the UI for seconds): the Surface panel then
shows *Build CT Detail* (:class:`~operators.ui.ops.PDEHEAD_OT_build_detail_map`: modal with progress, Esc keeps the old
map; synchronous from scripts). A live change of the PDE moves the surface away from the map's: the map is
then marked out of date and its displacement turned off (not left silently stale) until it is rebuilt
(*Rebuild CT Detail*, or Run Pipeline): rebuilding costs seconds (~2.6 s of CPU at 1024 x 1024 on CThead),
far beyond a slider's 100 ms step. nu, nv and caps do not change the map (the UVs are a function of (u, v)).
"""
from __future__ import annotations

import struct
import zlib

import bpy
import numpy as np

from ...pdehead_addon import detail_map_stages as engine_stages, print_mesh
from .. import state
from . import objects

DETAIL_IMAGE_KEY = "pdehead_detail_image"
DETAIL_MATERIAL_KEY = "pdehead_detail_material"
RANGE_KEY = "pdehead_detail_range_mm"
IMAGE_NODE, UV_NODE, BUMP_NODE = "CT detail", "CT detail UV", "CT detail bump"
SUBDIV_MOD, DISPLACE_MOD = "CT detail subdivision", "CT detail"
#: Catmull-Clark levels before the displacement: 2 quarters the viewport's ~2 mm rows and ~2.3 mm columns
#: (CThead at 120 x 240) to ~0.5 mm, the detail map's texel (~0.6 mm at 1024 px) and half a 1 mm lid line.
SUBDIV_LEVELS = 2
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
    image = bpy.data.images.get(image_name(obj))
    return image if image is not None and image.get(DETAIL_IMAGE_KEY) == 1 else None


def _material_output(nodes):
    return next((n for n in nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output), None) or \
        next((n for n in nodes if n.type == "OUTPUT_MATERIAL"), None)


def ensure_detail_material(obj, image):
    """The surface's own skin material with the detail bump nodes, given to its first slot when that holds
    the shared skin material or this one (a material the user chose stays). Returns the material."""
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
    # the relief is the Displace modifier's (real geometry); the material's own displacement stays off
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


def _settings_of(obj):
    """The study settings whose surface ``obj`` is, or None."""
    for coll in getattr(obj, "users_collection", ()):
        s = state.settings(coll)
        if s is not None and s.surface_object == obj:
            return s
    return None


def _strength_animated(settings) -> bool:
    ad = getattr(settings.id_data, "animation_data", None) if settings is not None else None
    return bool(ad and ((ad.action and any("detail_strength" in fc.data_path for fc in _fcurves(ad.action)))
                        or any("detail_strength" in d.data_path for d in ad.drivers)))


def _fcurves(action):
    fcurves = getattr(action, "fcurves", None)
    if fcurves is not None:
        return list(fcurves)
    out = []                                             # Blender 5: layered actions
    for layer in getattr(action, "layers", ()):
        for strip in layer.strips:
            for bag in getattr(strip, "channelbags", ()):
                out.extend(bag.fcurves)
    return out


def _unplug_bump(obj) -> None:
    """The earlier bump (the map in the material's Displacement): unplugged, the displacement replaces it."""
    mat = detail_material(obj)
    if mat is None:
        return
    out = _material_output(mat.node_tree.nodes)
    if out is not None:
        for link in list(out.inputs["Displacement"].links):
            mat.node_tree.links.remove(link)


def ensure_displacement(obj, image, settings=None):
    """The object's CT detail modifiers (subdivision, then Displace by the image texture in UV along the
    normals, its strength driven by ``settings.detail_strength``); returns the Displace modifier."""
    name = image_name(obj)
    tex = bpy.data.textures.get(name)
    if tex is None or tex.type != "IMAGE":
        tex = bpy.data.textures.new(name, "IMAGE")
    tex.image = image
    tex.extension = "EXTEND"
    tex.use_interpolation = True                          # bilinear, as the engine samples the map
    mods = obj.modifiers
    sub = mods.get(SUBDIV_MOD)
    if sub is None or sub.type != "SUBSURF":
        sub = mods.new(SUBDIV_MOD, "SUBSURF")
    sub.subdivision_type = "CATMULL_CLARK"
    sub.levels = sub.render_levels = SUBDIV_LEVELS
    sub.uv_smooth = "NONE"                                # the UVs linear: the map is a function of (u, v)
    disp = mods.get(DISPLACE_MOD)
    if disp is None or disp.type != "DISPLACE":
        disp = mods.new(DISPLACE_MOD, "DISPLACE")
    disp.texture = tex
    disp.texture_coords = "UV"
    disp.uv_layer = objects.UV_NAME
    disp.direction = "NORMAL"
    disp.space = "LOCAL"
    disp.mid_level = 0.5                                  # the image holds 0.5 + mm / (2 range)
    # the subdivision first, then the displacement: both after any modifier the user added
    for mod in (sub, disp):
        index = list(mods).index(mod)
        if index != len(mods) - 1:
            mods.move(index, len(mods) - 1)
    if settings is not None:
        _drive_strength(disp, settings, float(image.get(RANGE_KEY, 1.0)))
    return disp


def _drive_strength(disp, settings, range_mm: float) -> None:
    """The Displace strength follows ``settings.detail_strength`` (keyframes, Render Animation) through a
    driver with a simple expression (no Python: it runs without auto-run scripts)."""
    scale = 2.0 * range_mm * MM_TO_OBJECT
    fc = disp.driver_add("strength") if not _driven(disp) else _driven(disp)
    drv = fc.driver
    drv.type = "SCRIPTED"
    var = drv.variables[0] if len(drv.variables) else drv.variables.new()
    var.name, var.type = "s", "SINGLE_PROP"
    var.targets[0].id_type = "OBJECT"
    var.targets[0].id = settings.id_data
    var.targets[0].data_path = "pdehead.detail_strength"
    drv.expression = f"s * {scale!r}"


def _driven(disp):
    ad = disp.id_data.animation_data
    path = disp.path_from_id("strength")
    return next((d for d in ad.drivers if d.data_path == path), None) if ad is not None else None


def reopen_with_displacement() -> list[str]:
    """After a file is loaded: every study surface with a detail image gets the displacement in place of a
    bump an earlier version wired (its names)."""
    done = []
    for coll in state.studies():
        s = state.settings(coll)
        obj = s.surface_object if s is not None else None
        if obj is None or detail_image(obj) is None:
            continue
        mods = detail_modifiers(obj)
        if mods[1] is None or detail_material(obj) is not None:
            set_detail_shading(obj, s.detail_strength, s.use_detail_map and not s.detail_stale)
            done.append(obj.name)
    return done


def detail_modifiers(obj):
    """The object's (subdivision, Displace) CT detail modifiers, or (None, None)."""
    mods = obj.modifiers if obj is not None and obj.type == "MESH" else {}
    return mods.get(SUBDIV_MOD), mods.get(DISPLACE_MOD)


def set_detail_shading(obj, strength: float, enabled: bool) -> bool:
    """The CT detail displacement on (``enabled``, at ``strength`` x the CT's relief) or off; off too at
    strength 0 unless the strength is animated (the surface is then the PDE surface and costs nothing).
    A bump wired by an earlier version is unplugged. False when the object has no detail image."""
    image = detail_image(obj) if obj is not None else None
    if image is None:
        return False
    settings = _settings_of(obj)
    _unplug_bump(obj)
    disp = ensure_displacement(obj, image, settings)
    range_mm = float(image.get(RANGE_KEY, 1.0))
    disp.strength = float(strength) * 2.0 * range_mm * MM_TO_OBJECT
    on = bool(enabled) and (float(strength) != 0.0 or _strength_animated(settings))
    for mod in detail_modifiers(obj):
        if mod is not None and (mod.show_viewport != on or mod.show_render != on):
            mod.show_viewport = mod.show_render = on
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
    """The study's skin for Export for Printing: the PDE surface meshed at print resolution, displaced by its
    CT detail at the study's strength (:func:`pdehead_addon.print_mesh`, the face's path too)."""
    height, strength = detail_height(study)
    return print_mesh(study.head, height, strength)


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
    caller that stops early (Esc in :class:`~operators.ui.ops.PDEHEAD_OT_build_detail_map`) keeps the old map."""
    dmap = yield from engine_stages(head, seg.mask, seg.ct, resolution=int(resolution))
    set_detail_image(obj, dmap.height, dmap.meta["max_mm"])
    set_detail_shading(obj, strength, enabled)
    return dmap.meta
