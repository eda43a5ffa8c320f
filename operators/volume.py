"""The PDE head volume: a .vdb of the w-field and the CT, rendered by paper eq. 24 in shader nodes.

Section 4.3 of the paper renders the head by 3D texture mapping the CT onto the
PDE solid (eq. 23) with the opacity of each texel tied linearly to the solid's
parameter w (eq. 24)::

    alpha = (l_alpha - h_alpha) * w + h_alpha,   0 <= w <= 1

so the spine (w = 0) is the most opaque and the outer surface (w = 1) the most
transparent, and nothing outside the solid is drawn. Here the w-field sampled on
a voxel grid (the engine's ``WField``) goes into an OpenVDB file with three
float grids:

``w``
    w in [0, 1] inside the solid; outside voxels hold the engine's background value
    ``OUTSIDE_W`` (> 1, :mod:`pdehead_addon.pde_solid`), which the shader maps to zero density.
``intensity``
    the CT intensity inside the solid, windowed to [0, 1]; 0 outside.
``ct``
    the whole CT box windowed to [0, 1] (on the w-field's grid when that is the
    CT's grid, else on the CT's own grid at about the same voxel size): the input of the
    paper's baseline "intuitive texture mapping" (Fig. 8a / 15a), whose alpha is
    the pixel value itself, noise outside the head included.

A Volume object reads the file by a relative path (``//pdehead_vdb/<study>.vdb``)
because .vdb files cannot be packed into a .blend. Its material computes the
density from the ``w`` grid *in shader nodes* (node group "PDE Head eq. 24"), so
l_alpha, h_alpha and the density scale change live without rewriting the file.
"""
from __future__ import annotations

import gc
import os
import tempfile
from pathlib import Path

import numpy as np

from ..pdehead_addon import OUTSIDE_W
from ..pdehead_addon import defaults as D
from ..pdehead_addon.ct_volume import apply_window, ct_grid_for, head_mask_on_grid, intensity_window
from . import compat, vdb_writer
from .coords import grid_affine_world
GRID_NAMES = ("w", "intensity", "ct")
REQUIRED_GRIDS = ("w", "intensity")
VDB_FOLDER_NAME = "pdehead_vdb"
GROUP_NAME = "PDE Head eq. 24"
ALPHA_MODES = D.ALPHA_MODE.choices
INSIDE_EPS = 1e-3         # w <= 1 + eps counts as inside (interpolation at the surface)

# Transfer functions: Color Ramp presets over the windowed intensity in [0, 1], (position, RGBA) pairs.
# The ramp's colour colours the volume; its alpha multiplies the opacity (eq. 24's alpha from w, or the
# intensity in the baseline mode), so a preset can also make a tissue transparent. The ramp stays
# editable in the material ("Intensity colour"); a preset only sets its stops.
COLOUR_PRESETS: dict[str, list[tuple[float, tuple[float, float, float, float]]]] = {
    # the paper's look: grey levels, opacity from eq. 24 alone
    "grayscale": [(0.0, (0.0, 0.0, 0.0, 1.0)), (1.0, (1.0, 1.0, 1.0, 1.0))],
    # soft tissue warm and visible, air and noise transparent, bone pale
    "skin": [(0.0, (0.02, 0.004, 0.002, 0.0)),
             (0.08, (0.40, 0.10, 0.05, 0.0)),
             (0.2, (0.90, 0.58, 0.45, 1.0)),
             (0.70, (0.96, 0.86, 0.76, 1.0)),
             (1.0, (1.0, 0.98, 0.92, 1.0))],
    # only bone: soft tissue transparent, the skull ivory
    "bone": [(0.0, (0.0, 0.0, 0.0, 0.0)),
             (0.5, (0.55, 0.35, 0.25, 0.0)),
             (0.65, (0.90, 0.82, 0.68, 0.6)),
             (1.0, (1.0, 0.97, 0.90, 1.0))],
    # a radiograph: grey levels, opacity rising with density, air transparent
    "xray": [(0.0, (0.0, 0.0, 0.0, 0.0)),
             (0.08, (0.08, 0.08, 0.08, 0.0)),
             (1.0, (1.0, 1.0, 1.0, 1.0))],
}
COLOUR_LABELS = {"grayscale": ("Grayscale", "CT intensity as grey levels; opacity from eq. 24 only (the paper)"),
                 "skin": ("Skin", "Warm soft tissue, air transparent"),
                 "bone": ("Bone", "Only bone: soft tissue transparent"),
                 "xray": ("X-Ray", "Grey levels, opacity rising with density, air transparent")}


# ----------------------------------------------------------------------------- default voxel size
INSIDE_FRACTION = 0.6             #: share of the solid's bounding box inside the solid (heads: ~0.5)


def estimate_vdb(ct, solid_box_mm, voxel: float) -> tuple[float, float]:
    """(bytes of the .vdb, voxels of the w-field grid) at isotropic `voxel` mm.

    ``w`` is float32 and ``intensity`` half-float over the voxels inside the solid (outside is
    the background, stored sparsely); ``ct`` is half-float over the whole CT box on the CT's grid
    decimated by whole steps (:func:`ct_volume.ct_grid_for`).
    """
    extent = np.asarray(solid_box_mm[1], float) - np.asarray(solid_box_mm[0], float) + 2.0 * voxel
    grid_voxels = float(np.prod(np.ceil(extent / voxel) + 1))
    steps = np.array([max(1, int(round(voxel / sp))) for sp in ct.spacing], float)
    ct_voxels = float(np.prod(np.ceil(np.array(ct.shape) / steps)))
    return INSIDE_FRACTION * grid_voxels * (4 + 2) + ct_voxels * 2, grid_voxels


def auto_voxel_size(ct, head, max_bytes: float = D.MAX_VDB_BYTES.default,
                    max_voxels: float = D.MAX_WFIELD_VOXELS.default) -> float:
    """Default volume voxel size (mm): the CT's finest spacing, coarsened in 5 % steps only until the
    .vdb estimate fits `max_bytes` and the w-field grid `max_voxels` (:func:`estimate_vdb`).

    CThead (1 x 1 x 2 mm) gives about 1.3 mm (the w-field's voxel budget decides), the GE series
    (0.49 mm pixels) the same; a scan with 3 mm voxels keeps 3 mm.
    """
    pts = head.surface(32, 64).vertices
    box = (pts.min(axis=0), pts.max(axis=0))
    voxel = max(float(min(ct.spacing)), D.VOXEL_SIZE.min)
    for _ in range(200):
        size, count = estimate_vdb(ct, box, voxel)
        if size <= max_bytes and count <= max_voxels:
            break
        voxel *= 1.05
    return round(voxel, 2)


# ----------------------------------------------------------------------------- files and paths
def vdb_folder_for(blend_path: str | os.PathLike | None, prefs_folder: str | os.PathLike | None = None) -> Path:
    """Folder for a study's .vdb files.

    Beside the saved .blend (``<blend folder>/pdehead_vdb``) when the file is
    saved; otherwise the add-on preference folder, or a ``pdehead_vdb`` folder
    in the system temp directory when that preference is empty.
    """
    if blend_path:
        return Path(os.fspath(blend_path)).resolve().parent / VDB_FOLDER_NAME
    if prefs_folder:
        folder = os.fspath(prefs_folder)
        if folder.startswith("//"):
            raise ValueError("the VDB preference folder must be absolute for unsaved files")
        return Path(folder).expanduser().resolve()
    return Path(tempfile.gettempdir()) / VDB_FOLDER_NAME


def vdb_path_for(study: str, blend_path=None, prefs_folder=None) -> Path:
    """Absolute path of the .vdb of `study` (see :func:`vdb_folder_for`), file name made safe.

    A name changed by the cleaning gets a short hash of the original, so that
    "CT head" and "CT_head" never share (and overwrite) one file.
    """
    import hashlib

    import bpy

    safe = bpy.path.clean_name(study) or "study"
    if safe != study:
        safe += "-" + hashlib.sha1(study.encode("utf-8")).hexdigest()[:6]
    return vdb_folder_for(blend_path, prefs_folder) / f"{safe}.vdb"


def blender_filepath(path: str | os.PathLike) -> str:
    """Path as Blender should store it: ``//...`` relative to the saved .blend when inside its folder."""
    import bpy

    path = Path(os.fspath(path)).resolve()
    if bpy.data.filepath:
        blend_dir = Path(bpy.data.filepath).resolve().parent
        try:
            path.relative_to(blend_dir)
        except ValueError:
            return str(path)
        return bpy.path.relpath(str(path), start=str(blend_dir))
    return str(path)


def fresh_vdb_path(path) -> Path:
    """`path` if no file is there, else the first free ``<stem>-<n>.vdb`` beside it.

    A rebuilt volume is always written to a new file and the object switched to it, so an
    existing (maybe better) file is never overwritten; the old file is removed only when a
    save no longer references it (:func:`purge_superseded`).
    """
    path = Path(os.fspath(path))
    if not path.exists():
        return path
    n = 2
    while True:
        candidate = path.with_name(f"{path.stem}-{n}{path.suffix}")
        if not candidate.exists():
            return candidate
        n += 1


#: Absolute paths of .vdb files that a rebuild or a move replaced; deleted after the next save
#: that no longer references them (deleting at once would break undo back to the old file).
_SUPERSEDED: set[str] = set()


#: Absolute paths of the .vdb files written in this session.
_WRITTEN: set[str] = set()


def supersede(path) -> None:
    """Mark a replaced .vdb for removal after the next save (see :func:`purge_superseded`)."""
    if path:
        _SUPERSEDED.add(str(Path(os.fspath(path)).resolve()))


def referenced_vdb_files() -> set[str]:
    """Absolute paths of the .vdb files the Volume datablocks of the open file point at."""
    import bpy

    out = set()
    for vol in bpy.data.volumes:
        if vol.filepath:
            out.add(str(Path(bpy.path.abspath(vol.filepath)).resolve()))
    return out


def purge_superseded() -> list[Path]:
    """Delete the superseded .vdb files no Volume datablock references any more; returns them.

    Only the add-on's own files are ever deleted: those in a ``pdehead_vdb`` folder or written
    by :func:`write_vdb` in this session (the preference folder of unsaved files).
    """
    used = referenced_vdb_files()
    removed = []
    for text in sorted(_SUPERSEDED):
        path = Path(text)
        if text in used:
            continue
        _SUPERSEDED.discard(text)
        ours = path.parent.name == VDB_FOLDER_NAME or text in _WRITTEN
        if ours and path.suffix == ".vdb" and path.is_file():
            try:
                path.unlink()
                removed.append(path)
            except OSError as exc:  # read-only folder: keep the file, say so
                print(f"PDE Head: could not remove the replaced volume file {path}: {exc}")
    return removed


def write_vdb(wfield, path, window, *, ct=None, origin_m=(0.0, 0.0, 0.0)) -> Path:
    """Write the w-field as an OpenVDB file with float grids ``w``, ``intensity`` and ``ct``.

    Parameters
    ----------
    wfield : WField
        ``.w`` float [z, y, x] (in [0, 1] inside the solid, > 1 outside),
        ``.intensity`` float [z, y, x] raw CT units (0 outside), ``.spacing``
        (dz, dy, dx) mm, ``.origin`` (x, y, z) LPS mm, ``.direction`` 3x3.
    path : path-like
        Output file (parent folders are created).
    window : (lo, hi)
        Intensity window (:func:`intensity_window`); the ``intensity`` and ``ct``
        grids hold windowed values in [0, 1] (Cycles needs non-negative densities).
    ct : CTVolume, optional
        The full CT for the ``ct`` grid, which covers the whole CT box: on the
        w-field grid when that is the CT's grid, else on the CT's own grid
        decimated to about the w-field voxel size (:func:`ct_grid_for`; a grid
        has its own transform). Without it the ``ct`` grid repeats
        ``intensity``, so the intensity-alpha baseline then shows the solid only.
    origin_m : (3,) metres
        World position of the Volume object's origin; grid transforms are
        relative to it, so the object at ``origin_m`` puts voxel (k, j, i) at
        world ``LPS(k, j, i) * 0.001`` exactly.

    Returns
    -------
    Path of the written file.
    """
    openvdb = compat.openvdb_module()
    path = Path(os.fspath(path))
    path.parent.mkdir(parents=True, exist_ok=True)

    w = np.asarray(wfield.w, dtype=np.float32)
    if w.ndim != 3:
        raise ValueError(f"w-field must be 3-D [z, y, x], got shape {w.shape}")
    if np.shape(wfield.intensity) != w.shape:
        raise ValueError(f"w-field intensity shape {np.shape(wfield.intensity)} differs from w {w.shape}")
    inside = w <= 1.0  # NaN and OUTSIDE_W (2.0) are outside
    affine = grid_affine_world(wfield.spacing, wfield.origin, wfield.direction)
    affine[:3, 3] -= np.asarray(origin_m, dtype=np.float64)
    transform_rows = affine.T.tolist()  # OpenVDB uses row vectors: translation in the last row

    def grids():
        """(name, [z, y, x] float32 data, background, half floats, transform), one at a time: bounded memory."""
        yield ("w", np.where(inside, np.clip(w, 0.0, 1.0), np.float32(OUTSIDE_W)), OUTSIDE_W,
               False, transform_rows)
        intensity = apply_window(wfield.intensity, window)
        intensity[~inside] = 0.0
        yield "intensity", intensity, 0.0, True, transform_rows
        if ct is None:
            yield "ct", intensity, 0.0, True, transform_rows
            return
        data, spacing, ct_origin, ct_direction = ct_grid_for(ct, wfield)
        ct_affine = grid_affine_world(spacing, ct_origin, ct_direction)
        ct_affine[:3, 3] -= np.asarray(origin_m, dtype=np.float64)
        windowed = apply_window(data, window)
        windowed[~head_mask_on_grid(wfield, windowed.shape, spacing, ct_origin, ct_direction)] = 0.0
        yield "ct", windowed, 0.0, True, ct_affine.T.tolist()

    window_meta = f"{float(window[0])!r} {float(window[1])!r}"
    if openvdb is None:  # no bindings (bpy 4.2 from PyPI): our own writer, same grids and values (leaves
        # only where a voxel differs from the background: the bounds of a pruned grid)
        vdb_writer.write_vdb(path, (
            vdb_writer.DenseGrid(name, data.transpose(2, 1, 0), background, half, rows,
                                 {"pdehead_window": window_meta} if name == "w" else {})
            for name, data, background, half, rows in grids()))
        _WRITTEN.add(str(path.resolve()))
        return path
    written = []
    try:
        for name, data, background, half, rows in grids():
            grid = openvdb.FloatGrid(background=float(background))
            # numpy [k, j, i] -> OpenVDB (i, j, k): transpose (a copy) so index x is the CT's i axis
            grid.copyFromArray(np.ascontiguousarray(data.transpose(2, 1, 0)), tolerance=0.0)
            del data
            if hasattr(grid, "prune"):  # drop all-background tiles: Blender's bounds follow the kept data
                grid.prune()
            grid.name = name
            grid.transform = openvdb.createLinearTransform(rows)
            grid.gridClass = openvdb.GridClass.FOG_VOLUME
            grid.saveFloatAsHalf = half  # display data in [0, 1]: half precision is plenty, half the file
            written.append(grid)
        written[0]["pdehead_window"] = window_meta
        openvdb.write(str(path), grids=written)
        _WRITTEN.add(str(path.resolve()))
    finally:
        del written[:]  # free the grids now: nanobind reports "leaked" objects at exit otherwise
        gc.collect()
    return path


# ----------------------------------------------------------------------------- shader nodes
def _socket(sockets, identifier):
    for s in sockets:
        if s.identifier == identifier:
            return s
    raise KeyError(identifier)


def _math(nodes, op, label, location, a=None, b=None, c=None):
    n = nodes.new("ShaderNodeMath")
    n.operation = op
    n.label = label
    n.name = label
    n.location = location
    for i, v in enumerate((a, b, c)):
        if v is not None:
            n.inputs[i].default_value = v
    return n


def _new_socket(group, name, in_out, default=None, lo=None, hi=None, description=""):
    s = group.interface.new_socket(name, in_out=in_out, socket_type="NodeSocketFloat", description=description)
    if in_out == "INPUT":
        if lo is not None:
            s.min_value = lo
        if hi is not None:
            s.max_value = hi
        if default is not None:
            s.default_value = default
    return s


def ensure_eq24_group(name: str = GROUP_NAME):
    """The shader node group computing eq. 24 density from w (created once, reused).

    Inputs: ``W``, ``Intensity``, ``CT`` (grid values), ``Low Alpha`` (l_alpha),
    ``High Alpha`` (h_alpha), ``Density`` (scale, per metre), ``Emission`` (per
    unit density), ``Intensity Alpha`` (0: eq. 24; 1: the paper's baseline with
    alpha = windowed CT everywhere).
    Outputs: ``Density`` = max(scale * alpha, 0), ``Emission Strength`` =
    density * emission, ``Value`` (intensity for the colour ramp), ``Alpha``.

    ``alpha = ((l - h) * clamp(w, 0, 1) + h) * [w <= 1]`` in eq. 24 mode, so it
    is 0 outside the solid (w = 2); every path ends in a clamp or a max with 0,
    so no negative density reaches Cycles.
    """
    import bpy

    group = bpy.data.node_groups.get(name)
    if group is not None and group.bl_idname == "ShaderNodeTree" and group.get("pdehead_version") == 1:
        return group
    if group is None:
        group = bpy.data.node_groups.new(name, "ShaderNodeTree")
    group.nodes.clear()
    group.interface.clear()
    group["pdehead_version"] = 1
    group.description = "PDE Head: volume density from the solid parameter w by paper eq. 24"

    _new_socket(group, "W", "INPUT", OUTSIDE_W, description="PDE solid parameter w (> 1 outside)")
    _new_socket(group, "Intensity", "INPUT", 0.0, 0.0, 1.0, "windowed CT intensity inside the solid")
    _new_socket(group, "CT", "INPUT", 0.0, 0.0, 1.0, "windowed CT intensity in the whole CT box")
    _new_socket(group, "Low Alpha", "INPUT", D.LOW_ALPHA.default, 0.0, 1.0, "l_alpha of eq. 24 (at w = 1)")
    _new_socket(group, "High Alpha", "INPUT", D.HIGH_ALPHA.default, 0.0, 1.0, "h_alpha of eq. 24 (at w = 0)")
    _new_socket(group, "Density", "INPUT", D.DENSITY.default, D.DENSITY.min, D.DENSITY.max,
                "density per metre at alpha = 1")
    _new_socket(group, "Emission", "INPUT", D.EMISSION.default, 0.0, 1e3, "emission per unit density")
    _new_socket(group, "Intensity Alpha", "INPUT", 0.0, 0.0, 1.0,
                "0: eq. 24 alpha from w; 1: alpha = CT intensity everywhere (baseline)")
    for out in ("Density", "Emission Strength", "Value", "Alpha"):
        _new_socket(group, out, "OUTPUT")

    nodes, links = group.nodes, group.links
    gin = nodes.new("NodeGroupInput")
    gin.location = (-900, 0)
    gout = nodes.new("NodeGroupOutput")
    gout.location = (700, 0)
    I, O = gin.outputs, gout.inputs  # noqa: E741

    w_clamped = nodes.new("ShaderNodeClamp")
    w_clamped.name = w_clamped.label = "Clamp w"
    w_clamped.location = (-600, 200)
    w_clamped.inputs["Min"].default_value, w_clamped.inputs["Max"].default_value = 0.0, 1.0
    links.new(I["W"], w_clamped.inputs["Value"])

    slope = _math(nodes, "SUBTRACT", "l - h", (-600, 400))
    links.new(I["Low Alpha"], slope.inputs[0])
    links.new(I["High Alpha"], slope.inputs[1])
    alpha24 = _math(nodes, "MULTIPLY_ADD", "eq. 24: (l - h) w + h", (-350, 300))
    links.new(slope.outputs[0], alpha24.inputs[0])
    links.new(w_clamped.outputs[0], alpha24.inputs[1])
    links.new(I["High Alpha"], alpha24.inputs[2])
    inside = _math(nodes, "LESS_THAN", "inside: w < 1 + eps", (-350, 100), b=1.0 + INSIDE_EPS)
    links.new(I["W"], inside.inputs[0])
    masked = _math(nodes, "MULTIPLY", "alpha * inside", (-150, 250))
    links.new(alpha24.outputs[0], masked.inputs[0])
    links.new(inside.outputs[0], masked.inputs[1])

    ct_alpha = nodes.new("ShaderNodeClamp")
    ct_alpha.name = ct_alpha.label = "Clamp CT"
    ct_alpha.location = (-350, -150)
    links.new(I["CT"], ct_alpha.inputs["Value"])

    mode_alpha = nodes.new("ShaderNodeMix")
    mode_alpha.data_type = "FLOAT"
    mode_alpha.clamp_factor = True
    mode_alpha.name = mode_alpha.label = "Alpha mode"
    mode_alpha.location = (50, 150)
    links.new(I["Intensity Alpha"], _socket(mode_alpha.inputs, "Factor_Float"))
    links.new(masked.outputs[0], _socket(mode_alpha.inputs, "A_Float"))
    links.new(ct_alpha.outputs[0], _socket(mode_alpha.inputs, "B_Float"))
    alpha = nodes.new("ShaderNodeClamp")
    alpha.name = alpha.label = "Clamp alpha"
    alpha.location = (250, 150)
    links.new(_socket(mode_alpha.outputs, "Result_Float"), alpha.inputs["Value"])

    scaled = _math(nodes, "MULTIPLY", "alpha * density", (420, 200))
    links.new(alpha.outputs[0], scaled.inputs[0])
    links.new(I["Density"], scaled.inputs[1])
    density = _math(nodes, "MAXIMUM", "density >= 0", (560, 200), b=0.0)
    links.new(scaled.outputs[0], density.inputs[0])
    emission = _math(nodes, "MULTIPLY", "density * emission", (420, 0))
    links.new(density.outputs[0], emission.inputs[0])
    links.new(I["Emission"], emission.inputs[1])
    emission_pos = _math(nodes, "MAXIMUM", "emission >= 0", (560, 0), b=0.0)
    links.new(emission.outputs[0], emission_pos.inputs[0])

    mode_value = nodes.new("ShaderNodeMix")
    mode_value.data_type = "FLOAT"
    mode_value.clamp_factor = True
    mode_value.name = mode_value.label = "Colour source"
    mode_value.location = (50, -200)
    links.new(I["Intensity Alpha"], _socket(mode_value.inputs, "Factor_Float"))
    links.new(I["Intensity"], _socket(mode_value.inputs, "A_Float"))
    links.new(I["CT"], _socket(mode_value.inputs, "B_Float"))
    value = nodes.new("ShaderNodeClamp")
    value.name = value.label = "Clamp value"
    value.location = (250, -200)
    links.new(_socket(mode_value.outputs, "Result_Float"), value.inputs["Value"])

    links.new(density.outputs[0], O["Density"])
    links.new(emission_pos.outputs[0], O["Emission Strength"])
    links.new(value.outputs[0], O["Value"])
    links.new(alpha.outputs[0], O["Alpha"])
    return group


def apply_colour_preset(ramp_node, preset: str) -> None:
    """Set a Color Ramp node's stops from :data:`COLOUR_PRESETS`."""
    if preset not in COLOUR_PRESETS:
        raise ValueError(f"unknown colour preset {preset!r}; choose from {sorted(COLOUR_PRESETS)}")
    stops = COLOUR_PRESETS[preset]
    elements = ramp_node.color_ramp.elements
    while len(elements) > 1:
        elements.remove(elements[-1])
    elements[0].position, elements[0].color = stops[0]
    for pos, colour in stops[1:]:  # new() inserts in position order
        elements.new(pos).color = colour
    ramp_node.color_ramp.interpolation = "LINEAR"
    ramp_node["pdehead_preset"] = preset


def ensure_volume_material(obj=None, name: str | None = None):
    """The volume material (one per Volume object), built around the eq. 24 node group.

    Nodes: ``Attribute`` w / intensity / ct -> group "PDE Head eq. 24" ->
    ``Principled Volume`` (Density, Emission Strength; Color and Emission
    Color from ``Color Ramp`` over the group's Value) -> ``Material Output``
    Volume. Assigned to `obj` (slot 0) when given.
    """
    import bpy

    mat = None
    if obj is not None and obj.material_slots and obj.material_slots[0].material is not None:
        mat = obj.material_slots[0].material
        if mat.get("pdehead_volume_material") == 1:
            if mat.get("pdehead_volume_version", 1) < VOLUME_MATERIAL_VERSION:
                _upgrade_volume_material(mat)
            return mat
    if name is None:
        name = f"PDE Head Volume {obj.name}" if obj is not None else "PDE Head Volume"
    mat = bpy.data.materials.new(name)
    mat["pdehead_volume_material"] = 1
    mat["pdehead_volume_version"] = VOLUME_MATERIAL_VERSION
    if mat.node_tree is None:
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()

    attrs = {}
    for i, grid in enumerate(GRID_NAMES):
        a = nodes.new("ShaderNodeAttribute")
        a.attribute_type = "GEOMETRY"
        a.attribute_name = grid
        a.name = a.label = f"Attribute {grid}"
        a.location = (-700, 200 - 180 * i)
        attrs[grid] = a
    group_node = nodes.new("ShaderNodeGroup")
    group_node.node_tree = ensure_eq24_group()
    group_node.name = group_node.label = GROUP_NAME
    group_node.location = (-400, 100)
    links.new(_socket(attrs["w"].outputs, "Fac"), group_node.inputs["W"])
    links.new(_socket(attrs["intensity"].outputs, "Fac"), group_node.inputs["Intensity"])
    links.new(_socket(attrs["ct"].outputs, "Fac"), group_node.inputs["CT"])

    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.name = ramp.label = "Intensity colour"
    ramp.location = (-150, -150)
    apply_colour_preset(ramp, "grayscale")
    links.new(group_node.outputs["Value"], ramp.inputs["Fac"])

    pv = nodes.new("ShaderNodeVolumePrincipled")
    pv.location = (350, 100)
    _link_transfer(nodes, links, group_node, ramp, pv)
    links.new(ramp.outputs["Color"], pv.inputs["Color"])
    links.new(ramp.outputs["Color"], pv.inputs["Emission Color"])
    pv.inputs["Absorption Color"].default_value = (0.0, 0.0, 0.0, 1.0)

    out = nodes.new("ShaderNodeOutputMaterial")
    out.location = (650, 100)
    links.new(pv.outputs["Volume"], out.inputs["Volume"])

    if obj is not None:
        if obj.material_slots:
            obj.material_slots[0].material = mat
        else:
            obj.data.materials.append(mat)
    return mat


VOLUME_MATERIAL_VERSION = 2  #: 2: the colour ramp's alpha is the transfer function's opacity


def _link_transfer(nodes, links, group_node, ramp, pv) -> None:
    """Density and emission of the volume = the eq. 24 group's outputs x the colour ramp's alpha."""
    for out_name, in_name, y in (("Density", "Density", 250), ("Emission Strength", "Emission Strength", 50)):
        label = f"transfer alpha x {out_name.lower()}"
        node = nodes.get(label) or _math(nodes, "MULTIPLY", label, (150, y))
        links.new(group_node.outputs[out_name], node.inputs[0])
        links.new(ramp.outputs["Alpha"], node.inputs[1])
        links.new(node.outputs[0], pv.inputs[in_name])


def _upgrade_volume_material(mat) -> None:
    """A volume material of an older file (version 1): add the transfer-function opacity."""
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    group_node, ramp = nodes.get(GROUP_NAME), nodes.get("Intensity colour")
    pv = next((n for n in nodes if n.bl_idname == "ShaderNodeVolumePrincipled"), None)
    if group_node is not None and ramp is not None and pv is not None:
        for element in ramp.color_ramp.elements:  # old presets had alpha 1: the look stays as it was
            element.color = (*tuple(element.color)[:3], 1.0)
        _link_transfer(nodes, links, group_node, ramp, pv)
    mat["pdehead_volume_version"] = VOLUME_MATERIAL_VERSION


def _volume_nodes(obj):
    mat = ensure_volume_material(obj)
    nodes = mat.node_tree.nodes
    return nodes[GROUP_NAME], nodes["Intensity colour"]


def set_volume_settings(obj, low_alpha: float | None = None, high_alpha: float | None = None,
                        density: float | None = None, emission: float | None = None,
                        colour_preset: str | None = None, alpha_mode: str | None = None) -> None:
    """Set the eq. 24 parameters on a Volume object's material (None keeps the current value).

    Parameters
    ----------
    low_alpha, high_alpha : float in [0, 1]
        l_alpha and h_alpha of eq. 24 (paper: 0.1 and 0.9).
    density : float >= 0
        Density per metre at alpha = 1.
    emission : float >= 0
        Emission per unit density.
    colour_preset : {"grayscale", "skin", "bone", "xray"}
        Transfer function preset (:data:`COLOUR_PRESETS`): colour and opacity over the intensity.
    alpha_mode : {"EQ24", "INTENSITY"}
        "INTENSITY" is the paper's baseline (Fig. 8a / 15a): alpha = windowed CT
        everywhere in the CT box.
    """
    group_node, ramp = _volume_nodes(obj)
    inputs = group_node.inputs
    for key, value, lo, hi in (("Low Alpha", low_alpha, 0.0, 1.0), ("High Alpha", high_alpha, 0.0, 1.0),
                               ("Density", density, 0.0, None), ("Emission", emission, 0.0, None)):
        if value is not None:
            value = float(value)
            if not np.isfinite(value):
                raise ValueError(f"{key} must be finite, got {value}")
            value = max(lo, value if hi is None else min(hi, value))
            inputs[key].default_value = value
    if alpha_mode is not None:
        if alpha_mode not in ALPHA_MODES:
            raise ValueError(f"alpha_mode must be one of {ALPHA_MODES}, got {alpha_mode!r}")
        inputs["Intensity Alpha"].default_value = 1.0 if alpha_mode == "INTENSITY" else 0.0
    if colour_preset is not None:
        apply_colour_preset(ramp, colour_preset)


def get_volume_settings(obj) -> dict:
    """Current eq. 24 settings of a Volume object's material (keys as in :func:`set_volume_settings`)."""
    group_node, ramp = _volume_nodes(obj)
    inputs = group_node.inputs
    return {
        "low_alpha": inputs["Low Alpha"].default_value,
        "high_alpha": inputs["High Alpha"].default_value,
        "density": inputs["Density"].default_value,
        "emission": inputs["Emission"].default_value,
        "colour_preset": ramp.get("pdehead_preset", "grayscale"),
        "alpha_mode": "INTENSITY" if inputs["Intensity Alpha"].default_value >= 0.5 else "EQ24",
    }


# ----------------------------------------------------------------------------- the Volume object
def build_volume(wfield, collection, vdb_path, name: str = "Volume", obj=None, *, window=None, ct=None,
                 **settings):
    """Write `wfield` to `vdb_path` and show it as a Volume object with the eq. 24 material.

    Parameters
    ----------
    wfield : WField
        From ``PDEHead.w_field``.
    collection : bpy.types.Collection
        The study collection (its stored origin becomes the object's origin).
    vdb_path : path-like
        Absolute path of the .vdb (see :func:`vdb_path_for`); stored as
        ``//``-relative when it lies beside the saved .blend.
    obj : bpy.types.Object, optional
        An existing Volume object to update in place (keeps its material).
    window : (lo, hi), optional
        Intensity window; default :func:`intensity_window` of `ct` (or of the
        w-field's intensity inside the solid).
    ct : CTVolume, optional
        Full CT for the ``ct`` grid (intensity-alpha baseline).
    **settings
        Passed to :func:`set_volume_settings`.
    """
    import bpy
    from mathutils import Matrix

    from .objects import study_origin

    if window is None:
        if ct is not None:
            window = intensity_window(ct)
        else:
            inside = np.asarray(wfield.w) <= 1.0
            window = intensity_window(np.asarray(wfield.intensity)[inside]) if inside.any() else (0.0, 1.0)
    bounds_m = _grid_corners_world(wfield)
    origin = study_origin(collection, bounds_m)
    previous = None
    if obj is not None and obj.type == "VOLUME" and obj.data.filepath:
        previous = Path(bpy.path.abspath(obj.data.filepath)).resolve()
    # a new file every time: the current one (perhaps with CT data this build lacks) stays intact
    path = write_vdb(wfield, fresh_vdb_path(vdb_path), window, ct=ct, origin_m=origin)

    if obj is None:
        data = bpy.data.volumes.new(name)
        obj = bpy.data.objects.new(name, data)
        collection.objects.link(obj)
    elif obj.type != "VOLUME":
        raise TypeError(f"object {obj.name!r} is not a Volume object")
    data = obj.data
    data.grids.unload()
    data.filepath = blender_filepath(path)
    data.grids.load()
    if previous is not None and previous != Path(path).resolve():
        supersede(previous)
    obj.matrix_world = Matrix.Translation(origin)
    box = _solid_box_world(wfield)
    if box is not None:
        obj["pdehead_solid_box_m"] = [float(x) for x in (*(box[0] - origin), *(box[1] - origin))]
    elif "pdehead_solid_box_m" in obj.keys():
        del obj["pdehead_solid_box_m"]
    obj["pdehead_kind"] = "volume"
    obj["pdehead_window"] = [float(window[0]), float(window[1])]
    obj["pdehead_origin_m"] = list(origin)
    ensure_volume_material(obj)
    set_volume_settings(obj, **settings)
    return obj


def _solid_box_world(wfield):
    """World (min, max) metres of the voxels inside the solid (w <= 1), half a voxel added; None if empty."""
    inside = np.asarray(wfield.w) <= 1.0
    ranges = []
    for axes in ((1, 2), (0, 2), (0, 1)):  # k, j, i
        idx = np.flatnonzero(inside.any(axis=axes))
        if idx.size == 0:
            return None
        ranges.append((idx[0] - 0.5, idx[-1] + 0.5))
    (k0, k1), (j0, j1), (i0, i1) = ranges
    corners = np.array([[i, j, k, 1.0] for i in (i0, i1) for j in (j0, j1) for k in (k0, k1)])
    pts = (corners @ grid_affine_world(wfield.spacing, wfield.origin, wfield.direction).T)[:, :3]
    return pts.min(axis=0), pts.max(axis=0)


def solid_box(obj):
    """World (min, max) metres of the solid inside a PDE Head Volume object, or None if unknown."""
    box = obj.get("pdehead_solid_box_m") if obj is not None else None
    if box is None or len(box) != 6:
        return None
    m = np.array(obj.matrix_world)
    lo, hi = np.array(box[:3]), np.array(box[3:])
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pts = corners @ m[:3, :3].T + m[:3, 3]
    return pts.min(axis=0), pts.max(axis=0)


def _grid_corners_world(wfield) -> np.ndarray:
    nz, ny, nx = np.shape(wfield.w)
    corners = np.array([[i, j, k, 1.0] for i in (0, nx - 1) for j in (0, ny - 1) for k in (0, nz - 1)])
    return (corners @ grid_affine_world(wfield.spacing, wfield.origin, wfield.direction).T)[:, :3]


def relocate_vdb(obj, folder=None, blend_path=None) -> Path | None:
    """Copy a Volume object's .vdb into `folder` and point the object at the copy.

    `folder` defaults to ``pdehead_vdb`` beside `blend_path` (default: the saved .blend),
    so a volume built while the file was unsaved (in the preference or temp folder) follows
    the file once it is saved; the path is then stored relative (``//...``). A different file
    already at the destination is never overwritten (the copy gets a free name). Returns the
    new path, or None when there is nothing to do (no file, no saved .blend, or already there).

    ``blend_path`` lets the save_pre handler move files beside the file being written before
    Blender writes it; the stored path is then relative to the *current* .blend, which
    Blender's relative-path remapping turns into ``//pdehead_vdb/...`` of the new one.
    """
    import filecmp
    import shutil

    import bpy

    if obj is None or obj.type != "VOLUME" or not obj.data.filepath:
        return None
    blend_path = blend_path or bpy.data.filepath
    if folder is None:
        if not blend_path:
            return None
        folder = vdb_folder_for(blend_path)
    src = Path(bpy.path.abspath(obj.data.filepath)).resolve()
    dst = Path(os.fspath(folder)).resolve() / src.name
    if src.parent == dst.parent:
        if bpy.data.filepath and not obj.data.filepath.startswith("//"):
            obj.data.filepath = blender_filepath(dst)
        return None
    if not src.is_file():
        return None
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists() and not filecmp.cmp(src, dst, shallow=False):
        dst = fresh_vdb_path(dst)
    if not dst.exists():
        shutil.copy2(src, dst)
    obj.data.filepath = bpy.path.relpath(str(dst)) if bpy.data.filepath else str(dst)
    obj.data.grids.unload()
    obj.data.grids.load()
    return dst


def check_volume(obj) -> str | None:
    """None if the Volume object's .vdb loads with grids w and intensity, else a message for the user."""
    import bpy

    if obj is None or obj.type != "VOLUME":
        return "This is not a PDE Head volume object."
    data = obj.data
    if not data.filepath:
        return f"Volume '{obj.name}' has no .vdb file: rebuild the volume."
    path = bpy.path.abspath(data.filepath)
    if not os.path.isfile(path):
        return (f"Volume file not found: {path}. .vdb files are not packed into the .blend; keep the "
                f"'{VDB_FOLDER_NAME}' folder beside the .blend or rebuild the volume.")
    if not data.grids.load():
        return f"Cannot read volume file {path}: {data.grids.error_message or 'unknown error'}. Rebuild the volume."
    names = {g.name for g in data.grids}
    missing = [g for g in REQUIRED_GRIDS if g not in names]
    if missing:
        return f"Volume file {path} lacks the grid(s) {', '.join(missing)}: rebuild the volume."
    return None
