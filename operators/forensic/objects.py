"""The plain materials of the forensic objects and a study object's mesh as an engine Mesh."""
from __future__ import annotations

import bpy
import numpy as np

from ...pdehead_addon import Mesh
from .. import compat
from ..coords import MM_TO_M


def plain_material(name: str, colour):
    mat = bpy.data.materials.get(name)
    if mat is None:
        mat = bpy.data.materials.new(name)
        compat.node_tree(mat)  # nodes on where Blender < 5.0 starts without
        bsdf = mat.node_tree.nodes.get("Principled BSDF")
        bsdf.inputs["Base Color"].default_value = colour
        bsdf.inputs["Roughness"].default_value = 0.6
        mat.diffuse_color = colour
    return mat


def set_material(obj, mat) -> None:
    if obj.data.materials:
        obj.data.materials[0] = mat
    else:
        obj.data.materials.append(mat)


def engine_mesh_of(obj, origin):
    """The mesh of the study object ``obj`` as an engine Mesh in patient mm (its data's coordinates plus the
    study's ``origin``, metres; the object's own transform, e.g. the Frankfurt view, left out), triangulated."""
    me = obj.data
    me.calc_loop_triangles()
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    tris = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("vertices", tris)
    vertices = (co.reshape(-1, 3).astype(np.float64) + np.asarray(origin, float)) / MM_TO_M
    return Mesh(vertices, np.zeros((0, 4), np.int64), tris.reshape(-1, 3).astype(np.int64))
