"""Blender objects of the forensic toolkit: the study's sub-collections, the forensic cache, objects
linked from the study collection and the plain materials (:mod:`.forensic_skull`, :mod:`.forensic_study`
and :mod:`.face` share them).
"""
from __future__ import annotations

import bpy

from . import compat, state


def sub_collection(coll, suffix: str):
    name = f"{coll.name} {suffix}"
    sub = bpy.data.collections.get(name)
    if sub is None:
        sub = bpy.data.collections.new(name)
    if sub.name not in coll.children:
        coll.children.link(sub)
    return sub


def forensic_cache(coll):
    return state.cache_for(state.settings(coll).study_id).forensic


def linked_object(coll, key):
    obj = coll.get(key)
    return obj if isinstance(obj, bpy.types.Object) and obj.name in bpy.data.objects else None


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
