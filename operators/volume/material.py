"""The volume's material: paper eq. 24 in shader nodes (node group "PDE Head eq. 24") and the
transfer-function presets.

The material reads the ``w``, ``intensity`` and ``ct`` grids of the .vdb (:mod:`.vdb_grids`) with
Attribute nodes; the node group turns w into eq. 24's opacity
``alpha = (l_alpha - h_alpha) * w + h_alpha`` (zero outside the solid, w > 1), so l_alpha, h_alpha
and the density scale change live without rewriting the file.
"""
from __future__ import annotations

import bpy
import numpy as np

from ...pdehead_addon import OUTSIDE_W, defaults as D
from .. import compat
from .vdb_grids import GRID_NAMES

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
    mat = None
    if obj is not None and obj.material_slots and obj.material_slots[0].material is not None:
        mat = obj.material_slots[0].material
        if mat.get("pdehead_volume_material") == 1:
            return mat
    if name is None:
        name = f"PDE Head Volume {obj.name}" if obj is not None else "PDE Head Volume"
    mat = bpy.data.materials.new(name)
    mat["pdehead_volume_material"] = 1
    compat.node_tree(mat)  # nodes on where Blender < 5.0 starts without
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


def _link_transfer(nodes, links, group_node, ramp, pv) -> None:
    """Density and emission of the volume = the eq. 24 group's outputs x the colour ramp's alpha."""
    for out_name, in_name, y in (("Density", "Density", 250), ("Emission Strength", "Emission Strength", 50)):
        label = f"transfer alpha x {out_name.lower()}"
        node = nodes.get(label) or _math(nodes, "MULTIPLY", label, (150, y))
        links.new(group_node.outputs[out_name], node.inputs[0])
        links.new(ramp.outputs["Alpha"], node.inputs[1])
        links.new(node.outputs[0], pv.inputs[in_name])


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
